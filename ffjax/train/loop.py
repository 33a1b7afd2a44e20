"""The training loop: epochs of jitted steps, validation every train.val_every epochs, best/latest checkpoints,
resume.

At the speed of its step (issue 14; docs/benchmarks.md): no host sync per step (metrics are read every log
interval, one step behind the device), each split is preprocessed once, and every program besides the step
(evaluation, feature statistics, checkpoint checksums) is compiled before step 1, not mid-run.

Resuming restores params, optimizer, step, rng key and the grain iterator position from the newest
checkpoint and replays nothing else, so a killed-and-resumed run ends with the same numbers as an
uninterrupted one (bitwise: same compiled step, same restored arrays, same data order). A SIGKILL at any
point loses at most the steps since the last complete checkpoint: checkpoints are written beside the old
ones and renamed when complete, and every JSON/CSV file is replaced atomically (a torn last log line is
dropped on resume).

Non-finite steps: the jitted step never applies an update whose loss or gradient norm is NaN/inf; the loop
reads those metrics at its existing sync points (every log interval and before every checkpoint), so no
checkpoint ever holds a bad step and the error names the exact step. train.nonfinite = "stop" (default)
raises NonFiniteLossError naming the step and the batch's record indices; "skip" drops those updates,
counts them and goes on.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ffjax import metrics as fmetrics
from ffjax.runlock import folder_lock
from ffjax.train.checkpoint import (
    Checkpointer,
    CheckpointError,
    atomic_write_text,
    check_writable,
    read_model_json,
    write_model_json,
)
from ffjax.train.state import init_state
from ffjax.train.step import eval_step, feature_step, make_mesh, replicate, shard_batch, train_step

LOG_NAME, CSV_NAME, SUMMARY_NAME = "train_log.jsonl", "epochs.csv", "summary.json"
CSV_FIELDS = (
    "epoch",
    "step",
    "train_loss",
    "train_force_l1",
    "val_loss",
    "val_force_l1",
    "val_depth_mse",
    "val_nl1",
    "val_nl1_fx",
    "val_nl1_fy",
    "val_nl1_fz",
    "val_mae_fx",
    "val_mae_fy",
    "val_mae_fz",
    "time_s",
)


def with_output_affine(cfg: dict, stats) -> dict:
    """Fill the regressor's fixed output scale/shift from the training force range (a copy of cfg).

    Only when cfg model.regressor.normalize_output is set and no scale is given yet; model.json then
    records the numbers, so a loaded checkpoint rebuilds the same model.
    """
    from ffjax.models import output_affine

    rc = cfg["model"]["regressor"]
    if not rc.get("normalize_output") or rc.get("out_scale") is not None:
        return cfg
    cfg = {**cfg, "model": {**cfg["model"], "regressor": {**rc, **output_affine(stats.force_min, stats.force_max)}}}
    return cfg


class NonFiniteLossError(FloatingPointError):
    """Raised when a training loss or gradient is NaN/inf; the run folder keeps its last good checkpoint."""


NONFINITE_MODES = ("stop", "skip")


def batch_records(n: int, seed: int, batch_size: int, step: int) -> list[int]:
    """Indices into the train split of the batch that step `step` (1-based) trained on: the shuffled,
    repeated order make_dataset draws (one process), rebuilt only when an error needs to name it."""
    import grain

    ds = grain.MapDataset.range(n).shuffle(seed=seed).repeat(None).batch(batch_size, drop_remainder=True)
    return [int(i) for i in ds[step - 1]]


def open_sources(data_arg):
    """(train, val) sources from a dataset root (DIR/train, DIR/val), a {"train": .., "val": ..} dict
    of paths (shard dirs or release CSVs) or opened sources, or a (train, val) pair. val may be None."""
    from ffjax import data

    def _open(x):
        return data.open_split(x) if isinstance(x, (str, os.PathLike)) else x

    if isinstance(data_arg, (str, os.PathLike)):
        root = Path(data_arg)
        val = root / "val"
        return data.open_split(root / "train"), (data.open_split(val) if val.exists() else None)
    if isinstance(data_arg, dict):
        return _open(data_arg["train"]), (_open(data_arg["val"]) if data_arg.get("val") is not None else None)
    train_src, val_src = data_arg
    return _open(train_src), (_open(val_src) if val_src is not None else None)


class _Split:
    """A split for the ordered passes of evaluation (validation, feature statistics): preprocessed into memory
    once when it fits the in-memory budget (the rule make_dataset follows), so no pass re-reads or
    re-preprocesses a record; streamed per pass otherwise."""

    def __init__(self, source, stats, input_size: int):
        from ffjax.data import load_arrays
        from ffjax.data.pipeline import fits_in_memory

        self.source, self.stats, self.input_size = source, stats, input_size
        self.arrays = load_arrays(source, stats, input_size) if fits_in_memory(len(source), input_size) else None

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
    return _validate(state, _Split(val_src, stats, input_size), batch_size, mesh)


def _validate(state, split: _Split, batch_size: int, mesh) -> dict:
    sums, count, preds, trues = {"loss": 0.0, "force_l1": 0.0, "depth_mse": 0.0}, 0, [], []
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


def refresh_feature_norm(state, split: _Split, batch_size: int, mesh, max_samples: int = 2048):
    """Set the regressor's feature-normalization statistics to the exact mean/variance of the backbone's
    features over (up to max_samples) training frames, with the current weights; other states unchanged.

    Training normalizes with batch statistics, so this changes no gradient. Evaluation uses the stored
    statistics, and a running average cannot follow them: a ViT feature varies across images by ~1e-3 of
    its constant part, which moves more than that with every update, so an average over past steps is off
    by many standard deviations (measured: validation 28% with it, 4.1% with the batch's own statistics).
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


def _compile_ahead(state, train_data: _Split, val_data: _Split | None, batch_size: int, mesh, ckpt) -> None:
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


class _Log:
    """JSONL (every row) + CSV (one row per epoch); on resume rows past the restored step are dropped."""

    def __init__(self, run_dir: Path, keep_until: int | None):
        self.jsonl, self.csv = run_dir / LOG_NAME, run_dir / CSV_NAME
        if keep_until is None:
            for p in (self.jsonl, self.csv):
                p.unlink(missing_ok=True)
        else:
            self._truncate(keep_until)

    def _truncate(self, step: int) -> None:
        if self.jsonl.exists():
            rows = [r for r in self.jsonl.read_text().splitlines() if (_json_step(r) or step + 1) <= step]
            atomic_write_text(self.jsonl, "".join(r + "\n" for r in rows))
        if self.csv.exists():
            with self.csv.open() as f:
                rows = [r for r in csv.DictReader(f) if _complete(r) and (_int(r.get("step")) or step + 1) <= step]
            atomic_write_text(self.csv, _csv_text(rows))

    def row(self, row: dict) -> None:
        with self.jsonl.open("a") as f:
            f.write(json.dumps(row) + "\n")

    def epoch(self, row: dict) -> None:
        self._write_csv([row], "a")

    def _write_csv(self, rows, mode: str) -> None:
        if mode == "w" or not self.csv.exists():
            atomic_write_text(self.csv, _csv_text(rows))
            return
        with self.csv.open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=CSV_FIELDS, extrasaction="ignore").writerows(rows)


