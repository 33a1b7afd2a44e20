"""Converted weights on disk: DIR/variables.msgpack + DIR/convert.json, written whole and verified on load.

variables.msgpack  flax.serialization msgpack of the variables tree, laid out as in the composed model:
                   {"params": {"backbone", ["regressor", "decoder"]}, ["batch_stats": {"backbone"}]}
convert.json       {"format", "kind" (dinov2 | resnet18 | feelanyforce), "source", "backbone" (vit | resnet),
                    "model": sections to merge into cfg["model"] ({"vit": ...} / {"resnet": ...} / all),
                    "input_size" (release checkpoints), "notes", "variables_sha256", "sha256" (of the rest)}

The folder is written beside DIR and renamed into place when complete (a kill leaves the old one or none), and
every read checks both digests: a flipped byte in the weights or an edited convert.json is an error naming the
file, not a model that predicts other forces. Folders written before the digests existed load unchecked, with an
UnverifiedWarning that says how to convert them again.
`load(dir)` gives (model cfg sections, variables); `load_backbone(dir)` gives (params, batch_stats) for
`train.init_state(..., init_backbone=...)`, like `ffjax.train.pretrain.load_backbone`; `release_model(sections)`
the complete cfg["model"] of converted release weights.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
from flax import serialization

import configs
from ffjax.errors import CheckpointError
from ffjax.files import (
    as_json,
    atomic_write_bytes,
    atomic_write_json,
    json_digest,
    read_json,
    sha256_bytes,
    staged_folder,
)
from ffjax.jsontree import retuple
from ffjax.store.checksums import warn_unverified

FORMAT = "ffjax.convert/1"
META, VARIABLES = "convert.json", "variables.msgpack"
DIGEST, WEIGHTS_DIGEST = "sha256", "variables_sha256"
_TUPLES = dict.fromkeys(("widths", "blocks", "channels"), ())  # keys of a model section that hold tuples


def save(out_dir, kind: str, model_cfg: dict, variables: dict, source, **info) -> Path:
    """Write `variables` and a self-describing JSON as the folder `out_dir` (replacing it: the caller decides
    whether it may, see files.check_output); returns the folder."""
    raw = serialization.msgpack_serialize(_to_numpy(variables))
    meta = {"format": FORMAT, "kind": kind, "source": str(source),
            "backbone": "resnet" if "resnet" in model_cfg else "vit", "model": model_cfg, **info,
            WEIGHTS_DIGEST: sha256_bytes(raw)}
    meta = as_json(meta)
    with staged_folder(out_dir) as tmp:
        atomic_write_bytes(tmp / VARIABLES, raw)
        atomic_write_json(tmp / META, {**meta, DIGEST: json_digest(meta)})
    return Path(out_dir)


def read_meta(out_dir) -> dict:
    """convert.json, checked (format, digest), with the model sections' lists back as tuples."""
    path = Path(out_dir) / META
    meta = read_json(path)
    if meta is None:
        raise FileNotFoundError(f"{path} not found: not a converted folder (python -m ffjax.convert ...)")
    if meta.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not an ffjax.convert output (format {meta.get('format')!r})")
    recorded = meta.get(DIGEST)
    if recorded is not None and json_digest({k: v for k, v in meta.items() if k != DIGEST}) != recorded:
        raise CheckpointError(f"{path} was changed after it was written (its content does not match the sha256 "
                              "recorded in it); convert the weights again")
    meta["model"] = {k: retuple(v, _TUPLES) for k, v in meta["model"].items()}
    return meta


def load(out_dir) -> tuple[dict, dict]:
    """(cfg["model"] sections, variables as numpy arrays) from a converted folder, both verified (an
    UnverifiedWarning for a folder that records no digests)."""
    meta = read_meta(out_dir)
    path = Path(out_dir) / VARIABLES
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: the converted folder is incomplete; convert again")
    missing = [k for k in (DIGEST, WEIGHTS_DIGEST) if meta.get(k) is None]
    if missing:
        what = {DIGEST: f"the model config in {META}", WEIGHTS_DIGEST: f"the weights in {VARIABLES}"}
        warn_unverified(Path(out_dir) / META, missing, " and ".join(what[k] for k in missing) + " are",
                        f"convert the weights again: {_reconvert_command(out_dir, meta)}")
    raw = path.read_bytes()
    digest = meta.get(WEIGHTS_DIGEST)
    if digest is not None and sha256_bytes(raw) != digest:
        raise CheckpointError(f"{path} is corrupt or truncated ({len(raw):,} bytes): its sha256 differs from the "
                              f"one in {META}; copy or convert it again")
    try:
        tree = serialization.msgpack_restore(raw)
    except Exception as e:  # noqa: BLE001 - msgpack's errors ("Unpack failed: incomplete input") name no file
        raise CheckpointError(f"{path} is not readable ({type(e).__name__}: {e}): truncated or not written by "
                              "ffjax.convert; convert again") from e
    return meta["model"], tree


# the FeelAnyForce release's regressor predicts newtons directly: no feature normalization, no output map
RELEASE_HEAD = {"normalize_output": False, "out_scale": None, "out_shift": None, "feature_norm": False}


def model_config(model_cfg: dict, sections: dict, kind: str) -> dict:
    """cfg["model"] for converted weights: their sections merged over `model_cfg`'s (the weights decide the
    sizes, the rest keeps its values); a FeelAnyForce release's regressor is RELEASE_HEAD."""
    out = copy.deepcopy(model_cfg)
    for name, section in sections.items():
        out[name] = {**out.get(name, {}), **section}
    if kind == "feelanyforce":
        out["regressor"].update(RELEASE_HEAD)
    return out


def release_model(sections: dict) -> dict:
    """The complete cfg["model"] of converted FeelAnyForce release weights: the paper preset's, with the sizes
    the weights decide and the release's regressor head (what `ffjax.store.load` builds them with)."""
    return model_config(configs.get("paper")["model"], sections, "feelanyforce")


def _reconvert_command(out_dir, meta: dict) -> str:
    """The `python -m ffjax.convert` line that writes `out_dir` again from the source convert.json names."""
    model = meta.get("model", {})
    flags = [f"--heads {model['vit']['heads']}"] if "heads" in model.get("vit", {}) else []
    if meta.get("kind") == "feelanyforce":
        flags += [f"--depth-channel {meta['depth_channel']}"] if meta.get("depth_channel") else []
        flags += [] if "decoder" in model else ["--no-decoder"]
    return " ".join(["python -m ffjax.convert", str(meta.get("kind")), str(meta.get("source")), "--out", str(out_dir),
                     *flags, "--force"])


def load_backbone(out_dir) -> tuple[dict, dict]:
    """(backbone params, backbone batch_stats or {}) from a converted folder."""
    _, tree = load(out_dir)
    return tree["params"]["backbone"], tree.get("batch_stats", {}).get("backbone", {})


def _to_numpy(tree):
    if isinstance(tree, dict):
        return {k: _to_numpy(v) for k, v in tree.items()}
    return np.asarray(tree)
