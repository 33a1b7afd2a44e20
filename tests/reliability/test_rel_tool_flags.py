"""Issue 61: export, live and calibrate refuse a bad flag value at parse time with one line naming the flag and
the form expected (they were tracebacks, a segfault in cv2.VideoCapture(-1), or an export that failed only when
called), an export without a digest loads with a warning that it is unverified, a killed export leaves no temp
file, and a calibration without held-out frames does not report "held-out" errors. Random-weight smoke model."""

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest
from test_rel_live_faults import BG, ckpt  # noqa: F401 - the random-weight checkpoint fixture and its background

from ffjax import cli, export, inference, live, store
from ffjax.calibrate import record
from ffjax.calibrate import tool as calibrate_tool
from ffjax.errors import CheckpointError
from ffjax.files import atomic_write, atomic_write_bytes

pytest.importorskip("flatbuffers", reason="jax.export serialization needs the flatbuffers package")


def _refused(main, argv, capsys, fragment, tmp_path):
    """main(argv) stops in argparse: exit 2, one error line naming the flag and the expected form, nothing written."""
    with pytest.raises(SystemExit) as e:
        main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and err[-1].count("error:") == 1 and fragment in err[-1], err
    assert "Traceback" not in "\n".join(err)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("flag, value, fragment", [
    ("--batch", "-1", "argument --batch: expected an integer >= 0 (0: a symbolic batch size, any batch), got '-1'"),
    ("--batch", "two", "argument --batch: expected an integer >= 0"),
    ("--platforms", "bogus", "argument --platforms: expected a comma-separated list of cpu, cuda, rocm, tpu, "
                             "got 'bogus'"),
    ("--platforms", "cpu,gpu", "'gpu' is cuda for NVIDIA, rocm for AMD"),
    ("--platforms", "cpu,", "got 'cpu,'"),
    ("--frame-size", "abc", "argument --frame-size: expected HxW such as 240x320 (height x width, both >= 1), "
                            "got 'abc'"),
    ("--frame-size", "0x320", "argument --frame-size: expected HxW such as 240x320"),
])
def test_export_refuses_bad_flags_before_any_work(tmp_path, capsys, flag, value, fragment):
    """`--batch -1` was a 71-line TypeError, `--platforms bogus` an rc-0 export that failed when called,
    `--frame-size abc` "invalid literal for int()"."""
    _refused(export.main, ["--checkpoint", str(tmp_path / "missing"), "--out", str(tmp_path / "f.jaxexport"),
                           flag, value], capsys, fragment, tmp_path)


def test_platform_names_are_normalized():
    assert export.parse_platforms("CPU, cuda,cpu") == ("cpu", "cuda")
    with pytest.raises(ValueError, match="comma-separated list of cpu, cuda, rocm, tpu"):  # the library API too
        export.parse_platforms("bogus")


@pytest.mark.parametrize("flag, value, fragment", [
    ("--camera", "-1", "argument --camera: expected an integer >= 0, got '-1'"),  # a segfault in cv2 (rc 139)
    ("--resize", "0x0", "argument --resize: expected HxW such as 240x320 (both >= 1) or 'auto', got '0x0'"),
    ("--resize", "abc", "argument --resize: expected HxW"),
    ("--frame-size", "abc", "argument --frame-size: expected HxW such as 240x320"),
    ("--max-frames", "0", "argument --max-frames: expected an integer >= 1, got '0'"),  # it predicted a frame
    ("--fps", "-5", "argument --fps: expected a finite number > 0, got '-5'"),
    ("--fps", "nan", "argument --fps: expected a finite number > 0"),
    ("--warmup", "-3", "argument --warmup: expected an integer >= 0 (0: none), got '-3'"),
    ("--bg-frames", "0", "argument --bg-frames: expected an integer >= 1, got '0'"),
    ("--print-every", "-1", "argument --print-every: expected an integer >= 0 (0: never)"),
    ("--refresh-threshold", "0", "argument --refresh-threshold: expected a finite number > 0"),
    ("--refresh-frames", "0", "argument --refresh-frames: expected an integer >= 1"),
    ("--max-drops", "0", "argument --max-drops: expected an integer >= 1"),
    ("--reconnects", "-1", "argument --reconnects: expected an integer >= 0"),
    ("--reconnect-wait", "-1", "argument --reconnect-wait: expected a finite number >= 0"),
])
def test_live_refuses_bad_flags_before_any_work(tmp_path, capsys, flag, value, fragment):
    argv = ["--checkpoint", str(tmp_path / "missing"), "--headless", "--out", str(tmp_path / "out")]
    if flag != "--camera":
        argv += ["--camera", "0"]
    _refused(live.main, [*argv, flag, value], capsys, fragment, tmp_path)


