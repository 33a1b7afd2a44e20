"""Presets: one code path, sizes from here. `configs.get("quick", {"train.batch_size": 32})`.

Every key, its default and its check are in configs/base.py; a preset (smoke.py, ...) lists only what it
changes.

`get` validates the result (`validate`): unknown keys, wrong types and impossible values fail here, with the
dotted key in the message, before any entry point starts work.
"""

from __future__ import annotations

import ast
import copy
import difflib
import importlib
from typing import Any

from configs import base
from configs.checks import is_num, keys, rules
from ffjax.sim.seeds import MAX_SEED

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
# dotted key -> checker, one per key of configs/base.py; keys a config lacks are skipped (old model.json
# cfgs), unknown keys are set_path's job
RULES = rules(base.SPEC)
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
    if is_num(size) and is_num(patch) and patch > 0 and size % patch:
        errs.append(f"data.input_size ({size}) must be divisible by model.vit.patch ({patch}): the ViT cuts "
                    f"the input into {patch}x{patch} patches")
    fz_min, fz_max = _lookup(cfg, "data.fz_min"), _lookup(cfg, "data.fz_max")
    if is_num(fz_min) and is_num(fz_max) and fz_min >= fz_max:
        errs.append(f"data.fz_min ({fz_min}) must be below data.fz_max ({fz_max}): Fz is sampled between them")
    render = _lookup(cfg, "data.render_size")
    if isinstance(render, (list, tuple)) and all(is_num(v) for v in render) and 1 <= min(render) < MIN_RENDER:
        errs.append(f"data.render_size ({tuple(render)}) must be at least {MIN_RENDER} px on each side: smaller, "
                    "a contact covers less than a pixel and the depth targets are all zero")
    seed, n = _lookup(cfg, "seed"), _lookup(cfg, "seeds")
    if is_num(seed) and is_num(n) and seed + n - 1 > MAX_SEED >= seed:
        errs.append(f"seed ({seed}) + seeds ({n}) - 1 must be at most {MAX_SEED}: the experiments train seeds seed, "
                    f"seed + 1, ..., each a config seed; lower seed or seeds")
    steps, corpus = _lookup(cfg, "pretrain.steps"), _lookup(cfg, "pretrain.corpus_size")
    if is_num(steps) and is_num(corpus) and steps > 0 and corpus < 1:
        errs.append(f"pretrain.corpus_size ({corpus}) must be at least 1 for pretrain.steps ({steps}) > 0: the DINO "
                    "steps draw their images from it (pretrain.steps=0 pretrains nothing)")
    dim, heads = _lookup(cfg, "model.vit.dim"), _lookup(cfg, "model.vit.heads")
    if is_num(dim) and is_num(heads) and heads > 0 and dim % heads:
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


# -- configs saved before a key existed ---------------------------------------------------------------------
KEYS = keys(base.SPEC)
# The keys added after runs, datasets and pretrained backbones were saved (Key.late), at the values the code
# held as constants before: caches keyed on config sections hash `without_before_keys(cfg)`, so what was made
# before the keys existed stays valid.
BEFORE_KEYS = {dotted: key.old_value for dotted, key in KEYS.items() if key.late}


def upgrade(saved: dict) -> dict:
    """A saved config (an earlier run's model.json) as a full config of today: every key it lacks set to what
    it meant then (Key.before: the value the code used before the key existed). The one place old configs are
    read; the code then reads every key directly."""
    out = copy.deepcopy(saved)
    for dotted, key in KEYS.items():
        *parents, leaf = dotted.split(".")
        node = out
        for part in parents:
            node = node.setdefault(part, {})
        if leaf not in node:
            node[leaf] = key.old_value
    return out


def without_before_keys(cfg: dict) -> dict:
    """A copy of `cfg` less the BEFORE_KEYS that hold their before values (a changed value stays: it is
    another config)."""
    out = copy.deepcopy(cfg)
    for dotted, before in BEFORE_KEYS.items():
        *parents, leaf = dotted.split(".")
        node = out
        for part in parents:
            node = node.get(part) if isinstance(node, dict) else None
        if isinstance(node, dict) and leaf in node and node[leaf] == before and type(node[leaf]) is type(before):
            del node[leaf]
    return out
