"""Speed against accuracy: every method and backbone size, its Table I/II error against latency, training
throughput and parameter count, with the Pareto front marked.

    python -m experiments.pareto --preset {smoke,quick,full} [--sizes ...] [--methods ...] [--grid lean|full]
                                 [--seeds N] [--out DIR]

Stages are the ablation's (dataset, pretraining, and experiments.kernel's training and evaluation; each
cached). A size other than the preset's own pretrains its own backbone (DATA/pretrained/<kind>-<size>-<key>)
and trains into OUT/runs/<size>/<method>/seed<k>. Cells trained (`--grid lean`,
the default): every method at the preset's own size, and only the anchor (dino_rd for ViT, resnet_rd for
ResNet) at the other sizes; `--grid full` trains every method at every size. Timing happens after all
training, in one phase, with rounds interleaved over the cells (so load drift hits every cell alike):
force-only inference (jitted model.apply on preprocessed val images) at batch 1 and 32, and the jitted
train_step at the preset's batch size; each a median over rounds after compilation.
Writes OUT/pareto.png, pareto.md, pareto.csv and results.json.
"""

from __future__ import annotations

import copy
import functools
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from experiments import aggregate, common, kernel, style, tables
from ffjax import registry

# name: (backbone kind, overrides of cfg["model"][kind]); {} = the preset's own model. All patch 8.
SIZES = {
    "vit-xs": ("vit", {"dim": 32, "depth": 2, "heads": 2}),
    "vit-s": ("vit", {}),  # quick/full: dim 64 / depth 2 / heads 4
    "vit-m": ("vit", {"dim": 128, "depth": 4, "heads": 4}),  # the quick ViT before it was sized to the scene
    "resnet": ("resnet", {}),
}
# smoke: the ladder around the smoke ViT (dim 32 / depth 2) by depth only: equal feature widths let the
# sizes share the regressor's and calibration's compiled programs, which keeps the tests fast.
SMOKE_SIZES = {
    "vit-xs": ("vit", {"depth": 1}),
    "vit-s": ("vit", {}),
    "vit-m": ("vit", {"depth": 3}),
    "resnet": ("resnet", {}),
}
ANCHORS = {"vit": "dino_rd", "resnet": "resnet_rd"}  # the one method trained at every size (lean grid)
# (warm-up calls, calls per round, rounds) per measurement; the smoke preset only checks the code path.
REPEATS = {"smoke": {"b1": (2, 3, 3), "b32": (1, 2, 3), "train": (1, 2, 3)},
           "quick": {"b1": (5, 20, 7), "b32": (2, 5, 7), "train": (2, 4, 5)},
           "full": {"b1": (5, 20, 7), "b32": (2, 5, 7), "train": (2, 4, 5)},
           "gpu": {"b1": (5, 20, 7), "b32": (2, 5, 7), "train": (2, 4, 5)}}
PANELS = (  # (key, y metric, x metric, x is minimized, title)
    ("t1_latency", "table1", "latency_b1_ms", True, "Table I error vs batch-1 latency"),
    ("t1_train", "table1", "train_img_s", False, "Table I error vs training throughput"),
    ("t2_latency", "table2", "latency_b1_ms", True, "Table II error vs batch-1 latency"),
    ("t1_params", "table1", "params_total", True, "Table I error vs parameters"),
)
AXIS_LABELS = {"latency_b1_ms": "inference latency at batch 1 (ms)",
               "train_img_s": "training throughput (images/s)", "params_total": "parameters (all, trained or not)",
               "table1": "Table I error, unseen objects (%)", "table2": "Table II error, GelSight units (%)"}


