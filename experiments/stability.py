"""Where methods fail: the spread over seeds, and robustness sweeps on freshly rendered held-out presses.

    python -m experiments.stability --preset {smoke,quick,full} [--methods ...] [--ablation DIR]
                                    [--levels K] [--per-level N] [--out DIR]

Uses the ablation's trained checkpoints (DIR/results.json "checkpoints", default results/ablation-<preset>;
a sweep_loss results folder works too); methods it lacks are trained with the ablation's own stages into
DIR/runs. (1) Across seeds: each method's Table I / II error per seed (from the ablation's evaluations).
(2) Factors: for each, a family of test sets rendered by the simulator (the 9 Table II indenters, the training
sensor data.train_sensor, render seeds no dataset split uses), one per level of the factor; every method's
checkpoints are scored on all of them. Where a method's error reaches twice its value at the factor's
nominal level is marked ("doubles at"). Writes OUT/results.json, stability.md, stability.csv, seeds.csv and PNGs.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from pathlib import Path

import numpy as np

from experiments import common, kernel, style
from experiments import paper_numbers as P
from ffjax import cli, registry
from ffjax.sim.sensors import get_sensor, with_markers, with_pattern_moving

PER_LEVEL = {"smoke": 9, "quick": 180, "full": 360, "gpu": 360, "paper": 360}
N_LEVELS = {"smoke": 2}  # other presets: every level of each factor
STREAM = 1000  # sampling stream / render seed block no dataset split uses (held out)
SHEAR_N = 1.0  # |F_t| of the shear-angle sets, N
FLAT_SIDES_MM = (3.0, 5.0, 7.0, 10.0, 14.0, 18.0)
KNURL_MM = (0.0, 0.015, 0.03, 0.06)  # the cube's knurl is 0.03 mm (0.12 mm from trough to crest)
SPHERE_RADII_MM = (4.0, 10.0, 20.0, 30.0, 40.0)
BAR_LENGTHS_MM = (0.0, 4.0, 8.0, 12.0, 20.0, 30.0)
BAR_RADIUS_MM = 4.0  # the small sphere's: length 0 is that training indenter
TILT_TURN_DEG = (0.0, 45.0, 90.0, 135.0, 180.0)
# Ft / (Fz tan tilt) of the oblique press: 0.49 mean (0.35-0.69, 5-95%) over 300 quick training presses on gel 1 at
# +-15 deg (2fb3cf1's 2 power-law steps; 0.50 with 4 midpoint steps; docs/simulator.md). tilt_shear's push when the
# data is pressed obliquely: a shear of the training's size
PUSH_RATIO = 0.5


@dataclasses.dataclass(frozen=True)
class Factor:
    name: str
    label: str  # x axis
    levels: tuple[float, ...]
    ref: int  # the nominal level: "doubles" is relative to the error there
    what: str  # what changes, physically


def factors(cfg: dict) -> tuple[Factor, ...]:
    fz = float(cfg["data"]["fz_max"])
    # |F| bins of fz_max / 3: three inside the training range, two beyond it (up to 25 N at fz_max 15)
    force_levels = tuple(round(fz / 3 * (k + 0.5), 3) for k in range(5))
    return (
        Factor("noise", "camera noise std (8-bit levels)", (1.5, 3.0, 5.0, 8.0, 12.0, 16.0), 0,
               "per-pixel camera noise of the frame and of the background (mini-1's own is 1.5)"),
        Factor("illumination", "LED drift (fraction)", (0.0, 0.1, 0.2, 0.3, 0.4, 0.5), 0,
               "LED intensities move by +-level (alternating per LED) and their colour warms (red +level/2, "
               "blue -level/2); the background is re-recorded under the same light"),
        Factor("edge", "contact offset (fraction of the half pad)", (0.0, 0.25, 0.5, 0.7, 0.85, 0.95), 0,
               "the press centre moves toward the pad edge in a random direction"),
        Factor("force", "Fz bin centre (N)", force_levels, 1,
               f"Fz drawn within bins of {fz / 3:g} N (the shear as the training's loading gives it); training "
               f"covers Fz <= {fz:g} N"),
        Factor("shear_angle", "angle of the tangential force (deg)", (0.0, 60.0, 120.0, 180.0, 240.0, 300.0), 0,
               f"|F_t| = {SHEAR_N:g} N in a fixed direction, Fz in [6, fz_max], tool tilted along the push"),
        Factor("drift", "background gain drift (fraction)", (0.0, 0.02, 0.05, 0.1, 0.15, 0.2), 0,
               "the background frame comes from the sensor in an earlier state (exposure gain +level, LEDs "
               "drifted by level/2) while the frame is from the current one; a real GelSight Mini drifts by "
               "0.7-4.6% per channel in its first 3 minutes after start-up (experiments.diagnostics.rest_recording)"),
        Factor("markers", "gel printed with markers (0: no, 1: yes)", (0.0, 1.0), 0,
               "the same gel with dark markers (1.6 mm pitch, 0.5 mm dots) printed on its pigment: a pattern that "
               "moves with the gel, strong, and absent from training (the paper's gels carry none)"),
        Factor("pigment", "the gel's pigment (0: its own, 1: another gel's, 2: frozen)", (0.0, 1.0, 2.0), 0,
               "texture against mechanics, the mechanics kept: at 1 the training gel's stiffness and thickness with "
               "another gel's pigment pattern (gel 2's; gel 1's on a gel-2 sensor), at 2 the pigment frozen (the "
               "whole fine fixed pattern the camera's: only the surface's shape shows a shear)"),
        Factor("flat_size", "flat face side (mm)", FLAT_SIDES_MM, FLAT_SIDES_MM.index(14.0),
               "a square flat punch made like the cube indenter (14 mm, the largest flat face in training), "
               "its side from 3 to 18 mm (the pad sees 20.3 x 15.2 mm), posed and loaded as the cube is"),
        Factor("face_texture", "knurl amplitude of a 14 mm flat face (mm)", KNURL_MM, KNURL_MM.index(0.03),
               "the cube's 14 mm face with its diamond knurl (0.7 mm pitch) made shallower or deeper, from smooth "
               "(0) to twice the cube's (0.06): a textured face touches the gel on its crests only, a smooth one "
               "over its whole area; posed and loaded as the cube is"),
        Factor("sphere_radius", "sphere radius (mm)", SPHERE_RADII_MM, SPHERE_RADII_MM.index(40.0),
               "a smooth sphere like the sphere indenters (the big sphere, 40 mm, is the flattest curved body in "
               "training), its radius from 4 to 40 mm (fruit are 20-37 mm), posed and loaded as the big sphere is"),
        Factor("elongation", f"bar length (mm, radius {BAR_RADIUS_MM:g} mm)", BAR_LENGTHS_MM, 0,
               f"a smooth rounded bar of radius {BAR_RADIUS_MM:g} mm (at length 0 the small sphere indenter), "
               "0-30 mm long, posed and loaded as the small sphere is: in training the cross's bars are 12 mm and "
               "the prism's sharp edge 30 mm, the pad sees 20.3 x 15.2 mm, the marker and banana lie across it"),
        Factor("tilt_shear", "tilt direction turned from the shear's (deg)", TILT_TURN_DEG, 0,
               "the training sampling, pressed and then pushed sideways (with oblique training data, by "
               f"{PUSH_RATIO:g} Fz tan(tilt), the oblique press's mean), except that each body's tilt (same "
               "magnitude) is turned by the level away from its push: at 0 the tool pushes along its tilt; "
               "otherwise it leans one way and pushes another (a lateral move after contact)"),
    )


def pick_levels(f: Factor, k: int | None) -> Factor:
    """k of the factor's levels, always keeping the nominal one and the last (the strongest)."""
    if k is None or k >= len(f.levels):
        return f
    k, last = max(k, 2), len(f.levels) - 1
    idx = sorted({f.ref, last} | {int(round(i)) for i in np.linspace(0, last, k)})
    extra = [i for i in idx if i not in (f.ref, last)]
    while len(idx) > k:  # the nominal level pushed one out: drop a middle one
        idx.remove(extra.pop(len(extra) // 2))
    return dataclasses.replace(f, levels=tuple(f.levels[i] for i in idx), ref=idx.index(f.ref))


def drift_leds(sensor, level: float):
    """LED intensity and colour drift (ageing, temperature): intensities +-level alternating per LED,
    colour warmer by level/2 (red up, blue down)."""
    leds = tuple(dataclasses.replace(
        led, intensity=led.intensity * max(0.05, 1 + level * (1 if i % 2 == 0 else -1)),
        color=tuple(max(0.0, c * (1 + level * w)) for c, w in zip(led.color, (0.5, 0.0, -0.5))))
        for i, led in enumerate(sensor.leds))
    return dataclasses.replace(sensor, leds=leds)


def sensors_for(factor: str, level: float, sensor):
    """(sensor that renders the frames, sensor that recorded the background) at one level of a factor."""
    if factor == "noise":
        s = dataclasses.replace(sensor, noise_std=float(level))
        return s, s
    if factor == "illumination":
        s = drift_leds(sensor, level)
        return s, s
    if factor == "drift":
        early = dataclasses.replace(drift_leds(sensor, level / 2), brightness=sensor.brightness * (1 + level))
        return sensor, early
    if factor == "markers" and level:
        s = with_markers(sensor)
        return s, s
    if factor == "pigment" and level == 1:
        s = with_pigment_of(sensor, get_sensor(sensor.name, gel=2 if sensor.gel_id != 2 else 1))
        return s, s
    if factor == "pigment" and level == 2:
        s = with_pattern_moving(sensor, 0.0)
        return s, s
    return sensor, sensor


def with_pigment_of(sensor, donor):
    """`sensor` (its gel's mechanics, its camera) with the pigment pattern of donor's gel, at sensor's own share of
    the fixed pattern on the gel."""
    share = sensor.gel.pigment**2 / max(sensor.gel.pigment**2 + sensor.pixel_pattern**2, 1e-30)
    donor = with_pattern_moving(donor, share)
    gel = dataclasses.replace(sensor.gel, texture_seed=donor.gel.texture_seed, pigment=donor.gel.pigment)
    return dataclasses.replace(sensor, gel=gel)


def presses(cfg: dict, f: Factor, li: int, n: int, sensor) -> dict:
    """Forces and poses of one test set: the dataset's own sampling (a stream no split uses), then the
    factor's override (pose toward the edge, Fz bin, shear direction). Every factor and level starts from
    the same presses (shapes, poses, render seeds), so levels are paired comparisons and the nominal
    levels of noise, illumination and drift are the very same test set."""
    from ffjax import sim
    from ffjax.sim import dataset
    from ffjax.sim.shapes import bar, flat_punch, sphere

    level, fz_max = f.levels[li], float(cfg["data"]["fz_max"])
    if f.name == "flat_size":  # the cube's poses and loads, pressed with a flat face of another size
        spec = dataset.SplitSpec("stability", cfg["data"]["train_sensor"], ("cube",), n, STREAM)
        p = {k: v[:n] for k, v in dataset.sample_presses(spec, cfg).items()}
        return {"shapes": (flat_punch(level),), **p}
    if f.name == "face_texture":  # the cube's poses and loads, its face's knurl changed
        spec = dataset.SplitSpec("stability", cfg["data"]["train_sensor"], ("cube",), n, STREAM)
        p = {k: v[:n] for k, v in dataset.sample_presses(spec, cfg).items()}
        return {"shapes": (flat_punch(14.0, level),), **p}
    if f.name == "sphere_radius":  # the big sphere's poses and loads, pressed with a sphere of another radius
        spec = dataset.SplitSpec("stability", cfg["data"]["train_sensor"], (dataset.CALIB_SHAPE,), n, STREAM)
        p = {k: v[:n] for k, v in dataset.sample_presses(spec, cfg).items()}
        return {"shapes": (sphere(level),), **p}
    if f.name == "elongation":  # the small sphere's poses and loads, pressed with a bar of some length
        spec = dataset.SplitSpec("stability", cfg["data"]["train_sensor"], ("sphere_small",), n, STREAM)
        p = {k: v[:n] for k, v in dataset.sample_presses(spec, cfg).items()}
        return {"shapes": (bar(level, BAR_RADIUS_MM),), **p}
    shapes = tuple(s for s in sim.INDENTERS if s != dataset.CALIB_SHAPE)
    spec = dataset.SplitSpec("stability", cfg["data"]["train_sensor"], shapes, math.ceil(n / len(shapes)), STREAM)
    p = {k: v[:n] for k, v in dataset.sample_presses(spec, cfg).items()}
    rng = np.random.default_rng([int(cfg["seed"]), STREAM, 7])
    if f.name == "edge":
        fh, fw = sensor.fov_mm
        theta = rng.uniform(0, 2 * np.pi, n)
        p["x_mm"], p["y_mm"] = level * fw / 2 * np.cos(theta), level * fh / 2 * np.sin(theta)
    elif f.name == "force":
        lo, hi = max(level - fz_max / 6, 0.3), level + fz_max / 6
        fz = lo + (hi - lo) * rng.random(n)
        ft = p["force"][:, :2] * (fz / p["force"][:, 2])[:, None]
        cap = float(cfg["data"]["shear_max"])
        p["force"] = np.column_stack([np.clip(ft, -cap, cap), fz])
    elif f.name == "shear_angle":
        fz = rng.uniform(6.0, fz_max, n)
        a = np.radians(level)
        ft = SHEAR_N * np.stack([np.full(n, np.cos(a)), np.full(n, np.sin(a))], 1)
        p["force"] = np.column_stack([ft, fz])
        p["tilt_deg"] = np.degrees(np.arctan(ft / fz[:, None]))  # the tool pushes along its tilted axis
    elif f.name == "tilt_shear":  # same forces, the body's lean turned away from the push
        if cfg["data"]["loading"] == "oblique":  # the push an oblique press along the tilt gives on average
            p["force"][:, :2] = PUSH_RATIO * p["force"][:, 2:] * np.tan(np.radians(p["tilt_deg"]))
        a = np.radians(level)
        tx, ty = p["tilt_deg"][:, 0], p["tilt_deg"][:, 1]
        p["tilt_deg"] = np.column_stack([tx * np.cos(a) - ty * np.sin(a), tx * np.sin(a) + ty * np.cos(a)])
    return {"shapes": shapes, **p}


PUSHED = ("shear_angle", "tilt_shear")  # factors that set the push apart from the tilt: pressed, then pushed


def loading(cfg: dict, f: Factor) -> str:
    """How a factor's presses load the gel: the dataset's way, except for the factors that push in a direction of
    their own after the press (the "shear" path)."""
    return "shear" if f.name in PUSHED else cfg["data"]["loading"]


def render_sets(cfg: dict, jobs, n: int, progress: bool = False) -> dict:
    """{(factor name, level index): test set} for each (Factor, level index) in `jobs`. A test set: images
    (N,H,W,3), its background, the applied forces; presses the simulator refuses (e.g. beyond what the gel takes)
    are dropped and counted. Levels with the very same presses on the same gel (the camera, lighting, pigment and
    marker levels, and the background drift's) are solved once and rendered as each level's sensor sees them
    (`sim.press_many_seen`): the same frames as pressing each level on its own."""
    from tqdm import tqdm

    from ffjax import sim
    from ffjax.sim import dataset

    nominal = dataset.sensor_of(cfg["data"]["train_sensor"], cfg["data"])
    size = dataset.render_size(nominal, cfg["data"]["render_size"])
    groups: dict = {}  # what a solve reads -> [(job, presses, frame sensor, background sensor)]
    for f, li in jobs:
        frame_sensor, bg_sensor = sensors_for(f.name, f.levels[li], nominal)
        p = presses(cfg, f, li, n, nominal)
        bodies = tuple(p["shapes"][k] for k in p["shape_index"])
        path = loading(cfg, f)
        key = (tuple(b if isinstance(b, str) else id(b) for b in bodies), path, sim.mechanics_key(frame_sensor),
               *(np.asarray(p[k]).tobytes() for k in ("force", "x_mm", "y_mm", "yaw_deg", "tilt_deg", "seed")))
        groups.setdefault(key, []).append(((f.name, li), p, bodies, frame_sensor, bg_sensor, path))
    H, W = size
    sets = {}
    with tqdm(total=len(jobs), desc="render test sets", disable=not progress) as bar:
        for members in groups.values():
            _, p, bodies, _, _, path = members[0]
            views = []  # the group's distinct frame sensors (the drift levels all share the nominal one)
            for m in members:
                if m[3] not in views:
                    views.append(m[3])
            seen = sim.press_many_seen(bodies, views, p["force"], p["x_mm"], p["y_mm"], p["yaw_deg"], p["tilt_deg"],
                                       [int(v) for v in p["seed"]], size, path=path,
                                       steps=int(cfg["data"]["path_steps"]),
                                       quadrature=cfg["data"]["path_quadrature"])
            for job, _, _, frame_sensor, bg_sensor, _ in members:
                done = seen[views.index(frame_sensor)]
                kept = [s for s in done if not isinstance(s, ValueError)]
                sets[job] = {"image": np.stack([s.image for s in kept]) if kept else np.zeros((0, H, W, 3), np.uint8),
                             "force": np.stack([s.force for s in kept]) if kept else np.zeros((0, 3), np.float32),
                             "background": bg_sensor.background(size), "dropped": len(done) - len(kept)}
                bar.update()
    return sets


def doubles_at(levels, errors, ref: int = 0, factor: float = 2.0):
    """The level nearest `ref`, on either side (above it on a tie), where the error reaches factor x its value at
    `ref`, linearly interpolated between the two levels around the crossing; None if it never does. Both sides,
    since a nominal level in the middle or at the end of the range (a flat face's 14 mm, the big sphere's 40 mm)
    has departures below it too. NaN levels are skipped."""
    levels, errors = np.asarray(levels, float), np.asarray(errors, float)
    if not np.isfinite(errors[ref]):
        return None
    thr = factor * errors[ref]
    found = []  # (distance from ref in levels, the crossing)
    for side in (range(ref + 1, len(levels)), range(ref - 1, -1, -1)):
        prev = ref
        for i in side:
            if not np.isfinite(errors[i]):
                continue
            if errors[i] >= thr:
                e0, e1 = errors[prev], errors[i]
                t = 1.0 if e1 == e0 else float(np.clip((thr - e0) / (e1 - e0), 0, 1))
                found.append((abs(i - ref), float(levels[prev] + t * (levels[i] - levels[prev]))))
                break
            prev = i
    return min(found, key=lambda f: f[0])[1] if found else None


def strongest(entry: dict) -> int:
    """The index of a factor's strongest level: its last, or its first where the nominal level is the last (the
    big sphere's 40 mm radius, the flattest curved body in training)."""
    n = len(entry["levels"])
    return 0 if entry["ref"] == n - 1 and n > 1 else n - 1


def score_run(run_dir, sets: dict) -> dict:
    """{factor: [summary per level]} of one checkpoint on every test set (one batched predict)."""
    from ffjax import data, metrics, store

    trained = store.load(run_dir)
    stats, variables, size, model = trained.stats, trained.variables, trained.input_size, trained.build()
    keys = [(fn, li) for fn, lv in sets.items() for li in range(len(lv)) if len(lv[li]["force"])]
    x = np.concatenate([data.preprocess_image(sets[fn][li]["image"], sets[fn][li]["background"], stats, size)
                        for fn, li in keys]) if keys else np.zeros((0, size, size, 3), np.float32)
    pred = metrics.predict(model, variables, x)
    out = {fn: [None] * len(lv) for fn, lv in sets.items()}
    start = 0
    for fn, li in keys:
        true = sets[fn][li]["force"]
        p = pred[start:start + len(true)]
        start += len(true)
        out[fn][li] = metrics.summarize(p, true, stats.force_min, stats.force_max)
        out[fn][li]["bias_n"] = np.mean(p - true, axis=0).tolist()  # signed: saturation shows as Fz < 0
    return out


def checkpoints(cfg, methods, ablation_dir: Path, data_dir, force, progress) -> tuple[dict, dict, dict, list]:
    """({method: [run dirs]}, {method: [eval result per seed]}, timings, seeds): the ablation's runs; methods it
    lacks are trained (and evaluated) with its stages into ablation_dir/runs, so a later ablation reuses them."""
    saved = common.read_json(ablation_dir / "results.json") or {}
    ckpts = {m: [Path(p) for p in saved.get("checkpoints", {}).get(m, [])] for m in methods}
    seeds = saved.get("seeds") or [int(cfg["seed"])]
    timings: dict = {}
    data_root = Path(saved["data"]) if saved.get("data") and not data_dir else None
    if not (data_root and (data_root / "manifest.json").is_file()):
        data_root = common.ensure_data(cfg, data_dir, progress=progress)
    backbone = functools.cache(lambda kind: kernel.pretrained_backbone(cfg, kind, data_root, force, progress))
    evals = {}
    for m in methods:
        if ckpts[m]:
            evals[m] = [kernel.evaluate(cfg, d, data_root) for d in ckpts[m]]
            continue
        spec = registry.get(m)
        runs = [kernel.run(cfg, spec, seed, data_root, ablation_dir.absolute(),
                           backbone=functools.partial(backbone, spec.backbone), force=force, progress=progress)
                for seed in seeds]
        ckpts[m], evals[m] = [r.dir for r in runs], [r.result for r in runs]
        timings[f"train_{m}_s"] = round(sum(r.train_s for r in runs), 1)
    return ckpts, evals, timings, seeds


def seed_spread(evals: dict) -> dict:
    out = {}
    for m, runs in evals.items():
        vals = {"unseen_objects": [float(np.mean([v["nl1"] for v in r["table1"].values()])) for r in runs],
                "unseen_sensors": [float(np.mean([r["table2"][s]["nl1"] for s in P.SENSORS])) for r in runs],
                "digit": [float(r["table2"]["digit"]["nl1"]) for r in runs if "digit" in r["table2"]]}
        out[m] = {k: {**common.mean_std(v), "values": v, "range": float(np.ptp(v)) if v else float("nan")}
                  for k, v in vals.items()}
    return out


def main(argv=None) -> dict:
    ap = common.base_parser(__doc__, experiment="stability",
                            costs={"quick": "reuses an ablation's 15 runs (--ablation)"})
    ap.add_argument("--methods", nargs="+", default=None, metavar="NAME",
                    help="registry names (default: the ablation's methods, else the paper set)")
    ap.add_argument("--ablation", default=None, help="ablation results folder (default: results/ablation-<preset>)")
    ap.add_argument("--levels", type=cli.integer(1), default=None, help="levels per factor (default: all; 2 at smoke)")
    ap.add_argument("--per-level", type=cli.integer(1), default=None, help="presses per level (default: 180 at quick)")
    ap.add_argument("--factors", nargs="+", default=None, metavar="NAME", help="subset of the factors")
    args = ap.parse_args(argv)
    cfg = common.config_from_args(ap, args)
    abl = common.ablation_folder(ap, args.ablation, args.preset).absolute()
    saved = common.read_json(abl / "results.json") or {}
    methods = args.methods or saved.get("methods") or list(registry.PAPER_SET)
    for m in methods:
        if not saved.get("checkpoints", {}).get(m):  # one with runs (a sweep's variant too) loads from model.json
            registry.get(m)
    chosen = [pick_levels(f, args.levels or N_LEVELS.get(args.preset)) for f in factors(cfg)]
    if args.factors:
        unknown = set(args.factors) - {f.name for f in chosen}
        if unknown:
            ap.error(f"unknown factors {sorted(unknown)}; choose from {[f.name for f in chosen]}")
        chosen = [f for f in chosen if f.name in args.factors]
    out = Path(args.out or common.ROOT / "results" / f"stability-{args.preset}").absolute()
    results = run(cfg, methods, chosen, args.per_level or PER_LEVEL[args.preset], abl, out, args.data, args.force,
                  not args.quiet)
    print(results["summary"])
    print(f"\nwrote {out}/results.json, stability.md, stability.csv and plots")
    return results


def run(cfg, methods, chosen, per_level, ablation_dir, out, data_dir=None, force=False, progress=True) -> dict:
    from tqdm import tqdm

    out = Path(out).absolute()
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    ckpts, evals, timings, seeds = checkpoints(cfg, methods, Path(ablation_dir), data_dir, force, progress)
    t = time.perf_counter()
    jobs = [(f, li) for f in chosen for li in range(len(f.levels))]
    rendered = render_sets(cfg, jobs, per_level, progress)
    sets = {f.name: [rendered[f.name, li] for li in range(len(f.levels))] for f in chosen}
    timings["render_s"] = round(time.perf_counter() - t, 1)
    t = time.perf_counter()
    scored = {m: [score_run(d, sets) for d in ckpts[m]] for m in tqdm(methods, desc="score", disable=not progress)}
    timings["score_s"] = round(time.perf_counter() - t, 1)
    fres = {}
    for f in chosen:
        entry = {"label": f.label, "levels": list(f.levels), "ref": f.ref, "what": f.what,
                 "n": [len(s["force"]) for s in sets[f.name]], "dropped": [s["dropped"] for s in sets[f.name]],
                 "methods": {}}
        for m in methods:
            per_seed = [[(r[f.name][li] or {}).get("nl1", float("nan")) for li in range(len(f.levels))]
                        for r in scored[m]]
            cells = [common.mean_std([s[li] for s in per_seed]) for li in range(len(f.levels))]
            mean = [c["mean"] for c in cells]
            entry["methods"][m] = {
                "nl1": mean, "std": [c["std"] for c in cells], "per_seed": per_seed,
                "mae_n": _seed_mean(scored[m], f.name, "mae_n"), "bias_n": _seed_mean(scored[m], f.name, "bias_n"),
                "doubles_at": doubles_at(f.levels, mean, f.ref),
                "ratio_at_max": float(np.nanmax(np.delete(mean, f.ref)) / mean[f.ref]) if len(mean) > 1 else None,
            }
        fres[f.name] = entry
    timings["total_s"] = round(time.perf_counter() - t0, 1)
    results = {"preset": cfg["preset"], "commit": common.git_commit(), "seeds": seeds, "timings": timings,
               "methods": methods, "ablation": str(ablation_dir),
        "checkpoints": {m: [str(d) for d in ds] for m, ds in ckpts.items()}, "per_level": per_level,
        "sensor": cfg["data"]["train_sensor"], "seed_spread": seed_spread(evals), "factors": fres,
        "metric": "normalized L1 % (mean over Fx, Fy, Fz of mean |error| / training label range)", "config": cfg}
    results["breaks_first"] = {fn: breaks_first(e) for fn, e in fres.items()}
    results["summary"] = summary(results)
    write_all(results, out)
    return results


def _seed_mean(runs: list, fn: str, key: str) -> list:
    """Per level, the seeds' mean of a per-axis list (None where a level had no presses)."""
    out = []
    for li in range(len(runs[0][fn])):
        vals = [r[fn][li][key] for r in runs if r[fn][li]]
        out.append(np.mean(vals, axis=0).round(4).tolist() if vals else None)
    return out


def breaks_first(entry: dict) -> str | None:
    """The method whose error doubles at the level nearest the nominal one (on either side); if none doubles, the
    largest rise at any level off the nominal one (None if there is nothing to compare)."""
    ms = entry["methods"]
    nominal = entry["levels"][entry["ref"]]
    doubled = {m: abs(v["doubles_at"] - nominal) for m, v in ms.items() if v["doubles_at"] is not None}
    if doubled:
        return min(doubled, key=doubled.get)
    rises = {m: v["ratio_at_max"] for m, v in ms.items()
             if v["ratio_at_max"] is not None and np.isfinite(v["ratio_at_max"])}
    return max(rises, key=rises.get) if rises else None


def lowest_at(entry: dict, li: int) -> str | None:
    """The method with the lowest error at level index li (None if no method has a finite error there)."""
    errs = {m: v["nl1"][li] for m, v in entry["methods"].items() if np.isfinite(v["nl1"][li])}
    return min(errs, key=errs.get) if errs else None


_name = style.name


# Why a factor hurts (a mechanism in the simulator) and what might make one method more fragile: stated
# as hypotheses, the numbers above them are what was measured.
MECHANISM = {
    "noise": "noise is zero-mean and independent per pixel; after background subtraction it adds to the "
             "(small) shading change of light, shallow contacts",
    "illumination": "the flat field is subtracted away, but the slope-to-colour mapping the model learned changes "
                    "with the LEDs' intensity and colour",
    "edge": "part of the imprint leaves the field of view or lands where LED falloff and vignetting differ, and "
            "the training poses kept footprints on the pad",
    "force": "outside the training range the regressor has to extrapolate",
    "shear_angle": "a model that reads no shear at all scores |F_t| (|cos a| + |sin a|) on the two shear axes, "
                   "1.37x more at 60/120/240/300 deg than at 0/180 deg, so a curve with that shape is the metric's "
                   "geometry, not a direction the sensor sees worse (the per-axis bias_n in results.json tells which "
                   "axis a method reads); the LEDs' per-side colour and intensity can add a real asymmetry on top",
    "drift": "a background from another sensor state leaves a uniform offset over the whole difference image, "
             "a pattern no training image had",
    "markers": "the markers are background-subtracted away at rest, but where the gel moves they leave dark-light "
               "pairs far stronger than the pigment's: shear made visible in a form no training image had",
    "pigment": "a model that reads the shear from the training gel's own pigment moving (a pattern every gel has, "
               "but with other specks) loses it on another gel's pattern and on a frozen one; one that reads the "
               "surface's shape (the gel piled up ahead, stretched behind) keeps it; Fz barely depends on either",
    "flat_size": "a flat face shows its load only along its outline (inside, the pressed gel stays flat and "
                 "shades like the background), and faces smaller or larger than the training cube make contacts and "
                 "stiffnesses no training press had",
    "face_texture": "a body in stick holds the gel across its whole face whether it touches through knurl crests or "
                    "everywhere, so the shear stiffness is the face's; a model that learned the load per unit of "
                    "touching area from one texture misreads another",
    "sphere_radius": "the training set's spheres are 4 and 40 mm; at a given load a sphere between them makes a "
                     "contact whose width and depth lie between theirs, and in a bonded layer the stiffness grows "
                     "steeply with the contact's width against the thickness, so its depth-to-load relation is one no "
                     "training press showed: if the models do not interpolate across curvature, the error peaks "
                     "between the two training radii and falls toward both",
    "elongation": "a longer contact spreads the same load along a line: the pressure per unit length and the "
                  "imprint's depth fall with length, so a depth-to-load relation learned on round and short "
                  "contacts no longer holds, and a bar longer than the pad carries part of its load outside "
                  "the field of view",
    "tilt_shear": "in training the shear is Fz tan(tilt) plus noise, so the contact's tilted geometry (which side "
                  "presses deeper) predicts the shear as well as the gel's sideways strain does; a model that reads "
                  "the tilt cue predicts the shear along the lean, and its shear error grows as the lean turns away "
                  "(at 180 deg it reads the shear backwards), while one that reads the strain does not change",
}


def _traits(m: str, results: dict) -> str:
    from ffjax import store

    runs = results.get("checkpoints", {}).get(m)
    s = registry.get(m) if m in registry.names() or not runs else store.describe(runs[0]).spec  # a sweep's variant
    parts = [f"{'ResNet' if s.backbone == 'resnet' else 'ViT'} backbone",
             "frozen" if s.frozen_backbone else ("fine-tuned" if s.pretrained else "trained from scratch"),
             "with the depth head" if s.depth_head else "without a depth head"]
    return ", ".join(parts)


def summary(results: dict) -> str:
    lines = []
    for fn, e in results["factors"].items():
        ref = e["levels"][e["ref"]]
        si = strongest(e)
        parts = []
        for m, v in e["methods"].items():
            top = f"{v['nl1'][si]:.1f}% at {e['levels'][si]:g}"
            dbl = f"doubles at {v['doubles_at']:.3g}" if v["doubles_at"] is not None else "does not double"
            parts.append(f"{_name(m)} {v['nl1'][e['ref']]:.1f}% -> {top} ({dbl})")
        first = results["breaks_first"].get(fn)
        line = f"- **{fn}** ({e['label']}; nominal {ref:g}): " + "; ".join(parts) + "."
        if first and len(e["methods"]) > 1:
            line += f" Breaks first: **{_name(first)}** ({_traits(first, results)})."
            best = lowest_at(e, si)
            if best:
                line += (f" Lowest error at the strongest level: {_name(best)} (\"breaks first\" is relative to each "
                         f"method's own nominal error, so a method that starts low can break first and still be best)."
                         if best == first else f" Lowest error at the strongest level: {_name(best)}.")
        if fn == "force":
            bias = [v["bias_n"][-1][2] for v in e["methods"].values() if v["bias_n"][-1]]
            if bias:
                line += (f" Mean signed Fz error in the top bin: {', '.join(f'{b:+.2f} N' for b in bias)} "
                         f"(negative = under-predicting beyond the training range).")
        if fn in ("tilt_shear", "pigment"):
            shear = [(m, v["mae_n"]) for m, v in e["methods"].items() if all(v["mae_n"])]
            if shear:
                line += (f" Shear MAE (Fx / Fy) at levels {', '.join(f'{lv:g}' for lv in e['levels'])}: "
                         + "; ".join(f"{_name(m)} " + " -> ".join(f"{a[0]:.2f} / {a[1]:.2f}" for a in mae) + " N"
                                     for m, mae in shear) + ".")
        if sum(e["dropped"]):
            line += f" Presses the simulator refused (dropped): {e['dropped']}."
        line += f" Hypothesis: {MECHANISM.get(fn, '')}."
        lines.append(line)
    firsts = [m for m in results["breaks_first"].values() if m]
    if firsts and len(results["methods"]) > 1:
        counts = {m: firsts.count(m) for m in dict.fromkeys(firsts)}
        worst = max(counts, key=counts.get)
        lines.append(f"\nOverall: {_name(worst)} breaks first on {counts[worst]} of {len(results['factors'])} "
                     f"factors ({', '.join(f'{_name(m)} {c}' for m, c in counts.items())}). "
                     f"One seed's curves move by about the seeds' spread below; a difference in 'doubles at' "
                     f"between adjacent levels is not a resolved ranking.")
        bests = [lowest_at(e, strongest(e)) for e in results["factors"].values()]
        bests = [m for m in bests if m]
        if bests:
            bc = {m: bests.count(m) for m in dict.fromkeys(bests)}
            lines[-1] += (" Lowest error at each factor's strongest level: "
                          + ", ".join(f"{_name(m)} on {c}" for m, c in bc.items()) + f" of {len(bests)}.")
    return "\n".join(lines)


def write_all(results: dict, out: Path) -> None:
    ss = results["seed_spread"]
    seed_rows = [[_name(m)] + [f"{common.fmt(v[k], 2)} (range {v[k]['range']:.2f}, n={v[k]['n']})"
                               for k in ("unseen_objects", "unseen_sensors", "digit")] for m, v in ss.items()]
    seed_md = common.md_table(["Method", "unseen objects (Table I mean)", "Table II mean (9)", "DIGIT"], seed_rows)
    fac_md = []
    for fn, e in results["factors"].items():
        header = (["Method"] + [f"{lv:g}" + (" (nominal)" if i == e["ref"] else "") for i, lv in enumerate(e["levels"])]
                  + ["doubles at"])
        rows = [[_name(m)] + [f"{x:.1f}" for x in v["nl1"]]
                + [f"{v['doubles_at']:.3g}" if v["doubles_at"] is not None else "–"] for m, v in e["methods"].items()]
        fac_md.append(f"### {fn}: {e['label']}\n\n{e['what']}. Presses per level: {e['n']}.\n\n"
                      + common.md_table(header, rows) + f"\n![{fn}](stability_{fn}.png)\n")
    text = (f"# Stability (preset {results['preset']}, seeds {results['seeds']}, commit {results['commit'][:12]})\n\n"
            f"Normalized L1 error % on held-out simulated presses ({results['sensor']}, 9 Table II indenters, "
            f"{results['per_level']} per level).\n\n## Summary\n\n{results['summary']}\n\n"
            f"## Across seeds\n\n{seed_md}\n" + ("With one seed the spread is not measured.\n" if len(results['seeds'])
                                                < 2 else "") + "\n## Factors\n\n" + "\n".join(fac_md))
    common.write_text(out / "stability.md", text)
    rows = [[fn, lv, i == e["ref"], m, v["nl1"][i], v["std"][i], *(v["mae_n"][i] or [float("nan")] * 3), e["n"][i]]
            for fn, e in results["factors"].items() for m, v in e["methods"].items()
            for i, lv in enumerate(e["levels"])]
    common.write_csv(out / "stability.csv", ["factor", "level", "nominal", "method", "nl1_mean", "nl1_std", "mae_fx",
                                             "mae_fy", "mae_fz", "n"], rows)
    common.write_csv(out / "seeds.csv", ["method", "metric", "seed_values", "mean", "std"],
                     [[m, k, " ".join(f"{x:.3f}" for x in c["values"]), c["mean"], c["std"]]
                      for m, v in ss.items() for k, c in v.items()])
    plot(results, out)
    common.write_json(out / "results.json", results)


_LINES = ("-", "--", ":", "-.")
# The level names of the categorical factors (a level is a kind, not an amount: drawn as points at categorical
# positions, no line between them). A factor whose label lists "k: name" for each of its levels is read from there.
CATEGORIES = {"markers": {0.0: "none", 1.0: "markers"},
              "pigment": {0.0: "own", 1.0: "another gel's", 2.0: "frozen"}}
_DODGE = 0.09  # categorical: the methods' points side by side around each level's position
_NEAR = 0.25  # a 2x-nominal line this close to the curves (as a fraction of their span) widens the axis to show it


def _categories(fn: str, e: dict) -> tuple[str, ...] | None:
    """The names of a categorical factor's levels, in order; None for a numeric factor."""
    import re

    names = CATEGORIES.get(fn) or {float(k): v.strip() for k, v in re.findall(r"(\d+): ([^,)]+)", e["label"])}
    return tuple(names[lv] for lv in e["levels"]) if names and all(lv in names for lv in e["levels"]) else None


def _axis_label(label: str, categorical: bool) -> str:
    """The factor's label, less its "(0: ..., 1: ...)" code list where the ticks name the levels."""
    import re

    return re.sub(r"\s*\(\d+:[^)]*\)", "", label).strip() if categorical else label


def _span(e: dict, multi_seed: bool) -> tuple[float, float]:
    """The lowest and highest point of the factor's curves, error bars included (with >= 2 seeds)."""
    vals = []
    for v in e["methods"].values():
        y = np.asarray(v["nl1"], float)
        s = np.nan_to_num(np.asarray(v["std"], float)) if multi_seed else 0.0
        vals += [y - s, y + s]
    vals = np.concatenate(vals)
    vals = vals[np.isfinite(vals)]
    return (float(vals.min()), float(vals.max())) if vals.size else (0.0, 1.0)


def _curve(ax, e: dict, m: str, k: int, n: int, color, label: str, multi_seed: bool, cats) -> None:
    """Method m's error at each level (k of n methods): a line over a numeric factor, points side by side at each
    level's position for a categorical one (cats: the level names). 'x' where the error doubles."""
    v = e["methods"][m]
    thr = 2 * v["nl1"][e["ref"]]
    # the method's own marker, and a line style per position: equal curves (DINO_F R and DINO_F RD) stay
    # visible on each other
    kw = dict(yerr=v["std"] if multi_seed else None, fmt=style.marker(m), color=color,
              capsize=2 if multi_seed else 0, ms=5 - 0.5 * (k % 3), mfc="none" if k % 2 else color, label=label)
    if cats is None:
        ax.errorbar(e["levels"], v["nl1"], ls=_LINES[k % len(_LINES)], **kw)
        if v["doubles_at"] is not None:
            ax.axvline(v["doubles_at"], color=color, ls="--", lw=0.8)
            ax.plot([v["doubles_at"]], [thr], marker="x", color=color, ms=8)
        return
    x = np.arange(len(e["levels"])) + (k - (n - 1) / 2) * _DODGE
    ax.errorbar(x, v["nl1"], ls="none", **kw)
    # no interpolation between kinds: the 'x' sits on the level nearest the nominal one that reaches 2x
    hit = [i for i, y in enumerate(v["nl1"]) if i != e["ref"] and np.isfinite(y) and y >= thr]
    if v["doubles_at"] is not None and hit:
        i = min(hit, key=lambda i: (abs(i - e["ref"]), -i))
        ax.plot([x[i]], [thr], marker="x", color=color, ms=8)


def _thresholds(ax, e: dict, colors: dict, multi_seed: bool) -> None:
    """Each method's 2x-nominal line where it falls within (or near) the curves' range; the y axis fits the curves
    and those lines, and a threshold beyond it is named in a note with an arrow at the top (bottom) instead."""
    lo, hi = _span(e, multi_seed)
    d = hi - lo if hi > lo else max(abs(hi), 1.0) * 0.1
    off: dict = {}  # (rounded threshold, 'above'/'below') -> methods
    for m, v in e["methods"].items():
        thr = 2 * v["nl1"][e["ref"]]
        if not np.isfinite(thr):
            continue
        if lo - _NEAR * d <= thr <= hi + _NEAR * d:
            ax.axhline(thr, color=colors[m], ls=":", lw=0.8)
        else:
            off.setdefault((round(thr, 1), "above" if thr > hi else "below"), []).append(m)
    shown = [2 * v["nl1"][e["ref"]] for v in e["methods"].values()]
    shown = [t for t in shown if np.isfinite(t) and lo - _NEAR * d <= t <= hi + _NEAR * d]
    lo, hi = min([lo, *shown]), max([hi, *shown])
    d = hi - lo if hi > lo else d
    above = sorted((k for k in off if k[1] == "above"), reverse=True)
    below = sorted(k for k in off if k[1] == "below")
    line = 0.075  # one note's height, a fraction of the axes
    top, bottom = ((0.02 + line * len(rows)) if rows else 0.0 for rows in (above, below))  # the notes' room
    inner = (hi - lo + 0.1 * d) / (1 - top - bottom)
    ax.set_ylim(lo - 0.05 * d - bottom * inner, hi + 0.05 * d + top * inner)
    for rows, y0, step, arrow, va in ((above, 0.985, -line, "\u2191", "top"), (below, 0.015, line, "\u2193", "bottom")):
        for j, key in enumerate(rows):
            ms = off[key]
            ax.text(0.99, y0 + j * step, f"{arrow} 2x nominal off the axis: {key[0]:.1f}% "
                    f"({', '.join(_name(m) for m in ms)})", transform=ax.transAxes, ha="right", va=va,
                    fontsize=7, color=colors[ms[-1]], bbox=dict(fc="white", ec="none", alpha=0.8, pad=1))


def _labels(e: dict) -> dict:
    """Paper names, with '(= other)' for a method whose curve equals an earlier one's."""
    out, seen = {}, {}
    for m, v in e["methods"].items():
        key = tuple(round(x, 6) for x in v["nl1"])
        out[m] = _name(m) + (f" (= {_name(seen[key])})" if key in seen else "")
        seen.setdefault(key, m)
    return out


def _key(results: dict, colors: dict, multi_seed: bool, fz_max: float) -> list:
    """The figure's legend, said once: each method (its colour, marker and line, "(= other)" where its curves equal
    an earlier method's on every factor), then the encodings every panel shares."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    methods = list(results["methods"])
    per_factor = [_labels(e) for e in results["factors"].values()]
    handles = []
    for k, m in enumerate(methods):
        said = {lab.get(m, _name(m)) for lab in per_factor}
        handles.append(Line2D([], [], color=colors[m], ls=_LINES[k % len(_LINES)], marker=style.marker(m),
                              ms=5 - 0.5 * (k % 3), mfc="none" if k % 2 else colors[m],
                              label=said.pop() if len(said) == 1 else _name(m)))
    if multi_seed:
        handles.append(Line2D([], [], color="0.35", marker="|", ms=9, ls="none",
                              label=f"bar: ± std over {len(results['seeds'])} seeds"))
    handles += [Line2D([], [], color="0.35", marker="x", ms=8, ls="none",
                       label="x: the error doubles (dashed vertical: at that level)"),
                Line2D([], [], color="0.35", ls=":", lw=1, label="dotted: 2x the method's nominal error")]
    if "force" in results["factors"]:
        handles.append(Patch(facecolor="0.9", label=f"grey band: Fz beyond the training range (> {fz_max:g} N)"))
    return handles


@style.plots
def plot(results: dict, out: Path) -> list[Path]:
    """stability_<factor>.png per factor, stability.png (all factors, the encoding said once in a figure-level
    legend) and seeds.png (with >= 2 seeds), each stamped with preset, seeds and commit; error bars only over >= 2
    seeds."""
    colors = {m: style.colour(m) for m in results["methods"]}
    paths = []
    fz_max = float(results["config"]["data"]["fz_max"])
    multi_seed = len(results["seeds"]) >= 2
    key = _key(results, colors, multi_seed, fz_max)

    def stamp(fig):
        common.stamp(fig, results["preset"], results["seeds"], results.get("commit", "?"))

    def draw(ax, fn, e):
        labels = _labels(e)
        cats = _categories(fn, e)
        for k, m in enumerate(e["methods"]):
            _curve(ax, e, m, k, len(e["methods"]), colors[m], labels[m], multi_seed, cats)
        _thresholds(ax, e, colors, multi_seed)
        if fn == "force":  # the forces no training press reached: shaded, and said so where it is
            ax.axvspan(fz_max, max(e["levels"]) + fz_max / 6, color="0.9", zorder=0)
            ax.text(fz_max, 0.03, " beyond training", transform=ax.get_xaxis_transform(), ha="left", va="bottom",
                    fontsize=7, color="0.35")
        if cats is not None:
            ax.set_xticks(range(len(cats)))
            ax.set_xticklabels(cats)
            ax.set_xlim(-0.5, len(cats) - 0.5)
        ax.set_xlabel(_axis_label(e["label"], cats is not None))
        style.error_axis(ax)
        ax.set_title(fn.replace("_", " "))
        ax.grid(alpha=0.25)

    for fn, e in results["factors"].items():
        fig, ax = style.figure(figsize=(9.0, 3.9))
        draw(ax, fn, e)
        ax.set_title(f"Stability: error against {fn.replace('_', ' ')} (preset {results['preset']})")
        ax.legend(handles=[h for h in key if fn == "force" or not h.get_label().startswith("grey band")],
                  loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0, fontsize=7)
        stamp(fig)
        paths.append(style.save(fig, out / f"stability_{fn}.png"))
    n = len(results["factors"])
    cols = min(3, n)
    rows = (n + cols - 1) // cols
    spare = rows * cols - n  # empty slots at the end: the legend goes there, else below the panels
    fig, axes = style.figure(rows + (spare == 0), cols, figsize=(5.6 * cols, 4.0 * (rows + (spare == 0))),
                             squeeze=False)
    for ax, (fn, e) in zip(axes.flat, results["factors"].items()):
        draw(ax, fn, e)
    rest = list(axes.flat)[n:]
    for ax in rest:
        ax.axis("off")
    if rest:
        rest[0].legend(handles=key, loc="upper left" if len(rest) > 1 else "center", fontsize=11,
                       title="key (every panel)", title_fontsize=11, frameon=False)
    fig.suptitle(f"Stability: error against each factor (preset {results['preset']}, "
                 f"{len(results['seeds'])} seed{'s' if multi_seed else ''})", fontsize=13)
    stamp(fig)
    paths.append(style.save(fig, out / "stability.png", bottom=0.01))

    if not multi_seed:  # one dot per method says nothing about a spread
        (out / "seeds.png").unlink(missing_ok=True)
        return paths
    ss = results["seed_spread"]
    fig, ax = style.figure(figsize=(8.0, 3.9))
    keys = ("unseen_objects", "unseen_sensors", "digit")
    for i, (m, v) in enumerate(ss.items()):
        for j, k in enumerate(keys):
            vals = v[k]["values"]
            ax.scatter([j + 0.12 * (i - len(ss) / 2)] * len(vals), vals, color=colors.get(m, style.colour(m)), s=14,
                       marker=style.marker(m), label=_name(m) if j == 0 else None)
    ax.set_xticks(range(len(keys)))
    ax.set_xticklabels(["unseen objects (Table I mean)", "Table II mean", "DIGIT"])
    style.error_axis(ax)
    ax.grid(axis="y", alpha=0.25)
    ax.set_title(f"Seed to seed spread: one dot per seed ({len(results['seeds'])} seeds)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0)
    stamp(fig)
    paths.append(style.save(fig, out / "seeds.png", bottom=0.03))  # the footer clear of the tick labels
    return paths


if __name__ == "__main__":
    import sys

    sys.exit(cli.run(main))
