"""Recording (fake camera + typed forces -> release CSV) and the calibration CLI on it."""

import hashlib
import json

import _smoke_run
import numpy as np
import pytest

from ffjax import cli, data, inference
from ffjax.calibrate import record, tool


@pytest.fixture(scope="module")
def run_dir():
    return _smoke_run.smoke_run()


def _camera(seed=7, n=40):
    """A stand-in camera: settling frames, no-contact frames, then one press per frame (the sim knows the
    forces; the test types them in as the user would)."""
    b = _smoke_run.presses(n, seed=seed)
    frames = [b["background"]] * 4 + [b["background"]] * 3 + list(b["image"])
    return iter(frames), b


def test_parse_force():
    np.testing.assert_allclose(record.parse_force("2.5"), [0, 0, 2.5])
    np.testing.assert_allclose(record.parse_force("200g"), [0, 0, 0.2 * 9.81], rtol=1e-6)
    np.testing.assert_allclose(record.parse_force("0.5 kg"), [0, 0, 0.5 * 9.81], rtol=1e-6)
    np.testing.assert_allclose(record.parse_force("0.1, -0.2, 3 N"), [0.1, -0.2, 3])
    for bad in ("heavy", "1 2"):
        with pytest.raises(ValueError):
            record.parse_force(bad)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("calib")
    frames, b = _camera()
    typed = [" ".join(f"{v:.6g}" for v in f) for f in b["force"]]
    answers = iter(["oops"] + typed + ["q"])  # a typo is reported and asked again
    logs = []
    path = record.session(frames, lambda i: next(answers), out, per_press=1, warmup=4, bg_frames=3,
                          log=logs.append)
    assert any("cannot read a force" in line for line in logs)
    return path, b


