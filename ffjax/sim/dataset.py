"""Balanced presses on disk: every split the paper's tables need, as npz shards.

    python -m ffjax.simulate --preset quick --out DIR [--force] [--workers N] [--set data.x=y]   (the CLI)
    generate(cfg, out)                                                                    (from Python)

Layout: DIR/config.json (what was asked, written first), DIR/<split>/shard_#####.npz (image uint8
(N,H,W,3), depth float32 (N,H,W) mm, force float32 (N,3), shape (N,) str, per-sample pose and sim
meta), DIR/<split>/background.png, DIR/<split>/split.json, DIR/manifest.json (written last).

Sampling, as the paper's data collection: per shape, Fz is stratified over [fz_min, fz_max] (one
sample per equal-width bin, shuffled) so each shape's Fz histogram is flat; x, y uniform in a safe
region that keeps the shape's 15 N footprint on the pad; yaw uniform; roll/pitch uniform within
+-tilt_max_deg. data.loading "oblique" (the paper's): the robot presses along its tilted tool axis until
the gel carries Fz, and the shear is what that path gives (`mechanics.oblique_batch`, data.path_steps
increments); "shear" (before issue 32): pressed to Fz, then Fz * tan(tilt) plus noise (shear_noise * Fz)
applied sideways, redrawn beyond +-shear_max. data.sideways_share of the oblique train and val presses (per
shape, on a random stream of its own; the test splits keep the paper's presses) are pressed to Fz at their pose
and then pushed sideways by Fx, Fy uniform in +-shear_max, drawn apart from the lean, so the tool's tilt in the
image does not tell their shear (shards then carry a "sideways" flag). Either way the simulator caps the shear
at mu * Fz. The
labels are the force the gel carries plus the F/T sensor's noise (data.ft_noise N per axis, Gaussian, the
release's sensor at rest). Every sensor carries data.pattern_moving of its fine fixed pattern on the gel
(`sensors.with_pattern_moving`). The train, val and unseen splits are pressed on data.train_sensor; every
sensor of sim.SENSOR_NAMES gets a Table II and a calibration split.

Deterministic from cfg["seed"]: every split has its own random stream and its own block of render
seeds (train, val and test seeds are disjoint). Each shard is written atomically (temp file, fsync,
os.replace) and skipped when present and readable, so a killed run resumes: finished shards are kept,
the one being written is redone. A different config refuses to touch DIR unless force=True. An
unwritable DIR fails before any rendering; a full disk stops with a message, finished shards intact.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import functools
import hashlib
import io
import json
import multiprocessing
import os
import shutil
import signal
import time
import warnings
import zipfile
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from ffjax import compile_cache, sim
from ffjax.data.images import write_rgb
from ffjax.errors import DataError
from ffjax.files import LOCK_NAME, atomic_write, atomic_write_text, check_writable, folder_lock
from ffjax.sim import batched
from ffjax.sim.seeds import render_seeds
from ffjax.sim.sensors import MINI_NAMES, SENSOR_NAMES, get_sensor, with_pattern_moving

# 2: the camera's patterns stay put, a real Mini's colour balance and fine pattern; 3: the oblique press, F/T noise
# on the labels, the moving share of the fixed pattern a key (issue 32); 4: the force solve on the frame's grid
# (press.solve_size), no longer a fixed quarter of the native resolution
VERSION = 4
# Generation knobs (cfg["data"]): every one decides the bytes on disk
GEN_KEYS = ("render_size", "train_per_indenter", "val_per_indenter", "unseen_per_object",
            "sensor_test_per_indenter", "calib_samples", "fz_max", "shear_max", "shard_size", "fz_min",
            "tilt_max_deg", "shear_noise", "loading", "path_steps", "ft_noise", "pattern_moving", "path_quadrature")
# config.json names the training sensor only when it is not this one, the sensor of every folder written before
# it was a choice: those folders stay valid
LEGACY_TRAIN_SENSOR = "mini-1-gel1"
_SENSORS_BEFORE = tuple(f"mini-{u}-gel{g}" for u in (1, 2, 3) for g in (1, 2, 3)) + ("digit",)
CALIB_SHAPE = "sphere_big"
SENSOR_KEYS = SENSOR_NAMES  # every sensor gets a Table II split and a calibration split
MINI_KEYS = tuple(k for k in SENSOR_NAMES if get_sensor(k).name in MINI_NAMES)
# Shards are stored uncompressed: camera noise and the smooth depth tails deflate little, for several times
# the write time, and stored members load faster.
COMPRESS = False
SIDEWAYS_STREAM = 0x51DE  # the random stream of data.sideways_share's choice and pushes
SIDEWAYS_SPLITS = ("train", "val")  # the test splits (Tables I-III) keep the paper's oblique presses
_OURS = ("config.json", "manifest.json", "train", "val", "unseen", "sensor", "calib")


@dataclasses.dataclass(frozen=True)
class SplitSpec:
    name: str  # "train", "unseen/banana", "sensor/mini-2-gel3", "calib/digit", ...
    sensor: str  # a key of sim.SENSOR_NAMES: "mini-1-gel1" .. "mini-3-gel3", "digit"
    shapes: tuple[str, ...]
    per_shape: int
    index: int  # fixed position in the list of all splits: selects the random stream and seed block

    @property
    def count(self) -> int:
        return self.per_shape * len(self.shapes)


DATA_ENV = "FFJAX_DATA"


def default_root(preset: str) -> Path:
    """Where a preset's simulated dataset is kept when no --data is given, the same from any working folder:
    $FFJAX_DATA/<preset>; else the source checkout's data/<preset> (README installs from a checkout); else
    ~/.cache/ffjax/data/<preset>."""
    if os.environ.get(DATA_ENV):
        return Path(os.environ[DATA_ENV]).expanduser().absolute() / preset
    checkout = Path(__file__).resolve().parents[2]
    if (checkout / "pyproject.toml").is_file() and (checkout / "ffjax").is_dir():
        return checkout / "data" / preset
    return Path.home() / ".cache" / "ffjax" / "data" / preset


def split_dir(root, kind: str, name: str | None = None) -> Path:
    """Folder of a split: split_dir(DIR, "train"), split_dir(DIR, "unseen", "banana"),
    split_dir(DIR, "sensor", "mini-2-gel1"), split_dir(DIR, "calib", "digit")."""
    return Path(root) / kind if name is None else Path(root) / kind / name


def split_specs(cfg: dict) -> list[SplitSpec]:
    """All splits of a config, in a fixed order (the order sets each split's seeds)."""
    d = cfg["data"]
    train = d["train_sensor"]
    ind = tuple(sim.INDENTERS)
    table2 = tuple(s for s in ind if s != CALIB_SHAPE)
    specs = [("train", train, ind, d["train_per_indenter"]), ("val", train, ind, d["val_per_indenter"])]
    specs += [(f"unseen/{o}", train, (o,), d["unseen_per_object"]) for o in sim.UNSEEN_OBJECTS]
    specs += [(f"sensor/{k}", k, table2, d["sensor_test_per_indenter"]) for k in SENSOR_KEYS]
    specs += [(f"calib/{k}", k, (CALIB_SHAPE,), d["calib_samples"]) for k in SENSOR_KEYS]
    return [SplitSpec(n, s, sh, int(p), i) for i, (n, s, sh, p) in enumerate(specs)]


def gen_config(cfg: dict) -> dict:
    """What determines the bytes on disk (JSON-normalized): compared on every rerun."""
    d = cfg["data"]
    data = {k: d[k] for k in GEN_KEYS}
    if d["train_sensor"] != LEGACY_TRAIN_SENSOR:
        data["train_sensor"] = d["train_sensor"]
    if d["sideways_share"]:  # named only when used: the folders written before it was a key stay valid
        data["sideways_share"] = d["sideways_share"]
    if SENSOR_KEYS != _SENSORS_BEFORE:  # a sensor added (or removed) changes the splits and their seeds
        data["sensors"] = list(SENSOR_KEYS)
    return json.loads(json.dumps({"version": VERSION, "seed": int(cfg["seed"]), "data": data}))


def sim_fingerprint() -> str:
    """Hash of the simulator's source: recorded in the manifest, warned about (not enforced) on reuse."""
    h = hashlib.sha256()
    for f in sorted(Path(__file__).parent.glob("*.py")):
        h.update(f.name.encode() + f.read_bytes())
    return h.hexdigest()[:16]


def sensor_of(key: str, data: dict):
    """The sensor `key` as a dataset (cfg["data"] or gen_config's) simulates it: data.pattern_moving of its fine
    fixed pattern on the gel."""
    return with_pattern_moving(get_sensor(key), float(data["pattern_moving"]))


def render_size(sensor, size) -> tuple[int, int]:
    """cfg render_size is landscape (H < W); portrait sensors (DIGIT) render it transposed."""
    h, w = sorted(int(s) for s in size)
    return (w, h) if sensor.native_size[0] > sensor.native_size[1] else (h, w)


@functools.lru_cache(maxsize=256)
def safe_region(shape_name: str, sensor_key: str, fz_max: float) -> tuple[float, float]:
    """Half-ranges (x, y) in mm for the pose offset: the shape's footprint at fz_max stays on the pad
    (0.9 of it), but never less than a fifth of the half pad (large objects overhang anyway)."""
    shape, sensor = sim.get_shape(shape_name), get_sensor(sensor_key)
    try:
        pen = sim.press(shape, sensor, (0.0, 0.0, fz_max), size=(24, 32), noise=False).meta["penetration_mm"]
    except ValueError:  # the gel cannot take fz_max centred: use the deepest press it allows
        pen = 0.9 * sensor.gel.thickness_mm
    H, W = shape.height.shape
    yy, xx = np.nonzero(shape.height < pen)
    r = float(np.hypot(xx - (W - 1) / 2, yy - (H - 1) / 2).max()) * shape.mm_per_px
    fh, fw = sensor.fov_mm
    return max(0.2 * fw / 2, 0.9 * fw / 2 - r), max(0.2 * fh / 2, 0.9 * fh / 2 - r)


def sample_presses(spec: SplitSpec, cfg: dict) -> dict:
    """Forces and poses of every press of a split, in the (shuffled) order they are stored."""
    g = gen_config(cfg)
    d, seed = g["data"], g["seed"]
    parts = []
    for si, name in enumerate(spec.shapes):
        n = spec.per_shape
        rng = np.random.default_rng([seed, spec.index, si, VERSION])
        fz = d["fz_min"] + (d["fz_max"] - d["fz_min"]) * (rng.permutation(n) + rng.random(n)) / n
        rx, ry = safe_region(name, spec.sensor, d["fz_max"])
        x, y = rng.uniform(-rx, rx, n), rng.uniform(-ry, ry, n)
        yaw = rng.uniform(-180.0, 180.0, n)
        tilt = rng.uniform(-d["tilt_max_deg"], d["tilt_max_deg"], (n, 2))
        if d["loading"] == "oblique":  # the shear comes from the path: the request is the normal force
            part = {"shape_index": np.full(n, si), "force": np.column_stack([np.zeros((n, 2)), fz]),
                    "x_mm": x, "y_mm": y, "yaw_deg": yaw, "tilt_deg": tilt}
            share = float(d.get("sideways_share", 0.0)) if spec.name in SIDEWAYS_SPLITS else 0.0
            if share:  # a stream of its own: the oblique presses' draws stay those of a split without the share
                side_rng = np.random.default_rng([seed, spec.index, si, VERSION, SIDEWAYS_STREAM])
                part["sideways"] = side_rng.permutation(n) < round(share * n)
                push = side_rng.uniform(-d["shear_max"], d["shear_max"], (n, 2))
                part["force"][:, :2] = np.where(part["sideways"][:, None], push, 0.0)
            parts.append(part)
            continue
        # pushed sideways after the press: the tangential part is Fz * tan(tilt), plus noise
        base, spread = fz[:, None] * np.tan(np.radians(tilt)), d["shear_noise"] * fz[:, None]
        ft = base + rng.normal(0, 1, (n, 2)) * spread
        for _ in range(20):  # redraw (truncate) rather than clip: no pile-up at +-shear_max
            out = np.abs(ft) > d["shear_max"]
            if not out.any():
                break
            ft[out] = (base + rng.normal(0, 1, (n, 2)) * spread)[out]
        ft = np.clip(ft, -d["shear_max"], d["shear_max"])
        parts.append({"shape_index": np.full(n, si), "force": np.column_stack([ft, fz]), "x_mm": x, "y_mm": y,
                      "yaw_deg": yaw, "tilt_deg": tilt})
    p = {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}
    order = np.random.default_rng([seed, spec.index, 10**6, VERSION]).permutation(len(p["x_mm"]))
    p = {k: v[order] for k, v in p.items()}
    p["seed"] = render_seeds(seed, spec.index, len(order))  # a block of its own per split and config seed
    return p


# A pose the simulator refuses (a deep press off the pad) is pulled towards the centre, halving its offset twice,
# then untilted at an eighth: the requested Fz is always honoured. Deterministic.
_PULLS = ((1.0, True), (0.5, True), (0.25, True), (0.125, False))


def _press_safe(shapes, sensor, q: dict, size, data: dict) -> list:
    """Samples of the presses `q` (sampled arrays), loaded as data["loading"], their layer solves batched; refused
    poses are pressed again, pulled inwards (_PULLS), in one batch per round."""
    n = len(shapes)
    out: list = [None] * n
    paths = np.where(q["sideways"], "shear", data["loading"]) if "sideways" in q else np.full(n, data["loading"])
    todo = list(range(n))
    for scale, tilted in _PULLS:
        for path in sorted(set(paths[todo])):  # one batch per loading path
            group = [i for i in todo if paths[i] == path]
            tilt = [tuple(q["tilt_deg"][i]) if tilted else (0.0, 0.0) for i in group]
            got = sim.press_many([shapes[i] for i in group], sensor, q["force"][group], q["x_mm"][group] * scale,
                                 q["y_mm"][group] * scale, q["yaw_deg"][group], tilt,
                                 [int(v) for v in q["seed"][group]], size, path=str(path),
                                 steps=int(data["path_steps"]), quadrature=data["path_quadrature"])
            for i, s in zip(group, got):
                out[i] = s
        todo = [i for i in todo if isinstance(out[i], ValueError)]
        if not todo:
            return out
    raise out[todo[0]]


def ft_reading(force, seeds, noise_n: float) -> np.ndarray:
    """What the F/T sensor reads of the forces (N, 3) the gel carries: each plus Gaussian noise of noise_n N per
    axis, drawn from the press's render seed (independent of the shard it lands in)."""
    noise = np.stack([np.random.default_rng([int(s), 0xF7]).normal(0.0, 1.0, 3) for s in seeds]) if len(seeds) \
        else np.zeros((0, 3))
    return (np.asarray(force, np.float64) + noise_n * noise).astype(np.float32)


def render_shard(spec: SplitSpec, p: dict, lo: int, hi: int, size, data: dict) -> dict:
    """Render presses [lo, hi) of a split (already sampled) as `data` (gen_config's) says: the shard's arrays.
    "force" is the label (the F/T reading), "force_applied" what the gel carries."""
    sensor = sensor_of(spec.sensor, data)
    size = render_size(sensor, size)
    sl = slice(lo, hi)
    q = {k: v[sl] for k, v in p.items()}
    idx_all = q["shape_index"]
    smp = _press_safe([sim.get_shape(spec.shapes[i]) for i in idx_all], sensor, q, size, data)
    applied = np.stack([s.force for s in smp])
    out = {"image": np.stack([s.image for s in smp]), "depth": np.stack([s.depth for s in smp]),
           "force": ft_reading(applied, q["seed"], float(data["ft_noise"])), "force_applied": applied}
    for k in ("x_mm", "y_mm", "yaw_deg", "penetration_mm", "contact_area_mm2", "tilt_deg", "requested_force",
              "shear_disp_mm", "slip"):
        v = np.array([s.meta[k] for s in smp])
        out[k] = v.astype(np.float32) if v.dtype == np.float64 else v
    out["shape"] = np.array([spec.shapes[i] for i in idx_all])
    out["seed"] = q["seed"].astype(np.int64)
    if "sideways" in q:
        out["sideways"] = q["sideways"]
    return out


def save_npz(path, arrays: dict, compress: bool = COMPRESS) -> None:
    """np.savez(_compressed), but byte-reproducible (fixed zip timestamps) and atomic (tmp + os.replace)."""
    path = Path(path)
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED

    def write(f):
        with zipfile.ZipFile(f, "w", method, allowZip64=True) as zf:
            for key, arr in arrays.items():
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.asarray(arr), allow_pickle=False)
                info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
                info.compress_type = method
                zf.writestr(info, buf.getvalue())

    atomic_write(path, write, _RESUME_HINT)


