"""Table II at each share of the fixed pattern that moves with the gel: how much of a sensor's fine fixed pattern is
the gel's pigment (it moves under shear) and how much the camera's (it stays) cannot be measured from frames at
rest, so the methods are trained and tested in worlds where 0, 0.5 and 1 of it is pigment.

    python -m experiments.pattern_share --preset {smoke,quick,full} [--shares 0 0.5 1] [--methods dino_rd resnet_rd]
                                        [--seeds N] [--ablation DIR] [--data DIR] [--out DIR]

Each share is its own dataset (`data.pattern_moving`; the preset's share is the preset's own dataset, the others
sibling folders DATA-pattern<share>) and its own trained runs; the preset's share reuses the ablation's runs (and
all their seeds). Scored on Table II's nine GelSight units x gels: the mean error, and per gel the error of the
shear (Fx, Fy) and of Fz, where a model that reads the gel's own pattern shows as a shear read on gel 1 only.
Writes OUT/results.json, pattern_share.md, pattern_share.csv, pattern_share.png.
"""

from __future__ import annotations

import copy
import functools
import sys
import time
from pathlib import Path

import numpy as np

from experiments import common, kernel, style, tables
from experiments import paper_numbers as P
from ffjax import registry

DEFAULT_SHARES = (0.0, 0.5, 1.0)
DEFAULT_METHODS = ("dino_rd", "resnet_rd")
GELS = (1, 2, 3)
METRICS = {"table2": "Table II mean (9 units x gels)",
           **{f"shear_gel{g}": f"shear (Fx, Fy) on gel {g}" for g in GELS},
           **{f"fz_gel{g}": f"Fz on gel {g}" for g in GELS}}
_SHEAR = tuple(f"shear_gel{g}" for g in GELS)


def scores(ev: dict) -> dict:
    """A run's numbers from its evaluation (eval.json "result"): Table II's mean, per gel the shear and Fz errors."""
    t2 = ev["table2"]
    out = {"table2": float(np.mean([t2[s]["nl1"] for s in P.SENSORS]))}
    for g in GELS:
        gel = [t2[s] for s in P.SENSORS if s.endswith(f"gel{g}")]
        out[f"shear_gel{g}"] = float(np.mean([r["nl1_axes"][:2] for r in gel]))
        out[f"fz_gel{g}"] = float(np.mean([r["nl1_axes"][2] for r in gel]))
    return out


def data_folder(cfg: dict, data_dir, share: float) -> Path:
    """The dataset of one share: the preset's own (the ablation's) at the preset's share, else a sibling folder."""
    from ffjax.sim import dataset

    base = Path(data_dir or dataset.default_root(cfg["preset"])).absolute()
    return base if share == float(cfg["data"]["pattern_moving"]) else base.with_name(f"{base.name}-pattern{share:g}")