@pytest.mark.parametrize("flag, value, fragment", [
    ("--camera", "-1", "argument --camera: expected an integer >= 0, got '-1'"),
    ("--per-press", "0", "argument --per-press: expected an integer >= 1"),
    ("--warmup", "-1", "argument --warmup: expected an integer >= 0"),
    ("--bg-frames", "0", "argument --bg-frames: expected an integer >= 1"),
    ("--resize", "abc", "argument --resize: expected HxW such as 240x320"),
    ("--baud", "0", "argument --baud: expected an integer >= 1"),
])
def test_calibration_recording_refuses_bad_flags_before_any_work(tmp_path, capsys, flag, value, fragment):
    argv = ["--out", str(tmp_path / "rec")] + ([] if flag == "--camera" else ["--camera", "0"])
    _refused(record.main, [*argv, flag, value], capsys, fragment, tmp_path)


def test_calibrate_flags_name_the_expected_form(tmp_path, capsys):
    _refused(calibrate_tool.main, ["--checkpoint", str(tmp_path / "ck"), "--data", str(tmp_path / "d.csv"), "--out",
                                   str(tmp_path / "out"), "--steps", "abc"], capsys,
             "argument --steps: expected an integer >= 1, got 'abc'", tmp_path)


@pytest.fixture(scope="module")
def exported(ckpt, tmp_path_factory):  # noqa: F811 - the imported fixture
    pred = inference.Predictor(ckpt)
    return pred, export.save(pred, tmp_path_factory.mktemp("export") / "f.jaxexport")


def test_an_export_without_a_digest_warns_that_it_is_unverified(exported, tmp_path):
    """A sidecar without "sha256" loaded without a word, flipped bytes and all (Fz 9.79 -> 10.09)."""
    pred, good = exported
    path = tmp_path / good.name
    path.write_bytes(good.read_bytes())
    info = json.loads(export.sidecar_path(good).read_text())
    info.pop("sha256")
    export.sidecar_path(path).write_text(json.dumps(info))
    with pytest.warns(store.UnverifiedWarning, match=rf"{path}\.json records no sha256 .*: f\.jaxexport is not "
                      rf"verified.*export it again: python -m ffjax\.export --checkpoint \S+ --out {path} "
                      "--force") as got:
        fn = export.load(path)
    assert len([w for w in got if issubclass(w.category, store.UnverifiedWarning)]) == 1
    frame = BG[None]
    np.testing.assert_allclose(fn(frame, BG), export.load(good)(frame, BG))  # it still loads and runs
    export.sidecar_path(path).unlink()
    with pytest.warns(store.UnverifiedWarning, match=r"has no f\.jaxexport\.json beside it: the file is not verified"):
        export.load(path)
    info["sha256"] = "0" * 64  # a digest that does not match: refused as before
    export.sidecar_path(path).write_text(json.dumps(info))
    with pytest.raises(CheckpointError, match="sha256 differs"):
        export.load(path)


def test_an_export_removes_the_temp_files_of_a_killed_one(exported, tmp_path):
    """A killed export left `.OUT.tmp<pid>` beside --out for good."""
    pred, _ = exported
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                          check=True).stdout.strip()
    out = tmp_path / "kc"
    stale = [tmp_path / f".kc.tmp{dead}", tmp_path / f".kc.json.tmp{dead}"]
    running = tmp_path / f".kc.tmp{os.getppid()}"  # a writer that still runs keeps its temp file
    for p in (*stale, running):
        p.write_bytes(b"half an export")
    export.save(pred, out)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["kc", "kc.json", running.name])


def test_sigterm_during_a_write_removes_its_temp_file(tmp_path):
    """SIGTERM ended the process at once: no handler removed the temp file. Under sigterm_as_interrupt it is a
    KeyboardInterrupt, which atomic_write cleans up after; the previous handler comes back afterwards."""
    before = signal.getsignal(signal.SIGTERM)

    def write(f):
        f.write(b"half")
        os.kill(os.getpid(), signal.SIGTERM)

    with pytest.raises(KeyboardInterrupt), cli.sigterm_as_interrupt():
        atomic_write_bytes(tmp_path / "f.jaxexport", b"")  # a first, complete file
        atomic_write(tmp_path / "f.jaxexport", write)
    assert [p.name for p in tmp_path.iterdir()] == ["f.jaxexport"] and (tmp_path / "f.jaxexport").read_bytes() == b""
    assert signal.getsignal(signal.SIGTERM) is before


def test_a_calibration_without_held_out_frames_says_so_and_only_so(ckpt, tmp_path):  # noqa: F811
    """A 1-row CSV printed "no held-out frames ... errors below are on the fitting set" and then "held-out 1
    frames" right below it."""
    store.save_bundle(tmp_path / "model", ckpt)
    rec = record.Recorder(tmp_path / "calib", BG)
    rec.add(BG, (0.0, 0.0, 2.0))
    logs = []
    report = calibrate_tool.calibrate(tmp_path / "model", rec.flush(), tmp_path / "out", steps=1, log=logs.append)
    text = "\n".join(logs)
    assert report["n_holdout"] == 0 and report["holdout_after"] is None and report["fit_after"]["nl1"] >= 0
    assert "held-out 1 frames" not in text and "no held-out frames, errors on the 1 fitting frames" in text
