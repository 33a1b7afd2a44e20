"""Image files of a split: RGB frames read with the refusals a colour sensor's frames need, written as PNG,
and the no-contact background (background.png, a path or an array) loaded and checked."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ffjax.data.validate import file_problem
from ffjax.errors import DataError
from ffjax.files import atomic_write_bytes

BACKGROUND_NAME = "background.png"


def read_rgb(path: str | os.PathLike, what: str = "image") -> np.ndarray:
    """Read a colour image as RGB uint8 (an alpha channel is dropped). A missing, unreadable or truncated
    file (or a directory, a dangling or looping symlink) raises DataError, and so do images a colour sensor
    never writes: more than 8 bits per channel (decoding would silently drop the low bits: 12-bit data in 16
    bits would read as a near-black frame) and grayscale (it would become three equal channels, a colour the
    model never saw)."""
    path = Path(path)
    why = file_problem(path, what)
    if why:
        raise DataError(why)
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


def load_background(background, default_path: Path | None, where: str) -> np.ndarray | None:
    """The no-contact frame: `background` (an RGB array or an image path), else the image at `default_path`
    if there is one (anything by that name: a directory or a broken link there is refused, not passed over), else
    None; refused unless uint8 HxWx3 (`where` names the split in the error)."""
    if isinstance(background, np.ndarray):
        bg = background
    elif background is not None:
        bg = read_rgb(background, "background")
    elif default_path is not None and os.path.lexists(default_path):
        bg = read_rgb(default_path, "background")
    else:
        return None
    if bg.dtype != np.uint8 or bg.ndim != 3 or bg.shape[2] != 3:
        raise DataError(f"{where}: background must be uint8 HxWx3, got {bg.dtype} {bg.shape}")
    return bg
