"""The simulator's sensors at rest against a real GelSight Mini's recording (the FeelAnyForce release's
records/calibration_sphere, measured once into tests/fixtures/gelsight_mini_rest.json), by one estimator:
experiments.diagnostics.rest_recording. The bands were fixed before the optics were changed to meet them."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from experiments.diagnostics import rest_recording
from ffjax.sim.sensors import MINI_NAMES

REAL = json.loads((Path(__file__).parent / "fixtures" / "gelsight_mini_rest.json").read_text())


@pytest.mark.parametrize("key", [f"{unit}-gel{gel}" for unit in MINI_NAMES for gel in (1, 2, 3)])
def test_a_simulated_mini_at_rest_looks_like_the_real_one(key):
    sim = rest_recording.measure(*rest_recording.simulated(key, 8, 1.5))
    fine, slope = np.mean(REAL["fixed_pct"]), np.mean(REAL["gradient_pct_per_px"])
    # the fine fixed pattern (pigment + camera) and its gradient within 25% of the real unit's, per channel
    assert all(0.75 * fine <= v <= 1.25 * fine for v in sim["fixed_pct"]), sim["fixed_pct"]
    assert all(0.75 * slope <= v <= 1.25 * slope for v in sim["gradient_pct_per_px"]), sim["gradient_pct_per_px"]
    # the colour balance: each channel's level within 15% of the real background's
    assert np.allclose(sim["background_mean"], REAL["background_mean"], rtol=0.15), sim["background_mean"]
    # per-frame noise within the real channels' range
    assert all(min(REAL["noise"]) - 0.1 <= v <= max(REAL["noise"]) + 0.1 for v in sim["noise"]), sim["noise"]


def test_the_estimator_separates_pattern_noise_and_drift():
    """Synthetic frames with a known fixed pattern, white noise and a linear drift: each read back."""
    rng = np.random.default_rng(0)
    H, W, N = 96, 128, 30
    pattern = rng.standard_normal((H, W, 3)).astype(np.float32)
    base = np.float32(100.0) + 2.0 * pattern  # white: the 4 px high-pass keeps ~95% of it
    times = np.arange(N) * 6.0  # s
    drift = -0.5 * times / 60.0  # counts: -0.5 per minute on every channel
    frames = np.stack([np.clip(base + d + 1.5 * rng.standard_normal((H, W, 3)), 0, 255) for d in drift])
    frames = np.round(frames).astype(np.uint8)
    r = rest_recording.measure(frames, np.round(base).astype(np.uint8), times)
    hp = base - cv2.GaussianBlur(base, (0, 0), rest_recording.HIGHPASS_PX)
    assert np.allclose(r["fixed"], hp.std((0, 1)), rtol=0.05)
    assert np.allclose(r["noise"], np.hypot(1.5, 1 / np.sqrt(12)), rtol=0.05)  # + rounding to whole counts
    assert np.allclose(r["drift_per_min"], -0.5, atol=0.05)
    assert np.allclose(r["drift_last"], drift[-1], atol=0.1)


def test_the_drift_is_split_into_gain_offset_and_a_smooth_field():
    """Synthetic frames whose lighting drifts by a known gain on R, an offset on G and a smooth tilt across the pad
    on B, with noise: each read back per minute, and B's tilt left to the field."""
    rng = np.random.default_rng(2)
    H, W, N = 96, 128, 20
    yy, xx = np.mgrid[0:H, 0:W] / np.float32(W)
    level = np.stack([60 + 60 * xx, 100 + 40 * yy, 100 + 20 * yy], -1).astype(np.float32)  # vignette-like
    times = np.arange(N) * 12.0  # s: 3.8 minutes
    tilt = (xx - xx.mean()) * 4.0  # counts at the end: a field the gain and the offset cannot fit
    frames = []
    for t in times:
        u = t / times[-1]
        drifted = level * np.array([1 - 0.04 * u, 1, 1]) + np.stack([0 * xx, -1.0 * u + 0 * xx, tilt * u], -1)
        frames.append(np.clip(np.round(drifted + rng.standard_normal((H, W, 3))), 0, 255).astype(np.uint8))
    r = rest_recording.drift_makeup(np.stack(frames), times)
    minutes = times[-1] / 60  # the drift is linear in time: its rate is the whole drift over the whole span
    assert np.isclose(r["drift_gain_pct_per_min"][0], -4 / minutes, rtol=0.1)
    assert np.isclose(r["drift_offset_per_min"][1], -1 / minutes, rtol=0.1)
    assert abs(r["drift_gain_pct_per_min"][1]) < 0.1 and abs(r["drift_offset_per_min"][0]) < 0.3
    assert r["drift_field_rms_per_min"][2] > 5 * max(r["drift_field_rms_per_min"][:2])
    assert r["drift_level_fit_share"][0] > 0.9 and r["drift_level_fit_share"][2] < 0.5


def test_recording_errors_name_the_file(tmp_path):
    with pytest.raises(ValueError, match="no background.png"):
        rest_recording.load_recording(tmp_path)
    img = np.full((8, 10, 3), 90, np.uint8)
    cv2.imwrite(str(tmp_path / "background.png"), img)
    (tmp_path / "tactile").mkdir()
    for i, t in enumerate((1000, 1500, 2100)):
        cv2.imwrite(str(tmp_path / "tactile" / f"{t}.png"), img if i else img[:4])
    with pytest.raises(ValueError, match="1000.png: frame is 10x4"):
        rest_recording.load_recording(tmp_path)
    cv2.imwrite(str(tmp_path / "tactile" / "1000.png"), img)
    frames, bg, times = rest_recording.load_recording(tmp_path)
    assert frames.shape == (3, 8, 10, 3) and np.allclose(times, [0.0, 0.5, 1.1])


def test_the_diagnostic_runs_on_a_recording(tmp_path):
    rng = np.random.default_rng(1)
    rec = tmp_path / "rec"
    (rec / "tactile").mkdir(parents=True)
    bg = rng.integers(90, 110, (24, 32, 3), dtype=np.uint8)
    cv2.imwrite(str(rec / "background.png"), bg)
    for i in range(4):
        cv2.imwrite(str(rec / "tactile" / f"{1000 + 500 * i}.png"), bg)
    res = rest_recording.main(["--recording", str(rec), "--sensors", "mini-1-gel1", "--sim-frames", "3",
                               "--out", str(tmp_path / "out")])
    assert set(res["sources"]) == {"GelSight Mini (real)", "mini-1-gel1"}
    assert res["sources"]["GelSight Mini (real)"]["noise"] == [0.0, 0.0, 0.0]
    assert (tmp_path / "out" / "rest_recording.png").stat().st_size > 0
    assert "mini-1-gel1" in (tmp_path / "out" / "rest_recording.md").read_text()
