"""Data pipeline: sources on disk (npz shards, FeelAnyForce CSV), the one preprocessing path, train-set
statistics, and grain datasets.

    source = data.open_split("DIR/train")                  # or "my_recordings/data.csv"
    source = data.open_split("my.csv", validate=True)      # check every row's files now (DataError names line)
    stats = data.Stats.compute(source, cfg["data"])
    ds = data.make_dataset(source, stats, 64, batch_size=64, seed=0)
    it = iter(ds); batch = next(it); state = it.get_state()  # it.set_state(state) resumes
"""

from ffjax.data.csv_source import CsvSource
from ffjax.data.pipeline import load_arrays, make_dataset
from ffjax.data.preprocess import (
    depth_to_mm,
    pad_to_square,
    preprocess_depth,
    preprocess_image,
    subtract_background,
    to_unit,
)
from ffjax.data.shards import ShardSource
from ffjax.data.sources import open_split
from ffjax.data.stats import Stats
from ffjax.errors import DataError

__all__ = [
    "CsvSource", "DataError", "ShardSource", "Stats", "depth_to_mm", "load_arrays", "make_dataset",
    "open_split", "pad_to_square", "preprocess_depth", "preprocess_image", "subtract_background", "to_unit",
    "write_csv",
]


def write_csv(source, out, progress: bool = True):
    """Write a split in the FeelAnyForce release layout (see ffjax.data.csv_layout)."""
    # imported here so `python -m ffjax.data.csv_layout` does not find itself half-imported
    from ffjax.data.csv_layout import write_csv as _write_csv

    return _write_csv(source, out, progress)
