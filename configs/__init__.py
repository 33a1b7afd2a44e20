"""Presets: one code path, sizes from here. `configs.get("quick", {"train.batch_size": 32})`."""

from __future__ import annotations

import copy
import importlib
from typing import Any

PRESETS = ("smoke", "quick", "full", "paper")


def get(preset: str, overrides: dict[str, Any] | None = None) -> dict:
    """Return a fresh nested-dict config for `preset`, with dotted-key overrides applied."""
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
    cfg = copy.deepcopy(importlib.import_module(f"configs.{preset}").CONFIG)
    cfg["preset"] = preset
    for key, value in (overrides or {}).items():
        set_path(cfg, key, value)
    return cfg


def set_path(cfg: dict, dotted: str, value: Any) -> None:
    """Set `cfg["a"]["b"] = value` for `dotted="a.b"`; unknown keys are an error, not a silent add."""
    *parents, leaf = dotted.split(".")
    node = cfg
    for i, part in enumerate(parents):
        if not isinstance(node, dict) or part not in node:
            raise KeyError(f"unknown config key {'.'.join(parents[: i + 1])!r} in override {dotted!r}")
        node = node[part]
    if not isinstance(node, dict) or leaf not in node:
        raise KeyError(f"unknown config key {dotted!r}")
    old = node[leaf]
    if old is not None and value is not None and not isinstance(value, type(old)):
        if isinstance(old, float) and isinstance(value, int):
            value = float(value)
        elif isinstance(old, (tuple, list)) and isinstance(value, (tuple, list)):
            value = type(old)(value)
        else:
            raise TypeError(f"config key {dotted!r} expects {type(old).__name__}, got {type(value).__name__}")
    node[leaf] = value


def parse_override(text: str) -> tuple[str, Any]:
    """Parse a CLI override `a.b=value` (value read as a Python literal when it is one)."""
    import ast

    if "=" not in text:
        raise ValueError(f"override {text!r} must look like key.path=value")
    key, raw = text.split("=", 1)
    try:
        value = ast.literal_eval(raw)
    except (ValueError, SyntaxError):
        value = raw
    return key.strip(), value
