"""The figures: one style for all (experiments.style), no global backend switch in library code, and every
published figure redrawn by experiments.replot from its results.json alone, with the reviewers' complaints
(issue 62) checked on the redrawn figures themselves."""

from __future__ import annotations

import ast
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from experiments import catalog, replot, style

ROOT = Path(__file__).resolve().parents[1]
PUBLISHED = ROOT / "docs" / "results"


def _sources():
    for top in ("ffjax", "experiments"):
        yield from sorted((ROOT / top).rglob("*.py"))


def test_no_library_module_switches_matplotlibs_backend():
    """matplotlib.use / pyplot.switch_backend in library code break a notebook's inline plots (a later plt.show()
    draws nothing): figures are drawn on the object API instead (style.figure)."""
    switch = re.compile(r"\bmatplotlib\s*\.\s*use\s*\(|\bswitch_backend\s*\(")
    offenders = {str(p.relative_to(ROOT)) for p in _sources() if switch.search(p.read_text())}
    assert not offenders, f"switches the global backend: {sorted(offenders)}"


def _styled_modules():
    """The top-level experiment modules that draw, and the simulator's gallery (which draws without experiments)."""
    return [p for p in sorted((ROOT / "experiments").glob("*.py")) if p.name != "style.py"
            and "style.figure(" in p.read_text()]


def test_every_figure_is_drawn_through_the_style():
    """Every function that makes a figure (style.figure) runs under @style.plots (the shared fonts), and no drawing
    module reaches pyplot or writes a PNG other than through style.save."""
    drawing = _styled_modules()
    assert {p.stem for p in drawing} >= {"tables", "training_figures", "pareto", "stability", "pattern_share",
                                         "sweep_loss", "downstream_report"}
    for path in drawing:
        text = path.read_text()
        assert "import matplotlib.pyplot" not in text and ".savefig(" not in text, path.name
        tree = ast.parse(text)

        def decorated(fn) -> bool:
            return any(ast.unparse(d) == "style.plots" for d in fn.decorator_list)

        def visit(node, styled: bool, where: str):
            for child in ast.iter_child_nodes(node):
                if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    visit(child, styled or decorated(child), where)
                    continue
                if isinstance(child, ast.Call) and ast.unparse(child.func) == "style.figure":
                    assert styled, f"{where}:{child.lineno}: style.figure outside a @style.plots function"
                visit(child, styled, where)

        visit(tree, False, path.name)
    gallery = (ROOT / "ffjax" / "sim" / "gallery.py").read_text()
    assert "import matplotlib.pyplot" not in gallery and "FigureCanvasAgg" in gallery


def test_a_plot_leaves_the_backend_and_the_rcparams_alone(tmp_path, monkeypatch):
    import matplotlib

    from experiments import sweep_loss

    calls = []
    monkeypatch.setattr(matplotlib, "use", lambda *a, **k: calls.append(a))
    before = dict(matplotlib.rcParams)
    sweep_loss.plot(json.loads((PUBLISHED / "quick" / "sweep_loss" / "results.json").read_text()),
                    tmp_path / "sweep.png")
    assert not calls and (tmp_path / "sweep.png").stat().st_size > 10_000
    assert {k: v for k, v in matplotlib.rcParams.items() if before.get(k) != v} == {}


def _folders() -> list[Path]:
    """Every published results folder that holds a figure."""
    return sorted(p.parent for p in PUBLISHED.rglob("results.json") if any(p.parent.glob("*.png")))


@pytest.fixture(scope="module")
def redrawn(tmp_path_factory):
    """Each published folder replotted from a copy of its results.json alone: {folder name: (copy, {png: fig})},
    the figures caught on their way through style.save."""
    out = {}
    with pytest.MonkeyPatch.context() as mp:
        caught: dict = {}
        save = style.save

        def keep(fig, path, *args, **kwargs):
            caught[Path(path).name] = fig
            return save(fig, path, *args, **kwargs)

        mp.setattr(style, "save", keep)
        for folder in _folders():
            if folder.name in ("ablation", "downstream"):  # drawn in test_replot; Tables I-III below
                continue
            copy = tmp_path_factory.mktemp(folder.name)
            shutil.copy(folder / "results.json", copy / "results.json")
            caught = {}
            replot.replot(copy, commit="test")
            out[str(folder.relative_to(PUBLISHED))] = (copy, caught)
    return out


@pytest.mark.parametrize("folder", [str(p.relative_to(PUBLISHED)) for p in _folders()])
def test_replot_redraws_every_published_figure_from_its_results_alone(folder, redrawn):
    results = json.loads((PUBLISHED / folder / "results.json").read_text())
    assert catalog.kind_of(results) is not None and catalog.kind_of(results).replot is not None, folder
    if folder not in redrawn:  # ablation, downstream: test_replot.py
        return
    copy, figs = redrawn[folder]
    for png in sorted((PUBLISHED / folder).glob("*.png")):
        assert (copy / png.name).stat().st_size > 5_000, f"{folder}/{png.name} not redrawn"
    from PIL import Image

    for name in figs:  # saved through the style: at its resolution
        with Image.open(copy / name) as im:
            assert round(im.info["dpi"][0]) == style.DPI, name


