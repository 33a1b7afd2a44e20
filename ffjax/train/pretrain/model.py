"""The DINO model: a backbone of the force model plus a projection head (MLP -> L2-normalized bottleneck ->
weight-normed prototypes), built from a config's model and pretrain sections."""

from __future__ import annotations

import flax.linen as nn
import jax.numpy as jnp

from ffjax import models
from ffjax.models.model import BACKBONES

KINDS = tuple(BACKBONES)  # every backbone kind pretrains with DINO


class DINOHead(nn.Module):
    """MLP -> L2-normalized bottleneck -> weight-normed prototype layer (norm fixed at 1, as DINO).

    bn: BatchNorm in the MLP (DINO's use_bn_in_head). At CPU scale it matters: a freshly initialised
    backbone's feature barely varies across images, so without it every image gets nearly the same
    logits, centering leaves a flat teacher distribution and training stays in that (uniform) collapse.
    """

    out_dim: int
    hidden: int = 512
    bottleneck: int = 128
    bn: bool = True

    @nn.compact
    def __call__(self, x, train: bool = True):
        for i in (1, 2):
            x = nn.Dense(self.hidden, name=f"fc{i}")(x)
            if self.bn:
                x = nn.BatchNorm(use_running_average=not train, momentum=0.9, name=f"bn{i}")(x)
            x = nn.gelu(x)
        x = nn.Dense(self.bottleneck, name="fc3")(x)
        x = x / (jnp.linalg.norm(x, axis=-1, keepdims=True) + 1e-6)
        v = self.param("prototypes", nn.initializers.truncated_normal(0.02), (self.bottleneck, self.out_dim))
        return x @ (v / jnp.linalg.norm(v, axis=0, keepdims=True))


class DINO(nn.Module):
    """backbone + head; params {"backbone", "head"} so the backbone subtree is the model's as is."""

    backbone: nn.Module
    head: nn.Module

    def __call__(self, images, train: bool = True):
        feature = self.backbone(images, train=train)["feature"]
        return self.head(feature, train=train), feature


def build(cfg: dict, kind: str) -> DINO:
    p, S = cfg["pretrain"], int(cfg["data"]["input_size"])
    cfg_model = cfg["model"]
    if kind == "vit":
        vit = dict(cfg_model["vit"])
        # pos_grid None sizes the table from the first input; pin it to the input grid so local crops
        # interpolate it (same param shapes as models.build_backbone at input_size; identity there)
        vit["pos_grid"] = vit["pos_grid"] or S // int(vit["patch"])
        # LayerScale 1e-5 (DINOv2's init) leaves the CLS feature all but independent of the image at
        # init: every view then gets the same (uniform) teacher output and DINO never leaves it. DINO v1
        # has no LayerScale; start from a larger one (values only: the param tree is unchanged).
        if p["init_layerscale"]:
            vit["layerscale"] = float(p["init_layerscale"])
        cfg_model = {**cfg_model, "vit": vit}
    return DINO(backbone=models.build_backbone(cfg_model, kind, S),
                head=DINOHead(int(p["out_dim"]), int(p["head_hidden"]), int(p["head_bottleneck"]), bool(p["head_bn"])))
