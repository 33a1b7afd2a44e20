"""The Predictor: training's preprocessing, shapes, one compile per batch shape, clear refusals, the
out-of-range flag, depth in mm, and the three kinds of folder it loads (run, bundle, converted release)."""

import json
import warnings
from pathlib import Path

import _smoke_run
import numpy as np
import pytest

from ffjax import data, inference, store

FIXTURES = Path(__file__).parent / "fixtures"


@pytest.fixture(scope="module")
def run_dir():
    return _smoke_run.smoke_run()


@pytest.fixture(scope="module")
def pred(run_dir):
    return inference.load(run_dir)


@pytest.fixture(scope="module")
def batch():
    return _smoke_run.presses(4, seed=5)


def test_predict_matches_training_path_and_compiles_once_per_shape(run_dir, pred, batch):
    loaded = store.load(run_dir)
    cfg, stats, variables = loaded.cfg, loaded.stats, loaded.variables
    pred.set_background(batch["background"])
    forces = pred.predict(batch["image"])
    assert forces.shape == (4, 3) and forces.dtype == np.float32
    x = data.preprocess_image(batch["image"], batch["background"], stats, cfg["data"]["input_size"])
    np.testing.assert_array_equal(pred.preprocess(batch["image"]), x)  # training's preprocessing
    # the training checkpoint's own weights through model.apply (the jitted one: eager apply is slow)
    np.testing.assert_allclose(forces, pred._force_fn(variables, x), rtol=1e-6, atol=1e-6)
    one = pred.predict(batch["image"][2])  # (H, W, 3) -> (1, 3)
    np.testing.assert_allclose(one, forces[2:3], rtol=1e-5, atol=1e-5)
    size = pred._force_fn._cache_size()
    for i in range(3):
        pred.predict(batch["image"][i])
    assert pred._force_fn._cache_size() == size  # batch 1 compiled once
    bgr = pred.predict(batch["image"][..., ::-1], bgr=True)
    np.testing.assert_allclose(bgr, forces, rtol=1e-5, atol=1e-5)
    assert set(pred.last_timing) == {"preprocess_s", "model_s"}


def test_properties(pred):
    d = pred.describe()
    assert pred.input_size == 32 and pred.frame_size == _smoke_run.frame_size()
    assert pred.frame_size_source == "model.json" and d["channels"] == "RGB" and d["depth_head"]
    assert np.all(pred.force_min < pred.force_max)


def test_refuses_wrong_size_channels_dtype_and_missing_background(run_dir, batch):
    p = inference.load(run_dir)
    with pytest.raises(RuntimeError, match="set_background"):
        p.predict(batch["image"])
    p.set_background(batch["background"])
    h, w = _smoke_run.frame_size()
    with pytest.raises(ValueError, match=rf"is 48x64 \(HxW\) but this checkpoint was trained on {h}x{w}"):
        p.predict(np.zeros((48, 64, 3), np.uint8))
    with pytest.raises(ValueError, match="4 channels.*alpha"):
        p.predict(np.zeros((h, w, 4), np.uint8))
    with pytest.raises(ValueError, match="1 channels"):
        p.predict(np.zeros((h, w, 1), np.uint8))
    with pytest.raises(TypeError, match="uint8"):
        p.predict(batch["image"].astype(np.float32))
    loose = inference.load(run_dir, strict_size=False)
    big = np.zeros((48, 64, 3), np.uint8)
    with pytest.warns(UserWarning, match="48x64"), pytest.warns(inference.BackgroundWarning, match="dark"):
        loose.set_background(big)  # a zero frame is also a dark background: both are said
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert loose.predict(big).shape == (1, 3)
    assert inference.load(run_dir, frame_size=(48, 64)).frame_size == (48, 64)


def test_out_of_range_flag(pred, batch):
    pred.set_background(batch["background"])
    lo, hi = pred.force_min, pred.force_max
    flags = pred.out_of_range(np.stack([np.zeros(3), (lo + hi) / 2, hi + 10, lo - 10]))
    assert flags.tolist() == [False, False, True, True]  # zero (no contact) is always in range
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        f = pred.predict(batch["image"])
    assert pred.last_out_of_range.tolist() == pred.out_of_range(f).tolist()
    assert any(issubclass(w.category, inference.ForceRangeWarning) for w in caught) == bool(
        pred.last_out_of_range.any())


