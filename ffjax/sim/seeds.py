"""Render seeds of a simulated dataset: one per press, no two presses of a config seed alike.

Split `index` of config seed `seed` owns the block [(seed * MAX_SPLITS + index) * BLOCK, ... + BLOCK): blocks are
disjoint across splits and config seeds while a split holds at most BLOCK presses and a config at most MAX_SPLITS
splits. The seeds are int64 (numpy's), which bounds the config seed: MAX_SEED, checked by configs for `seed`.
"""

from __future__ import annotations

import numpy as np

BLOCK = 2**24  # render seeds (so presses) per split
MAX_SPLITS = 4096  # splits per config seed
MAX_SEED = 2**63 // (MAX_SPLITS * BLOCK) - 1  # the last config seed whose last block ends within int64


def render_seeds(seed: int, index: int, n: int) -> np.ndarray:
    """The n render seeds (int64) of split `index` of config seed `seed`."""
    # an index past MAX_SPLITS is a stream no dataset's split uses (the benchmark's): any that fits int64
    if not 0 <= seed <= MAX_SEED or index < 0 or (seed * MAX_SPLITS + index + 1) * BLOCK > 2**63 \
            or not 0 <= n <= BLOCK:
        raise ValueError(f"no render seed block for config seed {seed}, split {index}, {n} presses: the seed must "
                         f"be in [0, {MAX_SEED}], a split hold at most {BLOCK} presses, and the block fit in int64")
    return (seed * MAX_SPLITS + index) * BLOCK + np.arange(n, dtype=np.int64)
