"""One press: a body, a sensor, a requested force and a pose -> the camera frame and its labels."""

from __future__ import annotations

import dataclasses
import functools
import math
import time

import cv2
import numpy as np

from ffjax.sim import mechanics, optics
from ffjax.sim.sensors import Sensor, get_sensor
from ffjax.sim.shapes import FAR, INDENTERS, Shape, get_shape

SKIN_MM = 0.1  # bending length of the gel's pigment skin
MAX_TILT_DEG = 15.0  # "small tilt": beyond this the height-field (no undercut) picture breaks down


@dataclasses.dataclass
class Sample:
    image: np.ndarray  # uint8 (H, W, 3)
    background: np.ndarray  # uint8 (H, W, 3), the sensor's no-contact frame
    depth: np.ndarray  # float32 (H, W), gel surface displacement in mm (+ = pressed in, - = bulge)
    force: np.ndarray  # float32 (3,), applied (Fx, Fy, Fz) in N; shear capped at mu * Fz
    meta: dict


@functools.lru_cache(maxsize=64)
def _grid(sensor: Sensor, size: tuple[int, int]):
    return optics.grid(sensor, size)


def _solve_size(sensor: Sensor) -> tuple[int, int]:
    """Fixed grid for the force solve (quarter native resolution, ~0.25 mm: finer changes the approach by
    < 3%), so the force-depth relation does not depend on the render size."""
    h, w = sensor.native_size
    return h // 4, w // 4


def body_heights(shape: Shape, sensor: Sensor, size, x_mm, y_mm, yaw_deg, tilt_deg) -> np.ndarray:
    """Height of the posed body above the gel (mm) at each pixel of a `size` grid, including the
    gel's dome (DIGIT): the gap that pressing by delta closes."""
    X, Y = _grid(sensor, tuple(size))
    u, v = X - np.float32(x_mm), Y - np.float32(y_mm)
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    dy, dx = sensor.mm_per_px(size)
    h = shape.sample(c * u + s * v, -s * u + c * v, (dx + dy) / 2)
    tx, ty = tilt_deg
    if tx or ty:
        h = h + np.float32(math.tan(math.radians(tx))) * u + np.float32(math.tan(math.radians(ty))) * v
    if sensor.dome_radius_mm:
        h = h + (X**2 + Y**2) / np.float32(2 * sensor.dome_radius_mm)
    return h


