"""The training batches' order computed a whole epoch at a time is grain's order exactly, and the iterator
state keeps its meaning (runs checkpointed before resume at the same batch)."""

import grain
import numpy as np
import pytest
from grain._src.python.experimental.index_shuffle.python import index_shuffle_module

from ffjax.data import epoch_order
from ffjax.data.pipeline import Gather, ShuffledIndexBatches


# sizes around the cipher's block sizes (16 bits at least, then even) and the quick split; seeds at the edges
@pytest.mark.parametrize("n", [1, 2, 3, 7, 257, 6000, 65536, 70001])
@pytest.mark.parametrize("seed", [0, 2**32 - 1, 123456789])
def test_permutation_is_grains_index_shuffle(n, seed):
    want = [index_shuffle_module.index_shuffle(k, max_index=n - 1, seed=seed, rounds=4) for k in range(n)]
    assert epoch_order.permutation(n, seed).tolist() == want


def _grain_batches(n, batch, seed):
    return grain.MapDataset.range(n).shuffle(seed=seed).repeat(None).batch(batch, drop_remainder=True)


@pytest.mark.parametrize(("n", "batch", "seed"), [(37, 8, 0), (100, 64, 3), (64, 64, 7), (5, 2, 11)])
def test_batches_are_grains_across_epoch_boundaries(n, batch, seed):
    ours, theirs = ShuffledIndexBatches(n, batch, seed), _grain_batches(n, batch, seed)
    for j in list(range(3 * n // batch + 3)) + [10_000, 10_001]:  # batches that span two epochs included
        assert ours[j].tolist() == [int(i) for i in theirs[j]], j


def test_iterator_state_resumes_where_the_grain_chain_would():
    n, batch, seed = 37, 8, 0
    arrays = {"force": np.arange(n, dtype=np.float32)[:, None]}
    old = iter(_grain_batches(n, batch, seed).map(Gather(arrays)).to_iter_dataset(grain.ReadOptions(num_threads=0)))
    for _ in range(6):
        next(old)
    state = old.get_state()  # what a checkpoint written before this change holds
    new = iter(ShuffledIndexBatches(n, batch, seed).map(Gather(arrays)).to_iter_dataset(
        grain.ReadOptions(num_threads=0)))
    assert new.get_state().keys() == state.keys()
    new.set_state(state)
    for _ in range(5):
        assert np.array_equal(next(new)["force"], next(old)["force"])
