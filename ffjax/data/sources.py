"""Random-access sources over a split on disk: our npz shards, or the FeelAnyForce release CSV.

Both yield the same record, `{"image": uint8 HxWx3 RGB, "background": uint8 HxWx3, "depth": float32 HxW mm,
"force": float32 (3,)}`, and both also offer `read_range(start, stop)` (stacked arrays, the fast path used by
statistics, evaluation and the converter) and a `forces` array read without touching any image.
"""

from __future__ import annotations

import bisect
import csv
import json
import os
from collections import OrderedDict
from pathlib import Path

import cv2
import numpy as np

from ffjax.data.validate import (
    DataError,
    check_depth_values,
    depth_problem,
    image_problem,
    parse_ft_cell,
    png_size,
    report_bad_rows,
    same_file_key,
)
from ffjax.files import atomic_write_bytes

SHARD_GLOB = "shard_*.npz"
SHOW_SHARDS = 5
CSV_NAME = "data.csv"
BACKGROUND_NAME = "background.png"


def read_rgb(path: str | os.PathLike, what: str = "image") -> np.ndarray:
    """Read a colour image as RGB uint8 (an alpha channel is dropped). A missing, unreadable or truncated
    file raises DataError, and so do images a colour sensor never writes: more than 8 bits per channel
    (decoding would silently drop the low bits: 12-bit data in 16 bits would read as a near-black frame) and
    grayscale (it would become three equal channels, a colour the model never saw)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"missing {what}: {path}")
    raw = np.fromfile(path, dtype=np.uint8)
    img = cv2.imdecode(raw, cv2.IMREAD_UNCHANGED) if raw.size else None
    if img is None:
        raise DataError(f"unreadable or truncated {what}: {path}")
    if img.dtype != np.uint8:
        raise DataError(f"{what} {path} has {img.dtype} pixels, not 8-bit: convert it to 8 bits per channel "
                        "first (for 12-bit data in 16-bit files, scale by 255/4095), as the training frames are")
    if img.ndim == 2 or img.shape[2] == 1:
        raise DataError(f"{what} {path} is grayscale: this model reads colour (RGB) frames of a tactile sensor; "
                        "record or export the frames in colour")
    return np.ascontiguousarray(img[..., 2::-1])  # cv2 decodes to BGR(A): RGB, alpha dropped


def write_rgb(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an RGB uint8 image as a PNG (cv2 wants BGR), atomically."""
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))
    if not ok:
        raise OSError(f"could not encode {path}")
    atomic_write_bytes(path, buf.tobytes())


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


def _background(background, default_path: Path | None, where: str) -> np.ndarray | None:
    if isinstance(background, np.ndarray):
        bg = background
    elif background is not None:
        bg = read_rgb(background, "background")
    elif default_path is not None and default_path.is_file():
        bg = read_rgb(default_path, "background")
    else:
        return None
    if bg.dtype != np.uint8 or bg.ndim != 3 or bg.shape[2] != 3:
        raise DataError(f"{where}: background must be uint8 HxWx3, got {bg.dtype} {bg.shape}")
    return bg


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
        self.background = _background(background, self.path / BACKGROUND_NAME, str(self.path))
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


def parse_ft(cell: str, where: str) -> np.ndarray:
    """Parse an FT cell: 6 ("Fx Fy Fz Tx Ty Tz", the release) or 3 finite numbers; returns the force (3,)."""
    force, why = parse_ft_cell(cell)
    if why:
        raise DataError(f"{where}: {why}")
    return force


