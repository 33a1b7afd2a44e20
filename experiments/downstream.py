"""Downstream tasks with trained checkpoints in the loop: weighing by pushing (Table IV) and grasping.

    python -m experiments.downstream --preset {smoke,quick,full}
        [--checkpoint RUN_DIR | --ablation DIR] [--out DIR]

Checkpoints: --checkpoint (one run), --ablation (an ablation results folder: every method and seed in
its results.json), else results/ablation-<preset>/results.json, else a DINO RD run trained here on the
preset's dataset (OUT/runs/dino_rd/seed<k>, cached). Scenes (pushes, grasp trials) use fixed seeds and
are rendered once at the checkpoints' frame size; every checkpoint reads the same frames.
Writes OUT/results.json, table4.md, grasping.md, CSVs and PNG plots
(default OUT: results/downstream-<preset>).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from experiments import common, downstream_report
from ffjax.tasks import grasping, pushing

# Scene sizes per preset. The camera runs at 25 fps; presets keep every k-th frame (fps below) and the
# sweep's longest push is simulated once, shorter durations are its prefixes (the reference is tared at
# the start of each push, so a prefix IS a shorter push).
SCALES = {
    "smoke": {
        "fps": 5.0,
        "pushes": 1,
        "duration_s": 3.0,
        "sweep_s": (2.0, 3.0),
        "trials": 1,
        "fruit_trials": 1,
        "grasp_methods": "all",
        "max_steps": 60,
    },
    "quick": {
        "fps": 5.0,
        "pushes": 5,
        "duration_s": 15.0,
        "sweep_s": (3.0, 5.0, 10.0, 15.0, 20.0, 30.0),
        "trials": 10,
        "fruit_trials": 10,
        "grasp_methods": "all",
        "max_steps": 400,
    },
}
SCALES["full"] = {**SCALES["quick"], "fps": 25.0}  # quick subsamples the 25 fps camera; full keeps every frame
SCALES["paper"] = SCALES["full"]
CUP_TARGETS = (1.74, 2.1)  # N, the paper's two targets
PAPER_CUP = {1.74: {"true": 2.28, "est": 2.27}, 2.1: {"true": 3.36, "est": 3.32}}
MAIN_METHOD = "dino_rd"
TRUTH = "perfect"  # pseudo-method: the estimate is the true force (isolates the reference's error)


def main(argv=None) -> dict:
    ap = common.base_parser(__doc__, experiment="downstream",
                            costs={"quick": "reuses an ablation's checkpoints (--ablation)"})
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--checkpoint", default=None, help="one trained run folder (e.g. runs/quick-dino_rd)")
    src.add_argument("--ablation", default=None, help="ablation results folder (its results.json lists runs)")
    args = ap.parse_args(argv)
    cfg = common.config_from_args(ap, args)
    out = Path(args.out or common.ROOT / "results" / f"downstream-{args.preset}").absolute()
    t0 = time.perf_counter()
    checkpoints, source = find_checkpoints(cfg, args, out)
    timings = {"checkpoints_s": round(time.perf_counter() - t0, 1)}
    results = run(cfg, checkpoints, out, progress=not args.quiet, timings=timings, source=source)
    print(downstream_report.console_summary(results))
    print(f"\nwrote {out}/results.json, table4.md, grasping.md, CSVs and plots")
    return results


# ----------------------------------------------------------------------------------------- checkpoints
def find_checkpoints(cfg: dict, args, out: Path) -> tuple[dict, str]:
    """{method: [run dirs]} and where they came from."""
    from ffjax import store

    if args.checkpoint:
        run = Path(args.checkpoint).absolute()
        return {store.describe(run).spec.name: [str(run)]}, f"--checkpoint {run}"
    folder = Path(args.ablation or common.ROOT / "results" / f"ablation-{cfg['preset']}")
    res = common.read_json(folder / "results.json")
    if res and res.get("checkpoints"):
        return {m: [str(Path(d)) for d in dirs] for m, dirs in res["checkpoints"].items()}, str(folder)
    if args.ablation:
        raise FileNotFoundError(f"{folder}/results.json lists no checkpoints")
    return {MAIN_METHOD: [str(train_fallback(cfg, args, out))]}, "trained here (no ablation results found)"


def train_fallback(cfg: dict, args, out: Path) -> Path:
    """A DINO RD run on the preset's dataset, trained as the ablation trains it (cached stage)."""
    from experiments import kernel
    from ffjax import registry

    data_root = common.ensure_data(cfg, args.data, progress=not args.quiet)
    try:
        backbone = kernel.pretrained_backbone(cfg, "vit", data_root, args.force, not args.quiet)
    except ImportError:  # no pretraining module in this checkout: train from random init
        backbone = None
    seed = int(cfg["seed"])
    run_dir = kernel.run_dir(out, MAIN_METHOD, seed)
    kernel.train(cfg, registry.get(MAIN_METHOD), seed, data_root, run_dir, lambda: backbone, args.force,
                 not args.quiet)
    return run_dir


