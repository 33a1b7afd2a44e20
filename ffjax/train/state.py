"""Train state, parameter labels and the optimizer: an ablation is a label function plus loss weights.

`TrainState` is a pytree: its array fields (step, params, batch_stats, opt_state, key) are what
checkpoints hold; its static fields (model, tx, labels_fn, objective) are part of the tree
structure, so `train_step` compiles once per run and a state rebuilt from the same config reuses
the compiled step.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from ffjax import models
from ffjax.train.objective import Objective

# Groups an optimizer knows about; every parameter leaf gets exactly one of them.
GROUPS = ("backbone", "heads", "frozen")
TRAINABLE = ("all", "heads", "regressor", "last")
# Calibration's "last": the final Linear(->3) and the LayerNorm before it (release naming).
LAST_LAYERS = ("out", "norm_3")
# train.compute_dtype: the dtype of the train step's forward/backward (master weights stay float32)
COMPUTE_DTYPES = ("float32", "bfloat16")


@struct.dataclass
class TrainState:
    step: jax.Array
    params: Any
    batch_stats: Any
    opt_state: Any
    key: jax.Array
    model: nn.Module = struct.field(pytree_node=False)
    tx: optax.GradientTransformation = struct.field(pytree_node=False)
    labels_fn: Callable = struct.field(pytree_node=False)
    # the loss terms and their weights (ffjax/train/objective.py)
    objective: Objective = struct.field(pytree_node=False, default=None)
    # BatchNorm runs in train mode only when the backbone itself trains; a frozen backbone is a
    # fixed feature extractor (running statistics untouched), which is what calibration expects.
    bn_train: bool = struct.field(pytree_node=False, default=True)
    # The regressor's feature normalization uses batch statistics whenever the regressor trains as a whole
    # (a frozen backbone included); calibrating only its last layers keeps them fixed.
    head_bn_train: bool = struct.field(pytree_node=False, default=True)
    # Per-axis weights of the force L1 (mean 1): None = plain newtons; train.force_loss="normalized"
    # weighs each axis by 1 / its training range, as the metric does.
    force_weights: tuple[float, float, float] | None = struct.field(pytree_node=False, default=None)
    # train.compute_dtype: the train step runs forward and backward in this dtype on a cast copy of the
    # params; params, gradients, optimizer state and BatchNorm statistics stay float32. Evaluation is float32.
    compute_dtype: str = struct.field(pytree_node=False, default="float32")
    # the objective's weights as a float32 array: traced, so a weight's value compiles no program of its own
    loss_weights: jax.Array | None = None

    def variables(self) -> dict:
        out = {"params": self.params}
        if self.batch_stats:
            out["batch_stats"] = self.batch_stats
        return out

    def arrays(self) -> dict:
        """The checkpointed part (everything that changes during training)."""
        return {
            "step": self.step,
            "params": self.params,
            "batch_stats": self.batch_stats,
            "opt_state": self.opt_state,
            "key": self.key,
        }

    def with_arrays(self, arrays: dict) -> TrainState:
        return self.replace(**arrays)


@dataclasses.dataclass(frozen=True)
class Labeler:
    """Label function over a params tree: "backbone" | "heads" | "frozen" per leaf.

    trainable="all": the method's own setting (backbone trains unless `frozen_backbone`);
    "heads": backbone frozen, regressor and decoder train; "regressor": only the regressor;
    "last": only regressor/out and regressor/norm_3 (the paper's calibration).
    Frozen dataclass, so equal labelers hash equal and never force a recompile.
    """

    trainable: str = "all"
    frozen_backbone: bool = False

    def __post_init__(self):
        if self.trainable not in TRAINABLE:
            raise ValueError(f"trainable must be one of {TRAINABLE}, got {self.trainable!r}")

    def label(self, path: tuple[str, ...]) -> str:
        top = path[0]
        if self.trainable == "last":
            return "heads" if top == "regressor" and len(path) > 1 and path[1] in LAST_LAYERS else "frozen"
        if self.trainable == "regressor":
            return "heads" if top == "regressor" else "frozen"
        if top == "backbone":
            return "frozen" if (self.frozen_backbone or self.trainable == "heads") else "backbone"
        return "heads"

    def __call__(self, params):
        return jax.tree_util.tree_map_with_path(lambda p, _: self.label(_path_names(p)), params)

    @property
    def backbone_trains(self) -> bool:
        return self.trainable == "all" and not self.frozen_backbone

    @property
    def regressor_trains(self) -> bool:
        """The whole regressor trains (so its feature normalization follows batch statistics)."""
        return self.trainable != "last"


def _path_names(path) -> tuple[str, ...]:
    return tuple(str(getattr(k, "key", getattr(k, "name", k))) for k in path)


def learning_rate(base: float, cfg_train: dict, total_steps: int | None):
    """Constant, or `warmup_cosine` (linear warmup from 0, cosine decay to 0 at `total_steps`).

    The training loop always knows `total_steps`. A state built without it (benchmarks, calibration
    tools timing or fine-tuning a step at a time) gets the warmup and then the peak rate: there is no end
    to decay towards.
    """
    kind = cfg_train["schedule"]
    if kind == "constant":
        return base
    if kind == "warmup_cosine":
        if not total_steps:
            return optax.linear_schedule(0.0, base, max(int(cfg_train["warmup_steps"]), 1))
        warmup = min(int(cfg_train["warmup_steps"]), max(total_steps - 1, 0))
        return optax.warmup_cosine_decay_schedule(
            init_value=0.0, peak_value=base, warmup_steps=warmup, decay_steps=max(total_steps, warmup + 1)
        )
    raise ValueError(f"unknown schedule {kind!r}; use 'constant' or 'warmup_cosine'")


def make_optimizer(cfg_train: dict, labels, total_steps: int | None = None) -> optax.GradientTransformation:
    """Adam (no weight decay) per group: lr_backbone, lr_heads, frozen -> set_to_zero.

    `labels` is a params-shaped tree of group names or a function params -> that tree.
    cfg_train keys: lr_backbone, lr_heads, schedule, warmup_steps, grad_clip (0 = off).
    Equal settings with a hashable `labels` return the same object, so states built twice from one
    config share train_step's compiled program (the optimizer is part of the state's static structure).
    """
    schedule = cfg_train["schedule"]
    key = (
        float(cfg_train["lr_backbone"]),
        float(cfg_train["lr_heads"]),
        schedule,
        int(cfg_train["warmup_steps"]),
        float(cfg_train["grad_clip"]),
        None if schedule == "constant" else total_steps,
    )
    try:
        return _cached_optimizer(key, labels)
    except TypeError:  # unhashable labels (a tree): build a fresh one
        return _build_optimizer(cfg_train, labels, total_steps)


@functools.lru_cache(maxsize=64)
def _cached_optimizer(key: tuple, labels) -> optax.GradientTransformation:
    lr_b, lr_h, schedule, warmup, clip, total = key
    cfg = {
        "lr_backbone": lr_b,
        "lr_heads": lr_h,
        "schedule": schedule,
        "warmup_steps": warmup,
        "grad_clip": clip,
    }
    return _build_optimizer(cfg, labels, total)


def _build_optimizer(cfg_train: dict, labels, total_steps: int | None) -> optax.GradientTransformation:
    groups = {
        "backbone": optax.adam(learning_rate(cfg_train["lr_backbone"], cfg_train, total_steps)),
        "heads": optax.adam(learning_rate(cfg_train["lr_heads"], cfg_train, total_steps)),
        "frozen": optax.set_to_zero(),
    }
    tx = optax.multi_transform(groups, labels)
    clip = float(cfg_train["grad_clip"])
    return optax.chain(optax.clip_by_global_norm(clip), tx) if clip > 0 else tx


def replace_backbone(variables: dict, backbone_params, backbone_stats=None) -> dict:
    """Swap in a pretrained backbone; every leaf's shape must match (all mismatches reported at once)."""
    params = dict(variables["params"])
    if "backbone" not in params:
        raise ValueError("model has no 'backbone' params to initialise")
    _check_same(params["backbone"], backbone_params, "params/backbone")
    params["backbone"] = jax.tree.map(jnp.asarray, backbone_params)
    out = {**variables, "params": params}
    if variables.get("batch_stats", {}).get("backbone") is not None:
        if not backbone_stats:
            raise ValueError("the model's backbone has batch_stats but the pretrained backbone has none")
        _check_same(variables["batch_stats"]["backbone"], backbone_stats, "batch_stats/backbone")
        out["batch_stats"] = {
            **variables["batch_stats"],
            "backbone": jax.tree.map(jnp.asarray, backbone_stats),
        }
    return out


