"""Pinned results that hold on every CPU these tests run on.

XLA's CPU code orders float sums per instruction set, so the same training gives last-digit differences on an
AMD EPYC (AVX2) and an Intel Xeon (AVX-512/AMX) host, which grow to ~0.1 points through a few hundred steps. A
pin records the CPU kind it was made on:

- on a machine of that kind the result must match it bitwise (a refactor that changes one float shows);
- on another kind it must match within a tolerance measured between the two kinds (`close`), every string
  identical once its numbers are compared the same way.

A pin with `"bitwise": false` (and a `"why"`) is held within the tolerance on every kind, its own included:
one made before a change that moves the data by less than that tolerance (issue 30's batched simulator:
images within 1 count) and not re-made on its kind since, since no machine of that kind was at hand.

Pins live in tests/fixtures/pins/<name>/<kind>.json; `kind_name()` names this machine's kind.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

PINS = Path(__file__).parent / "fixtures" / "pins"

# Measured on the smoke ablation (tests/test_ablation.py) between an AMD EPYC (family 25 model 1, AVX2) and an
# Intel Xeon (AVX-512) host, jax 0.10.2: 320 of 900 numbers differ, by at most 0.086 (a per-axis error of
# ~19%) and 0.6% relative for means and per-axis errors; the seeds' std (a difference of two close numbers) by
# up to 6% relative, 0.085 absolute. The tolerance is about three times that.
ATOL, RTOL = 0.25, 0.02
_NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def cpu_kind() -> dict:
    """What decides XLA's CPU code here: vendor, family/model (the microarchitecture) and vector extensions."""
    info = {}
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        text = ""
    for line in text.splitlines():
        key, _, value = line.partition(":")
        key, value = key.strip(), value.strip()
        if key in ("vendor_id", "cpu family", "model", "flags") and key not in info:
            info[key] = value
        if len(info) == 4:
            break
    isa = sorted(f for f in info.get("flags", "").split() if f.startswith(("avx", "amx")))
    return {"vendor": info.get("vendor_id", "unknown"), "family": info.get("cpu family", "?"),
            "model": info.get("model", "?"), "isa": isa}


def kind_name(kind: dict | None = None) -> str:
    kind = kind or cpu_kind()
    return f"{kind['vendor']}-{kind['family']}-{kind['model']}"


def _same_kind(pinned: dict, here: dict) -> bool:
    """A pin's kind is this machine's when every field it records matches (a pin recording only the vendor
    matches every CPU of that vendor)."""
    return all(here.get(k) == v for k, v in pinned.items())


def load(name: str, jax_version: str) -> tuple[dict | None, list[dict]]:
    """(the pin of this machine's kind or None, the pins of other kinds), all made with `jax_version`."""
    here, own, others = cpu_kind(), None, []
    for path in sorted((PINS / name).glob("*.json")):
        pin = json.loads(path.read_text())
        if pin.get("jax") != jax_version:
            continue
        if own is None and pin.get("bitwise", True) and _same_kind(pin["cpu"], here):
            own = pin
        else:
            others.append(pin)
    return own, others


def strip_meta(pin: dict) -> dict:
    return {k: v for k, v in pin.items() if k not in ("cpu", "jax", "bitwise", "why")}


def differences(got, want, path: str = "", atol: float = ATOL, rtol: float = RTOL) -> list[str]:
    """Where `got` and `want` differ beyond the tolerance (floats, and numbers inside strings); [] when close."""
    if isinstance(want, dict) and isinstance(got, dict):
        if set(got) != set(want):
            return [f"{path}: keys {sorted(set(got) ^ set(want))} differ"]
        return [d for k in want for d in differences(got[k], want[k], f"{path}.{k}", atol, rtol)]
    if isinstance(want, list) and isinstance(got, list):
        if len(got) != len(want):
            return [f"{path}: {len(got)} items, pinned {len(want)}"]
        return [d for i, (a, b) in enumerate(zip(got, want)) for d in differences(a, b, f"{path}[{i}]", atol, rtol)]
    if isinstance(want, str) and isinstance(got, str):
        if _NUMBER.sub("#", got) != _NUMBER.sub("#", want):
            return [f"{path}: {got!r} != {want!r}"]
        pairs = zip(map(float, _NUMBER.findall(got)), map(float, _NUMBER.findall(want)))
        return [f"{path}: {got!r} != {want!r}" for a, b in pairs if not _close(a, b, atol, rtol)][:1]
    numbers = (int, float)
    if isinstance(want, numbers) and isinstance(got, numbers) and not isinstance(want, bool):
        return [] if _close(got, want, atol, rtol) else [f"{path}: {got} != {want}"]
    return [] if got == want else [f"{path}: {got!r} != {want!r}"]


def _close(a: float, b: float, atol: float, rtol: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return abs(a - b) <= atol + rtol * abs(b)
