"""Gel surface -> RGB frame for one sensor: Lambertian shading of the surface normals by the sensor's
LEDs (direction from each pixel to the LED, colour, inverse-square falloff), pigment albedo with its
texture and markers (warped by shear), uneven pad, vignetting, blur, camera noise, uint8.

Per-(sensor, size) tables (light directions, falloff, albedo, gain) are built once and cached.
`sensor` is a sensors.Sensor; this module does not import sensors.py (Sensor.background calls into it), so
the imports run one way: sensors -> optics.
"""

from __future__ import annotations

import dataclasses
import functools
import zlib

import cv2
import numpy as np


@dataclasses.dataclass
class Tables:
    X: np.ndarray  # (H, W) mm, pixel centres, x right
    Y: np.ndarray  # (H, W) mm, y down
    mpp: float  # mm per pixel (mean of dy, dx)
    dome_gx: np.ndarray | float  # slope of DIGIT's domed rest surface; 0 if flat
    dome_gy: np.ndarray | float
    light: np.ndarray  # (3, K, H, W) unit vectors from each pixel to each LED
    fall: np.ndarray  # (K, H, W) irradiance falloff of each LED
    colour: np.ndarray  # (K, 3) LED colour * intensity
    ambient: np.ndarray  # (3,)
    albedo: np.ndarray  # (H, W, 3) pigment, texture, markers, unevenness
    shade_gain: np.ndarray  # (H, W, 1) gain * vignette
    albedo_gain: np.ndarray | None  # (H, W, 3) albedo * shade_gain (what multiplies the radiance)
    flat: np.ndarray  # (H, W, 3) radiance of the undeformed gel
    blur: float  # px
    noise: float  # 8-bit std
    px: np.ndarray  # (H, W) float32 column index (for remap)
    py: np.ndarray


def _seed(*parts) -> int:
    return zlib.crc32("/".join(map(str, parts)).encode())