def _csv_text(rows) -> str:
    import io

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=CSV_FIELDS, extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def _json_step(line: str):
    """A log line's step, or None for a line a kill cut short (dropped on resume)."""
    try:
        return int(json.loads(line)["step"])
    except (ValueError, KeyError, TypeError):
        return None


def _complete(row: dict) -> bool:
    """False for a CSV row a kill cut short (fields missing) or garbled (extra fields)."""
    return None not in row and all(v is not None for v in row.values())


def _int(text):
    try:
        return int(text)
    except (TypeError, ValueError):
        return None


def train(cfg: dict, spec, data, out_dir, resume: bool = False, init_backbone: tuple | None = None,
          **kwargs) -> dict:
    """Train `spec` (a registry Method or its name) with `cfg`; returns a summary dict.

    data: dataset root with train/ and val/, or {"train": .., "val": ..}, or a (train, val) pair.
    init_backbone: (params, batch_stats) from `pretrain.load_backbone` (ignored on resume: the
    checkpoint has the weights). Keywords: init_variables (the whole model's variables to start from, e.g.
    the FeelAnyForce release, converted), max_steps (stop early, after checkpointing; resuming continues),
    callback(step, state) (runs after each step; may return a replacement state: tests inject faults),
    progress, devices. The run folder is locked while training (`ffjax.runlock`): a second training into it
    is refused with FolderLockedError naming the first.
    """
    run_dir = check_writable(out_dir)  # before any work: an unwritable --out fails in a second, not at step N
    with folder_lock(run_dir, "training run"):
        return _train(cfg, spec, data, run_dir, resume, init_backbone, **kwargs)


