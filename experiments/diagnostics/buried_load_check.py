"""Where a body in stick holds the gel: the simulator's stick solve against a finite-element model of the pressed layer.

    python -m experiments.diagnostics.buried_load_check [--smoke] [--out DIR]

A rigid cylinder (plane strain, so that an independent finite-element model stays small) presses gel 1's layer
to the approach a sphere of the same radius reaches at Fz = 2, 5 and 15 N in the simulator, then sticks and is
pushed sideways, its load unchanged. Three answers for the tangential stiffness and the antisymmetric surface
height (the gel piled up ahead of the body, sunk behind it) per unit tangential force:
- FE pressed (the reference, experiments.diagnostics.plane_strain_fe): the sideways step on the pressed mesh, the
  body holding the gel on its pit's walls;
- FE flat: the same on the undeformed mesh (the body holding the flat surface: what the simulator did before);
- the simulator's layer (ffjax.sim.elastic_layer, one row of a periodic grid, uniform along y): its normal solve
  at the FE's force, then the stick solve with the hold on the plane at the contact's mean depth (as the
  simulator now does) and on the surface (as before).
Accept band, fixed before the reference was run: the held model's antisymmetric height (peak and rms over
a + 2t outside the contact) within +-30% of FE pressed. Stiffness is reported, not banded.
Writes OUT/results.json, buried_load_check.md and buried_load_check.png.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from experiments.diagnostics import publish

RADII_MM = (4.0, 10.0)
FORCES_N = (2.0, 5.0, 15.0)  # the sphere's press in the simulator that sets each case's approach
BAND = 0.30


def _cylinder(radius: float):
    return lambda x: np.where(np.abs(x) < radius, radius - np.sqrt(np.maximum(radius**2 - x**2, 0.0)), 1e3)


def sphere_approach(radius: float, fz: float, sensor: str = "mini-1-gel1") -> float:
    """The approach (mm) of a smooth sphere of `radius` pressed centrally with fz in the simulator."""
    from ffjax import sim

    return float(sim.press(sim.shapes.sphere(radius), sensor, (0.0, 0.0, fz), noise=False, size=(60, 80))
                 .meta["penetration_mm"])


def _antisymmetric(x: np.ndarray, w: np.ndarray, at: np.ndarray) -> np.ndarray:
    return (np.interp(at, x, w) - np.interp(-at, x, w)) / 2


def case(radius: float, delta: float, thickness: float, shear_mpa: float, fine_dx: float, nz: int) -> dict:
    """One cylinder pressed by delta: FE (pressed and flat) and the layer's solve (held and surface)."""
    from experiments.diagnostics import plane_strain_fe as fe
    from ffjax.sim import elastic_layer as el
    from ffjax.sim.mechanics import HOLD_STEP_MM

    half = 9 * thickness
    m = fe.mesh(thickness, half, min(8.0, half / 2), fine_dx, nz)
    heights = _cylinder(radius)
    pressed = fe.press(m, shear_mpa, heights, delta)
    fe_runs = {"pressed": fe.stick(m, shear_mpa, pressed, True), "flat": fe.stick(m, shear_mpa, pressed, False)}
    rows, cols = 2, int(round(2 * half / fine_dx))
    layer = el.Layer((rows, cols), fine_dx, thickness, shear_mpa)
    x = (np.arange(cols) - cols / 2) * fine_dx
    h = np.where(np.broadcast_to(heights(x), (rows, cols)) < 1e2, np.broadcast_to(heights(x), (rows, cols)), el.FAR)
    normal = el.solve_contact(h, layer, pressed["force"] * rows * fine_dx)
    on = normal["contact"]
    a = float(np.abs(x[on[0]]).max()) + fine_dx / 2
    hold = float(np.round((normal["delta"] - h)[on].mean() / HOLD_STEP_MM) * HOLD_STEP_MM)
    at = x[(x > a + fine_dx) & (x < a + 2 * thickness)]
    out = {"radius_mm": radius, "delta_mm": delta, "fe_force_n_per_mm": pressed["force"],
           "model_delta_mm": float(normal["delta"]), "contact_half_mm": a,
           "fe_contact_half_mm": float(np.abs(m.x[pressed["contact"]]).max()), "hold_depth_mm": hold,
           "x_mm": at.tolist(), "stiffness": {}, "height_per_n": {}}
    for name, r in fe_runs.items():
        out["stiffness"][f"FE {name}"] = r["force"]
        out["height_per_n"][f"FE {name}"] = (_antisymmetric(r["x"], r["w"], at) / r["force"]).tolist()
    for name, depth in (("held", hold), ("surface", 0.0)):
        st = el.solve_stick(on, layer, depth=depth)
        k = float(st["K"][0, 0]) / (rows * fine_dx)
        out["stiffness"][f"model {name}"] = k
        out["height_per_n"][f"model {name}"] = (_antisymmetric(x, st["fields"][0][2][0], at) / k).tolist()
    ref = np.asarray(out["height_per_n"]["FE pressed"])
    out["ratios"] = {}
    for name in ("model held", "model surface", "FE flat"):
        v = np.asarray(out["height_per_n"][name])
        out["ratios"][name] = {"peak": float(np.abs(v).max() / np.abs(ref).max()),
                               "rms": float(np.sqrt((v**2).mean() / (ref**2).mean())),
                               "stiffness": out["stiffness"][name] / out["stiffness"]["FE pressed"]}
    r = out["ratios"]["model held"]
    out["within_band"] = bool(abs(r["peak"] - 1) <= BAND and abs(r["rms"] - 1) <= BAND)
    return out


