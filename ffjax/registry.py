"""Ablations as data: a Method says which backbone, whether it starts pretrained or frozen, which heads,
and the loss weights. Training turns it into param labels (frozen = optax.set_to_zero) and a loss.

    spec = registry.get("dino_rd"); registry.names(); registry.PAPER_SET
    registry.register(Method("dino_rd_b5", "DINO RD (beta 5)", "vit", beta=5.0))   # a new variant
"""

from __future__ import annotations

import dataclasses

from .models import BACKBONES


@dataclasses.dataclass(frozen=True)
class Method:
    """One row of an ablation table.

    pretrained: start from the cached self-supervised backbone (pretrain stage / converted weights).
    frozen_backbone: backbone params get no updates (optax.set_to_zero), heads train.
    depth_head: add the depth decoder and its loss beta * MSE(depth); alpha weighs L1(force, N).
    beta defaults to 10 with a depth head and 0 without. lr_*_scale multiply cfg["train"]["lr_*"].
    alpha and beta weigh the objective's terms (ffjax/train/objective.py: a term names the field its weight
    comes from, so a new term's weight is a new field here). model.json records every field, so a variant
    that is never registered still loads.
    """

    name: str
    paper_name: str
    backbone: str  # a kind of models.BACKBONES: "vit" | "resnet"
    pretrained: bool = True
    frozen_backbone: bool = False
    depth_head: bool = True
    alpha: float = 1.0
    beta: float | None = None
    lr_backbone_scale: float = 1.0
    lr_heads_scale: float = 1.0

    def __post_init__(self):
        if self.backbone not in BACKBONES:
            raise ValueError(f"{self.name}: backbone must be one of {', '.join(map(repr, BACKBONES))}, got "
                             f"{self.backbone!r}")
        if self.beta is None:
            object.__setattr__(self, "beta", 10.0 if self.depth_head else 0.0)
        if not self.depth_head and self.beta != 0:
            raise ValueError(f"{self.name}: beta={self.beta} needs a depth head")

    @property
    def trains(self) -> str:
        """What gets gradient updates: "heads" or "all"."""
        return "heads" if self.frozen_backbone else "all"

    def lrs(self, cfg_train: dict) -> tuple[float, float]:
        """(backbone lr, heads lr) from cfg["train"]; the backbone lr is 0 when it is frozen."""
        lr_b = 0.0 if self.frozen_backbone else cfg_train["lr_backbone"] * self.lr_backbone_scale
        return lr_b, cfg_train["lr_heads"] * self.lr_heads_scale


_METHODS: dict[str, Method] = {}


def register(method: Method, replace: bool = False) -> Method:
    """Add a variant; a name already taken is an error unless replace=True."""
    if method.name in _METHODS and not replace:
        raise ValueError(f"method {method.name!r} is already registered")
    _METHODS[method.name] = method
    return method


def get(name: str) -> Method:
    try:
        return _METHODS[name]
    except KeyError:
        raise KeyError(f"unknown method {name!r}; registered: {', '.join(names())}") from None


def names() -> list[str]:
    return list(_METHODS)


# The paper's methods (R = regressor head, D = depth decoder, F = frozen backbone), in table order.
register(Method("resnet_rd", "ResNet RD", "resnet"))
register(Method("dino_f_r", "DINO_F R", "vit", frozen_backbone=True, depth_head=False))
register(Method("dino_f_rd", "DINO_F RD", "vit", frozen_backbone=True))
register(Method("dino_r", "DINO R", "vit", depth_head=False))
register(Method("dino_rd", "DINO RD", "vit"))
# Ours: the same ViT trained from random init, to show what the self-supervised pretraining buys.
register(Method("dino_rd_scratch", "ViT RD (no pretraining)", "vit", pretrained=False))

PAPER_SET = ("resnet_rd", "dino_f_r", "dino_f_rd", "dino_r", "dino_rd")