def render_size_of(sensor: Sensor, size) -> tuple[int, int]:
    """`size` (or the sensor's native size) as (H, W) ints; ValueError unless two whole numbers >= 2."""
    if size is None:
        return tuple(sensor.native_size)
    try:
        h, w = (float(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"size must be (height, width) in pixels, got {size!r}") from None
    if not (h.is_integer() and w.is_integer() and h >= 2 and w >= 2):  # the shading needs a 2x2 gradient
        raise ValueError(f"size must be two whole numbers >= 2, got {size!r}")
    return int(h), int(w)


def _check(sensor: Sensor, force, x_mm, y_mm, yaw_deg, tilt_deg, seed=0):
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    f = np.asarray(force, dtype=np.float64).reshape(-1)
    if f.shape != (3,):
        raise ValueError(f"force must be (fx, fy, fz), got {force!r}")
    vals = [*f, x_mm, y_mm, yaw_deg, *tilt_deg]
    if not all(math.isfinite(float(v)) for v in vals):
        raise ValueError(f"force and pose must be finite numbers, got force={force!r}, pose="
                         f"{(x_mm, y_mm, yaw_deg, tuple(tilt_deg))!r}")
    if f[2] < 0:
        raise ValueError(f"Fz must be >= 0 (pressing into the gel), got {f[2]}")
    fh, fw = sensor.fov_mm
    if abs(x_mm) > fw / 2 or abs(y_mm) > fh / 2:
        raise ValueError(f"pose ({x_mm}, {y_mm}) mm is outside the {fw:.1f} x {fh:.1f} mm pad of {sensor.key}")
    if max(abs(tilt_deg[0]), abs(tilt_deg[1])) > MAX_TILT_DEG:
        raise ValueError(f"tilt {tuple(tilt_deg)} deg beyond the +-{MAX_TILT_DEG} deg the model supports")
    return f


def press(shape: Shape | str, sensor: Sensor | str, force=(0.0, 0.0, 1.0), x_mm: float = 0.0,
          y_mm: float = 0.0, yaw_deg: float = 0.0, tilt_deg=(0.0, 0.0), seed: int = 0,
          size: tuple[int, int] | None = None, noise: bool = True) -> Sample:
    """Press `shape` into `sensor` with the requested force (N) at a pose; returns the frame and labels.

    The penetration is solved so that the gel carries Fz; shear beyond mu * Fz slips and is capped
    (meta["slip"]). Camera noise comes from `seed` (independent of the background frame's fixed noise);
    noise=False renders a noiseless frame (then zero force gives exactly sensor.background(size, False)).
    """
    shape = get_shape(shape) if isinstance(shape, str) else shape
    sensor = get_sensor(sensor) if isinstance(sensor, str) else sensor
    size = render_size_of(sensor, size)
    s = _press(shape, sensor, force, x_mm, y_mm, yaw_deg, tilt_deg, seed, size, noise)
    s.background = optics.background(sensor, size, noise)
    return s


def _press(shape: Shape, sensor: Sensor, force, x_mm, y_mm, yaw_deg, tilt_deg, seed, size, noise) -> Sample:
    tilt = np.asarray(tilt_deg, dtype=np.float64).reshape(-1)
    if tilt.shape != (2,):
        raise ValueError(f"tilt_deg must be (tilt_x, tilt_y) in degrees, got {tilt_deg!r}")
    tilt_deg = tuple(float(t) for t in tilt)
    f = _check(sensor, force, x_mm, y_mm, yaw_deg, tilt_deg, seed)
    gel = sensor.gel
    pose = (float(x_mm), float(y_mm), float(yaw_deg), tilt_deg)

    # force balance on the fixed solve grid
    ssize = _solve_size(sensor)
    sdy, sdx = sensor.mm_per_px(ssize)
    h_s = body_heights(shape, sensor, ssize, *pose)
    if not (h_s < 0.5 * FAR).any():
        raise ValueError(f"{shape.name} at pose {pose} does not reach the pad")
    normal = mechanics.solve_normal(h_s, (sdx + sdy) / 2, gel.shear_mpa, gel.thickness_mm, float(f[2]))
    cell_s = sdx * sdy
    hmin = float(h_s.min())

    # the same press on the render grid: the solved surface, with the body's own detail where it touches
    dy, dx = sensor.mm_per_px(size)
    mpp = (dx + dy) / 2
    h = body_heights(shape, sensor, size, *pose)
    d = np.float32(hmin + normal.delta) - h  # > 0 where the body is below the undeformed surface
    # bilinear both ways: mirror-symmetric at any ratio (area averaging is not at 60 -> 48), and the
    # solved surface is smooth on the solve grid's scale
    to_render = lambda a: cv2.resize(a, (size[1], size[0]), interpolation=cv2.INTER_LINEAR)  # noqa: E731
    surface = to_render(normal.surface.astype(np.float32))
    depth = np.maximum(surface, d) if normal.delta > 0 else surface
    sh = mechanics.shear(f[:2], float(f[2]), normal.contact, (sdx + sdy) / 2, gel.shear_mpa, gel.thickness_mm,
                         gel.friction)
    disp_px = None
    if sh.field is not None:
        disp_px = to_render(sh.field) / np.float32(mpp)
        depth = _carried(depth, disp_px, (sh.disp_mm / mpp).astype(np.float32)) + to_render(mechanics.shear_bulge(sh))
    # the pigment skin cannot bend sharply: soften kinks at the contact edge (~0.1 mm)
    depth = mechanics.smooth(depth.astype(np.float32), SKIN_MM / mpp)
    image = optics.render(sensor, size, depth, disp_px, seed if noise else None)
    applied = np.array([sh.force[0], sh.force[1], f[2]], dtype=np.float32)
    meta = {
        "shape": shape.name, "sensor": sensor.name, "gel": sensor.gel_id, "sensor_key": sensor.key,
        "x_mm": pose[0], "y_mm": pose[1], "yaw_deg": pose[2], "tilt_deg": tilt_deg,
        "penetration_mm": normal.delta, "contact_area_mm2": float(normal.contact.sum() * cell_s),
        "slip": bool(sh.slip), "shear_disp_mm": tuple(float(v) for v in sh.disp_mm),
        "shear_stiffness_n_per_mm": float(sh.stiffness), "requested_force": tuple(float(v) for v in f),
        "mm_per_px": float(mpp), "seed": int(seed), "size": size,
    }
    return Sample(image, None, depth, applied, meta)


def _carried(depth: np.ndarray, disp_px: np.ndarray, body_px: np.ndarray) -> np.ndarray:
    """The surface shape carried by the gel's sideways motion. `depth` is the unsheared solution around the body
    where it is now; the body has moved by body_px from where it pressed, and the gel at each point by
    disp_px (all of body_px on the contact, less away from it), so the free surface around the contact trails
    behind: the height at x is the unsheared one at x + (body_px - disp_px)."""
    H, W = depth.shape
    cols, rows = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    lag = body_px[None, None, :] - disp_px
    return cv2.remap(depth.astype(np.float32), cols + lag[..., 0], rows + lag[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def press_batch(shape: Shape | str, sensor: Sensor | str, forces, x_mm=None, y_mm=None, yaw_deg=None,
                tilt_deg=None, seeds=None, size=None, noise: bool = True) -> dict:
    """N presses of one shape on one sensor (the dataset path; shares every cached table).

    forces (N, 3); poses are (N,) arrays (tilt (N, 2)) or None for centred/untilted; seeds (N,) or None
    (= 0..N-1). Returns {"image" (N,H,W,3) uint8, "depth" (N,H,W) float32, "force" (N,3) float32,
    "background" (H,W,3) uint8, "meta": list of dicts}.
    """
    shape = get_shape(shape) if isinstance(shape, str) else shape
    sensor = get_sensor(sensor) if isinstance(sensor, str) else sensor
    size = render_size_of(sensor, size)
    forces = np.asarray(forces, dtype=np.float64)
    if forces.ndim != 2 or forces.shape[1] != 3:
        raise ValueError(f"forces must be (N, 3), got shape {forces.shape}")
    n = len(forces)
    xs, ys, yaws = (_per_press(v, n, name) for v, name in ((x_mm, "x_mm"), (y_mm, "y_mm"), (yaw_deg, "yaw_deg")))
    tilts = np.zeros((n, 2)) if tilt_deg is None else np.asarray(tilt_deg, float)
    if tilts.shape != (n, 2):
        raise ValueError(f"tilt_deg must be ({n}, 2) for {n} forces, got shape {tilts.shape}")
    seeds = np.arange(n) if seeds is None else _per_press(seeds, n, "seeds", dtype=np.int64)
    H, W = size
    out = {"image": np.empty((n, H, W, 3), np.uint8), "depth": np.empty((n, H, W), np.float32),
           "force": np.empty((n, 3), np.float32), "background": optics.background(sensor, size, noise), "meta": []}
    for i in range(n):
        s = _press(shape, sensor, forces[i], xs[i], ys[i], yaws[i], tilts[i], int(seeds[i]), size, noise)
        out["image"][i], out["depth"][i], out["force"][i] = s.image, s.depth, s.force
        out["meta"].append(s.meta)
    return out


def _per_press(v, n: int, name: str, dtype=float) -> np.ndarray:
    """A per-press array of length n (zeros for None); ValueError on a length mismatch."""
    a = np.zeros(n, dtype) if v is None else np.asarray(v, dtype).reshape(-1)
    if a.shape != (n,):
        raise ValueError(f"{name} must have one value per force ({n}), got {a.size}")
    return a


def benchmark(size=(48, 64), n: int = 400, sensor: str = "mini-1", seed: int = 0, verbose: bool = True) -> dict:
    """Throughput of press_batch in one process over all indenters with random forces and poses (what
    dataset generation does). Returns and prints samples/minute by wall clock and by this process's CPU
    time (the rate per free core; a shared machine makes the wall rate lower)."""
    rng = np.random.default_rng(seed)
    sens = get_sensor(sensor)
    size = tuple(size)
    per = max(1, n // len(INDENTERS))
    for name in INDENTERS:  # build shape maps and tables outside the timing
        press_batch(name, sens, [(0, 0, 1.0)], size=size)
    t0, c0 = time.perf_counter(), time.process_time()
    for name in INDENTERS:
        f = np.stack([rng.uniform(-1.5, 1.5, per), rng.uniform(-1.5, 1.5, per), rng.uniform(0.2, 15, per)], 1)
        press_batch(name, sens, f, rng.uniform(-3, 3, per), rng.uniform(-2, 2, per), rng.uniform(-180, 180, per),
                    rng.uniform(-3, 3, (per, 2)), size=size)
    count = per * len(INDENTERS)
    out = {"size": size, "n": count, "per_minute_wall": count / (time.perf_counter() - t0) * 60,
           "per_minute_cpu": count / max(time.process_time() - c0, 1e-9) * 60}
    if verbose:
        print(f"sim.benchmark size={size} n={count}: {out['per_minute_wall']:,.0f} samples/minute wall, "
              f"{out['per_minute_cpu']:,.0f} per CPU-minute (1 process)")
    return out
