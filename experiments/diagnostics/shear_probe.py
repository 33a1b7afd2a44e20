"""Is shear visible, along which axis, and does a trained backbone carry it? Physics checks plus ridge probes.

    python -m experiments.diagnostics.shear_probe [--out DIR] [--data DATA_DIR] [--runs RUN_DIR ...]

1. Physics (no data needed): matched noiseless presses that differ only in Fx vs Fy (same magnitude), put
   through the model's preprocessing (background subtraction, pad to square, resize): the image-difference
   energy per axis, split into its two sources (pigment/markers carried by the stick displacement; shading of
   the shear bulge), with the LED ring rotated by 90 degrees and with four equal LEDs as controls; and the
   sign/axis convention (+Fx moves the gel towards +x = columns, +Fy towards +y = rows, down).
2. With --data (a dataset folder): per-axis ridge probes on the downsampled preprocessed train images, scored
   on val. With --runs (training run folders): the same probe on each run's backbone features, beside the
   run's own regressor. Writes DIR/results.json and DIR/report.md.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys
from pathlib import Path
from unittest import mock

import cv2
import numpy as np

# a compact round contact for the sign check: the big sphere (40 mm) presses a wide, nearly flat patch
SHAPES = ("sphere_10mm", "sphere_small", "cylinder", "cube", "ring")
FZ, FT = 5.0, 1.0  # N: matched presses differ only in the direction of a 1 N shear


def _modules():
    import ffjax.sim.press  # noqa: F401  (the module, not the function sim.press re-exports)

    return sys.modules["ffjax.sim.press"], sys.modules["ffjax.sim.mechanics"]


@contextlib.contextmanager
def only(source: str):
    """Render shear through one source only: "pigment" (no bulge) or "bulge" (pigment not moved)."""
    press_mod, mech = _modules()
    render = press_mod.optics.render
    if source == "pigment":
        with mock.patch.object(mech, "shear_bulge", lambda sh: np.zeros_like(sh.bulge)):
            yield
    elif source == "bulge":
        def no_pigment(sensor, size, depth, disp=None, seed=0):
            return render(sensor, size, depth, None, seed)

        with mock.patch.object(press_mod.optics, "render", no_pigment):
            yield
    else:
        yield


def lk_shift(a0: np.ndarray, a1: np.ndarray) -> np.ndarray:
    """Global translation (sx, sy) in px with a1(p) ~ a0(p - s): least squares on the image gradients."""
    gy, gx = np.gradient(a0, axis=(0, 1))
    return np.linalg.lstsq(np.stack([gx.ravel(), gy.ravel()], 1), -(a1 - a0).ravel(), rcond=None)[0]


def _inputs(sensor, shape, force, size, input_size):
    """Preprocessed noiseless frame and the crop that drops the square padding."""
    from ffjax import sim
    from ffjax.data import preprocess
    from ffjax.sim.shapes import sphere

    body = sphere(10.0) if shape == "sphere_10mm" else shape
    s = sim.press(body, sensor, force, size=size, noise=False)
    x = preprocess.to_unit(s.image, s.background, input_size)
    h, w = size
    pad = abs(w - h) * input_size // max(h, w) // 2
    crop = (slice(pad, input_size - pad), slice(None)) if h < w else (slice(None), slice(pad, input_size - pad))
    return x, crop, s


def matched(sensor, shape, size=(48, 64), input_size=64) -> dict:
    """Energy of the image change for +-Fx vs +-Fy and the image shift each one causes."""
    from ffjax.sim.dataset import render_size

    sens = _sensor(sensor)
    size = render_size(sens, size)
    x0, crop, _ = _inputs(sens, shape, (0, 0, FZ), size, input_size)
    out = {}
    for name, f in (("+x", (FT, 0)), ("-x", (-FT, 0)), ("+y", (0, FT)), ("-y", (0, -FT))):
        x1, _, s = _inputs(sens, shape, (*f, FZ), size, input_size)
        out[name] = {"energy": float(((x1 - x0) ** 2).sum()), "shift_px": lk_shift(x0[crop], x1[crop]).tolist(),
                     "label": [float(v) for v in s.force[:2]]}
    ex = (out["+x"]["energy"] + out["-x"]["energy"]) / 2
    ey = (out["+y"]["energy"] + out["-y"]["energy"]) / 2
    return {"energy_fx": ex, "energy_fy": ey, "ratio_y_over_x": ey / max(ex, 1e-12), "presses": out}


def _sensor(s):
    from ffjax import sim

    return sim.get_sensor(s) if isinstance(s, str) else s


def led_variant(sensor_key: str, kind: str):
    from ffjax.sim import sensors

    s = _sensor(sensor_key)
    if kind == "rot90":
        return dataclasses.replace(s, leds=tuple(dataclasses.replace(led, azimuth_deg=led.azimuth_deg + 90)
                                                 for led in s.leds))
    if kind == "equal4":
        return dataclasses.replace(s, leds=tuple(sensors.LED(a, 6.0, (0.8, 0.8, 0.8), 1.0) for a in (0, 90, 180, 270)))
    return s


def physics() -> dict:
    rows = []
    cases = [("mini-1-gel1", "as built", "all"), ("mini-1-gel1", "as built", "pigment"),
             ("mini-1-gel1", "as built", "bulge"), ("mini-1-gel1", "rot90", "all"), ("mini-1-gel1", "equal4", "all"),
             ("mini-1-gel3", "as built", "all"), ("digit", "as built", "all")]
    for key, leds, source in cases:
        with only(source):
            for shape in SHAPES:
                r = matched(led_variant(key, leds), shape)
                rows.append({"sensor": key, "leds": leds, "source": source, "shape": shape, **r})
    # native resolution: the pipeline's downsampling is not the cause
    r = matched("mini-1-gel1", "sphere_10mm", size=(240, 320), input_size=320)
    rows.append({"sensor": "mini-1-gel1", "leds": "as built (native 240x320)", "source": "all", "shape": "sphere_10mm",
                 **r})
    # the global shift estimate is meaningful for the 10 mm sphere (one smooth blob, the gel dragged around
    # it); the imprint of a sharp body stays where the body is and outweighs the drag, and flat faces and rings
    # shade their edges in ways a single translation does not describe, so the check uses that sphere
    return {"rows": rows, "sign_ok": all(_sign_ok(r["presses"]) for r in rows
                                         if r["source"] == "all" and r["shape"] == "sphere_10mm"),
            "resolution": resolution()}


RESOLUTIONS = ((48, 64), (120, 160), (240, 320))


def resolution() -> list:
    """The pigment's share of a 1 N shear's image change against the render size (the pigment's grain is finer
    than a 48x64 pixel, so its share grows with resolution): gels 1 and 2 of unit 1, the 10 mm sphere, each source
    alone, the input at the render's width."""
    rows = []
    for key in ("mini-1-gel1", "mini-1-gel2"):
        for size in RESOLUTIONS:
            e = {}
            for source in ("pigment", "bulge"):
                with only(source):
                    r = matched(key, "sphere_10mm", size=size, input_size=size[1])
                e[source] = (r["energy_fx"] + r["energy_fy"]) / 2
            rows.append({"sensor": key, "size": list(size), "energy_pigment": e["pigment"],
                         "energy_bulge": e["bulge"], "pigment_share": e["pigment"] / max(sum(e.values()), 1e-12)})
    return rows


