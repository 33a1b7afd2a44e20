"""Unlabeled image corpus for self-supervised pretraining (no evaluation sensor's labelled data).

Two halves, both uint8 (N, S, S, 3) at the model input size:
- procedural images: 1/f noise, random shapes, gratings and dot grids, colour blobs, and shaded random
  height fields (a sensor-free look-alike of background-subtracted tactile frames);
- frames from RANDOMIZED simulated sensors (perturbed LEDs / gel / noise, random procedural height-map
  shapes, never the named indenters or unseen objects), background-subtracted exactly like the
  training input: nobg = clip(img - bg + 127), padded to square, resized.
Deterministic from the seed (frame i uses its own generator seeded by (seed, i)); cached as .npy.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import functools
import hashlib
import json
import multiprocessing
import os
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from ffjax import compile_cache, sim
from ffjax.data.preprocess import to_unit
from ffjax.files import atomic_write, atomic_write_text
from ffjax.sim.dataset import default_workers, render_size

VERSION = 2  # 2: randomized sensors with camera patterns and colour balance (issue 32)
PROCEDURAL_KINDS = ("pink_noise", "shapes", "gratings", "blobs", "shaded_relief")


def corpus_settings(cfg: dict) -> dict:
    """The settings that determine the corpus (also its cache key)."""
    p = cfg["pretrain"]
    return {
        "version": VERSION,
        "size": int(p["corpus_size"]),
        "sim_fraction": float(p["corpus_sim_fraction"]),
        "input_size": int(cfg["data"]["input_size"]),
        "render_size": [int(v) for v in cfg["data"]["render_size"]],
        "fz_max": float(cfg["data"]["fz_max"]),
        "shear_max": float(cfg["data"]["shear_max"]),
        "seed": int(cfg["seed"]),
    }


def load_or_build(cfg: dict, cache_dir: str | os.PathLike | None = None, progress: bool = False):
    """Return (images uint8 (N,S,S,3), meta dict); cached in `cache_dir` as corpus_<hash>.npy + .json."""
    settings = corpus_settings(cfg)
    digest = hashlib.sha1(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:12]
    if cache_dir is not None:
        npy = Path(cache_dir) / f"corpus_{digest}.npy"
        meta_path = npy.with_suffix(".json")
        if npy.exists() and meta_path.exists():
            return np.load(npy), json.loads(meta_path.read_text())
    images, meta = build(settings, progress=progress)
    meta["hash"] = digest
    if cache_dir is not None:
        npy.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(npy, lambda f: np.save(f, images))
        atomic_write_text(meta_path, json.dumps(meta))
    return images, meta


def build(settings: dict, progress: bool = False, workers: int | None = None):
    """Generate the corpus; meta records each frame's kind and (for sim frames) shape and sensor. The sim
    frames (the slow part: the gel's contact solve, one press at a time) are spread over `workers` processes
    (default: dataset.default_workers: the CPU count, up to 8, when there are enough of them to pay for
    starting the processes; one on a GPU); every frame has its
    own generator, so the result does not depend on the split."""
    n, size = settings["size"], settings["input_size"]
    n_sim = int(round(n * settings["sim_fraction"]))
    if workers is None:
        workers = default_workers(n_sim, 400)
    chunks = [(lo, min(lo + 64, n)) for lo in range(0, n, 64)]
    images = np.empty((n, size, size, 3), np.uint8)
    kinds, frames = [None] * n, [None] * n
    bar = None
    if progress:
        bar = tqdm(total=n, desc="corpus", unit="img")
    tasks = [(settings, n_sim, lo, hi) for lo, hi in chunks]
    if workers <= 1:
        results = map(_build_chunk, tasks)
    else:
        pool = cf.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                      initializer=compile_cache.enable)  # the simulator's programs load, not compile
        results = pool.map(_build_chunk, tasks)
    try:
        for lo, imgs, chunk_kinds, chunk_frames in results:
            images[lo:lo + len(imgs)] = imgs
            kinds[lo:lo + len(imgs)], frames[lo:lo + len(imgs)] = chunk_kinds, chunk_frames
            if bar is not None:
                bar.update(len(imgs))
    finally:
        if workers > 1:
            pool.shutdown(cancel_futures=True)
        if bar is not None:
            bar.close()
    # shuffle deterministically so any prefix mixes both halves
    order = np.random.default_rng([settings["seed"], VERSION, 1 << 31]).permutation(n)
    meta = {"settings": settings, "kinds": [kinds[j] for j in order], "frames": [frames[j] for j in order],
            "sim_available": True}  # a field of the meta format; the simulator ships with ffjax
    return images[order], meta


def _build_chunk(task):
    """Frames [lo, hi) of the corpus: (lo, images, kinds, frame infos)."""
    settings, n_sim, lo, hi = task
    size = settings["input_size"]
    sensors = _cached_pool(settings["seed"]) if lo < n_sim else []
    images = np.empty((hi - lo, size, size, 3), np.uint8)
    kinds, frames = [], []
    for i in range(lo, hi):
        rng = np.random.default_rng([settings["seed"], VERSION, i])
        frame = None
        if i < n_sim:
            frame, info = sim_frame(rng, settings, sensors[i % len(sensors)])
        if frame is not None:
            images[i - lo] = frame
            kinds.append("sim")
            frames.append(info)
        else:
            kind = PROCEDURAL_KINDS[i % len(PROCEDURAL_KINDS)]
            images[i - lo] = procedural_image(kind, rng, size)
            kinds.append(kind)
            frames.append({})
    return lo, images, kinds, frames


# ----------------------------------------------------------------------------- procedural images
def procedural_image(kind: str, rng: np.random.Generator, size: int) -> np.ndarray:
    """One uint8 (size, size, 3) natural-image-like pattern of the given kind."""
    img = {"pink_noise": _pink_noise, "shapes": _shapes, "gratings": _gratings, "blobs": _blobs,
           "shaded_relief": _shaded_relief}[kind](rng, size)
    return np.clip(img * 255.0, 0, 255).astype(np.uint8)


def _pink_noise(rng, size):
    # 1/f^a spectrum per channel, mixed so the channels are correlated like natural images
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.rfftfreq(size)[None, :]
    f = np.sqrt(fx**2 + fy**2)
    f[0, 0] = 1.0
    amp = f ** -rng.uniform(1.0, 2.2)
    amp[0, 0] = 0.0
    chans = []
    for _ in range(3):
        spec = amp * np.exp(2j * np.pi * rng.random(amp.shape)) * rng.standard_normal(amp.shape)
        chans.append(np.fft.irfft2(spec, s=(size, size)))
    x = np.stack(chans, -1) @ _colour_mix(rng)
    x = (x - x.mean()) / (x.std() + 1e-8)
    return 0.5 + rng.uniform(0.1, 0.25) * x


def _shapes(rng, size):
    s = 4  # draw at 4x and downsample for anti-aliased edges
    img = np.ones((size * s, size * s, 3), np.float32) * rng.random(3)
    for _ in range(rng.integers(2, 9)):
        colour = tuple(float(c) for c in rng.random(3))
        c = tuple(int(v) for v in rng.integers(0, size * s, 2))
        r = int(rng.uniform(0.05, 0.4) * size * s)
        k = rng.integers(4)
        if k == 0:
            cv2.circle(img, c, r, colour, -1)
        elif k == 1:
            axes = (r, int(r * rng.uniform(0.2, 1.0)))
            cv2.ellipse(img, c, axes, float(rng.uniform(0, 180)), 0, 360, colour, -1)
        elif k == 2:
            pts = (np.array(c) + rng.normal(0, r, (rng.integers(3, 7), 2))).astype(np.int32)
            cv2.fillPoly(img, [pts], colour)
        else:
            p2 = tuple(int(v) for v in rng.integers(0, size * s, 2))
            cv2.line(img, c, p2, colour, int(rng.integers(1, 4) * s))
    img = cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)
    return img + rng.normal(0, 0.02, img.shape)


def _gratings(rng, size):
    yy, xx = np.mgrid[0:size, 0:size] / size
    x = np.zeros((size, size, 3))
    for _ in range(rng.integers(1, 4)):
        th, freq = rng.uniform(0, np.pi), rng.uniform(2, size / 4)
        if rng.random() < 0.3:  # dot grid, like a marker pattern
            wave = np.cos(2 * np.pi * freq * xx) * np.cos(2 * np.pi * freq * yy)
        else:
            wave = np.sin(2 * np.pi * freq * (xx * np.cos(th) + yy * np.sin(th)) + rng.uniform(0, 2 * np.pi))
        x += wave[..., None] * rng.normal(0, 1, 3)
    x /= np.abs(x).max() + 1e-8
    return 0.5 + rng.uniform(0.2, 0.5) * x


def _blobs(rng, size):
    yy, xx = np.mgrid[0:size, 0:size] / size
    x = np.ones((size, size, 3)) * rng.random(3)
    for _ in range(rng.integers(3, 12)):
        cy, cx, sig = rng.random(), rng.random(), rng.uniform(0.03, 0.3)
        g = np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * sig**2))
        x += g[..., None] * rng.normal(0, 0.5, 3)
    return x


def random_relief(rng: np.random.Generator, size: int) -> np.ndarray:
    """A random height field in [0, 1] (Gaussian bumps, ridges, smoothed polygons and 1/f texture)."""
    yy, xx = np.mgrid[0:size, 0:size] / size
    h = np.zeros((size, size))
    for _ in range(rng.integers(1, 5)):
        k = rng.integers(3)
        cy, cx = rng.uniform(0.2, 0.8, 2)
        if k == 0:  # elliptical bump (sphere / ellipsoid / egg-like)
            a, b, th = rng.uniform(0.05, 0.35), rng.uniform(0.05, 0.35), rng.uniform(0, np.pi)
            u = (xx - cx) * np.cos(th) + (yy - cy) * np.sin(th)
            v = -(xx - cx) * np.sin(th) + (yy - cy) * np.cos(th)
            h = np.maximum(h, rng.uniform(0.3, 1) * np.sqrt(np.clip(1 - (u / a) ** 2 - (v / b) ** 2, 0, None)))
        elif k == 1:  # ridge / edge
            th, w = rng.uniform(0, np.pi), rng.uniform(0.02, 0.15)
            d = (xx - cx) * np.cos(th) + (yy - cy) * np.sin(th)
            h = np.maximum(h, rng.uniform(0.3, 1) * np.exp(-(d**2) / (2 * w**2)))
        else:  # flat-topped polygon with rounded edges
            poly = np.zeros((size, size), np.float32)
            pts = ((np.array([cx, cy]) + rng.normal(0, 0.15, (rng.integers(3, 7), 2))) * size).astype(np.int32)
            cv2.fillPoly(poly, [pts], 1.0)
            poly = cv2.GaussianBlur(poly, (0, 0), max(0.5, rng.uniform(0.01, 0.05) * size))
            h = np.maximum(h, rng.uniform(0.3, 1) * poly)
    if rng.random() < 0.5:  # fine surface texture
        h = h + rng.uniform(0.0, 0.08) * (_pink_noise(rng, size)[..., 0] - 0.5)
    h = h - h.min()
    return h / (h.max() + 1e-8)


def _shaded_relief(rng, size):
    # Lambertian shading of a random relief under 2-4 coloured lights, on a neutral 0.5 background:
    # the look of a background-subtracted tactile frame without any sensor model.
    h = random_relief(rng, size) * rng.uniform(2, 12)
    gy, gx = np.gradient(h)
    n = np.stack([-gx, -gy, np.ones_like(h)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    out = np.zeros((size, size, 3))
    for _ in range(rng.integers(2, 5)):
        az, el = rng.uniform(0, 2 * np.pi), rng.uniform(0.2, 1.2)
        light = np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
        shade = n @ light - light[2]  # zero on flat gel, like a background-subtracted frame
        out += shade[..., None] * rng.dirichlet(np.ones(3)) * rng.uniform(0.5, 2)
    return 0.5 + out + rng.normal(0, rng.uniform(0, 0.02), out.shape)


def _colour_mix(rng):
    m = np.eye(3) * rng.uniform(0.2, 1.0) + rng.normal(0, 0.5, (3, 3))
    return m / (np.abs(m).sum(0, keepdims=True) + 1e-8)


# ----------------------------------------------------------------------------- randomized sim frames
SENSOR_POOL = 24  # randomized sensors per corpus (each builds its own cached optics tables)


def randomized_sensor(rng: np.random.Generator, index: int = 0):
    """A new sensor: a random preset's fields perturbed (LED count/colours/positions, gel stiffness and
    thickness, markers, brightness, vignette, blur, noise, dome). sim has no randomizer of its own, so
    this builds a `sim.Sensor` with `dataclasses.replace`; its name ("rand-<i>") never equals an
    evaluation sensor's, which also gives it its own background and gel texture."""
    name, gel = sim.SENSORS[rng.integers(len(sim.SENSORS))]
    base = sim.get_sensor(name, gel=gel)
    leds = []
    for _ in range(int(rng.integers(2, 6))):
        colour = rng.dirichlet(np.full(3, 0.6)) * rng.uniform(1.0, 1.6)
        leds.append(sim.LED(azimuth_deg=float(rng.uniform(0, 360)), height_mm=float(rng.uniform(2.5, 6.0)),
                            color=tuple(float(c) for c in np.clip(colour, 0.05, 1.0)),
                            intensity=float(rng.uniform(0.5, 1.3)), radius_mm=float(rng.uniform(9, 16))))
    young = float(base.gel.young_mpa * np.exp(rng.normal(0, 0.3)))
    gel_obj = dataclasses.replace(
        base.gel, young_mpa=young, shear_mpa=young / rng.uniform(2.7, 3.3),
        thickness_mm=float(rng.uniform(3.0, 6.0)), friction=float(rng.uniform(0.7, 1.3)),
        markers=bool(rng.random() < 0.3), texture_seed=int(rng.integers(1000, 1 << 30)),
        pigment=float(rng.uniform(0.003, 0.03)))
    sensor = dataclasses.replace(
        base, name=f"rand-{index}", gel=gel_obj, leds=tuple(leds),
        ambient=tuple(float(v) for v in rng.uniform(0.04, 0.14, 3)),
        albedo=tuple(float(v) for v in rng.uniform(0.75, 0.9, 3)),
        brightness=float(rng.uniform(80, 170)), vignette=float(rng.uniform(0.1, 0.45)),
        blur_px=float(rng.uniform(0.5, 1.5)), noise_std=float(rng.uniform(1.0, 4.0)),
        unevenness=float(rng.uniform(0.03, 0.1)), pixel_pattern=float(rng.uniform(0.003, 0.02)),
        dust=int(rng.integers(0, 10)), white_balance=tuple(float(v) for v in rng.uniform(0.7, 1.3, 3)),
        dome_radius_mm=float(rng.uniform(40, 100)) if rng.random() < 0.2 else None)
    return sensor