def _train(
    cfg: dict,
    spec,
    data,
    out_dir,
    resume: bool = False,
    init_backbone: tuple | None = None,
    *,
    init_variables: dict | None = None,
    max_steps: int | None = None,
    callback: Callable | None = None,
    progress: bool = True,
    devices=None,
) -> dict:
    from ffjax import data as fdata
    from ffjax import registry

    spec = registry.get(spec) if isinstance(spec, str) else spec
    run_dir = Path(out_dir)
    tc = cfg["train"]
    nonfinite = tc.get("nonfinite", "stop")
    if nonfinite not in NONFINITE_MODES:
        raise ValueError(f"train.nonfinite must be one of {NONFINITE_MODES}, got {nonfinite!r}")
    input_size, bs = int(cfg["data"]["input_size"]), int(tc["batch_size"])
    train_src, val_src = open_sources(data)
    steps_per_epoch = len(train_src) // bs
    if steps_per_epoch == 0:  # refused before anything is written into the run folder
        raise ValueError(f"train split has {len(train_src)} records, fewer than one batch of {bs}: "
                         "lower train.batch_size")
    ckpt = Checkpointer(run_dir)
    has_ckpt = ckpt.latest_step() is not None
    if has_ckpt and not resume:
        ckpt.close()
        raise FileExistsError(f"{run_dir} already holds checkpoints: pass resume=True (--resume) or a new folder")
    if resume and has_ckpt:
        info = read_model_json(run_dir)
        if info["method"] != spec.name:
            ckpt.close()
            raise CheckpointError(f"{run_dir} was trained with method {info['method']!r}, not {spec.name!r}")
        stats = fdata.Stats.from_dict(info["stats"])
        # compared after the output affine is filled in, as model.json records it
        changed = _diff(info["cfg"], json.loads(json.dumps(with_output_affine(cfg, stats))))
        if changed:  # allowed (e.g. more epochs), but the result then differs from an uninterrupted run
            warnings.warn(f"resuming {run_dir} with a changed config: {', '.join(changed)}", stacklevel=3)
    else:
        stats = fdata.Stats.compute(train_src, cfg["data"])
    cfg = with_output_affine(cfg, stats)
    first = train_src[0]
    write_model_json(run_dir, cfg, spec, stats, input_size, frame_size=first["image"].shape[:2],
                     background_stats=fdata.stats.background_stats(first["background"]))

    total = int(tc["epochs"]) * steps_per_epoch
    ckpt_every = max(int(tc.get("ckpt_every", steps_per_epoch)), 1)
    val_every = max(int(tc.get("val_every", 1)), 1)  # epochs; configs written before the key: every epoch
    log_every = max(1, min(25, steps_per_epoch))
    mesh = make_mesh(devices)

    key = jax.random.PRNGKey(int(cfg["seed"]))
    state = init_state(
        cfg,
        spec,
        key,
        input_size,
        init_backbone=None if resume and has_ckpt else init_backbone,
        variables=None if resume and has_ckpt else init_variables,
        total_steps=total,
    )
    # a full disk fails here, before step 1: two latest checkpoints, the best one, and one being written
    check_writable(run_dir, 4 * sum(int(np.asarray(x).nbytes) for x in jax.tree.leaves(state.arrays())))
    state = replicate(state, mesh)
    # each split preprocessed once: the training batches, feature statistics and validation all read these
    train_data = _Split(train_src, stats, input_size)
    val_data = _Split(val_src, stats, input_size) if val_src is not None else None
    it = iter(fdata.make_dataset(train_src, stats, input_size, bs, seed=int(cfg["seed"]), shuffle=True,
                                 arrays=train_data.arrays))
    meta = {
        "epoch_loss": 0.0,
        "epoch_force_l1": 0.0,
        "epoch_steps": 0,
        "best_val_loss": None,
        "best_step": None,
        "best_epoch": None,
        "last_val": None,
        "elapsed_s": 0.0,
        "nonfinite_steps": [],
    }
    if resume and has_ckpt:
        try:
            state, data_state, meta = ckpt.restore_latest(state)
        except CheckpointError:
            ckpt.close()
            raise
        meta.setdefault("nonfinite_steps", [])
        state = replicate(state, mesh)
        it.set_state(data_state)
    start = int(jax.device_get(state.step))
    log = _Log(run_dir, start if resume else None)
    if start < total:
        _compile_ahead(state, train_data, val_data, bs, mesh, ckpt)

    pending: list = []
    t0, elapsed0 = time.perf_counter(), float(meta["elapsed_s"])
    bar = _progress(progress, total, start, spec.name)

    def flush(keep: int = 0):
        """Log the pending steps' metrics, all but the newest `keep`: reading the newest step's would idle the
        device while the host writes the log, where leaving it queued keeps the device busy meanwhile."""
        n = max(len(pending) - keep, 0)
        rows = jax.device_get(pending[:n])
        del pending[:n]
        for step, m in rows:
            ok = math.isfinite(float(m["loss"])) and math.isfinite(float(m["grad_norm"]))
            row = {
                "kind": "train",
                "step": step,
                "epoch": math.ceil(step / steps_per_epoch),
                **{k: float(v) for k, v in m.items()},
            }
            if not ok:
                row["skipped"] = True
            log.row(row)
            if not ok and nonfinite == "stop":
                raise _nonfinite_error(row, step, ckpt, run_dir, len(train_src), int(cfg["seed"]), bs)
            if not ok:  # "skip": the step dropped the update; keep the epoch means finite
                meta["nonfinite_steps"].append(step)
                continue
            meta["epoch_loss"] += row["loss"]
            meta["epoch_force_l1"] += row["force_l1"]
            meta["epoch_steps"] += 1
        if rows and bar is not None:
            bar.set_postfix(loss=f"{rows[-1][1]['loss']:.4f}")

    try:
        for step in range(start, total):
            batch = next(it)
            state, m = train_step(state, shard_batch(batch, mesh))
            done = step + 1
            pending.append((done, m))
            if bar is not None:
                bar.update(1)
            if callback is not None:
                state = callback(done, state) or state
            epoch_end = done % steps_per_epoch == 0
            # by steps, not at every epoch end: on a small dataset an epoch is seconds, and each save costs
            # ~0.2 s of CPU (quick ViT on 2 cores: ~0.05 s here, the rest in orbax's writer thread, which
            # shares the cores with the step); the last step always saves
            save = done % ckpt_every == 0 or done == total or done == max_steps
            if save or epoch_end:
                flush()  # every step up to a checkpoint is checked finite; epoch means need every step
            elif done % log_every == 0:
                flush(keep=1)
            if epoch_end:
                epoch = done // steps_per_epoch
                evaluate = epoch % val_every == 0 or done == total
                t_eval = time.perf_counter()
                if evaluate:
                    jax.block_until_ready(state.params)  # queued train steps are not evaluation time
                    t_eval = time.perf_counter()
                    state = refresh_feature_norm(state, train_data, bs, mesh)
                _end_epoch(state, meta, done, epoch, val_data if evaluate else _SKIP, bs, mesh, ckpt, log,
                           elapsed0 + time.perf_counter() - t0)
                if evaluate:
                    meta["eval_s"] = meta.get("eval_s", 0.0) + time.perf_counter() - t_eval
            if save:
                meta["elapsed_s"] = elapsed0 + time.perf_counter() - t0
                ckpt.save_latest(done, state, it.get_state(), meta)
            if max_steps is not None and done >= max_steps:
                break
        flush()
    except BaseException:
        # already failing (a full disk, a kill, a NaN): the pending saves' own errors would only repeat it and
        # replace the message that says what happened, so they are dropped here
        if bar is not None:
            bar.close()
        with contextlib.suppress(Exception):
            ckpt.wait()
        with contextlib.suppress(Exception):
            ckpt.close()
        raise
    if bar is not None:
        bar.close()
    try:
        ckpt.wait()  # a pending async save must finish (or report its error) before the run counts as done
    except BaseException:
        with contextlib.suppress(Exception):
            ckpt.close()
        raise
    ckpt.close()

    final_step = int(jax.device_get(state.step))
    elapsed = elapsed0 + time.perf_counter() - t0
    summary = {
        "run_dir": str(run_dir),
        "method": spec.name,
        "preset": cfg.get("preset"),
        "steps": final_step,
        "total_steps": total,
        "complete": final_step >= total,
        "steps_per_epoch": steps_per_epoch,
        "epochs": final_step / steps_per_epoch,
        "devices": int(mesh.devices.size),
        "train_time_s": elapsed,
        # feature-norm refresh + validation + choosing the best checkpoint (train.val_every sets how often)
        "eval_time_s": meta.get("eval_s", 0.0),
        "best_step": meta["best_step"],
        "best_epoch": meta["best_epoch"],
        "best_val_loss": meta["best_val_loss"],
        "val": meta["last_val"],
        "force_range": {"min": list(stats.force_min), "max": list(stats.force_max)},
    }
    if meta["nonfinite_steps"]:
        warnings.warn(f"{len(meta['nonfinite_steps'])} non-finite step(s) skipped (train.nonfinite='skip'): "
                      f"steps {meta['nonfinite_steps'][:20]}", stacklevel=3)
    summary["nonfinite_skipped"] = list(meta["nonfinite_steps"])
    atomic_write_text(run_dir / SUMMARY_NAME, json.dumps(summary, indent=2))
    summary["state"] = state
    return summary


