"""Gel surface -> RGB frame for one sensor: Lambertian shading of the surface normals by the sensor's
LEDs (direction from each pixel to the LED, colour, inverse-square falloff), the gel's pigment and markers
(carried by its tangential displacement), then the camera's side, which stays put however the gel moves:
uneven lighting, vignetting, per-channel gain (its colour balance), blur, dust on the optics, the pixels'
fixed gain pattern, noise, uint8.

Static image patterns are split by what carries them: the fine fixed pattern a real sensor shows at rest is
part pigment (moves with the gel) and part camera (pixel gains, dust: stays); rest frames cannot tell the two
apart (experiments.diagnostics.rest_recording), so the split is a sensor parameter (sensors.PATTERN_MOVING).

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
    albedo: np.ndarray  # (H, W, 3) the gel's: pigment colour, its fine pattern, markers (moves with the gel)
    shade_gain: np.ndarray  # (H, W, 3) the camera's smooth gain: lighting unevenness, vignette, colour balance
    pixel_gain: np.ndarray  # (H, W, 1) the camera's fine gain after the blur: pixels' fixed pattern, dust
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


FINE_PX = 4.0  # a "fine" pattern: what a Gaussian blur of this sigma (native px) removes, finer than lighting
PIGMENT_GRAIN_PX = 1.0  # the pigment's grain (native px, Gaussian sigma); the camera's pixel pattern is white


def fine_pattern(rng: np.random.Generator, shape: tuple[int, int], grain_px: float, blur_px: float) -> np.ndarray:
    """A random fixed pattern at native size, float32, scaled so that its fine part (less a FINE_PX blur), as the
    camera sees it through a blur of blur_px, has rms 1: a sensor's pattern parameters are then what
    experiments.diagnostics.rest_recording reads off frames at rest (fraction of the level)."""
    x = rng.standard_normal(shape).astype(np.float32)
    if grain_px > 0:
        x = cv2.GaussianBlur(x, (0, 0), grain_px)
    seen = cv2.GaussianBlur(x, (0, 0), blur_px) if blur_px >= 0.3 else x
    fine = seen - cv2.GaussianBlur(seen, (0, 0), FINE_PX)
    return x / (fine.std() + 1e-12)


def _dust(rng: np.random.Generator, shape: tuple[int, int], count: int) -> np.ndarray:
    """The gain of `count` dust specks on the optics (out of focus, fixed to the camera): dark round blurs of
    0.6-1.5 px (sigma) that take 5-30% of the light at their centre, as a real Mini shows at rest."""
    H, W = shape
    gain = np.ones(shape, np.float32)
    rows, cols = np.mgrid[0:H, 0:W].astype(np.float32)
    for _ in range(count):
        y, x = rng.uniform(0, H), rng.uniform(0, W)
        sigma, depth = rng.uniform(0.6, 1.5), rng.uniform(0.05, 0.3)
        gain *= 1 - depth * np.exp(-((rows - y) ** 2 + (cols - x) ** 2) / (2 * sigma**2))
    return gain


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

    nh, nw = sensor.native_size
    # the gel's side, a property of the pad (a gel moved to another unit, Table II, brings it along)
    gel_rng = np.random.default_rng(_seed("gel", sensor.gel.texture_seed))
    tex = 1 + sensor.gel.pigment * fine_pattern(gel_rng, (nh, nw), PIGMENT_GRAIN_PX, sensor.blur_px)
    tex = cv2.resize(tex, (W, H), interpolation=cv2.INTER_AREA)
    if sensor.gel.markers:  # dark dots, 1.6 mm pitch, 0.5 mm diameter
        pitch, rad = 1.6, 0.25
        gx = X - pitch * np.round(X / pitch)
        gy = Y - pitch * np.round(Y / pitch)
        r = np.sqrt(gx**2 + gy**2)
        cover = np.clip((rad - r) / max(mpp, 1e-3) + 0.5, 0, 1)  # anti-aliased dot coverage
        tex = tex * (1 - 0.75 * cover)
    albedo = (np.asarray(sensor.albedo, np.float32) * tex[..., None]).astype(np.float32)

    # the camera's side, a property of the unit: the same for every gel it carries
    cam_rng = np.random.default_rng(_seed("camera", sensor.name))
    low = cv2.GaussianBlur(cam_rng.standard_normal((nh, nw)).astype(np.float32), (0, 0), nw / 8)
    low /= low.std() + 1e-9
    rr = (X / X.max()) ** 2 + (Y / Y.max()) ** 2
    smooth = (1 + sensor.unevenness * cv2.resize(low, (W, H), interpolation=cv2.INTER_AREA)) \
        * (1 - sensor.vignette * rr / 2)
    pixels = 1 + sensor.pixel_pattern * fine_pattern(cam_rng, (nh, nw), 0.0, 0.0)
    pixels *= _dust(cam_rng, (nh, nw), sensor.dust)
    pixels = cv2.resize(pixels, (W, H), interpolation=cv2.INTER_AREA)
    scale = W / sensor.native_size[1]
    t = Tables(X, Y, mpp, dome_gx, dome_gy, light, fall, colour, np.asarray(sensor.ambient, np.float32),
               albedo, smooth[..., None].astype(np.float32), pixels[..., None].astype(np.float32),
               np.zeros((H, W, 3), np.float32), sensor.blur_px * scale, sensor.noise_std,
               *np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32)))
    t.flat = _radiance(t, np.zeros((H, W), np.float32), (slice(None), slice(None)))
    # the camera's gain per channel: the untouched frame's mean is the sensor's brightness in its colour balance
    balance = np.asarray(sensor.white_balance, np.float32)
    level = sensor.brightness * balance / balance.mean()
    t.shade_gain = (t.shade_gain * level / (t.flat * albedo * t.shade_gain * t.pixel_gain).mean((0, 1)))
    t.shade_gain = t.shade_gain.astype(np.float32)
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
    albedo = t.albedo
    if disp_px is not None:  # pigment (and markers) carried by the tangential displacement; the camera's gains stay
        w = _window((np.abs(disp_px[..., 0]) + np.abs(disp_px[..., 1])) > 1e-3, 2)
        if w is not None:
            albedo = albedo.copy()
            albedo[w] = cv2.remap(t.albedo, t.px[w] - disp_px[w][..., 0], t.py[w] - disp_px[w][..., 1],
                                  cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    img *= albedo
    img *= t.shade_gain
    if t.blur >= 0.3:
        img = cv2.GaussianBlur(img, (0, 0), t.blur)
    img *= t.pixel_gain
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
