"""The training report's tables and figure (training.md/.csv, training_curves.csv/.png) from the numbers
experiments.training_report summarizes: drawing only, so `python -m experiments.replot` redraws them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments import common, style


def table_md(report: dict, preset: str) -> tuple[str, list, list]:
    const = report["constant"]
    header = ["Method", "steps", "train time (s)", "val normalized L1 (%)", "MAE Fx (N)", "MAE Fy (N)",
              "MAE Fz (N)", "shear MAE / constant's (Fx, Fy)"]
    rows = []
    for m, r in report["methods"].items():
        rows.append([style.name(m), r["steps"], common.fmt(r["train_time_s"], 0), common.fmt(r["val_nl1"], 2),
                     *(f"{v:.3f}" for v in r["mae_n"]), ", ".join(f"{v:.2f}" for v in r["shear_vs_constant"])])
    rows.append(["constant (training median)", "-", "-", f"{const['nl1']:.2f}", *(f"{v:.3f}" for v in const["mae_n"]),
                 "1.00, 1.00"])
    text = (f"# Training: final validation error per method (preset {preset})\n\n"
            "Validation split of the training sensor (mini-1/gel-1, the 10 training indenters). The last row predicts "
            "the training labels' median for every frame: a shear ratio near 1 means that method learned no "
            "shear.\n\n" + common.md_table(header, rows) + "\n\nCurves: training_curves.png / training_curves.csv "
            "(validation error after each epoch against the training step; the wall-clock times in the CSV are "
            "not a speed measurement: experiments.bench is).\n")
    return text, header, rows


def curve_rows(report: dict) -> tuple[list, list]:
    header = ["method", "seed_index", "epoch", "step", "time_s", "val_nl1"]
    rows = [[m, i, int(p["epoch"]), int(p["step"]), round(p["time_s"], 2), round(p["val_nl1"], 4)]
            for m, r in report["methods"].items() for i, cur in enumerate(r["curves"]) for p in cur]
    return header, rows


def _mean_curve(curves: list) -> dict:
    """The seeds' mean at each epoch all of them reached: {key: [values]} for step, time_s and val_nl1."""
    n = min(len(c) for c in curves)
    return {k: [float(np.mean([c[e][k] for c in curves])) for e in range(n)] for k in ("step", "time_s", "val_nl1")}


@style.plots
def plot(report: dict, path: Path, preset: str, seeds=(), commit: str = "?") -> Path:
    """Validation error against the training step (the epochs on the top axis where every run has the same steps
    per epoch): each method in its own colour, the seeds' mean bold (its marker), each seed thin. Not against
    wall-clock time: training runs are not a speed measurement (experiments.bench is). A method whose mean curve equals
    an earlier one's (DINO_F R and DINO_F RD: the same regressor on the same frozen features) is dashed, hollow,
    and says so in the legend."""
    from matplotlib.ticker import FixedLocator, NullLocator, ScalarFormatter

    fig, ax = style.figure(figsize=(9.5, 4.6))
    seen: dict = {}
    ratios = set()  # steps per epoch, over every point of every run
    for m, r in report["methods"].items():
        curves = [c for c in r["curves"] if c]
        if not curves:
            continue
        ratios |= {round(p["step"] / p["epoch"], 6) for c in curves for p in c if p["epoch"]}
        mean, colour = _mean_curve(curves), style.colour(m)
        key = tuple(round(v, 4) for v in mean["val_nl1"])
        twin = seen.setdefault(key, m)
        label = style.name(m) + (f" (= {style.name(twin)})" if twin != m else "") + \
            (f", mean of {len(curves)} seeds" if len(curves) > 1 else ", 1 seed")
        if len(curves) > 1:
            for c in curves:
                ax.plot([p["step"] for p in c], [p["val_nl1"] for p in c], color=colour, lw=0.7, alpha=0.35)
        ax.plot(mean["step"], mean["val_nl1"], color=colour, lw=1.8, ls="--" if twin != m else "-",
                marker=style.marker(m), ms=4, mfc="white" if twin != m else colour, label=label)
    ax.axhline(report["constant"]["nl1"], color="0.4", ls=":", lw=1, label="constant prediction (training median)")
    ax.set_xlabel("training step")
    ax.set_yscale("log")
    ax.yaxis.set_major_locator(FixedLocator([2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 30]))
    ax.yaxis.set_major_formatter(ScalarFormatter())
    ax.yaxis.set_minor_locator(NullLocator())
    ax.grid(True)
    if len(ratios) == 1:  # one number of steps per epoch: the epochs on the top axis
        per = ratios.pop()
        top = ax.secondary_xaxis("top", functions=(lambda s: s / per, lambda e: e * per))
        top.set_xlabel("epoch")
    style.error_axis(ax, "validation")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0, title="thin: each seed")
    fig.suptitle(f"Validation error during training (preset {preset}; one cosine schedule per run)")
    common.stamp(fig, preset, seeds, commit)
    return style.save(fig, path)


def write(report: dict, out: Path, preset: str, seeds=(), commit: str = "?") -> None:
    """training.md / training.csv (final errors), training_curves.csv and training_curves.png."""
    out = Path(out)
    text, header, rows = table_md(report, preset)
    common.write_text(out / "training.md", text)
    common.write_csv(out / "training.csv", header, rows)
    common.write_csv(out / "training_curves.csv", *curve_rows(report))
    plot(report, out / "training_curves.png", preset, seeds, commit)