def grid(sensor, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (X, Y) in mm of a render of `size`, origin at the pad centre."""
    H, W = size
    dy, dx = sensor.mm_per_px(size)
    x = (np.arange(W) - (W - 1) / 2) * dx
    y = (np.arange(H) - (H - 1) / 2) * dy
    X, Y = np.meshgrid(x.astype(np.float32), y.astype(np.float32))
    return X, Y


@functools.lru_cache(maxsize=64)
def tables(sensor, size: tuple[int, int]) -> Tables:
    H, W = size
    X, Y = grid(sensor, size)
    dy, dx = sensor.mm_per_px(size)
    mpp = (dx + dy) / 2
    if sensor.dome_radius_mm:
        R = sensor.dome_radius_mm
        dome = (X**2 + Y**2) / (2 * R)
        dome_gx, dome_gy = -X / R, -Y / R  # slope of the surface height z = -dome
    else:
        dome, dome_gx, dome_gy = np.float32(0.0), 0.0, 0.0
    light, fall, colour = [], [], []
    for led in sensor.leds:
        a = np.radians(led.azimuth_deg)
        lx, ly = led.radius_mm * np.cos(a) - X, led.radius_mm * np.sin(a) - Y
        lz = np.full_like(X, led.height_mm) + dome
        dist = np.sqrt(lx**2 + ly**2 + lz**2)
        light.append(np.stack([lx / dist, ly / dist, lz / dist]))
        fall.append((np.hypot(led.radius_mm, led.height_mm) / dist) ** sensor.falloff)  # 1 at the centre
        colour.append(np.asarray(led.color, np.float32) * led.intensity)
    light = np.stack(light, 1).astype(np.float32)
    fall = np.stack(fall).astype(np.float32)
    colour = np.stack(colour).astype(np.float32)

    # pigment: fine speckle of the gel's particles + low-frequency unevenness of the cast + markers. They belong
    # to the gel pad, not the camera unit: a gel moved to another unit (Table II) brings its own pattern
    rng = np.random.default_rng(_seed("gel", sensor.gel.texture_seed))
    nh, nw = sensor.native_size
    speck = cv2.GaussianBlur(rng.standard_normal((nh, nw)).astype(np.float32), (0, 0), 2.0)
    speck /= speck.std() + 1e-9
    low = cv2.GaussianBlur(rng.standard_normal((nh, nw)).astype(np.float32), (0, 0), nw / 8)
    low /= low.std() + 1e-9
    tex = 1 + sensor.gel.texture_contrast * speck + sensor.unevenness * low
    tex = cv2.resize(tex, (W, H), interpolation=cv2.INTER_AREA)
    if sensor.gel.markers:  # dark dots, 1.6 mm pitch, 0.5 mm diameter
        pitch, rad = 1.6, 0.25
        gx = X - pitch * np.round(X / pitch)
        gy = Y - pitch * np.round(Y / pitch)
        r = np.sqrt(gx**2 + gy**2)
        cover = np.clip((rad - r) / max(mpp, 1e-3) + 0.5, 0, 1)  # anti-aliased dot coverage
        tex = tex * (1 - 0.75 * cover)
    albedo = (np.asarray(sensor.albedo, np.float32) * tex[..., None]).astype(np.float32)

    rr = (X / X.max()) ** 2 + (Y / Y.max()) ** 2
    vign = (1 - sensor.vignette * rr / 2).astype(np.float32)
    scale = W / sensor.native_size[1]
    t = Tables(X, Y, mpp, dome_gx, dome_gy, light, fall, colour, np.asarray(sensor.ambient, np.float32),
               albedo, vign[..., None], None, np.zeros((H, W, 3), np.float32), sensor.blur_px * scale,
               sensor.noise_std, *np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32)))
    t.flat = _radiance(t, np.zeros((H, W), np.float32), (slice(None), slice(None)))
    t.shade_gain = (t.shade_gain * sensor.brightness / float((t.flat * albedo * t.shade_gain).mean()))
    t.albedo_gain = (albedo * t.shade_gain).astype(np.float32)
    return t


def _radiance(t: Tables, depth: np.ndarray, win: tuple[slice, slice]) -> np.ndarray:
    """Light reaching the camera per unit albedo, (h, w, 3), in the window `win` of the frame, from the
    gel surface z = -dome - depth (depth given on the window)."""
    gy, gx = np.gradient(depth, t.mpp)
    dgx, dgy = (t.dome_gx[win], t.dome_gy[win]) if isinstance(t.dome_gx, np.ndarray) else (0.0, 0.0)
    gx = dgx - gx  # gradient of the height z = -(dome + depth)
    gy = dgy - gy
    inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
    lx, ly, lz = t.light[(slice(None), slice(None)) + win]
    ndl = np.maximum((lz - gx * lx - gy * ly) * inv, 0.0)  # normal = (-gx, -gy, 1) / |.|, (K, h, w)
    ndl *= t.fall[(slice(None),) + win]
    out = np.empty(depth.shape + (3,), np.float32)
    for c in range(3):  # a K-term sum per channel; cheaper than a BLAS call on small, busy machines
        acc = np.full(depth.shape, t.ambient[c], np.float32)
        for k in range(len(t.colour)):
            acc += t.colour[k, c] * ndl[k]
        out[..., c] = acc
    return out


def _window(mask: np.ndarray, margin: int) -> tuple[slice, slice] | None:
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    if rows.size == 0:
        return None
    H, W = mask.shape
    return (slice(max(rows[0] - margin, 0), min(rows[-1] + margin + 1, H)),
            slice(max(cols[0] - margin, 0), min(cols[-1] + margin + 1, W)))


def render(sensor, size: tuple[int, int], depth: np.ndarray, disp_px: np.ndarray | None = None,
           seed: int | None = 0) -> np.ndarray:
    """uint8 (H, W, 3) frame of the gel with surface displacement `depth` (mm, + = into the gel) and the
    pigment moved by disp_px (H, W, 2) pixels; camera noise from `seed` (None = no noise)."""
    if np.shape(depth) != tuple(size) or not np.isfinite(depth).all():
        raise ValueError(f"depth must be finite with shape {tuple(size)}, got shape {np.shape(depth)}"
                         f"{'' if np.shape(depth) != tuple(size) else ' with NaN/inf values'}")
    if disp_px is not None and (np.shape(disp_px) != (*size, 2) or not np.isfinite(disp_px).all()):
        raise ValueError(f"disp_px must be finite with shape {(*size, 2)}, got shape {np.shape(disp_px)}")
    t = tables(sensor, tuple(size))
    img = t.flat.copy()
    win = _window(np.abs(depth) > 1e-5, 2)  # shading changes only where the surface moved
    if win is not None:
        img[win] = _radiance(t, depth[win].astype(np.float32), win)
    albedo = t.albedo_gain
    if disp_px is not None:  # pigment (and markers) carried by the tangential displacement
        w = _window((np.abs(disp_px[..., 0]) + np.abs(disp_px[..., 1])) > 1e-3, 2)
        if w is not None:
            albedo = albedo.copy()
            albedo[w] = cv2.remap(t.albedo_gain, t.px[w] - disp_px[w][..., 0], t.py[w] - disp_px[w][..., 1],
                                  cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    img *= albedo
    if t.blur >= 0.3:
        img = cv2.GaussianBlur(img, (0, 0), t.blur)
    if seed is not None and t.noise > 0:
        noise = np.random.default_rng(seed).standard_normal(img.shape, dtype=np.float32)
        noise *= t.noise
        img += noise
    img += 0.5
    np.clip(img, 0, 255, out=img)
    return img.astype(np.uint8)


@functools.lru_cache(maxsize=64)
def _background(sensor, size: tuple[int, int], noise: bool) -> np.ndarray:
    H, W = size
    img = render(sensor, size, np.zeros((H, W), np.float32), None, _seed("bg", sensor.key) if noise else None)
    img.setflags(write=False)
    return img


def background(sensor, size: tuple[int, int], noise: bool = True) -> np.ndarray:
    return _background(sensor, tuple(int(s) for s in size), bool(noise)).copy()
