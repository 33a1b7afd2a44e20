"""The composed FeelAnyForce network: backbone -> force regressor (+ depth decoder if the method has one)."""

from __future__ import annotations

import flax.linen as nn

from . import heads, resnet, vit

# The one list of backbone kinds: kind -> builder of its config section cfg["model"][kind]. A new backbone is a
# module with a `from_config(section)` whose __call__(images, train) returns {"feature", "tokens"}, an entry
# here, and its section (with checks) in configs/base.py.
BACKBONES = {"vit": vit.from_config, "resnet": resnet.from_config}


class ForceModel(nn.Module):
    """images (B,S,S,3) -> {"force": (B,3), "feature": (B,D), "depth": (B,S,S) if a decoder is given}.

    Params are grouped under the attribute names "backbone", "regressor", "decoder" (fixed: training labels
    and pretraining rely on them). Without a decoder no depth is computed at all.
    """

    backbone: nn.Module
    regressor: nn.Module
    decoder: nn.Module | None = None

    def __call__(self, images, train: bool = False, backbone_train: bool | None = None):
        # backbone_train (default: train) lets a frozen backbone keep its BatchNorm statistics while the
        # heads' own normalization trains on batch statistics
        enc = self.backbone(images, train=train if backbone_train is None else backbone_train)
        out = {"force": self.regressor(enc["feature"], train=train), "feature": enc["feature"]}
        if self.decoder is not None:
            out["depth"] = self.decoder(enc["feature"], enc["tokens"])
        return out


def build_backbone(cfg_model: dict, kind: str, input_size: int) -> nn.Module:
    """Backbone of `kind` (a BACKBONES key) from its section cfg["model"][kind]; __call__(images, train) ->
    {"feature", "tokens"}."""
    del input_size  # backbones adapt to the input grid (the ViT interpolates its position table)
    if kind not in BACKBONES:
        raise ValueError(f"unknown backbone {kind!r}; choose one of {', '.join(BACKBONES)}")
    return BACKBONES[kind](cfg_model[kind])


def build(cfg_model: dict, spec, input_size: int) -> ForceModel:
    """Model for a registry Method (`registry.get(name)`; anything with .backbone and .depth_head) at square
    input `input_size`. Names are the registry's to resolve: models do not import it (it imports BACKBONES)."""
    decoder = heads.decoder_from_config(cfg_model["decoder"], input_size) if spec.depth_head else None
    return ForceModel(
        backbone=build_backbone(cfg_model, spec.backbone, input_size),
        regressor=heads.regressor_from_config(cfg_model["regressor"]),
        decoder=decoder,
    )
