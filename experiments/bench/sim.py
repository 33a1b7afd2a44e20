"""The simulator's side of `experiments.bench --only sim`: presses per second of the batched layer solves
(ffjax.sim.batched, what the simulator runs) against the numpy reference (the path before them, kept for this
and for the agreement checks), in one run, per render size and batch size, pressed as the
dataset presses (the oblique press in data.path_steps increments: path_steps + 1 normal and path_steps stick
solves each); their agreement on every indenter, unseen object and sensor; the oblique path's distance to itself
converged in its steps, per quadrature, against its time; each preset's solve grid against one twice as fine, per
shape; the peak memory of one batch; and a
preset's whole dataset, end to end (read from a made dataset's manifest where the call that made it is that
measurement: `--data`, as the pipeline gives it)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

import configs
from experiments import common
from ffjax import sim
from ffjax.sim import batched, dataset, mechanics

_QUICK = configs.get("quick")  # pressed as its dataset presses (oblique: the request is Fz, the tilt pushes)
_DATA = _QUICK["data"]
_STREAMS = 10_000  # the benchmark's presses draw from random streams (SplitSpec.index) no split of a dataset uses
LOADING, STEPS, QUADRATURE = _DATA["loading"], int(_DATA["path_steps"]), _DATA["path_quadrature"]


def presses(n: int, seed: int = 0, shapes=None, sensor: str = "mini-1-gel1") -> dict:
    """n presses over `shapes` (default: the indenters) on `sensor`, drawn as the quick dataset draws a split's
    (`dataset.sample_presses`: its forces, offsets, yaws and tilts), in their shuffled order; seed picks the stream."""
    shapes = tuple(shapes or sim.INDENTERS)
    spec = dataset.SplitSpec(f"bench/{seed}", sensor, shapes, -(-n // len(shapes)), _STREAMS + seed)
    p = {k: v[:n] for k, v in dataset.sample_presses(spec, _QUICK).items()}
    return {"shape": [shapes[i] for i in p["shape_index"]], "forces": p["force"], "x_mm": p["x_mm"], "y_mm": p["y_mm"],
            "yaw_deg": p["yaw_deg"], "tilt_deg": p["tilt_deg"], "seeds": p["seed"]}


def _press(p: dict, sensor: str, size, lo: int, hi: int, reference: bool = False, steps: int = STEPS,
           quadrature: str = QUADRATURE) -> dict:
    """Presses lo:hi of `p` in one call, loaded as the quick dataset loads them (or along `steps` / `quadrature`)."""
    return sim.press_batch(p["shape"][lo:hi], sensor, p["forces"][lo:hi], p["x_mm"][lo:hi], p["y_mm"][lo:hi],
                           p["yaw_deg"][lo:hi], p["tilt_deg"][lo:hi], p["seeds"][lo:hi], tuple(size),
                           reference=reference, path=LOADING, steps=steps, quadrature=quadrature)


def _rate(p: dict, sensor: str, size, n: int, batch: int, reference: bool = False, warm: bool = True) -> float:
    """Presses per second over the first n presses, pressed in one call (as a dataset shard is) solved in pieces of
    `batch`; warm: after an untimed call on the same presses, so compiling (each window side's programs) is not
    counted."""
    before = batched.MAX_BATCH
    batched.MAX_BATCH = batch  # each piece one solve of this size, on any device
    try:
        if warm:
            _press(p, sensor, size, 0, n, reference)
        t0 = time.perf_counter()
        _press(p, sensor, size, 0, n, reference)
        return n / (time.perf_counter() - t0)
    finally:
        batched.MAX_BATCH = before


def rates(sizes: dict, batches, n: int, reference_n: int, sensor: str = "mini-1-gel1", calls: int = 0,
          log=print) -> dict:
    """{size name: {"reference_s", "batched_s": {batch: presses/s}, "speedup": {batch: ratio}}}, all in this
    run. Each batch size presses max(n, calls x batch) presses (calls: a GPU's large batches need more than n to
    be timed over several calls)."""
    count = {int(b): max(n, calls * int(b)) for b in batches}
    p = presses(max(*count.values(), reference_n) + max(batches), seed=1, sensor=sensor)
    out = {}
    for name, size in sizes.items():
        _rate(p, sensor, size, 1, 1, reference=True, warm=False)  # the shapes' tables built outside the timing
        ref = _rate(p, sensor, size, reference_n, 1, reference=True, warm=False)  # numpy: nothing to compile
        new = {b: _rate(p, sensor, size, k, b) for b, k in count.items()}
        out[name] = {"render_size": list(size), "reference_s": ref, "batched_s": new,
                     "speedup": {b: r / ref for b, r in new.items()},
                     "n": n, "presses": count, "reference_n": reference_n, "loading": LOADING, "steps": STEPS}
        log(f"[bench] sim {name}: reference {ref:.1f}/s, batched " + ", ".join(
            f"batch {b} {r:.1f}/s" for b, r in new.items()))
    return out


def _transform_pair_s(shape, channels: int, batch: int, calls: int = 50) -> float:
    """Seconds a press of one rfft2 and irfft2 of `channels` channels on `shape`, with a kernel product between
    (`batched._apply`, the solves' own program), timed over a batch of `batch`."""
    x = jax.device_put(np.ones((batch, channels, *shape), np.float32))
    kernel = jax.device_put(np.ones((shape[0], shape[1] // 2 + 1), np.float32))
    x = batched._apply(x, kernel).block_until_ready()
    t0 = time.perf_counter()
    for _ in range(calls):
        x = batched._apply(x, kernel)
    x.block_until_ready()
    return (time.perf_counter() - t0) / calls / batch


# transforms of each solve: (per iteration, once) on its window, and once on the whole grid
_TRANSFORMS = {"normal": (2, 1, 1),  # u and the CG direction's response; u at the end; u on the whole grid
               "stick": (1, 1, 2)}  # the direction's response; the first residual; the fields (held and surface)
_CHANNELS = {"normal": 1, "stick": 3}  # the stick solve transforms the traction's 3 components together


def floor(n: int, size, sensor: str = "mini-1-gel1") -> dict:
    """Where a press's time goes against what its transforms alone cost: n presses pressed as the dataset presses
    in one call (after an untimed call: compiling not counted), each layer solve's window and
    iterations recorded, and each solve's FFTs timed alone at the device's batch (`_transform_pair_s`). The
    transforms' sum is a floor for these solves with these iterations on this machine: no fusion or overhead
    saved gets under it, only fewer solves, fewer iterations or smaller grids."""
    p = presses(n, seed=4, sensor=sensor)
    _press(p, sensor, size, 0, n)
    with batched.record_solves() as seen:
        t0 = time.perf_counter()
        _press(p, sensor, size, 0, n)
        seconds = time.perf_counter() - t0
    pair, out = {}, {"presses": n, "render_size": list(size), "ms_a_press": 1e3 * seconds / n,
                     "batch": batched.max_batch(), "solves": {}}
    for kind in ("normal", "stick"):
        mine = [s for s in seen if s[0] == kind]
        per_it, once, whole = _TRANSFORMS[kind]
        ms = 0.0
        for _, side, grid, its in mine:
            for shape, count in (((side, side) if side else grid, per_it * its + once), (grid, whole)):
                key = (shape, _CHANNELS[kind])
                if key not in pair:
                    pair[key] = _transform_pair_s(shape, _CHANNELS[kind], batched.max_batch())
                ms += 1e3 * count * pair[key]
        out["solves"][kind] = {"a_press": len(mine) / n, "iterations_mean": float(np.mean([s[3] for s in mine])),
                               "iterations_p90": float(np.percentile([s[3] for s in mine], 90)),
                               "windowed": float(np.mean([s[1] > 0 for s in mine])),
                               "fft_floor_ms_a_press": ms / n}
    out["fft_floor_ms_a_press"] = sum(v["fft_floor_ms_a_press"] for v in out["solves"].values())
    return out


def agreement(size, per_shape: int, sensors=None) -> dict:
    """The batched path against the reference on the same presses: every indenter and unseen object, per sensor.
    Forces (relative), depth (um), the share of pixels more than 1 count apart, the presses whose contact
    differs by a cell (there the depth can differ by a few um near that cell), and presses one path refused
    and the other did not (none expected). Presses more than 1 um apart are solved again by the reference
    converged 100x further, and each path's distance to that is recorded: which of the two is off."""
    shapes = list(sim.INDENTERS) + list(sim.UNSEEN_OBJECTS)
    out = {}
    for key in sensors or sim.SENSOR_NAMES:
        sensor = sim.get_sensor(key)
        p = presses(per_shape * len(shapes), seed=2, shapes=shapes, sensor=key)
        args = ([sim.get_shape(s) for s in p["shape"]], sensor, p["forces"], p["x_mm"], p["y_mm"], p["yaw_deg"],
                p["tilt_deg"], [int(v) for v in p["seeds"]], tuple(size))
        how = {"path": LOADING, "steps": STEPS}
        new, ref = sim.press_many(*args, **how), sim.press_many(*args, reference=True, **how)
        ok = [i for i, (a, b) in enumerate(zip(new, ref))
              if not isinstance(a, ValueError) and not isinstance(b, ValueError)]
        both = [(new[i], ref[i]) for i in ok]
        depth = np.array([np.abs(a.depth - b.depth).max() for a, b in both]) * 1000
        # presses over 1 um again, the reference converged 100x further: is the difference the solver tolerance?
        far = [ok[i] for i in np.flatnonzero(depth > 1)]
        picked = [v if v is sensor else [v[i] for i in far] for v in args[:8]]
        with mechanics.reference_tolerance(1e-8, 1e-6):
            tight = sim.press_many(*picked, args[8], reference=True, **how) if far else []
        to_tight = {name: max((float(np.abs(path[i].depth - t.depth).max()) * 1000 for i, t in zip(far, tight)),
                              default=0.0) for name, path in (("batched", new), ("reference", ref))}
        image = np.stack([np.abs(a.image.astype(np.int16) - b.image) for a, b in both])
        force = max(float(np.abs(a.force - b.force).max() / np.abs(b.force).max()) for a, b in both)
        out[key] = {"presses": len(both), "refused_by_one": sum(isinstance(a, ValueError) != isinstance(b, ValueError)
                                                                for a, b in zip(new, ref)),
                    "force_rel_max": force, "depth_um_max": float(depth.max()),
                    "depth_um_p99": float(np.percentile(depth, 99)), "presses_over_1um": int((depth > 1).sum()),
                    "over_1um_to_converged_um": to_tight,
                    "contact_differs": sum(a.meta["contact_area_mm2"] != b.meta["contact_area_mm2"] for a, b in both),
                    "pixels_over_1_count": float((image > 1).mean()), "pixels_differ": float((image > 0).mean())}
    return out


SHEARED_N = 0.05  # presses sheared by less are left out of the path's relative force error (noise over a tiny force)


def discretization(sizes: dict, per_shape: int, sensor: str = "mini-1-gel1", shapes=None) -> dict:
    """What each preset's solve grid gives away: every indenter and unseen object pressed as the dataset presses
    (`per_shape` presses each), solved on the grid its frame size takes (`sim.solve_size`) and again on one twice
    as fine in each direction, rendered at the same frame size. Per size and shape: the tangential force's error
    relative to its size (presses sheared by more than SHEARED_N), the approach's relative error, and the
    rendered depth's largest difference (um), median and max over the presses. shapes: default all of them."""
    shapes = list(shapes or (*sim.INDENTERS, *sim.UNSEEN_OBJECTS))
    p = presses(per_shape * len(shapes), seed=3, shapes=shapes, sensor=sensor)
    s = sim.get_sensor(sensor)
    out = {}
    for label, size in sizes.items():
        size = tuple(size)
        grid = sim.solve_size(s, size)
        finer = (2 * grid[0], 2 * grid[1])
        args = ([sim.get_shape(v) for v in p["shape"]], s, p["forces"], p["x_mm"], p["y_mm"], p["yaw_deg"],
                p["tilt_deg"], [int(v) for v in p["seeds"]], size)
        how = {"path": LOADING, "steps": STEPS, "quadrature": QUADRATURE, "noise": False}
        coarse, fine = sim.press_many(*args, grid=grid, **how), sim.press_many(*args, grid=finer, **how)
        rows: dict = {}
        for name, a, b in zip(p["shape"], coarse, fine):
            if isinstance(a, ValueError) or isinstance(b, ValueError):
                rows.setdefault(name, []).append(None)
                continue
            ft = float(np.hypot(*b.force[:2]))
            shear = float(np.hypot(*(a.force[:2] - b.force[:2])) / ft) if ft > SHEARED_N else None
            approach = abs(a.meta["penetration_mm"] - b.meta["penetration_mm"]) / b.meta["penetration_mm"]
            rows.setdefault(name, []).append((shear, approach, float(np.abs(a.depth - b.depth).max()) * 1000))
        out[label] = {"render_size": list(size), "grid": list(grid), "finer": list(finer),
                      "shapes": {n: _errors(r) for n, r in rows.items()},
                      "all": _errors([x for r in rows.values() for x in r])}
    return {"sensor": sensor, "per_shape": per_shape, "sheared_above_n": SHEARED_N, "sizes": out}


def _errors(rows: list) -> dict:
    """Median and max of each error over the solved presses (None: a press one grid refused)."""
    solved = [r for r in rows if r is not None]
    stat = lambda v: {"median": float(np.median(v)), "max": float(np.max(v))} if v else None  # noqa: E731
    return {"presses": len(solved), "refused": len(rows) - len(solved),
            "shear_rel": stat([r[0] for r in solved if r[0] is not None]),
            "approach_rel": stat([r[1] for r in solved]), "depth_um": stat([r[2] for r in solved])}


def path_convergence(n: int, steps, reference: int, size, sensor: str = "mini-1-gel1") -> dict:
    """The oblique path against itself converged: n presses (mixed indenters, the dataset's ranges) pressed in
    `reference` steps with the power-law quadrature, then in each of `steps` with each of mechanics.QUADRATURES.
    Per variant: the tangential force's distance to the converged one relative to its size (median, p90, max over
    the presses sheared by more than SHEARED_N), the depth's (um; median and max over presses), the share of pixels
    more than 1 count apart, and its time a press in one call (the power variant after an untimed call; the
    midpoint one runs the very same solves, compiled by then). Where the default (STEPS with QUADRATURE, the
    quick config's) stands between fewer steps and the converged path."""
    p = presses(n, seed=5, sensor=sensor)

    def press(k: int, quadrature: str) -> tuple[dict, float]:
        t0 = time.perf_counter()
        r = _press(p, sensor, size, 0, n, steps=k, quadrature=quadrature)
        return r, time.perf_counter() - t0

    ref, _ = press(reference, "power")
    ft = np.hypot(*ref["force"][:, :2].T)
    sheared = ft > SHEARED_N
    rows = []
    for k in steps:
        press(k, "power")  # untimed: compiles what the reference's windows did not
        for q in ("power", "midpoint"):
            r, seconds = press(k, q)
            off = np.hypot(*(r["force"][:, :2] - ref["force"][:, :2]).T)[sheared] / ft[sheared]
            depth = np.abs(r["depth"] - ref["depth"]).max((1, 2)) * 1000
            pixels = np.abs(r["image"].astype(np.int16) - ref["image"]) > 1
            rows.append({"steps": int(k), "quadrature": q, "ms_a_press": 1e3 * seconds / n,
                         **({f"ft_rel_{name}": float(f(off)) for name, f in
                             (("median", np.median), ("p90", lambda x: np.percentile(x, 90)), ("max", np.max))}
                            if off.size else {}),
                         "depth_um_median": float(np.median(depth)), "depth_um_max": float(depth.max()),
                         "pixels_over_1_count": float(pixels.mean())})
    return {"presses": n, "sheared": int(sheared.sum()), "sheared_above_n": SHEARED_N, "render_size": list(size),
            "sensor": sensor, "reference_steps": int(reference),
            "default": {"steps": STEPS, "quadrature": QUADRATURE},
            "rows": sorted(rows, key=lambda r: (r["quadrature"], r["steps"]))}


# The peak is VmHWM, this process's own high-water mark: getrusage's ru_maxrss also counts the parent's resident
# size at the fork (Linux keeps the pre-exec high-water mark), which hid the batch under the benchmark's own memory.
_MEMORY = """
import json, sys
from experiments.bench import sim as bs

def hwm():
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) / 1024

import jax
from ffjax.sim import batched

batch, h, w, piece = (int(v) for v in sys.argv[1:5])
batched.MAX_BATCH = piece or None
p = bs.presses(batch, seed=3)
before = hwm()
bs._press(p, "mini-1-gel1", (h, w), 0, batch)
after = hwm()
stats = jax.local_devices()[0].memory_stats() if batched.on_accelerator() else None
print(json.dumps({"peak_rss_mib": after, "batch_growth_mib": after - before, "piece": batched.max_batch(),
                  "device_peak_mib": stats["peak_bytes_in_use"] / 2**20 if stats else None}))
"""


def peak_memory(batch: int, size, piece: int = 0) -> dict:
    """Peak resident memory of a fresh process pressing one batch (after importing everything) in pieces of
    `piece` presses (0: the device's default), in MiB; on a GPU also the device's peak (jax's allocator, not
    preallocated)."""
    env = {**os.environ, "FFJAX_CACHE": "off", "XLA_PYTHON_CLIENT_PREALLOCATE": "false"}
    r = subprocess.run([sys.executable, "-c", _MEMORY, str(batch), *map(str, size), str(piece)], capture_output=True,
                       text=True, check=True, env=env)
    return {"batch": batch, "render_size": list(size), **json.loads(r.stdout.strip().splitlines()[-1])}


def dataset_time(preset: str, workers: int | None = None, overrides: dict | None = None) -> dict:
    """`ffjax.sim.dataset.generate` of a preset's whole dataset (its data section changed by `overrides`: a
    sample of a preset too large to time whole) into a temporary folder, timed, with the load."""
    cfg = configs.get(preset, {f"data.{k}": v for k, v in (overrides or {}).items()})
    with tempfile.TemporaryDirectory() as tmp:
        load = os.getloadavg()
        t0 = time.perf_counter()
        m = dataset.generate(cfg, tmp, workers=workers, progress=False)
        seconds = time.perf_counter() - t0
        return {"preset": preset, "overrides": overrides or {}, "presses": m["generation"]["samples"],
                "workers": m["generation"]["workers"], "batch": batched.max_batch(),
                "render_size": list(cfg["data"]["render_size"]), "seconds": seconds, "load_before": list(load),
                "load_after": list(os.getloadavg()), "bytes_per_press": _bytes(tmp) / m["generation"]["samples"]}


def made_time(folder, preset: str) -> dict | None:
    """A made dataset's time from its manifest, as dataset_time gives it, when the call that made it is what
    dataset_time would time: the preset's whole dataset, every press rendered in that one call, by today's
    simulator with the default workers; else None. The load was not recorded there (None)."""
    m = common.read_json(Path(folder) / "manifest.json")
    if not m:
        return None
    cfg, gen = configs.get(preset), m["generation"]
    same = (m.get("preset") == preset and m.get("sim_fingerprint") == dataset.sim_fingerprint()
            and m.get("data_config") == json.loads(json.dumps(cfg["data"]))
            and gen["rendered"] == gen["samples"] == sum(s.count for s in dataset.split_specs(cfg))
            and gen["workers"] == dataset.default_workers(gen["samples"]))
    if not same:
        return None
    return {"preset": preset, "overrides": {}, "presses": gen["samples"], "workers": gen["workers"],
            "batch": batched.max_batch(), "render_size": list(cfg["data"]["render_size"]), "seconds": gen["seconds"],
            "load_before": None, "load_after": None, "bytes_per_press": _bytes(folder) / gen["samples"],
            "made_in": str(Path(folder).absolute())}


def _bytes(folder) -> int:
    return sum(f.stat().st_size for f in Path(folder).rglob("*") if f.is_file())


def for_device(plan: dict) -> dict:
    """The plan, with its "accelerator" entries in place of the CPU's where jax runs on a GPU/TPU."""
    extra = plan.get("accelerator") if batched.on_accelerator() else None
    return {k: v for k, v in {**plan, **(extra or {})}.items() if k != "accelerator"}


def run(plan: dict, log=print, data=None) -> dict:
    """Every measurement of the plan's "sim_speed" section (its "accelerator" entries on a GPU/TPU). The preset's
    dataset is timed by the call that made `data` where made_time takes it (the pipeline's: its ablation made it
    moments before), else made anew in a temporary folder."""
    plan = for_device(plan)
    out = {"rates": rates(plan["sizes"], plan["batches"], plan["n"], plan["reference_n"],
                          calls=plan.get("calls", 0), log=log),
           "default_batch": batched.max_batch()}
    log("[bench] sim speedup (best batch): " + ", ".join(
        f"{k} {max(v['speedup'].values()):.2f}x" for k, v in out["rates"].items()))
    out["agreement"] = agreement(tuple(plan["agreement_size"]), plan["agreement_per_shape"],
                                 plan.get("agreement_sensors"))
    log("[bench] sim agreement: depth within " + ", ".join(
        f"{k} {v['depth_um_max']:.2f} um" for k, v in out["agreement"].items()))
    if plan.get("floor"):
        out["floor"] = floor(plan["floor"], tuple(plan["agreement_size"]))
        log(f"[bench] sim floor: {out['floor']['ms_a_press']:.1f} ms a press, its transforms alone "
            f"{out['floor']['fft_floor_ms_a_press']:.1f} ms")
    if plan.get("path"):
        spec = plan["path"]
        out["path"] = path_convergence(spec["n"], spec["steps"], spec["reference"], tuple(plan["agreement_size"]))
        log("[bench] sim path, |Ft| off the converged path (median): " + ", ".join(
            f"{r['steps']} {r['quadrature']} {100 * r.get('ft_rel_median', float('nan')):.1f}%"
            for r in out["path"]["rows"]))
    if plan.get("discretization"):
        spec = plan["discretization"]
        out["discretization"] = discretization(spec["sizes"], spec["per_shape"], shapes=spec.get("shapes"))
        log("[bench] sim discretization, against a 2x-finer grid (median shear / approach): " + ", ".join(
            f"{k} {100 * v['all']['shear_rel']['median']:.2f}% / {100 * v['all']['approach_rel']['median']:.2f}%"
            for k, v in out["discretization"]["sizes"].items() if v["all"]["shear_rel"]))
    out["memory"] = peak_memory(*plan["memory"], plan.get("memory_piece", 0))
    log(f"[bench] sim memory: {out['memory']}")
    for key, spec in (("dataset", plan.get("dataset")), ("sample", plan.get("sample"))):
        if spec:
            preset, over = (spec, None) if isinstance(spec, str) else (spec["preset"], spec["set"])
            full = sum(s.count for s in dataset.split_specs(configs.get(preset)))
            made = made_time(data, preset) if data and not over else None
            out[key] = {**(made or dataset_time(preset, overrides=over)), "full_presses": full}
            log(f"[bench] {preset} dataset{' (sample)' if over else ''}: {out[key]['presses']} presses in "
                f"{out[key]['seconds']:.0f} s" + (f" (made in {data})" if made else ""))
    return out
