"""Force regressor and depth decoders (the release's "paper" decoder and a light "tokens" decoder).

Flax path <- release (FeelAnyForce checkpoint) meaning; WeightNormDense holds v (in,out) = weight_v.T,
g (out,) = weight_g[:, 0], bias:
  regressor/fc_i, regressor/norm_i (i = 0..3), regressor/out      Linear+LayerNorm+GELU x4, Linear(->3)
  decoder (paper):  decoder/fc (WeightNormDense D -> C0*(S/16)^2, reshaped channel-major like torch),
                    decoder/conv_0..conv_3 (k5; kernel = torch weight.permute(2, 3, 1, 0))
  decoder (tokens): decoder/proj (1x1 conv), decoder/up_0..up_{n-1} (Dense(4C) + pixel shuffle)
"""

from __future__ import annotations

import math

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

DECODER_KINDS = ("paper", "tokens")


def _uniform(bound: float):
    """U(-bound, bound), torch Linear's default init."""
    return lambda key, shape, dtype=jnp.float32: jax.random.uniform(key, shape, dtype, -bound, bound)


class WeightNormDense(nn.Module):
    """Linear with torch weight_norm(dim=0): weight = g * v / ||v||, the norm over inputs per output unit.

    g starts at ||v|| so the initial weight equals v (as torch does when it wraps a fresh Linear).
    """

    features: int
    use_bias: bool = True

    @nn.compact
    def __call__(self, x):
        fan_in = x.shape[-1]
        bound = 1.0 / math.sqrt(fan_in)  # torch Linear default init range
        v = self.param("v", _uniform(bound), (fan_in, self.features))
        g = self.param("g", lambda _key: jnp.linalg.norm(v, axis=0))
        # the norm reduces over fan_in inputs: in float32 even when the step feeds bfloat16 params
        v32 = v.astype(jnp.float32)
        w = v32 * (g.astype(jnp.float32) / jnp.linalg.norm(v32, axis=0))
        y = x @ w.astype(x.dtype)
        if self.use_bias:
            y = y + self.param("bias", _uniform(bound), (self.features,)).astype(y.dtype)
        return y


class Regressor(nn.Module):
    """feature (B,D) -> force (B,3) in newtons: 4 x (Linear + LayerNorm + GELU), then Linear "out".

    The last LayerNorm is "norm_{len(widths)-1}" (norm_3 for 4 widths): calibration tunes it with "out".
    feature_norm: standardize the feature first (BatchNorm "feature_norm": batch statistics while the head
    trains, running ones in evaluation). A ViT's CLS feature is mostly one constant vector with a small
    image-dependent part that the per-sample LayerNorms cannot single out; standardizing across images
    gives the first layer that part at unit scale. False is the release's architecture (converted weights).
    out_scale/out_shift: a fixed (not trained) affine map of the output, force = raw * scale + shift.
    Training sets them from the training labels (half-range, mid-range) so the head predicts O(1) numbers:
    Adam moves a weight about lr per step, so an identity head needs ~15 N / lr steps just to reach the
    top of the Fz range. None = identity, as the release (and its converted weights) has.
    """

    widths: tuple[int, ...] = (512, 256, 128, 64)
    out_scale: tuple[float, float, float] | None = None
    out_shift: tuple[float, float, float] | None = None
    feature_norm: bool = False

    @nn.compact
    def __call__(self, x, train: bool = False):
        if self.feature_norm:
            # momentum 0.9: the running statistics follow a fine-tuned backbone within ~10 steps
            x = nn.BatchNorm(use_running_average=not train, momentum=0.9, epsilon=1e-5, name="feature_norm")(x)
        for i, w in enumerate(self.widths):
            x = WeightNormDense(w, name=f"fc_{i}")(x)
            x = nn.LayerNorm(1e-5, name=f"norm_{i}")(x)  # torch default eps
            x = nn.gelu(x, approximate=False)
        x = WeightNormDense(3, name="out")(x)
        if self.out_scale is not None:
            x = x * jnp.asarray(self.out_scale, x.dtype)
        if self.out_shift is not None:
            x = x + jnp.asarray(self.out_shift, x.dtype)
        return x


