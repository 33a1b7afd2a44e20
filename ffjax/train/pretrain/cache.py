"""Pretrained backbones on disk: the settings that determine one (its cache key), the files of a DIR/<kind>
folder, the cache check, and saving / loading a backbone's {"params", "batch_stats"} as msgpack."""

from __future__ import annotations

import json
from pathlib import Path

import flax
import jax

import configs
from ffjax.files import atomic_write_bytes
from ffjax.train.pretrain import corpus
from ffjax.train.pretrain.model import KINDS

VERSION = 1
BACKBONE_FILE = "backbone.msgpack"
META_FILE = "pretrain.json"


def settings(cfg: dict, kind: str) -> dict:
    """Everything that determines a pretrained backbone (also the cache key): the backbone's model section, the
    whole pretrain section, input size, seed and the corpus settings. Config keys that hold the value the code
    used before they were keys (configs.BEFORE_KEYS) are left out, so backbones pretrained before then stay
    valid. tests/test_pretrain.py pins a hash of it per preset: a change invalidates every cached backbone."""
    sections = configs.without_before_keys({"model": cfg["model"], "pretrain": cfg["pretrain"]})
    p = {k: list(v) if isinstance(v, tuple) else v for k, v in sections["pretrain"].items()}
    return {"version": VERSION, "kind": kind, "model": jsonable(sections["model"][kind]),
            "input_size": int(cfg["data"]["input_size"]), "seed": int(cfg["seed"]), "pretrain": p,
            "corpus": corpus.corpus_settings(cfg)}


def jsonable(x):
    """`x` as it reads back from JSON (tuples as lists)."""
    return json.loads(json.dumps(x, default=list))


def run_dir(out, kind: str) -> Path:
    return Path(out) / kind


def is_cached(cfg: dict, kind: str, folder) -> bool:
    meta = Path(folder) / META_FILE
    if not (meta.exists() and (Path(folder) / BACKBONE_FILE).exists()):
        return False
    return json.loads(meta.read_text()).get("settings") == jsonable(settings(cfg, kind))


def save_backbone(path, params, batch_stats=None) -> None:
    """{"params", "batch_stats"} of a backbone as msgpack (atomic)."""
    tree = {"params": jax.device_get(params), "batch_stats": jax.device_get(batch_stats or {})}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, flax.serialization.msgpack_serialize(tree))


def load_backbone(path, kind: str | None = None):
    """(params, batch_stats) of a pretrained backbone: `path` is the backbone file, its folder
    (DIR/<kind>), or the --out DIR with `kind` given (or holding exactly one kind). batch_stats is {} for
    the ViT."""
    path = Path(path)
    if path.is_dir():
        if (path / BACKBONE_FILE).exists():
            path = path / BACKBONE_FILE
        else:
            found = [k for k in KINDS if (path / k / BACKBONE_FILE).exists() and kind in (None, k)]
            if len(found) != 1:
                raise FileNotFoundError(f"no unique pretrained backbone in {path} (found {found or 'none'}; "
                                        "pass kind= or the DIR/<kind> folder)")
            path = path / found[0] / BACKBONE_FILE
    tree = flax.serialization.msgpack_restore(path.read_bytes())
    return tree["params"], tree.get("batch_stats") or {}
