"""Simulator and input-pipeline side of `experiments.bench`: samples/s, batches/s, and whether the
pipeline ever bounds a training step."""

from __future__ import annotations

import json
import time
from pathlib import Path

import jax

from ffjax import data, registry, sim, train
from ffjax.sim import dataset as sim_dataset


def sim_rates(sizes: dict, n: dict) -> dict:
    """sim.benchmark (press_batch over all indenters, random forces/poses, 1 process) per render size."""
    out = {}
    for name, size in sizes.items():
        per_min = sim.benchmark(size=tuple(size), n=int(n[name]), verbose=False)["per_minute_wall"]
        out[name] = {"render_size": list(size), "samples": int(n[name]), "samples_s": per_min / 60}
    return out


def make_split(root, cfg: dict, name: str, index: int, per_shape: int) -> tuple[Path, float]:
    """Render one split of `per_shape` presses per indenter through the dataset code path (one shard);
    returns its folder and the render rate (samples/s)."""
    spec = sim_dataset.SplitSpec(name, "mini-1-gel1", tuple(sim.INDENTERS), per_shape, index)
    size = tuple(cfg["data"]["render_size"])
    t0 = time.perf_counter()
    arrays = sim_dataset.render_shard(spec, sim_dataset.sample_presses(spec, cfg), 0, spec.count, size)
    rate = spec.count / (time.perf_counter() - t0)
    folder = Path(root) / name
    folder.mkdir(parents=True, exist_ok=True)
    sim_dataset.save_npz(folder / "shard_00000.npz", arrays)
    from ffjax.data.sources import write_rgb

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


def loop_overhead(cfg: dict, method: str, source, stats, size: int, batch: int, steps: int) -> dict:
    """Train-loop step time fed by the pipeline (next(it) + train_step, as ffjax.train.loop does) vs fed
    one ready device batch: the pipeline's real cost when it shares the 2 cores with the step."""
    arrays = data.load_arrays(source, stats, size)
    state = train.init_state(cfg, registry.get(method), jax.random.PRNGKey(0), size)
    fixed = jax.device_put(next(iter(data.make_dataset(source, stats, size, batch, 0, arrays=arrays))))
    state, m = train.train_step(state, fixed)  # compile
    jax.block_until_ready(m["loss"])
    res = {}
    feeds = {"fixed_batch": None,
             "in_memory": data.make_dataset(source, stats, size, batch, 0, arrays=arrays),
             "streaming_w0": data.make_dataset(source, stats, size, batch, 0, in_memory=False)}
    for name, ds in feeds.items():
        it = iter(ds) if ds is not None else None
        if it is not None:
            next(it)
        t0 = time.perf_counter()
        for _ in range(steps):
            b = next(it) if it is not None else fixed
            state, m = train.train_step(state, b)
        jax.block_until_ready(m["loss"])
        res[name] = {"ms_per_step": (time.perf_counter() - t0) / steps * 1e3}
    for name in ("in_memory", "streaming_w0"):
        res[name]["overhead"] = res[name]["ms_per_step"] / res["fixed_batch"]["ms_per_step"] - 1
    res["steps"] = steps
    return res