def regressor_from_config(cfg_regressor: dict) -> Regressor:
    """Regressor from cfg["model"]["regressor"]."""

    def vec(key):
        v = cfg_regressor[key]
        return None if v is None else tuple(float(a) for a in v)

    return Regressor(tuple(int(w) for w in cfg_regressor["widths"]), vec("out_scale"), vec("out_shift"),
                     bool(cfg_regressor["feature_norm"]))


def output_affine(force_min, force_max) -> dict:
    """out_scale / out_shift for a training force range: raw outputs in [-1, 1] span the range."""
    lo, hi = np.asarray(force_min, np.float64), np.asarray(force_max, np.float64)
    return {"out_scale": [float(v) for v in np.maximum((hi - lo) / 2, 1e-3)],
            "out_shift": [float(v) for v in (hi + lo) / 2]}


def upsample_nearest2(x):
    """(B,H,W,C) -> (B,2H,2W,C), torch Upsample(scale_factor=2, mode="nearest")."""
    b, h, w, c = x.shape
    x = jnp.broadcast_to(x[:, :, None, :, None, :], (b, h, 2, w, 2, c))
    return x.reshape(b, 2 * h, 2 * w, c)


def depth_to_space2(x):
    """(B,H,W,4C) -> (B,2H,2W,C): pixel shuffle by 2, a pure reshape/transpose."""
    b, h, w, c4 = x.shape
    c = c4 // 4
    x = x.reshape(b, h, w, 2, 2, c).transpose(0, 1, 3, 2, 4, 5)
    return x.reshape(b, 2 * h, 2 * w, c)


def _fit(x, size: int):
    """Resize a (B,H,W,1) map to (B,size,size,1) when the upsampling overshot (bilinear, antialiased)."""
    if x.shape[1] == size and x.shape[2] == size:
        return x
    return jax.image.resize(x, (x.shape[0], size, size, x.shape[3]), "bilinear", antialias=True)


# Nearest x2 then a k5 "same" conv reads, for output row phase a (0 even, 1 odd), low-res rows
# i-1, i, i+1 with these sums of the 5 kernel rows (rows 2i+a-2 .. 2i+a+2 map to low rows floor(m/2)).
_PHASE_TAPS = np.array(
    [[[1, 1, 0, 0, 0], [0, 0, 1, 1, 0], [0, 0, 0, 0, 1]], [[1, 0, 0, 0, 0], [0, 1, 1, 0, 0], [0, 0, 0, 1, 1]]],
    np.float32,
)


class UpConv5(nn.Module):
    """torch Upsample(x2, nearest) + Conv2d(k5, pad 2), params as nn.Conv (kernel (5,5,Cin,Cout), bias).

    fast=True computes the same function as a 3x3 conv at the low resolution with 4*Cout outputs (one per
    output phase, kernels summed from the k5 taps) + pixel shuffle: 2.8x fewer FLOPs and no upsampled
    input map. fast=False is the literal upsample-then-conv (reference; tests check they agree).
    Computes in the input's dtype (a bfloat16 train step feeds bfloat16 maps; lax.conv wants equal dtypes).
    """

    features: int
    fast: bool = True

    @nn.compact
    def __call__(self, x):
        cin, c = x.shape[-1], self.features
        kernel = self.param("kernel", nn.initializers.lecun_normal(), (5, 5, cin, c))
        bias = self.param("bias", nn.initializers.zeros, (c,))
        dn = ("NHWC", "HWIO", "NHWC")
        bias = bias.astype(x.dtype)
        if not self.fast:
            y = jax.lax.conv_general_dilated(
                upsample_nearest2(x), kernel.astype(x.dtype), (1, 1), ((2, 2), (2, 2)), dimension_numbers=dn
            )
            return y + bias
        # the phase kernels sum up to 4 taps: in float32, rounded to the input's dtype once
        taps = jnp.asarray(_PHASE_TAPS)
        k = jnp.einsum("apu,bqv,uvio->pqiabo", taps, taps, kernel.astype(jnp.float32)).reshape(3, 3, cin, 4 * c)
        y = jax.lax.conv_general_dilated(x, k.astype(x.dtype), (1, 1), ((1, 1), (1, 1)), dimension_numbers=dn)
        return depth_to_space2(y + jnp.tile(bias, 4))


