"""experiments.same_output: the simulator's outputs at two commits, compared byte for byte."""

import subprocess

import pytest

from experiments import common, same_output


def test_compare_names_what_differs_and_what_one_side_lacks():
    base = {"a": "1", "b": "2", "c": "3"}
    assert same_output.compare(base, dict(base)) == {"presses": 3, "differ": [], "only_one_side": [], "same": True}
    r = same_output.compare(base, {"a": "1", "b": "9", "d": "4"})
    assert (r["differ"], r["only_one_side"], r["same"]) == (["b"], ["c", "d"], False)


def test_head_renders_the_same_bytes_as_itself(tmp_path):
    """The whole path on a few presses: both revisions rendered in their own worktree and process."""
    if subprocess.run(["git", "rev-parse", "HEAD"], cwd=common.ROOT, capture_output=True).returncode:
        pytest.skip("not a git checkout")
    r = same_output.check("HEAD", small=True)
    assert r["same"] and r["presses"] >= 9 and r["files"] == []


def test_a_dirty_simulator_is_not_certified(monkeypatch):
    monkeypatch.setattr(same_output, "_git", lambda *a, **k: " M ffjax/sim/press.py" if a[0] == "status" else "x")
    with pytest.raises(SystemExit, match="uncommitted"):
        same_output.main(["--base", "HEAD", "--certify"])
