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
from ffjax.data.validate import file_problem
from ffjax.errors import DataError


def is_csv_path(path: str | os.PathLike) -> bool:
    """Whether `path` names a CSV file: a .csv extension in any case (DATA.CSV, as Windows tools write it)."""
    return Path(path).suffix.lower() == ".csv"


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
        if os.path.lexists(path / CSV_NAME):  # CsvSource says what is wrong with one that is not a file
            return CsvSource(path / CSV_NAME, background=background, validate=validate, skip_bad_rows=skip_bad_rows)
        raise DataError(f"{path}: no {SHARD_GLOB} shards and no {CSV_NAME}; not a split (give a shard folder, a "
                        f"folder holding {CSV_NAME}, or the .csv file itself)")
    if is_csv_path(path):
        return CsvSource(path, background=background, validate=validate, skip_bad_rows=skip_bad_rows)
    raise DataError(file_problem(path, "split") or f"{path}: not a split directory or a .csv file")
