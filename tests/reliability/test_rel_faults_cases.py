"""faults_cases (beside this file), issue 17's numbered cases: the cheapest ones run through the harness in CI (case 3,
calibrate's refused flags; case 7's one-line errors that need no trained model; case 9's small files declaring
huge tensors), and its checks decide a row."""

import faults
import faults_cases
import pytest
from _tiny_data import write_tiny_split


@pytest.fixture(scope="module")
def shared(tmp_path_factory):
    root = tmp_path_factory.mktemp("cases")
    write_tiny_split(root / "data" / "train", 16, 0)
    write_tiny_split(root / "data" / "val", 8, 1)
    return faults_cases.Shared(env=faults._env(root), data=root / "data")


@pytest.mark.parametrize("fn, tags", [
    (faults_cases.case3, ["3a", "3b", "3c"]),
    (faults_cases.case7_inputs, ["7a", "7b", "7e", "7f", "7g", "7h", "7i", "7m", "7n"]),
    (faults_cases.case9, ["9a", "9b"]),
    (faults_cases.case33, ["33-2", "33-3", "33-4", "33-7a", "33-7b", "33-7c", "33-5"]),
])
def test_cheap_cases_pass_through_the_real_clis(fn, tags, shared, tmp_path):
    rows = faults_cases.run_case(fn, tmp_path / fn.__name__, shared, fn.__name__)
    assert [r["case"] for r in rows] == tags
    assert all(r["checks"] and r["rc"] in (1, 2) for r in rows)
    failed = [r for r in rows if not r["pass"]]
    assert not failed, faults_cases.cases_md(failed)
    assert all((tmp_path / fn.__name__ / f"{t}.stderr").is_file() for t in tags)  # every command's output kept


def test_a_failed_check_fails_its_row_and_the_table_says_so():
    ok = {"rc": 2, "out": "", "err": "usage: x\nx: error: argument --lr: bad | value\n", "cmd": "x", "seconds": 0.1}
    crash = {"rc": 1, "out": "", "err": "Traceback (most recent call last):\nValueError: --lr\n", "cmd": "x",
             "seconds": 0.1}
    good = faults_cases._row("3a", "w", "e", ok, faults_cases._error_checks(ok, (2,), ["--lr"]))
    bad = faults_cases._row("3b", "w", "e", crash, faults_cases._error_checks(crash, (2,), ["--lr"]))
    assert good["pass"] and good["key_line"] == "x: error: argument --lr: bad | value"
    assert not bad["pass"] and bad["checks"] == {"rc 2": False, "one error line": False, "says '--lr'": False,
                                                 "no 'Traceback'": False}
    md = faults_cases.cases_md([good, bad, faults_cases._skipped("5", "w", "e", "mount failed")])
    assert md.count("\n| ") == 3 and "bad \\| value" in md
    assert "| **NO** |" in md and "| skipped |" in md and "1 of 3 commands pass, 1 skipped." in md


def test_a_harness_error_is_a_failing_row(shared, tmp_path):
    def case0(d, sh):
        """A case whose harness breaks."""
        raise RuntimeError("boom")

    (row,) = faults_cases.run_case(case0, tmp_path / "case0", shared, "0")
    assert row["pass"] is False and "boom" in row["key_line"]
    assert "RuntimeError: boom" in (tmp_path / "case0" / "error.txt").read_text()
