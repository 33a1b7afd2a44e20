"""The simulator's gel against the exact small-strain elastic layer, shape by shape.

    python -m experiments.diagnostics.layer_check --preset {smoke,quick,full} [--out DIR]

Every shape is pressed at the pad centre, untilted, on data.train_sensor, at Fz = F and F + 1 N, twice: by
`ffjax.sim.press` (what makes the data: the layer solved on its ~0.25 mm grid, with local large-strain
stiffening, rendered with the body's detail; until issue 13, independent neo-Hookean columns with a
smoothing kernel) and by `ffjax.sim.elastic_layer` alone (small-strain, incompressible, bonded to the
glass, frictionless: the textbook problem, solved on the finer check grid with a margin of several
thicknesses around the pad). Per shape and Fz:
- approach delta and contact area: the stiffness each model gives;
- the pressure's shape in the reference (edge / centre ratio: > 1 edge-loaded, < 1 domed; the columns
  give ~1 for a flat face);
- the free surface around the contact: mean depression in a 1 mm band outside it and the largest bulge,
  both relative to delta;
- the image each surface makes through the same optics (mini-1's LEDs, no noise): RMS change per newton
  at the grid and at the training size. That is what a network reads Fz from, so it is the number that says
  whether the simulator keeps or erases the cue. Expected differences now: the stiffening at large strain
  (small, sharp bodies at high load) and the coarser solve grid.
Writes OUT/results.json, layer_check.md and layer_check.png (cross-sections and the per-shape ratios).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from experiments import common
from experiments.diagnostics.contact_probe import DF, change_per_newton
from experiments.tables import save_png

FORCES = (4.0, 8.0)  # N: mid-range presses; the image change is measured from each to +DF
MARGIN_T = 3.0  # reference grid margin around the pad, in gel thicknesses
BAND_MM = 1.0
FLAT_SIDES = (3.0, 5.0, 7.0, 10.0, 14.0, 18.0)
# smoke: one small and one large flat face and a sphere on a quarter-native grid, to keep the tests fast
SMOKE = {"flat": (3.0, 14.0), "indenters": ("sphere_big",), "objects": (), "grid_div": 4, "forces": (4.0,)}
PROFILE_SHAPES = ("flat_7mm", "flat_18mm", "sphere_big", "wrench")


def _shapes(preset: str) -> dict:
    from ffjax import sim

    if preset == "smoke":
        flats, indenters, objects = SMOKE["flat"], SMOKE["indenters"], SMOKE["objects"]
    else:
        flats, indenters, objects = FLAT_SIDES, sim.INDENTERS, sim.UNSEEN_OBJECTS
    out = {f"flat_{s:g}mm": ("flat punch", sim.shapes.flat_punch(s)) for s in flats}
    out |= {n: ("indenter", sim.get_shape(n)) for n in indenters}
    out |= {n: ("object", sim.get_shape(n)) for n in objects}
    return out


def _band_outside(contact: np.ndarray, px: int) -> np.ndarray:
    import cv2

    k = np.ones((2 * px + 1, 2 * px + 1), np.uint8)
    return cv2.dilate(contact.astype(np.uint8), k).astype(bool) & ~contact


def _filled(mask: np.ndarray, px: int) -> np.ndarray:
    """The mask closed over gaps of ~2 px + 1 pixels (a texture's valleys), holes filled."""
    import cv2

    k = np.ones((2 * px + 1, 2 * px + 1), np.uint8)
    closed = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_CLOSE, k)
    cnt, _ = cv2.findContours(closed, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return cv2.drawContours(np.zeros_like(closed), cnt, -1, 1, cv2.FILLED).astype(bool)


def _edge_over_centre(p: np.ndarray, contact: np.ndarray, inner: np.ndarray, edge: np.ndarray) -> float | None:
    """Load per area near the outline over load per area inside; None where the inside is not loaded (a
    ring's hole, a face too small to have an inside), where the ratio would describe a gap, not a pressure."""
    if not inner.any() or contact[inner].mean() < 0.1:
        return None
    return float(p[edge].mean() / p[inner].mean())


def _surface_stats(depth: np.ndarray, contact: np.ndarray, delta: float, band_px: int) -> dict:
    band = _band_outside(contact, band_px)
    return {"sink_band": float(depth[band].mean() / delta) if band.any() else float("nan"),
            "bulge": float(max(0.0, -depth[~contact].min()) / delta) if (~contact).any() else 0.0}


def _frames(sensor, depth: np.ndarray, sizes) -> list[np.ndarray]:
    import cv2

    from ffjax.sim import optics

    out = []
    for size in sizes:
        d = depth if tuple(size) == depth.shape else cv2.resize(depth, (size[1], size[0]),
                                                                 interpolation=cv2.INTER_AREA)
        out.append(optics.render(sensor, tuple(size), d.astype(np.float32), None, None).astype(np.float32))
    return out


def check_shape(shape, sensor, grid, train_size, forces) -> dict:
    """Simulator and reference for one shape at each Fz (see the module doc)."""
    from ffjax import sim
    from ffjax.sim import elastic_layer, mechanics
    from ffjax.sim.press import SKIN_MM, body_heights

    gel = sensor.gel
    dy, dx = sensor.mm_per_px(grid)
    mpp = (dx + dy) / 2
    m = int(round(MARGIN_T * gel.thickness_mm / mpp))
    h_pad = body_heights(shape, sensor, grid, 0.0, 0.0, 0.0, (0.0, 0.0)).astype(np.float64)
    h_box = np.full((grid[0] + 2 * m, grid[1] + 2 * m), elastic_layer.FAR)
    h_box[m:-m, m:-m] = np.where(h_pad < elastic_layer.FAR / 2, h_pad, elastic_layer.FAR)
    layer = elastic_layer.Layer(h_box.shape, mpp, gel.thickness_mm, gel.shear_mpa)
    band_px = max(1, int(round(BAND_MM / mpp)))
    sizes = (tuple(grid), tuple(train_size))
    rows = []
    for fz in forces:
        row = {"fz": fz}
        frames = {}
        for tag, f in (("a", fz), ("b", fz + DF)):
            s = sim.press(shape, sensor, (0.0, 0.0, f), 0.0, 0.0, 0.0, (0.0, 0.0), 0, grid, noise=False)
            ref = elastic_layer.solve_contact(h_box, layer, f)
            u = ref["u"][m:-m, m:-m]
            ref_depth = mechanics.smooth(u.astype(np.float32), SKIN_MM / mpp)  # the same pigment skin
            frames[tag] = (_frames(sensor, s.depth, sizes), _frames(sensor, ref_depth, sizes))
            if tag == "a":
                contact_sim = h_pad < h_pad.min() + s.meta["penetration_mm"]
                contact_ref = ref["contact"][m:-m, m:-m]
                p = ref["p"][m:-m, m:-m]
                # a textured face touches at its peaks: regions come from the filled outline and the ratio
                # is load per face area (valleys count as zero), so it describes the face, not the texture
                face = _filled(contact_ref, band_px)
                inner = face & ~_band_outside(~face, band_px)  # > 1 mm inside the outline
                edge = face & ~inner
                row |= {"delta_sim": s.meta["penetration_mm"], "delta_ref": ref["delta"],
                        "area_sim": s.meta["contact_area_mm2"], "area_ref": float(contact_ref.sum() * mpp**2),
                        "p_edge_over_centre": _edge_over_centre(p, contact_ref, inner, edge),
                        "ref_iterations": ref["iterations"],
                        **{f"{k}_sim": v for k, v in _surface_stats(s.depth, contact_sim, s.meta["penetration_mm"],
                                                                   band_px).items()},
                        **{f"{k}_ref": v for k, v in _surface_stats(u, contact_ref, ref["delta"], band_px).items()}}
                row["profile_sim"] = np.round(s.depth[grid[0] // 2], 5).tolist()
                row["profile_ref"] = np.round(u[grid[0] // 2], 5).tolist()
        for i, size_tag in enumerate(("grid", "train")):
            for j, model in enumerate(("sim", "ref")):
                row[f"sens_{size_tag}_{model}"] = change_per_newton(frames["b"][j][i] - frames["a"][j][i])
        rows.append(row)
    return {"rows": rows, "x_mm": ((np.arange(grid[1]) - (grid[1] - 1) / 2) * dx).tolist()}


def run(cfg: dict, out, progress: bool = True) -> dict:
    from ffjax import sim
    from ffjax.sim import dataset

    out = Path(out).absolute()
    out.mkdir(parents=True, exist_ok=True)
    preset = cfg["preset"]
    sensor = sim.get_sensor(cfg["data"]["train_sensor"])
    div = SMOKE["grid_div"] if preset == "smoke" else 2
    grid = (sensor.native_size[0] // div, sensor.native_size[1] // div)
    train_size = dataset.render_size(sensor, cfg["data"]["render_size"])
    forces = SMOKE["forces"] if preset == "smoke" else FORCES
    t0 = time.perf_counter()
    shapes = {}
    for name, (kind, shape) in tqdm(_shapes(preset).items(), desc="layer check", disable=not progress):
        shapes[name] = {"kind": kind, **check_shape(shape, sensor, grid, train_size, forces)}
    g = sensor.gel
    results = {"preset": preset, "commit": common.git_commit(), "sensor": cfg["data"]["train_sensor"],
               "grid": list(grid),
               "train_size": list(train_size), "forces": list(forces), "df_n": DF, "band_mm": BAND_MM,
               "gel": {"thickness_mm": g.thickness_mm, "young_mpa": g.young_mpa, "shear_mpa": g.shear_mpa},
               "margin_thicknesses": MARGIN_T, "shapes": shapes, "time_s": round(time.perf_counter() - t0, 1)}
    common.write_json(out / "results.json", results)
    common.write_text(out / "layer_check.md", report_md(results))
    plot(results, out / "layer_check.png")
    return results


def report_md(r: dict) -> str:
    header = ["shape", "kind", "Fz (N)", "approach sim / ref (mm)", "contact sim / ref (mm^2)",
              "ref pressure edge / centre", "band sink sim / ref (x delta)", "bulge sim / ref (x delta)",
              "image change per N, grid: sim / ref", "training size: sim / ref"]
    rows = []
    for s, v in r["shapes"].items():
        for w in v["rows"]:
            pe = w["p_edge_over_centre"]
            rows.append([s.replace("_", " "), v["kind"], f"{w['fz']:g}", f"{w['delta_sim']:.3f} / {w['delta_ref']:.3f}",
                         f"{w['area_sim']:.0f} / {w['area_ref']:.0f}", "–" if pe is None else f"{pe:.2f}",
                         f"{w['sink_band_sim']:.2f} / {w['sink_band_ref']:.2f}",
                         f"{w['bulge_sim']:.3f} / {w['bulge_ref']:.3f}",
                         f"{w['sens_grid_sim']:.2f} / {w['sens_grid_ref']:.2f}",
                         f"{w['sens_train_sim']:.2f} / {w['sens_train_ref']:.2f}"])
    g = r["gel"]
    return (f"# Simulator against the exact elastic layer ({r['preset']}, {r['sensor']}, commit {r['commit'][:12]})\n\n"
            f"Gel {g['thickness_mm']} mm, E {g['young_mpa']} MPa, G {g['shear_mpa']} MPa. Centre presses, untilted; "
            f"grid {r['grid']} (reference margin {r['margin_thicknesses']:g} thicknesses), images at the grid and "
            f"at the training size {r['train_size']}. sim = ffjax.sim.press (the layer on its solve grid with "
            "large-strain stiffening); ref = ffjax.sim.elastic_layer (incompressible bonded layer, small strain, "
            "frictionless). Band sink: mean "
            f"surface depression within {r['band_mm']:g} mm outside the contact over the approach; bulge: "
            "highest rise outside the contact over the approach. Image change: RMS difference of the noiseless "
            f"frames at Fz and Fz + {r['df_n']:g} N, per newton (8-bit levels).\n\n" + common.md_table(header, rows))


def plot(r: dict, path: Path) -> Path:
    from experiments import style

    shown = [s for s in PROFILE_SHAPES if s in r["shapes"]] or list(r["shapes"])[:2]
    fig, axes = style.figure(2, max(len(shown), 2), figsize=(4 * max(len(shown), 2), 7.5), squeeze=False)
    for ax, s in zip(axes[0], shown):
        v = r["shapes"][s]
        w = v["rows"][-1]
        ax.plot(v["x_mm"], -np.asarray(w["profile_sim"]), label="simulator", color="tab:blue")
        ax.plot(v["x_mm"], -np.asarray(w["profile_ref"]), label="elastic layer (exact, small strain)",
                color="tab:orange", ls="--")
        ax.set_title(f"{s.replace('_', ' ')}, Fz {w['fz']:g} N", fontsize=10)
        ax.set_xlabel("x across the pad centre (mm)")
        ax.set_ylabel("gel surface height (mm)")
        ax.grid(True, alpha=0.3)
    axes[0][len(shown) - 1].legend(fontsize=8, loc="best")  # the wrench panel has a free corner in every preset
    for ax in axes[0][len(shown):]:
        ax.axis("off")
    names = list(r["shapes"])
    last = [r["shapes"][s]["rows"][-1] for s in names]
    colours = {"flat punch": "tab:green", "indenter": "tab:blue", "object": "tab:red"}
    cols = [colours[r["shapes"][s]["kind"]] for s in names]
    area = [w["area_ref"] for w in last]
    ax = axes[1][0]
    ax.scatter(area, [w["delta_sim"] / w["delta_ref"] for w in last], c=cols)
    ax.axhline(1.0, color="0.4", lw=1)
    ax.set_xlabel("contact area, reference (mm^2)")
    ax.set_ylabel("approach: simulator / reference")
    ax.set_title(f"stiffness (Fz {last[0]['fz']:g} N)", fontsize=10)
    ncol = len(axes[1])
    for a in axes[1][1:]:
        a.remove()
    # the sensitivity panel spans the rest of the row: 26 named points do not fit in one column
    ax = fig.add_subplot(2, ncol, (ncol + 2, 2 * ncol))
    sim_s = [w["sens_train_sim"] for w in last]
    ref_s = [w["sens_train_ref"] for w in last]
    ax.scatter(ref_s, sim_s, c=cols)
    lim = max(max(sim_s), max(ref_s)) * 1.1
    ax.plot([0, lim], [0, lim], color="0.4", lw=1)
    ax.set_xlabel("image change per N, elastic layer (8-bit RMS)")
    ax.set_ylabel("image change per N, simulator")
    ax.set_title("what a network reads Fz from (training size)", fontsize=10)
    for k, c in colours.items():
        ax.scatter([], [], color=c, label=k)
    ax.legend(fontsize=8)
    for a in (axes[1][0], ax):
        a.grid(True, alpha=0.3)
    fig.suptitle(f"Simulator against the exact incompressible elastic layer ({r['sensor']}, {r['preset']})")
    common.stamp(fig, r["preset"], [], r["commit"])  # simulator only: no seeds
    return save_png(fig, path, then=lambda: common.label_points(ax, ref_s, sim_s, [s.replace("_", " ") for s in names]))


def main(argv=None) -> dict:
    ap = common.base_parser(__doc__, costs={"quick": "simulator only, no training"})
    args = ap.parse_args(argv)
    cfg = common.config_from_args(ap, args)
    out = Path(args.out or common.ROOT / "results" / f"layer_check-{args.preset}")
    results = run(cfg, out, progress=not args.quiet)
    print(report_md(results))
    return results


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
