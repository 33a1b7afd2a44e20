"""Validation and the evaluation passes of training: the validation loss and force metric, the regressor's
feature statistics, and compiling both before step 1."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ffjax import data as fdata
from ffjax import metrics as fmetrics
from ffjax.train.step import eval_step, feature_step, replicate, shard_batch


class Split:
    """A split for the ordered passes of evaluation (validation, feature statistics): preprocessed into memory
    once when it fits the in-memory budget (the rule make_dataset follows), so no pass re-reads or
    re-preprocesses a record; streamed per pass otherwise."""

    def __init__(self, source, stats, input_size: int):
        self.source, self.stats, self.input_size = source, stats, input_size
        fits = fdata.pipeline.fits_in_memory(len(source), input_size)
        self.arrays = fdata.load_arrays(source, stats, input_size) if fits else None

    def batches(self, batch_size: int):
        """Every record once, in order; the last batch may be short (as metrics.iterate_once)."""
        if self.arrays is None:
            yield from fmetrics.iterate_once(self.source, self.stats, self.input_size, batch_size)
            return
        for a in range(0, len(self.arrays["force"]), batch_size):
            yield {k: v[a: a + batch_size] for k, v in self.arrays.items()}


def _eval_batch(batch: dict, batch_size: int, mesh) -> dict:
    """A validation batch padded to the compiled size, with a mask over its real rows, on the mesh."""
    n = len(batch["force"])
    padded = {k: _pad(np.asarray(v), batch_size) for k, v in batch.items()}
    padded["mask"] = (np.arange(batch_size) < n).astype(np.float32)
    return shard_batch(padded, mesh)


def validate(state, val_src, stats, input_size: int, batch_size: int, mesh) -> dict:
    """Total/force/depth validation loss plus the force metric (normalized by the TRAIN force range)."""
    return run(state, Split(val_src, stats, input_size), batch_size, mesh)


def run(state, split: Split, batch_size: int, mesh) -> dict:
    """`validate` on a Split (preprocessed once, read by every validation of a run)."""
    sums, count, preds, trues = dict.fromkeys(("loss", *state.objective.names), 0.0), 0, [], []
    for batch in split.batches(batch_size):
        n = len(batch["force"])
        m = jax.device_get(eval_step(state, _eval_batch(batch, batch_size, mesh)))
        for k in sums:
            sums[k] += float(m[k]) * n
        count += n
        preds.append(np.asarray(m["force"])[:n])
        trues.append(np.asarray(batch["force"]))
    out = {k: v / max(count, 1) for k, v in sums.items()}
    lo, hi = split.stats.force_min, split.stats.force_max
    out.update(fmetrics.summarize(np.concatenate(preds), np.concatenate(trues), lo, hi))
    return out


def _has_feature_norm(state) -> bool:
    return "feature_norm" in (state.batch_stats or {}).get("regressor", {})


def _features(state, images, mesh):
    return feature_step(state, shard_batch({"image": images}, mesh)["image"])


def refresh_feature_norm(state, split: Split, batch_size: int, mesh, max_samples: int = 2048):
    """Set the regressor's feature-normalization statistics to the exact mean/variance of the backbone's
    features over (up to max_samples) training frames, with the current weights; other states unchanged.

    Training normalizes with batch statistics, so this changes no gradient. Evaluation uses the stored
    statistics, and a running average cannot follow them: a ViT feature varies across images by ~1e-3 of
    its constant part, which moves more than that with every update, so an average over past steps is off
    by many standard deviations (the validation error it gave is in docs/training.md).
    """
    if not _has_feature_norm(state):
        return state
    reg, feats = state.batch_stats["regressor"], []
    for batch in split.batches(batch_size):
        if len(batch["image"]) < batch_size or len(feats) * batch_size >= max_samples:
            break  # full batches only: one compiled shape
        feats.append(np.asarray(jax.device_get(_features(state, batch["image"], mesh)), np.float64))
    if not feats:
        return state
    f = np.concatenate(feats)
    dtype = reg["feature_norm"]["mean"].dtype
    new = {"mean": jnp.asarray(f.mean(0), dtype), "var": jnp.asarray(f.var(0), dtype)}
    batch_stats = {**state.batch_stats, "regressor": {**reg, "feature_norm": new}}
    return replicate(state.replace(batch_stats=batch_stats), mesh)


def compile_ahead(state, train_data: Split, val_data: Split | None, batch_size: int, mesh, ckpt) -> None:
    """Compile every program the loop runs besides its step before step 1: evaluation, feature statistics
    and the checkpoint checksums. Each takes seconds on a CPU; compiled at first use they stall training
    mid-run (at the first validation, the first save). Run on real batches, so the shapes are exactly the
    loop's; all are pure (nothing changes), and every complete run validates (given a val split) and saves."""
    first = next(val_data.batches(batch_size), None) if val_data is not None else None
    if first is not None:
        jax.block_until_ready(eval_step(state, _eval_batch(first, batch_size, mesh)))
    first = next(train_data.batches(batch_size))
    if _has_feature_norm(state) and len(first["image"]) == batch_size:
        jax.block_until_ready(_features(state, first["image"], mesh))
    ckpt.compile_checksums(state)


def _pad(x: np.ndarray, size: int) -> np.ndarray:
    if len(x) == size:
        return x
    return np.concatenate([x, np.zeros((size - len(x), *x.shape[1:]), x.dtype)])
