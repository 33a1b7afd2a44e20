"""How well can a frame tell Fz at light loads on wide contacts? The information a frame carries, against what models
read, on the training's and the downstream tasks' bodies.

    python -m experiments.diagnostics.low_force [--preset quick] [--data DATA_DIR] [--runs RUN_DIR ...] [--out DIR]

1. Physics (no data needed): each body pressed centrally on the training sensor at Fz from 0.1 to 4 N, at the
   training render size, noiseless. Per load: the approach, the contact area, the image change from the
   background, and the Cramer-Rao bound on Fz from one frame, sigma_F >= noise / ||dI/dFz|| (the frame's
   derivative by Fz from presses at Fz -+ 10%, the camera's white noise of sensor.noise_std counts per pixel and
   channel): no estimator, trained or not, reads Fz from one frame with a smaller spread than this, even knowing
   the body and its pose; a model knows neither, so its spread is larger (a wide body lightly pressed and a narrow
   one more firmly can make similar frames).
2. With --data (a dataset folder): how many training presses are light (Fz below 1 N and 2 N) and how wide their
   contacts are, per indenter; and how seated they are: each press's contact area against the same indenter's
   pressed centred and untilted at the same Fz (interpolated over SEAT_LOADS_N), per Fz band. A tilted face
   touches on its edge until the approach exceeds its width x sin(tilt), so a flat indenter's ratio says how often
   training shows that face flat on the gel; a sphere's stays near 1 at any tilt.
3. With --runs (training run folders): each run's mean signed Fz error on noisy frames of the same presses (8
   camera-noise draws per load): an offset at light load where the bound is large is the model answering from its
   training prior where the frame says little.
Writes OUT/results.json, low_force.md and low_force.png.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from experiments.diagnostics import publish

# training bodies (a small and a wide one, the flat face) and the downstream contacts whose Fz read was offset
BODIES = ("sphere_small", "sphere_big", "cube", "flat_face", "cup_rim", "tomato", "bottle_wall")
LOADS_N = (0.1, 0.25, 0.5, 1.0, 2.0, 4.0)
STEP = 0.1  # relative: the frame's derivative by Fz from presses at Fz (1 -+ STEP)
DRAWS = 8  # camera-noise draws per load for the models' read
STREAM = 2000  # render seeds no dataset split uses
SEAT_LOADS_N = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 12.0, 16.0)  # the untilted reference presses, interpolated between
FZ_BANDS_N = ((0.0, 2.0), (2.0, 5.0), (5.0, 10.0), (10.0, 16.0))
SEATED = 0.8  # a press whose contact is at least this share of the untilted one's counts as seated


def _body(name: str):
    from ffjax.tasks import contacts

    return contacts.get_contact(name)


def physics(cfg: dict) -> list:
    """Per body and load: approach (mm), contact area (mm2), image change from the background (rms and max, counts)
    and the Cramer-Rao bound on Fz (N) from one frame."""
    from ffjax import sim
    from ffjax.sim import dataset

    sensor = dataset.sensor_of(cfg["data"]["train_sensor"], cfg["data"])
    size = dataset.render_size(sensor, cfg["data"]["render_size"])
    rows = []
    for name in BODIES:
        body = _body(name)
        for fz in LOADS_N:
            lo, mid, hi = (sim.press(body, sensor, (0.0, 0.0, fz * k), size=size, noise=False)
                           for k in (1 - STEP, 1.0, 1 + STEP))
            bg = mid.background.astype(np.float64)
            change = mid.image.astype(np.float64) - bg
            grad = (hi.image.astype(np.float64) - lo.image.astype(np.float64)) / (2 * STEP * fz)
            crb = sensor.noise_std / max(float(np.sqrt((grad**2).sum())), 1e-12)
            rows.append({"body": name, "fz": fz, "approach_mm": float(mid.meta["penetration_mm"]),
                         "area_mm2": float(mid.meta["contact_area_mm2"]),
                         "change_rms": float(np.sqrt((change**2).mean())), "change_max": float(np.abs(change).max()),
                         "crb_n": crb, "crb_rel": crb / fz})
    return rows


def training_presses(cfg: dict, data_root: Path) -> dict:
    """Per indenter: the share of training presses below 1 and 2 N, their median contact area (mm2), and per Fz band
    (FZ_BANDS_N) how their contact compares with the indenter pressed centred and untilted at the same Fz: the
    median ratio and the share of presses at least SEATED of it."""
    from ffjax import data
    from ffjax.sim import dataset

    split = data.open_split(dataset.split_dir(data_root, "train"))
    shapes, fz, area = split.column("shape"), split.column("force_applied")[:, 2], split.column("contact_area_mm2")
    gel = dataset.sensor_of(cfg["data"]["train_sensor"], cfg["data"]).gel
    strain = split.column("penetration_mm") / gel.thickness_mm
    out = {}
    for s in sorted(set(shapes.tolist())):
        m = shapes == s
        light = m & (fz < 1.0)
        ratio = area[m] / np.interp(fz[m], SEAT_LOADS_N, untilted_areas(cfg, s))
        bands = []
        for lo, hi in FZ_BANDS_N:
            r = ratio[(fz[m] >= lo) & (fz[m] < hi)]
            bands.append({"fz_n": [lo, hi], "n": int(r.size), "median_ratio": _median(r),
                          "seated": float(np.mean(r >= SEATED)) if r.size else None})
        out[s] = {"n": int(m.sum()), "below_1n": float(np.mean(fz[m] < 1.0)), "below_2n": float(np.mean(fz[m] < 2.0)),
                  "median_area_mm2_below_1n": _median(area[light]),
                  "median_area_mm2": float(np.median(area[m])), "seating": bands,
                  "approach_over_t_top_band": _median(strain[m & (fz >= FZ_BANDS_N[-1][0])])}
    return out


def _median(x: np.ndarray) -> float | None:
    return float(np.median(x)) if x.size else None


def untilted_areas(cfg: dict, shape: str) -> list:
    """Contact area (mm2) of `shape` pressed centred and untilted at each of SEAT_LOADS_N, as the dataset presses it."""
    from ffjax import sim
    from ffjax.sim import dataset

    sensor = dataset.sensor_of(cfg["data"]["train_sensor"], cfg["data"])
    size = dataset.render_size(sensor, cfg["data"]["render_size"])
    n = len(SEAT_LOADS_N)
    got = sim.press_many([sim.get_shape(shape)] * n, sensor, [(0.0, 0.0, f) for f in SEAT_LOADS_N], [0.0] * n,
                         [0.0] * n, [0.0] * n, [(0.0, 0.0)] * n, [STREAM] * n, size, noise=False)
    for g in got:
        if isinstance(g, ValueError):
            raise g
    return [float(g.meta["contact_area_mm2"]) for g in got]


def model_reads(cfg: dict, runs: list) -> dict:
    """Per run, body and load: the mean signed Fz error (N) and its std over DRAWS noisy frames."""
    from ffjax import data, metrics, sim, store
    from ffjax.sim import dataset

    sensor = dataset.sensor_of(cfg["data"]["train_sensor"], cfg["data"])
    size = dataset.render_size(sensor, cfg["data"]["render_size"])
    frames, truth, keys = [], [], []
    for bi, name in enumerate(BODIES):
        body = _body(name)
        for li, fz in enumerate(LOADS_N):
            seeds = [(STREAM * 1000 + bi * 100 + li) * DRAWS + k for k in range(DRAWS)]
            b = sim.press_batch(body, sensor, [(0.0, 0.0, fz)] * DRAWS, seeds=seeds, size=size)
            frames.append(b["image"])
            truth.append(b["force"][:, 2])
            keys.append((name, fz))
    out = {}
    for run in runs:
        trained = store.load(run)
        x = np.concatenate([data.preprocess_image(f, sensor.background(size), trained.stats, trained.input_size)
                            for f in frames])
        pred = metrics.predict(trained.build(), trained.variables, x)[:, 2].reshape(len(keys), DRAWS)
        err = pred - np.stack(truth)
        out[str(run)] = {"method": trained.spec.name,
                         "rows": [{"body": k[0], "fz": k[1], "bias_n": float(e.mean()), "std_n": float(e.std())}
                                  for k, e in zip(keys, err)]}
    return out


def run(cfg: dict, data_root: Path | None, runs: list) -> dict:
    res = {"preset": cfg["preset"], "sensor": cfg["data"]["train_sensor"],
           "render_size": list(cfg["data"]["render_size"]), "physics": physics(cfg)}
    if data_root:
        res["training"] = training_presses(cfg, data_root)
    if runs:
        res["models"] = model_reads(cfg, runs)
    return res


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def readable_from(rows: list, body: str, rel: float = 0.1) -> float | None:
    """The lightest load at which the bound is within `rel` of Fz (None if none)."""
    ok = [r["fz"] for r in rows if r["body"] == body and r["crb_rel"] <= rel]
    return min(ok) if ok else None


def report(res: dict) -> str:
    h, w = res["render_size"]
    lines = [f"# Fz at light loads (preset {res['preset']}, {res['sensor']}, {h}x{w}, commit {res['commit'][:12]})",
             "", "Centred presses, noiseless frames. Change: the frame minus the background, counts (rms over the "
             "frame, max). Bound: the Cramer-Rao bound on Fz from one frame with the camera's noise, N (and "
             "relative to Fz): no estimator reads Fz with a smaller spread, even one that knows the body and its "
             "pose (a model knows neither).", "",
             "| body | Fz (N) | approach (um) | contact (mm2) | change rms / max | bound (N) | bound / Fz |",
             "|---|---|---|---|---|---|---|"]
    for r in res["physics"]:
        lines.append(f"| {r['body']} | {r['fz']:g} | {1000 * r['approach_mm']:.1f} | {r['area_mm2']:.1f} | "
                     f"{r['change_rms']:.2f} / {r['change_max']:.0f} | {r['crb_n']:.3f} | {r['crb_rel']:.2f} |")
    lines += ["", "Lightest load read within 10% by the bound: " + ", ".join(
        f"{b} {v:g} N" if (v := readable_from(res["physics"], b)) is not None else f"{b} none up to {LOADS_N[-1]:g} N"
        for b in BODIES) + "."]
    if res.get("training"):
        lines += ["", "## Light presses in training", "", "| indenter | presses | below 1 N | below 2 N | "
                  "median contact below 1 N (mm2) | median contact (mm2) |", "|---|---|---|---|---|---|"]
        for s, v in res["training"].items():
            a1 = v["median_area_mm2_below_1n"]
            lines.append(f"| {s} | {v['n']} | {100 * v['below_1n']:.0f}% | {100 * v['below_2n']:.0f}% | "
                         f"{'-' if a1 is None else f'{a1:.1f}'} | {v['median_area_mm2']:.1f} |")
        lines += ["", "## How seated the training presses are", "",
                  "Each press's contact area over the same indenter's pressed centred and untilted at the same Fz: "
                  f"median, and in brackets the share of presses at least {SEATED:.0%} of it (seated). A tilted "
                  "face touches on its edge until the approach exceeds its width x sin(tilt); a sphere is the same "
                  "body at any tilt, but a large one tilted about the tool's tip touches R sin(tilt) aside, partly "
                  "beyond the pad.", "",
                  "| indenter | " + " | ".join(f"Fz {lo:g}-{hi:g} N" for lo, hi in FZ_BANDS_N)
                  + f" | approach / gel thickness, Fz >= {FZ_BANDS_N[-1][0]:g} N (median) |",
                  "|---|" + "---|" * (len(FZ_BANDS_N) + 1)]
        for s, v in res["training"].items():
            lines.append(f"| {s} | " + " | ".join("-" if b["median_ratio"] is None else
                                                 f"{b['median_ratio']:.2f} ({100 * b['seated']:.0f}%)"
                                                 for b in v["seating"]) + f" | {_fmt(v['approach_over_t_top_band'])} |")
    for run, m in (res.get("models") or {}).items():
        lines += ["", f"## {m['method']}: mean signed Fz error (N) ± std over {DRAWS} noise draws ({run})", "",
                  "| body | " + " | ".join(f"{f:g} N" for f in LOADS_N) + " |", "|---|" + "---|" * len(LOADS_N)]
        for b in BODIES:
            cells = [r for r in m["rows"] if r["body"] == b]
            lines.append(f"| {b} | " + " | ".join(f"{r['bias_n']:+.2f} ± {r['std_n']:.2f}" for r in cells) + " |")
    return "\n".join(lines) + "\n"


def plot(res: dict, path: Path) -> Path:
    """Left: the bound relative to Fz against Fz per body; right: each model's mean signed Fz error."""
    import matplotlib

    from experiments import style
    from experiments.tables import save_png

    models = res.get("models") or {}
    seating = 1 if res.get("training") else 0
    n = 1 + seating + len(models)
    cols = min(3, n)  # rows of at most 3 panels: five side by side are too small to read
    rows_n = -(-n // cols)
    fig, axes = style.figure(rows_n, cols, figsize=(5.2 * cols, 3.9 * rows_n), squeeze=False)
    axes = axes.ravel()
    for extra in axes[n:]:
        extra.set_visible(False)
    ax = axes[0]
    colour = {b: matplotlib.colormaps["tab10"](i) for i, b in enumerate(BODIES)}  # distinct hues, none too pale
    for b in BODIES:
        rows = [r for r in res["physics"] if r["body"] == b]
        ax.plot([r["fz"] for r in rows], [r["crb_rel"] for r in rows], "o-", color=colour[b], ms=4,
                label=b.replace("_", " "))
    ax.axhline(0.1, color="0.5", ls=":", lw=1, label="10% of Fz")
    ax.set(xscale="log", yscale="log", xlabel="Fz (N)", ylabel="Cramer-Rao bound on Fz / Fz",
           title="what one frame can tell (noise-limited)")
    ax.set_xticks(LOADS_N, [f"{f:g}" for f in LOADS_N])
    ax.legend(fontsize=7)
    if seating:
        _seating_panel(axes[1], res["training"], colour)
    lows, highs = [0.0], [0.0]
    for k, (run, m) in enumerate(models.items(), start=1 + seating):  # noqa: B007 (one panel per run)
        ax = axes[k]
        for b in BODIES:
            rows = [r for r in m["rows"] if r["body"] == b]
            ax.errorbar([r["fz"] for r in rows], [r["bias_n"] for r in rows], yerr=[r["std_n"] for r in rows],
                        fmt="o-", color=colour[b], ms=4, capsize=2, label=b.replace("_", " "))
            lows += [r["bias_n"] - r["std_n"] for r in rows]
            highs += [r["bias_n"] + r["std_n"] for r in rows]
        ax.axhline(0, color="0.5", lw=1)
        ax.set(xscale="log", xlabel="Fz (N)", ylabel="mean signed Fz error (N)",
               title=f"{style.name(m['method'])}: what it reads", xticks=LOADS_N)
        ax.set_xticklabels([f"{f:g}" for f in LOADS_N])
    pad = 0.05 * (max(highs) - min(lows))
    for ax in axes[1 + seating:n]:  # one scale for every model, so their panels compare at a glance
        ax.set_ylim(min(lows) - pad, max(highs) + pad)
    from experiments import common

    common.stamp(fig, res["preset"], [], res.get("commit", "?"))
    return save_png(fig, Path(path))


def _seating_panel(ax, training: dict, colour: dict) -> None:
    """Median contact of the training presses over the untilted press's, per indenter and Fz band; the bodies of the
    other panels in their colours, the other indenters in greys told apart by marker."""
    mid = [(lo + hi) / 2 for lo, hi in FZ_BANDS_N]
    others = [s for s in training if s not in colour]
    for i, (s, v) in enumerate(training.items()):
        ratio = [np.nan if b["median_ratio"] is None else b["median_ratio"] for b in v["seating"]]
        grey = str(round(0.2 + 0.5 * others.index(s) / max(len(others) - 1, 1), 2)) if s in others else None
        ax.plot(mid, ratio, "os^vD<>ph*"[i % 10] + "-", color=colour.get(s, grey), ms=4, label=s.replace("_", " "),
                lw=2 if s in colour else 1)
    ax.axhline(SEATED, color="0.5", ls=":", lw=1, label=f"seated ({SEATED:.0%})")
    ax.set(xlabel="Fz band centre (N)", ylabel="contact / untilted contact at the same Fz (median)",
           title="training presses: how seated", ylim=(0, 1.55))  # headroom: the legend sits above the lines
    ax.set_xticks(mid, [f"{lo:g}-{hi:g}" for lo, hi in FZ_BANDS_N])
    ax.legend(fontsize=6, ncol=4, loc="upper center")


def main(argv=None) -> dict:
    from experiments import common
    from ffjax import cli

    ap = argparse.ArgumentParser(prog=common.prog(), description=common.description(__doc__))
    ap.add_argument("--preset", default="quick", help="the preset whose sensor and render size to use")
    ap.add_argument("--data", default=None, help="dataset folder: its light training presses")
    ap.add_argument("--runs", nargs="*", default=[], help="training run folders whose Fz read to measure")
    ap.add_argument("--out", default=None, help="results folder (default: results/low_force)")
    args = ap.parse_args(argv)
    import configs

    cfg = configs.get(args.preset)
    out = cli.check_out(ap, Path(args.out or common.ROOT / "results" / "low_force"))
    res = {"commit": common.git_commit(), **run(cfg, Path(args.data) if args.data else None, args.runs)}
    return publish(out, "low_force", res, report, plot)


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))

