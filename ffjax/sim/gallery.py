"""Look at the simulator: `python -m ffjax.sim.gallery --out DIR [--size H W]`.

Writes PNG grids: shapes.png (every indenter and unseen object on mini-1 gel 1), sensors.png (one shape
on every sensor x gel), force_ramp.png (0..15 N), shear_sweep.png (Fx past the friction cap). Each frame
is shown with its background-subtracted view and its depth map, labelled with the applied force.
"""

from __future__ import annotations

import argparse
import os

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ffjax import cli
from ffjax.sim import INDENTERS, SENSOR_NAMES, UNSEEN_OBJECTS, get_sensor, press


def _nobg(s):
    """What the model sees: image - background + 127, clipped, contrast x3 for the eye."""
    return np.clip((s.image.astype(np.int16) - s.background.astype(np.int16)) * 3 + 127, 0, 255).astype(np.uint8)


def _label(name: str) -> str:
    """'sphere_big' -> 'big sphere', 'wooden_spatula' -> 'wooden spatula': names a reader knows."""
    words = name.split("_")
    return " ".join(words[::-1]) if words[0] == "sphere" and len(words) == 2 else " ".join(words)


def _grid(samples, titles, path, cols=5, dmax=None):
    """Three rows per band of `cols` samples: frame, background-subtracted (x3), depth."""
    bands = (len(samples) + cols - 1) // cols
    # constrained layout: tight_layout-free figures left a quarter of the page as blank margin. A Figure on its own
    # Agg canvas, outside pyplot: no global backend is chosen or switched (a notebook's inline plots stay inline)
    fig = Figure(figsize=(2.4 * cols + 1.2, 2.0 * 3 * bands), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(3 * bands, cols, squeeze=False)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
        for spine in ax.spines.values():
            spine.set_visible(False)
    for b in range(bands):  # which row is which
        for r, label in enumerate(("camera frame", "minus background (x3)", "depth (mm)")):
            axes[3 * b + r, 0].set_ylabel(label, fontsize=7)
    dmax = dmax or max(float(s.depth.max()) for s in samples) or 1.0
    for i, (s, t) in enumerate(zip(samples, titles)):
        b, c = divmod(i, cols)
        f = s.force
        axes[3 * b, c].imshow(s.image)
        axes[3 * b, c].set_title(f"{t}\nF=({f[0]:.1f},{f[1]:.1f},{f[2]:.1f}) N" + (" slip" if s.meta["slip"] else ""),
                                 fontsize=7)
        axes[3 * b + 1, c].imshow(_nobg(s))
        im = axes[3 * b + 2, c].imshow(s.depth, cmap="viridis", vmin=-0.1 * dmax, vmax=dmax)
        axes[3 * b + 2, c].set_title(f"depth max {s.depth.max():.2f} mm", fontsize=6)
    fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.25, label="depth (mm)")
    fig.savefig(path, dpi=80)
    return path


def make(out: str, size=None) -> list[str]:
    os.makedirs(out, exist_ok=True)
    m1 = get_sensor("mini-1", 1)
    paths = []
    names = list(INDENTERS) + list(UNSEEN_OBJECTS)
    samples = [press(n, m1, force=(0.0, 0.0, 8.0), yaw_deg=20.0, seed=i, size=size) for i, n in enumerate(names)]
    paths.append(_grid(samples, [_label(n) for n in names], os.path.join(out, "shapes.png")))

    sensors = [get_sensor(k) for k in SENSOR_NAMES]
    # portrait sensors (DIGIT) at their native size
    samples = [press("cross", s, force=(0.5, 0.0, 6.0), seed=i, size=size if s.native_size[0] < s.native_size[1]
                     else None) for i, s in enumerate(sensors)]
    paths.append(_grid(samples, [s.key for s in sensors], os.path.join(out, "sensors.png")))

    fz = [0.0, 0.5, 1.5, 3.0, 5.0, 7.5, 10.0, 12.5, 15.0, 15.0]
    samples = [press("sphere_small", m1, force=(0.0, 0.0, f), seed=i, size=size) for i, f in enumerate(fz[:-1])]
    samples.append(press("triple_cylinder", m1, force=(0.0, 0.0, 15.0), seed=9, size=size))
    paths.append(_grid(samples, ["small sphere"] * 9 + ["triple cylinder"], os.path.join(out, "force_ramp.png")))

    fx = [-4.0, -2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0, 4.0]
    samples = [press("sphere_big", m1, force=(f, 0.0, 3.0), seed=i, size=size) for i, f in enumerate(fx)]
    samples.append(press("sphere_big", get_sensor("mini-1", 3), force=(2.0, 1.0, 3.0), seed=10, size=size))
    paths.append(_grid(samples, ["big sphere, Fz 3 N"] * 9 + ["gel 3 (markers)"], os.path.join(out, "shear_sweep.png")))
    return paths


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m ffjax.sim.gallery", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="folder for the PNG grids")
    ap.add_argument("--size", type=cli.integer(2), nargs=2, default=None, metavar=("H", "W"),
                    help="render size (default native)")
    args = ap.parse_args(argv)
    cli.check_out(ap, args.out)
    for p in make(args.out, tuple(args.size) if args.size else None):
        print(p)


if __name__ == "__main__":
    import sys

    from ffjax import cli

    sys.exit(cli.run(main))
