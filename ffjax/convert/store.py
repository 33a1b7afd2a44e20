"""Converted weights on disk: DIR/variables.msgpack + DIR/convert.json.

variables.msgpack  flax.serialization msgpack of the variables tree, laid out as in the composed model:
                   {"params": {"backbone", ["regressor", "decoder"]}, ["batch_stats": {"backbone"}]}
convert.json       {"format", "kind" (dinov2 | resnet18 | feelanyforce), "source", "backbone" (vit | resnet),
                    "model": sections to merge into cfg["model"] ({"vit": ...} / {"resnet": ...} / all),
                    "input_size" (release checkpoints), "notes"}
`load(dir)` gives (model cfg sections, variables); `load_backbone(dir)` gives (params, batch_stats) for
`train.init_state(..., init_backbone=...)`, like `ffjax.train.pretrain.load_backbone`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from flax import serialization

from ffjax.jsontree import retuple

FORMAT = "ffjax.convert/1"
_TUPLES = dict.fromkeys(("widths", "blocks", "channels"), ())  # keys of a model section that hold tuples


def save(out_dir, kind: str, model_cfg: dict, variables: dict, source: str, **info) -> Path:
    """Write `variables` and a self-describing JSON beside them; returns the directory."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tree = _to_numpy(variables)
    (out / "variables.msgpack").write_bytes(serialization.msgpack_serialize(tree))
    backbone = "resnet" if "resnet" in model_cfg else "vit"
    meta = {
        "format": FORMAT,
        "kind": kind,
        "source": str(source),
        "backbone": backbone,
        "model": model_cfg,
        **info,
    }
    (out / "convert.json").write_text(json.dumps(meta, indent=1, default=list) + "\n")
    return out


def read_meta(out_dir) -> dict:
    meta = json.loads((Path(out_dir) / "convert.json").read_text())
    if meta.get("format") != FORMAT:
        raise ValueError(f"{out_dir}: not an ffjax.convert output (format {meta.get('format')!r})")
    meta["model"] = {k: retuple(v, _TUPLES) for k, v in meta["model"].items()}
    return meta


def load(out_dir) -> tuple[dict, dict]:
    """(cfg["model"] sections, variables as numpy arrays) from a converted directory."""
    meta = read_meta(out_dir)
    tree = serialization.msgpack_restore((Path(out_dir) / "variables.msgpack").read_bytes())
    return meta["model"], tree


def load_backbone(out_dir) -> tuple[dict, dict]:
    """(backbone params, backbone batch_stats or {}) from a converted directory."""
    _, tree = load(out_dir)
    return tree["params"]["backbone"], tree.get("batch_stats", {}).get("backbone", {})


def _to_numpy(tree):
    if isinstance(tree, dict):
        return {k: _to_numpy(v) for k, v in tree.items()}
    return np.asarray(tree)
