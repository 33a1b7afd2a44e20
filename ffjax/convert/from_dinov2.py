"""DINOv2 torch-hub ViT state dicts -> ffjax.models.ViT params.

Accepts the official `dinov2_vit{s,b,l}14_pretrain.pth` files (no registers, MLP FFN) and any state dict
with the same names (optionally under a prefix, e.g. the FeelAnyForce release's "tactile_backbone.").
The position table keeps the checkpoint's grid (37x37 for the hub models, trained at 518 px) as
`pos_grid`; the model interpolates it to the input grid like DINOv2 (bicubic, interpolate_offset 0.1).
"""

from __future__ import annotations

import math
import re

import jax
import jax.numpy as jnp
import numpy as np

from ..models import vit as vit_lib
from . import kinds, mapping, reader
from .mapping import conv, identity, linear

_B = r"blocks\.(?:\d+\.)?(\d+)\."  # "blocks.N." or the FSDP-chunked "blocks.C.N."

TABLE: list[mapping.Rule] = [
    (r"patch_embed\.proj\.weight", "patch_embed/proj/kernel", conv),
    (r"patch_embed\.proj\.bias", "patch_embed/proj/bias", identity),
    (r"cls_token", "cls_token", identity),
    (r"pos_embed", "pos_embed", identity),
    (r"mask_token", None, identity),  # used only by iBOT masking during DINOv2 pretraining
    (_B + r"(norm1|norm2)\.weight", r"blocks_\1/\2/scale", identity),
    (_B + r"(norm1|norm2)\.bias", r"blocks_\1/\2/bias", identity),
    (_B + r"attn\.(qkv|proj)\.weight", r"blocks_\1/attn/\2/kernel", linear),
    (_B + r"attn\.(qkv|proj)\.bias", r"blocks_\1/attn/\2/bias", identity),
    (_B + r"(ls1|ls2)\.gamma", r"blocks_\1/\2/gamma", identity),
    (_B + r"mlp\.(fc1|fc2)\.weight", r"blocks_\1/mlp/\2/kernel", linear),
    (_B + r"mlp\.(fc1|fc2)\.bias", r"blocks_\1/mlp/\2/bias", identity),
    (r"norm\.weight", "norm/scale", identity),
    (r"norm\.bias", "norm/bias", identity),
    (r"head\.(weight|bias)", None, identity),  # hub backbones have an Identity head; a linear one is dropped
]

# heads of the hub models by name; otherwise DINOv2's head dim 64 is assumed
HUB_HEADS = {"vits14": 6, "vitb14": 12, "vitl14": 16, "vitg14": 24}


def infer_config(state: dict[str, np.ndarray], heads: int | None = None, source: str = "") -> dict:
    """cfg["model"]["vit"] read off a DINOv2 state dict's shapes (heads: given, or dim // 64)."""
    kinds.check(state, "dinov2", source)
    need = ("patch_embed.proj.weight", "pos_embed", "blocks.0.mlp.fc1.weight")
    missing = [k for k in need if k not in state]
    if missing:
        raise mapping.ConversionError(source, {"missing DINOv2 keys needed to infer the config": missing})
    dim, _, patch, _ = state["patch_embed.proj.weight"].shape
    n = state["pos_embed"].shape[1] - 1
    grid = math.isqrt(n)
    if grid * grid != n:
        raise mapping.ConversionError(source, {"pos_embed is not a square grid (+1 cls)": [str(n)]})
    depth = 1 + max(int(m.group(1)) for k in state if (m := re.match(_B, k)))
    valid = ", ".join(str(h) for h in range(1, dim + 1) if dim % h == 0)
    if heads is None:
        if dim % 64:
            raise ValueError(f"{source}: embed dim {dim} is not a multiple of 64, so its attention heads are not "
                             f"known; pass heads= (CLI: --heads), one that divides {dim}: {valid}")
        heads = dim // 64
    if heads < 1 or dim % heads:
        raise ValueError(f"{source}: --heads {heads} (heads=) must divide the ViT width {dim}: use one of {valid}")
    return {
        "dim": int(dim),
        "depth": int(depth),
        "heads": int(heads),
        "patch": int(patch),
        "mlp_ratio": float(state["blocks.0.mlp.fc1.weight"].shape[0] / dim),
        "layerscale": 1e-5,
        "pos_grid": int(grid),
        "interpolate_offset": 0.1,
    }


def expected_params(cfg_vit: dict) -> dict:
    """Abstract (shape-only) ViT params for `cfg_vit`; nothing is allocated."""
    model = vit_lib.from_config(cfg_vit)
    s = cfg_vit["patch"] * 2
    shapes = jax.eval_shape(model.init, jax.random.PRNGKey(0), jnp.zeros((1, s, s, 3)))
    return shapes["params"]


def convert_state(state: dict[str, np.ndarray], heads: int | None = None, source: str = "") -> tuple[dict, dict]:
    """A flat DINOv2 state dict -> (cfg_vit, params)."""
    cfg = infer_config(state, heads, source)
    return cfg, mapping.apply(TABLE, state, expected_params(cfg), source)


def dinov2(path, heads: int | None = None, prefix: str = "") -> tuple[dict, dict]:
    """Convert a DINOv2 checkpoint file -> (cfg["model"]["vit"], ViT params as numpy arrays).

    heads: attention heads (default: from the file name "vit{s,b,l,g}14", else embed dim // 64).
    prefix: take only keys under this prefix (e.g. "backbone.").
    """
    state = reader.read_state_dict(path)
    if prefix:
        state, _ = mapping.fold_prefix(state, prefix)
    if heads is None:
        heads = next((h for name, h in HUB_HEADS.items() if name in str(path)), None)
    return convert_state(state, heads, str(path))
