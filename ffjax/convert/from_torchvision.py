"""torchvision ResNet-18 (BasicBlock) state dicts -> ffjax.models.ResNet params and batch_stats.

BatchNorm weight/bias become params scale/bias; running_mean/var become batch_stats mean/var;
num_batches_tracked and the ImageNet classifier `fc` are dropped on purpose.
"""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np

from ..models import resnet as resnet_lib
from . import kinds, mapping, reader
from .mapping import conv, identity

_BLOCK = r"layer(\d)\.(\d+)\."
_DS = r"layer(\d)\.(\d+)\.downsample\."

TABLE: list[mapping.Rule] = [
    (r"conv1\.weight", "params/conv1/kernel", conv),
    (r"bn1\.weight", "params/bn1/scale", identity),
    (r"bn1\.bias", "params/bn1/bias", identity),
    (r"bn1\.running_mean", "batch_stats/bn1/mean", identity),
    (r"bn1\.running_var", "batch_stats/bn1/var", identity),
    (_BLOCK + r"(conv1|conv2)\.weight", r"params/layer\1_\2/\3/kernel", conv),
    (_BLOCK + r"(bn1|bn2)\.weight", r"params/layer\1_\2/\3/scale", identity),
    (_BLOCK + r"(bn1|bn2)\.bias", r"params/layer\1_\2/\3/bias", identity),
    (_BLOCK + r"(bn1|bn2)\.running_mean", r"batch_stats/layer\1_\2/\3/mean", identity),
    (_BLOCK + r"(bn1|bn2)\.running_var", r"batch_stats/layer\1_\2/\3/var", identity),
    (_DS + r"0\.weight", r"params/layer\1_\2/downsample_0/kernel", conv),
    (_DS + r"1\.weight", r"params/layer\1_\2/downsample_1/scale", identity),
    (_DS + r"1\.bias", r"params/layer\1_\2/downsample_1/bias", identity),
    (_DS + r"1\.running_mean", r"batch_stats/layer\1_\2/downsample_1/mean", identity),
    (_DS + r"1\.running_var", r"batch_stats/layer\1_\2/downsample_1/var", identity),
    (r".*num_batches_tracked", None, identity),
    (r"fc\.(weight|bias)", None, identity),  # ImageNet classifier: not part of the backbone
]


def infer_config(state: dict[str, np.ndarray], source: str = "") -> dict:
    """cfg["model"]["resnet"] read off the state dict: widths per stage and blocks per stage."""
    kinds.check(state, "resnet18", source)
    blocks: dict[int, int] = {}
    widths: dict[int, int] = {}
    for k, v in state.items():
        if m := re.fullmatch(_BLOCK + r"conv1\.weight", k):
            stage, idx = int(m.group(1)), int(m.group(2))
            blocks[stage] = max(blocks.get(stage, 0), idx + 1)
            widths[stage] = int(v.shape[0])
    if sorted(blocks) != [1, 2, 3, 4] or "conv1.weight" not in state:
        raise mapping.ConversionError(source, {"not a 4-stage torchvision ResNet (layer1..layer4)": sorted(blocks)})
    if state["conv1.weight"].shape[2:] != (7, 7):
        raise mapping.ConversionError(source, {"stem conv1 is not 7x7": [str(state["conv1.weight"].shape)]})
    if any(k.endswith("conv3.weight") for k in state):
        raise mapping.ConversionError(source, {"Bottleneck blocks (ResNet-50+) are not supported": ["conv3"]})
    return {
        "widths": tuple(widths[i] for i in (1, 2, 3, 4)),
        "blocks": tuple(blocks[i] for i in (1, 2, 3, 4)),
        "stem": "imagenet",
    }


def expected_variables(cfg_resnet: dict) -> dict:
    model = resnet_lib.from_config(cfg_resnet)
    return jax.eval_shape(model.init, jax.random.PRNGKey(0), jnp.zeros((1, 32, 32, 3)))


def convert_state(state: dict[str, np.ndarray], source: str = "") -> tuple[dict, dict, dict]:
    """A flat torchvision ResNet state dict -> (cfg_resnet, params, batch_stats)."""
    cfg = infer_config(state, source)
    out = mapping.apply(TABLE, state, expected_variables(cfg), source)
    return cfg, out["params"], out["batch_stats"]


def resnet18(path, prefix: str = "") -> tuple[dict, dict, dict]:
    """Convert a torchvision ResNet-18 file -> (cfg["model"]["resnet"], params, batch_stats)."""
    state = reader.read_state_dict(path)
    if prefix:
        state, _ = mapping.fold_prefix(state, prefix)
    return convert_state(state, str(path))
