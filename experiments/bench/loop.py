"""Simulator and input-pipeline side of `experiments.bench`: samples/s, batches/s, and whether the
pipeline ever bounds a training step."""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from ffjax import data, registry, sim, train
from ffjax.sim import dataset as sim_dataset


def sim_rates(sizes: dict, n: dict) -> dict:
    """sim.benchmark (press_batch over all indenters, random forces/poses, 1 process) per render size, compiled:
    each size's first call is untimed (alone in a process it compiled every solve inside the timing: 4.3 samples/s
    at 48x64 at 8a59790 against 31.8 after other presses)."""
    out = {}
    for name, size in sizes.items():
        sim.benchmark(size=tuple(size), n=int(n[name]), verbose=False)
        per_min = sim.benchmark(size=tuple(size), n=int(n[name]), verbose=False)["per_minute_wall"]
        out[name] = {"render_size": list(size), "samples": int(n[name]), "samples_s": per_min / 60}
    return out


def make_split(root, cfg: dict, name: str, index: int, per_shape: int) -> tuple[Path, float]:
    """Render one split of `per_shape` presses per indenter through the dataset code path (one shard);
    returns its folder and the render rate (samples/s)."""
    spec = sim_dataset.SplitSpec(name, "mini-1-gel1", tuple(sim.INDENTERS), per_shape, index)
    size = tuple(cfg["data"]["render_size"])
    t0 = time.perf_counter()
    arrays = sim_dataset.render_shard(spec, sim_dataset.sample_presses(spec, cfg), 0, spec.count, size,
                                      sim_dataset.gen_config(cfg)["data"])
    rate = spec.count / (time.perf_counter() - t0)
    folder = Path(root) / name
    folder.mkdir(parents=True, exist_ok=True)
    sim_dataset.save_npz(folder / "shard_00000.npz", arrays)
    from ffjax.data.images import write_rgb

    write_rgb(folder / "background.png", sim.get_sensor("mini-1").background(size))
    (folder / "split.json").write_text(json.dumps({"sensor": "mini-1-gel1", "count": spec.count}))
    return folder, rate


def _batches_s(ds, n: int) -> dict:
    """Rate over n batches counted from iterator creation (grain prefetches records in threads while the
    first batch is awaited, so a rate after the first batch would count buffered work as free)."""
    t0 = time.perf_counter()
    it = iter(ds)
    next(it)
    first = time.perf_counter() - t0
    for _ in range(n - 1):
        next(it)
    total = time.perf_counter() - t0
    return {"first_batch_s": first, "batches": n, "batches_s": n / total,
            "batches_s_after_first": (n - 1) / max(total - first, 1e-9)}


def pipeline_rates(source, stats, size: int, batch: int, n: int, workers=(0, 2)) -> dict:
    """Batches/s of make_dataset: the in-memory path (preprocess once, gather rows) and streaming
    (preprocess per record) with each worker count; `load_s` is the in-memory path's one-time cost."""
    t0 = time.perf_counter()
    arrays = data.load_arrays(source, stats, size)
    load_s = time.perf_counter() - t0
    out = {"in_memory": _batches_s(data.make_dataset(source, stats, size, batch, 0, arrays=arrays), n)}
    out["in_memory"]["load_s"] = load_s
    for w in workers:
        ds = data.make_dataset(source, stats, size, batch, 0, worker_count=w, in_memory=False)
        out[f"streaming_w{w}"] = _batches_s(ds, n)
    for v in out.values():
        v["img_s"] = v["batches_s"] * batch
    return out


class Repeated:
    """A split's records repeated to `n` (index i reads record i mod len): a dataset with the preset's epoch
    length from a few hundred rendered presses, for timing the loop."""

    def __init__(self, source, n: int):
        self.source, self.n = source, int(n)
        self.background = source.background
        self._all = source.read_range(0, len(source))

    def __len__(self) -> int:
        return self.n

    def _idx(self, start, stop):
        return np.arange(start, min(stop, self.n)) % len(self.source)

    def __getitem__(self, i) -> dict:
        j = int(i) % len(self.source)
        return {**{k: v[j] for k, v in self._all.items()}, "background": self.background}

    def read_range(self, start: int = 0, stop: int | None = None) -> dict:
        idx = self._idx(start, self.n if stop is None else stop)
        return {k: v[idx] for k, v in self._all.items()}

    @property
    def forces(self) -> np.ndarray:
        return self._all["force"][self._idx(0, self.n)].astype(np.float32)


