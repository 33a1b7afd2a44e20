"""Our own split format: a directory of `shard_#####.npz` files (image, depth, force, shape, meta), an optional
split.json manifest (shard_counts, count) and background.png; see ShardSource."""

from __future__ import annotations

import bisect
import json
from collections import OrderedDict
from pathlib import Path

import numpy as np

from ffjax.data.images import BACKGROUND_NAME, load_background
from ffjax.errors import DataError

SHARD_GLOB = "shard_*.npz"
SHOW_SHARDS = 5


class ShardSource:
    """A directory of `shard_#####.npz` files (image, depth, force, shape, meta) plus background.png.

    Shards are decompressed whole and kept in an LRU cache of `cache_bytes`; a small split therefore
    lives in memory after the first pass, a large one is best read shard-sequentially (read_range).
    """

    def __init__(self, path, background=None, cache_bytes: int = 4 << 30, validate: bool = False):
        self.path = Path(path)
        self.files = sorted(self.path.glob(SHARD_GLOB))
        self.info = self._read_manifest()
        if not self.files:
            raise DataError(f"{self.path}: no {SHARD_GLOB} files")
        counts = self.info.get("shard_counts")
        if counts is None or validate:
            counts = self._check_shards(counts)
        self.offsets = np.concatenate([[0], np.cumsum(counts)]).astype(int).tolist()
        if self.offsets[-1] == 0:
            raise DataError(f"{self.path}: the split has no records (empty shards)")
        self.background = load_background(background, self.path / BACKGROUND_NAME, str(self.path))
        if self.background is None:
            raise DataError(f"{self.path}: missing {BACKGROUND_NAME} (or pass background=...)")
        self.cache_bytes = cache_bytes
        self._cache: OrderedDict[int, dict] = OrderedDict()

    def _read_manifest(self) -> dict:
        """split.json (optional); its shard list must match the shard files present."""
        file = self.path / "split.json"
        if not file.is_file():
            return {}
        try:
            info = json.loads(file.read_text())
        except (OSError, ValueError) as e:
            raise DataError(f"{file}: unreadable manifest ({e})") from e
        counts = info.get("shard_counts") if isinstance(info, dict) else None
        if counts is None:
            return info if isinstance(info, dict) else {}
        if not isinstance(counts, list) or not all(isinstance(c, int) and c >= 0 for c in counts):
            raise DataError(f"{file}: shard_counts must be a list of record counts, got {counts!r}")
        want = [self.path / f"shard_{k:05d}.npz" for k in range(len(counts))]
        missing = [f.name for f in want if f not in self.files]
        extra = [f.name for f in self.files if f not in want]
        if missing or extra:
            raise DataError(f"{file} lists {len(counts)} shards but the folder does not match: "
                            f"missing {missing[:SHOW_SHARDS]}, unlisted {extra[:SHOW_SHARDS]} "
                            f"(an interrupted generation? rerun it to finish the split)")
        if "count" in info and info["count"] != sum(counts):
            raise DataError(f"{file}: count {info['count']} != sum of shard_counts {sum(counts)}")
        return info

    def _check_shards(self, counts: list[int] | None) -> list[int]:
        """Open every shard (force labels only) and compare its record count with the manifest's."""
        found = []
        for k, f in enumerate(self.files):
            force = self._load_member(f, "force")
            if force.ndim != 2 or force.shape[1] != 3:
                raise DataError(f"{f}: force array is {force.shape}, expected (N, 3)")
            bad = ~np.isfinite(force).all(axis=1)
            if bad.any():
                raise DataError(f"{f}: force label of record {int(np.argmax(bad))} (in this shard) is NaN/inf")
            if counts is not None and counts[k] != len(force):
                raise DataError(f"{f}: {len(force)} records, but {self.path / 'split.json'} says {counts[k]}")
            found.append(len(force))
        return found

    def __len__(self) -> int:
        return self.offsets[-1]

    def __getstate__(self):  # workers start with an empty cache instead of a pickled copy
        return {**self.__dict__, "_cache": OrderedDict()}

    @staticmethod
    def _load_member(file: Path, key: str) -> np.ndarray:
        try:
            with np.load(file, allow_pickle=False) as z:
                return z[key]
        except KeyError as e:
            raise DataError(f"{file}: no array {key!r}") from e
        except Exception as e:  # zipfile / zlib errors: a truncated or corrupt shard
            raise DataError(f"{file}: unreadable shard ({e})") from e

    def _shard(self, k: int) -> dict:
        if k in self._cache:
            self._cache.move_to_end(k)
            return self._cache[k]
        file = self.files[k]
        try:
            with np.load(file, allow_pickle=False) as z:
                arrays = {key: z[key] for key in ("image", "depth", "force")}
        except KeyError as e:
            raise DataError(f"{file}: shard lacks array {e}") from e
        except Exception as e:
            raise DataError(f"{file}: unreadable shard ({e})") from e
        n = self.offsets[k + 1] - self.offsets[k]
        img = arrays["image"]
        if img.shape[0] != n or img.shape[1:] != self.background.shape:
            raise DataError(f"{file}: image array {img.shape} does not match {n} rows of background "
                            f"{self.background.shape}")
        if arrays["depth"].shape != img.shape[:3] or arrays["force"].shape != (n, 3):
            raise DataError(f"{file}: depth {arrays['depth'].shape} / force {arrays['force'].shape} "
                            f"do not match image {img.shape}")
        self._cache[k] = arrays
        while len(self._cache) > 1 and sum(a.nbytes for s in self._cache.values()
                                           for a in s.values()) > self.cache_bytes:
            self._cache.popitem(last=False)
        return arrays

    def _locate(self, index: int) -> tuple[int, int]:
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {self.path} ({len(self)} records)")
        k = bisect.bisect_right(self.offsets, index) - 1
        return k, index - self.offsets[k]

    def __getitem__(self, index) -> dict:
        k, row = self._locate(int(index))
        s = self._shard(k)
        return {"image": s["image"][row], "background": self.background, "depth": s["depth"][row],
                "force": s["force"][row]}

    def read_range(self, start: int = 0, stop: int | None = None) -> dict:
        """Stacked image/depth/force for records [start, stop), read shard by shard."""
        stop = len(self) if stop is None else min(stop, len(self))
        parts = []
        for k in range(len(self.files)):
            lo, hi = max(start, self.offsets[k]), min(stop, self.offsets[k + 1])
            if lo < hi:
                s = self._shard(k)
                parts.append({key: a[lo - self.offsets[k]: hi - self.offsets[k]] for key, a in s.items()})
        if not parts:
            h, w = self.background.shape[:2]
            return {"image": np.zeros((0, h, w, 3), np.uint8), "depth": np.zeros((0, h, w), np.float32),
                    "force": np.zeros((0, 3), np.float32)}
        return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}

    def column(self, key: str) -> np.ndarray:
        """One per-sample array over the whole split (force, shape, or any meta array) without images."""
        return np.concatenate([self._load_member(f, key) for f in self.files])

    @property
    def forces(self) -> np.ndarray:
        return self.column("force").astype(np.float32)

    def __repr__(self) -> str:
        return f"ShardSource({str(self.path)!r}, n={len(self)})"