def _nonfinite_error(row, step, ckpt, run_dir, n, seed, bs) -> NonFiniteLossError:
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


_SKIP = object()  # _end_epoch's val_data on an epoch that does not validate


def _end_epoch(state, meta, step, epoch, val_data, bs, mesh, ckpt, log, elapsed):
    n = max(meta["epoch_steps"], 1)
    row = {
        "epoch": epoch,
        "step": step,
        "train_loss": meta["epoch_loss"] / n,
        "train_force_l1": meta["epoch_force_l1"] / n,
        "time_s": round(elapsed, 2),
    }
    meta.update(epoch_loss=0.0, epoch_force_l1=0.0, epoch_steps=0)
    if val_data is _SKIP:  # not a validation epoch (train.val_every): the row has train columns only
        log.epoch(row)
        return
    if val_data is not None:
        val = _validate(state, val_data, bs, mesh)
        meta["last_val"] = {**val, "epoch": epoch, "step": step}
        log.row({"kind": "val", "step": step, "epoch": epoch, **val})
        row.update(
            {
                "val_loss": val["loss"],
                "val_force_l1": val["force_l1"],
                "val_depth_mse": val["depth_mse"],
                "val_nl1": val["nl1"],
            }
        )
        row.update({f"val_nl1_{a}": v for a, v in zip(("fx", "fy", "fz"), val["nl1_axes"])})
        row.update({f"val_mae_{a}": v for a, v in zip(("fx", "fy", "fz"), val["mae_n"])})
        score = val["loss"]
    else:
        score = row["train_loss"]  # no validation split: keep the newest epoch as "best"
    if meta["best_val_loss"] is None or score < meta["best_val_loss"]:
        meta.update(best_val_loss=score, best_step=step, best_epoch=epoch)
        ckpt.save_best(step, state, {"epoch": epoch, "step": step, "val_loss": score, "val": meta["last_val"]})
    log.epoch(row)


def _diff(a, b, prefix: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in sorted(set(a) | set(b)) for d in _diff(a.get(k), b.get(k), f"{prefix}{k}.")]
    return [] if a == b else [f"{prefix[:-1]}: {a} -> {b}"]


def _progress(enabled: bool, total: int, start: int, name: str):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=start, desc=f"train {name}", unit="step", dynamic_ncols=True)
