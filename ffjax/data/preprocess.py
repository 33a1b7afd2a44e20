"""The one preprocessing path (training, evaluation, inference): REFERENCE.md's recipe with the wrap fixed.

image: nobg = clip(img - bg + 127, 0, 255) in integer math -> pad to square with 0 -> resize to S x S
(cv2.INTER_AREA when shrinking, the antialiased choice; bilinear when enlarging) -> /255 -> (x - mean) / std.
depth (mm): pad with 0 mm (no deformation) -> resize the same way -> map [depth_min, depth_max] to [0, 1].
Landscape frames (GelSight Mini) are padded top/bottom, portrait ones (DIGIT) left/right.
"""

from __future__ import annotations

import cv2
import numpy as np


def subtract_background(image: np.ndarray, background: np.ndarray) -> np.ndarray:
    """clip(image - background + 127) as uint8; int16 math so dark-on-bright never wraps around."""
    diff = image.astype(np.int16) - background.astype(np.int16) + 127
    return np.clip(diff, 0, 255).astype(np.uint8)


def pad_to_square(x: np.ndarray, batched: bool = False, value: float = 0) -> np.ndarray:
    """Pad along the short image axis, centred, to max(H, W) squared; x is (H, W[, C]), or (B, H, W[, C])
    when `batched`."""
    hw_axis = 1 if batched else 0
    h, w = x.shape[hw_axis], x.shape[hw_axis + 1]
    if h == w:
        return x
    pad = [(0, 0)] * x.ndim
    short = hw_axis if h < w else hw_axis + 1
    total = abs(w - h)
    pad[short] = (total // 2, total - total // 2)
    return np.pad(x, pad, constant_values=value)


def _resize(x: np.ndarray, size: int) -> np.ndarray:
    """Resize one (H, W[, C]) float32 square frame to (size, size[, C])."""
    if x.shape[0] == size and x.shape[1] == size:
        return x
    interp = cv2.INTER_AREA if x.shape[0] > size else cv2.INTER_LINEAR
    out = cv2.resize(x, (size, size), interpolation=interp)
    return out.reshape((size, size) + x.shape[2:])


def to_unit(image: np.ndarray, background: np.ndarray, input_size: int) -> np.ndarray:
    """Background-subtracted, padded, resized image in [0, 1], float32 (S, S, 3) or (B, S, S, 3)."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or np.asarray(background).dtype != np.uint8:
        raise TypeError(f"image and background must be uint8, got {image.dtype} and "
                        f"{np.asarray(background).dtype}")
    if image.shape[-3:] != np.shape(background)[-3:]:
        raise ValueError(f"image {image.shape} and background {np.shape(background)} differ in size")
    nobg = pad_to_square(subtract_background(image, background), batched=image.ndim == 4).astype(np.float32)
    if nobg.ndim == 4:
        out = np.stack([_resize(f, input_size) for f in nobg]) if len(nobg) else \
            np.zeros((0, input_size, input_size, 3), np.float32)
    else:
        out = _resize(nobg, input_size)
    return out * np.float32(1 / 255)


def _get(stats, key):
    return np.asarray(stats[key] if isinstance(stats, dict) else getattr(stats, key), np.float32)


def preprocess_image(image: np.ndarray, background: np.ndarray, stats, input_size: int) -> np.ndarray:
    """uint8 frame(s) + no-contact background -> normalized float32 (S, S, 3) or (B, S, S, 3).

    `stats` is a data.Stats (or its dict); `background` may be one frame shared by a batch.
    """
    x = to_unit(image, background, input_size)
    return (x - _get(stats, "mean")) / _get(stats, "std")


def preprocess_depth(depth_mm: np.ndarray, stats, input_size: int) -> np.ndarray:
    """Depth in mm, (H, W) or (B, H, W) -> float32 (S, S) or (B, S, S) in [0, 1] (train-set range)."""
    d = np.asarray(depth_mm, np.float32)
    d = pad_to_square(d, batched=d.ndim == 3)
    d = np.stack([_resize(f, input_size) for f in d]) if d.ndim == 3 else _resize(d, input_size)
    lo, hi = float(_get(stats, "depth_min")), float(_get(stats, "depth_max"))
    span = max(hi - lo, 1e-9)  # a train set of constant depth (no depth labels, depth_eps 0) would divide by 0
    return np.clip((d - lo) / span, 0.0, 1.0).astype(np.float32)


def depth_to_mm(depth_unit: np.ndarray, stats) -> np.ndarray:
    """Invert preprocess_depth's normalization (not the pad/resize): [0, 1] -> mm."""
    lo, hi = float(_get(stats, "depth_min")), float(_get(stats, "depth_max"))
    return np.asarray(depth_unit, np.float32) * (hi - lo) + lo