def main(argv=None) -> dict:
    ap = common.base_parser(__doc__, experiment="pareto",
                            costs={"quick": "reuses an ablation's runs (--ablation)"})
    ap.add_argument("--methods", nargs="+", default=None, metavar="NAME",
                    help=f"registry names (default: the paper set {', '.join(registry.PAPER_SET)})")
    ap.add_argument("--sizes", nargs="+", default=None, metavar="SIZE", help=f"of {', '.join(SIZES)} (default: all)")
    ap.add_argument("--grid", choices=("lean", "full"), default="lean",
                    help="lean: all methods at the preset's size, the anchor method at the others")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per cell (default: the preset's `seeds`)")
    ap.add_argument("--ablation", default=None,
                    help="ablation results folder whose finished runs are reused for the preset's own size "
                         "(default: results/ablation-<preset>; 'none' to never reuse)")
    common.add_workers(ap)
    args = ap.parse_args(argv)
    if args.preset not in REPEATS:
        ap.error(f"--preset {args.preset}: pareto runs at {', '.join(REPEATS)} (paper scale is for a GPU)")
    cfg = common.config_from_args(ap, args)
    methods = args.methods or list(registry.PAPER_SET)
    sizes = args.sizes or list(SIZES)
    for m in methods:
        registry.get(m)
    unknown = [s for s in sizes if s not in SIZES]
    if unknown:
        ap.error(f"unknown sizes {unknown}; choose from {', '.join(SIZES)}")
    seeds = common.n_seeds(ap, args, cfg)
    out = Path(args.out or common.ROOT / "results" / f"pareto-{args.preset}")
    reuse = None if args.ablation == "none" else common.ablation_folder(ap, args.ablation, args.preset)
    results = run(cfg, methods, sizes, seeds, out, data_dir=args.data, full_grid=args.grid == "full", force=args.force,
                  progress=not args.quiet, reuse_from=reuse, workers=common.workers(ap, args))
    print(results["markdown"])
    print(f"wrote {out}/pareto.png, pareto.md, pareto.csv, results.json")
    return results


# ---------------------------------------------------------------- sizes and the grid
def size_table(preset: str) -> dict:
    return SMOKE_SIZES if preset == "smoke" else SIZES


def size_cfg(cfg: dict, size: str) -> dict:
    """The preset's config with the size's backbone overrides applied."""
    kind, over = size_table(cfg["preset"])[size]
    out = copy.deepcopy(cfg)
    out["model"][kind].update(over)
    return out


def grid(cfg: dict, methods, sizes, full: bool = False) -> list[tuple[str, str]]:
    """(size, method) cells to train: a method only at sizes of its own backbone kind."""
    table = size_table(cfg["preset"])
    cells = []
    for size in sizes:
        kind, over = table[size]
        mine = [m for m in methods if registry.get(m).backbone == kind]
        if not full and over:
            mine = [m for m in mine if m == ANCHORS[kind]] or mine
        cells += [(size, m) for m in mine]
    return cells


def backbone_for(cfg, scfg, size, spec, data_root, force, progress):
    """(params, batch_stats) of the size's pretrained backbone; the preset's own size shares the ablation's."""
    if not spec.pretrained:
        return None
    from ffjax.train import pretrain

    if not size_table(cfg["preset"])[size][1]:
        return kernel.pretrained_backbone(cfg, spec.backbone, data_root, force, progress)
    # Beside the ablation's backbones (sharing the corpus cache pretrain keeps in the parent folder), one folder
    # per size config: a changed size table never overwrites another size's backbone.
    key = common.fingerprint(spec.backbone, scfg["model"][spec.backbone])[:8]
    folder = data_root / "pretrained" / f"{spec.backbone}-{size}-{key}"
    pretrain.ensure(scfg, spec.backbone, folder, force=force, progress=progress)
    return pretrain.load_backbone(folder)


# ---------------------------------------------------------------- the Pareto front
def pareto_front(points, minimize=(True, True)) -> list[int]:
    """Indices of the non-dominated points: no other point is at least as good on both axes and better on one.

    points: sequence of (a, b); minimize[i] False means larger is better on that axis. NaN points never count.
    """
    sign = np.where(np.asarray(minimize, bool), 1.0, -1.0)
    p = np.asarray(points, np.float64).reshape(-1, 2) * sign
    ok = np.all(np.isfinite(p), axis=1)
    front = []
    for i in np.flatnonzero(ok):
        others = p[ok]
        dominated = np.any(np.all(others <= p[i], axis=1) & np.any(others < p[i], axis=1))
        if not dominated:
            front.append(int(i))
    return front


# ---------------------------------------------------------------- timing
def _cpu_times() -> list[int]:
    with open("/proc/stat") as f:
        return [int(v) for v in f.readline().split()[1:]]


def _steal(before: list[int], after: list[int]) -> dict:
    d = [a - b for a, b in zip(after, before)]
    total = max(sum(d[:8]), 1)
    return {"steal": round(d[7] / total, 4) if len(d) > 7 else 0.0, "busy": round(1 - (d[3] + d[4]) / total, 4)}


class Timers:
    """The jitted programs of one cell: force-only inference at batch 1 and 32, and the train step."""

    def __init__(self, run_dir: Path, arrays: dict, batch_size: int):
        import jax

        from ffjax import models, store, train

        trained = store.load(run_dir)
        cfg, spec, size, variables = trained.cfg, trained.spec, trained.input_size, trained.variables
        model = trained.build()
        # Force only: what a deployed estimator returns; XLA drops the unused depth decoder.
        self.infer = jax.jit(lambda v, x: model.apply(v, x, train=False)["force"])
        self.variables = variables
        self.x = {1: jax.device_put(arrays["image"][:1]), 32: jax.device_put(arrays["image"][:32])}
        # Placed like the training loop places them, so a step compiled by training in this process is reused.
        mesh = train.make_mesh()
        self.batch = train.shard_batch({k: v[:batch_size] for k, v in arrays.items()}, mesh)
        self.batch_size = batch_size
        # A copy: train_step donates its state, which would delete buffers shared with `variables`.
        own = jax.tree.map(lambda a: a.copy(), variables)
        self.state = train.replicate(train.init_state(cfg, spec, jax.random.PRNGKey(0), size, variables=own), mesh)
        labels = train.Labeler("all", spec.frozen_backbone)(variables["params"])
        self.params_total = models.count_params(variables["params"])
        self.params_trainable = int(sum(np.size(p) for p, lab in zip(jax.tree.leaves(variables["params"]),
                                                                     jax.tree.leaves(labels)) if lab != "frozen"))
        t0 = time.perf_counter()
        for b in (1, 32):
            self.call(f"b{b}")
        self.call("train")
        self.compile_s = time.perf_counter() - t0

    def call(self, what: str) -> None:
        import jax

        from ffjax import train

        if what == "train":
            self.state, m = train.train_step(self.state, self.batch)  # the input state is donated
            jax.block_until_ready(m)
        else:
            jax.block_until_ready(self.infer(self.variables, self.x[int(what[1:])]))


def _tile(arrays: dict, n: int) -> dict:
    reps = -(-n // len(arrays["force"]))
    return {k: np.concatenate([v] * reps)[:n] for k, v in arrays.items()}


def measure(cells: dict, arrays: dict, batch_size: int, repeats: dict, progress: bool) -> dict:
    """Milliseconds per call (median over rounds, rounds interleaved over cells) for every cell's programs."""
    arrays = _tile(arrays, max(32, batch_size))
    timers = {c: Timers(d, arrays, batch_size) for c, d in tqdm(cells.items(), desc="compile", disable=not progress)}
    per = {c: {w: [] for w in repeats} for c in cells}
    for t in timers.values():
        for what, (warm, _, _) in repeats.items():
            for _ in range(warm):
                t.call(what)
    n_rounds = max(r for _, _, r in repeats.values())
    for r in tqdm(range(n_rounds), desc="timing rounds", disable=not progress):
        for c, t in timers.items():
            for what, (_, steps, rounds) in repeats.items():
                if r >= rounds:
                    continue
                t0 = time.perf_counter()
                for _ in range(steps):
                    t.call(what)
                per[c][what].append((time.perf_counter() - t0) / steps * 1e3)
    out = {}
    for c, t in timers.items():
        ms = {w: statistics.median(v) for w, v in per[c].items()}
        out[c] = {"latency_b1_ms": ms["b1"], "latency_b32_ms": ms["b32"], "b32_img_s": 32e3 / ms["b32"],
                  "train_step_ms": ms["train"], "train_img_s": batch_size * 1e3 / ms["train"],
                  "params_total": t.params_total, "params_trainable": t.params_trainable,
                  "compile_s": round(t.compile_s, 2),
                  "rounds_ms": {w: [round(x, 3) for x in v] for w, v in per[c].items()}}
    return out


# ---------------------------------------------------------------- the experiment
def run(cfg: dict, methods, sizes, n_seeds: int, out, data_dir=None, full_grid: bool = False,
        force: bool = False, progress: bool = True, reuse_from=None, workers: int = 1) -> dict:
    """Train/evaluate every cell (cached, `workers` runs training at once: kernel.run_all), time them all in one
    phase, write the chart, tables and JSON."""
    from ffjax import data, store
    from ffjax.sim import dataset

    out = Path(out).absolute()
    t_start = time.perf_counter()
    timings: dict = {}
    data_root = common.ensure_data(cfg, data_dir, progress=progress)
    seeds = kernel.seeds(cfg, n_seeds)
    cells = grid(cfg, methods, sizes, full=full_grid)
    per_run, run_dirs, reused, cell_seeds, jobs = {}, {}, [], {}, []
    for size, method in cells:
        spec, scfg = registry.get(method), size_cfg(cfg, size)
        label = f"{method}@{size}"
        own_size = not size_table(cfg["preset"])[size][1]  # the ablation trains exactly this model
        # loaded once per cell, and only if one of its seeds trains here
        backbone = functools.cache(functools.partial(backbone_for, cfg, scfg, size, spec, data_root, force, progress))
        source = reuse_from if own_size else None
        # a cell the ablation trained also gets every further seed it has, at no cost
        cell_seeds[label] = kernel.seeds_for(scfg, spec, n_seeds, data_root, source)
        jobs += [(label, kernel.Job(scfg, spec, seed, data_root, out, backbone=backbone, reuse_from=source, size=size))
                 for seed in cell_seeds[label]]
    runs = kernel.run_all([j for _, j in jobs], workers, force, progress, "pareto runs")
    for (label, _), r in zip(jobs, runs, strict=True):
        if r.reused:
            reused.append(str(r.dir))
        per_run.setdefault(label, []).append(r.result)
        run_dirs.setdefault(label, []).append(r.dir)
        # a run trained side by side with another counts one core's seconds (kernel.run_all)
        cells_s = timings.setdefault("cells_s", {})
        cells_s[label] = round(cells_s.get(label, 0.0) + r.train_s + r.eval_s, 1)
    timings.update(train_eval_s=round(time.perf_counter() - t_start, 1), train_workers=workers)

    agg = aggregate.aggregate(per_run)
    # Timing: the first seed's checkpoint of each cell (all seeds share one architecture).
    stats = store.describe(run_dirs[next(iter(run_dirs))][0]).stats
    val = data.load_arrays(data.open_split(dataset.split_dir(data_root, "val")), stats,
                           int(cfg["data"]["input_size"]))
    env = {"loadavg_before": os.getloadavg(), "cpu_before": _cpu_times()}
    t = time.perf_counter()
    speed = measure({c: d[0] for c, d in run_dirs.items()}, val, int(cfg["train"]["batch_size"]),
                    REPEATS[cfg["preset"]], progress)
    timings["measure_s"] = round(time.perf_counter() - t, 1)
    env.update(loadavg_after=os.getloadavg(), steal=_steal(env.pop("cpu_before"), _cpu_times()))

    rows = []
    for size, method in cells:
        label = f"{method}@{size}"
        kind = size_table(cfg["preset"])[size][0]
        rows.append({"label": label, "method": method, "size": size, "backbone": kind,
                     "model": size_cfg(cfg, size)["model"][kind], "table1": agg["table1"][label]["mean"],
                     "table2": agg["table2"][label]["mean"], "seeds": cell_seeds[label], **speed[label],
                     "runs": [str(d) for d in run_dirs[label]]})
    fronts = {key: [rows[i]["label"] for i in pareto_front(_xy(rows, y, x), (x_min, True))]
              for key, y, x, x_min, _ in PANELS}
    timings["total_s"] = round(time.perf_counter() - t_start, 1)
    results = {"preset": cfg["preset"], "commit": common.git_commit(), "seeds": seeds, "methods": methods,
               "sizes": {s: size_table(cfg["preset"])[s] for s in sizes}, "grid": "full" if full_grid else "lean",
               "grid_rule": "lean: every method at the preset's own size, only dino_rd (ViT) / resnet_rd (ResNet) "
                            "at the other sizes; full: every method at every size of its backbone kind",
               "cells": rows, "fronts": fronts, "reused_ablation_runs": reused,
               "timings": timings, "machine": {**common.machine(), **env}, "repeats": REPEATS[cfg["preset"]],
               "data": str(data_root), "config": cfg, "overrides": overrides(cfg),
               "notes": "error = normalized L1 % (Table I: mean over the 10 unseen objects; Table II: mean over "
                        "the 9 GelSight sensor/gel pairs), mean over seeds. Latency = force-only jitted "
                        "model.apply on preprocessed inputs; train img/s = jitted train_step at the preset batch. "
                        "Medians over interleaved rounds after compilation; compare only within one run."}
    results["markdown"] = markdown(results)
    write_all(results, out)
    return results


def overrides(cfg: dict) -> list[str]:
    """'key.path=value' for every setting that differs from the named preset (numbers then are not the preset's)."""
    import configs

    def walk(a, b, path):
        if isinstance(a, dict) and isinstance(b, dict):
            return [d for k in sorted(b) for d in walk(a.get(k), b[k], path + [k])]
        return [] if a == b or (isinstance(a, (list, tuple)) and list(a) == list(b or [])) else \
            [f"{'.'.join(path)}={b}"]

    return walk(configs.get(cfg["preset"]), cfg, [])


def _xy(rows, y: str, x: str) -> list[tuple[float, float]]:
    return [(float(r[x]), float(r[y]["mean"])) for r in rows]


# ---------------------------------------------------------------- outputs
CSV_HEADER = ["method", "size", "backbone", "params_total", "params_trainable", "table1_nl1", "table1_std",
              "table2_nl1", "table2_std", "latency_b1_ms", "latency_b32_ms", "b32_img_s", "train_img_s",
              "train_step_ms", "compile_s"]


def _csv_rows(results: dict) -> list[list]:
    return [[r["method"], r["size"], r["backbone"], r["params_total"], r["params_trainable"],
             round(r["table1"]["mean"], 3), round(r["table1"]["std"], 3), round(r["table2"]["mean"], 3),
             round(r["table2"]["std"], 3), round(r["latency_b1_ms"], 3), round(r["latency_b32_ms"], 3),
             round(r["b32_img_s"], 1), round(r["train_img_s"], 1), round(r["train_step_ms"], 2), r["compile_s"]]
            for r in results["cells"]]


def markdown(results: dict) -> str:
    m = results["machine"]
    sizes = ", ".join(f"{s} = {k} {v or '(preset)'}" for s, (k, v) in results["sizes"].items())
    lines = [f"# Speed against accuracy ({results['preset']} preset, commit {_short(results['commit'])})\n",
             f"Seeds: {seeds_said(results, names=True)}; each cell's count in the seeds column. Grid "
             f"{results['grid']}; sizes: {sizes}.",
             f"Overrides of the preset: {', '.join(results.get('overrides') or []) or 'none'}.",
             f"Machine: {m['cpu_model']}, {m['cores']} cores; load average {_la(m['loadavg_before'])} before and "
             f"{_la(m['loadavg_after'])} after timing; steal {m['steal']['steal']:.1%}, busy {m['steal']['busy']:.1%} "
             "during it. Compare only within this run.\n"]
    shown = {r["label"]: _shown(r) for r in results["cells"]}  # names people read
    rows = []
    for r in results["cells"]:
        rows.append([shown[r["label"]], len(r.get("seeds", results["seeds"])), f"{r['params_total']:,}",
                     f"{r['params_trainable']:,}",
                     common.fmt(r["table1"], 2), common.fmt(r["table2"], 2), f"{r['latency_b1_ms']:.2f}",
                     f"{r['latency_b32_ms']:.1f}", f"{r['b32_img_s']:.0f}", f"{r['train_img_s']:.0f}"])
    lines.append(common.md_table(["method, size", "seeds", "params", "trainable", "Table I nl1 %", "Table II nl1 %",
                                  "latency b1 ms", "latency b32 ms", "infer img/s b32", "train img/s"], rows))
    lines.append("Pareto fronts (non-dominated: lower error and lower latency/params or higher throughput):\n")
    for key, _, _, _, title in PANELS:
        lines.append(f"- {title}: {', '.join(shown.get(c, c) for c in results['fronts'][key])}")
    lines.append("\n" + results["notes"])
    return "\n".join(lines) + "\n"


def _shown(r: dict) -> str:
    """A cell's name people read: 'DINO RD vit-s'."""
    return f"{style.name(r['method'])} {r['size']}"


def seeds_said(results: dict, names: bool = False) -> str:
    """The cells' seeds in words, from what each cell records (its seeds, and which of its runs the ablation's):
    e.g. "0 for the cells trained here; 0-2 for the cells reused from the ablation" (names: the cells of each
    group in brackets). ValueError naming the key for a results.json without `reused_ablation_runs` (written before
    it was recorded)."""
    if "reused_ablation_runs" not in results:
        raise ValueError("pareto results.json has no 'reused_ablation_runs' (written before it was recorded): run "
                         "experiments.pareto again to record which cells' runs were the ablation's")
    reused_runs = set(results["reused_ablation_runs"])
    cells = {}
    for r in results["cells"]:
        flags = [d in reused_runs for d in r.get("runs", [])]
        reused = True if flags and all(flags) else False if not any(flags) else None
        cells[_shown(r)] = ([int(k) for k in r.get("seeds", results["seeds"])], reused)
    return tables.seeds_text(cells, here="the cells trained here", names=", ".join if names else None)


def _num(v: float) -> str:
    return f"{v / 1e6:g}M" if v >= 1e6 else f"{v / 1e3:g}k" if v >= 1e4 else f"{v:g}"


def _short(commit: str) -> str:
    return commit[:12] + ("-dirty" if commit.endswith("-dirty") else "")


def _la(la) -> str:
    return "/".join(f"{x:.1f}" for x in la)


def _point_label(r: dict) -> str:
    """A point's label on the chart: 'DINO RD vit-xs'; a size named like its backbone adds nothing ('ResNet RD')."""
    return style.name(r["method"]) if r["size"] == r.get("backbone", r["size"]) else _shown(r)


def _together(xy, log_x: bool, tol: float = 0.015) -> list[list[int]]:
    """Groups of points that would sit on each other (within `tol` of the axis' span in x and in y, x in log
    where the axis is): drawn side by side and labelled once."""
    ok = [i for i, p in enumerate(xy) if np.all(np.isfinite(p)) and (not log_x or p[0] > 0)]
    if not ok:
        return []
    xs = np.array([np.log10(xy[i][0]) if log_x else xy[i][0] for i in ok])
    ys = np.array([xy[i][1] for i in ok])
    sx, sy = max(float(np.ptp(xs)), 1e-12), max(float(np.ptp(ys)), 1e-12)
    groups: list[list[int]] = []
    for k, i in enumerate(ok):
        for g in groups:
            j = ok.index(g[0])
            if abs(xs[k] - xs[j]) <= tol * sx and abs(ys[k] - ys[j]) <= tol * sy:
                g.append(i)
                break
        else:
            groups.append([i])
    return groups


def _group_label(rows: list) -> str:
    """One label for points drawn together: 'DINO_F R, DINO_F RD vit-s' (one size), else each point's label."""
    sizes = {r["size"] for r in rows}
    if len(sizes) == 1:
        tail = _point_label(rows[0])[len(style.name(rows[0]["method"])):]
        return ", ".join(style.name(r["method"]) for r in rows) + tail
    return " / ".join(_point_label(r) for r in rows)


@style.plots
def plot(results: dict, path: Path) -> Path:
    """Four panels (PANELS): each cell's error against a cost, colour = method, marker = backbone size, filled =
    mean ± std over 2+ seeds, hollow = 1 seed, the Pareto front ringed and stepped. Every point is labelled once;
    points that would coincide (DINO_F R and DINO_F RD share their speed and error) sit side by side under one
    label. The machine and its load are in pareto.md, not on the chart."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter
    from matplotlib.transforms import offset_copy

    rows = results["cells"]
    methods = sorted({r["method"] for r in rows}, key=lambda m: (m not in registry.PAPER_SET, m))
    colours = {m: style.colour(m) for m in methods}  # the method's colour in every figure; the marker is the size
    markers = dict(zip(results["sizes"], "osD^vP*X"))
    fig, axes = style.figure(2, 2, figsize=(12, 9.6))
    to_label = []  # per panel: the groups' anchors and names, their radii, the lines drawn (data coordinates)
    spread = False
    for ax, (_, y, x, x_min, title) in zip(axes.ravel(), PANELS):
        xy = _xy(rows, y, x)
        on_front = set(pareto_front(xy, (x_min, True)))
        xs = [a for a, _ in xy if np.isfinite(a) and a > 0]
        log_x = bool(xs) and max(xs) / min(xs) > 4  # log only where it spreads points; narrow ranges read linear
        groups = _together(xy, log_x)
        anchors = [(float(np.mean([xy[i][0] for i in g])) if not log_x else
                    float(10 ** np.mean([np.log10(xy[i][0]) for i in g])), float(np.mean([xy[i][1] for i in g])))
                   for g in groups]  # a group's position: its points' centre (they differ by under 1.5% of the axis)
        lines = []
        for g, anchor in zip(groups, anchors):
            for k, i in enumerate(g):  # side by side, 9 points apart, around the group's position
                r, (a, b) = rows[i], (xy[i] if len(g) == 1 else anchor)
                at = offset_copy(ax.transData, fig=fig, x=9 * (k - (len(g) - 1) / 2), y=0, units="points")
                multi = r[y].get("n", 1) >= 2
                c = colours[r["method"]]
                ax.scatter(a, b, edgecolors=c, facecolors=c if multi else "white", marker=markers.get(r["size"], "o"),
                           s=48, lw=1.3, zorder=3, transform=at)
                if multi and r[y].get("std"):  # the seeds' spread of the error; none drawn for one seed
                    spread = True
                    ax.errorbar(a, b, yerr=r[y]["std"], color=c, lw=1, capsize=0, zorder=2, transform=at)
                    lines.append([(a, b - r[y]["std"]), (a, b + r[y]["std"])])
        front = sorted((xy[i] for i in on_front), key=lambda p: p[0])
        if front:
            fx, fy = zip(*front)
            ax.step(fx, fy, where="post" if x_min else "pre", color="k", lw=1, ls="--", zorder=2)
            for (x0, y0), (x1, y1) in zip(front, front[1:]):  # the step's corners: post moves along x first
                corner = (x1, y0) if x_min else (x0, y1)
                lines += [[(x0, y0), corner], [corner, (x1, y1)]]
            ax.scatter(fx, fy, s=170, facecolors="none", edgecolors="k", lw=1.2, zorder=4)
        if log_x:
            ax.set_xscale("log")
            ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
            ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: _num(v)))
            ax.xaxis.set_minor_formatter(NullFormatter())
        # markers drawn with an offset transform are left out of autoscaling: their data (and error bars) put in
        seen = [(a, b + d * r[y].get("std", 0.0)) for r, (a, b) in zip(rows, xy) for d in (-1, 1)
                if np.isfinite(a) and np.isfinite(b)]
        if seen:
            ax.update_datalim(seen)
        ax.margins(x=0.14, y=0.1)  # room for the labels
        ax.autoscale_view()
        ax.set(xlim=ax.get_xlim(), ylim=ax.get_ylim())  # fixed before the labels are placed in display space
        # every point labelled once (a group once), placed once the layout is final (below)
        radii = [np.sqrt(170 if any(i in on_front for i in g) else 48) / 2 + 1 + 4.5 * (len(g) - 1) for g in groups]
        to_label.append((ax, anchors, [_group_label([rows[i] for i in g]) for g in groups], radii, lines))
        ax.set(title=title, xlabel=AXIS_LABELS[x], ylabel=AXIS_LABELS[y])
        ax.grid(which="both")
    # three keys, one per encoding, so that no glyph means two things
    size_mk = [markers.get(s, "o") for s in results["sizes"]]
    keys = [("method (colour)", [Patch(facecolor=colours[m], label=style.name(m)) for m in methods]),
            ("backbone size (marker)", [Line2D([], [], color="0.2", marker=mk, ls="", label=s)
                                        for s, mk in zip(results["sizes"], size_mk)]),
            ("seeds and front", [Patch(facecolor="0.45", edgecolor="0.45", label="filled: mean of 2+ seeds"),
                                 Patch(facecolor="white", edgecolor="0.45", label="hollow: 1 seed")]
             + ([Line2D([], [], color="0.45", lw=1, label="bar: ± std over seeds")] if spread else [])
             + [Line2D([], [], color="k", ls="--", lw=1, label="Pareto front (ringed)")])]
    for k, (title, handles) in enumerate(keys):
        fig.legend(handles=handles, title=title, loc="upper center", bbox_to_anchor=((k + 0.5) / len(keys), 0.115),
                   ncol=2 if len(handles) > 3 else 1, frameon=False)
    fig.suptitle(f"Speed against accuracy (preset {results['preset']})")
    common.stamp(fig, results["preset"], [], results.get("commit", "?"), seeds_text=seeds_said(results))
    def labels():  # once the layout is final: placed in display space
        renderer = fig.canvas.get_renderer()
        px_per_pt = fig.dpi / 72.0
        for ax, anchors, names, radii, lines in to_label:
            to_px = ax.transData.transform
            obstacles = []
            for (cx, cy), r in zip(map(to_px, anchors), radii):  # every group's markers, as one box
                obstacles.append((cx - r * px_per_pt, cy - r * px_per_pt, cx + r * px_per_pt, cy + r * px_per_pt))
            for seg in lines:  # error bars and the front's step, as thin boxes
                (ax0, ay0), (ax1, ay1) = to_px(seg[0]), to_px(seg[1])
                obstacles.append((min(ax0, ax1) - 1, min(ay0, ay1) - 1, max(ax0, ax1) + 1, max(ay0, ay1) + 1))
            common.place_labels(ax, anchors, names, radii, obstacles, renderer)

    return style.save(fig, path, then=labels, bottom=0.12)  # the bottom strip: the keys and the footer


def write_all(results: dict, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    common.write_json(out / "results.json", {k: v for k, v in results.items() if k != "markdown"})
    common.write_text(out / "pareto.md", results["markdown"])
    common.write_csv(out / "pareto.csv", CSV_HEADER, _csv_rows(results))
    plot(results, out / "pareto.png")


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
