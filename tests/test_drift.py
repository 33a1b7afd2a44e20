"""ffjax.data.drift: the real Mini's LED drift as a training augmentation (train.drift_minutes)."""

import json

import jax
import numpy as np
import pytest
from _tiny_data import write_tiny_dataset
from test_data import S, fabricate

import configs
from ffjax import data, train
from ffjax.data import drift


@pytest.fixture(scope="module")
def split(tmp_path_factory):
    return data.open_split(fabricate(tmp_path_factory.mktemp("drift") / "train", n=64))  # 12x16 frames, padded to 16


@pytest.fixture(scope="module")
def stats(split):
    return data.Stats.compute(split, {"input_size": S, "depth_eps": 0.05})


def _batch(split, stats):
    return next(iter(data.make_dataset(split, stats, S, batch_size=64, seed=0)))


def _added_counts(aug: drift.DriftAugment, batch, stats, seed=0):
    """(what the augmentation added, in camera counts, (B, S, S, 3); the pad mask (B, S, S, 1))."""
    out = aug.random_map(batch, np.random.default_rng(seed))["image"]
    on_pad = np.all(batch["image"] == aug.pad, axis=-1, keepdims=True)
    return (out - batch["image"]) * 255 * np.asarray(stats.std, np.float32), on_pad


def test_the_rates_are_the_rest_recordings(tmp_path):
    src = json.loads(drift.MEASURED.read_text())["sources"][drift.SOURCE]
    rates = drift.DriftRates.measured()
    assert rates.shift == tuple(src["drift_per_min"]) and rates.field == tuple(src["drift_field_rms_per_min"])
    with pytest.raises(data.DataError, match="nope.json: no such file"):
        drift.DriftRates.measured(tmp_path / "nope.json")
    (tmp_path / "bad.json").write_text(json.dumps({"sources": {}}))
    with pytest.raises(data.DataError, match=r"bad.json: no drift rates"):
        drift.DriftRates.measured(tmp_path / "bad.json")


def test_off_by_default_and_refused_below_zero():
    assert configs.get("smoke")["train"]["drift_minutes"] == 0
    assert drift.augment(configs.get("smoke")["train"], None) is None
    with pytest.raises(ValueError, match="minutes must be > 0"):
        drift.DriftAugment(drift.DriftRates.measured(), 0.0, [0, 0, 0], [1, 1, 1])


def test_a_frame_shifts_by_one_time_and_sign_in_the_recordings_colour_balance(split, stats):
    batch, minutes = _batch(split, stats), 3.0
    rates = drift.DriftRates.measured()
    added, on_pad = _added_counts(drift.DriftAugment(drift.DriftRates(rates.shift, (0, 0, 0)), minutes,
                                                     stats.mean, stats.std), batch, stats)
    assert on_pad.any() and not on_pad.all()  # the 12x16 frames' padded rows, and the frame
    assert np.all(added[np.broadcast_to(on_pad, added.shape)] == 0)  # padding is never drifted
    per_frame = np.array([a[~p[..., 0]].mean(0) for a, p in zip(added, on_pad)])  # (B, 3) counts
    scale = per_frame / np.asarray(rates.shift)  # t x sign, the same for the three channels of a frame
    np.testing.assert_allclose(scale, scale[:, :1].repeat(3, 1), rtol=1e-3, atol=1e-3)
    assert np.abs(scale[:, 0]).max() <= minutes * (1 + 1e-4) and (scale[:, 0] > 0).any() and (scale[:, 0] < 0).any()
    assert np.abs(scale[:, 0]).max() > minutes / 2  # 64 uniform draws of t in [0, minutes]


def test_the_field_is_smooth_and_at_most_the_recordings_rate(split, stats):
    batch, minutes = _batch(split, stats), 2.0
    rates = drift.DriftRates.measured()
    added, on_pad = _added_counts(drift.DriftAugment(drift.DriftRates((0, 0, 0), rates.field), minutes,
                                                     stats.mean, stats.std), batch, stats, seed=1)
    full = drift.smooth_field(np.random.default_rng(0), 8, 64)
    np.testing.assert_allclose(np.sqrt(np.mean(full**2, axis=(1, 2))), 1.0, rtol=1e-4)
    steps = np.abs(np.diff(full, axis=2)).mean() / np.abs(full).mean()
    assert steps < 0.2  # neighbouring pixels of a 64-px field differ little: no contact-like detail
    rms = np.sqrt(np.mean(added**2, axis=(1, 2)))  # per frame and channel, counts
    assert np.all(rms <= minutes * np.asarray(rates.field) * (1 + 1e-4)) and rms.max() > 0


def test_drifted_batches_resume_like_the_rest(split, stats):
    aug = drift.DriftAugment(drift.DriftRates.measured(), 3.0, stats.mean, stats.std)
    it = iter(data.make_dataset(split, stats, S, batch_size=8, seed=0, augment=aug))
    plain = iter(data.make_dataset(split, stats, S, batch_size=8, seed=0))
    for _ in range(9):  # past an epoch boundary
        a, b = next(it), next(plain)
        np.testing.assert_array_equal(a["force"], b["force"])  # the same rows, drifted
        assert not np.array_equal(a["image"], b["image"])
    state = it.get_state()
    want = [next(it)["image"] for _ in range(3)]
    again = iter(data.make_dataset(split, stats, S, batch_size=8, seed=0, augment=aug))
    again.set_state(state)
    for w in want:
        np.testing.assert_array_equal(next(again)["image"], w)


def test_a_run_trains_on_drifted_frames(tmp_path, monkeypatch):
    """train.drift_minutes reaches the training batches (and only them: validation frames stay as recorded)."""
    seen = []
    real = drift.DriftAugment.random_map
    monkeypatch.setattr(drift.DriftAugment, "random_map", lambda self, b, rng: seen.append(1) or real(self, b, rng))
    root = write_tiny_dataset(tmp_path / "data", 32, 12)
    cfg = configs.get("smoke", {"train.epochs": 3, "train.ckpt_every": 5, "train.drift_minutes": 3.0})
    run = train.train(cfg, "dino_rd", root, tmp_path / "run", progress=False)
    assert run["complete"] and np.isfinite(run["val"]["loss"]) and len(seen) >= run["steps"]
    assert json.loads((tmp_path / "run" / "model.json").read_text())["cfg"]["train"]["drift_minutes"] == 3.0
    assert jax.device_get(run["state"].step) == run["steps"]