# ----------------------------------------------------------------------------------------- the tasks
def run(
    cfg: dict, checkpoints: dict, out, progress: bool = True, timings: dict | None = None, source: str = ""
) -> dict:
    """Both tasks with every checkpoint ({method: [run dirs]}); writes and returns the results dict."""
    from ffjax.tasks.sensing import ModelSensor

    out = Path(out).absolute()
    out.mkdir(parents=True, exist_ok=True)
    timings = dict(timings or {})
    sc = SCALES[cfg["preset"]]
    sensors = {(m, i): ModelSensor(d) for m, dirs in checkpoints.items() for i, d in enumerate(dirs)}
    sizes = {s.frame_size for s in sensors.values()}
    if len(sizes) != 1:
        raise ValueError(f"checkpoints expect different frame sizes {sizes}: run them separately")
    size = sizes.pop()
    main_method = MAIN_METHOD if MAIN_METHOD in checkpoints else next(iter(checkpoints))

    t = time.perf_counter()
    push = run_pushing(sc, sensors, size, progress)
    timings["pushing_s"] = round(time.perf_counter() - t, 1)
    t = time.perf_counter()
    grasp = run_grasping(sc, sensors, size, main_method, progress)
    timings["grasping_s"] = round(time.perf_counter() - t, 1)

    push_cfg = push.pop("config")
    results = {
        "preset": cfg["preset"],
        "commit": common.git_commit(),
        "timings": timings,
        "checkpoints": checkpoints,
        "checkpoint_source": source,
        "main_method": main_method,
        "frame_size": list(size),
        "out_of_range_frames": {f"{m}/{i}": s.out_of_range for (m, i), s in sensors.items()},
        "scale": sc,
        "push_config": push_cfg,
        "pushing": push,
        "grasping": grasp,
        "objects": [dataclasses.asdict(o) for o in pushing.OBJECTS],
        "cup": {**dataclasses.asdict(grasping.CUP), "targets": CUP_TARGETS, "paper": PAPER_CUP},
        "fruits": [{**dataclasses.asdict(f), "gentle_n": f.gentle_n} for f in grasping.FRUITS],
        "gripper": dataclasses.asdict(grasping.GripperConfig(max_steps=sc["max_steps"])),
    }
    t = time.perf_counter()
    trace = push_trace(results, push_cfg, sensors, size)
    timings["plot_trace_s"] = round(time.perf_counter() - t, 1)
    timings["total_s"] = round(sum(v for k, v in timings.items() if k != "total_s"), 1)
    downstream_report.write_all(results, out, push_trace=trace)
    return results


def _push_cfg(sc: dict) -> pushing.PushConfig:
    return pushing.PushConfig(
        duration_s=max(sc["sweep_s"] + (sc["duration_s"],)), fps=sc["fps"], pushes=sc["pushes"]
    )


