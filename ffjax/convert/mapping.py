"""The mapping engine: a regex table from PyTorch names to Flax paths, every tensor shape-checked.

A table is a list of `(pattern, target, transform)`: `pattern` is a regex matched against the whole torch
key, `target` a "/"-separated Flax path that may use the pattern's groups (`\\1`), or None to ignore the
key on purpose; `transform` maps the torch array to the Flax layout. The first matching rule wins. All
problems (keys no rule matches, Flax params nothing filled, shape mismatches, conflicting duplicates) are
collected and raised together as one `ConversionError`.
"""

from __future__ import annotations

import re
from collections.abc import Callable

import numpy as np
from flax import traverse_util

Transform = Callable[[np.ndarray], np.ndarray]


def identity(x: np.ndarray) -> np.ndarray:
    return x


def linear(x: np.ndarray) -> np.ndarray:
    """torch Linear weight (out, in) -> Flax Dense kernel (in, out)."""
    return x.T


def conv(x: np.ndarray) -> np.ndarray:
    """torch Conv2d weight (O, I, kH, kW) -> Flax Conv kernel (kH, kW, I, O)."""
    return x.transpose(2, 3, 1, 0)


class ConversionError(ValueError):
    """Every mapping problem of one conversion, listed at once ({kind of problem: [items]}); a single problem
    (a file that is another model's, a config that cannot be read off it) is one line."""

    def __init__(self, source: str, problems: dict[str, list[str]]):
        self.source, self.problems = source, problems
        each = [(kind, item) for kind, items in problems.items() for item in items]
        if len(each) == 1:
            super().__init__(f"cannot convert {source}: {each[0][0]}: {each[0][1]}")
            return
        lines = [f"cannot convert {source}:"]
        for kind, items in problems.items():
            if not items:
                continue
            lines.append(f"  {kind} ({len(items)}):")
            lines.extend(f"    {item}" for item in items)
        super().__init__("\n".join(lines))


Rule = tuple[str, str | None, Transform]


def apply(
    table: list[Rule],
    state: dict[str, np.ndarray],
    expected: dict,
    source: str = "<state dict>",
    dtype=np.float32,
) -> dict:
    """Map a flat torch state dict onto the nested Flax tree whose shapes `expected` gives.

    `expected` is a nested dict of arrays or `jax.ShapeDtypeStruct`s (e.g. from `jax.eval_shape` of an
    init). Returns a nested dict of numpy arrays (cast to `dtype`) with exactly the structure of `expected`.
    """
    compiled = [(re.compile(p), t, f) for p, t, f in table]
    want = {"/".join(k): tuple(v.shape) for k, v in traverse_util.flatten_dict(expected).items()}
    out: dict[str, np.ndarray] = {}
    origin: dict[str, str] = {}
    filled: set[str] = set()
    problems: dict[str, list[str]] = {"unmapped torch keys": [], "shape mismatches": [], "conflicts": []}
    for key in sorted(state):
        value = state[key]
        rule = next(((m, t, f) for rx, t, f in compiled if (m := rx.fullmatch(key))), None)
        if rule is None:
            problems["unmapped torch keys"].append(f"{key} {tuple(value.shape)}")
            continue
        match, target, transform = rule
        if target is None:
            continue
        path = match.expand(target)
        array = np.asarray(transform(np.asarray(value)), dtype=dtype)
        if path not in want:
            problems["unmapped torch keys"].append(f"{key} {tuple(value.shape)} -> {path} (no such Flax param)")
        elif array.shape != want[path]:
            filled.add(path)  # reported here, not again as missing
            problems["shape mismatches"].append(
                f"{key} {tuple(value.shape)} -> {path}: converted {array.shape}, Flax expects {want[path]}"
            )
        elif path in out:
            if not np.array_equal(out[path], array):  # aliases (shared modules) must agree
                problems["conflicts"].append(f"{key} and {origin[path]} both map to {path} with different values")
        else:
            out[path], origin[path] = array, key
    problems["missing Flax params"] = [f"{p} {s}" for p, s in sorted(want.items()) if p not in out and p not in filled]
    if any(problems.values()):
        raise ConversionError(source, problems)
    return traverse_util.unflatten_dict({tuple(p.split("/")): v for p, v in out.items()})


def fold_prefix(state: dict[str, np.ndarray], prefix: str) -> tuple[dict, dict]:
    """Split a state dict into (keys under `prefix` with it stripped, the rest)."""
    inside = {k[len(prefix) :]: v for k, v in state.items() if k.startswith(prefix)}
    rest = {k: v for k, v in state.items() if not k.startswith(prefix)}
    return inside, rest
