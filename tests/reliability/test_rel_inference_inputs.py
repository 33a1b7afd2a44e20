"""Bad input at inference: refusals name the argument (expected vs got), bad frames are flagged not raised,
and a background from another sensor is warned about. A randomly initialised smoke-size model: no training."""

import json
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import configs
from ffjax import data, inference, models, registry, sim, store

H, W, SIZE = 24, 32, 32


def sensor_bg(name: str) -> np.ndarray:
    return sim.sensors.get_sensor(name).background((H, W))


def tiny_checkpoint(reference_bg=None) -> store.Trained:
    """A smoke dino_r model with random weights; `reference_bg`'s statistics recorded as the training one's."""
    cfg = configs.get("smoke")
    spec = registry.get("dino_r")
    model = models.build(cfg["model"], spec, SIZE)
    variables = model.init(jax.random.PRNGKey(0), jnp.zeros((1, SIZE, SIZE, 3)), train=False)
    stats = data.Stats(mean=(0.5,) * 3, std=(0.1,) * 3, depth_min=0.0, depth_max=1.0, force_min=(-2.0, -2.0, 0.0),
                       force_max=(2.0, 2.0, 15.0), input_size=SIZE)
    ref = None if reference_bg is None else inference.background_stats(reference_bg)
    return store.Trained(cfg, spec, stats, SIZE, (H, W), "argument", "run", "memory", variables,
                        background_stats=ref)


@pytest.fixture(scope="module")
def pred():
    return inference.Predictor(tiny_checkpoint(sensor_bg("mini-1")))


