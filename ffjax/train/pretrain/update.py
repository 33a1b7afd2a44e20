"""The DINO update: schedules (lr, teacher momentum and temperature), optimizer, state, the loss and the pure
step `update(state, batch, key)` (jitted once by the caller), with its collapse monitors.

The student matches the teacher's centred, sharpened distribution across multi-crop views; the teacher is an
EMA of the student (Caron et al. 2021).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import optax

from ffjax.train.pretrain.model import build


def schedules(p: dict):
    """lr, teacher momentum (cosine 0.996 -> 1) and teacher temperature (linear warmup) per step."""
    steps = max(int(p["steps"]), 1)
    lr = optax.warmup_cosine_decay_schedule(0.0, p["lr"], min(int(p["warmup_steps"]), steps - 1) or 0,
                                            steps, p["lr"] * p["min_lr_ratio"])

    def momentum(step):
        return 1 - (1 - p["momentum"]) * (jnp.cos(jnp.pi * jnp.minimum(step, steps) / steps) + 1) / 2

    def teacher_temp(step):
        w = max(int(p["teacher_temp_warmup"]), 1)
        frac = jnp.minimum(step / w, 1.0)
        return p["teacher_temp_start"] + frac * (p["teacher_temp"] - p["teacher_temp_start"])

    return lr, momentum, teacher_temp


def make_optimizer(p: dict):
    lr, _, _ = schedules(p)
    decay_mask = partial(jax.tree.map, lambda x: x.ndim > 1)  # no weight decay on biases / norms
    return optax.chain(optax.clip_by_global_norm(p["grad_clip"]),
                       optax.adamw(lr, weight_decay=p["weight_decay"], mask=decay_mask))


def init_state(cfg: dict, kind: str, key) -> dict:
    """{"step", "student": {params, batch_stats}, "teacher": {...}, "opt_state", "center"} (a pytree)."""
    model, p = build(cfg, kind), cfg["pretrain"]
    S = int(cfg["data"]["input_size"])
    variables = model.init(key, jnp.zeros((2, S, S, 3)), train=False)
    student = {"params": variables["params"], "batch_stats": variables.get("batch_stats", {})}
    teacher = jax.tree.map(jnp.array, student)  # a copy, not an alias (the step donates its input)
    return {"step": jnp.zeros((), jnp.int32), "student": student, "teacher": teacher,
            "opt_state": make_optimizer(p).init(student["params"]),
            "center": jnp.zeros((1, int(p["out_dim"])), jnp.float32)}


def _apply(model, vars_, images, train: bool):
    """(logits, features, new batch_stats); ResNet BatchNorm state threads through functionally."""
    if vars_["batch_stats"]:
        (logits, feat), upd = model.apply({"params": vars_["params"], "batch_stats": vars_["batch_stats"]},
                                          images, train=train, mutable=["batch_stats"])
        return logits, feat, upd["batch_stats"]
    logits, feat = model.apply({"params": vars_["params"]}, images, train=train)
    return logits, feat, vars_["batch_stats"]


def dino_loss(student_logits, teacher_probs, student_temp: float):
    """Cross-entropy of every student view against every teacher (global) view but its own.
    student_logits (V,B,K), teacher_probs (2,B,K)."""
    logp = jax.nn.log_softmax(student_logits / student_temp, axis=-1)
    total, terms = 0.0, 0
    for iq in range(teacher_probs.shape[0]):
        for v in range(student_logits.shape[0]):
            if v == iq:
                continue
            total += jnp.mean(-jnp.sum(teacher_probs[iq] * logp[v], axis=-1))
            terms += 1
    return total / terms


def _noisy(x, key, level: float):
    """Camera-like Gaussian pixel noise, a random strength per view (in normalized units)."""
    ks, kn = jax.random.split(key)
    return x + level * jax.random.uniform(ks, (x.shape[0], 1, 1, 1)) * jax.random.normal(kn, x.shape)


def make_update(cfg: dict, kind: str):
    """update(state, batch, key) -> (state, metrics): the pure DINO step (jit it once). batch = multicrop's
    views; key draws the per-view pixel noise."""
    model, p = build(cfg, kind), cfg["pretrain"]
    tx = make_optimizer(p)
    lr_fn, momentum_fn, temp_fn = schedules(p)
    freeze_last = int(p["freeze_last_steps"])

    def update(state, batch, key):
        step = state["step"]
        kg, kl = jax.random.split(jax.random.fold_in(key, step))
        glob, loc = _noisy(batch["global"], kg, p["noise"]), batch.get("local")
        loc = None if loc is None else _noisy(loc, kl, p["noise"])
        B = glob.shape[0] // 2
        t_logits, _, t_stats = _apply(model, state["teacher"], glob, train=True)
        t_logits = jax.lax.stop_gradient(t_logits)
        t_probs = jax.nn.softmax((t_logits - state["center"]) / temp_fn(step), axis=-1).reshape(2, B, -1)

        def loss_fn(params):
            vars_ = {"params": params, "batch_stats": state["student"]["batch_stats"]}
            g_logits, feat, stats = _apply(model, vars_, glob, train=True)
            logits = [g_logits.reshape(2, B, -1)]
            if loc is not None:
                l_logits, _, stats = _apply(model, {"params": params, "batch_stats": stats}, loc, train=True)
                logits.append(l_logits.reshape(-1, B, l_logits.shape[-1]))
            loss = dino_loss(jnp.concatenate(logits, 0), t_probs, p["student_temp"])
            return loss, (feat, stats)

        (loss, (feat, s_stats)), grads = jax.value_and_grad(loss_fn, has_aux=True)(state["student"]["params"])
        # DINO keeps the prototype layer fixed for the first steps: it stabilises the start
        protos = jnp.where(step < freeze_last, 0.0, grads["head"]["prototypes"])
        grads = {**grads, "head": {**grads["head"], "prototypes": protos}}
        updates, opt_state = tx.update(grads, state["opt_state"], state["student"]["params"])
        params = optax.apply_updates(state["student"]["params"], updates)
        m = momentum_fn(step)
        t_params = jax.tree.map(lambda t, s: m * t + (1 - m) * s, state["teacher"]["params"], params)
        center = p["center_momentum"] * state["center"] + (1 - p["center_momentum"]) * t_logits.mean(0, keepdims=True)
        metrics = {"loss": loss, "lr": lr_fn(step), "momentum": m, "teacher_temp": temp_fn(step),
                   **_collapse_monitors(t_probs, feat)}
        new = {"step": step + 1, "student": {"params": params, "batch_stats": s_stats},
               "teacher": {"params": t_params, "batch_stats": t_stats}, "opt_state": opt_state,
               "center": center}
        return new, metrics

    return update


def _collapse_monitors(t_probs, feat) -> dict:
    """Per-sample teacher entropy falls with sharpening; the entropy of the batch-mean distribution stays high
    unless every image maps to the same prototypes; a collapsed backbone's normalized features stop varying."""
    mean_probs = t_probs.mean((0, 1))
    featn = feat / (jnp.linalg.norm(feat, axis=-1, keepdims=True) + 1e-6)
    return {
        "teacher_entropy": -jnp.sum(t_probs * jnp.log(t_probs + 1e-12), -1).mean(),
        "teacher_batch_entropy": -jnp.sum(mean_probs * jnp.log(mean_probs + 1e-12)),
        "feature_std": featn.std(0).mean(),
    }