def _sign_ok(p: dict) -> bool:
    """+Fx label moves the image towards +x, +Fy towards +y (and the minus presses the other way)."""
    return (p["+x"]["shift_px"][0] > 0 > p["-x"]["shift_px"][0]
            and p["+y"]["shift_px"][1] > 0 > p["-y"]["shift_px"][1]
            and p["+x"]["label"][0] > 0 and p["+y"]["label"][1] > 0)


def ridge(xtr, ytr, xva, yva, alphas=(1e-2, 1e-1, 1, 10, 100, 1e3, 1e4)) -> dict:
    """Per-axis val MAE (N) of ridge on standardized inputs, at the alpha best for the shear axes."""
    mu, sd = xtr.mean(0), xtr.std(0) + 1e-6
    a, b = (xtr - mu) / sd, (xva - mu) / sd
    ym = ytr.mean(0)
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    uy = u.T @ (ytr - ym)
    best = None
    for al in alphas:
        mae = np.abs(b @ (vt.T @ ((s / (s**2 + al))[:, None] * uy)) + ym - yva).mean(0)
        if best is None or mae[:2].mean() < best[1][:2].mean():
            best = (al, mae)
    return {"alpha": best[0], "mae_n": best[1].round(4).tolist()}


def probes(data_root: Path, runs: list[Path]) -> dict:
    from experiments import common
    from ffjax import calibrate, data, store
    from ffjax.sim import dataset

    if runs:  # the runs' own input statistics and size (the probes standardize anyway)
        stats = store.describe(runs[0]).stats
    else:  # the input size of the preset the dataset was made with (its config.json holds only what sim reads)
        made = common.read_json(data_root / "manifest.json") or {}
        if "data_config" not in made:
            raise FileNotFoundError(f"{data_root / 'manifest.json'}: no finished dataset there (python -m "
                                    "ffjax.simulate)")
        stats = data.Stats(mean=(0.0,) * 3, std=(1.0,) * 3, depth_min=0.0, depth_max=1.0, force_min=(0.0,) * 3,
                           force_max=(1.0,) * 3, input_size=int(made["data_config"]["input_size"]))
    size = int(stats.input_size)
    tr = data.load_arrays(data.open_split(dataset.split_dir(data_root, "train")), stats, size)
    va = data.load_arrays(data.open_split(dataset.split_dir(data_root, "val")), stats, size)
    ytr, yva = tr["force"], va["force"]
    out = {"constant_mae_n": np.abs(yva - ytr.mean(0)).mean(0).round(4).tolist(), "pixels": {}, "features": {}}
    def down(a, r):
        return np.stack([cv2.resize(x, (r, r), interpolation=cv2.INTER_AREA) for x in a]).reshape(len(a), -1)

    for r in (8, 16, 32):
        out["pixels"][f"{r}x{r}"] = ridge(down(tr["image"], r), ytr, down(va["image"], r), yva)
    for run in runs:
        trained = store.load(run)
        cfg, spec, variables, model = trained.cfg, trained.spec, trained.variables, trained.build()
        ftr = calibrate.features(model, variables, tr["image"])
        fva = calibrate.features(model, variables, va["image"])
        head = calibrate.predict_from_features(cfg["model"]["regressor"], variables["params"]["regressor"], fva,
                                              calibrate.regressor_stats(variables))
        out["features"][str(run)] = {"method": spec.name, "dim": int(ftr.shape[1]),
                                     "own_head_mae_n": np.abs(head - yva).mean(0).round(4).tolist(),
                                     "ridge": ridge(ftr, ytr, fva, yva)}
    return out


