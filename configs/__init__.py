"""Presets: one code path, sizes from here. `configs.get("quick", {"train.batch_size": 32})`.

`get` validates the result (`validate`): unknown keys, wrong types and impossible values fail here, with the
dotted key in the message, before any entry point starts work.
"""

from __future__ import annotations

import copy
import difflib
import importlib
import math
from typing import Any

PRESETS = ("smoke", "quick", "full", "gpu", "paper")


class ConfigError(ValueError):
    """A config key or value that can never work; the message names the dotted key."""


class UnknownKeyError(ConfigError, KeyError):
    """An override names a key no preset has (also a KeyError, as before validation existed)."""

    def __str__(self) -> str:  # KeyError would repr() the message, quotes and all
        return str(self.args[0])


class ConfigTypeError(ConfigError, TypeError):
    """A value of the wrong type for its key (also a TypeError, as before validation existed)."""


def get(preset: str, overrides: dict[str, Any] | None = None) -> dict:
    """Return a fresh nested-dict config for `preset`, with dotted-key overrides applied, validated."""
    if preset not in PRESETS:
        raise ConfigError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
    cfg = copy.deepcopy(importlib.import_module(f"configs.{preset}").CONFIG)
    cfg["preset"] = preset
    for key, value in (overrides or {}).items():
        set_path(cfg, key, value)
    validate(cfg)
    return cfg


def from_cli(parser, preset: str, overrides: list[str]) -> dict:
    """get() for a CLI: `--set KEY=VALUE` strings in; a bad key or value exits via parser.error (usage, code 2)."""
    try:
        return get(preset, dict(parse_override(s) for s in overrides))
    except ConfigError as e:
        parser.error(str(e))


def _leaves(cfg: dict, prefix: str = "") -> list[str]:
    out = []
    for k, v in cfg.items():
        out += _leaves(v, f"{prefix}{k}.") if isinstance(v, dict) else [f"{prefix}{k}"]
    return out


def _unknown(cfg: dict, dotted: str, bad: str) -> UnknownKeyError:
    """The error for an unknown key, with the closest valid keys (typos are the usual cause)."""
    where = "" if bad == dotted else f" (in override {dotted!r})"
    if bad == dotted and "." in dotted:  # the section exists: suggest among its keys, then list them
        section, leaf = dotted.rsplit(".", 1)
        node = cfg
        for part in section.split("."):
            node = node[part]
        names = [k for k in node if not isinstance(node[k], dict)]
        # match spelled-out forms too, so "learning_rate" finds lr_heads, "batch" finds batch_size
        spelled = {n.replace("lr", "learning_rate").replace("_", " "): n for n in names}
        close = [spelled[c] for c in difflib.get_close_matches(leaf.replace("_", " "), spelled, n=3, cutoff=0.5)]
        hint = (f"; did you mean {' or '.join(repr(f'{section}.{c}') for c in close)}?" if close else "") + \
            f" (keys under {section!r}: {', '.join(names)})"
    else:  # a section (or a top-level key) is unknown: match the whole dotted key
        close = difflib.get_close_matches(dotted, _leaves(cfg), n=3, cutoff=0.6)
        hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else \
            f" (top-level keys: {', '.join(cfg)})"
    return UnknownKeyError(f"unknown config key {bad!r}{where}{hint}")


def set_path(cfg: dict, dotted: str, value: Any) -> None:
    """Set `cfg["a"]["b"] = value` for `dotted="a.b"`; unknown keys are an error, not a silent add."""
    *parents, leaf = dotted.split(".")
    node = cfg
    for i, part in enumerate(parents):
        if not isinstance(node, dict) or part not in node:
            raise _unknown(cfg, dotted, ".".join(parents[: i + 1]))
        node = node[part]
    if not isinstance(node, dict) or leaf not in node:
        raise _unknown(cfg, dotted, dotted)
    node[leaf] = _coerce(dotted, node[leaf], value)


def _coerce(dotted: str, old: Any, value: Any) -> Any:
    """`value` in the type of the preset's `old` (int -> float, list <-> tuple of the same length)."""
    if old is None or value is None:
        return value  # optional keys (e.g. pos_grid); validate() checks what was given
    if isinstance(value, bool) != isinstance(old, bool):  # bool is an int to isinstance; not to a config
        raise ConfigTypeError(f"config key {dotted!r} expects {type(old).__name__}, got {value!r}")
    if isinstance(old, float) and isinstance(value, int):
        return float(value)
    if isinstance(old, (tuple, list)) and isinstance(value, (tuple, list)):
        if len(value) != len(old) and dotted.rsplit(".", 1)[-1] not in _FREE_LENGTH:
            raise ConfigTypeError(f"config key {dotted!r} expects {len(old)} values like {old!r}, got "
                                  f"{len(value)}: {value!r}")
        return type(old)(value)
    if not isinstance(value, type(old)):
        raise ConfigTypeError(f"config key {dotted!r} expects {type(old).__name__} (like {old!r}), got "
                              f"{type(value).__name__} {value!r}")
    return value


