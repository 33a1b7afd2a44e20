"""The depth decoders' cost on CPU: `python -m experiments.bench.decoders` prints it as JSON (docs/models.md)."""

from __future__ import annotations

import json
import time

import jax
import jax.numpy as jnp

import configs
from ffjax import registry
from ffjax.models import model as model_lib
from ffjax.models import vit
from ffjax.models.heads import count_params, decoder_from_config


def _timed_steps(fns: dict, args: dict, steps: int, rounds: int) -> dict:
    """Milliseconds per call of each jitted fn, interleaved over rounds (min): these VMs lose CPU to
    neighbours, so only ratios taken in one run are comparable."""
    best = {k: float("inf") for k in fns}
    for k, f in fns.items():
        jax.block_until_ready(f(*args[k]))  # compile
    for _ in range(rounds):
        for k, f in fns.items():
            t0 = time.perf_counter()
            for _ in range(steps):
                out = f(*args[k])
            jax.block_until_ready(out)
            best[k] = min(best[k], (time.perf_counter() - t0) / steps * 1e3)
    return {k: round(v, 1) for k, v in best.items()}


def measure_decoders(preset: str = "quick", batch: int = 64, steps: int = 3, rounds: int = 3) -> dict:
    """Decoder cost on CPU: parameter counts and train-step time (forward + backward, plain SGD update) of
    the decoder alone and of the whole dino_rd model with each decoder kind (dino_r = no decoder) at
    `preset` scale, plus the paper-scale decoders counted with jax.eval_shape (no allocation)."""
    cfg = configs.get(preset)
    m, s = cfg["model"], cfg["data"]["input_size"]
    d, p = m["vit"]["dim"], m["vit"]["patch"]
    key = jax.random.PRNGKey(0)
    images = jax.random.normal(key, (batch, s, s, 3))
    feature = jax.random.normal(key, (batch, d))
    tokens = jax.random.normal(key, (batch, s // p, s // p, d))
    target = jax.random.uniform(key, (batch, s, s))

    def sgd(loss_fn):
        @jax.jit
        def step(params):
            loss, g = jax.value_and_grad(loss_fn)(params)
            return jax.tree.map(lambda a, b: a - 1e-3 * b, params, g), loss

        return step

    fns, args, counts = {}, {}, {}
    for kind, fast in (("paper", False), ("paper", True), ("tokens", True)):
        dec = decoder_from_config({**m["decoder"], "kind": kind, "fast": fast}, s)
        params = dec.init(key, feature, tokens)["params"]
        counts[kind] = count_params(params)
        kind = kind if fast else "paper_literal"  # literal: upsample, then conv k5
        fns[f"decoder_{kind}"] = sgd(
            lambda q, dec=dec: jnp.mean((dec.apply({"params": q}, feature, tokens) - target) ** 2)
        )
        args[f"decoder_{kind}"] = (params,)
    for name, kind in (("dino_rd_paper", "paper"), ("dino_rd_tokens", "tokens"), ("dino_r", None)):
        spec = registry.get("dino_r" if kind is None else "dino_rd")
        net = model_lib.build({**m, "decoder": {**m["decoder"], "kind": kind or "tokens"}}, spec, s)
        params = net.init(key, images)["params"]

        def loss(q, net=net):
            out = net.apply({"params": q}, images)
            depth = jnp.mean((out["depth"] - target) ** 2) if "depth" in out else 0.0
            return jnp.mean(jnp.abs(out["force"])) + 10.0 * depth

        fns[f"model_{name}"], args[f"model_{name}"] = sgd(loss), (params,)
    ms = _timed_steps(fns, args, steps, rounds)
    pcfg = configs.get("paper")
    pm, ps, dv = pcfg["model"], pcfg["data"]["input_size"], vit.vit_config("b14")["dim"]
    pdec = decoder_from_config({**pm["decoder"], "kind": "paper"}, ps)
    pshapes = jax.eval_shape(pdec.init, key, jnp.zeros((1, dv)))["params"]
    tdec = decoder_from_config({**pm["decoder"], "kind": "tokens"}, ps)
    tshapes = jax.eval_shape(tdec.init, key, jnp.zeros((1, dv)), jnp.zeros((1, ps // 14, ps // 14, dv)))
    return {
        "preset": preset,
        "batch": batch,
        "input_size": s,
        "decoder_params": counts,
        "train_step_ms": ms,
        "paper_scale": {
            "paper_decoder_params": count_params(pshapes),
            "paper_decoder_linear_params": count_params(pshapes["fc"]),
            "tokens_decoder_params": count_params(tshapes["params"]),
        },
    }


if __name__ == "__main__":
    print(json.dumps(measure_decoders(), indent=1))
