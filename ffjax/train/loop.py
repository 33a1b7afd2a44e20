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
import dataclasses
import io
import json
import math
import os
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import grain
import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from ffjax import data as fdata
from ffjax import metrics as fmetrics
from ffjax import registry, store
from ffjax.data import load_arrays
from ffjax.data.pipeline import fits_in_memory
from ffjax.errors import CheckpointError
from ffjax.files import atomic_write_text, check_writable, folder_lock
from ffjax.models import output_affine
from ffjax.store import model_json
from ffjax.store.checkpoints import Checkpointer
from ffjax.train.state import init_state
from ffjax.train.step import eval_step, feature_step, make_mesh, replicate, shard_batch, train_step

LOG_NAME, CSV_NAME, SUMMARY_NAME = "train_log.jsonl", "epochs.csv", "summary.json"


def csv_fields(objective) -> tuple[str, ...]:
    """epochs.csv's columns: the epoch's train means (loss, and each objective term with a train column), its
    validation (loss, each term, the force metric per axis), and the elapsed time."""
    return (
        "epoch",
        "step",
        "train_loss",
        *(f"train_{t.name}" for t in objective.terms if t.train_column),
        "val_loss",
        *(f"val_{name}" for name in objective.names),
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
    rc = cfg["model"]["regressor"]
    if not rc["normalize_output"] or rc["out_scale"] is not None:
        return cfg
    cfg = {**cfg, "model": {**cfg["model"], "regressor": {**rc, **output_affine(stats.force_min, stats.force_max)}}}
    return cfg


class NonFiniteLossError(FloatingPointError):
    """Raised when a training loss or gradient is NaN/inf; the run folder keeps its last good checkpoint."""


NONFINITE_MODES = ("stop", "skip")


def batch_records(n: int, seed: int, batch_size: int, step: int) -> list[int]:
    """Indices into the train split of the batch that step `step` (1-based) trained on: the shuffled,
    repeated order make_dataset draws (one process), rebuilt only when an error needs to name it."""
    ds = grain.MapDataset.range(n).shuffle(seed=seed).repeat(None).batch(batch_size, drop_remainder=True)
    return [int(i) for i in ds[step - 1]]


def open_sources(data_arg):
    """(train, val) sources from a dataset root (DIR/train, DIR/val), a {"train": .., "val": ..} dict
    of paths (shard dirs or release CSVs) or opened sources, or a (train, val) pair. val may be None."""
    def _open(x):
        return fdata.open_split(x) if isinstance(x, (str, os.PathLike)) else x

    if isinstance(data_arg, (str, os.PathLike)):
        root = Path(data_arg)
        val = root / "val"
        return fdata.open_split(root / "train"), (fdata.open_split(val) if val.exists() else None)
    if isinstance(data_arg, dict):
        return _open(data_arg["train"]), (_open(data_arg["val"]) if data_arg.get("val") is not None else None)
    train_src, val_src = data_arg
    return _open(train_src), (_open(val_src) if val_src is not None else None)


class _Split:
    """A split for the ordered passes of evaluation (validation, feature statistics): preprocessed into memory
    once when it fits the in-memory budget (the rule make_dataset follows), so no pass re-reads or
    re-preprocesses a record; streamed per pass otherwise."""

    def __init__(self, source, stats, input_size: int):

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

    def __init__(self, run_dir: Path, keep_until: int | None, fields: tuple[str, ...]):
        self.jsonl, self.csv, self.fields = run_dir / LOG_NAME, run_dir / CSV_NAME, fields
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
            atomic_write_text(self.csv, _csv_text(rows, self.fields))

    def row(self, row: dict) -> None:
        with self.jsonl.open("a") as f:
            f.write(json.dumps(row) + "\n")

    def epoch(self, row: dict) -> None:
        self._write_csv([row], "a")

    def _write_csv(self, rows, mode: str) -> None:
        if mode == "w" or not self.csv.exists():
            atomic_write_text(self.csv, _csv_text(rows, self.fields))
            return
        with self.csv.open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=self.fields, extrasaction="ignore").writerows(rows)


