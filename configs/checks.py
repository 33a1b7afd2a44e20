"""Checkers for config values and the tree helpers that turn configs/base.py into defaults and rules.

A checker takes a value and returns None (fine) or the end of a sentence that follows the dotted key:
"must be > 0, got -1".
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable
from typing import Any

Check = Callable[[Any], "str | None"]


AS_DEFAULT = "<the default>"  # Key.before when a config without the key meant the default


@dataclasses.dataclass(frozen=True)
class Key:
    """A config key in configs/base.py: its default, the check every value of it must pass, what a saved config
    without it means (`before`: the value the code used before the key existed; configs.upgrade fills it in)
    and whether caches ignore it at that value (`late`: added after runs and datasets were saved, so their cache
    keys, hashed without it, stay valid)."""

    default: Any
    check: Check
    before: Any = AS_DEFAULT
    late: bool = False

    @property
    def old_value(self) -> Any:
        return copy.deepcopy(self.default if self.before == AS_DEFAULT else self.before)


def defaults(spec: dict) -> dict:
    """The nested config of a spec: every Key replaced by its default (a fresh copy)."""
    return {k: defaults(v) if isinstance(v, dict) else copy.deepcopy(v.default) for k, v in spec.items()}


def keys(spec: dict, prefix: str = "") -> dict[str, Key]:
    """dotted key -> Key, for every Key of a spec."""
    out = {}
    for k, v in spec.items():
        out.update(keys(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
    return out


def rules(spec: dict) -> dict[str, Check]:
    """dotted key -> checker, for every Key of a spec."""
    return {k: v.check for k, v in keys(spec).items()}


def derive(parent: dict, changes: dict, where: str = "") -> dict:
    """A preset: a deep copy of `parent` with `changes` (a nested dict of the keys that differ) applied.
    A key the parent lacks is an error (a typo would otherwise add a key nothing reads)."""
    out = copy.deepcopy(parent)
    for k, v in changes.items():
        if k not in out:
            raise KeyError(f"preset changes unknown config key {where + k!r}")
        out[k] = derive(out[k], v, f"{where}{k}.") if isinstance(v, dict) else copy.deepcopy(v)
    return out


def is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def num(lo=None, hi=None, lo_open=False, hi_open=False, integer=False, optional=False) -> Check:
    """A (finite) number in [lo, hi] (open ends when *_open), an int when `integer`; None too if optional."""
    kind = "an integer" if integer else "a number"
    rng = "".join([f" {'>' if lo_open else '>='} {lo}" if lo is not None else "",
                   " and" if lo is not None and hi is not None else "",
                   f" {'<' if hi_open else '<='} {hi}" if hi is not None else ""])

    def check(v):
        if v is None and optional:
            return None
        if not is_num(v) or (integer and not isinstance(v, int)) or not math.isfinite(v):
            return f"must be {kind}{rng}, got {v!r}"
        if lo is not None and (v <= lo if lo_open else v < lo) or hi is not None and (v >= hi if hi_open else v > hi):
            return f"must be{rng}, got {v!r}"
        return None

    return check


def because(check: Check, why: str) -> Check:
    """`check`, its refusal followed by `why` (where its bound comes from)."""
    def explained(v):
        err = check(v)
        return err and f"{err}: {why}"

    return explained


def seq(item: Check, length=None, min_len=1, ordered=False, optional=False) -> Check:
    """A list/tuple of `length` (or >= min_len) items each passing `item`; `ordered`: lo <= hi."""
    def check(v):
        if v is None and optional:
            return None
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


def choice(*options, optional=False) -> Check:
    def check(v):
        if (v is None and optional) or v in options:
            return None
        return f"must be one of {', '.join(repr(o) for o in options)}, got {v!r}"

    return check


def boolean(v) -> str | None:
    return None if isinstance(v, bool) else f"must be True or False, got {v!r}"


POS_INT, NN_INT, INT = num(1, integer=True), num(0, integer=True), num(integer=True)
POS, NN, PROB = num(0, lo_open=True), num(0), num(0, 1)
SCALE = seq(num(0, 1, lo_open=True), length=2, ordered=True)