def test_record_writes_release_layout(recorded, tmp_path):
    path, b = recorded
    src = data.open_split(path)
    assert len(src) == len(b["force"])
    np.testing.assert_array_equal(src.background, b["background"])
    np.testing.assert_allclose(src.forces, b["force"], rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(src[3]["image"], b["image"][3])
    header = path.read_text().splitlines()[0]
    assert header == "tactile,FT" and path.read_text().splitlines()[1].endswith(" 0 0 0")
    # a second session into the same folder appends with its own background
    frames, b2 = _camera(seed=8, n=3)
    answers = iter(["1.5", "q"])
    out = tmp_path / "again"
    import shutil

    shutil.copytree(path.parent, out)
    p2 = record.session(frames, lambda i: next(answers), out, per_press=2, warmup=4, bg_frames=3, log=lambda s: None)
    src2 = data.open_split(p2)
    assert len(src2) == len(b["force"]) + 2 and (out / "background_1.png").is_file()
    np.testing.assert_array_equal(src2[len(b["force"])]["image"], b2["image"][0])
    np.testing.assert_allclose(src2.forces[-1], [0, 0, 1.5])


def test_a_second_recording_into_a_busy_folder_is_refused(recorded, tmp_path):
    """It used to go on and, at its first press, rewrite data.csv without the first session's rows."""
    from ffjax.errors import FolderLockedError
    from ffjax.files import folder_lock

    path, _ = recorded
    before = _digest(path.parent)
    frames, _ = _camera(seed=9, n=3)
    with folder_lock(path.parent, "calibration recording"), \
            pytest.raises(FolderLockedError, match=rf"{path.parent} is in use by another calibration recording \(pid"):
        record.session(frames, lambda i: "1.5" if i == 0 else "q", path.parent, per_press=1, warmup=0, bg_frames=1,
                       log=lambda s: None)
    assert _digest(path.parent) == before


def _digest(folder):
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_calibrate_cli_improves_and_writes_a_loadable_checkpoint(run_dir, recorded, tmp_path, capsys):
    path, b = recorded
    before_files = _digest(run_dir)
    out = tmp_path / "calibrated"
    argv = ["--checkpoint", str(run_dir), "--data", str(path), "--out", str(out), "--layers", "regressor",
            "--steps", "150", "--lr", "3e-3", "--holdout", "0.25"]
    assert tool.main(argv) == 0
    assert _digest(run_dir) == before_files  # the original is never modified
    text = capsys.readouterr().out
    assert "before" in text and "after" in text
    rep = json.loads((out / "calibration.json").read_text())
    assert rep["n"] == 40 and rep["n_holdout"] == 10 and rep["n_fit"] == 30
    # the smoke model saw two training steps, so whether 30 frames generalize to 10 held-out ones is luck;
    # the fit itself must lower the error on the frames it was fitted to, and both numbers are reported
    assert rep["fit_after"]["nl1"] < 0.9 * rep["fit_before"]["nl1"], rep
    assert np.isfinite(rep["holdout_after"]["nl1"]) and np.isfinite(rep["holdout_before"]["nl1"])
    pred = inference.load(out)
    assert pred.trained.kind == "bundle" and pred.frame_size == tuple(b["image"].shape[1:3])
    pred.set_background(b["background"])
    hold = tool.split_indices(40, 0.25, 0)[1]
    forces = np.concatenate([pred.predict(b["image"][i]) for i in hold])  # batch 1: compiled already
    mae = np.abs(forces - b["force"][hold]).mean(0)
    np.testing.assert_allclose(mae, rep["holdout_after"]["mae_n"], rtol=1e-3, atol=1e-4)
    # calibrating a calibrated folder works too; a non-empty --out or the checkpoint itself is refused
    assert tool.main(["--checkpoint", str(out), "--data", str(path), "--out", str(tmp_path / "c2"),
                      "--steps", "2", "--layers", "regressor", "--lr", "3e-3"]) == 0  # compiled step reused
    assert tool.main(argv) == 2
    assert tool.main(["--checkpoint", str(run_dir), "--data", str(path), "--out", str(run_dir / "x")]) == 2
    assert f"--out {run_dir / 'x'} is inside {run_dir}, which this command reads" in capsys.readouterr().err
    # a second calibration into a folder another one is writing stops, naming the holder
    from ffjax.files import folder_lock

    with folder_lock(tmp_path / "c3", "calibration"):
        assert cli.run(tool.main, ["--checkpoint", str(run_dir), "--data", str(path), "--out", str(tmp_path / "c3"),
                          "--steps", "1", "--layers", "regressor"]) == 1
    assert "is in use by another calibration (pid" in capsys.readouterr().err
    assert [p.name for p in (tmp_path / "c3").iterdir()] == []  # the holder's lock file went with its release


def test_a_diverging_calibration_writes_nothing(run_dir, recorded, tmp_path, capsys):
    """--lr 1e30 passes the flag check but the fit diverges: it used to write a NaN-weight bundle and exit 0."""
    path, _ = recorded
    out = tmp_path / "diverged"
    assert tool.main(["--checkpoint", str(run_dir), "--data", str(path), "--out", str(out), "--steps", "20",
                      "--layers", "regressor", "--lr", "1e30"]) == 2
    assert "calibration diverged: the fitted regressor has NaN/inf weights" in capsys.readouterr().err
    assert [p.name for p in out.iterdir()] == []


@pytest.mark.parametrize("flag", [("--lr", "nan"), ("--lr", "-1"), ("--lr", "inf"), ("--batch-size", "0"),
                                  ("--steps", "0"), ("--holdout", "1"), ("--holdout", "nan")])
def test_calibrate_refuses_bad_flags_before_any_work(tmp_path, capsys, flag):
    with pytest.raises(SystemExit) as e:
        tool.main(["--checkpoint", str(tmp_path / "ck"), "--data", str(tmp_path / "d.csv"),
                   "--out", str(tmp_path / "out"), *flag])
    assert e.value.code == 2 and f"argument {flag[0]}" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_split_indices_seeded_and_disjoint():
    fit, hold = tool.split_indices(10, 0.2, seed=1)
    assert len(hold) == 2 and not set(fit) & set(hold) and sorted([*fit, *hold]) == list(range(10))
    assert np.array_equal(hold, tool.split_indices(10, 0.2, seed=1)[1])
    assert len(tool.split_indices(1, 0.2, 0)[1]) == 0


def test_calibrate_refuses_an_out_it_cannot_write_before_any_work(tmp_path, capsys):
    """Issue 33 (7): an --out that cannot be written (under a file here; a read-only disk alike) is a usage error
    naming --out (exit 2), before the checkpoint or the data are read."""
    (tmp_path / "notes.txt").write_text("a file")
    with pytest.raises(SystemExit) as e:
        tool.main(["--checkpoint", str(tmp_path / "ck"), "--data", str(tmp_path / "d.csv"),
                   "--out", str(tmp_path / "notes.txt" / "out")])
    assert e.value.code == 2 and "--out" in capsys.readouterr().err
