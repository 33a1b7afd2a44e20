"""What training reached, per method: the validation error beside the constant-prediction level, and the
validation error against wall-clock training time and steps (each run's epochs.csv). The numbers only: their
tables and figure are drawn by experiments.training_figures.

A model that outputs one constant shear scores the constant level on Fx/Fy: a shear MAE near it means the
method did not learn shear, whatever its Fz does. The curves are the training runs themselves (one cosine
schedule each), so the error at an intermediate epoch is what that epoch reached on the way, not what a
shorter run with its own schedule would reach.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from experiments import common

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
