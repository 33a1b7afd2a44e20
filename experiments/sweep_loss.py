"""Does the depth head help, and how much? Sweep the loss weights of the fine-tuned DINO model.

    python -m experiments.sweep_loss --preset {smoke,quick,full} [--betas 0 1 3 10 30] [--alpha 1]
                                     [--seeds N] [--base dino_rd] [--ablation DIR] [--out DIR]

The loss is alpha * L1(force) + beta * MSE(depth). Each beta is a registry entry made from the base
method with dataclasses.replace (data, not a new code path). beta = 0 means the depth head is ABSENT
(no decoder at all, so exactly DINO R), not present-but-unweighted; the base's own beta (10 for DINO RD)
is the base method itself. Variants that match a method the ablation already trained (same name, config
and seed) reuse its run folder instead of training again. Training and evaluation are the ablation's
(experiments.kernel). Writes OUT/results.json, sweep.md, sweep.csv, sweep.png.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from experiments import common, kernel, style, tables
from experiments import paper_numbers as P
from ffjax import cli, registry

DEFAULT_BETAS = (0.0, 1.0, 3.0, 10.0, 30.0)
# What each run is scored on (from its ablation evaluation): unseen objects = Table I mean; unseen
# sensors = Table II mean over the 8 GelSight unit x gel combinations other than the training one.
METRICS = {"unseen_objects": "unseen objects (Table I mean)",
           "unseen_sensors": "unseen GelSight units x gels (Table II, 8 combos)",
           "digit": "DIGIT (uncalibrated)",
           "train_sensor": "training sensor mini-1/gel-1"}


def variant(base: registry.Method, beta: float, alpha: float = 1.0) -> registry.Method:
    """The registry entry for (alpha, beta): an already registered method with exactly these settings
    (e.g. dino_r for beta 0, dino_rd for beta 10), else a new one registered here."""
    beta, alpha = float(beta), float(alpha)
    want = dataclasses.replace(base, depth_head=beta > 0, beta=beta, alpha=alpha)
    same = [m for m in map(registry.get, registry.names())
            if dataclasses.replace(m, name=want.name, paper_name=want.paper_name) == want]
    if base in same:
        return base
    if same:
        return same[0]
    tag = f"_b{beta:g}" + (f"_a{alpha:g}" if alpha != 1.0 else "")
    label = f"{base.paper_name} (beta {beta:g}" + (f", alpha {alpha:g})" if alpha != 1.0 else ")")
    spec = dataclasses.replace(want, name=base.name + tag, paper_name=label)
    known = registry.names()
    if spec.name in known and registry.get(spec.name) != spec:
        raise ValueError(f"registry name {spec.name!r} is taken by another method")
    return spec if spec.name in known else registry.register(spec)


def scores(ev: dict) -> dict:
    """The sweep's numbers from one run's ablation evaluation (eval.json "result")."""
    t1, t2 = ev["table1"], ev["table2"]
    return {"unseen_objects": float(np.mean([t1[o]["nl1"] for o in t1])),
            "unseen_sensors": float(np.mean([t2[s]["nl1"] for s in P.SENSORS[1:]])),
            "digit": float(t2["digit"]["nl1"]) if "digit" in t2 else float("nan"),
            "train_sensor": float(t2[P.SENSORS[0]]["nl1"]),
            "unseen_objects_mae_n": np.mean([t1[o]["mae_n"] for o in t1], axis=0).round(4).tolist()}


def main(argv=None) -> dict:
    ap = common.base_parser(__doc__, experiment="sweep_loss",
                            costs={"quick": "reuses an ablation's runs (--ablation)"})
    ap.add_argument("--betas", type=cli.number(0, inclusive=True), nargs="+", default=list(DEFAULT_BETAS),
                    help="depth-loss weights")
    ap.add_argument("--alpha", type=cli.number(0), default=1.0, help="force-loss weight (the x axis is beta / alpha)")
    ap.add_argument("--seeds", type=int, default=None,
                    help="seeds per beta (default: the preset's `seeds`: 1, 3 at full)")
    ap.add_argument("--base", default="dino_rd", help="registry method the variants are made from")
    ap.add_argument("--ablation", default=None,
                    help="ablation results folder whose finished runs are reused (default: results/ablation-<preset>)")
    common.add_workers(ap)
    args = ap.parse_args(argv)
    if any(b < 0 for b in args.betas) or args.alpha <= 0:
        ap.error("betas must be >= 0 and alpha > 0")
    cfg = common.config_from_args(ap, args)
    seeds_n = common.n_seeds(ap, args, cfg)
    base = registry.get(args.base)
    if not base.depth_head:
        ap.error(f"--base {args.base} has no depth head; choose one with a decoder (e.g. dino_rd)")
    out = Path(args.out or common.ROOT / "results" / f"sweep_loss-{args.preset}").absolute()
    abl = common.ablation_folder(ap, args.ablation, args.preset)
    results = run(cfg, base, sorted(set(args.betas)), args.alpha, seeds_n, out, abl, args.data, args.force,
                  not args.quiet, common.workers(ap, args))
    print(results["finding"])
    print(f"\nwrote {out}/results.json, sweep.md, sweep.csv, sweep.png")
    return results


def run(cfg, base, betas, alpha, n_seeds, out, ablation_dir=None, data_dir=None, force=False, progress=True,
        workers: int = 1) -> dict:
    out = Path(out).absolute()
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    data_root = common.ensure_data(cfg, data_dir, progress=progress)
    timings = {"data_s": round(time.perf_counter() - t0, 1), "train_s": {}, "eval_s": {}}
    specs = {b: variant(base, b, alpha) for b in betas}
    backbone = None
    if any(s.pretrained for s in specs.values()):
        t = time.perf_counter()
        backbone = kernel.pretrained_backbone(cfg, base.backbone, data_root, force, progress)
        timings[f"pretrain_{base.backbone}_s"] = round(time.perf_counter() - t, 1)
    seeds = kernel.seeds(cfg, n_seeds)
    reuse_from = None if force else ablation_dir  # --force retrains here rather than reusing the ablation's runs
    # a beta the ablation trained (DINO R, DINO RD) also gets every further seed it has, at no cost
    all_seeds = {beta: kernel.seeds_for(cfg, spec, n_seeds, data_root, reuse_from) for beta, spec in specs.items()}
    jobs = [kernel.Job(cfg, specs[beta], seed, data_root, out, backbone=lambda: backbone, reuse_from=reuse_from)
            for beta, beta_seeds in all_seeds.items() for seed in beta_seeds]
    done = iter(kernel.run_all(jobs, workers, force, progress, "sweep runs"))
    per_beta = {}
    for beta, spec in specs.items():
        runs, per_seed, reused = [], [], []
        beta_seeds = all_seeds[beta]
        for r in (next(done) for _ in beta_seeds):
            timings["train_s"].setdefault(f"{beta:g}", []).append(r.train_s)
            timings["eval_s"].setdefault(f"{beta:g}", []).append(r.eval_s)
            per_seed.append(scores(r.result))
            runs.append(str(r.dir))
            reused.append(bool(r.reused))
        per_beta[f"{beta:g}"] = {
            "beta": beta, "alpha": alpha, "ratio": beta / alpha, "method": spec.name, "paper_name": spec.paper_name,
            "depth_head": spec.depth_head, "seeds": beta_seeds, "run_dirs": runs, "reused": reused,
            "per_seed": per_seed,
            **{m: common.mean_std([s[m] for s in per_seed]) for m in METRICS},
        }
    timings.update(train_workers=workers, total_s=round(time.perf_counter() - t0, 1))
    results = {"preset": cfg["preset"], "commit": common.git_commit(), "seeds": seeds, "timings": timings,
               "base": base.name, "alpha": alpha, "betas": betas, "per_beta": per_beta, "metrics": METRICS,
               # the ablation's keys too, so `stability --ablation <this folder>` scores the sweep's models
               "methods": [v["method"] for v in per_beta.values()],
               "checkpoints": {v["method"]: v["run_dirs"] for v in per_beta.values()},
               "beta0": "depth head absent (no decoder): the DINO R model",
               "metric": "normalized L1 % (mean over Fx, Fy, Fz of mean |error| / training label range)",
               "data": str(data_root), "config": cfg}
    results["finding"] = finding(results)
    write_all(results, out)
    return results


def _fmt(ms: dict) -> str:
    return common.fmt(ms, 2)


def _spread(z: dict, b: dict) -> tuple[float, str] | None:
    """The seeds' spread of a gap between two cells (mean_std dicts) and how it was taken: a 1-seed cell is taken to
    spread like the other (the only spread measured); None when neither has 2 seeds."""
    nz, nb = z.get("n", 1), b.get("n", 1)
    if nz > 1 and nb > 1:
        return float(np.hypot(z["std"], b["std"])), "the seeds' spread"
    if max(nz, nb) > 1:
        known, n = (z, nz) if nz > 1 else (b, nb)
        return float(np.hypot(known["std"], known["std"])), f"the {n}-seed spread taken for both"
    return None


def _against_no_head(z: dict, b: dict) -> str:
    """What a weighted cell does against no head: helps or hurts only when the gap exceeds the spread."""
    gap = b["mean"] - z["mean"]
    sp = _spread(z, b)
    if sp is None:
        return f"{'lower' if gap < 0 else 'higher'} by {abs(gap):.2f}, one seed each: no spread to judge it"
    spread, how = sp
    if abs(gap) <= spread:
        return f"a tie with no head (gap {gap:+.2f} within {how}, {spread:.2f})"
    return f"the head {'helps' if gap < 0 else 'hurts'} (gap {gap:+.2f} beyond {how}, {spread:.2f})"


def finding(results: dict) -> str:
    """Plain sentences from the numbers, per metric: no head against the base's default beta (the cells with the
    most seeds) and against the best other beta, each judged against the seeds' spread; at a preset that judges
    nothing (common.verdicts: smoke) the numbers alone, and one sentence saying so."""
    judge = common.verdicts(results)

    def against(z: dict, b: dict) -> str:
        return f": {_against_no_head(z, b)}" if judge else ""

    pb = results["per_beta"]
    zero = pb.get("0")
    weighted = {k: v for k, v in pb.items() if v["beta"] > 0}
    if zero is None or not weighted:
        return "The sweep needs beta = 0 and at least one beta > 0 to say whether the depth head helps."
    base_beta = f"{registry.get(results['base']).beta:g}"
    out = []
    for m in ("unseen_objects", "unseen_sensors", "digit"):
        z = zero[m]
        if not np.isfinite(z["mean"]):
            continue
        parts = [f"On {METRICS[m]}, no head reads {_fmt(z)}%"]
        if base_beta in weighted:
            d = weighted[base_beta][m]
            parts.append(f"the default beta/alpha = {weighted[base_beta]['ratio']:g} {_fmt(d)}%{against(z, d)}")
        others = {k: v for k, v in weighted.items() if k != base_beta}
        if others:
            k = min(others, key=lambda k: others[k][m]["mean"])
            b = others[k][m]
            seeds = f"{b.get('n', 1)} seed{'s' if b.get('n', 1) > 1 else ''}"
            low = "; the lowest of several one-seed points is biased low" \
                if judge and b.get("n", 1) == 1 and len(others) > 1 else ""
            parts.append(f"the lowest other beta/alpha, {others[k]['ratio']:g} ({seeds}), {_fmt(b)}%"
                         f"{against(z, b)}{low}")
        out.append("; ".join(parts) + ".")
    single = [k for k, v in pb.items() if len(v["per_seed"]) == 1]
    if not judge:
        out.append(common.no_verdict(results))
    elif len(single) == len(pb):
        out.append("One seed per beta: differences of a few tenths of a percent are within run-to-run noise "
                   "(run --seeds 3 to measure it).")
    elif single:
        out.append(f"One seed at beta = {', '.join(single)}: their points show the trend, not its spread.")
    return " ".join(out)


def _table(results: dict) -> tuple[list, list, list]:
    header = ["beta", "beta/alpha", "method", "depth head", "seeds"] + [METRICS[m] for m in METRICS]
    rows, csv_rows = [], []
    for k, v in results["per_beta"].items():
        n = len(v["per_seed"])
        rows.append([k, f"{v['ratio']:g}", v["paper_name"], "yes" if v["depth_head"] else "absent", n]
                    + [_fmt(v[m]) for m in METRICS])
        csv_rows.append([v["beta"], v["ratio"], v["method"], int(v["depth_head"]), n]
                        + [x for m in METRICS for x in (v[m]["mean"], v[m]["std"])])
    csv_header = ["beta", "beta_over_alpha", "method", "depth_head", "seeds"] + [f"{m}_{s}" for m in METRICS
                                                                                    for s in ("mean", "std")]
    return header, rows, [csv_header, csv_rows]


def _seed_text(results: dict) -> str:
    """'3 seeds', or '1-3 seeds per beta' when the betas the ablation trained have more."""
    counts = sorted({len(v["per_seed"]) for v in results["per_beta"].values()})
    return f"{counts[0]} seed(s)" if len(counts) == 1 else f"{counts[0]}-{counts[-1]} seeds per beta"


def _cells(results: dict) -> dict:
    """{beta: (seeds, reused)} for tables.seeds_text: reused True when every run of the beta is the ablation's, False
    when none is, None when some are, as each beta's `seeds` and `reused` record (ValueError naming the key where a
    results.json lacks one: one written before they were recorded says nothing to go by)."""
    out = {}
    for k, v in results["per_beta"].items():
        missing = [key for key in ("seeds", "reused") if key not in v]
        if missing:
            raise ValueError(f"sweep_loss results.json: per_beta[{k!r}] has no {' or '.join(map(repr, missing))} "
                             "(written before they were recorded): run experiments.sweep_loss again to record them")
        flags = v["reused"]
        out[k] = (v["seeds"], True if flags and all(flags) else False if not any(flags) else None)
    return out


def seeds_said(results: dict, names: bool = False) -> str:
    """The sweep's seeds in words, e.g. "0 for the sweep's own cells; 0-2 for the cells reused from the ablation"
    (names: the betas of each group in brackets)."""
    return tables.seeds_text(_cells(results), here="the sweep's own cells",
                             names=(lambda ks: "beta " + ", ".join(ks)) if names else None)


def write_all(results: dict, out: Path) -> None:
    header, rows, (csv_header, csv_rows) = _table(results)
    text = (f"# Loss-weight sweep: alpha * L1(force) + beta * MSE(depth), base {style.name(results['base'])} "
            f"(preset {results['preset']}, {_seed_text(results)}, commit {results['commit'][:12]})\n\n"
            f"Seeds: {seeds_said(results, names=True)}.\n\n"
            f"Normalized L1 error %, mean ± std over seeds (± only over 2 or more). beta = 0: {results['beta0']}.\n\n"
            + common.md_table(header, rows) + "\n" + results["finding"] + "\n\n![sweep](sweep.png)\n")
    common.write_text(out / "sweep.md", text)
    common.write_csv(out / "sweep.csv", csv_header, csv_rows)
    plot(results, out / "sweep.png")
    common.write_json(out / "results.json", results)


@style.plots
def plot(results: dict, path: Path) -> Path:
    """Error against beta/alpha: beta = 0 in its own narrow panel, beta > 0 on a log axis; dots = seeds."""
    from matplotlib.ticker import FixedFormatter, FixedLocator, NullLocator

    pb = results["per_beta"]
    zero = pb.get("0")
    pos = sorted((v for v in pb.values() if v["beta"] > 0), key=lambda v: v["ratio"])
    shown = [m for m in ("unseen_objects", "unseen_sensors", "digit")
             if any(np.isfinite(v[m]["mean"]) for v in pb.values())]
    fig, axes = style.figure(1, 2 * len(shown), figsize=(5.0 * len(shown), 3.9), squeeze=False,
                             gridspec_kw={"width_ratios": [1, 4] * len(shown)})

    def mean_dot(ax, x, v, m, marker, color):
        """A cell's mean: ± std over seeds with two or more, else a hollow marker (one seed, spread unknown)."""
        multi = len(v["per_seed"]) >= 2
        ax.errorbar([x], [v[m]["mean"]], yerr=[v[m]["std"]] if multi else None, fmt=marker, color=color,
                    mfc=color if multi else "white", capsize=3, zorder=3)
        if multi:  # a one-seed cell's hollow marker is its seed: a dot on it would fill it in
            ax.scatter([x] * len(v["per_seed"]), [s[m] for s in v["per_seed"]], s=10, color="k", alpha=0.5,
                       zorder=4)

    no_head_method = zero["method"] if zero else "dino_r"  # the beta = 0 cell is a registry method (DINO R)
    head, no_head = style.colour(results["base"]), style.colour(no_head_method)

    for i, m in enumerate(shown):
        a0, a1 = axes[0, 2 * i], axes[0, 2 * i + 1]
        if zero:
            mean_dot(a0, 0, zero, m, style.marker(no_head_method), no_head)
        a0.set_xticks([0])
        a0.set_xticklabels(["0\n(no head)"])
        a0.set_xlim(-1, 1)
        style.error_axis(a0)  # the metric is the panel's title
        if pos:
            x = [v["ratio"] for v in pos]
            a1.plot(x, [v[m]["mean"] for v in pos], "-", color=head, zorder=2)
            for v in pos:
                mean_dot(a1, v["ratio"], v, m, style.marker(results["base"]), head)
            a1.set_xscale("log")
            # ticks at the swept ratios: a log axis over 0.1-10 otherwise labels only 10^0 and 10^1
            a1.xaxis.set_major_locator(FixedLocator(x))
            a1.xaxis.set_major_formatter(FixedFormatter([f"{r:g}" for r in x]))
            a1.xaxis.set_minor_locator(NullLocator())
            if zero:
                a1.axhline(zero[m]["mean"], color=no_head, ls=":", lw=1,
                           label=f"beta = 0 ({style.name(no_head_method)})")
            a1.plot([], [], style.marker(results["base"]), color=head, label="mean ± std (2+ seeds)")
            a1.plot([], [], style.marker(results["base"]), color=head, mfc="white", label="1 seed")
            a1.scatter([], [], s=10, color="k", alpha=0.5, label="each seed")
            a1.legend(fontsize=7, loc="best")
        a1.set_xlabel("beta / alpha (depth-loss weight)")
        a1.sharey(a0)
        a1.tick_params(labelleft=False)
        a1.set_title(METRICS[m])
        for a in (a0, a1):
            a.grid(axis="y")
    fig.suptitle(f"Loss-weight sweep ({style.name(results['base'])}, preset {results['preset']}, "
                 f"{_seed_text(results)})")
    common.stamp(fig, results["preset"], [], results.get("commit", "?"), seeds_text=seeds_said(results))
    return style.save(fig, Path(path), bottom=0.015)  # the footer, under the right panel's x label, clear of it


if __name__ == "__main__":
    sys.exit(cli.run(main))
