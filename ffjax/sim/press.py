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


def solve_size(sensor: Sensor, size) -> tuple[int, int]:
    """The force solve's grid for frames of `size`: the frame's own pixels, never finer than a quarter of the
    native resolution (~0.3 mm on a Mini, where a finer grid no longer changes a press's shear or approach by a
    percent). A coarser frame cannot show detail a finer solve would add, so its solve costs what the frame
    resolves; docs/simulator.md states what each grid gives away against a 2x-finer one, shape by shape."""
    h, w = render_size_of(sensor, size)
    nh, nw = sensor.native_size
    return min(h, nh // 4), min(w, nw // 4)


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
          size: tuple[int, int] | None = None, noise: bool = True, path: str = "shear",
          steps: int = mechanics.PATH_STEPS, quadrature: str = mechanics.PATH_QUADRATURE) -> Sample:
    """Press `shape` into `sensor` with the requested force (N) at a pose; returns the frame and labels.

    The penetration is solved so that the gel carries Fz; shear beyond mu * Fz slips and is capped
    (meta["slip"]). path="oblique": the paper's press along the tilted tool axis, its shear from the path
    (request (0, 0, Fz), in `steps` increments with a `quadrature`; see `press_many`). Camera noise comes from
    `seed` (independent of the background frame's fixed noise); noise=False renders a noiseless frame (then zero
    force gives exactly sensor.background(size, False)).
    The batch of one of `press_batch`.
    """
    shape = get_shape(shape) if isinstance(shape, str) else shape
    sensor = get_sensor(sensor) if isinstance(sensor, str) else sensor
    size = render_size_of(sensor, size)
    s = press_many([shape], sensor, [force], [x_mm], [y_mm], [yaw_deg], [tilt_deg], [seed], size, noise,
                   path=path, steps=steps, quadrature=quadrature)[0]
    if isinstance(s, ValueError):
        raise s
    s.background = optics.background(sensor, size, noise)
    return s


@dataclasses.dataclass
class _Request:
    """One press, checked, with its body's heights on the force solve's grid."""

    shape: Shape
    force: np.ndarray  # (3,) requested, N
    pose: tuple  # (x_mm, y_mm, yaw_deg, (tilt_x, tilt_y))
    seed: int
    h_s: np.ndarray  # heights above the gel on the solve grid, mm


def _request(shape: Shape, sensor: Sensor, ssize, force, x_mm, y_mm, yaw_deg, tilt_deg, seed) -> _Request:
    tilt = np.asarray(tilt_deg, dtype=np.float64).reshape(-1)
    if tilt.shape != (2,):
        raise ValueError(f"tilt_deg must be (tilt_x, tilt_y) in degrees, got {tilt_deg!r}")
    tilt_deg = tuple(float(t) for t in tilt)
    f = _check(sensor, force, x_mm, y_mm, yaw_deg, tilt_deg, seed)
    pose = (float(x_mm), float(y_mm), float(yaw_deg), tilt_deg)
    h_s = body_heights(shape, sensor, ssize, *pose)
    if not (h_s < 0.5 * FAR).any():
        raise ValueError(f"{shape.name} at pose {pose} does not reach the pad")
    return _Request(shape, f, pose, int(seed), h_s)


PATHS = ("shear", "oblique")


def press_many(shapes, sensor: Sensor | str, forces, xs, ys, yaws, tilts, seeds, size: tuple[int, int] | None = None,
               noise: bool = True, reference: bool = False, path: str = "shear",
               steps: int = mechanics.PATH_STEPS, quadrature: str = mechanics.PATH_QUADRATURE,
               grid: tuple[int, int] | None = None) -> list:
    """One Sample per press (shapes, by name or Shape, and poses may all differ; one sensor and render size), or
    the ValueError that press refused: the layer solves of all of them run as one batch
    (`mechanics.solve_normal_batch`, `shear_batch`); reference=True runs the numpy reference solves instead (the
    benchmark's old path).

    path "shear": pressed to Fz, then the requested (Fx, Fy) applied in stick. path "oblique": the paper's
    press, the tool moved along its tilted axis until the gel carries Fz, the shear coming from the path
    (`mechanics.oblique_batch` in `steps` increments, each step's stiffness taken by its `quadrature`; request
    (0, 0, Fz), the tilt sets the push). grid: the force solve's grid (default `solve_size` of the render size;
    the benchmark's discretization check solves on a finer one)."""
    sensor = get_sensor(sensor) if isinstance(sensor, str) else sensor
    return press_many_seen(shapes, (sensor,), forces, xs, ys, yaws, tilts, seeds, size, noise, reference, path,
                           steps, quadrature, grid)[0]


