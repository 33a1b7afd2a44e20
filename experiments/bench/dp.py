"""Data-parallel train step on N virtual CPU devices vs one device, in one process.

Run by `experiments.bench` as a subprocess (the device count is fixed when jax starts):
    XLA_FLAGS=--xla_force_host_platform_device_count=8 python -m experiments.bench.dp '{"preset": "quick"}'
prints one JSON line: ms per step on the 1-device and the N-device mesh, and the loss difference.
"""

from __future__ import annotations

import json
import sys

import jax
import numpy as np

from experiments.bench.jax_step import case_cfg, fake_batch, median_ms
from ffjax import registry, train


def run(preset: str, method: str, batch: int, size: int | None, warmup: int, steps: int, rounds: int) -> dict:
    cfg = case_cfg(preset)
    size = size or cfg["data"]["input_size"]
    host = fake_batch(batch, size)
    out = {"devices": jax.device_count(), "method": method, "batch": batch, "input_size": size}
    losses = {}
    for name, devs in (("one_device", jax.devices()[:1]), ("all_devices", jax.devices())):
        mesh = train.make_mesh(devs)
        state = train.replicate(train.init_state(cfg, registry.get(method), jax.random.PRNGKey(0), size), mesh)
        b = train.shard_batch(host, mesh)
        holder = {"state": state}

        def step(holder=holder, b=b):
            holder["state"], m = train.train_step(holder["state"], b)
            holder["loss"] = m["loss"]
            m["loss"].block_until_ready()

        step()
        losses[name] = float(holder["loss"])
        ms, per = median_ms(step, warmup, steps, rounds)
        out[name] = {"ms": ms, "ms_rounds": per, "img_s": batch / ms * 1e3, "n_devices": len(devs)}
    out["first_step_loss_abs_diff"] = abs(losses["one_device"] - losses["all_devices"])
    out["speedup_all_over_one"] = out["one_device"]["ms"] / out["all_devices"]["ms"]
    return out


if __name__ == "__main__":
    a = json.loads(sys.argv[1]) if len(sys.argv) > 1 else {}
    res = run(a.get("preset", "quick"), a.get("method", "dino_rd"), int(a.get("batch", 64)), a.get("size"),
              int(a.get("warmup", 1)), int(a.get("steps", 2)), int(a.get("rounds", 3)))
    print(json.dumps(res, default=lambda o: np.asarray(o).tolist()))
