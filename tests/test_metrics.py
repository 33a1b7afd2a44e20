"""The force metric on hand-made numbers, and batched evaluation (padding must not change results)."""

import flax.linen as nn
import jax
import numpy as np
import pytest
from _tiny_data import write_tiny_split

import configs
from ffjax import data, metrics

PRED = np.array([[1.0, 0.0, 10.0], [0.0, 1.0, 12.0]])
TRUE = np.array([[0.0, 0.0, 11.0], [0.0, -1.0, 12.0]])
FMIN, FMAX = (-2.0, -2.0, 0.0), (2.0, 2.0, 15.0)


def test_normalized_l1_by_hand():
    axes, mean = metrics.normalized_l1(PRED, TRUE, FMIN, FMAX)
    # |err| means per axis: 0.5, 1.0, 0.5 N; ranges 4, 4, 15 N.
    np.testing.assert_allclose(axes, [12.5, 25.0, 100 * 0.5 / 15])
    assert mean == pytest.approx((12.5 + 25.0 + 100 * 0.5 / 15) / 3)
    np.testing.assert_allclose(metrics.mae_newtons(PRED, TRUE), [0.5, 1.0, 0.5])
    s = metrics.summarize(PRED, TRUE, FMIN, FMAX)
    assert s["n"] == 2 and s["nl1"] == pytest.approx(mean) and s["mae_n"] == [0.5, 1.0, 0.5]
    assert metrics.normalized_l1(TRUE, TRUE, FMIN, FMAX)[1] == 0.0
    with pytest.raises(ValueError, match="positive"):
        metrics.normalized_l1(PRED, TRUE, FMIN, FMIN)


class Probe(nn.Module):
    """Stand-in model with the real output contract: {"force": (B, 3)}."""

    @nn.compact
    def __call__(self, x, train=False):
        return {"force": nn.Dense(3)(x.reshape(len(x), -1))}


@pytest.fixture(scope="module")
def probe():
    model = Probe()
    return model, model.init(jax.random.PRNGKey(0), np.zeros((1, 32, 32, 3), np.float32))


def test_predict_pads_the_last_batch(probe):
    model, variables = probe
    x = np.random.default_rng(0).normal(size=(5, 32, 32, 3)).astype(np.float32)
    full = np.asarray(model.apply(variables, x)["force"])
    np.testing.assert_allclose(metrics.predict(model, variables, x, batch_size=2), full, rtol=1e-5, atol=1e-5)
    r = metrics.evaluate(model, variables, x, full, FMIN, FMAX, batch_size=4)
    assert r["n"] == 5 and r["nl1"] == pytest.approx(0.0, abs=1e-4)


def test_evaluate_split_uses_train_force_range(probe, tmp_path):
    model, variables = probe
    write_tiny_split(tmp_path / "val", 7, 3)
    src = data.open_split(tmp_path / "val")
    stats = data.Stats.compute(src, configs.get("smoke")["data"])
    r = metrics.evaluate_split(model, variables, tmp_path / "val", stats, 32, batch_size=4)
    arrays = data.load_arrays(src, stats, 32)
    pred = np.asarray(model.apply(variables, arrays["image"])["force"])
    expect = metrics.summarize(pred, arrays["force"], stats.force_min, stats.force_max)
    assert r["n"] == 7
    np.testing.assert_allclose(r["nl1_axes"], expect["nl1_axes"], rtol=1e-4)
    np.testing.assert_allclose(r["mae_n"], expect["mae_n"], rtol=1e-4)
