"""What every experiment shares: config/CLI plumbing, cached stages, run provenance, and (from ffjax.results)
tables, atomic writes and figure stamps."""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import configs

# re-exported: every experiment's --help description (its docstring's first paragraph); the experiments write
# their tables and files through common
from ffjax.cli import description  # noqa: F401
from ffjax.results import fmt, md_table, mean_std, read_json, stamp, write_csv, write_json, write_text  # noqa: F401

ROOT = Path(__file__).resolve().parent.parent


def prog(spec=None) -> str | None:
    """`python -m package.module` for the module of `spec` (default: the running one), so usage lines show the
    command users type (argparse would print the file name, e.g. `ablation.py`); None outside `python -m`."""
    spec = spec or getattr(sys.modules.get("__main__"), "__spec__", None)
    return f"python -m {spec.name}" if spec is not None and spec.name else None


def measured_cost(experiment: str, preset: str) -> str | None:
    """What the published run of `experiment` at `preset` took, read from its own record
    (docs/results/<preset>/reproduce.json: wall time, flags, commit, machine), as "measured <minutes> min with
    --seeds 3 at <commit> on <CPU>, 2 cores": the flags it ran with beyond the preset and its folders, which a plain
    run may not share; None where none is published (or it was not run afresh there). Read, never
    written into the source: a new run's time does not make the experiments' code stale."""
    record = ROOT / "docs" / "results" / preset / "reproduce.json"
    try:
        run = json.loads(record.read_text())
        this = run["experiments"][experiment]
        machine = this.get("machine") or run.get("machine", {})  # each entry's own: one record holds several VMs
        if not this.get("fresh", True) or not this.get("wall_s"):
            return None
        minutes = float(this["wall_s"]) / 60
        flags = _published_flags(this.get("argv") or [], preset)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    on = f" on {machine['cpu_model']}, {machine['cores']} cores" if {"cpu_model", "cores"} <= set(machine) else ""
    return (f"measured {minutes:.0f} min{f' with {flags}' if flags else ''} at "
            f"{str(this.get('commit', run.get('commit', '?')))[:7]}{on} ({record.relative_to(ROOT)})")


_FOLDER_FLAGS = ("--preset", "--out", "--data", "--ablation", "--work", "--publish")  # each followed by its value


def _published_flags(argv: list, preset: str | None = None) -> str:
    """A recorded run's flags less the preset, its folders, --quiet and a --seeds that is `preset`'s own: what a
    plain run does not share, e.g. "--seeds 3"."""
    try:
        plain = {"--seeds": str(configs.get(preset)["seeds"])} if preset else {}
    except configs.ConfigError:
        plain = {}
    said, args = [], [str(a) for a in argv]
    while args:
        flag = args.pop(0)
        name, has_value = flag.split("=")[0], "=" in flag
        if name in _FOLDER_FLAGS or name in plain:
            value = flag.split("=", 1)[1] if has_value else (args.pop(0) if args else "")
            if name in plain and value != plain[name]:
                said.append(f"{name} {value}")
        elif flag != "--quiet":
            said.append(flag)
    return " ".join(said)


def base_parser(doc: str, default_preset: str = "quick", costs: dict | None = None,
                experiment: str | None = None) -> argparse.ArgumentParser:
    """The experiments' shared flags. doc: the module's docstring, of which --help shows the whole first paragraph
    (cli.description). costs: {preset: what a run does, in words (no timings: those go stale)},
    shown in --help and said at the start of a run with the published run's measured time where one is recorded
    (measured_cost), so nobody starts a half-hour job without knowing. experiment: its name in the published
    record (e.g. "sweep_loss"); None for a command the pipeline does not run (no measured time to show)."""
    costs = {"smoke": "toy sizes, a check of the plumbing whose numbers carry no verdict", **(costs or {})}
    for preset in configs.PRESETS:
        measured = measured_cost(experiment, preset) if experiment and preset != "smoke" else None
        if measured:
            costs[preset] = f"{costs[preset]}; {measured}" if preset in costs else measured
    # the caller's module, not __main__: experiments.reproduce runs each experiment in its own process
    ap = argparse.ArgumentParser(prog=prog(sys._getframe(1).f_globals.get("__spec__")),
                                 description=description(doc))
    ap.set_defaults(_costs=costs)
    ap.add_argument("--preset", default=default_preset, choices=configs.PRESETS,
                    help=f"size of data, models and training (default: {default_preset}). Cost: "
                         + "; ".join(f"{k}: {v}" for k, v in costs.items()))
    ap.add_argument("--out", default=None, help="results folder (default: results/<experiment>-<preset>)")
    ap.add_argument("--data", default=None, help="dataset folder (default: data/<preset>, made if missing)")
    ap.add_argument("--force", action="store_true", help="redo cached stages even when their config matches")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="config override, e.g. train.epochs=2 (repeatable)")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    return ap


