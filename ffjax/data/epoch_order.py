"""grain's shuffle order, a whole epoch at a time in numpy.

`grain.MapDataset.shuffle(seed)` places record k of epoch e at `index_shuffle(k, n - 1, seed + e, rounds=4)`:
a 4-round Simon block cipher (round keys from C++'s std::seed_seq) with cycle walking. grain evaluates it
one element at a time from Python, taking CPU for every batch from the cores the train step runs on (issue 14);
the same permutation vectorized costs a small part of that per epoch (measured: docs/benchmarks.md). The tests
compare it with grain's own function for many sizes and seeds, so the training order stays grain's exactly.
"""

from __future__ import annotations

import math

import numpy as np

_M32 = 0xFFFFFFFF
ROUNDS = 4  # grain's shuffle uses 4


def seed_seq_generate(seed: int, n: int) -> list[int]:
    """std::seed_seq{seed}.generate(n words) as the C++ standard ([rand.util.seedseq]) defines it."""
    v, s = [int(seed) & _M32], 1
    out = [0x8B8B8B8B] * n
    t = 11 if n >= 623 else 7 if n >= 68 else 5 if n >= 39 else 3 if n >= 7 else (n - 1) // 2
    p, m = (n - t) // 2, max(s + 1, n)
    q = p + t

    def mix(x):
        return (x ^ (x >> 27)) & _M32

    for k in range(m):
        r1 = (1664525 * mix(out[k % n] ^ out[(k + p) % n] ^ out[(k - 1) % n])) & _M32
        r2 = (r1 + (s if k == 0 else k % n + v[k - 1] if k <= s else k % n)) & _M32
        out[(k + p) % n] = (out[(k + p) % n] + r1) & _M32
        out[(k + q) % n] = (out[(k + q) % n] + r2) & _M32
        out[k % n] = r2
    for k in range(m, m + n):
        r3 = (1566083941 * mix((out[k % n] + out[(k + p) % n] + out[(k - 1) % n]) & _M32)) & _M32
        r4 = (r3 - k % n) & _M32
        out[(k + p) % n] ^= r3
        out[(k + q) % n] ^= r4
        out[k % n] = r4
    return out


def _block_bits(max_index: int) -> int:
    bits = math.ceil(math.log2(max_index))
    return max(bits + bits % 2, 16)


def permutation(n: int, seed: int, rounds: int = ROUNDS) -> np.ndarray:
    """[index_shuffle(k, n - 1, seed, rounds) for k in range(n)] as int64, vectorized."""
    if n <= 1:
        return np.zeros(n, np.int64)
    w = _block_bits(n - 1) // 2
    mask = np.uint64((1 << w) - 1)
    keys = [np.uint64(k) & mask for k in seed_seq_generate(seed, rounds)]
    one, two, eight, wide = np.uint64(1), np.uint64(2), np.uint64(8), np.uint64(w)

    def rotl(x, r):
        return ((x << r) | (x >> (wide - r))) & mask

    def f(x):
        return (rotl(x, one) & rotl(x, eight)) ^ rotl(x, two)

    def encrypt(x):
        left, right = (x >> wide) & mask, x & mask
        for i in range(0, rounds, 2):
            left = left ^ f(right) ^ keys[i]
            right = right ^ f(left) ^ keys[i + 1]
        return (left << wide) | right

    out = np.arange(n, dtype=np.uint64)
    todo = np.arange(n)
    while todo.size:  # cycle walking: encrypt again until the value falls in [0, n)
        out[todo] = encrypt(out[todo])
        todo = todo[out[todo] > np.uint64(n - 1)]
    return out.astype(np.int64)
