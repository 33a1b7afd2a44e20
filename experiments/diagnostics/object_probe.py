"""Where the force is in an object's image, and how much of it a trained model reads (issue 13).

    python -m experiments.diagnostics.object_probe --preset quick [--runs RUN_DIR ...] [--data DATA_DIR] [--out DIR]

1. Signal (no model): for every training indenter and Table I object, centred noiseless presses at Fz = 5 N on
   the training sensor, put through the model's preprocessing at the training size: the image energy of a
   +1 N change of Fz and of a 1 N shear (mean of +-x, +-y), the contact area (and its share of the pad), and,
   for scale, the energy of camera noise between two frames of one press.
2. Read-out (with --runs): for each run, on the dataset's unseen-object splits, its validation split (per
   training indenter) and its Table II splits (per unit x gel), the slope of predicted on true force per axis
   (1 = the full force read; 0 = none), the Fz offset and the MAE per axis.
Writes DIR/results.json, DIR/object_probe.md and DIR/object_probe.png.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from experiments import common

FZ, STEP_N = 5.0, 1.0  # signal: presses at FZ, changed by STEP_N


def _frame(sensor, shape, force, size, input_size, seed=0, noise=False):
    from ffjax import sim
    from ffjax.data import preprocess

    s = sim.press(shape, sensor, force, size=size, noise=noise, seed=seed)
    return preprocess.to_unit(s.image, s.background, input_size), s


def signal(shapes, sensor_key: str, size=(48, 64), input_size=64) -> dict:
    """Image energy per newton of Fz and of shear for each shape on the sensor `sensor_key` (the training
    sensor; see the module docstring)."""
    from ffjax import sim
    from ffjax.sim.dataset import render_size

    sensor = sim.get_sensor(sensor_key)
    size = render_size(sensor, size)
    pad_mm2 = float(np.prod(sensor.fov_mm))
    out = {}
    for name in shapes:
        x0, s0 = _frame(sensor, name, (0, 0, FZ), size, input_size)
        ez = float(((_frame(sensor, name, (0, 0, FZ + STEP_N), size, input_size)[0] - x0) ** 2).sum())
        shear = [float(((_frame(sensor, name, (*f, FZ), size, input_size)[0] - x0) ** 2).sum())
                 for f in ((STEP_N, 0), (-STEP_N, 0), (0, STEP_N), (0, -STEP_N))]
        a, b = (_frame(sensor, name, (0, 0, FZ), size, input_size, seed=k, noise=True)[0] for k in (1, 2))
        area = float(s0.meta["contact_area_mm2"])
        out[name] = {"kind": "indenter" if name in sim.INDENTERS else "object", "area_mm2": area,
                     "pad_share": area / pad_mm2, "energy_fz_per_n": ez, "energy_shear_per_n": float(np.mean(shear)),
                     "noise_energy": float(((a - b) ** 2).sum()) / 2}
    return out


def _predict(model, images):
    return np.concatenate([model.predict(images[i:i + 50]) for i in range(0, len(images), 50)])


def _fit(pred, force) -> dict:
    slope = [float(np.polyfit(force[:, k], pred[:, k], 1)[0]) for k in range(3)]
    return {"n": len(force), "slope": slope, "fz_offset_n": float(np.polyfit(force[:, 2], pred[:, 2], 1)[1]),
            "mae_n": np.abs(pred - force).mean(0).tolist()}


def readout(run, data: Path) -> dict:
    """Slopes and MAEs of one run on every unseen object and on each training indenter of the val split."""
    from ffjax import data as fdata
    from ffjax import inference

    model = inference.load(run)
    res = {}
    splits = [(p.name, p) for p in sorted((data / "unseen").iterdir()) if p.is_dir()] + [("val", data / "val")]
    from ffjax.sim.dataset import MINI_KEYS

    # Table II: the indenters on every GelSight unit x gel (the DIGIT's portrait frames need a calibrated model)
    splits += [(f"sensor/{k}", data / "sensor" / k) for k in MINI_KEYS if (data / "sensor" / k).is_dir()]
    for name, folder in splits:
        shards = [np.load(f) for f in sorted(folder.glob("shard_*.npz"))]
        images = np.concatenate([z["image"] for z in shards])
        force = np.concatenate([z["force"] for z in shards]).astype(np.float64)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # out-of-range flags: the slopes are what is measured here
            model.set_background(fdata.open_split(folder)[0]["background"])
            pred = _predict(model, images).astype(np.float64)
        if name != "val":
            res[name] = _fit(pred, force)
            continue
        shape = np.concatenate([z["shape"] for z in shards]).astype(str)
        for s in np.unique(shape):
            res[s] = _fit(pred[shape == s], force[shape == s])
    return res


def run_label(run) -> str:
    """'DINO RD, seed 0 (ablation-quick-e30)' for results/ablation-quick-e30/runs/dino_rd/seed0."""
    from experiments import style

    parts = Path(run).parts
    if len(parts) >= 4 and parts[-3] == "runs":
        seed = parts[-1].removeprefix("seed")
        return f"{style.name(parts[-2])}, seed {seed} ({parts[-4]})"
    return str(run)


def markdown(res: dict) -> str:
    sig, lines, sensor = res["signal"], [], res["sensor"]
    lines += [f"# Where the force is in the image, and how much of it is read (preset {res['preset']})", "",
              f"Centred noiseless presses at Fz = {FZ:g} N on {sensor}, preprocessed at the training size; image "
              f"energy (sum of squared changes) of +{STEP_N:g} N Fz and of a {STEP_N:g} N shear. Camera noise between "
              "two frames of one press: "
              f"{np.mean([v['noise_energy'] for v in sig.values()]):.2f} per frame. Commit `{res['commit'][:7]}`.", ""]
    runs = list(res.get("readout", {}))
    head = "| shape | kind | contact at 5 N (mm², share of pad) | energy per N Fz | per N shear |"
    sep = "|---|---|---|---|---|"
    for r in runs:
        head += f" {run_label(r)}: slope Fx / Fy / Fz, Fz offset (N) |"
        sep += "---|"
    lines += [head, sep]
    for name, v in sorted(sig.items(), key=lambda kv: (kv[1]["kind"], -kv[1]["energy_shear_per_n"])):
        row = (f"| {name} | {v['kind']} | {v['area_mm2']:.0f} ({100 * v['pad_share']:.0f}%) | "
               f"{v['energy_fz_per_n']:.3f} | {v['energy_shear_per_n']:.2f} |")
        for r in runs:
            f = res["readout"][r].get(name)
            row += (f" {f['slope'][0]:.2f} / {f['slope'][1]:.2f} / {f['slope'][2]:.2f}, {f['fz_offset_n']:+.2f} |"
                    if f else " |")
        lines.append(row)
    sensors = sorted({k for r in runs for k in res["readout"][r] if k.startswith("sensor/")})
    if sensors:
        lines += ["", f"How much of each axis is read on every unit x gel (Table II's presses; training: {sensor}):",
                  "", "| sensor |" + "".join(f" {run_label(r)}: slope Fx / Fy / Fz |" for r in runs),
                  "|---|" + "---|" * len(runs)]
        for k in sensors:
            cells = [res["readout"][r].get(k) for r in runs]
            lines.append(f"| {k[7:]} |" + "".join(f" {f['slope'][0]:.2f} / {f['slope'][1]:.2f} / {f['slope'][2]:.2f} |"
                                                  if f else " |" for f in cells))
    return "\n".join(lines) + "\n"


def plot(res: dict, path: Path) -> None:
    """The contact's share of the pad against the shear a model reads (its slope), one point per shape: a face
    that covers most of the view hides the contact's edge, where shear shows."""
    from experiments import style

    runs = list(res.get("readout", {}))
    fig, axes = style.figure(1, max(len(runs), 1), figsize=(5.5 * max(len(runs), 1), 4.2), squeeze=False,
                             layout="constrained")
    to_label = []  # placed once the layout is final (below)
    for ax, run in zip(axes[0], runs or [None]):
        names = [n for n in res["signal"] if run is None or n in res["readout"][run]]
        x = [100 * res["signal"][n]["pad_share"] for n in names]
        y = [np.mean(res["readout"][run][n]["slope"][:2]) if run else 0.0 for n in names]
        kinds = [res["signal"][n]["kind"] for n in names]
        for kind, marker in (("indenter", "o"), ("object", "s")):
            idx = [i for i, k in enumerate(kinds) if k == kind]
            ax.scatter([x[i] for i in idx], [y[i] for i in idx], marker=marker,
                       label="training indenter (val)" if kind == "indenter" else "Table I object")
        to_label.append((ax, x, y, [n.replace("_", " ") for n in names]))
        ax.axhline(1.0, color="0.5", ls=":", lw=1)
        ax.set(xlabel=f"contact area at Fz {FZ:g} N, centred (% of the pad)", ylabel="shear read (slope, mean Fx Fy)",
               title=run_label(run) if run else "signal only")
    fig.get_layout_engine().set(rect=(0, 0.04, 1, 0.96))  # the bottom strip for the provenance stamp
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right upper", fontsize=8)
    common.stamp(fig, res["preset"], res.get("seeds", []), res["commit"])
    fig.draw_without_rendering()  # runs the layout engine: the labels are placed in display space
    for args in to_label:
        common.label_points(*args)
    fig.savefig(path, dpi=120)