class _PureStep:
    """The bare jitted step, compiled and warmed, on batches already on the device: the loop's own first
    `staged` batches in its order, cycled (`run(steps)`), or one fixed batch (`run(steps, fixed=True)`).

    The staged batches are the reference: the step computes different data at every step, as in the loop,
    and only the feeding, logging, validation and saving are left to the loop. One fixed batch stays in the
    CPU's caches and runs a little faster than any real training (measured; reported beside, as before)."""

    def __init__(self, cfg: dict, method: str, source, size: int, batch: int, warmup: int, staged: int = 64):
        stats = data.Stats.compute(source, cfg["data"], size)
        self.state = train.init_state(cfg, registry.get(method), jax.random.PRNGKey(0), size)
        it = iter(data.make_dataset(source, stats, size, batch, seed=int(cfg["seed"])))
        self.batches = [jax.device_put(next(it)) for _ in range(max(1, min(staged, len(source) // batch)))]
        self.run(warmup)
        self.run(warmup, fixed=True)

    def run(self, steps: int, fixed: bool = False) -> np.ndarray:
        """(wall s, process CPU s) for `steps` steps, dispatch to the last result."""
        batches = self.batches[:1] if fixed else self.batches
        t0 = _clocks()
        for i in range(steps):
            self.state, m = train.train_step(self.state, batches[i % len(batches)])
        jax.block_until_ready(m["loss"])
        return _clocks() - t0


def _clocks() -> np.ndarray:
    """Wall and process CPU time (all threads: XLA's, orbax's async writer, the loop's own)."""
    return np.array([time.perf_counter(), time.process_time()])


def loop_efficiency(cfg: dict, method: str, source, size: int, batch: int, n_train: int, n_val: int,
                    epochs: int, warmup: int = 3) -> dict:
    """ffjax.train.loop.train against its own jitted step, over the same steps at the same batch.

    The loop trains `epochs` epochs of `n_train` records (validation on `n_val`, checkpoints, logs, the
    data pipeline, all as configured in cfg). Its clock starts after `warmup` steps and stops when train()
    returns: everything the loop does in between is in it (final validation and checkpoint waits
    included); the one-time work before (preprocessing the splits, compiling the step and the evaluation
    and checksum programs, the warm-up steps) is not, and is reported as `startup_s`. The pure step runs the
    same number of steps on the loop's own batches staged on the device (`_PureStep`), half just before the
    loop and half just after, so a change of machine load during the measurement weighs on both sides alike;
    the same on one fixed batch, interleaved with it, gives the `*_fixed` figures.
    `efficiency` = pure s / loop s (wall). `efficiency_training` = pure s / (loop s - eval_s): the loop's
    training steps alone, its evaluation (feature-norm refresh + validation + the best checkpoint, reported
    as `eval_s` and `eval_share`) left out, as train.val_every sets that cost, not the loop's overhead.
    `efficiency_cpu` = pure / loop in process CPU seconds (all threads): work, not waiting, so it would miss
    a loop stalled on I/O, but other processes' load moves it far less than the wall figures; a check on
    them, not a replacement."""
    cfg = {**cfg, "train": {**cfg["train"], "batch_size": batch, "epochs": epochs}}
    cfg["data"] = {**cfg["data"], "input_size": size}
    tr, va = Repeated(source, n_train), Repeated(source, n_val)
    steps = epochs * (n_train // batch) - warmup
    pure = _PureStep(cfg, method, tr, size, batch, warmup)
    load = [os.getloadavg()[0]]
    half = steps // 2
    pure_t, fixed_t = pure.run(half), pure.run(half, fixed=True)
    clock = {}

    def cb(done, state):
        if done == warmup:
            jax.block_until_ready(state.params)
            clock["t0"] = _clocks()

    with tempfile.TemporaryDirectory() as tmp:
        t_call = time.perf_counter()
        summary = train.train(cfg, method, (tr, va), Path(tmp) / "run", callback=cb, progress=False)
        loop_s, loop_cpu = (float(x) for x in _clocks() - clock["t0"])
    fixed_t = fixed_t + pure.run(steps - half, fixed=True)
    pure_s, pure_cpu = (float(x) for x in pure_t + pure.run(steps - half))
    fixed_s = float(fixed_t[0])
    load.append(os.getloadavg()[0])
    assert summary["steps"] - warmup == steps
    eval_s = summary["eval_time_s"]
    return {"method": method, "batch": batch, "input_size": size, "steps": steps, "epochs": epochs,
            "steps_per_epoch": summary["steps_per_epoch"], "val_every": cfg["train"]["val_every"],
            "ckpt_every": cfg["train"]["ckpt_every"], "n_train": n_train, "n_val": n_val,
            "loop_ms": loop_s / steps * 1e3, "pure_ms": pure_s / steps * 1e3, "eval_s": eval_s,
            "startup_s": float(clock["t0"][0] - t_call), "efficiency": float(pure_s / loop_s),
            "efficiency_training": float(pure_s / max(loop_s - eval_s, 1e-9)), "eval_share": eval_s / loop_s,
            "efficiency_cpu": float(pure_cpu / loop_cpu), "load1": load, "staged_batches": len(pure.batches),
            "fixed_ms": fixed_s / steps * 1e3, "efficiency_fixed": fixed_s / loop_s,
            "efficiency_training_fixed": fixed_s / max(loop_s - eval_s, 1e-9)}
