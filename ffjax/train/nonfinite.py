"""What a non-finite step does: train.nonfinite "stop" raises NonFiniteLossError naming the step, the batch's
records and the last good checkpoint; "skip" drops the update (the jitted step never applies one) and goes on."""

from __future__ import annotations

import math

import grain


class NonFiniteLossError(FloatingPointError):
    """Raised when a training loss or gradient is NaN/inf; the run folder keeps its last good checkpoint."""


MODES = ("stop", "skip")


def batch_records(n: int, seed: int, batch_size: int, step: int) -> list[int]:
    """Indices into the train split of the batch that step `step` (1-based) trained on: the shuffled,
    repeated order make_dataset draws (one process), rebuilt only when an error needs to name it."""
    ds = grain.MapDataset.range(n).shuffle(seed=seed).repeat(None).batch(batch_size, drop_remainder=True)
    return [int(i) for i in ds[step - 1]]


def error(row, step, ckpt, run_dir, n, seed, bs) -> NonFiniteLossError:
    """The error for a non-finite logged `row` at `step` (n train records, the run's seed and batch size)."""
    good = ckpt.latest_step()
    what = "loss" if not math.isfinite(row["loss"]) else "gradient"
    idx = batch_records(n, seed, bs, step)
    return NonFiniteLossError(
        f"non-finite training {what} (loss {row['loss']}, grad norm {row['grad_norm']}) at step {step} "
        f"(epoch {row['epoch']}, batch {step - 1}: train records {idx}); stopped, the update was not applied. "
        f"Last good checkpoint: step {good} in {run_dir / 'checkpoints'}"
        + (" (none yet)" if good is None else "")
        + ". Lower train.lr_* or set train.grad_clip, check those records, then resume or restart "
        "(or set train.nonfinite=skip)."
    )