def test_predict_depth_in_mm(pred, batch):
    pred.set_background(batch["background"])
    d = pred.predict_depth(batch["image"][:2])
    h, w = _smoke_run.frame_size()
    assert d.shape == (2, h, w) and d.dtype == np.float32
    sq = pred.predict_depth(batch["image"][:2], frame=False)
    assert sq.shape == (2, pred.input_size, pred.input_size) and np.isfinite(sq).all()
    unit = pred._depth_fn(pred.variables, pred.preprocess(batch["image"][:2]))  # the decoder's [0, 1] scale
    np.testing.assert_allclose(sq, data.depth_to_mm(np.asarray(unit), pred.stats), rtol=1e-6)
    assert pred.input_size == w  # smoke: 24x32 pads to 32x32 = the input, no resize: the crop is exact
    np.testing.assert_allclose(d, sq[:, (w - h) // 2: (w - h) // 2 + h], rtol=1e-6)


def test_bundle_round_trip_and_no_depth_head(run_dir, batch, tmp_path):
    ckpt = store.load(run_dir)
    store.save_bundle(tmp_path / "b", ckpt)
    a, b = inference.load(run_dir), inference.load(tmp_path / "b")
    assert b.trained.kind == "bundle" and b.frame_size == a.frame_size and b.frame_size_source == "model.json"
    for p in (a, b):
        p.set_background(batch["background"])
    np.testing.assert_array_equal(a.predict(batch["image"]), b.predict(batch["image"]))
    # a method without a depth head: same backbone and regressor, decoder dropped
    import dataclasses

    from ffjax import registry

    params = {k: v for k, v in ckpt.variables["params"].items() if k != "decoder"}
    ckpt = dataclasses.replace(ckpt, spec=registry.get("dino_r"))
    # the regressor's feature normalization keeps its statistics in batch_stats: they travel with the params
    store.save_bundle(tmp_path / "r", ckpt, {"params": params, "batch_stats": ckpt.variables["batch_stats"]})
    r = inference.load(tmp_path / "r")
    r.set_background(batch["background"])
    np.testing.assert_allclose(r.predict(batch["image"]), a.predict(batch["image"]), rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match="no depth head"):
        r.predict_depth(batch["image"])


def test_converted_release_folder(tmp_path):
    from ffjax.convert import __main__ as convert_cli

    out = tmp_path / "release"
    assert convert_cli.main(["feelanyforce", str(FIXTURES / "feelanyforce_tiny.pth.tar"), "--out", str(out),
                             "--heads", "2"]) == 0
    p = inference.load(out)
    assert p.trained.kind == "converted" and p.frame_size == (240, 320) and p.method == "dino_rd"
    np.testing.assert_allclose(p.stats.mean, store.RELEASE_STATS["mean"])
    rng = np.random.default_rng(0)
    bg = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    img = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    p.set_background(bg)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f = p.predict(img)
    assert f.shape == (1, 3) and np.isfinite(f).all()
    (out / "sensor.json").write_text('{"frame_size": [120, 160]}')
    assert inference.load(out).frame_size == (120, 160)


def test_not_a_checkpoint(tmp_path):
    with pytest.raises(FileNotFoundError, match="not a checkpoint folder"):
        inference.load(tmp_path)


def test_training_run_records_its_background_and_warns_on_another_sensors(run_dir, batch):
    from ffjax import sim

    info = json.loads((run_dir / "model.json").read_text())
    assert info["background_stats"] == inference.background_stats(batch["background"])
    model = inference.load(run_dir)
    with warnings.catch_warnings():
        warnings.simplefilter("error", inference.BackgroundWarning)
        model.set_background(batch["background"])  # the training sensor's own background: no warning
    digit = sim.sensors.get_sensor("digit").background(_smoke_run.frame_size())
    with pytest.warns(inference.BackgroundWarning):
        model.set_background(digit)
