"""The FeelAnyForce release layout: data.csv (tactile, depth, FT; optional per-row background) with paths
relative to the CSV's folder; see CsvSource. Cells are checked on open, files optionally (validate)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ffjax.data.images import BACKGROUND_NAME, load_background, read_rgb
from ffjax.data.validate import (
    check_depth_values,
    depth_problem,
    file_problem,
    image_problem,
    parse_ft_cell,
    png_size,
    report_bad_rows,
    same_file_key,
)
from ffjax.errors import DataError

CSV_NAME = "data.csv"


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
            self.background = load_background(background, self.root / BACKGROUND_NAME, str(self.csv_path))
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
        sizes = {size: cell for cell, (size, why) in self._bg_size.items() if size and not why}
        if len(sizes) > 1:  # per-row backgrounds (validate): one split, one frame size, or batches cannot stack
            (a, ca), (b, cb) = list(sizes.items())[:2]
            raise DataError(f"{self.csv_path}: background {ca} is {a[0]}x{a[1]} px but {cb} is {b[0]}x{b[1]} px: a "
                            "split holds frames of one size (split it, or resize the frames)")
        keep = [i for i in range(len(rows)) if i not in problems]
        self._row_ids, self._lines = keep, [lines[i] for i in keep]
        self.tactile = [rows[i]["tactile"] for i in keep]
        self.depth_paths = [rows[i].get("depth", "") for i in keep]
        self.bg_paths = [rows[i].get("background", "") for i in keep]
        self.forces = np.stack([forces[i] for i in keep])

    def _read(self) -> tuple[list[str], list[dict], list[int]]:
        """Header, rows (cells stripped; None marks a missing cell, key None extra ones), line numbers."""
        why = file_problem(self.csv_path, "CSV")
        if why:
            raise DataError(why)
        rows, lines = [], []
        try:
            with open(self.csv_path, newline="", encoding="utf-8-sig") as f:
                reader = csv.DictReader(f)
                columns = [c.strip() for c in (reader.fieldnames or [])]
                twice = sorted({c for c in columns if columns.count(c) > 1})
                if twice:  # DictReader would keep the last one silently
                    at = {c: ", ".join(str(k + 1) for k, x in enumerate(columns) if x == c) for c in twice}
                    where = ", ".join(f"{c!r} (columns {at[c]})" for c in twice)
                    raise DataError(f"{self.csv_path}: the header names {where} more than once; keep one of each")
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
                    why = (f"duplicate row: tactile image {r['tactile']} is the file of line {seen[key]} (the same "
                           "path, or a link to it)")
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
            self._bg_cache[p] = load_background(self._resolve(p), None, self._where(i))
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
            why = file_problem(dpath, "depth file")
            if why:
                raise DataError(f"{where}: {why}")
            try:
                depth = np.load(dpath, allow_pickle=False)
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
        first = recs[0]["image"].shape
        for i, r in enumerate(recs):
            if r["image"].shape != first:
                raise DataError(f"{self._where(start + i)}: frame {self.tactile[start + i]} is {r['image'].shape[:2]}"
                                f", {self.tactile[start]} is {first[:2]}: a split holds frames of one size")
        out = {k: np.stack([r[k] for r in recs]) for k in ("image", "depth", "force")}
        if self._bg_column:  # per-row backgrounds: keep them so batched preprocessing can use them
            out["background"] = np.stack([r["background"] for r in recs])
        return out

    def __repr__(self) -> str:
        return f"CsvSource({str(self.csv_path)!r}, n={len(self)})"
