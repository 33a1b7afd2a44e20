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

Non-finite steps (train.nonfinite; ffjax.train.nonfinite): the loop reads every step's loss and gradient norm at
its sync points (each log interval, before every checkpoint), so no checkpoint ever holds a bad step.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import signal
import threading
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np
from tqdm.auto import tqdm

from ffjax import data as fdata
from ffjax import registry, store
from ffjax.data import drift
from ffjax.errors import CheckpointError
from ffjax.files import atomic_write_text, check_writable, folder_lock
from ffjax.models import output_affine
from ffjax.store import model_json
from ffjax.store.checkpoints import Checkpointer
from ffjax.train import nonfinite, validation
from ffjax.train.run_log import RunLog, csv_fields, val_columns
from ffjax.train.state import init_state
from ffjax.train.step import make_mesh, replicate, shard_batch, train_step

SUMMARY_NAME = "summary.json"


def with_output_affine(cfg: dict, stats) -> dict:
    """Fill the regressor's fixed output scale/shift from the training force range (a copy of cfg).

    Only when cfg model.regressor.normalize_output is set and no scale is given yet; model.json then
    records the numbers, so a loaded checkpoint rebuilds the same model. An axis the labels hold constant (a
    sensor that records Fz only) is scaled like the mean of the axes that vary: at output_affine's floor scale the
    normalized force loss (1 / scale per axis, mean 1) would leave the axes that vary almost no weight.
    """
    rc = cfg["model"]["regressor"]
    if not rc["normalize_output"] or rc["out_scale"] is not None:
        return cfg
    lo, hi = (np.asarray(v, np.float64) for v in (stats.force_min, stats.force_max))
    flat = ~(hi > lo)
    if flat.any() and not flat.all():  # labels where no axis varies: check_force_range refuses them
        half = float(np.mean((hi - lo)[~flat])) / 2
        lo, hi = np.where(flat, lo - half, lo), np.where(flat, hi + half, hi)
    cfg = {**cfg, "model": {**cfg["model"], "regressor": {**rc, **output_affine(lo, hi)}}}
    return cfg


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
    if tc["nonfinite"] not in nonfinite.MODES:
        raise ValueError(f"train.nonfinite must be one of {nonfinite.MODES}, got {tc['nonfinite']!r}")
    input_size, bs = int(cfg["data"]["input_size"]), int(tc["batch_size"])
    train_src, val_src = open_sources(data)
    steps_per_epoch = len(train_src) // bs
    if steps_per_epoch == 0:  # refused before anything is written into the run folder
        raise ValueError(f"train split has {len(train_src)} records, fewer than one batch of {bs}: "
                         "lower train.batch_size")
    fdata.stats.check_force_range(train_src)  # labels that never vary: refused before the run folder is touched
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
    train_data = validation.Split(train_src, stats, input_size)
    val_data = validation.Split(val_src, stats, input_size) if val_src is not None else None
    it = iter(fdata.make_dataset(train_src, stats, input_size, bs, seed=int(cfg["seed"]), shuffle=True,
                                 arrays=train_data.arrays, augment=drift.augment(cfg["train"], stats)))
    meta = _new_meta(state.objective)
    if restoring:
        state, meta = _restore(ckpt, state, meta, it, mesh)
    start = int(jax.device_get(state.step))
    log = RunLog(run_dir, start if resume else None, csv_fields(state.objective))
    if start < total:
        validation.compile_ahead(state, train_data, val_data, bs, mesh, ckpt)
    return _Run(run_dir=run_dir, cfg=cfg, spec=spec, stats=stats, ckpt=ckpt, mesh=mesh, state=state, meta=meta,
                log=log, data=_Data(it, train_data, val_data), plan=_Plan(bs, steps_per_epoch, total, start))


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
    # compared after the output affine is filled in, as model.json records it; the saved config read as it was
    # meant (a key it lacks holds the value the code used then), less the report section: how results are worded
    # changes nothing the run trains
    before, now = (json.loads(json.dumps({k: v for k, v in c.items() if k != "report"}))
                   for c in (saved.cfg, with_output_affine(cfg, stats)))
    changed = _diff(before, now)
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


@dataclasses.dataclass(frozen=True)
class _Plan:
    """How far a run goes: its batch size, steps per epoch, last step and the step it starts from."""

    batch_size: int
    steps_per_epoch: int
    total: int
    start: int