def mechanics_key(sensor: Sensor) -> tuple:
    """What a press's solve reads of a sensor (the pad's geometry and the gel's mechanics): sensors with equal keys
    solve every press alike and differ only in how they see it (LEDs, camera, pigment, markers)."""
    g = sensor.gel
    return (tuple(sensor.native_size), sensor.native_mm_per_px, sensor.dome_radius_mm, g.young_mpa, g.shear_mpa,
            g.thickness_mm, g.friction)


def press_many_seen(shapes, sensors, forces, xs, ys, yaws, tilts, seeds, size: tuple[int, int] | None = None,
                    noise: bool = True, reference: bool = False, path: str = "shear",
                    steps: int = mechanics.PATH_STEPS, quadrature: str = mechanics.PATH_QUADRATURE,
                    grid: tuple[int, int] | None = None) -> list[list]:
    """`press_many` solved once and rendered as each of `sensors` sees it: one list of Samples (or ValueErrors) per
    sensor, each the very list press_many would give for that sensor. The sensors must share `mechanics_key` (a
    robustness sweep's lighting, camera noise or pigment levels of one gel); the first one's solve serves all."""
    views = [get_sensor(s) if isinstance(s, str) else s for s in sensors]
    if not views:
        raise ValueError("press_many_seen needs at least one sensor")
    sensor = views[0]
    for v in views[1:]:
        if mechanics_key(v) != mechanics_key(sensor):
            raise ValueError(f"press_many_seen: {v.key} solves presses differently from {sensor.key} (pad or gel "
                             f"mechanics {mechanics_key(v)} vs {mechanics_key(sensor)}); press them apart")
    if path not in PATHS:
        raise ValueError(f"path must be one of {PATHS}, got {path!r}")
    size = render_size_of(sensor, size)
    shapes = [get_shape(s) if isinstance(s, str) else s for s in shapes]
    if len({len(shapes), len(forces), len(xs), len(ys), len(yaws), len(tilts), len(seeds)}) != 1:
        raise ValueError("press_many needs one shape, force, x, y, yaw, tilt and seed per press, got "
                         f"{[len(v) for v in (shapes, forces, xs, ys, yaws, tilts, seeds)]}")
    gel = sensor.gel
    ssize = solve_size(sensor, size) if grid is None else render_size_of(sensor, grid)
    sdy, sdx = sensor.mm_per_px(ssize)
    out: list = [None] * len(shapes)
    reqs = {}
    for i, args in enumerate(zip(shapes, forces, xs, ys, yaws, tilts, seeds)):
        try:
            if path == "oblique" and np.asarray(args[1], float).reshape(-1)[:2].any():
                raise ValueError(f"an oblique press takes its shear from the tilted path: request (0, 0, Fz), got "
                                 f"{tuple(float(v) for v in np.asarray(args[1]).reshape(-1))}")
            reqs[i] = _request(args[0], sensor, ssize, *args[1:])
        except ValueError as e:
            out[i] = e
    if not reqs:
        return [list(out) for _ in views]
    # similar presses side by side: a batch runs until its slowest press converges, and the same body at a
    # similar force takes a similar number of iterations (results do not depend on the order)
    reqs = dict(sorted(reqs.items(), key=lambda kv: (kv[1].shape.name, float(kv[1].force[2]))))
    mpp_s = (sdx + sdy) / 2
    heights, fzs = [r.h_s for r in reqs.values()], [float(r.force[2]) for r in reqs.values()]
    if path == "oblique":
        slopes = [np.tan(np.radians(r.pose[3])) for r in reqs.values()]
        normals, by_path = mechanics.oblique_batch(heights, mpp_s, gel.shear_mpa, gel.thickness_mm, gel.friction,
                                                   fzs, slopes, steps, reference, quadrature)
    else:
        normals = mechanics.solve_normal_batch(heights, mpp_s, gel.shear_mpa, gel.thickness_mm, fzs, reference)
    ok = []
    for k, (i, nrm) in enumerate(zip(reqs, normals)):
        if isinstance(nrm, ValueError):
            out[i] = nrm
        else:
            ok.append((reqs[i], nrm, i, k))
    if not ok:
        return [list(out) for _ in views]
    if path == "oblique":
        shears = [by_path[k] for *_, k in ok]
    else:
        shears = mechanics.shear_batch([r.force[:2] for r, *_ in ok], [float(r.force[2]) for r, *_ in ok],
                                       np.stack([n.contact for _, n, *_ in ok]), mpp_s, gel.shear_mpa,
                                       gel.thickness_mm, gel.friction, reference,
                                       [mechanics.hold_depth(n, gel.thickness_mm) for _, n, *_ in ok])
    seen = []
    for view in views:
        frames = list(out)
        for (req, nrm, i, _), sh in zip(ok, shears):
            frames[i] = _sample(req, view, size, ssize, nrm, sh, noise, path)
        seen.append(frames)
    return seen


