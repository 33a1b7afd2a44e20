"""Force error metrics: normalized L1 (percent of the training full-scale range) and MAE in newtons.

The paper reports an "L1 normalized error" in percent without defining the normalization (nor does
its code). Ours, an assumption stated wherever numbers are reported: for each axis a,

    nl1_a = mean_i |F_hat_ia - F_ia| / (max F_a - min F_a over the TRAINING labels) * 100

and the headline figure is the mean of nl1_a over the three axes. The range comes from the training
split (`Stats.force_min/force_max`), never from the split being evaluated, so every test set of one
model is divided by the same numbers. Shear axes have a much smaller range (~4 N) than Fz (~15 N),
so equal newton errors weigh more on Fx/Fy; the per-axis MAE in newtons is always reported too. An axis
the training labels never vary on (a sensor that records Fz only) has no full scale: its nl1_a is NaN
(not applicable) and the headline is the mean over the axes that vary.
"""

from __future__ import annotations

import functools

import jax
import numpy as np

from ffjax import data

AXES = data.stats.AXES


def normalized_l1(pred, true, force_min, force_max) -> tuple[np.ndarray, float]:
    """Per-axis normalized L1 in percent (3,) and its mean over axes (the headline number). An axis the training
    labels hold constant (a sensor that records Fz only) has no range to divide by: its entry is NaN and the
    headline is the mean over the axes that vary (its error in newtons stays in mae_newtons)."""
    pred, true = np.asarray(pred, np.float64), np.asarray(true, np.float64)
    span = np.asarray(force_max, np.float64) - np.asarray(force_min, np.float64)
    if not np.all(span >= 0) or not np.any(span > 0):  # NaN, min above max, or no axis that varies
        raise ValueError(f"the training force range (max - min = {span} N) must be positive on some axis and "
                         "negative on none: it is the training labels' (Stats.force_min, force_max)")
    err = np.mean(np.abs(pred - true), axis=0)
    axes = np.where(span > 0, err / np.where(span > 0, span, 1.0) * 100.0, np.nan)
    return axes, float(np.nanmean(axes))


def mae_newtons(pred, true) -> np.ndarray:
    """Per-axis mean absolute error in newtons (3,)."""
    return np.mean(np.abs(np.asarray(pred, np.float64) - np.asarray(true, np.float64)), axis=0)


def summarize(pred, true, force_min, force_max) -> dict:
    """{"nl1": mean %, "nl1_axes": [3 x %], "mae_n": [3 x N], "n": count} as plain Python numbers."""
    pred, true = np.asarray(pred).reshape(-1, 3), np.asarray(true).reshape(-1, 3)
    if len(pred) == 0:
        return {"nl1": float("nan"), "nl1_axes": [float("nan")] * 3, "mae_n": [float("nan")] * 3, "n": 0}
    axes, mean = normalized_l1(pred, true, force_min, force_max)
    return {"nl1": mean, "nl1_axes": axes.tolist(), "mae_n": mae_newtons(pred, true).tolist(), "n": len(pred)}


@functools.lru_cache(maxsize=32)
def _predict_fn(model):
    # One compiled apply per model config (linen modules hash by their fields).
    return jax.jit(lambda variables, x: model.apply(variables, x, train=False)["force"])


def batched(fn, variables, images, batch_size: int = 64, width: int = 3) -> np.ndarray:
    """fn(variables, chunk) over preprocessed images (N, S, S, 3) in fixed-size chunks; the last chunk is
    zero-padded, so `fn` compiles once. Returns the stacked outputs (N, ...); (0, width) for no images."""
    images = np.asarray(images, np.float32)
    out = []
    for start in range(0, len(images), batch_size):
        chunk = images[start : start + batch_size]
        n = len(chunk)
        if n < batch_size:
            chunk = np.concatenate([chunk, np.zeros((batch_size - n, *chunk.shape[1:]), chunk.dtype)])
        out.append(np.asarray(fn(variables, chunk))[:n])
    return np.concatenate(out) if out else np.zeros((0, width), np.float32)


def predict(model, variables, images, batch_size: int = 64) -> np.ndarray:
    """Forces (N, 3) for preprocessed images (N, S, S, 3); the last batch is padded, so one compile."""
    return batched(_predict_fn(model), variables, images, batch_size)


def evaluate(model, variables, images, forces, force_min, force_max, batch_size: int = 64) -> dict:
    """Evaluate on in-memory preprocessed arrays; see `summarize` for the keys."""
    return summarize(predict(model, variables, images, batch_size), forces, force_min, force_max)


def evaluate_split(model, variables, source, stats, input_size: int, batch_size: int = 64) -> dict:
    """Evaluate on a data source (shard dir / CSV from `data.open_split`, or an opened source).

    Streams batches through the same preprocessing as training; normalization uses `stats`
    (the TRAINING split's force range).
    """
    if isinstance(source, str) or hasattr(source, "__fspath__"):
        source = data.open_split(source)
    preds, trues = [], []
    for batch in iterate_once(source, stats, input_size, batch_size):
        preds.append(predict(model, variables, batch["image"], batch_size))
        trues.append(np.asarray(batch["force"]))
    pred = np.concatenate(preds) if preds else np.zeros((0, 3))
    true = np.concatenate(trues) if trues else np.zeros((0, 3))
    return summarize(pred, true, stats.force_min, stats.force_max)


def iterate_once(source, stats, input_size: int, batch_size: int):
    """One ordered pass over every record (last batch may be short)."""
    ds = data.make_dataset(
        source, stats, input_size, batch_size, seed=0, shuffle=False, num_epochs=1, drop_remainder=False
    )
    yield from iter(ds)
