"""grain pipelines over a source: shuffled, repeated, preprocessed, batched, with checkpointable iterators.

Two paths, same numbers. `in_memory` (the default whenever the preprocessed split fits the budget)
preprocesses the split once and batches indices, gathering rows from arrays: tens of thousands of
images per second, so the pipeline never bounds a CPU-scale training run. Streaming preprocesses per
record inside grain (optionally in `worker_count` processes), for splits too large for memory.
"""

from __future__ import annotations

import sys

import grain
import numpy as np
from absl import flags

from ffjax.data import epoch_order
from ffjax.data.preprocess import preprocess_depth, preprocess_image
from ffjax.data.stats import Stats, source_background

IN_MEMORY_BYTES = 4 << 30


def fits_in_memory(n: int, input_size: int) -> bool:
    """Whether n preprocessed records (image + depth, float32) fit the in-memory path's budget."""
    return n * input_size**2 * 16 <= IN_MEMORY_BYTES


def load_arrays(source, stats: Stats, input_size: int, chunk: int = 512) -> dict:
    """The whole split preprocessed: {"image": (N,S,S,3), "depth": (N,S,S), "force": (N,3)} float32."""
    n = len(source)
    out = {"image": np.empty((n, input_size, input_size, 3), np.float32),
           "depth": np.empty((n, input_size, input_size), np.float32),
           "force": np.empty((n, 3), np.float32)}
    for a in range(0, n, chunk):
        b = source.read_range(a, min(a + chunk, n))
        bg = b.get("background", source_background(source))
        out["image"][a: a + len(b["force"])] = preprocess_image(b["image"], bg, stats, input_size)
        out["depth"][a: a + len(b["force"])] = preprocess_depth(b["depth"], stats, input_size)
        out["force"][a: a + len(b["force"])] = b["force"]
    return out


class Preprocess:
    """Record -> model-ready example (a class, not a lambda, so worker processes can pickle it)."""

    def __init__(self, stats: Stats, input_size: int):
        self.stats, self.input_size = stats, input_size

    def __call__(self, r: dict) -> dict:
        return {"image": preprocess_image(r["image"], r["background"], self.stats, self.input_size),
                "depth": preprocess_depth(r["depth"], self.stats, self.input_size),
                "force": np.asarray(r["force"], np.float32)}


class Gather:
    """A batch of indices -> a batch of rows from preprocessed arrays."""

    def __init__(self, arrays: dict):
        self.arrays = arrays

    def __call__(self, idx) -> dict:
        idx = np.asarray(idx)
        return {k: v[idx] for k, v in self.arrays.items()}


class ShuffledIndexBatches(grain.MapDataset):
    """Batch j of indices into [0, n), reshuffled every epoch, endless: the same batches as
    `MapDataset.range(n).shuffle(seed).repeat(None).batch(batch_size, drop_remainder=True)` (tested), from a
    whole epoch's permutation computed at once (`epoch_order`) instead of one grain call per element."""

    def __init__(self, n: int, batch_size: int, seed: int):
        super().__init__()
        self.n, self.batch_size, self.seed = int(n), int(batch_size), int(seed)
        self._perms: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return sys.maxsize // self.batch_size

    def __str__(self) -> str:
        return f"ShuffledIndexBatches(n={self.n}, batch_size={self.batch_size}, seed={self.seed})"

    def _perm(self, epoch: int) -> np.ndarray:
        if epoch not in self._perms:
            # a batch spans at most two epochs: keep the one before this
            self._perms = {e: p for e, p in self._perms.items() if e == epoch - 1}
            self._perms[epoch] = epoch_order.permutation(self.n, (self.seed + epoch) % 2**32)
        return self._perms[epoch]

    def __getitem__(self, index):
        if isinstance(index, slice):
            return self.slice(index)
        pos = index * self.batch_size + np.arange(self.batch_size)
        epochs, k = np.divmod(pos, self.n)
        return np.concatenate([self._perm(int(e))[k[epochs == e]] for e in np.unique(epochs)])


def _augmented(ds: grain.MapDataset, augment, seed: int) -> grain.MapDataset:
    return ds if augment is None else ds.random_map(augment, seed=seed)


def _mark_flags_parsed():
    # grain 0.2.18 worker processes read absl flags and raise UnparsedFlagAccessError unless parsed.
    if not flags.FLAGS.is_parsed():
        flags.FLAGS.mark_as_parsed()


def make_dataset(source, stats: Stats, input_size: int, batch_size: int, seed: int, shuffle: bool = True,
                 num_epochs: int | None = None, drop_remainder: bool = True, worker_count: int = 0,
                 in_memory: bool | None = None, process_index: int = 0, process_count: int = 1,
                 arrays: dict | None = None, augment=None) -> grain.IterDataset:
    """Batches {"image": (B,S,S,3), "depth": (B,S,S), "force": (B,3)} float32 numpy.

    num_epochs=None repeats forever (each epoch reshuffled from `seed`). `iter(ds)` gives an iterator
    with get_state()/set_state() for checkpoints. worker_count > 0 streams through grain worker
    processes (call from under `if __name__ == "__main__":`). `process_index/process_count` give each
    host a disjoint slice of every epoch. `arrays` reuses a load_arrays result (in-memory path). `augment`: a
    grain RandomMap applied to every batch (ffjax.data.drift), its draws fixed by `seed` and the batch's index, so a
    resumed iterator gives the same frames.
    """
    n = len(source)
    if in_memory is None:
        in_memory = arrays is not None or (worker_count == 0 and fits_in_memory(n, input_size))
    if in_memory:
        arrays = arrays if arrays is not None else load_arrays(source, stats, input_size)
        if shuffle and process_count == 1 and num_epochs is None and drop_remainder:  # the training path
            ds = ShuffledIndexBatches(len(arrays["force"]), batch_size, seed).map(Gather(arrays))
            return _augmented(ds, augment, seed).to_iter_dataset(grain.ReadOptions(num_threads=0))
        ds = grain.MapDataset.range(len(arrays["force"]))
    else:
        ds = grain.MapDataset.source(source)
    if shuffle:
        ds = ds.shuffle(seed=seed)
    if process_count > 1:
        ds = ds.slice(slice(process_index, None, process_count))
    ds = ds.repeat(num_epochs)
    if in_memory:
        ds = ds.batch(batch_size, drop_remainder=drop_remainder, batch_fn=np.asarray).map(Gather(arrays))
        return _augmented(ds, augment, seed).to_iter_dataset(grain.ReadOptions(num_threads=0))
    ds = _augmented(ds.map(Preprocess(stats, input_size)).batch(batch_size, drop_remainder=drop_remainder), augment,
                    seed)
    if worker_count > 0:
        _mark_flags_parsed()
        return ds.to_iter_dataset().mp_prefetch(grain.MultiprocessingOptions(num_workers=worker_count))
    return ds.to_iter_dataset()
