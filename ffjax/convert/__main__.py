"""Convert PyTorch weights (a DINOv2 ViT, a torchvision ResNet-18 or the FeelAnyForce release) to a Flax folder.

    python -m ffjax.convert {dinov2,resnet18,feelanyforce} IN --out DIR [--heads N] [--depth-channel C]

Writes DIR/variables.msgpack and DIR/convert.json (see ffjax.store.converted), whole: a kill leaves the old folder
or none; an existing DIR is replaced only with --force, and DIR may not hold IN. Prints a summary.
"""

from __future__ import annotations

import argparse
import sys

import jax
import numpy as np

from ffjax import cli
from ffjax.files import check_output
from ffjax.store import converted

from . import from_dinov2, from_release, from_torchvision, mapping, reader


def _count(tree) -> int:
    return int(sum(np.size(x) for x in jax.tree.leaves(tree)))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m ffjax.convert", description=cli.description(__doc__))
    p.add_argument("kind", choices=("dinov2", "resnet18", "feelanyforce"),
                   help="what IN holds: a DINOv2 ViT, a torchvision ResNet-18 or the FeelAnyForce release checkpoint")
    p.add_argument("input", help=".pth / .pth.tar / .pt (torch.save zip) or .safetensors")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--heads", type=int, default=None, help="ViT attention heads (default: from name, dim//64)")
    p.add_argument("--prefix", default="", help="dinov2/resnet18: take only keys under this prefix")
    p.add_argument(
        "--depth-channel",
        type=int,
        default=0,
        choices=(0, 1, 2),
        help="feelanyforce: which of the release decoder's 3 output channels to keep",
    )
    p.add_argument("--no-decoder", action="store_true", help="feelanyforce: drop the depth decoder")
    p.add_argument("--force", action="store_true", help="replace an existing --out folder")
    a = p.parse_args(argv)
    if a.heads is not None and a.heads < 1:
        p.error(f"--heads {a.heads}: must be at least 1 (the ViT's attention heads, a divisor of its width)")
    try:
        check_output(a.out, reads=[a.input], force=a.force)  # before reading: a refused --out costs nothing
        return _run(a)
    except (mapping.ConversionError, reader.UnsafePickleError, ValueError, FileNotFoundError, FileExistsError) as e:
        return cli.fail(e, cli.USAGE)  # every mapping problem is in the message: no traceback needed


def _run(a: argparse.Namespace) -> int:
    info = {}
    if a.kind == "dinov2":
        cfg, params = from_dinov2.dinov2(a.input, heads=a.heads, prefix=a.prefix)
        model_cfg, variables = {"vit": cfg}, {"params": {"backbone": params}}
    elif a.kind == "resnet18":
        cfg, params, stats = from_torchvision.resnet18(a.input, prefix=a.prefix)
        model_cfg = {"resnet": cfg}
        variables = {"params": {"backbone": params}, "batch_stats": {"backbone": stats}}
    else:
        model_cfg, variables, size = from_release.convert_file(a.input, a.heads, a.depth_channel, not a.no_decoder)
        info = {
            "input_size": size,
            "depth_channel": a.depth_channel,
            "notes": "release decoder has 3 output channels; depth_channel of them kept",
        }
    out = converted.save(a.out, a.kind, model_cfg, variables, a.input, **info)
    groups = {k: _count(v) for k, v in variables["params"].items()}
    print(f"converted {a.input} -> {out}: " + ", ".join(f"{k} {n:,} params" for k, n in groups.items()))
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