def add_workers(ap) -> None:
    """--workers, for the experiments that train several runs (experiments.kernel.run_all)."""
    ap.add_argument("--workers", type=int, default=None, metavar="N",
                    help="training runs at once, each in its own process on its share of the cores (default: 2 on "
                         "a CPU with 2 or more cores, 1 on a GPU; 1: one at a time on every core)")


def default_workers() -> int:
    """How many runs train at once by default (experiments.kernel.run_all): two on a CPU with at least two cores
    (each on its half), one on an accelerator (one device; runs there would only queue)."""
    import jax

    return min(2, len(os.sched_getaffinity(0))) if jax.default_backend() == "cpu" else 1


def workers(ap, args) -> int:
    """--workers, else default_workers()."""
    if args.workers is not None and args.workers < 1:
        ap.error(f"--workers must be at least 1, got {args.workers} (leave it out for the default)")
    return args.workers or default_workers()


def config_from_args(ap, args) -> dict:
    """The validated config of --preset and --set; a bad key or value is a usage error (exit 2). Says which
    preset runs and what it costs (stderr), before any work."""
    cfg = configs.from_cli(ap, args.preset, args.set)
    if hasattr(args, "seeds"):  # the count flags too, before --out is made; the experiment's own call repeats it
        n_seeds(ap, args, cfg)
    if getattr(args, "workers", None) is not None:
        workers(ap, args)
    if getattr(args, "out", None) is not None:  # an impossible --out fails now, named, not after the first stage
        from ffjax import cli

        cli.check_out(ap, args.out)
    git_commit()  # the code this run loaded, recorded before any work
    cost = getattr(args, "_costs", {}).get(args.preset)
    print(f"{ap.prog}: preset {args.preset}" + (f" ({cost})" if cost else "")
          + ("" if args.preset == "smoke" else "; --preset smoke for a quick check"), file=sys.stderr)
    return cfg


def n_seeds(ap, args, cfg: dict) -> int:
    """Seeds per method: --seeds, else the config's `seeds`; written into cfg (and checked there: seed + seeds - 1
    is a config seed too), so the config a results.json records says how many ran."""
    if args.seeds is None:
        return cfg["seeds"]
    if args.seeds < 1:  # 0 is a value, not "left out": it used to run the preset's count silently
        ap.error(f"--seeds must be at least 1, got {args.seeds} (leave it out for the config's seeds, {cfg['seeds']})")
    cfg["seeds"] = args.seeds
    try:
        configs.validate(cfg)
    except configs.ConfigError as e:
        ap.error(f"--seeds {args.seeds}: {e}")
    return args.seeds


def verdicts(results: dict) -> bool:
    """Whether a run's report may judge its numbers (say "reproduces", "the head helps"): its config's
    report.verdicts, off where the numbers only check the plumbing (the smoke preset); for a results.json written
    before the key, its preset's value today (True for a preset this code lacks)."""
    report = (results.get("config") or {}).get("report")
    if isinstance(report, dict) and "verdicts" in report:
        return bool(report["verdicts"])
    try:
        return bool(configs.get(results.get("preset"))["report"]["verdicts"])
    except (configs.ConfigError, KeyError, TypeError):
        return True