def _csv_text(rows, fields) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
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
    progress, devices. The run folder is locked while training (`ffjax.files.folder_lock`): a second training into it
    is refused with FolderLockedError naming the first.
    """
    run_dir = check_writable(out_dir)  # before any work: an unwritable --out fails in a second, not at step N
    with folder_lock(run_dir, "training run"):
        return _train(cfg, spec, data, run_dir, resume, init_backbone, **kwargs)


def _train(cfg: dict, spec, data, out_dir, resume: bool = False, init_backbone: tuple | None = None, *,
           init_variables: dict | None = None, max_steps: int | None = None, callback: Callable | None = None,
           progress: bool = True, devices=None) -> dict:
    spec = registry.get(spec) if isinstance(spec, str) else spec
    run = _open_run(cfg, spec, data, Path(out_dir), resume, init_backbone, init_variables, devices)
    run.loop(max_steps, callback, progress)
    return run.finish()


def _open_run(cfg, spec, data, run_dir: Path, resume, init_backbone, init_variables, devices) -> _Run:
    """Everything before step 1: sources, statistics (the run's own on resume), model.json, the state (restored
    on resume), the data iterator, the log, and every program besides the step compiled."""
    tc = cfg["train"]
    if tc["nonfinite"] not in NONFINITE_MODES:
        raise ValueError(f"train.nonfinite must be one of {NONFINITE_MODES}, got {tc['nonfinite']!r}")
    input_size, bs = int(cfg["data"]["input_size"]), int(tc["batch_size"])
    train_src, val_src = open_sources(data)
    steps_per_epoch = len(train_src) // bs
    if steps_per_epoch == 0:  # refused before anything is written into the run folder
        raise ValueError(f"train split has {len(train_src)} records, fewer than one batch of {bs}: "
                         "lower train.batch_size")
    ckpt = Checkpointer(run_dir)
    restoring = ckpt.latest_step() is not None
    if restoring and not resume:
        ckpt.close()
        raise FileExistsError(f"{run_dir} already holds checkpoints: pass resume=True (--resume) or a new folder")
    stats = _resumed_stats(ckpt, run_dir, cfg, spec) if restoring else fdata.Stats.compute(train_src, cfg["data"])
    cfg = with_output_affine(cfg, stats)
    first = train_src[0]
    model_json.write(run_dir, model_json.info(cfg, spec, stats, input_size, first["image"].shape[:2],
                                              fdata.stats.background_stats(first["background"])))
    total = int(tc["epochs"]) * steps_per_epoch
    mesh = make_mesh(devices)
    state = init_state(cfg, spec, jax.random.PRNGKey(int(cfg["seed"])), input_size,
                       init_backbone=None if restoring else init_backbone,
                       variables=None if restoring else init_variables, total_steps=total)
    # a full disk fails here, before step 1: two latest checkpoints, the best one, and one being written
    check_writable(run_dir, 4 * sum(int(np.asarray(x).nbytes) for x in jax.tree.leaves(state.arrays())))
    state = replicate(state, mesh)
    # each split preprocessed once: the training batches, feature statistics and validation all read these
    train_data = _Split(train_src, stats, input_size)
    val_data = _Split(val_src, stats, input_size) if val_src is not None else None
    it = iter(fdata.make_dataset(train_src, stats, input_size, bs, seed=int(cfg["seed"]), shuffle=True,
                                 arrays=train_data.arrays))
    meta = _new_meta(state.objective)
    if restoring:
        state, meta = _restore(ckpt, state, meta, it, mesh)
    start = int(jax.device_get(state.step))
    log = _Log(run_dir, start if resume else None, csv_fields(state.objective))
    if start < total:
        _compile_ahead(state, train_data, val_data, bs, mesh, ckpt)
    return _Run(run_dir, cfg, spec, stats, ckpt, mesh, state, it, train_data, val_data, log, meta, len(train_src),
                bs, steps_per_epoch, total, start)


def _resumed_stats(ckpt, run_dir: Path, cfg: dict, spec):
    """The data statistics the run was started with; refused when the folder holds another method's run."""
    try:
        saved = store.describe(run_dir)  # the reader inference and experiments use
    except CheckpointError:
        ckpt.close()
        raise
    if saved.spec.name != spec.name:
        ckpt.close()
        raise CheckpointError(f"{run_dir} was trained with method {saved.spec.name!r}, not {spec.name!r}")
    stats = saved.stats
    # compared after the output affine is filled in, as model.json records it
    changed = _diff(saved.info["cfg"], json.loads(json.dumps(with_output_affine(cfg, stats))))
    if dataclasses.is_dataclass(spec) and saved.spec != spec:  # e.g. another loss weight under the same name
        changed += _diff(dataclasses.asdict(saved.spec), dataclasses.asdict(spec), "method.")
    if changed:  # allowed (e.g. more epochs), but the result then differs from an uninterrupted run
        warnings.warn(f"resuming {run_dir} with a changed config: {', '.join(changed)}", stacklevel=5)
    return stats


def _new_meta(objective) -> dict:
    """What a checkpoint carries besides the arrays: the epoch's running sums, the best epoch so far, time."""
    return {
        "epoch_loss": 0.0,
        **{f"epoch_{t.name}": 0.0 for t in objective.terms if t.train_column},
        "epoch_steps": 0,
        "best_val_loss": None,
        "best_step": None,
        "best_epoch": None,
        "last_val": None,
        "elapsed_s": 0.0,
        "nonfinite_steps": [],
    }