def _texts(fig) -> list[str]:
    return [t.get_text() for ax in fig.axes for t in ax.texts] + [t.get_text() for t in fig.texts]


def test_pareto_labels_every_point_once_with_a_short_title_and_clear_keys(redrawn):
    from experiments import pareto

    results = json.loads((PUBLISHED / "quick" / "pareto" / "results.json").read_text())
    fig = redrawn["quick/pareto"][1]["pareto.png"]
    assert fig.get_suptitle() == f"Speed against accuracy (preset {results['preset']})"
    names = {style.name(m) for m in results["methods"]}
    for ax in fig.axes:
        labels = [t.get_text() for t in ax.texts]
        # each label names one point, or points drawn together ('DINO_F R, DINO_F RD vit-s'): every cell once
        named = sum(len([n for n in re.split(r", | / ", lab.split(" vit-")[0]) if n in names]) for lab in labels)
        assert named == len(results["cells"]), (ax.get_title(), labels)
        assert "_" not in ax.get_xlabel() and "nl1" not in ax.get_ylabel()
        assert not any(" resnet" in lab for lab in labels)
    # the keys: each a legend of its own, no marker of the sizes' key used for the seeds
    keys = {lg.get_title().get_text(): lg for lg in fig.legends}
    assert len(keys) == 3
    sizes = {h.get_marker() for h in keys["backbone size (marker)"].legend_handles}
    assert not sizes & {getattr(h, "get_marker", lambda: None)() for h in keys["seeds and front"].legend_handles}
    assert pareto.AXIS_LABELS["train_img_s"] == "training throughput (images/s)"


def test_stability_says_its_encoding_once_and_explains_the_grey_band(redrawn):
    figs = redrawn["quick/stability"][1]
    fig = figs["stability.png"]
    titles = [ax.get_title() for ax in fig.axes if ax.get_visible() and ax.axison]
    assert titles and not any("doubles" in t or "dotted" in t for t in titles)
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    assert len(legends) == 1
    said = [t.get_text() for t in legends[0].get_texts()]
    assert any(s.startswith("grey band") for s in said) and any(s.startswith("x: ") for s in said)
    assert any("beyond training" in t for t in _texts(fig))
    w, h = fig.get_size_inches()
    assert w / 3 >= 5 and h / np.ceil(len(titles) / 3) >= 3.5  # panels of a readable size


def test_pattern_share_shows_the_spread_against_the_error_itself(redrawn):
    fig = redrawn["quick/pattern_share"][1]["pattern_share.png"]
    assert all(ax.get_ylim()[0] == 0 for ax in fig.axes)


def test_tables_draw_the_paper_beside_our_bars_and_clip_a_far_value(tmp_path, monkeypatch):
    from experiments import paper_numbers as P
    from experiments import tables, training_figures

    caught = {}
    save = style.save
    monkeypatch.setattr(style, "save", lambda fig, path, *a, **k: (caught.__setitem__(Path(path).name, fig),
                                                                   save(fig, path, *a, **k))[1])
    results = json.loads((PUBLISHED / "quick" / "ablation" / "results.json").read_text())
    tables.plot_all(results, tmp_path)
    for name in ("table1.png", "table2.png", "table3.png"):
        for ax in caught[name].axes:
            paper = [p for p in ax.patches if p.get_hatch() == style.PAPER_HATCH]
            ours = [p for p in ax.patches if p.get_hatch() != style.PAPER_HATCH and p.get_height() > 0]
            if not paper:
                continue
            for p in paper:  # beside our bars, never on them; in the colour of the bar just left of it
                assert not any(p.get_x() < o.get_x() + o.get_width() - 1e-9 and o.get_x() < p.get_x() + p.get_width()
                               - 1e-9 for o in ours)
                left = max((o for o in ours if o.get_x() < p.get_x()), key=lambda o: o.get_x())
                assert np.allclose(p.get_edgecolor()[:3], left.get_facecolor()[:3])
            labels = [t.get_text() for t in (ax.get_legend().get_texts() if ax.get_legend() else [])]
            assert name == "table3.png" or any(s.startswith(style.PAPER_LABEL) for s in labels)
    # Table III's DIGIT panel: the y range is ours; the paper's value far above it is clipped and written there
    digit = caught["table3.png"].axes[P.CALIB_TARGETS.index("digit")]
    far = max(v[P.CALIB_TARGETS.index("digit")] for v in P.TABLE3.values())
    assert digit.get_ylim()[1] < far
    assert f"\u2191{far:.1f}" in [t.get_text() for t in digit.texts]
    # the training curves: against the step, not wall-clock time (the runs were not timed for speed)
    training_figures.plot(results["training"], tmp_path / "training_curves.png", results["preset"])
    ax = caught["training_curves.png"].axes[0]
    assert ax.get_xlabel() == "training step"
    assert not any("time" in a.get_xlabel() for a in caught["training_curves.png"].axes)