# lists whose length is a free choice (stage counts); every other list keeps the preset's length
_FREE_LENGTH = ("widths", "blocks", "channels")


def parse_override(text: str) -> tuple[str, Any]:
    """Parse a CLI override `a.b=value` (value read as a Python literal when it is one)."""
    import ast

    if "=" not in text:
        raise ConfigError(f"override {text!r} must look like key.path=value")
    key, raw = text.split("=", 1)
    if not key.strip():
        raise ConfigError(f"override {text!r} has no key before '='")
    try:
        value = ast.literal_eval(raw.strip())
    except (ValueError, SyntaxError):
        value = raw.strip()
    return key.strip(), value



# -- validation --------------------------------------------------------------------------------------------
def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _num(lo=None, hi=None, lo_open=False, hi_open=False, integer=False, optional=False):
    """A checker: a (finite) number in [lo, hi] (open ends when *_open), an int when `integer`."""
    kind = "an integer" if integer else "a number"
    rng = "".join([f" {'>' if lo_open else '>='} {lo}" if lo is not None else "",
                   " and" if lo is not None and hi is not None else "",
                   f" {'<' if hi_open else '<='} {hi}" if hi is not None else ""])

    def check(v):
        if v is None and optional:
            return None
        if not _is_num(v) or (integer and not isinstance(v, int)) or not math.isfinite(v):
            return f"must be {kind}{rng}, got {v!r}"
        if lo is not None and (v <= lo if lo_open else v < lo) or hi is not None and (v >= hi if hi_open else v > hi):
            return f"must be{rng}, got {v!r}"
        return None

    return check


def _seq(item, length=None, min_len=1, ordered=False):
    """A checker: a list/tuple of `length` (or >= min_len) items each passing `item`; `ordered`: lo <= hi."""
    def check(v):
        n = f"{length}" if length else f"at least {min_len}"
        if not isinstance(v, (list, tuple)) or (len(v) != length if length else len(v) < min_len):
            return f"must be a list of {n} values, got {v!r}"
        for i, x in enumerate(v):
            err = item(x)
            if err:
                return f"item {i} {err}"
        if ordered and v[0] > v[1]:
            return f"must be (low, high) with low <= high, got {v!r}"
        return None

    return check


def _choice(*options, optional=False):
    def check(v):
        if (v is None and optional) or v in options:
            return None
        return f"must be one of {', '.join(repr(o) for o in options)}, got {v!r}"

    return check


def _bool(v):
    return None if isinstance(v, bool) else f"must be True or False, got {v!r}"


_POS_INT, _NN_INT = _num(1, integer=True), _num(0, integer=True)
_POS, _NN, _PROB = _num(0, lo_open=True), _num(0), _num(0, 1)
_SCALE = _seq(_num(0, 1, lo_open=True), length=2, ordered=True)

