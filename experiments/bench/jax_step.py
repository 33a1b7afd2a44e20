"""The JAX side of `experiments.bench`: train-step and inference timing, FLOP/s, profile, make-it-fast checks.

Every timing is a median over rounds after compilation and warm-up; callers compare only ratios taken
in one run (these VMs lose CPU to neighbours).
"""

from __future__ import annotations

import glob
import re
import statistics
import tempfile
import time
from collections import defaultdict

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend import core as jex_core

import configs
from ffjax import models, registry, train
from ffjax.train import step as step_lib


def median_ms(fn, warmup: int, steps: int, rounds: int) -> tuple[float, list[float]]:
    """Median (over rounds) milliseconds per call of `fn` (which must block until its result is ready)."""
    for _ in range(warmup):
        fn()
    per = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        for _ in range(steps):
            fn()
        per.append((time.perf_counter() - t0) / steps * 1e3)
    return statistics.median(per), per


def fake_batch(batch: int, size: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    return {"image": rng.standard_normal((batch, size, size, 3), np.float32),
            "depth": rng.random((batch, size, size), np.float32),
            "force": rng.standard_normal((batch, 3)).astype(np.float32)}


def case_cfg(preset: str, overrides: dict | None = None, vit: str | None = None) -> dict:
    """A preset config; `vit` = "s14"/"b14" swaps in a DINOv2 ViT's architecture (pos table 37x37 as released),
    keeping the preset's other ViT keys (those the released architecture does not name, e.g. interpolate_offset)."""
    cfg = configs.get(preset, overrides or {})
    if vit:
        cfg["model"]["vit"] = {**cfg["model"]["vit"], **models.vit_config(vit)}
    return cfg


def arch_of(cfg: dict, method: str, size: int) -> dict:
    """The architecture as plain data, for the torch side (experiments.bench.torch_twin.ForceModel)."""
    spec = registry.get(method)
    m = cfg["model"]
    return {
        "backbone": spec.backbone,
        "vit": {k: m["vit"][k] for k in ("dim", "depth", "heads", "patch", "mlp_ratio", "layerscale")}
        | {"pos_grid": m["vit"]["pos_grid"]},
        "resnet": {"widths": list(m["resnet"]["widths"]), "blocks": list(m["resnet"]["blocks"]),
                   "stem": m["resnet"]["stem"]},
        "regressor": list(m["regressor"]["widths"]),
        "feature_norm": bool(m["regressor"]["feature_norm"]),
        "decoder": ({"kind": m["decoder"]["kind"], "channels": list(m["decoder"]["channels"])}
                    if spec.depth_head else None),
        "input_size": size,
        "beta": float(spec.beta),
        "lrs": [cfg["train"]["lr_backbone"], cfg["train"]["lr_heads"]],
    }


def program_flops(fn, *args) -> float:
    """FLOPs of the matrix products and convolutions `fn(*args)` runs, counted from its jaxpr (every
    dot_general and conv_general_dilated, backward included, scans times their length): the architecture's
    own count, independent of XLA's cost analysis (which leaves out library calls such as cuBLAS on GPU).
    Elementwise ops, reductions and softmax are left out (a few % of a ViT's FLOPs)."""
    return _jaxpr_flops(jax.make_jaxpr(fn)(*args).jaxpr)


def _jaxpr_flops(jaxpr) -> float:
    total = 0.0
    for eqn in jaxpr.eqns:
        name = eqn.primitive.name
        if name == "dot_general":
            (lc, _), _ = eqn.params["dimension_numbers"]
            lhs, out = eqn.invars[0].aval, eqn.outvars[0].aval
            total += 2.0 * np.prod(out.shape) * np.prod([lhs.shape[i] for i in lc])
        elif name == "conv_general_dilated":
            rhs, out = eqn.invars[1].aval, eqn.outvars[0].aval
            rhs_spec = eqn.params["dimension_numbers"].rhs_spec
            # each output element: one multiply-add per kernel tap and input channel of its group; an
            # lhs dilation (the input gradient of a strided conv) makes all but 1/d of the taps hit zeros
            dil = np.prod(eqn.params.get("lhs_dilation") or (1,))
            total += 2.0 * np.prod(out.shape) * np.prod(rhs.shape) / rhs.shape[rhs_spec[0]] / dil
        mult = eqn.params.get("length", 1) if name == "scan" else 1
        for sub in jex_core.jaxprs_in_params(eqn.params):
            total += mult * _jaxpr_flops(sub)
    return total


def _cost(compiled) -> dict:
    ca = compiled.cost_analysis()
    ca = ca[0] if isinstance(ca, (list, tuple)) else ca
    out = {"flops": float(ca.get("flops", float("nan"))),
           "bytes_accessed": float(ca.get("bytes accessed", float("nan")))}
    try:
        ma = compiled.memory_analysis()
        out["memory"] = {k: int(getattr(ma, k)) for k in (
            "argument_size_in_bytes", "output_size_in_bytes", "alias_size_in_bytes", "temp_size_in_bytes")}
        m = out["memory"]
        out["memory"]["peak_bytes"] = (m["argument_size_in_bytes"] + m["output_size_in_bytes"]
                                       - m["alias_size_in_bytes"] + m["temp_size_in_bytes"])
    except Exception:  # noqa: BLE001 - not every backend reports it
        out["memory"] = None
    return out


def train_case(cfg: dict, method: str, batch: int, size: int, warmup: int = 2, steps: int = 3,
               rounds: int = 3, step_fn=None) -> dict:
    """Time the library's donated train_step (or another jitted `step_fn(state, batch)`) with the FLOPs of
    its matrix products counted from the program (achieved GFLOP/s use them), XLA's own count beside it
    (it misses library calls such as cuBLAS on GPU) and its memory analysis; compile_s is the first call's
    trace + compile."""
    step_fn = step_fn or train.train_step
    state = train.init_state(cfg, registry.get(method), jax.random.PRNGKey(0), size)
    b = jax.device_put(fake_batch(batch, size))
    t0 = time.perf_counter()
    state, m = step_fn(state, b)  # first call: trace + compile (what a training run pays once)
    m["loss"].block_until_ready()
    compile_s = time.perf_counter() - t0
    cost = _cost(step_fn.lower(state, b).compile())  # a cache hit: the program just compiled
    flops = program_flops(step_fn, state, b)
    holder = {"state": state}

    def run():
        holder["state"], m = step_fn(holder["state"], b)
        m["loss"].block_until_ready()

    ms, per = median_ms(run, warmup, steps, rounds)
    return {"method": method, "batch": batch, "input_size": size, "ms": ms, "ms_rounds": per,
            "img_s": batch / ms * 1e3, "compile_s": compile_s, "params": models.count_params(state.params),
            "gflop_per_step": flops / 1e9, "gflop_per_step_xla": cost["flops"] / 1e9,
            "achieved_gflops": flops / (ms * 1e-3) / 1e9,
            "memory": cost["memory"], "bytes_accessed": cost["bytes_accessed"]}


def infer_case(cfg: dict, method: str, batch: int, size: int, warmup: int = 2, steps: int = 5,
               rounds: int = 3) -> dict:
    """Force-only inference (XLA drops the unused depth head), batch `batch`, eval mode."""
    model = models.build(cfg["model"], registry.get(method), size)
    x = jnp.asarray(fake_batch(batch, size)["image"])
    variables = jax.jit(lambda k: model.init(k, x[:1], train=False))(jax.random.PRNGKey(0))
    fn = jax.jit(lambda v, x: model.apply(v, x, train=False)["force"])
    t0 = time.perf_counter()
    fn(variables, x).block_until_ready()
    compile_s = time.perf_counter() - t0
    ms, per = median_ms(lambda: fn(variables, x).block_until_ready(), warmup, steps, rounds)
    return {"method": method, "batch": batch, "input_size": size, "ms": ms, "ms_rounds": per,
            "img_s": batch / ms * 1e3, "fps_batch1": 1e3 / ms if batch == 1 else None, "compile_s": compile_s,
            "params": models.count_params(variables["params"])}


def matmul_peak(n: int = 2048, rounds: int = 5) -> dict:
    """The machine's float32 limit as XLA sees it: a large jitted matmul (best and median of rounds)."""
    a = jax.random.normal(jax.random.PRNGKey(0), (n, n), jnp.float32)
    f = jax.jit(lambda a, b: a @ b)
    f(a, a).block_until_ready()
    ms, per = median_ms(lambda: f(a, a).block_until_ready(), 1, 1, rounds)
    return {"n": n, "ms": ms, "gflops": 2 * n**3 / (min(per) * 1e-3) / 1e9,
            "gflops_median": 2 * n**3 / (ms * 1e-3) / 1e9}


# ---------------------------------------------------------------- profile
_SKIP = ("ThreadpoolListener", "ThunkExecutor", "end: ", "$", "PjitFunction", "ParseArguments",
         "PythonRefManager")


def _hlo_kinds(hlo_text: str) -> dict:
    """instruction name -> a readable kind: opcode, fusion kind + the heavy op it wraps (dot/conv/reduce)."""
    comps, kinds, cur = {}, {}, None
    for line in hlo_text.splitlines():
        head = re.match(r"^\s*(?:ENTRY\s+)?%?([\w.\-]+)\s.*\{\s*$", line)
        if head and "=" not in line.split("{")[0]:
            cur = head.group(1)
            comps[cur] = []
            continue
        m = re.match(r"^\s*(?:ROOT\s+)?%?([\w.\-]+)\s*=\s*\S+\s+([\w\-]+)\(", line)
        if m and cur is not None:
            comps[cur].append(m.group(2))
            name, op = m.group(1), m.group(2)
            kinds[name] = op
            if op == "fusion":
                called = re.search(r"calls=%?([\w.\-]+)", line)
                fk = re.search(r"kind=(\w+)", line)
                kinds[name] = ("fusion:" + (fk.group(1) if fk else "?"), called.group(1) if called else None)
    out = {}
    for name, k in kinds.items():
        if isinstance(k, tuple):
            body = comps.get(k[1], [])
            heavy = next((o for o in ("convolution", "dot", "reduce-window", "reduce", "scatter", "gather",
                                      "transpose", "exponential", "erf") if o in body), "elementwise")
            out[name] = f"{k[0]}({heavy})"
        else:
            out[name] = k
    return out


def profile_step(cfg: dict, method: str, batch: int, size: int, steps: int = 3, top: int = 12) -> dict:
    """Per-op time of the train step from a jax.profiler trace (XLA CPU thunk events), grouped by HLO
    instruction and by kind, plus a forward / backward / optimizer split from separately jitted parts."""
    state = train.init_state(cfg, registry.get(method), jax.random.PRNGKey(0), size)
    b = jax.device_put(fake_batch(batch, size))
    holder = {"state": state}

    def run():
        holder["state"], m = train.train_step(holder["state"], b)
        m["loss"].block_until_ready()

    run()
    run()
    kinds = _hlo_kinds(train.train_step.lower(holder["state"], b).compile().as_text())
    with tempfile.TemporaryDirectory() as tmp:
        jax.profiler.start_trace(tmp)
        t0 = time.perf_counter()
        for _ in range(steps):
            run()
        wall = (time.perf_counter() - t0) / steps * 1e3
        jax.profiler.stop_trace()
        files = sorted(glob.glob(f"{tmp}/**/*.xplane.pb", recursive=True))
        by_name = defaultdict(float)
        if files:
            from jax.profiler import ProfileData

            pd = ProfileData.from_file(files[-1])
            for plane in pd.planes:
                for line in plane.lines:
                    if "python" in line.name.lower():
                        continue
                    for e in line.events:
                        if e.name and not e.name.startswith(_SKIP):
                            by_name[e.name] += e.duration_ns / 1e6 / steps
    total = sum(by_name.values()) or float("nan")
    by_kind = defaultdict(float)
    for name, ms in by_name.items():
        by_kind[kinds.get(name, re.sub(r"[.\d]+$", "", name))] += ms
    ops = sorted(by_name.items(), key=lambda kv: -kv[1])[:top]
    split = _phase_split(holder["state"], b)
    return {
        "method": method, "batch": batch, "input_size": size, "step_ms_wall": wall,
        "op_ms_total": total, "n_ops_seen": len(by_name),
        "top_ops": [{"name": n, "kind": kinds.get(n, "?"), "ms": ms, "share": ms / total} for n, ms in ops],
        "by_kind": [{"kind": k, "ms": ms, "share": ms / total}
                    for k, ms in sorted(by_kind.items(), key=lambda kv: -kv[1])[:top]],
        "phases": split,
    }


def _phase_split(state, b, rounds: int = 3) -> dict:
    """ms of forward only, forward+backward (value_and_grad) and the full step (+ Adam update)."""
    def loss_fn(params):
        out, _ = step_lib._forward(state, params, b["image"], True, state.key)
        return step_lib._losses(state, out, b)[0]

    fwd = jax.jit(loss_fn)
    grad = jax.jit(jax.value_and_grad(loss_fn))
    full = NO_DONATE
    res = {}
    for name, f in (("forward", lambda: fwd(state.params)), ("forward_backward", lambda: grad(state.params)),
                    ("full_step", lambda: full(state, b))):
        jax.block_until_ready(f())
        res[name] = median_ms(lambda f=f: jax.block_until_ready(f()), 1, 2, rounds)[0]
    res["backward"] = res["forward_backward"] - res["forward"]
    res["optimizer_and_rest"] = res["full_step"] - res["forward_backward"]
    return res


# ---------------------------------------------------------------- make it fast
# ffjax's step jitted without donation (one object, so the profile and the donation check share it)
NO_DONATE = jax.jit(step_lib._train_step)


def recompile_check(cfg: dict, method: str, batch: int, size: int, steps: int = 4) -> dict:
    """The public train_step traces once per state structure: TRACE_COUNT must not move after step 1,
    also for a state rebuilt from the same config (the resume path)."""
    spec = registry.get(method)
    b = jax.device_put(fake_batch(batch, size))
    c0 = train.TRACE_COUNT["train"]
    state = train.init_state(cfg, spec, jax.random.PRNGKey(0), size)
    state, m = train.train_step(state, b)
    c1 = train.TRACE_COUNT["train"]
    for _ in range(steps):
        state, m = train.train_step(state, b)
    state2 = train.init_state(cfg, spec, jax.random.PRNGKey(1), size)
    state2, _ = train.train_step(state2, b)
    jax.block_until_ready(m["loss"])
    c2 = train.TRACE_COUNT["train"]
    return {"traces_first_call": c1 - c0, "traces_after": c2 - c1, "steps": steps + 2,
            "compiles_once": (c1 - c0) <= 1 and c2 == c1}


def donation(cfg: dict, method: str, batch: int, size: int, warmup=2, steps=3, rounds=3,
             done: dict | None = None) -> dict:
    """The library's donated step vs the same step jitted without donation: time and compiled memory.
    `done` may hold an already measured {"donate": train_case(...)} of the same case."""
    res = {}
    for name, fn in (("donate", train.train_step), ("no_donate", NO_DONATE)):
        res[name] = (done or {}).get(name) or train_case(cfg, method, batch, size, warmup, steps, rounds,
                                                         step_fn=fn)
    res["speedup_donate"] = res["no_donate"]["ms"] / res["donate"]["ms"]
    pd, pn = (res[k]["memory"] or {} for k in ("donate", "no_donate"))
    if pd and pn:
        res["peak_bytes_ratio_donate_over_no"] = pd["peak_bytes"] / pn["peak_bytes"]
    return res


def decoder_kinds(preset: str, batch: int, size: int | None = None, warmup=2, steps=3, rounds=3,
                  overrides: dict | None = None, done: dict | None = None) -> dict:
    """dino_rd with the release's decoder (nearest upsample + conv k5) vs the tokens decoder (Dense(4C) +
    depth_to_space) vs no decoder (dino_r), all through the library's train_step."""
    res = {}
    for name, method, kind in (("paper", "dino_rd", "paper"), ("tokens", "dino_rd", "tokens"),
                               ("none", "dino_r", "tokens")):
        cfg = case_cfg(preset, {**(overrides or {}), "model.decoder.kind": kind})
        s = size or cfg["data"]["input_size"]
        res[name] = (done or {}).get(name) or train_case(cfg, method, batch, s, warmup, steps, rounds)
    res["speedup_tokens_over_paper"] = res["paper"]["ms"] / res["tokens"]["ms"]
    res["decoder_share_paper"] = 1 - res["none"]["ms"] / res["paper"]["ms"]
    res["decoder_share_tokens"] = 1 - res["none"]["ms"] / res["tokens"]["ms"]
    return res


def with_dtype(cfg: dict, dtype: str) -> dict:
    """cfg with train.compute_dtype set: the library's own mixed-precision train step."""
    return {**cfg, "train": {**cfg["train"], "compute_dtype": dtype}}


def bf16_speed(cfg: dict, method: str, batch: int, size: int, warmup=2, steps=3, rounds=3,
               done: dict | None = None) -> dict:
    """bfloat16 compute (float32 master weights) vs float32; `done["float32"]` may be the library step
    already measured on the same case (the same computation in float32)."""
    res = {name: (done or {}).get(name) or train_case(with_dtype(cfg, name), method, batch, size, warmup, steps,
                                                      rounds)
           for name in ("float32", "bfloat16")}
    res["speedup_bf16"] = res["float32"]["ms"] / res["bfloat16"]["ms"]
    return res


def paired_ms(cfgs: dict, method: str, batch: int, size: int, steps: int = 3, rounds: int = 5) -> dict:
    """ms per train step (wall and process CPU) of one case under each named cfg, timed in alternating
    blocks of `steps` steps (order reversed every round) so machine load weighs on all alike; medians over
    rounds, and the median of the per-round ratios of each cfg to the first."""
    b = jax.device_put(fake_batch(batch, size))
    states = {}
    for name, cfg in cfgs.items():
        state = train.init_state(cfg, registry.get(method), jax.random.PRNGKey(0), size)
        for _ in range(2):  # compile, then one warm step
            state, m = train.train_step(state, b)
        jax.block_until_ready(m["loss"])
        states[name] = state
    per = {name: [] for name in cfgs}
    for r in range(rounds):
        for name in (list(cfgs) if r % 2 == 0 else list(cfgs)[::-1]):
            t0 = np.array([time.perf_counter(), time.process_time()])
            for _ in range(steps):
                states[name], m = train.train_step(states[name], b)
            jax.block_until_ready(m["loss"])
            per[name].append((np.array([time.perf_counter(), time.process_time()]) - t0) / steps * 1e3)
    first = list(cfgs)[0]
    return {name: {"ms": float(np.median([x[0] for x in v])), "cpu_ms": float(np.median([x[1] for x in v])),
                   "ms_rounds": [float(x[0]) for x in v],
                   f"speed_over_{first}": float(np.median([a[0] / x[0] for a, x in zip(per[first], v)]))}
            for name, v in per.items()}


def bf16_accuracy(cfg: dict, method: str, arrays: dict, val: dict, steps: int, batch: int) -> dict:
    """Train `steps` steps from the same init on the same batch order in float32 and bfloat16 compute;
    compare the training loss curve's tail and the float32-evaluated validation loss / force L1."""
    size = arrays["image"].shape[1]
    n = len(arrays["force"])
    order = np.random.default_rng(0).permutation(np.tile(np.arange(n), steps * batch // n + 1))
    res = {}
    for name in ("float32", "bfloat16"):
        state = train.init_state(with_dtype(cfg, name), registry.get(method), jax.random.PRNGKey(0), size)
        losses = []
        t0 = time.perf_counter()
        for i in range(steps):
            idx = order[i * batch: (i + 1) * batch]
            state, m = train.train_step(state, {k: v[idx] for k, v in arrays.items()})
            losses.append(m["loss"])
        losses = [float(x) for x in jax.device_get(losses)]
        ev = train.eval_step(state, val)
        res[name] = {"train_loss_first10": float(np.mean(losses[:10])),
                     "train_loss_last10": float(np.mean(losses[-10:])),
                     "val_loss": float(ev["loss"]), "val_force_l1": float(ev["force_l1"]),
                     "val_depth_mse": float(ev["depth_mse"]), "wall_s": time.perf_counter() - t0}
    f, b = res["float32"], res["bfloat16"]
    res["steps"], res["batch"] = steps, batch
    res["val_loss_ratio_bf16_over_f32"] = b["val_loss"] / f["val_loss"]
    res["val_force_l1_ratio_bf16_over_f32"] = b["val_force_l1"] / f["val_force_l1"]
    return res