@functools.lru_cache(maxsize=4)
def _cached_pool(seed: int) -> tuple:
    return tuple(sensor_pool(seed))


def sensor_pool(seed: int, n: int = SENSOR_POOL) -> list:
    """The corpus's randomized sensors, deterministic from the seed."""
    return [randomized_sensor(np.random.default_rng([seed, VERSION, 7, i]), i) for i in range(n)]


def sim_frame(rng: np.random.Generator, settings: dict, sensor):
    """One background-subtracted frame of a random procedural shape pressed into `sensor`."""
    hsize = 96
    relief = random_relief(rng, hsize)
    height_mm = (1.0 - relief) * rng.uniform(1.0, 4.0)  # lower = touches first
    if rng.random() < 0.5:  # a finite object with an outline, not a plate with bumps
        height_mm[relief < rng.uniform(0.02, 0.2)] = np.inf
    mm_per_px = float(rng.uniform(0.08, 0.25))
    shape = sim.Shape.from_heightmap(height_mm, mm_per_px, name=f"rand-{rng.integers(1 << 30)}")
    size = render_size(sensor, settings["render_size"])
    fh, fw = sensor.fov_mm
    for _ in range(4):  # a pose/force the gel cannot take raises: draw another
        fz = float(rng.uniform(0.2, settings["fz_max"]))
        ft, phi = rng.uniform(0, settings["shear_max"]) * min(1.0, fz / 2), rng.uniform(0, 2 * np.pi)
        try:
            sample = sim.press(shape, sensor, force=(ft * np.cos(phi), ft * np.sin(phi), fz),
                               x_mm=float(rng.uniform(-0.3, 0.3) * fw), y_mm=float(rng.uniform(-0.3, 0.3) * fh),
                               yaw_deg=float(rng.uniform(0, 360)), tilt_deg=tuple(rng.uniform(-3, 3, 2)),
                               seed=int(rng.integers(1 << 30)), size=size)
            break
        except ValueError:
            continue
    else:
        return None, {}
    frame = to_input(sample.image, sensor.background(size), settings["input_size"])
    return frame, {"shape": shape.name, "sensor": sensor.key, "fz": fz}


def to_input(image: np.ndarray, background: np.ndarray, size: int) -> np.ndarray:
    """The training input before normalization (data.preprocess: nobg, pad, resize) as uint8."""
    return np.clip(np.rint(to_unit(image, background, size) * 255), 0, 255).astype(np.uint8)