def run(smoke: bool = False) -> dict:
    from ffjax.sim.sensors import get_sensor

    gel = get_sensor("mini-1-gel1").gel
    radii, forces = (RADII_MM[:1], FORCES_N[1:2]) if smoke else (RADII_MM, FORCES_N)
    fine_dx, nz = (0.1, 16) if smoke else (0.05, 36)
    cases = []
    for radius in radii:
        for fz in forces:
            c = case(radius, sphere_approach(radius, fz), gel.thickness_mm, gel.shear_mpa, fine_dx, nz)
            c["sphere_fz_n"] = fz
            cases.append(c)
    return {"experiment": "buried_load_check", "thickness_mm": gel.thickness_mm, "shear_mpa": gel.shear_mpa,
            "band": BAND, "mesh": {"fine_dx_mm": fine_dx, "rows": nz}, "cases": cases,
            "all_within_band": all(c["within_band"] for c in cases)}


def report(res: dict) -> str:
    lines = [f"# Where a body in stick holds the gel: the layer's solve against FE (commit `{res['commit'][:7]}`)",
             "", f"Gel 1 (t = {res['thickness_mm']} mm, G = {res['shear_mpa']} MPa), plane strain; FE mesh "
             f"{res['mesh']['fine_dx_mm']} mm at the contact, {res['mesh']['rows']} rows. Ratios to FE pressed "
             f"(accept band for the held model's height: +-{res['band']:.0%}).", "",
             "| cylinder R | approach (sphere at Fz) | contact half FE / model | hold depth | stiffness N/mm/mm "
             "FE pressed / FE flat / held / surface | height per N: held peak, rms | surface peak, rms | "
             "FE flat peak | in band |", "|---|---|---|---|---|---|---|---|---|"]
    for c in res["cases"]:
        s, r = c["stiffness"], c["ratios"]
        lines.append(
            f"| {c['radius_mm']:g} mm | {c['delta_mm']:.2f} mm ({c['sphere_fz_n']:g} N) | "
            f"{c['fe_contact_half_mm']:.2f} / {c['contact_half_mm']:.2f} mm | {c['hold_depth_mm']:.2f} mm | "
            f"{s['FE pressed']:.3f} / {s['FE flat']:.3f} / {s['model held']:.3f} / {s['model surface']:.3f} | "
            f"{r['model held']['peak']:.2f}, {r['model held']['rms']:.2f} | "
            f"{r['model surface']['peak']:.2f}, {r['model surface']['rms']:.2f} | {r['FE flat']['peak']:.2f} | "
            f"{'yes' if c['within_band'] else 'NO'} |")
    return "\n".join(lines) + "\n"


def plot(res: dict, path: Path) -> Path:
    from experiments import common, style
    from experiments.tables import save_png

    cases = res["cases"]
    cols = len({c["sphere_fz_n"] for c in cases})
    rows = len(cases) // cols
    fig, axes = style.figure(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    styles = {"FE pressed": ("k", "-"), "FE flat": ("0.55", "--"), "model held": ("tab:orange", "-"),
              "model surface": ("tab:blue", ":")}
    for ax, c in zip(axes.ravel(), cases):
        x = np.asarray(c["x_mm"]) - c["contact_half_mm"]
        for name, (colour, ls) in styles.items():
            ax.plot(x, -1e3 * np.asarray(c["height_per_n"][name]), ls, color=colour, lw=1.4, label=name)
        ax.set_title(f"R {c['radius_mm']:g} mm, approach {c['delta_mm']:.2f} mm (sphere at {c['sphere_fz_n']:g} N)",
                     fontsize=9)
        ax.set_xlabel("distance ahead of the contact edge (mm)")
        ax.set_ylabel("rise ahead per tangential force\n(um per N/mm)")
    axes[0, 0].legend(fontsize=7)
    common.stamp(fig, "plane strain", [], res["commit"])
    return save_png(fig, Path(path))


def main(argv=None) -> dict:
    from experiments import common
    from ffjax import cli

    ap = argparse.ArgumentParser(prog=common.prog(), description=common.description(__doc__))
    ap.add_argument("--smoke", action="store_true", help="one case on a coarse mesh (seconds)")
    ap.add_argument("--out", default=None, help="results folder (default: results/buried_load_check)")
    args = ap.parse_args(argv)
    out = cli.check_out(ap, Path(args.out or common.ROOT / "results" / "buried_load_check"))
    res = {"commit": common.git_commit(), **run(args.smoke)}
    return publish(out, "buried_load_check", res, report, plot)


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
