"""Per-row checks of a split on disk, cheap enough to run over every row when a CSV is opened.

Files are checked from their headers and trailers, not decoded: a PNG's size (IHDR chunk) and its IEND
trailer (an interrupted copy or download loses the end of the file), and a depth .npy's header (shape,
dtype) and length. Damage inside a file that passes these (a bad zlib stream mid-PNG) is still caught, with
the same file and row, when the record is read. Every problem is reported as "FILE row R (line L): what".
"""

from __future__ import annotations

import errno
import logging
import math
import os
import re
import stat
import struct
from pathlib import Path

import numpy as np

from ffjax.errors import DataError

log = logging.getLogger("ffjax.data")

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_TRAILER = b"\x00\x00\x00\x00IEND\xaeB`\x82"  # the IEND chunk: length 0, type, CRC
FT_NAMES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
# The largest force per axis a label may hold, N: a vision-based tactile sensor's gel tears long before (the paper
# presses to ~15-20 N, GelSight Minis are rated for tens of newtons), and the 6-axis sensors used to label them
# measure up to ~100-200 N. A label beyond it is a unit or parsing error (a row of 1e30 trained to "MAE 7e28 N").
FORCE_LIMIT_N = 200.0
SHOW = 5  # reasons quoted in a bad-rows error or skip warning
# A number as the release writes them ("0.017000", "-0.000100") or as %g does ("1.5e-05"). float() takes more: "1_0"
# (a typo, read as 10), "nan", "infinity", non-ASCII digits; a label must be exactly what was measured.
NUMBER = r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?"


def plain_number(text: str) -> float | None:
    """`text` as a float when it is a plain decimal or scientific number (NUMBER), else None."""
    return float(text) if re.fullmatch(NUMBER, text) else None


def parse_ft_cell(cell: str) -> tuple[np.ndarray | None, str | None]:
    """(force (3,) float32, None) for a good FT cell ("Fx Fy Fz Tx Ty Tz" or "Fx Fy Fz"; values separated by
    spaces or by commas), else (None, why)."""
    text = str(cell).strip()
    # commas separate values only where they are the separator: "0,5 1,2 3,0" (decimal commas) must not become
    # six labels 0 5 1 2 3 0
    parts = [p.strip() for p in text.split(",")] if "," in text else text.split()
    if any(len(p.split()) > 1 for p in parts):
        return None, (f"FT cell {cell!r} separates its values by commas and by spaces (decimal commas? write 0.5, "
                      "not 0,5)")
    if len(parts) not in (3, 6):
        return None, f"FT cell {cell!r} has {len(parts)} values, expected 6 (Fx Fy Fz Tx Ty Tz) or 3"
    values = []
    for name, p in zip(FT_NAMES, parts):
        v = plain_number(p)
        if v is None:
            special = p.lower().lstrip("+-")
            if special in ("nan", "inf", "infinity"):
                return None, f"FT cell {cell!r}: {name} is {'NaN' if special == 'nan' else 'inf'}"
            return None, (f"FT cell {cell!r}: {name} {p!r} is not a number (write plain decimals with a '.' like "
                          "0.017, -2 or 1.5e-3, separated by spaces)")
        if not math.isfinite(v):  # 1e999
            return None, f"FT cell {cell!r}: {name} {p!r} is inf"
        values.append(v)
    worst = max(range(3), key=lambda k: abs(values[k]))
    if abs(values[worst]) > FORCE_LIMIT_N:
        return None, (f"FT cell {cell!r}: {FT_NAMES[worst]} = {values[worst]:g} N is beyond {FORCE_LIMIT_N:g} N, "
                      "more than any tactile sensor takes (a unit error? forces are in newtons)")
    return np.asarray(values[:3], np.float32), None


def png_size(path: Path) -> tuple[int, int] | None:
    """(height, width) from a PNG's header, or None when the file is not a PNG (or is unreadable)."""
    try:
        with open(path, "rb") as f:
            head = f.read(24)
    except OSError:
        return None
    if not head.startswith(PNG_SIGNATURE) or head[12:16] != b"IHDR":
        return None
    w, h = struct.unpack(">II", head[16:24])
    return h, w


def file_problem(path: Path, what: str) -> str | None:
    """Why `path` is not a regular file to read, said as what it is (a directory, a dangling symlink, a symlink
    loop, a pipe); None when it is one."""
    try:
        st = path.stat()
    except FileNotFoundError:
        if path.is_symlink():
            return f"{what} {path} is a symlink to {os.path.realpath(path)}, which does not exist"
        return f"missing {what} {path}"
    except OSError as e:
        if e.errno == errno.ELOOP:
            return f"{what} {path} is a symlink loop (its links lead back to themselves)"
        return f"unreadable {what} {path} ({e.strerror})"
    if stat.S_ISDIR(st.st_mode):
        return f"{what} {path} is a directory, not a file"
    if not stat.S_ISREG(st.st_mode):  # reading a FIFO would block forever
        return f"{what} {path} is not a regular file (a pipe, socket or device)"
    return None


