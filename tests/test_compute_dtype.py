"""train.compute_dtype="bfloat16": every distinct code path of the registry (ViT and ResNet with its BatchNorm,
trained and frozen, with each decoder and without one) trains with float32 master weights, and a short run lands
within a stated tolerance of the float32 run. Entries that differ only in their weights' start (dino_rd_scratch)
or in a path another case already covers are not run again: each is a compile of its own."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_train import fixed_batch

import configs
from ffjax import registry, train

# A short bf16 run's float32-evaluated validation loss stays within this fraction of the float32 run's.
VAL_LOSS_TOLERANCE = 0.10


def _bf16_cfg(extra=None):
    return configs.get("smoke", {"train.compute_dtype": "bfloat16", **(extra or {})})


def _dtypes(tree):
    return {str(x.dtype) for x in jax.tree.leaves(tree) if jnp.issubdtype(x.dtype, jnp.floating)}


# (method, decoder): the paper decoder on the ResNet and the trained and frozen ViT, the ViT without a decoder
STEP_PATHS = [("resnet_rd", "paper"), ("dino_rd", "paper"), ("dino_f_rd", "paper"), ("dino_r", "tokens")]
# with the default (token) decoder: the ResNet and the trained ViT, and the frozen ViT without one; these short runs
# also check the state's dtypes, so their step paths are not compiled a second time above
LOSS_PATHS = ["resnet_rd", "dino_rd", "dino_f_r"]


def _path(name: str) -> tuple:
    spec = registry.get(name)
    return spec.backbone, spec.frozen_backbone, spec.depth_head


def test_the_cases_cover_every_path_of_the_registry():
    """A registry entry added with a new (backbone, frozen, decoder) combination needs a case of its own."""
    assert {_path(n) for n, _ in STEP_PATHS} | {_path(n) for n in LOSS_PATHS} == set(map(_path, registry.names()))


@pytest.mark.parametrize("name, decoder", STEP_PATHS)
def test_bf16_step_runs_for_every_path_and_keeps_float32_state(name, decoder):
    spec = registry.get(name)
    cfg = _bf16_cfg({"model.decoder.kind": decoder})
    state = train.init_state(cfg, spec, jax.random.PRNGKey(0))
    assert state.compute_dtype == "bfloat16"
    for _ in range(2):
        state, m = train.train_step(state, fixed_batch(cfg))
    _check_float32_state(state, m)
    ev = train.eval_step(state, {**fixed_batch(cfg), "mask": np.ones(8, np.float32)})
    assert ev["force"].dtype == np.float32


def _check_float32_state(state, metrics):
    """A finite loss, a gradient, and float32 master weights, optimizer moments and BatchNorm running statistics."""
    assert np.isfinite(float(metrics["loss"])) and float(metrics["grad_norm"]) > 0
    assert _dtypes(state.params) == {"float32"}
    assert _dtypes(state.opt_state) <= {"float32"}
    assert _dtypes(state.batch_stats) <= {"float32"}


def _short_run(cfg, name, steps=30):
    """(the final state, its last step's metrics, the validation loss evaluated in float32)."""
    state = train.init_state(cfg, registry.get(name), jax.random.PRNGKey(0))
    for i in range(steps):
        state, m = train.train_step(state, fixed_batch(cfg, seed=i % 4))
    val = {**fixed_batch(cfg, seed=99), "mask": np.ones(8, np.float32)}
    ev = train.eval_step(state, val)
    assert ev["force"].dtype == np.float32
    return state, m, float(ev["loss"])


@pytest.mark.parametrize("name", LOSS_PATHS)
def test_bf16_validation_loss_within_tolerance_of_float32(name):
    *_, f32 = _short_run(configs.get("smoke"), name)
    state, m, bf16 = _short_run(_bf16_cfg(), name)
    assert state.compute_dtype == "bfloat16"
    _check_float32_state(state, m)
    assert abs(bf16 - f32) <= VAL_LOSS_TOLERANCE * f32, (bf16, f32)


def test_unknown_compute_dtype_is_refused_by_name():
    with pytest.raises(ValueError, match="compute_dtype"):
        configs.get("smoke", {"train.compute_dtype": "float16"})