def main(argv=None) -> dict:
    ap = common.base_parser(__doc__, costs={"quick": "reads two trained runs"})
    ap.add_argument("--runs", nargs="*", default=[], help="training run folders (e.g. results/ablation-quick/runs/"
                    "dino_rd/seed0) whose read-out to measure")
    args = ap.parse_args(argv)
    cfg = common.config_from_args(ap, args)
    from ffjax import sim
    from ffjax.sim import dataset

    data = Path(args.data or dataset.default_root(cfg["preset"]))
    out = Path(args.out or common.ROOT / "results" / f"object_probe-{cfg['preset']}")
    out.mkdir(parents=True, exist_ok=True)
    size = tuple(cfg["data"]["render_size"])
    res = {"preset": cfg["preset"], "commit": common.git_commit(), "sensor": cfg["data"]["train_sensor"],
           "signal": signal(tuple(sim.INDENTERS) + tuple(sim.UNSEEN_OBJECTS), cfg["data"]["train_sensor"], size=size,
                            input_size=int(cfg["data"]["input_size"]))}
    if args.runs:
        res["seeds"] = sorted({int(Path(r).name[4:]) for r in args.runs if Path(r).name.startswith("seed")})
        res["readout"] = {str(r): readout(r, data) for r in args.runs}
    common.write_json(out / "results.json", res)
    common.write_text(out / "object_probe.md", markdown(res))
    plot(res, out / "object_probe.png")
    print(markdown(res))
    print(f"wrote {out}/results.json, object_probe.md, object_probe.png")
    return res


if __name__ == "__main__":
    import sys

    from ffjax import cli

    sys.exit(cli.run(main))