class CsvSource:
    """The FeelAnyForce release layout: a CSV with `tactile` (image path), optional `depth` (.npy, mm)
    and `FT` ("Fx Fy Fz Tx Ty Tz") columns; paths are relative to the CSV's folder (absolute ones work too).

    The no-contact background is, in this order: the `background` argument (path or RGB array), a
    per-row `background` column (path; images are cached), or `background.png` beside the CSV.
    FT cells are all parsed on open (and rows are checked for duplicates); validate=True also checks every
    row's image and depth file from their headers (exists, complete, right size), and skip_bad_rows=True
    drops bad rows (logged; kept in `skipped` as (where, why)) instead of raising. Images are decoded, and
    checked again, when a record is read.
    """

    def __init__(self, csv_path, background=None, validate: bool = False, skip_bad_rows: bool = False):
        self.csv_path = Path(csv_path)
        self.root = self.csv_path.parent
        columns, rows, lines = self._read()
        missing = [c for c in ("tactile", "FT") if c not in columns]
        if missing:
            raise DataError(f"{self.csv_path}: missing column(s) {missing}; found {columns}")
        if not rows:
            raise DataError(f"{self.csv_path}: no data rows (an empty split)")
        self.has_depth = "depth" in columns
        self._bg_column = "background" in columns and background is None
        self.background = None
        if not self._bg_column:
            self.background = _background(background, self.root / BACKGROUND_NAME, str(self.csv_path))
            if self.background is None:
                raise DataError(f"{self.csv_path}: no background: pass background=..., add a 'background' "
                                f"column, or put {BACKGROUND_NAME} beside the CSV")
        self._bg_cache: dict[str, np.ndarray] = {}
        self._bg_size: dict[str, tuple] = {}
        self._row_ids, self._lines = list(range(len(rows))), lines
        forces, problems = self._check_cells(rows, len(columns))
        if validate or skip_bad_rows:
            problems.update({i: why for i, r in enumerate(rows) if i not in problems
                             for why in [self._check_files(r)] if why})
        self.skipped = [(self._where(i), why) for i, why in sorted(problems.items())]
        report_bad_rows(str(self.csv_path), self.skipped, len(rows), skip_bad_rows)
        keep = [i for i in range(len(rows)) if i not in problems]
        self._row_ids, self._lines = keep, [lines[i] for i in keep]
        self.tactile = [rows[i]["tactile"] for i in keep]
        self.depth_paths = [rows[i].get("depth", "") for i in keep]
        self.bg_paths = [rows[i].get("background", "") for i in keep]
        self.forces = np.stack([forces[i] for i in keep])

    def _read(self) -> tuple[list[str], list[dict], list[int]]:
        """Header, rows (cells stripped; None marks a missing cell, key None extra ones), line numbers."""
        if not self.csv_path.is_file():
            raise DataError(f"missing CSV: {self.csv_path}")
        rows, lines = [], []
        try:
            with open(self.csv_path, newline="", encoding="utf-8-sig") as f:
                reader = csv.DictReader(f)
                columns = [c.strip() for c in (reader.fieldnames or [])]
                reader.fieldnames = columns
                for r in reader:
                    rows.append({k: v if v is None or k is None else v.strip() for k, v in r.items()})
                    lines.append(reader.line_num)
        except (UnicodeDecodeError, csv.Error) as e:
            raise DataError(f"{self.csv_path} line {len(lines) + 2}: not a readable CSV ({e})") from e
        return columns, rows, lines

    def _check_cells(self, rows: list[dict], n_columns: int) -> tuple[list, dict[int, str]]:
        """Forces (None where bad) and {row: why} from the cells alone: cell count, paths, FT, duplicates."""
        forces, problems, seen = [], {}, {}
        for i, r in enumerate(rows):
            n_cells = n_columns + len(r.get(None, [])) - sum(v is None for k, v in r.items() if k is not None)
            force, why = None, None
            if n_cells != n_columns:
                why = f"{n_cells} cells, the header has {n_columns}"
            elif not r["tactile"]:
                why = "empty tactile path"
            else:
                force, why = parse_ft_cell(r["FT"])
            if why is None:
                key = same_file_key(self._resolve(r["tactile"]))
                if key in seen:
                    why = f"duplicate row: tactile image {r['tactile']} is also on line {seen[key]}"
                seen.setdefault(key, self._lines[i])
            forces.append(force if why is None else None)
            if why:
                problems[i] = why
        return forces, problems

    def _check_files(self, r: dict) -> str | None:
        """Why a row's files are unusable (missing, truncated, wrong size), from headers only; None if fine."""
        want, why = self._background_size(r)
        if why:
            return why
        image = self._resolve(r["tactile"])
        why = image_problem(image, want)
        if why or not (self.has_depth and r.get("depth")):
            return why
        return depth_problem(self._resolve(r["depth"]), want or png_size(image))

    def _background_size(self, r: dict) -> tuple[tuple | None, str | None]:
        """(height, width) of this row's background when cheaply known, or (None, why it is unusable)."""
        if self.background is not None:
            return self.background.shape[:2], None
        cell = r.get("background") or ""
        if not cell:
            return None, "empty background cell"
        if cell not in self._bg_size:
            path = self._resolve(cell)
            self._bg_size[cell] = (png_size(path), image_problem(path, None, "background image"))
        return self._bg_size[cell]

    def _where(self, i: int) -> str:
        return f"{self.csv_path} row {self._row_ids[i]} (line {self._lines[i]})"

    def _resolve(self, p: str) -> Path:
        q = Path(p)
        return q if q.is_absolute() else self.root / q

    def __len__(self) -> int:
        return len(self.tactile)

    def _row_background(self, i: int) -> np.ndarray:
        if self.background is not None:
            return self.background
        p = self.bg_paths[i]
        if not p:
            raise DataError(f"{self._where(i)}: empty background cell")
        if p not in self._bg_cache:
            self._bg_cache[p] = _background(self._resolve(p), None, self._where(i))
        return self._bg_cache[p]

    def __getitem__(self, index) -> dict:
        i = int(index)
        if not 0 <= i < len(self):
            raise IndexError(f"index {i} out of range for {self.csv_path} ({len(self)} rows)")
        where = self._where(i)
        try:
            image = read_rgb(self._resolve(self.tactile[i]), "tactile image")
        except DataError as e:
            raise DataError(f"{where}: {e}") from None
        background = self._row_background(i)
        if image.shape != background.shape:
            raise DataError(f"{where}: image {self.tactile[i]} is {image.shape}, "
                            f"background is {background.shape}")
        h, w = image.shape[:2]
        if self.has_depth and self.depth_paths[i]:
            dpath = self._resolve(self.depth_paths[i])
            try:
                depth = np.load(dpath, allow_pickle=False)
            except FileNotFoundError:
                raise DataError(f"{where}: missing depth file {dpath}") from None
            except Exception as e:
                raise DataError(f"{where}: unreadable depth file {dpath} ({e})") from None
            depth = np.squeeze(depth)
            if depth.shape != (h, w):
                raise DataError(f"{where}: depth {dpath} is {depth.shape}, image is {(h, w)}")
            try:
                depth = check_depth_values(depth, dpath)
            except (DataError, ValueError, TypeError) as e:
                raise DataError(f"{where}: {e}") from None
        else:
            depth = np.zeros((h, w), np.float32)
        return {"image": image, "background": background, "depth": depth, "force": self.forces[i]}

    def read_range(self, start: int = 0, stop: int | None = None) -> dict:
        stop = len(self) if stop is None else min(stop, len(self))
        recs = [self[i] for i in range(start, stop)]
        if not recs:
            return {"image": np.zeros((0, 1, 1, 3), np.uint8), "depth": np.zeros((0, 1, 1), np.float32),
                    "force": np.zeros((0, 3), np.float32)}
        out = {k: np.stack([r[k] for r in recs]) for k in ("image", "depth", "force")}
        if self._bg_column:  # per-row backgrounds: keep them so batched preprocessing can use them
            out["background"] = np.stack([r["background"] for r in recs])
        return out

    def __repr__(self) -> str:
        return f"CsvSource({str(self.csv_path)!r}, n={len(self)})"
