"""Reproduce the paper's Tables I-III on the simulated fixtures, end to end.

    python -m experiments.ablation --preset {smoke,quick,full,paper} [--methods ...] [--seeds N] [--out DIR]

Stages, each cached in a folder and reused when its config matches (`--force` redoes them; a killed
run continues where it stopped): the dataset (data/<preset>), the self-supervised backbones
(data/<preset>/pretrained/<kind>), one training run per method and seed (OUT/runs/<method>/seed<k>),
and its evaluation (Table I objects, Table II sensors, Table III calibrations; OUT/runs/.../eval.json).
Then OUT/results.json, table1.md, table2.md, table3.md, CSVs and PNG plots.
"""

from __future__ import annotations

import copy
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from experiments import common, paper_numbers, tables, training_report
from ffjax import registry

DEFAULT_SEEDS = {"smoke": 1, "quick": 1, "full": 3, "gpu": 1, "paper": 1}
# Table III: (target sensor, which layers calibrate): GelSight units tune the last Linear + LayerNorm,
# DIGIT (another kind of sensor) the whole regressor, as the paper does.
CALIBRATIONS = (("mini-2-gel1", "last"), ("mini-3-gel2", "last"), ("digit", "regressor"))


def main(argv=None) -> dict:
    ap = common.base_parser(__doc__.strip().splitlines()[0], costs={"quick": "~30 min",
                                                                           "full": "52 min (3 seeds, before issue 13)"})
    ap.add_argument("--methods", nargs="+", default=None, metavar="NAME",
                    help=f"registry names (default: the paper set {', '.join(registry.PAPER_SET)})")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per method (default: 1, 3 at full)")
    args = ap.parse_args(argv)
    cfg = common.config_from_args(ap, args)
    methods = args.methods or list(registry.PAPER_SET)
    for m in methods:
        registry.get(m)  # unknown names fail here, before any work
    seeds = args.seeds or DEFAULT_SEEDS[args.preset]
    if seeds < 1:
        ap.error("--seeds must be at least 1")
    out = Path(args.out or common.ROOT / "results" / f"ablation-{args.preset}")
    results = run(cfg, methods, seeds, out, data_dir=args.data, force=args.force, progress=not args.quiet)
    print(tables.console_summary(results))
    print(f"\nwrote {out}/results.json, table1.md, table2.md, table3.md, training.md and plots")
    return results


def run(cfg: dict, methods, n_seeds: int, out, data_dir=None, force: bool = False, progress: bool = True) -> dict:
    """Every stage for `methods` x `n_seeds`; returns (and writes) the results dict."""
    out = Path(out).absolute()
    out.mkdir(parents=True, exist_ok=True)
    timings: dict = {}
    t0 = time.perf_counter()
    data_root = common.ensure_data(cfg, data_dir, progress=progress)
    timings["data_s"] = round(time.perf_counter() - t0, 1)

    specs = [registry.get(m) for m in methods]
    backbones = {}
    for kind in sorted({s.backbone for s in specs if s.pretrained}):
        t = time.perf_counter()
        backbones[kind] = pretrained_backbone(cfg, kind, data_root, force, progress)
        timings[f"pretrain_{kind}_s"] = round(time.perf_counter() - t, 1)

    seeds = [int(cfg["seed"]) + k for k in range(n_seeds)]
    per_run, checkpoints, train_s, eval_s = {}, {}, {}, {}
    jobs = [(s, seed) for s in specs for seed in seeds]
    for spec, seed in tqdm(jobs, desc="ablation runs", disable=not progress or len(jobs) < 2):
        run_dir = out / "runs" / spec.name / f"seed{seed}"
        t = time.perf_counter()
        train_run(cfg, spec, seed, data_root, run_dir, backbones.get(spec.backbone), force, progress)
        train_s.setdefault(spec.name, []).append(round(time.perf_counter() - t, 1))
        t = time.perf_counter()
        per_run.setdefault(spec.name, []).append(evaluate_run(cfg, run_dir, data_root, force))
        eval_s.setdefault(spec.name, []).append(round(time.perf_counter() - t, 1))
        checkpoints.setdefault(spec.name, []).append(str(run_dir))
    timings.update(train_s=train_s, eval_s=eval_s, total_s=round(time.perf_counter() - t0, 1))

    results = tables.aggregate(per_run)
    results.update(preset=cfg["preset"], commit=common.git_commit(), seeds=seeds, methods=methods,
                   timings=timings, checkpoints=checkpoints, data=str(data_root), config=cfg,
                   metric="normalized L1 %: mean |error| / (max - min of the training labels) per axis, "
                          "averaged over Fx, Fy, Fz; mae_n = per-axis MAE in newtons")
    results["training"] = training_report.summarize(checkpoints, data_root)
    results["findings"] = tables.findings(results)
    tables.write_all(results, out)
    training_report.write(results["training"], out, cfg["preset"], seeds, results["commit"])
    return results


