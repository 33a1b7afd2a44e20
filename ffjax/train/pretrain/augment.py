"""DINO's multi-crop views on the host: random resized crops, flips, colour / LED-gain jitter and blur in
numpy/cv2 (an in-jit version tripled the compile time for no speed-up on CPU). Pixel noise is added inside
the jitted update from its key (update.py)."""

from __future__ import annotations

import math

import cv2
import numpy as np


def _crop_box(rng, S: int, scale) -> tuple[int, int, int, int]:
    """Random resized crop box (y0, x0, h, w): area fraction in `scale`, aspect ratio in [3/4, 4/3]."""
    area = rng.uniform(*scale) * S * S
    ratio = math.exp(rng.uniform(math.log(3 / 4), math.log(4 / 3)))
    h = int(round(min(S, max(4, math.sqrt(area / ratio)))))
    w = int(round(min(S, max(4, math.sqrt(area * ratio)))))
    return int(rng.integers(0, S - h + 1)), int(rng.integers(0, S - w + 1)), h, w


def augment_view(img: np.ndarray, rng: np.random.Generator, out: int, scale, p: dict) -> np.ndarray:
    """One view of a uint8 (S,S,3) image in [0, 1] float32: random resized crop, flips, brightness /
    contrast / per-channel (LED) gain, Gaussian blur."""
    y0, x0, h, w = _crop_box(rng, img.shape[0], scale)
    crop = img[y0: y0 + h, x0: x0 + w]
    interp = cv2.INTER_AREA if min(h, w) > out else cv2.INTER_LINEAR
    x = cv2.resize(crop, (out, out), interpolation=interp).astype(np.float32) * np.float32(1 / 255)
    if rng.random() < p["flip"]:
        x = x[:, ::-1]
    if rng.random() < p["flip"]:
        x = x[::-1]
    cj = p["color_jitter"]
    if cj > 0:
        mean = x.mean()
        contrast, gain = 1 + cj * rng.uniform(-1, 1), 1 + cj * rng.uniform(-1, 1)
        chan = (1 + 0.5 * cj * rng.uniform(-1, 1, 3)).astype(np.float32)
        x = ((x - mean) * contrast + mean) * gain * chan
    if rng.random() < p["blur"]:
        x = cv2.GaussianBlur(np.ascontiguousarray(x), (0, 0), rng.uniform(0.1, 1.5) * out / img.shape[0])
    return np.clip(x, 0.0, 1.0)


def multicrop(images: np.ndarray, rng: np.random.Generator, p: dict, input_size: int, norm) -> dict:
    """uint8 (B,S,S,3) -> {"global": (2B,S,S,3) [view 0 batch, view 1 batch], "local": (L*B,s,s,3)},
    normalized by the corpus mean/std."""
    mean, std = np.asarray(norm[0], np.float32), np.asarray(norm[1], np.float32)

    def views(n, out, scale):
        v = np.stack([augment_view(im, rng, out, scale, p) for _ in range(n) for im in images])
        return (v - mean) / std

    batch = {"global": views(2, input_size, p["global_scale"])}
    if p["local_crops"]:
        batch["local"] = views(int(p["local_crops"]), int(p["local_size"]), p["local_scale"])
    return batch