class PaperDecoder(nn.Module):
    """CLS feature (B,D) -> depth (B,S,S): the release's decoder with one output channel.

    WeightNormDense(D -> C0*b*b) + ReLU with b = ceil(S/16), reshape (C0,b,b), then 4 x (nearest x2 +
    conv k5, see UpConv5): C0->C1->C2->C3->1, ReLU between, LeakyReLU(0.01) at the end.
    S not a multiple of 16: the 16*b map is resized to S.
    At paper scale (D=768, C0=512, S=224) the first Linear alone holds ~77M parameters.
    """

    channels: tuple[int, int, int, int]
    out_size: int
    fast: bool = True

    @nn.compact
    def __call__(self, feature, tokens=None):
        del tokens
        b = math.ceil(self.out_size / 16)
        c0 = self.channels[0]
        x = nn.relu(WeightNormDense(c0 * b * b, name="fc")(feature))
        # torch reshapes the Linear output as (C0, b, b): keep that order so release weights load unchanged
        x = x.reshape(-1, c0, b, b).transpose(0, 2, 3, 1)
        outs = (*self.channels[1:], 1)
        for i, c in enumerate(outs):
            x = UpConv5(c, self.fast, name=f"conv_{i}")(x)
            x = nn.relu(x) if i < len(outs) - 1 else x
        return nn.leaky_relu(_fit(x, self.out_size), 0.01)[..., 0]


class TokenDecoder(nn.Module):
    """Patch tokens (B,h,w,D) -> depth (B,S,S), light: 1x1 conv to C0, then n = ceil(log2(S/h)) stages of
    Dense(4C) + pixel shuffle (ReLU between; the last stage emits 1 channel), LeakyReLU(0.01).

    Every stage is per pixel, so the sub-pixel offsets stay as extra axes (B,h,w,2,2,...,C) and one
    transpose at the end lays the map out: the same function as depth_to_space2 after each stage, without
    moving the wide intermediate maps. When S/h is not a power of two (ViT-B/14 at 224: h=16, S/h=14) the
    map grows past S (16 -> 256) and the one-channel result is resized to S (bilinear, antialiased).
    Channels for stage i (< n-1) are channels[min(i+1, len-1)].
    """

    channels: tuple[int, ...]
    out_size: int

    @nn.compact
    def __call__(self, feature, tokens):
        del feature
        b, h, w, _ = tokens.shape
        n = max(1, math.ceil(math.log2(self.out_size / h) - 1e-9))
        x = nn.Conv(self.channels[0], (1, 1), name="proj")(tokens)
        for i in range(n):
            c = 1 if i == n - 1 else self.channels[min(i + 1, len(self.channels) - 1)]
            x = nn.Dense(4 * c, name=f"up_{i}")(nn.relu(x))
            x = x.reshape(*x.shape[:-1], 2, 2, c)  # (..., dy, dx, c) as depth_to_space2 reads the channels
        # axes: b, h, w, (dy_1, dx_1), ..., (dy_n, dx_n), c=1 -> b, h, dy_1..dy_n, w, dx_1..dx_n
        dys = [3 + 2 * i for i in range(n)]
        x = x[..., 0].transpose(0, 1, *dys, 2, *[d + 1 for d in dys])
        x = x.reshape(b, h * 2**n, w * 2**n, 1)
        return nn.leaky_relu(_fit(x, self.out_size), 0.01)[..., 0]


def decoder_from_config(cfg_decoder: dict, out_size: int) -> nn.Module:
    kind = cfg_decoder["kind"]
    channels = tuple(cfg_decoder["channels"])
    if kind == "paper":
        return PaperDecoder(channels, out_size, fast=cfg_decoder["fast"])
    if kind == "tokens":
        return TokenDecoder(channels, out_size)
    raise ValueError(f"unknown decoder kind {kind!r}; choose one of {', '.join(DECODER_KINDS)}")


def count_params(tree) -> int:
    """Number of scalars in a (possibly abstract, from jax.eval_shape) pytree."""
    return int(sum(np.prod(x.shape) for x in jax.tree.leaves(tree)))
