"""DINOv2-style Vision Transformer (no registers), laid out so torch-hub DINOv2 weights map one to one.

Flax path <- DINOv2 key (torch `a.N.b` becomes flax `a_N/b`; Dense kernel = torch weight.T,
Conv kernel = torch weight.permute(2, 3, 1, 0), LayerNorm scale/bias = weight/bias):
  patch_embed/proj/{kernel,bias}      <- patch_embed.proj.{weight,bias}
  cls_token (1,1,D), pos_embed (1,1+G*G,D) <- cls_token, pos_embed  (mask_token is unused)
  blocks_N/norm1, blocks_N/attn/qkv, blocks_N/attn/proj, blocks_N/ls1/gamma,
  blocks_N/norm2, blocks_N/mlp/fc1, blocks_N/mlp/fc2, blocks_N/ls2/gamma, norm
"""

from __future__ import annotations

import math
from functools import lru_cache

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

LN_EPS = 1e-6  # DINOv2's LayerNorm eps
_dense_init = nn.initializers.truncated_normal(0.02)

_DINOV2 = {"patch": 14, "mlp_ratio": 4.0, "layerscale": 1e-5, "pos_grid": 37}  # hub models: 518/14 = 37
PRESETS = {
    "s14": {"dim": 384, "depth": 12, "heads": 6, **_DINOV2},
    "b14": {"dim": 768, "depth": 12, "heads": 12, **_DINOV2},
}


def vit_config(name: str) -> dict:
    """cfg["model"]["vit"] for DINOv2 ViT-S/14 ("s14") or ViT-B/14 ("b14"), pos table 37x37 as released."""
    if name not in PRESETS:
        raise ValueError(f"unknown ViT preset {name!r}; choose one of {', '.join(PRESETS)}")
    return dict(PRESETS[name])


def _cubic(t: np.ndarray, a: float = -0.75) -> np.ndarray:
    """Keys cubic kernel with torch's a=-0.75 (jax.image.resize uses -0.5, so it would not match DINOv2)."""
    t = np.abs(t)
    return np.where(
        t <= 1,
        ((a + 2) * t - (a + 3)) * t * t + 1,
        np.where(t < 2, ((a * t - 5 * a) * t + 8 * a) * t - 4 * a, 0.0),
    )


@lru_cache(maxsize=64)
def bicubic_matrix(n_in: int, n_out: int, scale: float) -> np.ndarray:
    """(n_out, n_in) matrix of torch `interpolate(mode="bicubic", align_corners=False)` along one axis.

    `scale` is torch's output/input scale factor; the source coordinate is (i + 0.5) / scale - 0.5,
    taps are clamped at the border, as torch does.
    """
    src = (np.arange(n_out) + 0.5) / scale - 0.5
    base = np.floor(src).astype(int)
    frac = src - base
    m = np.zeros((n_out, n_in), np.float64)
    for k in range(-1, 3):
        idx = np.clip(base + k, 0, n_in - 1)
        np.add.at(m, (np.arange(n_out), idx), _cubic(frac - k))
    return m.astype(np.float32)


def interpolate_pos_embed(pos: jax.Array, grid: tuple[int, int], offset: float = 0.1) -> jax.Array:
    """Resample a (1, 1+M*M, D) position table to `grid` (h, w) like DINOv2's interpolate_pos_encoding.

    DINOv2 passes scale_factor=(h + 0.1)/M ("interpolate_offset", a historical kludge kept for weight
    compatibility); offset=0 gives a plain size-based resize. Identity when the grid already matches.
    """
    n = pos.shape[1] - 1
    m = int(round(math.sqrt(n)))
    assert m * m == n, f"pos_embed holds {n} patch positions, not a square grid"
    h, w = grid
    if (h, w) == (m, m):
        return pos
    scale = ((h + offset) / m, (w + offset) / m) if offset else (h / m, w / m)
    mh = jnp.asarray(bicubic_matrix(m, h, scale[0]))
    mw = jnp.asarray(bicubic_matrix(m, w, scale[1]))
    patch = pos[0, 1:].reshape(m, m, -1).astype(jnp.float32)
    patch = jnp.einsum("hi,wj,ijd->hwd", mh, mw, patch).reshape(1, h * w, -1)
    return jnp.concatenate([pos[:, :1], patch.astype(pos.dtype)], axis=1)


class PatchEmbed(nn.Module):
    dim: int
    patch: int

    @nn.compact
    def __call__(self, x):
        p = self.patch
        return nn.Conv(self.dim, (p, p), strides=(p, p), padding="VALID", name="proj")(x)


