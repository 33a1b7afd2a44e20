"""The live loop headless on a short simulated video and on a folder of frames; the smoothing filters."""

import csv

import _smoke_run
import cv2
import numpy as np
import pytest

from ffjax import inference, live
from ffjax.data.images import write_rgb
from ffjax.live import filters


@pytest.fixture(scope="module")
def run_dir():
    return _smoke_run.smoke_run()


@pytest.fixture(scope="module")
def clip():
    """A no-contact frame, then presses of rising Fz: what a camera sees when something is pushed in."""
    b = _smoke_run.presses(7, seed=3)
    frames = np.concatenate([b["background"][None], b["image"]])
    return frames, b["background"]


def _read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def _video(frames, path):
    h, w = frames.shape[1:3]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (w, h))
    for f in frames:
        vw.write(np.ascontiguousarray(f[..., ::-1]))  # VideoWriter wants BGR
    vw.release()
    return path


def test_video_headless_writes_forces_and_annotated_video(run_dir, clip, tmp_path):
    frames, _ = clip
    video = _video(frames, tmp_path / "press.mp4")
    out = tmp_path / "out"
    assert live.main(["--checkpoint", str(run_dir), "--video", str(video), "--out", str(out), "--headless",
                      "--print-every", "0"]) == 0
    rows = _read_csv(out / "forces.csv")
    assert len(rows) == len(frames)  # the background frame itself is predicted too
    assert list(rows[0]) == ["t", "fx", "fy", "fz", "out_of_range", "frame"]
    assert [float(r["t"]) for r in rows] == pytest.approx(np.arange(len(frames)) / 10.0, abs=1e-3)
    assert all(np.isfinite(float(r[k])) for r in rows for k in ("fx", "fy", "fz"))
    assert {r["out_of_range"] for r in rows} <= {"0", "1"}
    cap = cv2.VideoCapture(str(out / "annotated.mp4"))
    n = 0
    while cap.read()[0]:
        n += 1
    assert n == len(frames)


def test_a_failed_start_keeps_the_previous_recording_and_a_new_one_moves_it_aside(run_dir, clip, tmp_path):
    frames, _ = clip
    video, out = _video(frames, tmp_path / "press.mp4"), tmp_path / "out"
    args = ["--checkpoint", str(run_dir), "--out", str(out), "--headless", "--print-every", "0"]
    assert live.main([*args, "--video", str(video)]) == 0
    first = (out / "forces.csv").read_bytes()
    with pytest.raises(FileNotFoundError, match="no such file"):  # a typo: nothing predicted, nothing overwritten
        live.main([*args, "--video", str(tmp_path / "typo.mp4")])
    (tmp_path / "notes.mp4").write_text("not a video")
    with pytest.raises(RuntimeError, match="cannot open video"):
        live.main([*args, "--video", str(tmp_path / "notes.mp4")])
    with pytest.raises(RuntimeError, match="cannot open camera 99"):
        live.main([*args, "--camera", "99"])
    with pytest.raises(FileNotFoundError, match=r"--images .*typo: no such folder"):
        live.main([*args, "--images", str(tmp_path / "typo")])
    assert (out / "forces.csv").read_bytes() == first
    assert sorted(p.name for p in out.iterdir()) == ["annotated.mp4", "forces.csv"]  # nothing moved aside
    assert live.main([*args, "--video", str(video), "--max-frames", "2"]) == 0
    assert (out / "forces.1.csv").read_bytes() == first and (out / "annotated.1.mp4").exists()
    assert len(_read_csv(out / "forces.csv")) == 2


def test_images_folder_matches_predictor_and_smooths(run_dir, clip, tmp_path):
    frames, bg = clip
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, f in enumerate(frames[1:]):
        write_rgb(folder / f"{i:03d}.png", f)
    write_rgb(tmp_path / "bg.png", bg)
    out = tmp_path / "out"
    assert live.main(["--checkpoint", str(run_dir), "--images", str(folder), "--background", str(tmp_path / "bg.png"),
                      "--out", str(out), "--headless", "--smooth", "ema:0.5", "--print-every", "0"]) == 0
    rows = _read_csv(out / "forces.csv")
    assert [r["frame"] for r in rows] == [f"{i:03d}.png" for i in range(len(frames) - 1)]
    pred = inference.load(run_dir)
    pred.set_background(bg)
    want = pred.predict(frames[1:])
    raw = np.array([[float(r[k]) for k in ("fx_raw", "fy_raw", "fz_raw")] for r in rows])
    np.testing.assert_allclose(raw, want, atol=1e-4)  # PNG is lossless: the same numbers as predict
    smooth = np.array([[float(r[k]) for k in ("fx", "fy", "fz")] for r in rows])
    ema = filters.EMA(0.5)
    np.testing.assert_allclose(smooth, [ema(0, x) for x in want], atol=1e-4)