def image_problem(path: Path, want_hw: tuple[int, int] | None, what: str = "tactile image") -> str | None:
    """Why `path` cannot be a (want_hw) frame, from its header and trailer; None when it looks fine.

    PNGs get their size and completeness checked; other formats only their existence (they are
    decoded, and checked, when read)."""
    why = file_problem(path, what)
    if why:
        return why
    size = path.stat().st_size
    if size == 0:
        return f"empty {what} {path}"
    try:
        with open(path, "rb") as f:
            head = f.read(26)
            f.seek(max(size - len(PNG_TRAILER), 0))
            tail = f.read()
    except OSError as e:
        return f"unreadable {what} {path} ({e})"
    if not head.startswith(PNG_SIGNATURE):
        return None
    if head[12:16] != b"IHDR":
        return f"unreadable {what} {path} (no PNG header)"
    if tail != PNG_TRAILER:
        return f"truncated {what} {path} (the PNG ends before its IEND chunk)"
    w, h = struct.unpack(">II", head[16:24])
    if want_hw is not None and (h, w) != tuple(want_hw):
        return f"{what} {path} is {h}x{w} px, the background is {want_hw[0]}x{want_hw[1]} px"
    if len(head) == 26 and head[24] == 16:  # the same refusals as images.read_rgb, from the header
        return f"{what} {path} has uint16 pixels, not 8-bit: convert it to 8 bits per channel first"
    if len(head) == 26 and head[25] in (0, 4):  # PNG colour types: grayscale, grayscale + alpha
        return f"{what} {path} is grayscale: this model reads colour (RGB) frames of a tactile sensor"
    return None


def depth_problem(path: Path, want_hw: tuple[int, int] | None) -> str | None:
    """Why `path` cannot be a depth map (.npy, mm) of size want_hw; reads only the header (memory-mapped)."""
    why = file_problem(path, "depth file")
    if why:
        return why
    try:
        d = np.load(path, mmap_mode="r", allow_pickle=False)
    except Exception as e:  # short file, bad header, pickled object array
        return f"unreadable depth file {path} ({type(e).__name__}: {e})"
    if not isinstance(d, np.ndarray):  # an .npz archive
        d.close()
        return f"depth file {path} is not a single .npy array"
    shape, dtype = np.squeeze(d).shape, d.dtype
    del d  # closes the memory map
    if dtype.kind not in "fiu":
        return f"depth file {path} has dtype {dtype}, expected a real number type (mm)"
    if want_hw is not None and shape != tuple(want_hw):
        return f"depth file {path} is {shape}, the image is {tuple(want_hw)}"
    return None


def check_depth_values(depth: np.ndarray, path: Path) -> np.ndarray:
    """The loaded depth as float32; a dtype that is not real numbers (complex, bool, strings) or NaN/inf anywhere
    raises DataError (a load-time check)."""
    if np.asarray(depth).dtype.kind not in "fiu":
        raise DataError(f"depth file {path} holds {np.asarray(depth).dtype} values, expected real numbers (mm)")
    depth = np.asarray(depth, np.float32)
    bad = ~np.isfinite(depth)
    if bad.any():
        raise DataError(f"depth file {path} has {int(bad.sum())} NaN/inf values")
    return depth


def same_file_key(path: Path) -> str | tuple[int, int]:
    """A key under which two rows naming one file compare equal (for duplicate rows): the file's device and inode
    when it exists (a symlink or a hard link to it is the same file), else its path with every link resolved."""
    try:
        st = os.stat(path)
    except OSError:
        return os.path.normcase(os.path.realpath(path))
    return st.st_dev, st.st_ino


def report_bad_rows(source: str, problems: list[tuple[str, str]], n_rows: int, skip: bool) -> None:
    """Raise one DataError naming the first bad row (and how many there are), or, when `skip`, log how
    many rows are dropped with the first few reasons. `problems` is [(where, why), ...]."""
    if not problems:
        return
    quoted = "; ".join(f"{w}: {why}" for w, why in problems[:SHOW])
    more = f" (first {SHOW} shown)" if len(problems) > SHOW else ""
    if not skip:
        where, why = problems[0]
        tail = "" if len(problems) == 1 else f"\n{len(problems)} bad rows in {source}{more}: {quoted}"
        raise DataError(f"{where}: {why}{tail}\n(skip_bad_rows=True, or --skip-bad-rows on the command line, "
                        f"drops bad rows and reports how many)")
    if len(problems) == n_rows:
        raise DataError(f"{source}: all {n_rows} rows are bad, nothing left to use{more}: {quoted}")
    log.warning("%s: skipped %d of %d rows%s: %s", source, len(problems), n_rows, more, quoted)