class Attention(nn.Module):
    """Fused-qkv einsum attention (a faster forward than nn.MultiHeadDotProductAttention on CPU)."""

    dim: int
    heads: int

    @nn.compact
    def __call__(self, x):
        b, n, _ = x.shape
        hd = self.dim // self.heads
        # torch layout: qkv output is [q | k | v], each heads x head_dim
        qkv = nn.Dense(3 * self.dim, kernel_init=_dense_init, name="qkv")(x).reshape(b, n, 3, self.heads, hd)
        q, k, v = qkv[:, :, 0], qkv[:, :, 1], qkv[:, :, 2]
        logits = jnp.einsum("bqhd,bkhd->bhqk", q * (hd**-0.5), k)
        attn = jax.nn.softmax(logits.astype(jnp.float32), axis=-1).astype(x.dtype)
        out = jnp.einsum("bhqk,bkhd->bqhd", attn, v).reshape(b, n, self.dim)
        return nn.Dense(self.dim, kernel_init=_dense_init, name="proj")(out)


class LayerScale(nn.Module):
    init_value: float

    @nn.compact
    def __call__(self, x):
        gamma = self.param("gamma", nn.initializers.constant(self.init_value), (x.shape[-1],))
        return x * gamma.astype(x.dtype)


class Mlp(nn.Module):
    hidden: int

    @nn.compact
    def __call__(self, x):
        d = x.shape[-1]
        x = nn.Dense(self.hidden, kernel_init=_dense_init, name="fc1")(x)
        x = nn.gelu(x, approximate=False)  # torch nn.GELU default is the exact erf form
        return nn.Dense(d, kernel_init=_dense_init, name="fc2")(x)


class Block(nn.Module):
    dim: int
    heads: int
    mlp_ratio: float
    layerscale: float

    @nn.compact
    def __call__(self, x):
        y = Attention(self.dim, self.heads, name="attn")(nn.LayerNorm(LN_EPS, name="norm1")(x))
        x = x + LayerScale(self.layerscale, name="ls1")(y)
        y = Mlp(int(self.dim * self.mlp_ratio), name="mlp")(nn.LayerNorm(LN_EPS, name="norm2")(x))
        return x + LayerScale(self.layerscale, name="ls2")(y)


class ViT(nn.Module):
    """images (B,S,S,3) -> {"feature": final-norm CLS (B,D), "tokens": final-norm patch tokens (B,h,w,D)}.

    pos_grid: side of the learned position table (DINOv2 checkpoints: 37); None = the input grid.
    """

    dim: int
    depth: int
    heads: int
    patch: int
    mlp_ratio: float = 4.0
    layerscale: float = 1e-5
    pos_grid: int | None = None
    interpolate_offset: float = 0.1

    @nn.compact
    def __call__(self, images, train: bool = False):
        del train  # no dropout / stochastic depth: kept for a uniform backbone signature
        x = PatchEmbed(self.dim, self.patch, name="patch_embed")(images)
        b, h, w, d = x.shape
        x = x.reshape(b, h * w, d)
        g = self.pos_grid or h
        cls = self.param("cls_token", nn.initializers.normal(1e-6), (1, 1, d))
        pos = self.param("pos_embed", _dense_init, (1, 1 + g * g, d))
        x = jnp.concatenate([jnp.broadcast_to(cls, (b, 1, d)).astype(x.dtype), x], axis=1)
        x = x + interpolate_pos_embed(pos, (h, w), self.interpolate_offset).astype(x.dtype)
        for i in range(self.depth):
            x = Block(self.dim, self.heads, self.mlp_ratio, self.layerscale, name=f"blocks_{i}")(x)
        x = nn.LayerNorm(LN_EPS, name="norm")(x)
        return {"feature": x[:, 0], "tokens": x[:, 1:].reshape(b, h, w, d)}


def from_config(cfg_vit: dict) -> ViT:
    """Build a ViT from cfg["model"]["vit"]."""
    return ViT(
        dim=cfg_vit["dim"],
        depth=cfg_vit["depth"],
        heads=cfg_vit["heads"],
        patch=cfg_vit["patch"],
        mlp_ratio=float(cfg_vit["mlp_ratio"]),
        layerscale=float(cfg_vit["layerscale"]),
        pos_grid=cfg_vit["pos_grid"],
        interpolate_offset=float(cfg_vit["interpolate_offset"]),
    )