def pressed(bg: np.ndarray) -> np.ndarray:
    """The background with a brighter disc: a contact patch."""
    yy, xx = np.mgrid[:H, :W]
    f = bg.astype(np.int16)
    f[(yy - H // 2) ** 2 + (xx - W // 2) ** 2 < 25] += 40
    return np.clip(f, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("bad, err, match", [
    (None, TypeError, "image is None.*cap.read"),
    (np.zeros((H, W, 3), np.float32), TypeError, r"image must be uint8.*got float32.*\* 255"),
    (np.zeros((H, W, 3), np.uint16), TypeError, "got uint16.*8 bits"),
    (np.zeros((H, W), np.uint8), ValueError, r"\(H, W, 3\) or \(N, H, W, 3\), got shape \(24, 32\).*grayscale"),
    (np.zeros((1, 1, H, W, 3), np.uint8), ValueError, "got shape"),
    (np.zeros((H, W, 4), np.uint8), ValueError, "4 channels.*needs 3.*alpha"),
    (np.zeros((3, H, W), np.uint8), ValueError, "channels first"),
    (np.zeros((48, 64, 3), np.uint8), ValueError, r"image is 48x64 \(HxW\) but this checkpoint was trained on 24x32"),
])
def test_refuses_what_can_never_work(pred, bad, err, match):
    pred.set_background(sensor_bg("mini-1"))
    with pytest.raises(err, match=match):
        pred.predict(bad)


def test_background_refusals_name_the_argument(pred):
    with pytest.raises(TypeError, match="background is None"):
        pred.set_background(None)
    with pytest.raises(ValueError, match="background is 48x64.*24x32"):
        pred.set_background(np.zeros((48, 64, 3), np.uint8))
    with pytest.raises(ValueError, match="background must be one frame"):
        pred.set_background(np.zeros((2, H, W, 3), np.uint8))
    pred.set_background(sensor_bg("mini-1")[None])  # a batch of one is one frame
    assert pred.background.shape == (H, W, 3)


def test_bad_frames_are_flagged_not_raised(pred):
    bg = sensor_bg("mini-1")
    pred.set_background(bg)
    frames = np.stack([pressed(bg), np.zeros_like(bg), np.full_like(bg, 255), pressed(sensor_bg("digit"))])
    with pytest.warns(inference.FrameWarning, match="background_mismatch/dark/saturated"):
        forces = pred.predict(frames)
    assert forces.shape == (4, 3) and np.isfinite(forces).all()
    assert list(pred.last_frame_issues) == ["", "dark", "saturated", "background_mismatch"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a good frame gives no warning of any kind
        pred.predict(pressed(bg))
    assert list(pred.last_frame_issues) == [""]


def test_background_from_another_sensor_warns(pred):
    # another gel on the unit, or another unit of the same product (its colour balance measured on a real Mini,
    # units scattering around it): within tolerance
    for same in ("mini-1", "mini-1-gel2", "mini-2", "mini-3-gel3"):
        with warnings.catch_warnings():
            warnings.simplefilter("error", inference.BackgroundWarning)
            pred.set_background(sensor_bg(same))
        assert pred.background_issues == []
    brighter = np.clip(sensor_bg("mini-2").astype(np.float32) * 1.4, 0, 255).astype(np.uint8)  # another exposure
    for other in (sensor_bg("digit"), brighter):
        with pytest.warns(inference.BackgroundWarning, match=r"differ from the checkpoint's training background"):
            pred.set_background(other)
        assert len(pred.background_issues) == 1
    with pytest.warns(inference.BackgroundWarning, match="background is dark"):
        pred.set_background(np.zeros((H, W, 3), np.uint8))
    with pytest.warns(inference.BackgroundWarning, match="background is saturated"):
        pred.set_background(np.full((H, W, 3), 255, np.uint8))


def test_no_reference_no_statistics_warning():
    p = inference.Predictor(tiny_checkpoint(None))
    with warnings.catch_warnings():
        warnings.simplefilter("error", inference.BackgroundWarning)
        p.set_background(sensor_bg("digit"))
    assert p.describe()["background_stats"] is None


def test_bgr_background_gets_a_channel_order_hint():
    rng = np.random.default_rng(0)
    rgb = np.clip(rng.normal([60, 120, 200], 5, (H, W, 3)), 0, 255).astype(np.uint8)
    ref = inference.background_stats(rgb)
    assert inference.background_check(rgb, ref) == []
    (msg,) = inference.background_check(rgb[..., ::-1], ref)
    assert "BGR" in msg and "bgr=True" in msg


def test_bgr_flag_is_exactly_a_channel_swap(pred):
    bg = sensor_bg("mini-1")
    frames = np.stack([pressed(bg), bg])
    pred.set_background(bg)
    rgb = pred.predict(frames)
    pred.set_background(np.ascontiguousarray(bg[..., ::-1]), bgr=True)
    np.testing.assert_array_equal(pred.predict(np.ascontiguousarray(frames[..., ::-1]), bgr=True), rgb)


def test_bundle_and_sensor_json_record_the_reference(tmp_path):
    ckpt = tiny_checkpoint(None)
    store.save_bundle(tmp_path / "b", ckpt, background=sensor_bg("mini-1"))
    info = json.loads((tmp_path / "b" / "model.json").read_text())
    assert info["background_stats"]["mean"] == pytest.approx(sensor_bg("mini-1").reshape(-1, 3).mean(0), abs=0.01)
    p = inference.load(tmp_path / "b")
    with pytest.warns(inference.BackgroundWarning):
        p.set_background(sensor_bg("digit"))
    store.save_bundle(tmp_path / "c", ckpt)  # no background: none recorded ...
    (tmp_path / "c" / "sensor.json").write_text(json.dumps(
        {"background_stats": inference.background_stats(sensor_bg("mini-2"))}))  # ... but sensor.json has one
    assert inference.load(tmp_path / "c").trained.background_stats["mean"] == pytest.approx(
        sensor_bg("mini-2").reshape(-1, 3).mean(0), abs=0.01)


def test_background_png_beside_a_bundle_is_the_reference(tmp_path):
    from ffjax.data.images import write_rgb

    store.save_bundle(tmp_path / "cal", tiny_checkpoint(None))  # what ffjax.calibrate writes, roughly
    write_rgb(tmp_path / "cal" / "background.png", sensor_bg("digit"))
    p = inference.load(tmp_path / "cal")
    with pytest.warns(inference.BackgroundWarning, match="another sensor"):
        p.set_background(sensor_bg("mini-1"))


def test_set_background_keeps_its_own_copy():
    """Issue 33 (1): a camera buffer reused after set_background must not change later predictions."""
    p = inference.Predictor(tiny_checkpoint(sensor_bg("mini-1")))
    buf = sensor_bg("mini-1").copy()
    frame = pressed(buf)
    p.set_background(buf)
    before = p.predict(frame)
    buf[:] = 0  # the caller's next camera read lands in the same buffer
    np.testing.assert_array_equal(p.predict(frame), before)
    with pytest.raises(ValueError, match="read-only"):
        p.background[0, 0, 0] = 1


def test_no_frames_give_no_depth_maps():
    """Issue 33 (7): predict_depth on 0 frames returns (0, H, W), as predict returns (0, 3)."""
    spec = registry.get("dino_rd")
    t = tiny_checkpoint(sensor_bg("mini-1"))
    model = models.build(t.cfg["model"], spec, SIZE)
    variables = model.init(jax.random.PRNGKey(0), jnp.zeros((1, SIZE, SIZE, 3)), train=False)
    p = inference.Predictor(store.Trained(t.cfg, spec, t.stats, SIZE, (H, W), "argument", "run", "memory", variables))
    p.set_background(sensor_bg("mini-1"))
    none = np.zeros((0, H, W, 3), np.uint8)
    assert p.predict(none).shape == (0, 3)
    assert p.predict_depth(none).shape == (0, H, W) and p.predict_depth(none, frame=False).shape == (0, SIZE, SIZE)


def test_a_frame_size_given_as_a_list_is_the_same_size():
    """Issue 33 (7): "image is 24x32 (HxW) but this checkpoint was trained on 24x32" (a list against a tuple)."""
    t = tiny_checkpoint(sensor_bg("mini-1"))
    p = inference.Predictor(store.Trained(t.cfg, t.spec, t.stats, SIZE, [H, W], "argument", "run", "memory",
                                          t.variables))
    p.set_background(sensor_bg("mini-1"))
    assert p.predict(pressed(sensor_bg("mini-1"))).shape == (1, 3)
