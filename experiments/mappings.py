"""The memory mappings of a process that compiles many programs: XLA maps each compiled CPU program's code in
~1,000 small mappings, and jax's caches keep every program the process ever compiled. A test-suite worker reached
Linux's limit (vm.max_map_count, 65,530) at ~90% of the suite: mmap then failed inside XLA, which crashed the
process (a segfault, or a corrupted interpreter that failed at random later). The test suite and the one
command (`experiments.reproduce`, every experiment of a preset in one process) drop jax's caches past half the
limit; later work only compiles again."""

from __future__ import annotations

import functools
import gc

import jax


@functools.lru_cache(maxsize=1)
def limit() -> int | None:
    """The kernel's limit on a process's memory mappings (Linux), else None."""
    try:
        with open("/proc/sys/vm/max_map_count") as f:
            return int(f.read())
    except (OSError, ValueError):
        return None


def count() -> int | None:
    """The mappings this process holds now (Linux), else None."""
    try:
        with open("/proc/self/maps", "rb") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return None


def release_if_crowded(share: float = 0.5) -> bool:
    """Drop jax's compiled programs (`jax.clear_caches`) when this process holds more than `share` of the
    kernel's limit on mappings; whether it did (off Linux: never)."""
    top, now = limit(), count()
    if not top or now is None or now <= share * top:
        return False
    jax.clear_caches()
    gc.collect()
    return True