def test_nan_forces_are_flagged_counted_and_never_crash_the_loop(run_dir, clip, tmp_path):
    """Corrupt weights (one NaN in the last layer): predict flags every frame, the live loop logs, counts and
    annotates them, and the smoothing filter is not poisoned by them."""
    import jax

    frames, bg = clip
    pred = inference.load(run_dir)
    pred.variables = jax.tree.map(np.array, pred.variables)  # writable copies
    kernel = [k for k in jax.tree.leaves(pred.variables["params"]["regressor"]) if k.ndim == 2][-1]
    kernel[:] = np.nan  # the regressor's output layer: every force is NaN
    pred.set_background(bg)
    with pytest.warns(inference.NonFiniteWarning):
        f = pred.predict(frames[1:3])
    assert np.isnan(f).all() and pred.last_nonfinite.all() and pred.last_out_of_range.all()
    logs = []
    summary = live.run(pred, ((i / 10, x, i) for i, x in enumerate(frames[1:])), out=tmp_path,
                       background=bg, smoother=filters.EMA(0.5), log=logs.append)
    assert summary["frames"] == len(frames) - 1
    assert summary["flagged"] == {"non-finite force (corrupt weights or input)": len(frames) - 1}
    assert any("non-finite" in m for m in logs) and any("[NON-FINITE]" in m for m in logs)
    assert len(_read_csv(tmp_path / "forces.csv")) == len(frames) - 1


def test_run_retakes_background_and_caps_rate(run_dir, clip):
    frames, bg = clip
    pred = inference.load(run_dir)
    stream = ((i / 30, f, i) for i, f in enumerate([frames[1]] * 2 + [bg] * 3 + list(frames[1:])))
    logs = []
    s = live.run(pred, stream, warmup=2, bg_frames=3, fps_cap=200, print_every=1, log=logs.append)
    assert s["frames"] == 3 + len(frames) - 1 and s["background_taken"]
    np.testing.assert_array_equal(pred.background, bg)  # warm-up frames (pressed) were skipped
    assert logs[0].startswith("background taken from 3")
    assert any("Hz" in line for line in logs[2:])


def test_annotate_draws_on_an_enlarged_frame(clip):
    frames, _ = clip
    img = live.annotate(frames[1], [1.0, -0.5, 5.0], np.array([-2, -2, 0.0]), np.array([2, 2, 15.0]), True, 24.0)
    assert img.dtype == np.uint8 and img.shape[0] >= frames.shape[1] * 10 and img.shape[1] > 480


def test_filters():
    ema = filters.parse("ema:0.25")
    ys = [ema(i, [4.0, 0, 0])[0] for i in range(3)]
    assert ys == pytest.approx([4.0, 4.0, 4.0])  # starts at the first sample: no ramp from zero
    ema.reset()
    ema(0, [0, 0, 0])
    assert ema(1, [4, 0, 0])[0] == pytest.approx(1.0)
    one = filters.parse("one-euro:min_cutoff=1.0,beta=0.5")
    rng = np.random.default_rng(0)
    t = np.arange(200) / 100
    noisy = 3 + 0.2 * rng.standard_normal(200)
    out = np.array([one(ti, [x, 0, 0])[0] for ti, x in zip(t, noisy)])
    assert np.std(out[50:]) < 0.5 * np.std(noisy[50:])  # jitter at rest is smoothed
    assert filters.parse("one-euro:1,0.1,2").d_cutoff == 2.0
    assert filters.parse(None) is None and filters.parse("off") is None
    for bad in ("ema:2", "kalman:1", "one-euro:gain=1"):
        with pytest.raises(ValueError):
            filters.parse(bad)
