"""`python -m ffjax.calibrate`: fine-tune a checkpoint's regressor on a user's labelled frames (paper IV-B).

    python -m ffjax.calibrate --checkpoint RUN --data calib/data.csv --out RUN_sensor2 [--layers last|regressor]
        [--steps N] [--lr X] [--holdout 0.2] [--background FILE] [--seed 0]

--data: a CSV in the release layout (tactile, optional depth, FT "Fx Fy Fz Tx Ty Tz"; paths relative to the
CSV; background.png beside it or --background), e.g. what `python -m ffjax.calibrate.record` writes, or a
shard folder. A seeded random --holdout fraction is kept aside; the rest trains:
  --layers last       the final Linear(->3) and the LayerNorm before it: another unit of the same sensor
                      type (GelSight Mini -> another Mini or another gel), the paper's default
  --layers regressor  the whole regressor head: a different sensor type (e.g. DIGIT)
The backbone is frozen, so its features are computed once and only the head trains (ffjax.calibrate.core).
Reported before and after on the held-out part: normalized L1 % (per axis, divided by the ORIGINAL training
force range, as everywhere in ffjax) and MAE in newtons. The held-out frames are presses of the same objects
as the fitting frames: they measure the fit, not the transfer to other shapes. With a single calibration object
(the paper's Big Sphere) the head also learns that object's own error and passes it to every other shape: record
presses of a few different shapes (flat and round), and calibrate only when the new sensor's error on the object
differs from the training sensor's on the same object (see docs/results.md, Table III).
--out gets a new self-describing folder
(model.json, variables.msgpack, calibration.json, background.png) that inference.load / ffjax.live /
ffjax.export accept; its expected frame size is the calibration frames'. The checkpoint is never modified.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np

from ffjax import cli, metrics, store
from ffjax import data as fdata
from ffjax.calibrate import core
from ffjax.data.images import write_rgb
from ffjax.files import atomic_write_json, check_output, folder_lock


def split_indices(n: int, holdout: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(fit, held-out) index arrays from a seeded permutation; at least one of each when n >= 2."""
    if not 0 <= holdout < 1:
        raise ValueError(f"holdout must be in [0, 1), got {holdout}")
    perm = np.random.default_rng(seed).permutation(n)
    k = 0 if holdout == 0 or n < 2 else int(np.clip(round(holdout * n), 1, n - 1))
    return np.sort(perm[k:]), np.sort(perm[:k])


def _check_finite(regressor, steps: int, lr: float, out: Path) -> None:
    """Refuse a fit that diverged (a too-high --lr): it used to be written as a NaN-weight bundle, exit code 0."""
    if not all(np.isfinite(x).all() for x in jax.tree.leaves(regressor)):
        raise ValueError(f"calibration diverged: the fitted regressor has NaN/inf weights after {steps} steps at "
                         f"--lr {lr:g}; nothing was written to {out}. Lower --lr (the default is the config's "
                         "calibrate.lr)")


def calibrate(checkpoint, data, out, layers: str = "last", steps: int | None = None, lr: float | None = None,
              holdout: float | None = None, seed: int = 0, background=None, batch_size: int | None = None,
              which: str = "best", force: bool = False, log=print) -> dict:
    """Fine-tune, evaluate before/after on a held-out part, write a new checkpoint folder; returns the report."""
    checkpoint, out = Path(checkpoint), Path(out)
    if layers not in core.LAYERS:
        raise ValueError(f"--layers must be one of {core.LAYERS}, got {layers!r}")
    reads = [checkpoint, data, background if isinstance(background, (str, Path)) else None]
    check_output(out, reads, force)
    # held from the start: two calibrations into one --out must not mix their files; checked again inside,
    # since another one may have finished there between the first check and the lock
    with folder_lock(out, "calibration"):
        check_output(out, reads, force)
        ckpt = store.load(checkpoint, which)
        cc = ckpt.cfg["calibrate"]
        steps = int(cc["steps"] if steps is None else steps)
        lr = float(cc["lr"] if lr is None else lr)
        holdout = float(cc["holdout"] if holdout is None else holdout)
        batch_size = int(cc["batch_size"] if batch_size is None else batch_size)

        source = fdata.open_split(data, background=background)
        if len(source) == 0:
            raise ValueError(f"{data}: no labelled frames")
        first = source[0]
        frame = tuple(first["image"].shape[:2])
        if frame != tuple(ckpt.frame_size):
            log(f"note: calibration frames are {frame[0]}x{frame[1]}, the checkpoint's {ckpt.frame_size[0]}x"
                f"{ckpt.frame_size[1]} ({ckpt.frame_size_source}); the new checkpoint expects {frame[0]}x{frame[1]}"
                + ("" if layers == "regressor" else ". For a different sensor type use --layers regressor"))
        arrays = fdata.load_arrays(source, ckpt.stats, ckpt.input_size)
        y = arrays["force"]
        feats = core.features(ckpt.build(), ckpt.variables, arrays["image"], batch_size=min(64, len(y)))
        fit, hold = split_indices(len(y), holdout, seed)
        if len(hold) == 0:
            log("warning: no held-out frames (holdout 0 or a single frame): errors below are on the fitting set")
        head = ckpt.cfg["model"]["regressor"]
        # as numpy, like fit_regressor's output: predict_from_features then compiles once for both (committed
        # device arrays would be another cache entry)
        reg = jax.tree.map(np.asarray, ckpt.variables["params"]["regressor"])
        stats = core.regressor_stats(ckpt.variables)
        if stats is not None:
            stats = jax.tree.map(np.asarray, stats)
        lo, hi = ckpt.stats.force_min, ckpt.stats.force_max
        # predictions for all frames at once, then indexed: one compiled shape for before and after
        pred_before = core.predict_from_features(head, reg, feats, stats)
        new_reg = core.fit_regressor(head, reg, feats[fit], y[fit], layers=layers, steps=steps, lr=lr,
                                     batch_size=batch_size, seed=seed, reg_stats=stats)
        _check_finite(new_reg, steps, lr, out)
        pred = core.predict_from_features(head, new_reg, feats, stats)
        # no held-out part: its errors are None, not the fitting set's under the held-out name
        before = metrics.summarize(pred_before[hold], y[hold], lo, hi) if len(hold) else None
        after = metrics.summarize(pred[hold], y[hold], lo, hi) if len(hold) else None
        after_fit = metrics.summarize(pred[fit], y[fit], lo, hi)
        before_fit = metrics.summarize(pred_before[fit], y[fit], lo, hi)
        report = {
            "checkpoint": str(checkpoint), "data": str(data), "layers": layers, "steps": steps, "lr": lr,
            "batch_size": batch_size, "holdout": holdout, "seed": seed, "n": int(len(y)), "n_fit": int(len(fit)),
            "n_holdout": int(len(hold)), "frame_size": list(frame),
            "force_range_used": {"min": list(lo), "max": list(hi)},
            "holdout_before": before, "holdout_after": after, "fit_before": before_fit, "fit_after": after_fit,
            "calibration_force_range": {"min": y.min(0).tolist(), "max": y.max(0).tolist()},
        }
        variables = core.with_regressor(ckpt.variables, new_reg)
        atomic_write_json(out / "calibration.json", report, indent=2)
        bg = getattr(source, "background", None)
        write_rgb(out / "background.png", bg if bg is not None else first["background"])
        # model.json last: a folder a kill left without it is no bundle, never one with the old weights
        store.save_bundle(out, ckpt, variables, frame_size=frame, calibration=report)
    log(format_report(report))
    log(f"wrote {out} (python -m ffjax.live --checkpoint {out} ...)")
    return report