def no_verdict(results: dict) -> str:
    """The one sentence a report without verdicts (verdicts(results) False) carries instead of them."""
    preset = results.get("preset") or (results.get("config") or {}).get("preset", "?")
    return (f"Preset {preset}: its numbers check the plumbing and carry no verdict on the "
            "paper's findings (config report.verdicts is off); the tables are written all the same.")


def ablation_folder(ap, given, preset: str) -> Path:
    """The ablation results folder whose runs an experiment reuses: `given` (--ablation), which must exist (a typo
    used to retrain everything silently), else results/ablation-<preset>."""
    if given is None:
        return ROOT / "results" / f"ablation-{preset}"
    if not Path(given).is_dir():
        ap.error(f"--ablation {given}: no such folder (an experiments.ablation --out folder; leave --ablation out "
                 f"to use results/ablation-{preset})")
    return Path(given)


@functools.cache
def git_commit() -> str:
    """HEAD's hash, with "-dirty" when tracked files other than documentation (docs/, *.md, the executed notebooks)
    differ from it: numbers then are not from a commit (results published and tables written by an earlier call are
    not code, so a `reproduce --only` after a publishing one still runs on its commit). Read once per process, at
    the run's start (config_from_args): a commit made while a run goes on is not its code."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".", ":(exclude)docs",
                                ":(exclude)notebooks", ":(exclude,glob)**/*.md"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.strip()
        return head + ("-dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def machine() -> dict:
    """What a timed result ran on: the CPU by name with its family and model (two VMs both called "AMD EPYC" can
    be a Zen 1 and a Zen 3, whose matrix units differ 2x), its SIMD, cores, memory, python, jax, flax, devices."""
    import flax
    import jax

    info = {"cpu_model": "unknown", "cores": os.cpu_count(), "python": platform.python_version(),
            "jax": jax.__version__, "flax": flax.__version__, "devices": [str(d) for d in jax.devices()],
            "platform": platform.platform()}
    try:
        cpu = {}
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() in ("model name", "cpu family", "model", "flags") and key.strip() not in cpu:
                cpu[key.strip()] = value.strip()
            if line.strip() == "":
                break  # the first processor's block
        name = cpu.get("model name", "unknown")
        if "cpu family" in cpu:
            name += f" (family {cpu['cpu family']}, model {cpu.get('model', '?')})"
        info["cpu_model"] = name
        info["simd"] = sorted(f for f in cpu.get("flags", "").split()
                              if f.startswith(("avx512f", "avx512_bf16", "amx", "avx2")))
        info["mem_gib"] = round(int(Path("/proc/meminfo").read_text().split("\n")[0].split()[1]) / 2**20, 1)
    except (OSError, ValueError, IndexError):
        pass
    return info


def fingerprint(*parts) -> str:
    """Short stable hash of JSON-able parts (configs, names, seeds): the key of a cached stage."""
    blob = json.dumps(parts, sort_keys=True, default=lambda o: list(o) if isinstance(o, tuple) else str(o))
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


# Point labels: the text's size, a gap to its marker, and the offsets tried (in points, times the marker's radius
# plus the gap): right, left, the four diagonals, above, below; then the same farther out (_RINGS), with a leader
# line.
LABEL_FONT = 7
LABEL_GAP = 2.0
_DIRECTIONS = (("left", "center", 1, 0), ("right", "center", -1, 0), ("left", "bottom", 0.8, 0.8),
               ("left", "top", 0.8, -0.8), ("right", "bottom", -0.8, 0.8), ("right", "top", -0.8, -0.8),
               ("center", "bottom", 0, 1), ("center", "top", 0, -1))  # diagonals: the corner clears the marker
_RINGS = (1.0, 2.2, 3.4)


def _overlap(a, b) -> float:
    """Area shared by two boxes (x0, y0, x1, y1)."""
    return max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))


def place_labels(ax, points, texts, radii, obstacles, renderer, fontsize: float = LABEL_FONT) -> list:
    """Label points (data coordinates) where the labels miss each other, every marker and line and stay inside the
    axes: each label takes the cheapest of the offsets in _DIRECTIONS, sized by the renderer's text extents; the
    most crowded points choose first. obstacles: boxes (x0, y0, x1, y1) in display pixels, a line's at most 3 px
    across, a marker's more. radii: each point's marker radius in points. Call after the figure's layout and the
    axes' limits are final (label_points does this from the axes' own markers and lines). Returns the annotations,
    left out of later layouts (they sit inside the axes)."""
    import matplotlib.patheffects as pe

    px_per_pt = ax.figure.dpi / 72.0
    inner = ax.get_window_extent(renderer).padded(-2)
    frame = (inner.x0, inner.y0, inner.x1, inner.y1)
    anchors = [tuple(ax.transData.transform(p)) for p in points]
    lines = [b for b in obstacles if min(b[2] - b[0], b[3] - b[1]) <= 3]
    marks = [b for b in obstacles if min(b[2] - b[0], b[3] - b[1]) > 3]
    centres = [((b[0] + b[2]) / 2, (b[1] + b[3]) / 2) for b in marks]
    style_kw = {"textcoords": "offset points", "fontsize": fontsize, "zorder": 6,
                "path_effects": [pe.withStroke(linewidth=2.5, foreground="white")]}  # legible over grid lines
    sizes = []
    for (x, y), text in zip(points, texts):  # measured, then removed: the chosen offset is drawn below
        probe = ax.annotate(text, (x, y), xytext=(0, 0), **style_kw)
        bb = probe.get_window_extent(renderer)
        sizes.append((bb.width + 2, bb.height + 1))
        probe.remove()

    def candidates(i):
        (px, py), (w, h) = anchors[i], sizes[i]
        d = radii[i] + LABEL_GAP
        for ring, scale in enumerate(_RINGS):
            for ha, va, ux, uy in _DIRECTIONS:
                ox, oy = ux * d * scale, uy * d * scale
                x0 = px + ox * px_per_pt - {"left": 0, "right": w, "center": w / 2}[ha]
                y0 = py + oy * px_per_pt - {"bottom": 0, "top": h, "center": h / 2}[va]
                yield (ha, va, ox, oy, ring), (x0, y0, x0 + w, y0 + h)

    def dist(box, x, y) -> float:
        return float(np.hypot(max(box[0] - x, 0, x - box[2]), max(box[1] - y, 0, y - box[3])))

    def cost(i, box, ring, placed) -> float:
        """Outside the axes or on another label: never where avoidable; on a marker: bad; across a thin line:
        minor. A farther ring, or an offset nearer another marker than its own (whose point would it name?),
        costs extra."""
        outside = (box[2] - box[0]) * (box[3] - box[1]) - _overlap(box, frame)
        own = dist(box, *anchors[i])
        nearer = any(dist(box, x, y) < own for x, y in centres
                     if np.hypot(x - anchors[i][0], y - anchors[i][1]) > 0.5)
        return (1e4 * outside + 1e3 * sum(_overlap(box, b) for b in placed) + 10 * sum(_overlap(box, b) for b in marks)
                + 2 * sum(_overlap(box, b) for b in lines) + 300 * ring + 500 * nearer)

    free = [sum(cost(i, box, c[4], []) < 1e-6 for c, box in candidates(i)) for i in range(len(points))]
    placed, out = [], []
    for i in sorted(range(len(points)), key=lambda i: (free[i], i)):
        # the cheapest offset; among equals the first (near before far, right before left ...)
        _, ((ha, va, ox, oy, ring), box) = min(enumerate(candidates(i)),
                                              key=lambda kc: (cost(i, kc[1][1], kc[1][0][4], placed), kc[0]))
        placed.append(box)
        arrow = {"arrowprops": {"arrowstyle": "-", "lw": 0.5, "color": "0.4", "shrinkA": 0,
                                "shrinkB": radii[i]}} if ring else {}  # a leader line back to the marker
        out.append(ax.annotate(texts[i], points[i], xytext=(ox, oy), ha=ha, va=va, **style_kw, **arrow))
        out[-1].set_in_layout(False)
    return out


def label_points(ax, xs, ys, texts, fontsize: float = LABEL_FONT) -> list:
    """place_labels for a plain scatter: the obstacles are what the axes hold (every scatter marker, every line,
    the legend) and each point's radius is that of the marker drawn on it (default size where none is). Call once
    the figure's layout is final (e.g. through tables.save_png's `then`, or after fig.draw_without_rendering()
    for a layout engine): the labels are placed in display space. Non-finite points get no label."""
    fig = ax.figure
    renderer = fig.canvas.get_renderer()
    ax.set(xlim=ax.get_xlim(), ylim=ax.get_ylim())  # the autoscaled limits, fixed before placing in display space
    px_per_pt = fig.dpi / 72.0
    obstacles, marks = [], []  # marks: (centre x, y in px, radius in points)
    for coll in ax.collections:
        offsets = coll.get_offset_transform().transform(coll.get_offsets())
        sizes = np.broadcast_to(coll.get_sizes() if len(coll.get_sizes()) else [36.0], (len(offsets),))
        for (cx, cy), s in zip(offsets, sizes):
            r = float(np.sqrt(s)) / 2 + 1  # points, with the edge
            marks.append((cx, cy, r))
            obstacles.append((cx - r * px_per_pt, cy - r * px_per_pt, cx + r * px_per_pt, cy + r * px_per_pt))
    for line in ax.lines:
        xy = line.get_transform().transform(line.get_xydata())
        for (x0, y0), (x1, y1) in zip(xy, xy[1:]):
            # thin boxes along the segment (at most 1 px a step), which place_labels reads as a line's
            n = max(1, int(np.ceil(min(abs(x1 - x0), abs(y1 - y0)))))
            t = np.linspace(0, 1, n + 1)
            for a, b in zip(t, t[1:]):
                xa, xb, ya, yb = x0 + a * (x1 - x0), x0 + b * (x1 - x0), y0 + a * (y1 - y0), y0 + b * (y1 - y0)
                obstacles.append((min(xa, xb) - 1, min(ya, yb) - 1, max(xa, xb) + 1, max(ya, yb) + 1))
    if ax.get_legend() is not None:
        bb = ax.get_legend().get_window_extent(renderer)
        obstacles.append((bb.x0, bb.y0, bb.x1, bb.y1))
    points, shown, radii = [], [], []
    for x, y, text in zip(xs, ys, texts):
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        px, py = ax.transData.transform((x, y))
        near = [r for cx, cy, r in marks if np.hypot(cx - px, cy - py) < 0.5]
        points.append((x, y))
        shown.append(text)
        radii.append(max(near, default=4.0))
    return place_labels(ax, points, shown, radii, obstacles, renderer, fontsize)


def ensure_data(cfg: dict, data_dir=None, force: bool = False, progress: bool = True) -> Path:
    """The preset's simulated dataset, generated on first use and reused after (same config)."""
    from ffjax.sim import dataset

    root = Path(data_dir or dataset.default_root(cfg["preset"])).absolute()
    if not (root / "manifest.json").exists():
        # a mistyped --data would otherwise quietly cost a whole simulation
        print(f"note: no dataset at {root}: simulating the {cfg['preset']} preset's dataset there (first use; reused "
              "after). Interrupt now if the path is a typo.", file=sys.stderr, flush=True)
    dataset.generate(cfg, root, force=force, progress=progress)
    return root


class Stage:
    """A cached unit of work in a folder: done when `stage.json` holds the same key and status "done".

    A folder with another key is cleared before the work is redone; one with the same key but not
    done is handed back for resuming (partial work is continued, finished work is not redone).
    """

    def __init__(self, folder, key: str, force: bool = False):
        self.folder, self.key = Path(folder).absolute(), key
        self.file = self.folder / "stage.json"
        info = read_json(self.file) or {}
        if force or (info and info.get("key") != key):
            if self.folder.exists():
                shutil.rmtree(self.folder)
            info = {}
        self.done = info.get("status") == "done"
        self.partial = bool(info) and not self.done
        self.folder.mkdir(parents=True, exist_ok=True)
        if not info:
            write_json(self.file, {"key": key, "status": "started", "started": time.time()})

    def finish(self, **extra) -> None:
        write_json(self.file, {"key": self.key, "status": "done", "finished": time.time(), **extra})
        self.done = True
