"""`--init KIND:PATH`: start training (or evaluation) from real or cached weights.

KIND is one of
  dinov2        official DINOv2 torch-hub weights (ViT-S/14, ViT-B/14): the backbone only
  resnet18      torchvision ResNet-18 weights: the backbone only
  feelanyforce  the release checkpoint (checkpoint_v1.pth.tar): backbone + regressor (+ decoder)
  pretrained    a backbone cached by `python -m ffjax.train.pretrain`
PATH is the original file (.pth / .pth.tar / .safetensors, read without unpickling code) or a folder
written by `python -m ffjax.convert` (or by the pretraining stage).
"""

from __future__ import annotations

import copy
from pathlib import Path

from ffjax import convert
from ffjax.store import converted
from ffjax.train.pretrain import load_backbone

KINDS = ("dinov2", "resnet18", "feelanyforce", "pretrained")
_BACKBONE = {"dinov2": "vit", "resnet18": "resnet", "feelanyforce": "vit"}


def parse(text: str) -> tuple[str, Path]:
    kind, sep, path = text.partition(":")
    if not sep or kind not in KINDS or not path:
        raise ValueError(f"--init expects KIND:PATH with KIND one of {', '.join(KINDS)}; got {text!r}")
    if not Path(path).exists():
        raise FileNotFoundError(f"--init {kind}: {path} does not exist")
    return kind, Path(path)


def _converted(kind: str, path: Path) -> tuple[dict, dict, dict]:
    """(cfg["model"] sections, variables, extra info) from a file or a convert folder."""
    if path.is_dir():
        meta = converted.read_meta(path)
        if meta["kind"] != kind:
            raise ValueError(f"{path} holds converted {meta['kind']} weights, not {kind}")
        sections, variables = converted.load(path)
        return sections, variables, meta
    if kind == "dinov2":
        vit_cfg, params = convert.dinov2(path)
        return {"vit": vit_cfg}, {"params": {"backbone": params}}, {}
    if kind == "resnet18":
        resnet_cfg, params, stats = convert.resnet18(path)
        return {"resnet": resnet_cfg}, {"params": {"backbone": params}, "batch_stats": {"backbone": stats}}, {}
    sections, variables, size = convert.from_release.convert_file(path)
    return sections, variables, {"input_size": size}


def apply(cfg: dict, spec, text: str) -> tuple[dict, tuple | None, dict | None]:
    """(cfg with the weights' model sizes, init_backbone or None, init_variables or None) for train.train.

    The weights decide the architecture: their sections replace the preset's. A FeelAnyForce release
    checkpoint predicts newtons directly, so its regressor keeps the identity output map.
    """
    kind, path = parse(text)
    if kind == "pretrained":
        return cfg, load_backbone(path), None
    if spec.backbone != _BACKBONE[kind]:
        raise ValueError(f"--init {kind} gives a {_BACKBONE[kind]} backbone; method {spec.name} uses {spec.backbone}")
    sections, variables, info = _converted(kind, path)
    cfg = {**copy.deepcopy(cfg), "model": converted.model_config(cfg["model"], sections, kind)}
    if kind != "feelanyforce":
        stats = variables.get("batch_stats", {}).get("backbone", {})
        return cfg, (variables["params"]["backbone"], stats), None
    cfg["train"]["force_loss"] = "newton"  # as the release trained; per-axis weights need a normalized output
    if info.get("input_size"):
        cfg["data"]["input_size"] = int(info["input_size"])
    params = dict(variables["params"])
    if not spec.depth_head:
        params.pop("decoder", None)
    elif "decoder" not in params:
        raise ValueError(f"{path} has no depth decoder; method {spec.name} needs one (use a method without D)")
    return cfg, None, {**variables, "params": params}