def run_pushing(sc: dict, sensors: dict, size, progress: bool) -> dict:
    """Table IV per checkpoint (and for a perfect tactile sensor), and its push-duration sweep."""
    cfg = _push_cfg(sc)
    durations = sorted(set(sc["sweep_s"]) | {sc["duration_s"]})
    est: dict = {key: {} for key in [*sensors, (TRUTH, 0)]}
    pushes: dict = {}
    for oi, obj in enumerate(tqdm(pushing.OBJECTS, desc="pushing", disable=not progress)):
        pushes[obj.name] = [pushing.simulate_push(obj, cfg, seed=1000 * oi + k) for k in range(cfg.pushes)]
        for p in pushes[obj.name]:
            frames, bg = pushing.render_push(p, "mini-1", size)  # the training sensor, as in the paper
            for key, sensor in sensors.items():
                est[key].setdefault(obj.name, []).append(sensor(frames, bg)[:, 2])
            est[(TRUTH, 0)].setdefault(obj.name, []).append(p.force[:, 2])
    table, sweep = {}, {}
    for (method, _), per_obj in est.items():
        for T in durations:
            rows = {o: pushing.weigh(pushes[o], per_obj[o], duration_s=T) for o in per_obj}
            sweep.setdefault(method, {}).setdefault(str(T), []).append(rows)
            if T == sc["duration_s"]:
                table.setdefault(method, []).append(rows)
    return {
        "config": dataclasses.asdict(cfg),
        "duration_s": sc["duration_s"],
        "durations": durations,
        "table": {m: _agg_rows(runs) for m, runs in table.items()},
        "sweep": {m: {T: _agg_rows(runs) for T, runs in per_T.items()} for m, per_T in sweep.items()},
        "per_run": table,
    }


def _agg_rows(runs: list[dict]) -> dict:
    """{object: {field: mean_std over runs}} plus "mean" over objects (per run, then over runs)."""
    objs = list(runs[0])
    fields = [k for k, v in runs[0][objs[0]].items() if isinstance(v, float)]
    agg = {o: {f: common.mean_std([r[o][f] for r in runs]) for f in fields} for o in objs}
    agg["mean"] = {
        f: common.mean_std([np.mean([r[o][f] for o in objs]) for r in runs])
        for f in ("force_error", "weight_error", "weight_error_rel", "weight_error_true_mu")
    }
    return agg


def push_trace(results: dict, push_cfg: dict, sensors: dict, size) -> dict:
    """One push of the 1 kg weight re-simulated (same seed) with the main method's estimate, for the plot."""
    cfg = pushing.PushConfig(**{**push_cfg, "drift_n_per_s": tuple(push_cfg["drift_n_per_s"])})
    p = pushing.simulate_push(pushing.OBJECTS[0], cfg, seed=0)
    frames, bg = pushing.render_push(p, "mini-1", size)
    est = sensors[(results["main_method"], 0)](frames, bg)
    return {
        "t": p.t,
        "true": p.force[:, 2],
        "reference": p.reference,
        "estimate": est[:, 2],
        "phase": p.phase,
        "object": p.obj.label,
        "method": results["main_method"],
    }