def main(argv=None) -> dict:
    ap = common.base_parser(__doc__, experiment="pattern_share",
                            costs={"quick": "~2 datasets and 2 methods x 2 shares of training beyond the ablation"})
    ap.add_argument("--shares", type=float, nargs="+", default=list(DEFAULT_SHARES),
                    help="shares of the fine fixed pattern on the gel, each in [0, 1]")
    ap.add_argument("--methods", nargs="+", default=list(DEFAULT_METHODS), choices=registry.names(),
                    help="registry methods to train at every share")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per method and share (default: the preset's)")
    ap.add_argument("--ablation", default=None,
                    help="ablation results folder whose finished runs are reused (default: results/ablation-<preset>)")
    common.add_workers(ap)
    args = ap.parse_args(argv)
    if any(not 0 <= s <= 1 for s in args.shares):
        ap.error(f"--shares must each be in [0, 1], got {args.shares}")
    cfg = common.config_from_args(ap, args)
    out = Path(args.out or common.ROOT / "results" / f"pattern_share-{args.preset}").absolute()
    abl = common.ablation_folder(ap, args.ablation, args.preset)
    results = run(cfg, args.methods, sorted(set(args.shares)), common.n_seeds(ap, args, cfg), out, abl, args.data,
                  args.force, not args.quiet, common.workers(ap, args))
    print(results["finding"])
    print(f"\nwrote {out}/results.json, pattern_share.md, pattern_share.csv, pattern_share.png")
    return results


def run(cfg, methods, shares, n_seeds, out, ablation_dir=None, data_dir=None, force=False, progress=True,
        workers: int = 1) -> dict:
    out = Path(out).absolute()
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    nominal = float(cfg["data"]["pattern_moving"])
    timings: dict = {"data_s": {}, "train_s": {}, "eval_s": {}}
    reuse_from = None if force else ablation_dir
    roots, backbones, cells = {}, {}, []
    for share in sorted(shares, key=lambda s: s != nominal):  # the preset's own data first: it holds the backbones
        cell_cfg = copy.deepcopy(cfg)
        cell_cfg["data"]["pattern_moving"] = float(share)
        t = time.perf_counter()
        roots[share] = common.ensure_data(cell_cfg, data_folder(cfg, data_dir, share), progress=progress)
        timings["data_s"][f"{share:g}"] = round(time.perf_counter() - t, 1)
        home = next(iter(roots.values()))  # pretraining reads no dataset: one backbone per kind for every share
        for m in methods:
            spec = registry.get(m)
            if spec.pretrained and spec.backbone not in backbones:
                backbones[spec.backbone] = kernel.pretrained_backbone(cfg, spec.backbone, home, force, progress)
            seeds = kernel.seeds_for(cell_cfg, spec, n_seeds, roots[share], reuse_from)
            cells.append((share, m, [kernel.Job(cell_cfg, spec, seed, roots[share], out / f"share{share:g}",
                                                backbone=functools.partial(backbones.get, spec.backbone),
                                                reuse_from=reuse_from) for seed in seeds]))
    done = iter(kernel.run_all([j for *_, js in cells for j in js], workers, force, progress, "pattern_share runs"))
    per_share = {f"{share:g}": {"share": float(share), "data": str(roots[share]), "methods": {}} for share in roots}
    for share, m, js in cells:
        runs = [next(done) for _ in js]
        timings["train_s"][f"{m}@{share:g}"] = [r.train_s for r in runs]
        timings["eval_s"][f"{m}@{share:g}"] = [r.eval_s for r in runs]
        per_seed = [scores(r.result) for r in runs]
        per_share[f"{share:g}"]["methods"][m] = {
            "seeds": [j.seed for j in js], "run_dirs": [str(r.dir) for r in runs], "per_seed": per_seed,
            **{k: common.mean_std([s[k] for s in per_seed]) for k in METRICS}}
    timings.update(train_workers=workers, total_s=round(time.perf_counter() - t0, 1))
    results = {"preset": cfg["preset"], "commit": common.git_commit(), "seeds": kernel.seeds(cfg, n_seeds),
               "timings": timings, "methods": list(methods), "shares": [float(s) for s in shares],
               "nominal_share": nominal, "per_share": per_share, "metrics": METRICS,
               "metric": "normalized L1 % (mean |error| / training label range; shear: mean over Fx and Fy)",
               "config": cfg}
    results["finding"] = finding(results)
    write_all(results, out)
    return results


def _cell(results: dict, share: str, m: str) -> dict:
    return results["per_share"][share]["methods"][m]


def _shares(results: dict) -> list[str]:
    """per_share's keys by share (run with the preset's share first, since it holds the backbones)."""
    return sorted(results["per_share"], key=lambda k: results["per_share"][k]["share"])


def finding(results: dict) -> str:
    """What the shares change, per method: Table II's mean and the shear read off gel 1 against gels 2-3, each
    gap beside the seed spreads it must exceed."""
    lines = []
    shares = _shares(results)
    for m in results["methods"]:
        cells = [_cell(results, s, m) for s in shares]
        t2 = ", ".join(f"{s}: {common.fmt(c['table2'], 1)}" for s, c in zip(shares, cells))
        gaps = [np.mean([c[f"shear_gel{g}"]["mean"] for g in GELS[1:]]) - c["shear_gel1"]["mean"] for c in cells]
        # the yardstick: the largest seed spread of any cell with 2 or more seeds (one seed has none of its own)
        spreads = [c[k]["std"] for c in cells if len(c["per_seed"]) >= 2 for k in ("table2", *_SHEAR)]
        noise = f"seed std up to {max(spreads):.1f}" if spreads else "one seed per cell: no seed spread measured"
        lines.append(f"- {style.name(m)}: Table II mean % by share {t2}; the shear error on gels 2-3 minus that on "
                     f"gel 1 (points), by share: {', '.join(f'{s}: {g:+.1f}' for s, g in zip(shares, gaps))} "
                     f"({noise}).")
    return "Moving share of the fixed pattern (0: all camera, 1: all pigment):\n" + "\n".join(lines)


def _table(results: dict) -> tuple[list, list, list]:
    header = ["share", "method", "seeds"] + list(METRICS.values())
    rows, csv_rows = [], []
    for s in _shares(results):
        cell = results["per_share"][s]
        for m, v in cell["methods"].items():
            rows.append([s, style.name(m), len(v["per_seed"])] + [common.fmt(v[k], 1) for k in METRICS])
            csv_rows.append([cell["share"], m, len(v["per_seed"])] + [x for k in METRICS
                                                                       for x in (v[k]["mean"], v[k]["std"])])
    csv_header = ["share", "method", "seeds"] + [f"{k}_{x}" for k in METRICS for x in ("mean", "std")]
    return header, rows, [csv_header, csv_rows]


def seeds_said(results: dict) -> str:
    """The cells' seeds in words (tables.seed_groups), by share: '0-2' where every cell has the same seeds, else
    e.g. '0 at shares 0, 1; 0-2 at share 0.5' (the preset's share has the ablation's seeds); a share whose methods
    differ names them, e.g. 'share 0.5 (DINO RD)'."""
    cells = {(k, m): (v["seeds"], False) for k in _shares(results)
             for m, v in results["per_share"][k]["methods"].items()}
    groups = tables.seed_groups(cells)
    if len(groups) <= 1:
        return groups[0][0] if groups else "none"
    said = []
    for span, _, labels in groups:
        shares = []
        for k in dict.fromkeys(k for k, _ in labels):  # in share order
            mine = [m for kk, m in labels if kk == k]
            whole = len(mine) == len(results["per_share"][k]["methods"])
            shares.append(k if whole else f"{k} ({', '.join(map(style.name, mine))})")
        said.append(f"{span} at share{'s' if len(shares) > 1 else ''} {', '.join(shares)}")
    return "; ".join(said)


def write_all(results: dict, out: Path) -> None:
    header, rows, (csv_header, csv_rows) = _table(results)
    text = (f"# Table II by the moving share of the fixed pattern (preset {results['preset']}, commit "
            f"{results['commit'][:12]})\n\nEach share is its own dataset and its own trained models; "
            f"{results['metric']}, mean ± std over seeds (± only over 2 or more). The preset's share is "
            f"{results['nominal_share']:g}.\n\n" + common.md_table(header, rows) + "\n" + results["finding"]
            + "\n\n![pattern share](pattern_share.png)\n")
    common.write_text(out / "pattern_share.md", text)
    common.write_csv(out / "pattern_share.csv", csv_header, csv_rows)
    plot(results, out / "pattern_share.png")
    common.write_json(out / "results.json", results)


@style.plots
def plot(results: dict, path: Path) -> Path:
    """Left: Table II's mean against the share, per method. Then one panel per method: its shear error on each gel
    against the share (solid gel 1, the training gel; dashed gel 2; dotted gel 3). Error bars: std over 2 or more
    seeds, dots its seeds; a hollow marker is one seed. Points at one share are set slightly apart to stay readable.
    Every y axis starts at 0: a spread of a fraction of a point reads as what it is against the error itself."""
    keys = _shares(results)
    shares = np.array([results["per_share"][k]["share"] for k in keys])
    methods = results["methods"]
    step = 0.02 * max(float(np.ptp(shares)), 1.0)  # the sideways offset between points at one share
    fig, axes = style.figure(1, 1 + len(methods), figsize=(4.4 * (1 + len(methods)), 4.0), squeeze=False)
    axes = axes[0]
    styles = {1: "-", 2: "--", 3: ":"}

    def draw(ax, m, metric, dx, ls):
        c, mk = style.colour(m), style.marker(m)
        cells = [_cell(results, k, m) for k in keys]
        x = shares + dx
        ax.plot(x, [v[metric]["mean"] for v in cells], ls=ls, color=c, zorder=2)
        for xi, v in zip(x, cells):
            multi = len(v["per_seed"]) >= 2
            ax.errorbar([xi], [v[metric]["mean"]], yerr=[v[metric]["std"]] if multi else None, fmt=mk, color=c,
                        mfc=c if multi else "white", capsize=3, zorder=3)
            if multi:
                ax.scatter([xi] * len(v["per_seed"]), [s[metric] for s in v["per_seed"]], s=9, color="k",
                           alpha=0.45, zorder=4)

    for i, m in enumerate(methods):
        draw(axes[0], m, "table2", (i - (len(methods) - 1) / 2) * step, "-")
        axes[0].plot([], [], style.marker(m), color=style.colour(m), label=style.name(m))
        for g in GELS:
            draw(axes[1 + i], m, f"shear_gel{g}", (g - 2) * step, styles[g])
            axes[1 + i].plot([], [], styles[g], color=style.colour(m), label=f"gel {g}" + (" (trained on)" if g == 1
                                                                                            else ""))
        axes[1 + i].set_title(f"{style.name(m)}: shear (Fx, Fy) error per gel", fontsize=9)
    axes[0].plot([], [], "o", color="0.3", label="mean ± std (2+ seeds)")
    axes[0].plot([], [], "o", color="0.3", mfc="white", label="1 seed")
    axes[0].scatter([], [], s=9, color="k", alpha=0.45, label="each seed")
    axes[0].set_title("Table II mean, 9 GelSight units x gels", fontsize=9)
    shear_axes = list(axes[1:])
    hi = max((ax.get_ylim()[1] for ax in shear_axes), default=1.0)
    for ax in axes:
        # from 0, with room above for the legend: the seeds' spread against the size of the error, not magnified
        ax.set_ylim(0, 1.3 * (hi if ax in shear_axes else ax.get_ylim()[1]))  # one scale for every method's shear
        ax.set_xticks(shares)
        ax.set_xlabel("share of the fixed pattern on the gel")
        style.error_axis(ax)
        ax.grid(axis="y")
        ax.legend(fontsize=7, loc="upper center", ncol=2)
    fig.suptitle(f"Table II by the moving share of the fixed pattern (0: all the camera's, stays; 1: all pigment, "
                 f"moves with the gel; preset {results['preset']})", fontsize=10)
    common.stamp(fig, results["preset"], [], results.get("commit", "?"), seeds_text=seeds_said(results))
    return style.save(fig, Path(path), bottom=0.015)  # the footer, under the right panel's x label, clear of it


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