def _sample(req: _Request, sensor: Sensor, size: tuple[int, int], ssize: tuple[int, int], normal, sh, noise: bool,
            path: str) -> Sample:
    """The frame and labels of one solved press: the solved surface on the render grid, with the body's own
    detail where it touches, carried by the shear, rendered."""
    sdy, sdx = sensor.mm_per_px(ssize)
    dy, dx = sensor.mm_per_px(size)
    mpp = (dx + dy) / 2
    h = body_heights(req.shape, sensor, size, *req.pose)
    d = np.float32(float(req.h_s.min()) + normal.delta) - h  # > 0 where the body is below the undeformed surface
    # bilinear both ways: mirror-symmetric at any ratio (area averaging is not at 60 -> 48), and the
    # solved surface is smooth on the solve grid's scale
    to_render = lambda a: cv2.resize(a, (size[1], size[0]), interpolation=cv2.INTER_LINEAR)  # noqa: E731
    surface = to_render(normal.surface.astype(np.float32))
    depth = np.maximum(surface, d) if normal.delta > 0 else surface
    disp_px = None
    if sh.field is not None:
        disp_px = to_render(sh.field) / np.float32(mpp)
        depth = _carried(depth, disp_px, (sh.disp_mm / mpp).astype(np.float32)) + to_render(mechanics.shear_bulge(sh))
    # the pigment skin cannot bend sharply: soften kinks at the contact edge (~0.1 mm)
    depth = mechanics.smooth(depth.astype(np.float32), SKIN_MM / mpp)
    image = optics.render(sensor, size, depth, disp_px, req.seed if noise else None)
    f, pose = req.force, req.pose
    applied = np.array([sh.force[0], sh.force[1], f[2]], dtype=np.float32)
    hold = sh.hold_mm if sh.field is not None else 0.0
    meta = {
        "shape": req.shape.name, "sensor": sensor.name, "gel": sensor.gel_id, "sensor_key": sensor.key,
        "x_mm": pose[0], "y_mm": pose[1], "yaw_deg": pose[2], "tilt_deg": pose[3],
        "penetration_mm": normal.delta, "contact_area_mm2": float(normal.contact.sum() * sdx * sdy),
        "slip": bool(sh.slip), "shear_disp_mm": tuple(float(v) for v in sh.disp_mm),
        "shear_stiffness_n_per_mm": float(sh.stiffness), "hold_depth_mm": hold, "path": path,
        "requested_force": tuple(float(v) for v in f),
        "mm_per_px": float(mpp), "seed": int(req.seed), "size": size,
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


def press_batch(shape, sensor: Sensor | str, forces, x_mm=None, y_mm=None, yaw_deg=None,
                tilt_deg=None, seeds=None, size=None, noise: bool = True, reference: bool = False,
                path: str = "shear", steps: int = mechanics.PATH_STEPS,
                quadrature: str = mechanics.PATH_QUADRATURE) -> dict:
    """N presses on one sensor, their layer solves batched (the dataset path; shares every cached table).

    shape: one shape (name or Shape) for all, or a sequence of N. forces (N, 3); poses are (N,) arrays (tilt
    (N, 2)) or None for centred/untilted; seeds (N,) or None (= 0..N-1). Returns {"image" (N,H,W,3) uint8,
    "depth" (N,H,W) float32, "force" (N,3) float32, "background" (H,W,3) uint8, "meta": list of dicts}; the first
    press the simulator refuses raises its ValueError. reference=True: the numpy reference solves; path, steps,
    quadrature: see `press_many`.
    """
    shape = get_shape(shape) if isinstance(shape, str) else shape
    if not isinstance(shape, Shape):
        shape = [get_shape(s) if isinstance(s, str) else s for s in shape]
        if len(shape) != len(forces):
            raise ValueError(f"shape must be one shape or one per force ({len(forces)}), got {len(shape)}")
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
    shapes = [shape] * n if isinstance(shape, Shape) else shape
    samples = press_many(shapes, sensor, forces, xs, ys, yaws, tilts, [int(v) for v in seeds], size, noise, reference,
                         path, steps, quadrature)
    for i, s in enumerate(samples):
        if isinstance(s, ValueError):
            raise s
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