def run_grasping(sc: dict, sensors: dict, size, main_method: str, progress: bool) -> dict:
    gcfg = grasping.GripperConfig(max_steps=sc["max_steps"])
    readers = {key: s for key, s in sensors.items() if sc["grasp_methods"] == "all" or key[0] == main_method}
    cup, cup_trace = {}, None
    for k in tqdm(range(sc["trials"]), desc="cup trials", disable=not progress):
        trial = grasping.GraspTrial(grasping.CUP, gcfg, seed=k, size=size)
        for target in CUP_TARGETS:
            true = grasping.run_grasp(trial, target, "reach", grasping.truth_reader(trial))
            cup.setdefault((TRUTH, 0), {}).setdefault(str(target), []).append(true)
            for key, sensor in readers.items():
                read = grasping.model_reader(trial, sensor)
                res = grasping.run_grasp(trial, target, "reach", read)
                res["deformation_error_pct"] = res["deformation_pct"] - true["deformation_pct"]
                cup.setdefault(key, {}).setdefault(str(target), []).append(res)
                if k == 0 and key == (main_method, 0) and target == CUP_TARGETS[-1]:
                    cup_trace = _grasp_trace(trial, sensor, res, true, target)
    fruits = {}
    for fruit in tqdm(grasping.FRUITS, desc="fruits", disable=not progress):
        for k in range(sc["fruit_trials"]):
            trial = grasping.GraspTrial(fruit, gcfg, seed=100 + k, size=size)
            for mode, target, rule in (("gentle", fruit.gentle_n, "reach"), ("firm", fruit.firm_n, "below")):
                for key in [(TRUTH, 0), *readers]:
                    read = (
                        grasping.truth_reader(trial)
                        if key[0] == TRUTH
                        else grasping.model_reader(trial, readers[key])
                    )
                    res = grasping.run_grasp(trial, target, rule, read)
                    res["success"] = bool(fruit.gentle_n <= res["force"] <= fruit.firm_n)
                    res.pop("readings")
                    fruits.setdefault(key, {}).setdefault(fruit.name, {}).setdefault(mode, []).append(res)
    for runs in cup.values():
        for rs in runs.values():
            for r in rs:
                r.pop("readings", None)
    return {
        "cup": _by_method(cup),
        "fruits": _by_method(fruits),
        "cup_trace": cup_trace,
        "summary": {
            "cup": {m: _cup_summary(v) for m, v in _by_method(cup).items()},
            "fruits": {m: _fruit_summary(v) for m, v in _by_method(fruits).items()},
        },
    }


def _by_method(d: dict) -> dict:
    """{(method, i): x} -> {method: [x per checkpoint]}."""
    out: dict = {}
    for (m, _), v in d.items():
        out.setdefault(m, []).append(v)
    return out


def _cup_summary(per_ckpt: list[dict]) -> dict:
    out = {}
    for target in per_ckpt[0]:
        rs = [r for c in per_ckpt for r in c[target]]
        out[target] = {
            "deformation_pct": common.mean_std([r["deformation_pct"] for r in rs]),
            "force": common.mean_std([r["force"] for r in rs]),
            "overshoot_n": common.mean_std([r["overshoot_n"] for r in rs]),
            "abs_force_error_n": common.mean_std([abs(r["overshoot_n"]) for r in rs]),
            "step_increment_n": common.mean_std([r["step_increment_n"] for r in rs]),
            "reached": float(np.mean([r["reached"] for r in rs])),
            "abs_deformation_error_pct": common.mean_std(
                [abs(r.get("deformation_error_pct", 0.0)) for r in rs]
            ),
        }
    return out


def _fruit_summary(per_ckpt: list[dict]) -> dict:
    out = {}
    for fruit in per_ckpt[0]:
        out[fruit] = {}
        for mode in per_ckpt[0][fruit]:
            rs = [r for c in per_ckpt for r in c[fruit][mode]]
            out[fruit][mode] = {
                "success": float(np.mean([r["success"] for r in rs])),
                "n": len(rs),
                "force": common.mean_std([r["force"] for r in rs]),
            }
    return out


def _grasp_trace(trial, sensor, res: dict, true: dict, target: float) -> dict:
    """Per-step forces and deformation of one cup grasp (both sensors' estimates) for the plot."""
    last = max(res["stop_step"], true["stop_step"]) + 3
    steps = np.arange(1, last + 1)
    bgs = trial.backgrounds()
    est = [sensor(np.stack([trial.frames(s)[k] for s in steps]), bg)[:, 2] for k, bg in enumerate(bgs)]
    return {
        "steps": steps,
        "true": [trial.force(s) for s in steps],
        "est_a": est[0],
        "est_b": est[1],
        "deformation_pct": [trial.deformation_pct(s) for s in steps],
        "target": target,
        "stop_est": res["stop_step"],
        "stop_true": true["stop_step"],
    }


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
