"""What a state dict holds, told from its key names: a file handed to the wrong converter is refused in one line
that says what it is and which converter (and --prefix) reads it."""

from __future__ import annotations

from .mapping import ConversionError

# kind -> (what it is, the file users have)
KINDS = {"dinov2": ("a DINOv2 ViT", "dinov2_vitb14_pretrain.pth"),
         "resnet18": ("a torchvision ResNet-18", "resnet18-f37072fd.pth"),
         "feelanyforce": ("a FeelAnyForce release", "checkpoint_v1.pth.tar")}
_VIT, _RESNET = "patch_embed.proj.weight", "layer1.0.conv1.weight"  # a key every file of that kind has


def holds(state: dict) -> tuple[str | None, str, str]:
    """(kind, what the state dict holds in words with example keys, the prefix its keys carry); kind None: none
    of KINDS."""
    keys = sorted(state)

    def like(*names):
        return "keys like " + ", ".join(dict.fromkeys(n for n in names if n))

    def first(start):
        return next((k for k in keys if k.startswith(start)), None)

    vit = [k[: -len(_VIT)] for k in keys if k.endswith(_VIT)]
    if vit and first("regressor."):
        return "feelanyforce", f"a FeelAnyForce release checkpoint ({like(vit[0] + _VIT, first('regressor.'))})", ""
    if vit:
        p = vit[0]
        return "dinov2", f"a DINOv2/ViT state dict ({like(p + _VIT, first(p + 'blocks.'))})", p
    resnet = [k[: -len(_RESNET)] for k in keys if k.endswith(_RESNET)]
    if resnet:
        p = resnet[0]
        return "resnet18", f"a torchvision ResNet state dict ({like(first(p + 'conv1.'), p + _RESNET)})", p
    return None, f"no DINOv2, ResNet or FeelAnyForce weights ({like(*keys[:3]) if keys else 'no tensors'})", ""


def check(state: dict, want: str, source: str) -> None:
    """ConversionError unless the state dict is `want`'s (a KINDS key) with no prefix left on its keys; it says
    what the file holds and what reads it."""
    kind, what, prefix = holds(state)
    if kind == want and not prefix:
        return
    if kind == want:
        raise ConversionError(source, {f"it holds {what}": [f"pass --prefix {prefix} (prefix=) to read the keys "
                                                            "under it"]})
    name, example = KINDS[want]
    if kind is None:
        how = f"give {name}'s weight file (e.g. {example})"
    else:
        flag = f" --prefix {prefix}" if prefix else ""
        how = f"use `python -m ffjax.convert {kind}{flag}` (convert.{kind})"
    raise ConversionError(source, {f"it holds {what}, not {name}": [how]})