def _write_text(path: Path, text: str) -> None:
    atomic_write_text(path, text, _RESUME_HINT)


_RESUME_HINT = "finished shards are kept, rerun the same command to continue"


def _shard_ok(path: Path, n: int) -> bool:
    """A shard is done when it is there, its zip directory reads and it holds the n presses this config puts in it
    (cheap: the force array's header only); a shard of another config's size is redone."""
    try:
        with zipfile.ZipFile(path) as zf, zf.open("force.npy") as f:
            read = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
            shape = read[np.lib.format.read_magic(f)](f)[0]
            return len(shape) == 2 and shape[0] == n
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return False


def _stray(folder: Path, count: int) -> list[Path]:
    """Shard files in a split's folder beyond the ones its config writes (an interrupted writer of another
    config left them)."""
    want = {f"shard_{k:05d}.npz" for k in range(count)}
    return sorted(p for p in folder.glob("shard_*.npz") if p.name not in want)


def _start_worker() -> None:
    """A worker leaves Ctrl-C to the parent, which stops them all with one line (not one traceback each)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    compile_cache.enable()  # a worker loads what the parent or an earlier run compiled


def _shard_task(args) -> int:
    spec, p, lo, hi, size, data, path = args
    cv2.setNumThreads(1)  # one process per core already
    save_npz(path, render_shard(spec, p, lo, hi, size, data))
    return hi - lo


def _prepare(out: Path, g: dict, force: bool) -> None:
    cfg_file = out / "config.json"
    if cfg_file.is_file():
        old = json.loads(cfg_file.read_text())
        manifest = out / "manifest.json"
        stale_sim = manifest.is_file() and json.loads(manifest.read_text()).get("sim_fingerprint") \
            != sim_fingerprint()
        if old == g and not (force and stale_sim):  # force regenerates a same-config set made by another sim
            return
        if not force:
            diff = sorted(k for k in set(old.get("data", {})) | set(g["data"])
                          if old.get("data", {}).get(k) != g["data"].get(k))
            diff += [k for k in ("version", "seed") if old.get(k) != g[k]]
            raise FileExistsError(f"{out} holds a dataset generated with a different config (differs in: "
                                  f"{', '.join(diff)}); pass --force (force=True) to delete and regenerate "
                                  f"it, or choose another --out")
    elif out.is_dir() and any(p.name != LOCK_NAME for p in out.iterdir()) and not force:
        raise FileExistsError(f"{out} is not empty and holds no dataset config.json; pass --force to write "
                              f"into it anyway (only this tool's files are ever deleted), or choose another "
                              f"--out")
    for name in _OURS:  # only what this tool writes
        target = out / name
        if target.is_dir():
            shutil.rmtree(target)
        elif target.exists():
            target.unlink()
    out.mkdir(parents=True, exist_ok=True)
    _write_text(cfg_file, json.dumps(g, indent=1))


WORKERS_FROM = 2000  # presses: starting worker processes costs more than it saves on fewer
MAX_WORKERS = 8


def cpu_workers() -> int:
    """Worker processes a CPU gives a whole dataset: one per core, up to MAX_WORKERS."""
    return min(os.cpu_count() or 1, MAX_WORKERS)


def default_workers(presses: int, at_least: int = WORKERS_FROM) -> int:
    """Processes to simulate `presses` in: cpu_workers() from `at_least` presses on; one below it, and one on a
    GPU, which runs a whole batch at once and would give each process most of its memory."""
    return 1 if presses < at_least or batched.on_accelerator() else cpu_workers()


def generate(cfg: dict, out, force: bool = False, workers: int | None = None, progress: bool = True) -> dict:
    """Write (or finish, or reuse) every split of `cfg` under `out`; returns the manifest dict. One writer per
    folder: a second one is refused (FolderLockedError naming the first) before it touches anything."""
    out = Path(out)
    check_writable(out, what="dataset folder")  # before any rendering
    with folder_lock(out, "dataset generation"):
        return _generate(cfg, out, force, workers, progress)


def _generate(cfg: dict, out: Path, force: bool, workers: int | None, progress: bool) -> dict:
    g = gen_config(cfg)
    _prepare(out, g, force)
    specs = split_specs(cfg)
    size, shard = tuple(g["data"]["render_size"]), int(g["data"]["shard_size"])
    tasks, splits, total = [], {}, 0
    for spec in specs:
        folder = out / spec.name
        folder.mkdir(parents=True, exist_ok=True)
        for stale in folder.glob(".*.tmp*"):  # leftovers of a killed run
            stale.unlink()
        bounds = [(a, min(a + shard, spec.count)) for a in range(0, spec.count, shard)]
        stray = _stray(folder, len(bounds))
        if stray:
            names = ", ".join(p.name for p in stray[:5]) + (", ..." if len(stray) > 5 else "")
            raise DataError(f"{folder} holds shard(s) this config does not write ({names}): left by a writer with "
                            "another config; pass --force (force=True) to regenerate the folder")
        sensor = sensor_of(spec.sensor, g["data"])
        info = {"name": spec.name, "sensor": spec.sensor, "sensor_name": sensor.name, "gel": sensor.gel_id,
                "shapes": list(spec.shapes), "per_shape": spec.per_shape, "count": spec.count,
                "shard_counts": [b - a for a, b in bounds], "render_size": list(render_size(sensor, size)),
                "seed": g["seed"], "seed_block": spec.index}
        splits[spec.name] = info
        total += spec.count
        todo = [(k, a, b) for k, (a, b) in enumerate(bounds)
                if not _shard_ok(folder / f"shard_{k:05d}.npz", b - a)]
        if not (folder / "split.json").is_file():
            _write_text(folder / "split.json", json.dumps(info, indent=1))
        if not (folder / "background.png").is_file():
            write_rgb(folder / "background.png", sensor.background(render_size(sensor, size)))
        if todo:
            p = sample_presses(spec, cfg)
            tasks += [(spec, {k: v[a:b] for k, v in p.items()}, 0, b - a, size, g["data"],
                       folder / f"shard_{k:05d}.npz")
                      for k, a, b in todo]
    manifest_file = out / "manifest.json"
    if not tasks and manifest_file.is_file():
        manifest = json.loads(manifest_file.read_text())
        if manifest.get("sim_fingerprint") != sim_fingerprint():
            warnings.warn(f"{out} was generated by another version of ffjax/sim; reusing it anyway (same "
                          f"config). Delete it or pass --force to regenerate with the current simulator.",
                          stacklevel=2)
        return manifest
    if manifest_file.is_file():
        manifest_file.unlink()  # incomplete again until every shard is back
    todo_n = sum(t[3] for t in tasks)
    if workers is None:
        workers = default_workers(todo_n)
    workers = max(1, min(workers, len(tasks)))
    t0 = time.perf_counter()
    with tqdm(total=total, initial=total - todo_n, unit="press", desc=f"dataset {out.name}",
              disable=not progress, smoothing=0.1) as bar:
        if workers <= 1:
            for t in tasks:
                bar.update(_shard_task(t))
        else:
            ctx = multiprocessing.get_context("spawn")  # safe even if the caller already started jax threads
            pool = cf.ProcessPoolExecutor(workers, mp_context=ctx, initializer=_start_worker)
            try:
                for n in (f.result() for f in cf.as_completed([pool.submit(_shard_task, t) for t in tasks])):
                    bar.update(n)
            except KeyboardInterrupt:  # finished shards stay; the workers are stopped, not waited for
                procs = list((getattr(pool, "_processes", None) or {}).values())
                pool.shutdown(wait=False, cancel_futures=True)
                for proc in procs:  # each writes its shard atomically: a stopped one leaves only a temp file
                    proc.terminate()
                raise
            pool.shutdown()
    seconds = time.perf_counter() - t0
    manifest = {"version": VERSION, "preset": cfg.get("preset"), "seed": g["seed"], "config": g,
                "data_config": json.loads(json.dumps(cfg["data"])), "splits": splits,
                "sim_fingerprint": sim_fingerprint(),
                "sim": {"sensors": list(SENSOR_KEYS), "indenters": list(sim.INDENTERS),
                        "unseen_objects": list(sim.UNSEEN_OBJECTS)},
                "generation": {"samples": total, "rendered": todo_n, "seconds": round(seconds, 2),
                               "samples_per_minute": round(todo_n / max(seconds, 1e-9) * 60),
                               "workers": workers}}
    _write_text(manifest_file, json.dumps(manifest, indent=1))
    return manifest


if __name__ == "__main__":  # the command line sits above the presets (configs), which the simulator does not import
    import shlex
    import sys

    from ffjax import cli

    sys.exit(cli.fail(f"ffjax.sim.dataset has no command line: run python -m ffjax.simulate "
                      f"{shlex.join(sys.argv[1:])}".rstrip(), cli.USAGE))