# dotted key -> checker; keys a config lacks are skipped (old model.json cfgs), unknown keys are set_path's job
RULES = {
    "seed": _num(integer=True),
    "data.render_size": _seq(_POS_INT, length=2), "data.input_size": _POS_INT,
    "data.train_per_indenter": _POS_INT, "data.val_per_indenter": _NN_INT, "data.unseen_per_object": _NN_INT,
    "data.sensor_test_per_indenter": _NN_INT, "data.calib_samples": _POS_INT,
    "data.fz_max": _POS, "data.shear_max": _NN, "data.shard_size": _POS_INT, "data.depth_eps": _NN,
    "model.vit.dim": _POS_INT, "model.vit.depth": _POS_INT, "model.vit.heads": _POS_INT,
    "model.vit.patch": _POS_INT, "model.vit.mlp_ratio": _POS, "model.vit.layerscale": _num(0, optional=True),
    "model.vit.pos_grid": _num(1, integer=True, optional=True),
    "model.resnet.widths": _seq(_POS_INT), "model.resnet.blocks": _seq(_POS_INT),
    "model.resnet.stem": _choice("small", "imagenet"),
    "model.regressor.widths": _seq(_POS_INT), "model.regressor.normalize_output": _bool,
    "model.regressor.feature_norm": _bool,
    "model.decoder.kind": _choice("paper", "tokens"), "model.decoder.channels": _seq(_POS_INT),
    "train.batch_size": _POS_INT, "train.epochs": _POS_INT, "train.lr_backbone": _POS, "train.lr_heads": _POS,
    "train.schedule": _choice("constant", "warmup_cosine"), "train.warmup_steps": _NN_INT,
    "train.ckpt_every": _POS_INT, "train.val_every": _POS_INT, "train.grad_clip": _NN,
    "train.nonfinite": _choice("stop", "skip"),
    "train.force_loss": _choice("newton", "normalized"), "train.compute_dtype": _choice("float32", "bfloat16"),
    "pretrain.steps": _NN_INT, "pretrain.batch_size": _POS_INT, "pretrain.lr": _POS,
    "pretrain.corpus_size": _NN_INT, "pretrain.out_dim": _POS_INT, "pretrain.warmup_steps": _NN_INT,
    "pretrain.min_lr_ratio": _PROB, "pretrain.weight_decay": _NN, "pretrain.grad_clip": _NN,
    "pretrain.head_hidden": _POS_INT, "pretrain.head_bottleneck": _POS_INT, "pretrain.freeze_last_steps": _NN_INT,
    "pretrain.init_layerscale": _NN, "pretrain.head_bn": _bool, "pretrain.local_crops": _NN_INT,
    "pretrain.local_size": _POS_INT, "pretrain.global_scale": _SCALE, "pretrain.local_scale": _SCALE,
    "pretrain.student_temp": _POS, "pretrain.teacher_temp": _POS, "pretrain.teacher_temp_start": _POS,
    "pretrain.teacher_temp_warmup": _NN_INT, "pretrain.momentum": _PROB, "pretrain.center_momentum": _PROB,
    "pretrain.flip": _PROB, "pretrain.color_jitter": _NN, "pretrain.blur": _PROB, "pretrain.noise": _NN,
    "pretrain.corpus_sim_fraction": _PROB,
    "calibrate.steps": _NN_INT, "calibrate.lr": _POS, "calibrate.batch_size": _POS_INT,
    "calibrate.holdout": _num(0, 1, hi_open=True),
}
_MISSING = object()


def _lookup(cfg: dict, dotted: str):
    node = cfg
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return _MISSING
        node = node[part]
    return node


MIN_RENDER = 16  # px: the pad is ~20 x 15 mm, so a 4 mm contact still spans ~3 pixels


def _cross_checks(cfg: dict) -> list[str]:
    """Rules between keys: shapes that cannot fit together."""
    errs = []
    size, patch = _lookup(cfg, "data.input_size"), _lookup(cfg, "model.vit.patch")
    if _is_num(size) and _is_num(patch) and patch > 0 and size % patch:
        errs.append(f"data.input_size ({size}) must be divisible by model.vit.patch ({patch}): the ViT cuts "
                    f"the input into {patch}x{patch} patches")
    render = _lookup(cfg, "data.render_size")
    if isinstance(render, (list, tuple)) and all(_is_num(v) for v in render) and min(render) < MIN_RENDER:
        errs.append(f"data.render_size ({tuple(render)}) must be at least {MIN_RENDER} px on each side: smaller, "
                    "a contact covers less than a pixel and the depth targets are all zero")
    dim, heads = _lookup(cfg, "model.vit.dim"), _lookup(cfg, "model.vit.heads")
    if _is_num(dim) and _is_num(heads) and heads > 0 and dim % heads:
        errs.append(f"model.vit.dim ({dim}) must be divisible by model.vit.heads ({heads})")
    widths, blocks = _lookup(cfg, "model.resnet.widths"), _lookup(cfg, "model.resnet.blocks")
    if isinstance(widths, (list, tuple)) and isinstance(blocks, (list, tuple)) and len(widths) != len(blocks):
        errs.append(f"model.resnet.widths ({len(widths)} stages) and model.resnet.blocks ({len(blocks)}) must "
                    f"have the same length")
    if _lookup(cfg, "train.force_loss") == "normalized" and _lookup(cfg, "model.regressor.normalize_output") is False:
        errs.append("train.force_loss='normalized' weighs each axis by its training range, which training records "
                    "only with model.regressor.normalize_output=True")
    return errs


def validate(cfg: dict) -> dict:
    """Raise ConfigError listing every bad key (dotted name, what is expected, what was given); else return cfg.

    Checks types and ranges (positive sizes, lr > 0, probabilities in [0, 1], ...) and keys that must fit
    together (input_size divisible by the ViT patch). `get` calls it, so every entry point is covered."""
    errs = []
    for key, check in RULES.items():
        value = _lookup(cfg, key)
        if value is not _MISSING:
            err = check(value)
            if err:
                errs.append(f"{key} {err}")
    errs += _cross_checks(cfg)
    if errs:
        preset = cfg.get("preset")
        head = f"invalid config{f' (preset {preset!r})' if preset else ''}: "
        raise ConfigError(head + ("; ".join(errs) if len(errs) < 2 else "\n  " + "\n  ".join(errs)))
    return cfg
