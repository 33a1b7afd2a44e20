"""What every experiment shares: config/CLI plumbing, cached stages, run provenance, atomic writes."""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import configs

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


def fingerprint(*parts) -> str:
    """Short stable hash of JSON-able parts (configs, names, seeds): the key of a cached stage."""
    blob = json.dumps(parts, sort_keys=True, default=lambda o: list(o) if isinstance(o, tuple) else str(o))
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def write_json(path, obj) -> None:
    """Write JSON atomically (tmp + fsync + rename): a kill never leaves a half-written results file."""
    write_text(path, json.dumps(obj, indent=1, default=_jsonable))


def write_text(path, text: str) -> None:
    """Write text atomically: the old file or the new one survives a kill or a full disk, never a part."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        with open(tmp, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise


def stamp(fig, preset: str, seeds, commit: str) -> None:
    """Print what a figure was made from in its corner (preset, seeds, commit), and say so when the preset's
    numbers mean nothing: a PNG copied into a notebook keeps its provenance. No seeds (a simulator-only check
    trains nothing): none shown."""
    text = f"ffjax · preset {preset}" + (f" · seeds {list(seeds)}" if seeds else "") + f" · commit {str(commit)[:7]}"
    if preset == "smoke":
        text += " · SMOKE PRESET: plumbing check, numbers meaningless"
    fig.text(0.995, 0.005, text, ha="right", va="bottom", fontsize=7, color="0.35")


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


def read_json(path):
    path = Path(path)
    return json.loads(path.read_text()) if path.is_file() else None


def _jsonable(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (tuple, set)):
        return list(o)
    return str(o)


def ensure_data(cfg: dict, data_dir=None, force: bool = False, progress: bool = True) -> Path:
    """The preset's simulated dataset, generated on first use and reused after (same config)."""
    from ffjax.sim import dataset

    root = Path(data_dir or ROOT / "data" / cfg["preset"]).absolute()
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


def mean_std(values) -> dict:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], np.float64)
    if len(v) == 0:
        return {"mean": float("nan"), "std": float("nan"), "n": 0}
    return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0, "n": int(len(v))}


def fmt(ms: dict | None, digits: int = 1) -> str:
    """'4.2 ± 0.3' (or '4.2' for one seed) from a mean_std dict."""
    if not ms or not np.isfinite(ms.get("mean", float("nan"))):
        return "–"
    if ms.get("n", 1) > 1:
        return f"{ms['mean']:.{digits}f} ± {ms['std']:.{digits}f}"
    return f"{ms['mean']:.{digits}f}"


def md_table(header: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out) + "\n"


def write_csv(path, header: list[str], rows: list[list]) -> None:
    import csv
    import io

    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(header)
    w.writerows(rows)
    write_text(path, buf.getvalue())