def _check_same(expected, given, where: str) -> None:
    flat_e = {"/".join(_path_names(p)): v.shape for p, v in jax.tree_util.tree_leaves_with_path(expected)}
    flat_g = {"/".join(_path_names(p)): jnp.shape(v) for p, v in jax.tree_util.tree_leaves_with_path(given)}
    problems = [f"missing {k}" for k in flat_e if k not in flat_g]
    problems += [f"unexpected {k}" for k in flat_g if k not in flat_e]
    problems += [
        f"{k}: model {flat_e[k]} vs given {flat_g[k]}" for k in flat_e if k in flat_g and flat_e[k] != flat_g[k]
    ]
    if problems:
        raise ValueError(
            f"pretrained backbone does not fit the model ({where}; same backbone kind and config?):\n  "
            + "\n  ".join(problems)
        )


def init_state(
    cfg: dict,
    spec,
    key: jax.Array,
    input_size: int | None = None,
    *,
    trainable: str = "all",
    labels_fn: Callable | None = None,
    init_backbone: tuple | None = None,
    variables: dict | None = None,
    total_steps: int | None = None,
    cfg_train: dict | None = None,
) -> TrainState:
    """Build the model for `spec`, initialise (or take `variables`), and attach the optimizer.

    init_backbone=(params, batch_stats) replaces params["backbone"]. `labels_fn` overrides the
    label function built from (trainable, spec.frozen_backbone). `cfg_train` overrides cfg["train"]
    (calibration passes its own lr); its compute_dtype (float32 when absent) is the train step's precision.
    The rng key is split: one half initialises, one is carried.
    """
    input_size = int(input_size or cfg["data"]["input_size"])
    model = models.build(cfg["model"], spec, input_size)
    init_key, carry_key = jax.random.split(key)
    if variables is None:
        variables = _compiled_init(model, input_size)(init_key)
    variables = dict(variables)
    if init_backbone is not None:
        variables = replace_backbone(variables, *init_backbone)
    labeler = labels_fn or Labeler(trainable, bool(getattr(spec, "frozen_backbone", False)))
    cfg_train = _scaled_lrs(cfg_train or cfg["train"], spec)
    tx = make_optimizer(cfg_train, labeler, total_steps)
    params = variables["params"]
    compute_dtype = cfg_train["compute_dtype"]
    if compute_dtype not in COMPUTE_DTYPES:
        raise ValueError(f"train.compute_dtype must be one of {COMPUTE_DTYPES}, got {compute_dtype!r}")
    objective = Objective.of(spec)
    return TrainState(
        step=jnp.zeros((), jnp.int32),
        params=params,
        batch_stats=variables.get("batch_stats", {}),
        opt_state=tx.init(params),
        key=carry_key,
        model=model,
        tx=tx,
        labels_fn=labeler,
        objective=objective,
        loss_weights=jnp.asarray(objective.weights, jnp.float32),
        bn_train=getattr(labeler, "backbone_trains", True),
        head_bn_train=getattr(labeler, "regressor_trains", True),
        force_weights=force_weights(cfg, cfg_train),
        compute_dtype=compute_dtype,
    )


