"""experiments.replot re-renders a committed result folder from its results.json without changing a number."""

import json
import shutil
from pathlib import Path

import pytest

from experiments import replot

ROOT = Path(__file__).resolve().parents[1]
PUBLISHED = ROOT / "docs" / "results" / "quick"  # experiments.reproduce's tree
# results.json files kept from earlier published runs: a 3-seed ablation whose frozen variants tie, and the probes
# (diagnostics outside the pipeline, whose published folders left the tree)
FIXTURES = ROOT / "tests" / "fixtures" / "results"


def test_replot_reproduces_the_committed_tables(tmp_path):
    src = PUBLISHED / "ablation"
    shutil.copy(src / "results.json", tmp_path / "results.json")
    assert replot.replot(tmp_path) == "ablation"
    for name in ("table1.md", "table2.md", "table3.md", "training.md"):
        assert (tmp_path / name).read_text() == (src / name).read_text(), name
    for name in ("table1.png", "table2.png", "table3.png", "training_curves.png"):
        assert (tmp_path / name).stat().st_size > 10_000, name


def test_replot_rewrites_verdicts_written_by_older_code(tmp_path):
    """A folder's findings were worded by the code of its run's day; the two frozen variants, equal to 0.1 points
    over 3 seeds, must read as a tie, not 'does NOT reproduce'."""
    results = json.loads((FIXTURES / "ablation-full.json").read_text())
    results["findings"] = {k: f"stale {k}" for k in ("table1", "table2", "table3")}
    (tmp_path / "results.json").write_text(json.dumps(results))
    replot.replot(tmp_path)
    table2 = (tmp_path / "table2.md").read_text()
    assert "stale" not in table2
    assert "The frozen backbone (DINO_F R) is worst: tie, not resolved" in table2


def test_replot_redraws_the_downstream_tables_and_figures_and_records_its_commit(tmp_path):
    src = PUBLISHED / "downstream"
    shutil.copy(src / "results.json", tmp_path / "results.json")
    assert replot.replot(tmp_path) == "downstream"
    for name in ("table4.md", "grasping.md", "table4.csv", "push_duration.csv", "grasp_cup.csv"):
        assert (tmp_path / name).read_text() == (src / name).read_text(), name
    for name in ("push_force.png", "push_duration.png", "grasp_steps.png"):
        assert (tmp_path / name).stat().st_size > 10_000, name
    before, after = (json.loads(p.read_text()) for p in (src / "results.json", tmp_path / "results.json"))
    assert after.pop("replotted") and after == {k: v for k, v in before.items() if k != "replotted"}


@pytest.mark.parametrize("kind", ["object_probe", "contact_probe"])
def test_replot_redraws_the_probe_figures(tmp_path, kind):
    shutil.copy(FIXTURES / f"{kind}.json", tmp_path / "results.json")
    assert replot.replot(tmp_path) == kind
    png = f"{kind}.png"
    assert (tmp_path / png).stat().st_size > 10_000


def test_replot_refuses_other_folders(tmp_path):
    with pytest.raises(FileNotFoundError, match="results.json"):
        replot.replot(tmp_path)
    (tmp_path / "results.json").write_text('{"cells": []}')
    with pytest.raises(ValueError, match="not from an experiment that re-renders"):
        replot.replot(tmp_path)


def test_the_commit_is_read_once_at_the_start_of_a_run(monkeypatch):
    """A result records the code it ran: a commit made during a long run must not be stamped on its figures."""
    from experiments import common

    common.git_commit.cache_clear()
    monkeypatch.setattr(common.subprocess, "run", lambda *a, **k: (_ for _ in ()).throw(OSError("no git")))
    assert common.git_commit() == "unknown"
    monkeypatch.undo()
    assert common.git_commit() == "unknown"  # HEAD moved on, the run's commit did not
    common.git_commit.cache_clear()


def test_only_code_makes_a_run_dirty(tmp_path, monkeypatch):
    """Published results and tables (docs/, *.md) are not code: a run after a publishing call still records its
    commit; a changed source file makes it "-dirty"."""
    import subprocess

    from experiments import common

    git = lambda *a: subprocess.run(["git", *a], cwd=tmp_path, check=True, capture_output=True)  # noqa: E731
    git("init", "-q")
    for name in ("docs/results/x.json", "README.md", "ffjax/code.py"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("0\n")
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "first")
    monkeypatch.setattr(common, "ROOT", tmp_path)
    read = lambda: (common.git_commit.cache_clear(), common.git_commit())[1]  # noqa: E731
    head = read()
    assert len(head) == 40
    (tmp_path / "docs/results/x.json").write_text("1\n")
    (tmp_path / "README.md").write_text("1\n")
    assert read() == head
    (tmp_path / "ffjax/code.py").write_text("1\n")
    assert read() == head + "-dirty"
    common.git_commit.cache_clear()


def test_replot_records_the_commit_read_before_it_rewrote_anything(tmp_path, monkeypatch):
    """Re-rendering rewrites tracked files (results.json, the tables): a commit read after the first folder would
    say "-dirty" for every folder of a call on a clean checkout, and experiments.status would keep asking a replot."""
    from experiments import common

    src = PUBLISHED / "ablation"
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        shutil.copy(src / "results.json", tmp_path / name / "results.json")
    reads = iter(["c0ffee", "c0ffee-dirty", "c0ffee-dirty"])
    monkeypatch.setattr(common, "git_commit", lambda: next(reads))
    assert replot.main([str(tmp_path / "a"), str(tmp_path / "b")]) == 0
    for name in ("a", "b"):
        assert json.loads((tmp_path / name / "results.json").read_text())["replotted"] == "c0ffee"
