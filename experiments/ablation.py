"""Reproduce the paper's Tables I-III on the simulated fixtures, end to end.

    python -m experiments.ablation --preset {smoke,quick,full,paper} [--methods ...] [--seeds N] [--out DIR]

Stages, each cached in a folder and reused when its config matches (`--force` redoes them; a killed
run continues where it stopped): the dataset (data/<preset>), the self-supervised backbones
(data/<preset>/pretrained/<kind>), one training run per method and seed (OUT/runs/<method>/seed<k>),
and its evaluation (Table I objects, Table II sensors, Table III calibrations; OUT/runs/.../eval.json);
the last two are experiments.kernel's.
Then OUT/results.json, table1.md, table2.md, table3.md, CSVs and PNG plots.
"""

from __future__ import annotations

import functools
import time
from pathlib import Path

from experiments import aggregate, common, kernel, tables, training_figures, training_report
from ffjax import registry


def main(argv=None) -> dict:
    ap = common.base_parser(__doc__, experiment="ablation",
                            costs={"quick": "every method, 1 seed (published: 3), its dataset made first where missing",
                                   "full": "every method, 3 seeds"})
    ap.add_argument("--methods", nargs="+", default=None, metavar="NAME",
                    help=f"registry names (default: the paper set {', '.join(registry.PAPER_SET)})")
    ap.add_argument("--seeds", type=int, default=None,
                    help="seeds per method (default: the preset's `seeds`: 1, 3 at full)")
    common.add_workers(ap)
    args = ap.parse_args(argv)
    cfg = common.config_from_args(ap, args)
    methods = args.methods or list(registry.PAPER_SET)
    for m in methods:
        registry.get(m)  # unknown names fail here, before any work
    seeds = common.n_seeds(ap, args, cfg)
    out = Path(args.out or common.ROOT / "results" / f"ablation-{args.preset}")
    results = run(cfg, methods, seeds, out, data_dir=args.data, force=args.force, progress=not args.quiet,
                  workers=common.workers(ap, args))
    print(tables.console_summary(results))
    print(f"\nwrote {out}/results.json, table1.md, table2.md, table3.md, training.md and plots")
    return results


def run(cfg: dict, methods, n_seeds: int, out, data_dir=None, force: bool = False, progress: bool = True,
        workers: int = 1) -> dict:
    """Every stage for `methods` x `n_seeds`, `workers` runs training at once (kernel.run_all); returns (and
    writes) the results dict."""
    out = Path(out).absolute()
    out.mkdir(parents=True, exist_ok=True)
    timings: dict = {}
    t0 = time.perf_counter()
    data_root = common.ensure_data(cfg, data_dir, progress=progress)
    timings["data_s"] = round(time.perf_counter() - t0, 1)

    specs = [registry.get(m) for m in methods]
    backbones, kinds = {}, sorted({s.backbone for s in specs if s.pretrained})
    t = time.perf_counter()
    if kernel.pretraining_corpus(cfg, kinds, data_root, force, progress):
        timings["pretrain_corpus_s"] = round(time.perf_counter() - t, 1)
    for kind in kinds:
        t = time.perf_counter()
        backbones[kind] = kernel.pretrained_backbone(cfg, kind, data_root, force, progress)
        timings[f"pretrain_{kind}_s"] = round(time.perf_counter() - t, 1)

    seeds = kernel.seeds(cfg, n_seeds)
    per_run, checkpoints, train_s, eval_s = {}, {}, {}, {}
    jobs = [kernel.Job(cfg, spec, seed, data_root, out, backbone=functools.partial(backbones.get, spec.backbone))
            for spec in specs for seed in seeds]
    for job, r in zip(jobs, kernel.run_all(jobs, workers, force, progress, "ablation runs"), strict=True):
        spec = job.spec
        train_s.setdefault(spec.name, []).append(r.train_s)
        eval_s.setdefault(spec.name, []).append(r.eval_s)
        per_run.setdefault(spec.name, []).append(r.result)
        checkpoints.setdefault(spec.name, []).append(str(r.dir))
    # train_s of runs trained side by side is one core's (docs/experiments.md)
    timings.update(train_s=train_s, eval_s=eval_s, train_workers=workers, total_s=round(time.perf_counter() - t0, 1))

    results = aggregate.aggregate(per_run)
    results.update(preset=cfg["preset"], commit=common.git_commit(), machine=common.machine(), seeds=seeds,
                   methods=methods,
                   timings=timings, checkpoints=checkpoints, data=str(data_root), config=cfg,
                   metric="normalized L1 %: mean |error| / (max - min of the training labels) per axis, "
                          "averaged over Fx, Fy, Fz; mae_n = per-axis MAE in newtons")
    results["training"] = training_report.summarize(checkpoints, data_root)
    results["findings"] = tables.findings(results)
    tables.write_all(results, out)
    training_figures.write(results["training"], out, cfg["preset"], seeds, results["commit"])
    return results


if __name__ == "__main__":
    import sys

    from ffjax import cli

    sys.exit(cli.run(main))