FORCE_LOSSES = ("newton", "normalized")


def force_weights(cfg: dict, cfg_train: dict) -> tuple[float, float, float] | None:
    """Per-axis weights of the force loss for train.force_loss, or None for plain newtons.

    "normalized": 1 / training range per axis (the metric's normalization), scaled to mean 1 so the loss
    stays in newton-like units and the terms' weights keep their meaning. The range is the regressor's out_scale
    (half the training range), so it needs model.regressor.normalize_output. A state built outside the
    training loop (benchmarks, tests), before the loop fills out_scale from the labels, weighs axes equally.
    """
    kind = cfg_train["force_loss"]
    if kind not in FORCE_LOSSES:
        raise ValueError(f"train.force_loss must be one of {FORCE_LOSSES}, got {kind!r}")
    if kind == "newton":
        return None
    rc = cfg["model"]["regressor"]
    scale = rc["out_scale"]
    if scale is None and rc["normalize_output"]:
        return None
    if scale is None:
        raise ValueError("train.force_loss='normalized' needs the training force range: set "
                         "model.regressor.normalize_output=True (training fills out_scale from the labels)")
    inv = [1.0 / float(v) for v in scale]
    return tuple(v * len(inv) / sum(inv) for v in inv)


def abstract_state(cfg: dict, spec, input_size: int | None = None, **kw) -> TrainState:
    """The TrainState's shapes and dtypes (jax.ShapeDtypeStruct leaves) without allocating or compiling:
    for restore targets and for checking paper-scale configs (`jax.eval_shape(train_step, state, batch)`)."""
    size = int(input_size or cfg["data"]["input_size"])
    model = models.build(cfg["model"], spec, size)

    def build(key):
        variables = model.init(key, jnp.zeros((1, size, size, 3), jnp.float32), train=False)
        return init_state(cfg, spec, key, size, variables=variables, **kw)

    return jax.eval_shape(build, jax.random.PRNGKey(0))


@functools.lru_cache(maxsize=16)
def _compiled_init(model: nn.Module, input_size: int):
    """model.init compiled once per model config. It runs once per run, so XLA's backend optimisation is
    off: a third of the compile time (an eager init would compile each of its ~200 ops separately)."""
    dummy = jax.ShapeDtypeStruct((1, input_size, input_size, 3), jnp.float32)
    lowered = jax.jit(lambda k, x: model.init(k, x, train=False)).lower(jax.random.PRNGKey(0), dummy)
    compiled = lowered.compile({"xla_backend_optimization_level": 0})
    zeros = jnp.zeros(dummy.shape, dummy.dtype)
    return lambda key: compiled(key, zeros)


def _scaled_lrs(cfg_train: dict, spec) -> dict:
    """Methods may scale the config's learning rates (registry fields lr_*_scale; 1 when absent)."""
    out = dict(cfg_train)
    out["lr_backbone"] = float(out["lr_backbone"]) * float(getattr(spec, "lr_backbone_scale", 1.0))
    out["lr_heads"] = float(out["lr_heads"]) * float(getattr(spec, "lr_heads_scale", 1.0))
    return out
