"""The pure training and evaluation steps, each jitted once, and data-parallel placement.

The loss and the metrics it logs are the state's objective (ffjax/train/objective.py: the terms, each
declared once, weighted by the method's fields); the step returns {"loss", <one per term>, "grad_norm"}.
Data parallel: the batch is sharded along a 1-D mesh of all devices and the state is replicated;
XLA inserts the gradient all-reduce, so the numbers equal a single-device step up to float
summation order. One device is the degenerate mesh.
Mixed precision (train.compute_dtype="bfloat16", state.compute_dtype): the train step runs forward and
backward on a bfloat16 copy of the float32 params and images; outputs return to float32 before the losses,
so gradients, Adam and the updates stay float32 (master weights), as do BatchNorm's running statistics.
Evaluation always runs in float32.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ffjax.train.state import TrainState

# Incremented at trace time only: tests use it to check the step compiles once.
TRACE_COUNT = {"train": 0, "eval": 0}


def _forward(state: TrainState, params, images, train: bool, key):
    """train: a training step. The backbone and the heads' normalization each follow batch statistics
    only when they train (state.bn_train, state.head_bn_train)."""
    variables = {"params": params}
    if state.batch_stats:
        variables["batch_stats"] = state.batch_stats
    mutable = ["batch_stats"] if (train and state.batch_stats) else False
    res = state.model.apply(variables, images, train=train and state.head_bn_train,
                            backbone_train=train and state.bn_train, rngs={"dropout": key}, mutable=mutable)
    if mutable:
        out, updates = res
        return out, updates["batch_stats"]
    return res, state.batch_stats


def _losses(state: TrainState, out, batch, weights=None):
    """(loss, {term name: batch mean}) of the state's objective; `weights` (B,) masks padded rows in evaluation."""
    return state.objective.losses(state, out, batch, weights)


def _mixed_forward(state: TrainState, params, images, key):
    """The training forward in state.compute_dtype: the cast sits inside the differentiated function, so
    gradients reach the float32 params in float32. float32 takes the plain path (no casts traced at all)."""
    if state.compute_dtype == "float32":
        return _forward(state, params, images, True, key)
    dtype = jnp.dtype(state.compute_dtype)
    out, new_stats = _forward(state, _cast(params, dtype), images.astype(dtype), True, key)
    # losses in float32 (a bf16 MSE over a whole depth map loses the small residuals); running statistics
    # keep their float32 dtype (flax reduces in float32 already; the cast makes it a guarantee)
    out = _cast(out, jnp.float32)
    new_stats = jax.tree.map(lambda n, o: n.astype(o.dtype), new_stats, state.batch_stats)
    return out, new_stats


def _cast(tree, dtype):
    return jax.tree.map(lambda x: x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


def _train_step(state: TrainState, batch: dict):
    TRACE_COUNT["train"] += 1
    labels = state.labels_fn(state.params)
    key = jax.random.fold_in(state.key, state.step)

    def loss_fn(params):
        # Frozen leaves get stop_gradient: their backward pass is never built (a frozen backbone
        # costs a forward only), and set_to_zero keeps them fixed.
        params = jax.tree.map(lambda p, l: jax.lax.stop_gradient(p) if l == "frozen" else p, params, labels)
        out, new_stats = _mixed_forward(state, params, batch["image"], key)
        loss, terms = _losses(state, out, batch)
        return loss, (terms, new_stats)

    (loss, (terms, new_stats)), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params)
    updates, opt_state = state.tx.update(grads, state.opt_state, state.params)
    params = optax.apply_updates(state.params, updates)
    grad_norm = optax.tree.norm(grads)
    finite = jnp.isfinite(loss) & jnp.isfinite(grad_norm)
    # A non-finite step never reaches the state (as optax.apply_if_finite): params, optimizer and batch
    # stats stay as they were, only the step (and with it the dropout key) moves on. The loop reads
    # loss and grad_norm with the other metrics, at its existing sync points, and stops or goes on
    # (train.nonfinite): no extra output, no extra host sync.
    kept = _select(finite, (params, opt_state, new_stats), (state.params, state.opt_state, state.batch_stats))
    metrics = {"loss": loss, **terms, "grad_norm": grad_norm}
    new_state = state.replace(step=state.step + 1, params=kept[0], opt_state=kept[1], batch_stats=kept[2])
    return new_state, metrics


def _select(ok, new, old):
    return jax.tree.map(lambda a, b: jnp.where(ok, a, b), new, old)


def _eval_step(state: TrainState, batch: dict):
    TRACE_COUNT["eval"] += 1
    out, _ = _forward(state, state.params, batch["image"], False, state.key)
    weights = batch.get("mask")
    loss, terms = _losses(state, out, batch, weights)
    return {"loss": loss, **terms, "force": out["force"]}


def _feature_step(state: TrainState, images):
    out, _ = _forward(state, state.params, images, False, state.key)
    return out["feature"]


# train_step(state, batch) -> (state, {loss, <each objective term>, grad_norm}); the input state is donated.
# When loss or grad_norm is NaN/inf that step's update is dropped (the step counter still moves on).
train_step = jax.jit(_train_step, donate_argnums=0)
# eval_step(state, batch) -> {loss, <each objective term>, force (B,3)}; an optional batch["mask"] (B,)
# weights rows, so a padded last batch averages over its real rows only.
eval_step = jax.jit(_eval_step)
# feature_step(state, images) -> the backbone feature (B, D) in evaluation mode
feature_step = jax.jit(_feature_step)


def make_mesh(devices=None) -> Mesh:
    """1-D mesh ("data",) over all (or the given) devices."""
    return Mesh(np.asarray(devices if devices is not None else jax.devices()), ("data",))


def replicate(tree, mesh: Mesh):
    """Replicate a state over the mesh. On a 1-device mesh arrays stay uncommitted (placed like plain jax
    arrays), so the loop, a resumed run and direct train_step calls all share one compiled step."""
    if mesh.devices.size == 1:
        return jax.tree.map(jnp.asarray, jax.device_get(tree))
    return jax.device_put(tree, NamedSharding(mesh, PartitionSpec()))


def shard_batch(batch: dict, mesh: Mesh) -> dict:
    """Put a host batch on the mesh, split along axis 0 (the batch must divide by the device count)."""
    n = mesh.devices.size
    b = len(next(iter(batch.values())))
    if b % n:
        raise ValueError(f"batch size {b} is not divisible by the {n} devices of the mesh")
    if n == 1:
        return batch
    return jax.device_put(batch, NamedSharding(mesh, PartitionSpec("data")))
