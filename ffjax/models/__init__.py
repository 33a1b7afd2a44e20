"""Flax (linen) models: DINOv2-style ViT, ResNet-18 style backbone, force regressor, depth decoders.

model = models.build(cfg["model"], registry.get("dino_rd"), input_size)
variables = model.init(key, images, train=False)
out = model.apply(variables, images)        # {"force", "feature", ["depth"]}
"""

from .heads import (
    DECODER_KINDS,
    PaperDecoder,
    Regressor,
    TokenDecoder,
    UpConv5,
    WeightNormDense,
    count_params,
    decoder_from_config,
    output_affine,
    regressor_from_config,
)
from .model import BACKBONES, ForceModel, build, build_backbone
from .resnet import ResNet
from .vit import ViT, interpolate_pos_embed, vit_config

__all__ = [
    "BACKBONES",
    "DECODER_KINDS",
    "ForceModel",
    "PaperDecoder",
    "Regressor",
    "ResNet",
    "TokenDecoder",
    "UpConv5",
    "ViT",
    "WeightNormDense",
    "build",
    "build_backbone",
    "count_params",
    "decoder_from_config",
    "interpolate_pos_embed",
    "output_affine",
    "regressor_from_config",
    "vit_config",
]
