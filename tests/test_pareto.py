"""experiments.pareto: the Pareto front on hand-made points, the grid and the size configs. Its smoke run is part
of the whole pipeline's test (test_reproduce.py). No timed assertions: the machine is shared."""

import pytest

from experiments import common, pareto


def test_front_minimizes_both_axes():
    pts = [(1, 5), (2, 3), (3, 4), (4, 1), (2, 3.5), (5, 1)]
    assert pareto.pareto_front(pts) == [0, 1, 3]


def test_front_maximizes_x_when_asked_and_skips_nan():
    # (throughput, error): more throughput and less error are better
    pts = [(100, 5), (50, 2), (80, 6), (100, 5.5), (float("nan"), 0.1), (10, 2)]
    assert pareto.pareto_front(pts, (False, True)) == [0, 1]


def test_front_keeps_ties_and_handles_empty():
    assert pareto.pareto_front([(1, 1), (1, 1), (2, 2)]) == [0, 1]
    assert pareto.pareto_front([]) == []


def test_lean_grid_trains_all_methods_only_at_the_presets_size():
    cfg = {"preset": "quick"}
    cells = pareto.grid(cfg, ["resnet_rd", "dino_r", "dino_rd"], ["vit-xs", "vit-s", "resnet"])
    assert cells == [("vit-xs", "dino_rd"), ("vit-s", "dino_r"), ("vit-s", "dino_rd"), ("resnet", "resnet_rd")]
    full = pareto.grid(cfg, ["dino_r", "dino_rd"], ["vit-xs", "vit-m"], full=True)
    assert len(full) == 4


def test_size_cfg_overrides_only_the_backbone():
    import configs

    cfg = configs.get("quick")
    m = pareto.size_cfg(cfg, "vit-m")["model"]
    assert (m["vit"]["dim"], m["vit"]["depth"], m["vit"]["patch"]) == (128, 4, cfg["model"]["vit"]["patch"])
    assert m["resnet"] == cfg["model"]["resnet"] and cfg["model"]["vit"]["dim"] == 64


def test_backbone_folder_per_size(tmp_path, monkeypatch):
    import configs
    from ffjax import registry
    from ffjax.train import pretrain

    calls = []
    monkeypatch.setattr(pretrain, "ensure", lambda cfg, kind, folder, **kw: calls.append((cfg, kind, folder)))
    monkeypatch.setattr(pretrain, "load_backbone", lambda folder, kind=None: ("params", folder))
    cfg, spec = configs.get("smoke"), registry.get("dino_rd")
    folders = set()
    for size in ("vit-xs", "vit-m"):
        scfg = pareto.size_cfg(cfg, size)
        assert pareto.backbone_for(cfg, scfg, size, spec, tmp_path, False, False) == ("params", calls[-1][2])
        assert calls[-1][0] is scfg and calls[-1][1] == "vit"
        folders.add(calls[-1][2])
    assert len(folders) == 2 and all(f.parent == tmp_path / "pretrained" for f in folders)
    assert tmp_path / "pretrained" / "vit" not in folders  # the preset's own (the ablation's) stays apart
    assert pareto.backbone_for(cfg, cfg, "vit-s", registry.get("dino_rd_scratch"), tmp_path, False, False) is None


def _cell(method, size, seeds, runs):
    return {"method": method, "size": size, "seeds": seeds, "runs": runs}


def test_seeds_said_tells_own_cells_from_the_ablations():
    """The figure corner and pareto.md say which cells have which seeds (not the union over all cells)."""
    abl = [f"/a/runs/dino_r/seed{k}" for k in range(3)]
    res = {"seeds": [0], "reused_ablation_runs": abl,
           "cells": [_cell("dino_rd", "vit-xs", [0], ["/p/runs/vit-xs/dino_rd/seed0"]),
                     _cell("dino_r", "vit-s", [0, 1, 2], abl)]}
    assert pareto.seeds_said(res) == "0 for the cells trained here; 0-2 for the cells reused from the ablation"
    assert pareto.seeds_said(res, names=True) == ("0 for the cells trained here (DINO RD vit-xs); "
                                                  "0-2 for the cells reused from the ablation (DINO R vit-s)")
    res["cells"][1]["seeds"], res["cells"][1]["runs"] = [0], abl[:1]
    assert pareto.seeds_said(res) == "0"  # every cell alike: just the seeds
    del res["reused_ablation_runs"]  # a results.json from before it was recorded: refused by name, not guessed
    with pytest.raises(ValueError, match="reused_ablation_runs"):
        pareto.seeds_said(res)


def test_seed_span():
    from experiments import tables

    assert [tables.seed_span(s) for s in ([0], [2, 0, 1], [0, 1, 4], [])] == ["0", "0-2", "0-1, 4", ""]


def test_point_labels_miss_each_other_and_stay_in_the_axes():
    """Crowded points, some at the axes' edge: every label inside the axes and clear of the others."""
    from matplotlib.text import Text

    from experiments import style

    fig, ax = style.figure(figsize=(4, 3))  # outside pyplot: no backend switched for the rest of the suite
    pts = [(0.0, 0.0), (0.02, 0.01), (0.04, -0.01), (1.0, 1.0), (0.98, 0.99), (0.5, 0.5)]
    ax.scatter(*zip(*pts))
    ax.set(xlim=(-0.05, 1.05), ylim=(-0.05, 1.05))
    fig.tight_layout()
    renderer = fig.canvas.get_renderer()
    labels = common.place_labels(ax, pts, [f"method {k} long-name" for k in range(len(pts))], [4.0] * len(pts),
                                 [], renderer)
    for t in labels:
        t.update_positions(renderer)
    boxes = [Text.get_window_extent(t, renderer) for t in labels]  # the text's, without a leader line
    frame = ax.get_window_extent(renderer)
    assert all(frame.x0 <= b.x0 and b.x1 <= frame.x1 and frame.y0 <= b.y0 and b.y1 <= frame.y1 for b in boxes)
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])
