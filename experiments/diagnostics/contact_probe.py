"""Where Fz is in the image, per shape: contact size against the pad, and how much a newton changes the frame.

    python -m experiments.diagnostics.contact_probe --preset {smoke,quick,full} [--per-shape N] [--out DIR]

For each training indenter and each unseen object (Table I), presses drawn as the dataset draws them
(on the training sensor, data.train_sensor; a sampling stream no split uses; Fz in the upper half of the range,
where the errors are largest) are rendered twice, at Fz and at Fz + dF with the same pose and no camera noise.
Per shape:
- contact area (mm^2) and its fraction of the pad; how often the contact reaches the pad's border (part of
  its outline, where a flat face shows its depth, is then outside the image);
- sensitivity: RMS change of the frame per newton (8-bit levels / N), at native resolution and at the
  training render size: what a model has to read Fz from;
- the share of that change within 1 mm of the contact outline (a flat face changes the image only at its
  edge: inside, the gel surface stays flat and its shading equals the background's).
Writes OUT/results.json, contact_probe.md and contact_probe.png.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from experiments import common
from experiments.tables import save_png
from ffjax import cli

STREAM = 2000  # sampling stream no dataset split (or experiments.stability) uses
DF = 1.0  # N: the Fz step of the sensitivity
EDGE_MM = 1.0
PER_SHAPE = {"smoke": 3, "quick": 24, "full": 48, "gpu": 48, "paper": 48}
NATIVE = {"smoke": (60, 80)}  # smoke: a quarter of the native size, to keep the tests fast


def change_per_newton(diff: np.ndarray, df: float = DF) -> float:
    """RMS of a frame difference per newton (8-bit levels / N): how much a network sees Fz move."""
    return float(np.sqrt(np.mean(diff**2)) / df)


def _edge_band(contact: np.ndarray, px: int) -> np.ndarray:
    import cv2

    k = np.ones((2 * px + 1, 2 * px + 1), np.uint8)
    c = contact.astype(np.uint8)
    return (cv2.dilate(c, k) - cv2.erode(c, k)).astype(bool)


def probe_shape(shape: str, cfg: dict, n: int, native) -> dict:
    """Per-press contact and sensitivity measurements for one shape (see the module doc)."""
    from ffjax import sim
    from ffjax.sim import dataset
    from ffjax.sim.press import body_heights

    sensor = sim.get_sensor(cfg["data"]["train_sensor"])
    train_size = dataset.render_size(sensor, cfg["data"]["render_size"])
    spec = dataset.SplitSpec("contact_probe", cfg["data"]["train_sensor"], (shape,), 4 * n, STREAM)
    p = dataset.sample_presses(spec, cfg)
    fz_max = float(cfg["data"]["fz_max"])
    keep = np.nonzero(p["force"][:, 2] >= fz_max / 2)[0][:n]
    fh, fw = sensor.fov_mm
    rows = []
    for i in keep:
        pose = (p["x_mm"][i], p["y_mm"][i], p["yaw_deg"][i], tuple(p["tilt_deg"][i]))
        f0 = p["force"][i].copy()
        f0[2] = min(f0[2], fz_max - DF)
        f1 = f0 + np.array([0.0, 0.0, DF])
        row = {}
        try:
            for name, size in (("native", native), ("train", train_size)):
                a = sim.press(shape, sensor, f0, *pose[:3], pose[3], 0, size, noise=False)
                b = sim.press(shape, sensor, f1, *pose[:3], pose[3], 0, size, noise=False)
                diff = b.image.astype(np.float32) - a.image.astype(np.float32)
                row[f"sens_{name}"] = change_per_newton(diff)
                if name == "native":
                    h = body_heights(sim.get_shape(shape), sensor, size, *pose)
                    pen, hmin = a.meta["penetration_mm"], float(h.min())
                    contact = h < hmin + pen
                    band = _edge_band(contact, max(1, int(round(EDGE_MM / a.meta["mm_per_px"]))))
                    e = np.sum(diff**2, axis=-1)
                    row["edge_share"] = float(e[band].sum() / max(e.sum(), 1e-9))
                    row["area_mm2"] = a.meta["contact_area_mm2"]
                    row["pad_fraction"] = row["area_mm2"] / (fh * fw)
                    row["at_border"] = bool(contact[0].any() or contact[-1].any() or contact[:, 0].any()
                                            or contact[:, -1].any())
                    row["penetration_mm"] = pen
                    row["fz"] = float(f0[2])
        except ValueError:  # a pose the simulator refuses (beyond what the gel takes)
            continue
        rows.append(row)
    return {"n": len(rows), **summarize_rows(rows)}


def summarize_rows(rows: list[dict]) -> dict:
    if not rows:
        return {}
    med = {k: float(np.median([r[k] for r in rows])) for k in ("area_mm2", "pad_fraction", "penetration_mm",
                                                                  "sens_native", "sens_train", "edge_share", "fz")}
    med["at_border"] = float(np.mean([r["at_border"] for r in rows]))
    med["area_p90_mm2"] = float(np.percentile([r["area_mm2"] for r in rows], 90))
    return med


def run(cfg: dict, out, per_shape: int | None = None, progress: bool = True) -> dict:
    from ffjax import sim

    out = Path(out).absolute()
    out.mkdir(parents=True, exist_ok=True)
    n = per_shape or PER_SHAPE[cfg["preset"]]
    native = NATIVE.get(cfg["preset"], sim.get_sensor(cfg["data"]["train_sensor"]).native_size)
    t0 = time.perf_counter()
    groups = {"indenter": sim.INDENTERS, "object": sim.UNSEEN_OBJECTS}
    shapes = {}
    for kind, names in groups.items():
        for s in tqdm(names, desc=f"contact probe: {kind}s", disable=not progress):
            shapes[s] = {"kind": kind, **probe_shape(s, cfg, n, tuple(native))}
    results = {"preset": cfg["preset"], "commit": common.git_commit(), "sensor": cfg["data"]["train_sensor"],
               "per_shape": n,
               "native_size": list(native), "train_size": list(cfg["data"]["render_size"]), "df_n": DF,
               "edge_mm": EDGE_MM, "shapes": shapes, "time_s": round(time.perf_counter() - t0, 1)}
    common.write_json(out / "results.json", results)
    common.write_text(out / "contact_probe.md", report_md(results))
    plot(results, out / "contact_probe.png")
    return results


def report_md(r: dict) -> str:
    header = ["shape", "kind", "contact area (mm^2, median / p90)", "pad fraction", "reaches pad border",
              "penetration (mm)", "image change per N, native", "per N, training size", "share at the outline"]
    rows = []
    for s, v in r["shapes"].items():
        if not v.get("n"):
            rows.append([s, v["kind"], "refused"] + ["–"] * 6)
            continue
        rows.append([s.replace("_", " "), v["kind"], f"{v['area_mm2']:.1f} / {v['area_p90_mm2']:.1f}",
                     f"{v['pad_fraction']:.2f}", f"{100 * v['at_border']:.0f}%", f"{v['penetration_mm']:.3f}",
                     f"{v['sens_native']:.2f}", f"{v['sens_train']:.2f}", f"{100 * v['edge_share']:.0f}%"])
    return (f"# Contact probe ({r['preset']}, {r['sensor']}, commit {r['commit'][:12]})\n\n"
            f"{r['per_shape']} presses per shape drawn as the dataset draws them, Fz >= half the range; each "
            f"rendered at Fz and Fz + {r['df_n']:g} N, same pose, no camera noise. Image change = RMS difference "
            f"of the two frames per newton (8-bit levels); native {r['native_size']}, training size "
            f"{r['train_size']}. Share at the outline: fraction of that change within {r['edge_mm']:g} mm of "
            "the contact's outline.\n\n" + common.md_table(header, rows))


def plot(r: dict, path: Path) -> Path:
    from matplotlib.ticker import FixedLocator, NullLocator, ScalarFormatter

    from experiments import style

    fig, axes = style.figure(1, 2, figsize=(12, 4.5))
    done = [v for v in r["shapes"].values() if v.get("n")]
    largest = max((v["area_mm2"] for v in done if v["kind"] == "indenter"), default=None)
    for v in r["shapes"].values():
        if not v.get("n"):
            continue
        style = {"indenter": ("o", "tab:blue"), "object": ("s", "tab:red")}[v["kind"]]
        for ax, y in zip(axes, ("sens_train", "edge_share")):
            val = v[y] * (100 if y == "edge_share" else 1)
            ax.scatter(v["area_mm2"], val, marker=style[0], color=style[1])
    for ax, label in zip(axes, ("image change per N at the training size (8-bit RMS)",
                                "share of the change within 1 mm of the outline (%)")):
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(FixedLocator([10, 20, 50, 100, 200, 500]))
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_locator(NullLocator())
        if largest:
            ax.axvline(largest, color="0.4", ls="--", lw=1, label="largest training contact")
        ax.set_xlabel("contact area at Fz >= half range (mm^2, median)")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0].scatter([], [], marker="o", color="tab:blue", label="training indenters")
    axes[0].scatter([], [], marker="s", color="tab:red", label="unseen objects (Table I)")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Where Fz shows: contact size against image change per newton ({r['sensor']})")
    common.stamp(fig, r["preset"], [], r["commit"])

    def labels():  # placed once the layout is final
        for ax, y in zip(axes, ("sens_train", "edge_share")):
            # the right panel's upper cluster (nearly all the change at the outline) would be a pile of labels
            shown = [(s, v) for s, v in r["shapes"].items()
                     if v.get("n") and (y == "sens_train" or v["edge_share"] < 0.95)]
            common.label_points(ax, [v["area_mm2"] for _, v in shown],
                                [v[y] * (100 if y == "edge_share" else 1) for _, v in shown],
                                [s.replace("_", " ") for s, _ in shown])

    return save_png(fig, path, then=labels)


def main(argv=None) -> dict:
    ap = common.base_parser(__doc__, costs={"quick": "simulator only, no training"})
    ap.add_argument("--per-shape", type=cli.integer(1), default=None, help="presses per shape (default by preset)")
    args = ap.parse_args(argv)
    cfg = common.config_from_args(ap, args)
    out = Path(args.out or common.ROOT / "results" / f"contact_probe-{args.preset}")
    results = run(cfg, out, args.per_shape, progress=not args.quiet)
    print(report_md(results))
    return results


if __name__ == "__main__":
    import sys

    sys.exit(cli.run(main))