def format_report(r: dict) -> str:
    def line(name, m):
        ax = " ".join(f"{v:6.2f}" for v in m["nl1_axes"])
        mae = " ".join(f"{v:6.3f}" for v in m["mae_n"])
        return f"  {name:<8} {m['nl1']:7.2f}   ({ax})   {mae}"

    held = r["n_holdout"] > 0
    on = (f"held-out {r['n_holdout']} frames:" if held else
          f"no held-out frames, errors on the {r['n_fit']} fitting frames (they show the fit only):")
    return "\n".join([
        f"calibrated layers={r['layers']} on {r['n_fit']} frames, {r['steps']} steps, lr {r['lr']:g}; {on}",
        "             nL1 %   (Fx     Fy     Fz)      MAE N (Fx     Fy     Fz)",
        line("before", r["holdout_before" if held else "fit_before"]),
        line("after", r["holdout_after" if held else "fit_after"]),
        "  (nL1: mean |error| / the training force range per axis, in %; " + (
            "held-out frames are of the calibration objects, so they do not show how other shapes fare)" if held
            else "hold some frames out (--holdout, and record more presses) to see how the calibration generalizes)"),
    ])


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m ffjax.calibrate", description=cli.description(__doc__),
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="\n".join(__doc__.splitlines()[1:]))
    p.add_argument("--checkpoint", required=True, help="training run, calibrated or converted folder")
    p.add_argument("--data", required=True, help="release-layout CSV (or a folder holding data.csv / shards)")
    p.add_argument("--out", required=True, help="new folder for the calibrated checkpoint")
    p.add_argument("--layers", default="last", choices=core.LAYERS,
                   help="what calibration tunes: last (the regressor's output layer and its last norm, the default) "
                        "or regressor (the whole regressor); the backbone stays fixed")
    p.add_argument("--steps", type=cli.integer(1), default=None,
                   help="optimizer steps (default: cfg calibrate.steps)")
    p.add_argument("--lr", type=cli.number(0), default=None, help="Adam learning rate (default: cfg calibrate.lr)")
    p.add_argument("--holdout", type=cli.fraction, default=None, help="held-out fraction (default: cfg, 0.2)")
    p.add_argument("--batch-size", type=cli.integer(1), default=None,
                   help="samples per optimizer step (default: cfg calibrate.batch_size)")
    p.add_argument("--background", default=None, help="no-contact frame, if not background.png beside the CSV")
    p.add_argument("--seed", type=cli.integer(0), default=0,
                   help="seed of the held-out split and of the batch order (default: 0)")
    p.add_argument("--which", default="best", choices=("best", "latest"), help=cli.WHICH_HELP)
    p.add_argument("--force", "--overwrite", dest="force", action="store_true",
                   help="replace an existing --out (it may never be inside --checkpoint or --data)")
    return p


def main(argv=None) -> int:
    ap = build_parser()
    a = ap.parse_args(argv)
    # where --out goes must be writable: a usage error naming --out (exit 2) before any work, not an errno at the end
    cli.check_out(ap, Path(a.out).absolute().parent)
    try:
        calibrate(a.checkpoint, a.data, a.out, a.layers, a.steps, a.lr, a.holdout, a.seed, a.background,
                  a.batch_size, a.which, a.force)
    except (ValueError, FileExistsError, FileNotFoundError) as e:
        return cli.fail(e, cli.USAGE)
    return 0
