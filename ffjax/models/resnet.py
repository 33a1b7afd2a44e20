"""ResNet-18 style backbone (BasicBlock) with torchvision-compatible names; BatchNorm state is functional.

Flax path <- torchvision key (torch `a.N.b` becomes flax `a_N/b`):
  conv1/kernel, bn1/{scale,bias} + batch_stats bn1/{mean,var}   <- conv1.weight, bn1.{weight,bias,running_*}
  layerL_B/{conv1,bn1,conv2,bn2}, layerL_B/downsample_0 (conv), layerL_B/downsample_1 (bn)
Conv kernel = torch weight.permute(2, 3, 1, 0). The ImageNet `fc` head is not part of the backbone.
"""

from __future__ import annotations

from functools import partial

import flax.linen as nn
import jax.numpy as jnp
from jax import lax

_conv_init = nn.initializers.variance_scaling(2.0, "fan_out", "normal")  # torchvision's kaiming_normal


def _bn(train: bool, name: str):
    # torch momentum 0.1 == flax momentum 0.9; torch eps 1e-5
    return nn.BatchNorm(use_running_average=not train, momentum=0.9, epsilon=1e-5, name=name)


def _conv_op(lhs, rhs, window_strides, padding, lhs_dilation=None, rhs_dilation=None, dimension_numbers=None,
             feature_group_count=1, precision=None):
    """lax.conv_general_dilated (NHWC, HWIO), computed as one matrix product of the windows (im2col) where the
    window is larger than the map it makes: the same sum. XLA's CPU convolution leaves its fast path there, in
    the forward and both gradients: at the quick preset's 64 px the last stage's 2x2 maps took most of the train
    step, and through the product the step takes about half the time (measured: docs/benchmarks.md). Bigger maps
    (every stage at paper scale) keep the library's convolution."""

    def library():
        return lax.conv_general_dilated(lhs, rhs, window_strides, padding, lhs_dilation, rhs_dilation,
                                        dimension_numbers, feature_group_count, precision=precision)

    dilated = any(d is not None and tuple(d) != (1, 1) for d in (lhs_dilation, rhs_dilation))
    nhwc = lax.conv_dimension_numbers(lhs.shape, rhs.shape, ("NHWC", "HWIO", "NHWC"))
    layout = lax.conv_dimension_numbers(lhs.shape, rhs.shape, dimension_numbers)  # None: lax's NCHW default
    if dilated or feature_group_count != 1 or layout != nhwc or isinstance(padding, str) and padding != "VALID":
        return library()
    kh, kw = rhs.shape[:2]
    pads = ((0, 0), (0, 0)) if padding == "VALID" else tuple(tuple(p) for p in padding)
    ho = (lhs.shape[1] + sum(pads[0]) - kh) // window_strides[0] + 1
    wo = (lhs.shape[2] + sum(pads[1]) - kw) // window_strides[1] + 1
    if ho >= kh and wo >= kw:
        return library()
    sh, sw = window_strides
    x = jnp.pad(lhs, ((0, 0), *pads, (0, 0)))
    windows = [x[:, i:i + sh * (ho - 1) + 1:sh, j:j + sw * (wo - 1) + 1:sw] for i in range(kh) for j in range(kw)]
    # (i, j, channel) order: rhs's HWIO flattened over its first three axes
    return jnp.dot(jnp.concatenate(windows, axis=-1), rhs.reshape(-1, rhs.shape[-1]), precision=precision)


_conv = partial(nn.Conv, use_bias=False, kernel_init=_conv_init, conv_general_dilated=_conv_op)


class BasicBlock(nn.Module):
    features: int
    stride: int = 1

    @nn.compact
    def __call__(self, x, train: bool):
        s = (self.stride, self.stride)
        y = _conv(self.features, (3, 3), s, padding=((1, 1), (1, 1)), name="conv1")(x)
        y = nn.relu(_bn(train, "bn1")(y))
        y = _conv(self.features, (3, 3), padding=((1, 1), (1, 1)), name="conv2")(y)
        y = _bn(train, "bn2")(y)
        if self.stride != 1 or x.shape[-1] != self.features:
            x = _conv(self.features, (1, 1), s, padding="VALID", name="downsample_0")(x)
            x = _bn(train, "downsample_1")(x)
        return nn.relu(x + y)


class ResNet(nn.Module):
    """images (B,S,S,3) -> {"feature": global-average-pooled last map (B,C), "tokens": last map (B,h,w,C)}.

    stem "imagenet": conv 7x7 s2 + maxpool 3x3 s2 as torchvision (overall stride 32; loads its weights);
    stem "small": conv 3x3 s1, no maxpool (overall stride 8) for tiny inputs; same names, other kernel shape.
    """

    widths: tuple[int, ...] = (64, 128, 256, 512)
    blocks: tuple[int, ...] = (2, 2, 2, 2)
    stem: str = "imagenet"

    @nn.compact
    def __call__(self, images, train: bool = False):
        if self.stem == "imagenet":
            x = _conv(self.widths[0], (7, 7), (2, 2), padding=((3, 3), (3, 3)), name="conv1")(images)
            x = nn.relu(_bn(train, "bn1")(x))
            # torch pads max-pool with -inf, which is what flax's "padding" does for max_pool
            x = nn.max_pool(x, (3, 3), (2, 2), padding=((1, 1), (1, 1)))
        elif self.stem == "small":
            x = _conv(self.widths[0], (3, 3), padding=((1, 1), (1, 1)), name="conv1")(images)
            x = nn.relu(_bn(train, "bn1")(x))
        else:
            raise ValueError(f"unknown ResNet stem {self.stem!r}; use 'imagenet' or 'small'")
        for i, (width, n) in enumerate(zip(self.widths, self.blocks)):
            for j in range(n):
                stride = 2 if (i > 0 and j == 0) else 1
                x = BasicBlock(width, stride, name=f"layer{i + 1}_{j}")(x, train)
        return {"feature": jnp.mean(x, axis=(1, 2)), "tokens": x}


def from_config(cfg_resnet: dict) -> ResNet:
    """Build from cfg["model"]["resnet"]."""
    return ResNet(
        widths=tuple(cfg_resnet["widths"]),
        blocks=tuple(cfg_resnet["blocks"]),
        stem=cfg_resnet["stem"],
    )
