"""Open a split on disk as a random-access source: our npz shards (ffjax.data.shards.ShardSource) or the
FeelAnyForce release CSV (ffjax.data.csv_source.CsvSource).

Both yield the same record, `{"image": uint8 HxWx3 RGB, "background": uint8 HxWx3, "depth": float32 HxW mm,
"force": float32 (3,)}`, and both also offer `read_range(start, stop)` (stacked arrays, the fast path used by
statistics, evaluation and the converter) and a `forces` array read without touching any image.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ffjax.data.csv_source import CSV_NAME, CsvSource
from ffjax.data.shards import SHARD_GLOB, ShardSource
from ffjax.errors import DataError


def open_split(path: str | os.PathLike, background: str | os.PathLike | np.ndarray | None = None, *,
               validate: bool = False, skip_bad_rows: bool = False):
    """Open a split: a shard directory (shard_*.npz), a release-layout CSV file, or a folder holding data.csv.

    `background` overrides the no-contact frame (a path or an RGB uint8 array); see CsvSource for the
    order in which a CSV's background is otherwise found. validate=True checks every row's files (or every
    shard) up front, so a bad row fails now rather than mid-run; skip_bad_rows=True (CSV; implies
    validate) drops bad rows instead, logging how many and why.
    """
    path = Path(path)
    if path.is_dir():
        if any(path.glob(SHARD_GLOB)) or (path / "split.json").is_file():
            return ShardSource(path, background=background, validate=validate)
        if (path / CSV_NAME).is_file():
            return CsvSource(path / CSV_NAME, background=background, validate=validate, skip_bad_rows=skip_bad_rows)
        raise DataError(f"{path}: no {SHARD_GLOB} shards and no {CSV_NAME}; not a split")
    if path.suffix.lower() == ".csv":
        return CsvSource(path, background=background, validate=validate, skip_bad_rows=skip_bad_rows)
    raise DataError(f"{path}: not a split directory or a .csv file")