def report(res: dict) -> str:
    lines = ["# Shear visibility", "", f"Matched presses, Fz = {FZ} N, |F_t| = {FT} N, noiseless, after preprocessing "
             "(energy = sum of squared differences of the [0, 1] input to the no-shear press).", "",
             "| sensor | LEDs | shear source | shape | E(Fx) | E(Fy) | Fy/Fx | shift +Fx (px) | shift +Fy (px) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in res["physics"]["rows"]:
        px, py = r["presses"]["+x"]["shift_px"], r["presses"]["+y"]["shift_px"]
        lines.append(f"| {r['sensor']} | {r['leds']} | {r['source']} | {r['shape']} | {r['energy_fx']:.3f} | "
                     f"{r['energy_fy']:.3f} | {r['ratio_y_over_x']:.2f} | ({px[0]:+.2f}, {px[1]:+.2f}) | "
                     f"({py[0]:+.2f}, {py[1]:+.2f}) |")
    lines += ["", "Sign/axis convention on the spheres (+Fx -> +x columns, +Fy -> +y rows): "
              f"{'OK' if res['physics']['sign_ok'] else 'BROKEN'}"]
    if res["physics"].get("resolution"):
        lines += ["", "## The pigment's share of a shear's image change, by render size", "",
                  "The 10 mm sphere, each source alone (the pigment carried by the gel; the surface's shape: the gel "
                  "piled up ahead, stretched behind), the input at the render's width; share = E(pigment) / "
                  "(E(pigment) + E(shape)).", "", "| sensor | render size | E(pigment) | E(shape) | pigment share |",
                  "|---|---|---|---|---|"]
        lines += [f"| {r['sensor']} | {r['size'][0]}x{r['size'][1]} | {r['energy_pigment']:.4f} | "
                  f"{r['energy_bulge']:.4f} | {r['pigment_share']:.2f} |" for r in res["physics"]["resolution"]]
    p = res.get("probes")
    if p:
        lines += ["", "## Ridge probes, val MAE (N) Fx / Fy / Fz", "",
                  f"constant (train mean): {' / '.join(f'{v:.3f}' for v in p['constant_mae_n'])}", ""]
        for k, v in p["pixels"].items():
            lines.append(f"- pixels {k}x3: {' / '.join(f'{m:.3f}' for m in v['mae_n'])} (alpha {v['alpha']:g})")
        for run, v in p["features"].items():
            ridge_mae = " / ".join(f"{m:.3f}" for m in v["ridge"]["mae_n"])
            head_mae = " / ".join(f"{m:.3f}" for m in v["own_head_mae_n"])
            lines.append(f"- {v['method']} features (dim {v['dim']}): ridge {ridge_mae}; "
                         f"its own regressor {head_mae} ({run})")
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    from experiments import common

    ap = argparse.ArgumentParser(prog=common.prog(), description=common.description(__doc__))
    ap.add_argument("--out", default=None, help="results folder (default: results/shear_probe)")
    ap.add_argument("--data", default=None, help="dataset folder for the ridge probes (train and val splits)")
    ap.add_argument("--runs", nargs="*", default=[], help="training run folders whose backbone features to probe")
    args = ap.parse_args(argv)
    if args.runs and not args.data:
        ap.error("--runs needs --data (the probes fit on its train split and score on val)")
    out = Path(args.out or common.ROOT / "results" / "shear_probe")
    res = {"commit": common.git_commit(), "physics": physics()}
    if args.data:
        res["probes"] = probes(Path(args.data), [Path(r) for r in args.runs])
    out.mkdir(parents=True, exist_ok=True)
    common.write_json(out / "results.json", res)
    common.write_text(out / "report.md", report(res))
    print(report(res))
    return res


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
