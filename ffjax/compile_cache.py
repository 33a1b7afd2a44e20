"""jax's persistent compilation cache, configured in one place: a program compiled once on a machine (a solve, a
train step, an inference) is loaded from disk by every later process instead of compiled again.

The folder is $FFJAX_CACHE/xla/<key>, else ~/.cache/ffjax/xla/<key>; FFJAX_CACHE=off leaves jax alone, and so does a
cache directory the user set in jax already. The key names the jax and jaxlib versions, the machine and the CPU (its
model and instruction-set flags): XLA compiles CPU programs for the host's instructions, so an entry made on
another CPU or by another jax is never read."""

from __future__ import annotations

import hashlib
import os
import platform
from pathlib import Path

import jax


def _cpu() -> str:
    """The CPU's model name and instruction-set flags (Linux), else what platform reports."""
    try:
        text = Path("/proc/cpuinfo").read_text(errors="replace")
    except OSError:
        return platform.processor()
    seen: dict[str, str] = {}
    for line in text.splitlines():
        name, _, value = line.partition(":")
        name = name.strip()
        if name in ("model name", "flags", "Features", "CPU part") and name not in seen:
            seen[name] = value.strip()
    return "|".join(f"{k}={v}" for k, v in sorted(seen.items())) or platform.processor()


def key() -> str:
    """The cache's sub-folder for this jax on this CPU: 'jax<version>-<machine>-<hash of jaxlib and the CPU>'."""
    import jaxlib

    digest = hashlib.sha256("\n".join([jax.__version__, jaxlib.__version__, platform.machine(), _cpu()]).encode())
    return f"jax{jax.__version__}-{platform.machine()}-{digest.hexdigest()[:12]}"


def folder() -> Path | None:
    """Where enable() keeps the programs (None: FFJAX_CACHE=off)."""
    root = os.environ.get("FFJAX_CACHE") or str(Path.home() / ".cache" / "ffjax")
    return None if root == "off" else Path(root) / "xla" / key()


def enable() -> Path | None:
    """Turn the cache on for this process (before its first compile); returns the directory in use, or None when it
    is off or cannot be written (then every process compiles, as without it)."""
    if jax.config.jax_compilation_cache_dir:
        return Path(jax.config.jax_compilation_cache_dir)
    path = folder()
    if path is None:
        return None
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:  # a read-only home
        return None
    jax.config.update("jax_compilation_cache_dir", str(path))
    # jax keeps only programs that took >= 1 s to compile by default; most of ours (the solves, small train steps)
    # compile faster, and none of them would be kept
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path