def _restore(ckpt, state, meta: dict, it, mesh):
    """(state, meta) from the newest intact checkpoint; the data iterator is moved to its position."""
    try:
        state, data_state, saved = ckpt.restore_latest(state)
    except CheckpointError:
        ckpt.close()
        raise
    for k, v in meta.items():  # keys a checkpoint written before them lacks (nonfinite_steps, a new term's sum)
        saved.setdefault(k, v)
    state = replicate(state, mesh)
    it.set_state(data_state)
    return state, saved


@dataclasses.dataclass
class _Run:
    """One opened training run (`_open_run`): `loop` runs the steps, `finish` closes it and writes the summary."""

    run_dir: Path
    cfg: dict
    spec: object
    stats: object
    ckpt: Checkpointer
    mesh: object
    state: object
    it: object  # the training batches (a grain iterator; its position is checkpointed)
    train_data: _Split
    val_data: _Split | None
    log: _Log
    meta: dict
    n_train: int
    bs: int
    steps_per_epoch: int
    total: int
    start: int

    def __post_init__(self):
        tc = self.cfg["train"]
        self.nonfinite = tc["nonfinite"]
        self.ckpt_every = max(int(tc["ckpt_every"]), 1)
        self.val_every = max(int(tc["val_every"]), 1)  # epochs
        self.log_every = max(1, min(25, self.steps_per_epoch))
        self.sums = [t.name for t in self.state.objective.terms if t.train_column]  # the epoch means' terms
        self.pending: list = []  # (step, device metrics) not logged yet
        self.bar = None

    def loop(self, max_steps: int | None, callback: Callable | None, progress: bool) -> None:
        """Steps from the restored (or first) step to the end or max_steps; metrics are read only at log
        intervals, epoch ends and saves."""
        self.t0, self.elapsed0 = time.perf_counter(), float(self.meta["elapsed_s"])
        self.bar = _progress(progress, self.total, self.start, self.spec.name)
        try:
            for step in range(self.start, self.total):
                self.state, m = train_step(self.state, shard_batch(next(self.it), self.mesh))
                done = step + 1
                self.pending.append((done, m))
                if self.bar is not None:
                    self.bar.update(1)
                if callback is not None:
                    self.state = callback(done, self.state) or self.state
                epoch_end = done % self.steps_per_epoch == 0
                # by steps, not at every epoch end: on a small dataset an epoch is seconds, and each save costs
                # CPU the step shares (~0.03 s packed at quick on 2 cores); the last step always saves
                save = done % self.ckpt_every == 0 or done == self.total or done == max_steps
                if save or epoch_end:
                    self.flush()  # every step up to a checkpoint is checked finite; epoch means need every step
                elif done % self.log_every == 0:
                    self.flush(keep=1)
                if epoch_end:
                    self.end_epoch(done)
                if save:
                    self.meta["elapsed_s"] = self.elapsed0 + time.perf_counter() - self.t0
                    self.ckpt.save_latest(done, self.state, self.it.get_state(), self.meta)
                if max_steps is not None and done >= max_steps:
                    break
            self.flush()
        except BaseException:
            # already failing (a full disk, a kill, a NaN): the pending saves' own errors would only repeat it and
            # replace the message that says what happened, so they are dropped here
            if self.bar is not None:
                self.bar.close()
            with contextlib.suppress(Exception):
                self.ckpt.wait()
            with contextlib.suppress(Exception):
                self.ckpt.close()
            raise

    def flush(self, keep: int = 0) -> None:
        """Log the pending steps' metrics, all but the newest `keep`: reading the newest step's would idle the
        device while the host writes the log, where leaving it queued keeps the device busy meanwhile."""
        n = max(len(self.pending) - keep, 0)
        rows = jax.device_get(self.pending[:n])
        del self.pending[:n]
        for step, m in rows:
            ok = math.isfinite(float(m["loss"])) and math.isfinite(float(m["grad_norm"]))
            row = {
                "kind": "train",
                "step": step,
                "epoch": math.ceil(step / self.steps_per_epoch),
                **{k: float(v) for k, v in m.items()},
            }
            if not ok:
                row["skipped"] = True
            self.log.row(row)
            if not ok and self.nonfinite == "stop":
                raise _nonfinite_error(row, step, self.ckpt, self.run_dir, self.n_train, int(self.cfg["seed"]),
                                       self.bs)
            if not ok:  # "skip": the step dropped the update; keep the epoch means finite
                self.meta["nonfinite_steps"].append(step)
                continue
            self.meta["epoch_loss"] += row["loss"]
            for name in self.sums:
                self.meta[f"epoch_{name}"] += row[name]
            self.meta["epoch_steps"] += 1
        if rows and self.bar is not None:
            self.bar.set_postfix(loss=f"{rows[-1][1]['loss']:.4f}")

    def end_epoch(self, done: int) -> None:
        """The epoch's CSV row; on a validation epoch (train.val_every, and the last) also validate and keep the
        best checkpoint."""
        epoch = done // self.steps_per_epoch
        evaluate = epoch % self.val_every == 0 or done == self.total
        t_eval = time.perf_counter()
        if evaluate:
            jax.block_until_ready(self.state.params)  # queued train steps are not evaluation time
            t_eval = time.perf_counter()
            self.state = refresh_feature_norm(self.state, self.train_data, self.bs, self.mesh)
        row = self._epoch_row(done, epoch, self.elapsed0 + time.perf_counter() - self.t0)
        if not evaluate:  # not a validation epoch (train.val_every): the row has train columns only
            self.log.epoch(row)
            return
        if self.val_data is not None:
            val = _validate(self.state, self.val_data, self.bs, self.mesh)
            self.meta["last_val"] = {**val, "epoch": epoch, "step": done}
            self.log.row({"kind": "val", "step": done, "epoch": epoch, **val})
            row.update(_val_columns(val, self.state.objective))
            score = val["loss"]
        else:
            score = row["train_loss"]  # no validation split: keep the newest epoch as "best"
        meta = self.meta
        if meta["best_val_loss"] is None or score < meta["best_val_loss"]:
            meta.update(best_val_loss=score, best_step=done, best_epoch=epoch)
            self.ckpt.save_best(done, self.state, {"epoch": epoch, "step": done, "val_loss": score,
                                                   "val": meta["last_val"]})
        self.log.epoch(row)
        meta["eval_s"] = meta.get("eval_s", 0.0) + time.perf_counter() - t_eval

    def _epoch_row(self, done: int, epoch: int, elapsed: float) -> dict:
        """The epoch's train columns (means over its finite steps); the running sums start again."""
        n = max(self.meta["epoch_steps"], 1)
        row = {"epoch": epoch, "step": done, "train_loss": self.meta["epoch_loss"] / n}
        row.update({f"train_{name}": self.meta[f"epoch_{name}"] / n for name in self.sums})
        row["time_s"] = round(elapsed, 2)
        self.meta.update({"epoch_loss": 0.0, **{f"epoch_{name}": 0.0 for name in self.sums}, "epoch_steps": 0})
        return row

    def finish(self) -> dict:
        """Wait for the last saves, write summary.json; the summary (with the final state) is returned."""
        if self.bar is not None:
            self.bar.close()
        try:
            self.ckpt.wait()  # a pending async save must finish (or report its error) before the run counts as done
        except BaseException:
            with contextlib.suppress(Exception):
                self.ckpt.close()
            raise
        self.ckpt.close()
        meta, stats = self.meta, self.stats
        final_step = int(jax.device_get(self.state.step))
        summary = {
            "run_dir": str(self.run_dir),
            "method": self.spec.name,
            "preset": self.cfg.get("preset"),
            "steps": final_step,
            "total_steps": self.total,
            "complete": final_step >= self.total,
            "steps_per_epoch": self.steps_per_epoch,
            "epochs": final_step / self.steps_per_epoch,
            "devices": int(self.mesh.devices.size),
            "train_time_s": self.elapsed0 + time.perf_counter() - self.t0,
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
                          f"steps {meta['nonfinite_steps'][:20]}", stacklevel=4)
        summary["nonfinite_skipped"] = list(meta["nonfinite_steps"])
        atomic_write_text(self.run_dir / SUMMARY_NAME, json.dumps(summary, indent=2))
        summary["state"] = self.state
        return summary


def _val_columns(val: dict, objective) -> dict:
    """epochs.csv's validation columns from a `_validate` result."""
    row = {"val_loss": val["loss"], **{f"val_{name}": val[name] for name in objective.names}, "val_nl1": val["nl1"]}
    row.update({f"val_nl1_{a}": v for a, v in zip(("fx", "fy", "fz"), val["nl1_axes"])})
    row.update({f"val_mae_{a}": v for a, v in zip(("fx", "fy", "fz"), val["mae_n"])})
    return row


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


def _diff(a, b, prefix: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in sorted(set(a) | set(b)) for d in _diff(a.get(k), b.get(k), f"{prefix}{k}.")]
    return [] if a == b else [f"{prefix[:-1]}: {a} -> {b}"]


def _progress(enabled: bool, total: int, start: int, name: str):
    if not enabled:
        return None
    return tqdm(total=total, initial=start, desc=f"train {name}", unit="step", dynamic_ncols=True)