def pretrained_backbone(cfg: dict, kind: str, data_root: Path, force: bool, progress: bool):
    """(params, batch_stats) of the cached self-supervised backbone, pretraining it on first use."""
    from ffjax.train import pretrain

    folder = data_root / "pretrained" / kind
    pretrain.ensure(cfg, kind, folder, force=force, progress=progress)
    return pretrain.load_backbone(folder)


def train_key(cfg: dict, spec, seed: int, data_root: Path) -> str:
    manifest = common.read_json(data_root / "manifest.json") or {}
    return common.fingerprint("train", {k: cfg[k] for k in ("data", "model", "train", "pretrain")},
                              spec.__dict__, seed, manifest.get("config"))


def train_run(cfg, spec, seed, data_root, run_dir, backbone, force, progress) -> None:
    """Train one method/seed in `run_dir`, or reuse it, or resume it if a kill left it partial."""
    from ffjax import train

    stage = common.Stage(run_dir, train_key(cfg, spec, seed, data_root), force)
    if stage.done:
        return
    run_cfg = copy.deepcopy(cfg)
    run_cfg["seed"] = seed
    has_ckpt = (run_dir / "checkpoints").exists()
    train.train(run_cfg, spec, data_root, run_dir, resume=has_ckpt, init_backbone=backbone, progress=progress)
    stage.finish()


def evaluate_run(cfg: dict, run_dir: Path, data_root: Path, force: bool) -> dict:
    """Tables I-III numbers of one trained run (cached in run_dir/eval.json).

    Every test split goes through the backbone once; the regressor (before and after each
    calibration) then runs on the cached features, which is exact because calibration never
    touches the backbone.
    """
    from ffjax import calibrate, data, metrics, models
    from ffjax.sim import dataset
    from ffjax.train import load_checkpoint

    key = common.fingerprint("eval", common.read_json(run_dir / "stage.json"), cfg["calibrate"], 2)
    cached = common.read_json(run_dir / "eval.json")
    if cached and cached.get("key") == key and not force:
        return cached["result"]

    run_cfg, spec, stats, variables = load_checkpoint(run_dir, "best")
    size = int(run_cfg["data"]["input_size"])
    model = models.build(run_cfg["model"], spec, size)
    head = run_cfg["model"]["regressor"]
    reg, reg_stats = variables["params"]["regressor"], calibrate.regressor_stats(variables)

    def feats(kind, name):
        arr = data.load_arrays(data.open_split(dataset.split_dir(data_root, kind, name)), stats, size)
        return calibrate.features(model, variables, arr["image"]), arr["force"]

    def score(reg_params, fx):
        pred = calibrate.predict_from_features(head, reg_params, fx[0], reg_stats)
        return metrics.summarize(pred, fx[1], stats.force_min, stats.force_max)

    objects = {o: feats("unseen", o) for o in paper_numbers.OBJECTS}
    sensors = {s: feats("sensor", s) for s in dataset.SENSOR_KEYS}
    result = {"table1": {o: score(reg, fx) for o, fx in objects.items()},
              "table2": {s: score(reg, fx) for s, fx in sensors.items()},
              "table3": {}}
    cc = cfg["calibrate"]
    for target, layers in CALIBRATIONS:
        calib = feats("calib", target)
        tuned = calibrate.fit_regressor(head, reg, *calib, layers=layers, steps=int(cc["steps"]),
                                        lr=float(cc["lr"]), batch_size=int(cc["batch_size"]), seed=int(cfg["seed"]),
                                        reg_stats=reg_stats)
        others = [s for s in paper_numbers.SENSORS if s != target]
        before = {s: result["table2"][s]["nl1"] for s in others}
        after = {s: score(tuned, sensors[s])["nl1"] for s in others}
        result["table3"][target] = {
            "layers": layers,
            "before": result["table2"][target],
            "after": score(tuned, sensors[target]),
            "others_before": float(np.mean(list(before.values()))),
            "others_after": float(np.mean(list(after.values()))),
            # relative change of the uncalibrated GelSight sensors' error, percent (paper: 4% for DINO RD)
            "degradation_pct": float(np.mean([(after[s] - before[s]) / before[s] * 100 for s in others])),
        }
    common.write_json(run_dir / "eval.json", {"key": key, "result": result})
    return result


if __name__ == "__main__":
    import sys

    from ffjax import cli

    sys.exit(cli.run(main))