@dataclasses.dataclass(frozen=True)
class _Data:
    """A run's training batches (a grain iterator; its position is checkpointed) and both splits, preprocessed
    once, for the evaluation passes."""

    it: object
    train: validation.Split
    val: validation.Split | None


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
    meta: dict  # what a checkpoint carries besides the arrays (_new_meta)
    log: RunLog
    data: _Data
    plan: _Plan

    def __post_init__(self):
        self.bs, self.steps_per_epoch, self.total, self.start = dataclasses.astuple(self.plan)
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
                self.state, m = train_step(self.state, shard_batch(next(self.data.it), self.mesh))
                done = step + 1
                self.pending.append((done, m))
                if self.bar is not None:
                    self.bar.update(1)
                if callback is not None:
                    self.state = callback(done, self.state) or self.state
                epoch_end = done % self.steps_per_epoch == 0
                # by steps, not at every epoch end: on a small dataset an epoch is seconds, and each save costs
                # CPU the step shares (measured: docs/benchmarks.md); the last step always saves
                save = done % self.ckpt_every == 0 or done == self.total or done == max_steps
                if save or epoch_end:
                    self.flush()  # every step up to a checkpoint is checked finite; epoch means need every step
                elif done % self.log_every == 0:
                    self.flush(keep=1)
                if epoch_end:
                    self.end_epoch(done)
                if save:
                    self.meta["elapsed_s"] = self.elapsed0 + time.perf_counter() - self.t0
                    with _ctrl_c_held():
                        self.ckpt.save_latest(done, self.state, self.data.it.get_state(), self.meta)
                if max_steps is not None and done >= max_steps:
                    break
            self.flush()
        except BaseException:
            # already failing (a full disk, a kill, a NaN): the pending saves' own errors would only repeat it and
            # replace the message that says what happened, so they are dropped here
            if self.bar is not None:
                self.bar.close()
            with _ctrl_c_held():  # Ctrl-C: the checkpoint being written is finished, not torn
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
                raise nonfinite.error(row, step, self.ckpt, self.run_dir, len(self.data.train.source),
                                       int(self.cfg["seed"]), self.bs)
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
            self.state = validation.refresh_feature_norm(self.state, self.data.train, self.bs, self.mesh)
        row = self._epoch_row(done, epoch, self.elapsed0 + time.perf_counter() - self.t0)
        if not evaluate:  # not a validation epoch (train.val_every): the row has train columns only
            self.log.epoch(row)
            return
        if self.data.val is not None:
            val = validation.run(self.state, self.data.val, self.bs, self.mesh)
            self.meta["last_val"] = {**val, "epoch": epoch, "step": done}
            self.log.row({"kind": "val", "step": done, "epoch": epoch, **val})
            row.update(val_columns(val, self.state.objective))
            score = val["loss"]
        else:
            score = row["train_loss"]  # no validation split: keep the newest epoch as "best"
        meta = self.meta
        if meta["best_val_loss"] is None or score < meta["best_val_loss"]:
            meta.update(best_val_loss=score, best_step=done, best_epoch=epoch)
            with _ctrl_c_held():
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
        with _ctrl_c_held():
            try:
                self.ckpt.wait()  # a pending async save must finish (or report its error) before the run is done
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


@contextlib.contextmanager
def _ctrl_c_held():
    """Hold Ctrl-C back while orbax saves or waits for a save, then raise it (KeyboardInterrupt): raised inside
    orbax (a save's coroutines built but not run, a finalize thread half-joined) it left a step half-listed and
    echoes after the "interrupted" line ("coroutine ... was never awaited", "Save Finalize thread failed"). Only
    where Ctrl-C raises KeyboardInterrupt: the main thread under Python's own handler."""
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield
        return
    held = []
    signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if held:
        raise KeyboardInterrupt


def _diff(a, b, prefix: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in sorted(set(a) | set(b)) for d in _diff(a.get(k), b.get(k), f"{prefix}{k}.")]
    return [] if a == b else [f"{prefix[:-1]}: {a} -> {b}"]


def _progress(enabled: bool, total: int, start: int, name: str):
    if not enabled:
        return None
    return tqdm(total=total, initial=start, desc=f"train {name}", unit="step", dynamic_ncols=True)
