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

import configs

# re-exported: the experiments write their tables and files through common
from ffjax.results import fmt, md_table, mean_std, read_json, stamp, write_csv, write_json, write_text  # noqa: F401

ROOT = Path(__file__).resolve().parent.parent


def prog() -> str | None:
    """`python -m package.module` for the running module, so usage lines show the command users type
    (argparse would print the file name, e.g. `ablation.py`); None outside `python -m`."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    return f"python -m {spec.name}" if spec is not None and spec.name else None


def base_parser(description: str, default_preset: str = "quick", costs: dict | None = None) -> argparse.ArgumentParser:
    """The experiments' shared flags. costs: {preset: measured wall time on the 2-core VM}, shown in --help and
    said at the start of a run, so nobody starts a half-hour job without knowing."""
    costs = {"smoke": "a minute or two, numbers meaningless", **(costs or {})}
    ap = argparse.ArgumentParser(prog=prog(), description=description)
    ap.set_defaults(_costs=costs)
    ap.add_argument("--preset", default=default_preset, choices=configs.PRESETS,
                    help=f"size of data, models and training (default: {default_preset}). Measured on a 2-core "
                         "CPU: " + "; ".join(f"{k}: {v}" for k, v in costs.items()))
    ap.add_argument("--out", default=None, help="results folder (default: results/<experiment>-<preset>)")
    ap.add_argument("--data", default=None, help="dataset folder (default: data/<preset>, made if missing)")
    ap.add_argument("--force", action="store_true", help="redo cached stages even when their config matches")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="config override, e.g. train.epochs=2 (repeatable)")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    return ap


def config_from_args(ap, args) -> dict:
    """The validated config of --preset and --set; a bad key or value is a usage error (exit 2). Says which
    preset runs and what it costs (stderr), before any work."""
    cfg = configs.from_cli(ap, args.preset, args.set)
    if getattr(args, "out", None) is not None:  # an impossible --out fails now, named, not after the first stage
        from ffjax import cli

        cli.check_out(ap, args.out)
    git_commit()  # the code this run loaded, recorded before any work
    cost = getattr(args, "_costs", {}).get(args.preset)
    print(f"{prog() or 'experiment'}: preset {args.preset}" + (f" (measured: {cost})" if cost else "")
          + ("" if args.preset == "smoke" else "; --preset smoke for a quick check"), file=sys.stderr)
    return cfg


def n_seeds(ap, args, cfg: dict) -> int:
    """Seeds per method: --seeds, else the config's `seeds`; written into cfg, so the config a results.json
    records says how many ran."""
    n = args.seeds or cfg["seeds"]
    if n < 1:
        ap.error("--seeds must be at least 1")
    cfg["seeds"] = n
    return n


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
    """HEAD's hash, with "-dirty" when tracked files differ from it (numbers then are not from a commit). Read
    once per process, at the run's start (config_from_args): a commit made while a run goes on is not its code."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
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


def place_labels(ax, xs, ys, texts, fontsize: float = 7) -> None:
    """Annotate points without labels on top of each other: each label takes the first of a few offsets
    (right, below, left, above ...) whose box misses the boxes placed before it. Call after the axes' scales
    are set."""
    ax.autoscale_view()
    to_px = ax.transData.transform
    char_w, line_h = 0.6 * fontsize, 1.3 * fontsize  # in points ~ pixels at the figures' dpi scale
    placed = []
    for x, y, text in sorted(zip(xs, ys, texts), key=lambda t: -t[1]):
        px, py = to_px((x, y))
        w = char_w * len(text)
        for dx, dy in ((4, 3), (4, -line_h - 2), (-w - 4, 3), (-w - 4, -line_h - 2), (4, line_h + 4),
                       (4, -2 * line_h - 4), (-w / 2, line_h + 6), (-w / 2, -2 * line_h - 6)):
            box = (px + dx, py + dy, px + dx + w, py + dy + line_h)
            if not any(b[0] < box[2] and box[0] < b[2] and b[1] < box[3] and box[1] < b[3] for b in placed):
                break
        placed.append(box)
        ax.annotate(text, (x, y), xytext=(dx, dy), textcoords="offset pixels", fontsize=fontsize)


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
