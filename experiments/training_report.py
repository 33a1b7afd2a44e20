"""What training reached, per method: the validation error beside the constant-prediction level, and the
validation error against wall-clock training time and steps (each run's epochs.csv).

A model that outputs one constant shear scores the constant level on Fx/Fy: a shear MAE near it means the
method did not learn shear, whatever its Fz does. The curves are the training runs themselves (one cosine
schedule each), so the error at an intermediate epoch is what that epoch reached on the way, not what a
shorter run with its own schedule would reach.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from experiments import common, tables

AXES = ("Fx", "Fy", "Fz")


def constant_level(data_root) -> dict:
    """The metric of predicting the training labels' median for every validation frame."""
    from ffjax import data, metrics

    root = Path(data_root)
    y_train, y_val = data.open_split(root / "train").forces, data.open_split(root / "val").forces
    guess = np.broadcast_to(np.median(y_train, axis=0), y_val.shape)
    return metrics.summarize(guess, y_val, y_train.min(axis=0), y_train.max(axis=0))


def read_curve(run_dir) -> list[dict]:
    """epochs.csv of a run as rows of floats (epoch, step, time_s, val_nl1, val_mae_f*)."""
    path = Path(run_dir) / "epochs.csv"
    if not path.exists():
        return []
    with path.open(newline="") as f:
        return [{k: float(v) for k, v in row.items() if v not in ("", None)} for row in csv.DictReader(f)]


def summarize(checkpoints: dict, data_root) -> dict:
    """{method: [run dirs]} -> final validation error per method (mean ± std over seeds) and the curves."""
    const = constant_level(data_root)
    methods = {}
    for method, runs in checkpoints.items():
        curves = [read_curve(r) for r in runs]
        finals = [c[-1] for c in curves if c]
        if not finals:
            continue
        mae = np.mean([[f[f"val_mae_{a.lower()}"] for a in AXES] for f in finals], axis=0)
        methods[method] = {
            "val_nl1": common.mean_std([f["val_nl1"] for f in finals]),
            "mae_n": mae.round(4).tolist(),
            # shear MAE as a fraction of the constant prediction's (1.0 = learned no shear)
            "shear_vs_constant": [round(float(mae[i] / const["mae_n"][i]), 3) for i in (0, 1)],
            "steps": int(finals[0]["step"]),
            "train_time_s": common.mean_std([f["time_s"] for f in finals]),
            "curves": [[{k: c[k] for k in ("epoch", "step", "time_s", "val_nl1") if k in c} for c in cur]
                       for cur in curves],
        }
    return {"constant": {"nl1": const["nl1"], "mae_n": const["mae_n"]}, "methods": methods}


def table_md(report: dict, preset: str) -> tuple[str, list, list]:
    const = report["constant"]
    header = ["Method", "steps", "train time (s)", "val normalized L1 (%)", "MAE Fx (N)", "MAE Fy (N)",
              "MAE Fz (N)", "shear MAE / constant's (Fx, Fy)"]
    rows = []
    for m, r in report["methods"].items():
        rows.append([tables._name(m), r["steps"], common.fmt(r["train_time_s"], 0), common.fmt(r["val_nl1"], 2),
                     *(f"{v:.3f}" for v in r["mae_n"]), ", ".join(f"{v:.2f}" for v in r["shear_vs_constant"])])
    rows.append(["constant (training median)", "-", "-", f"{const['nl1']:.2f}", *(f"{v:.3f}" for v in const["mae_n"]),
                 "1.00, 1.00"])
    text = (f"# Training: final validation error per method (preset {preset})\n\n"
            "Validation split of the training sensor (mini-1/gel-1, the 10 training indenters). The last row predicts "
            "the training labels' median for every frame: a shear ratio near 1 means that method learned no "
            "shear.\n\n" + common.md_table(header, rows) + "\n\nCurves: training_curves.png / training_curves.csv "
            "(validation error after each epoch against training wall-clock time and steps).\n")
    return text, header, rows


def curve_rows(report: dict) -> tuple[list, list]:
    header = ["method", "seed_index", "epoch", "step", "time_s", "val_nl1"]
    rows = [[m, i, int(p["epoch"]), int(p["step"]), round(p["time_s"], 2), round(p["val_nl1"], 4)]
            for m, r in report["methods"].items() for i, cur in enumerate(r["curves"]) for p in cur]
    return header, rows


def plot(report: dict, path: Path, preset: str, seeds=(), commit: str = "?") -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FixedLocator, NullLocator, ScalarFormatter

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.4), sharey=True)
    colors = plt.cm.tab10(np.arange(max(len(report["methods"]), 1)))
    # identical runs (e.g. DINO_F R and DINO_F RD: same regressor, same gradients) would hide each other
    styles = ("-", "--", ":", "-.")
    for k, ((m, r), color) in enumerate(zip(report["methods"].items(), colors)):
        for i, cur in enumerate(r["curves"]):
            if not cur:
                continue
            for ax, key in zip(axes, ("time_s", "step")):
                ax.plot([p[key] for p in cur], [p["val_nl1"] for p in cur], color=color, alpha=0.9 if i == 0 else 0.4,
                        ls=styles[k % len(styles)], lw=1.6, label=tables._name(m) if i == 0 else None,
                        marker="." if len(cur) < 40 else None)
    ticks = [2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 30]
    for ax, label in zip(axes, ("training wall-clock time (s)", "training steps")):
        ax.axhline(report["constant"]["nl1"], color="0.4", ls="--", lw=1, label="constant prediction")
        ax.set_xlabel(label)
        ax.set_yscale("log")
        ax.yaxis.set_major_locator(FixedLocator(ticks))
        ax.yaxis.set_major_formatter(ScalarFormatter())
        ax.yaxis.set_minor_locator(NullLocator())
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("validation normalized L1 (%)")
    axes[1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    fig.suptitle(f"Accuracy against training time (preset {preset}; one cosine schedule per run)")
    common.stamp(fig, preset, seeds, commit)
    return tables.save_png(fig, path)


def write(report: dict, out: Path, preset: str, seeds=(), commit: str = "?") -> None:
    """training.md / training.csv (final errors), training_curves.csv and training_curves.png."""
    out = Path(out)
    text, header, rows = table_md(report, preset)
    common.write_text(out / "training.md", text)
    common.write_csv(out / "training.csv", header, rows)
    common.write_csv(out / "training_curves.csv", *curve_rows(report))
    plot(report, out / "training_curves.png", preset, seeds, commit)
