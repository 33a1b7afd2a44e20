"""Calibration for a new sensor (paper IV-B): fine-tune part of the regressor on ~100 labelled frames.

The backbone stays fixed, so calibrating the regressor on the backbone's features is exactly the same
as fine-tuning the whole model with everything but those layers frozen (BatchNorm in eval mode), at a
fraction of the cost: the features are computed once, then the small head trains on them.

layers="last": the final Linear(->3) and the LayerNorm before it (another unit of the same sensor).
layers="regressor": the whole regressor head (a different kind of sensor, e.g. DIGIT).
A regressor with a feature normalization (model.regressor.feature_norm) keeps its running statistics
(`reg_stats`, the regressor's batch_stats) fixed: 100 presses of one indenter would misstate the
statistics of every other contact. With layers="regressor" its scale and bias train with the rest.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ffjax import metrics
from ffjax.models import heads

LAYERS = ("last", "regressor")


@functools.lru_cache(maxsize=32)
def _feature_fn(model):
    return jax.jit(lambda variables, x: model.apply(variables, x, train=False)["feature"])


def features(model, variables, images, batch_size: int = 64) -> np.ndarray:
    """Backbone features (N, D) of preprocessed images (N, S, S, 3); padded last batch, one compile."""
    return metrics.batched(_feature_fn(model), variables, images, batch_size, width=0)


def trainable_mask(reg_params: dict, layers: str) -> dict:
    """Params-shaped tree of bools: which regressor leaves calibration updates."""
    if layers not in LAYERS:
        raise ValueError(f"layers must be one of {LAYERS}, got {layers!r}")
    n_norms = sum(1 for k in reg_params if k.startswith("norm_"))
    last = {"out", f"norm_{n_norms - 1}"}
    return {k: jax.tree.map(lambda _, k=k: layers == "regressor" or k in last, v) for k, v in reg_params.items()}


def regressor_stats(variables: dict):
    """The regressor's batch_stats in a model's variables (None when its head has no feature normalization)."""
    return (variables.get("batch_stats") or {}).get("regressor")


def _vars(params, stats) -> dict:
    return {"params": params} if not stats else {"params": params, "batch_stats": stats}


def _head(cfg_regressor) -> heads.Regressor:
    return cfg_regressor if isinstance(cfg_regressor, heads.Regressor) else heads.regressor_from_config(cfg_regressor)


@functools.lru_cache(maxsize=16)
def _fit_fns(reg: heads.Regressor, layers: str, lr: float):
    """(optimizer, jitted step) per (head, layers, lr): repeated calibrations reuse the compiled step."""
    abstract = jax.eval_shape(reg.init, jax.random.PRNGKey(0), jnp.zeros((1, 1), jnp.float32))
    # the mask depends only on the param names, which the widths fix (the input dim does not matter)
    mask = trainable_mask(abstract["params"], layers)
    tx = optax.multi_transform(
        {"train": optax.adam(lr), "frozen": optax.set_to_zero()},
        jax.tree.map(lambda m: "train" if m else "frozen", mask),
    )

    @jax.jit
    def step(params, opt_state, stats, x, y):
        def loss_fn(p):
            return jnp.mean(jnp.abs(reg.apply(_vars(p, stats), x) - y))

        loss, grads = jax.value_and_grad(loss_fn)(params)
        updates, opt_state = tx.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, loss

    return tx, step


def fit_regressor(cfg_regressor, reg_params, feats, forces, layers: str = "last", steps: int = 200, lr: float = 1e-4,
                  batch_size: int = 32, seed: int = 0, reg_stats=None):
    """Fine-tune `reg_params` on (features, forces) with L1 loss (the decoder loss is off); returns params.

    cfg_regressor: the checkpoint's cfg["model"]["regressor"] (or a Regressor module). reg_stats: the
    regressor's batch_stats (`regressor_stats(variables)`), needed when it normalizes its features.
    """
    feats, forces = np.asarray(feats, np.float32), np.asarray(forces, np.float32)
    if len(feats) == 0:
        raise ValueError("calibration needs at least one labelled sample")
    if layers not in LAYERS:
        raise ValueError(f"layers must be one of {LAYERS}, got {layers!r}")
    tx, step = _fit_fns(_head(cfg_regressor), layers, float(lr))
    # all on one device and committed, as the step's outputs are: otherwise the second call recompiles
    params = jax.device_put(jax.tree.map(np.asarray, reg_params), jax.devices()[0])
    opt_state = jax.device_put(tx.init(params), jax.devices()[0])
    stats = jax.device_put(jax.tree.map(np.asarray, reg_stats), jax.devices()[0]) if reg_stats else None
    rng = np.random.default_rng(seed)
    bs = min(batch_size, len(feats))
    for _ in range(steps):
        idx = rng.choice(len(feats), bs, replace=False)
        params, opt_state, _ = step(params, opt_state, stats, feats[idx], forces[idx])
    return jax.tree.map(np.asarray, params)


@functools.lru_cache(maxsize=8)
def _regressor_fn(reg: heads.Regressor):
    return jax.jit(reg.apply)


def predict_from_features(cfg_regressor, reg_params, feats, reg_stats=None) -> np.ndarray:
    """Forces (N, 3) from backbone features with the given regressor params (and batch_stats, if it has any)."""
    fn = _regressor_fn(_head(cfg_regressor))
    return np.asarray(fn(_vars(reg_params, reg_stats), np.asarray(feats, np.float32)))


def with_regressor(variables: dict, reg_params) -> dict:
    """A copy of `variables` whose regressor params are replaced (other params shared, not copied)."""
    params = dict(variables["params"])
    params["regressor"] = reg_params
    return {**variables, "params": params}
