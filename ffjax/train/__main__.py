"""Train one method on a preset's simulated data or on release-layout CSVs, and report its validation force error.

    python -m ffjax.train --preset quick --method dino_rd [--data DIR | --data TRAIN.csv --val VAL.csv]
        [--out RUN] [--resume[=auto]] [--pretrained DIR | --init KIND:PATH] [--set key.path=value ...]

Without --data the preset's simulated dataset is generated (or reused) in its cache folder,
ffjax.sim.dataset.default_root (the checkout's data/<preset>, or $FFJAX_DATA/<preset>). --data may
also be a CSV in the FeelAnyForce release layout (tactile, depth, FT; paths relative to the CSV).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import configs
from ffjax import cli, data, registry, train
from ffjax.data.sources import is_csv_path
from ffjax.errors import CheckpointError, WriteError
from ffjax.sim import dataset
from ffjax.train import init_weights
from ffjax.train.pretrain import load_backbone


def parse_args(argv=None):
    ap = argparse.ArgumentParser(prog="python -m ffjax.train", description=cli.description(__doc__))
    ap.add_argument("--preset", default="quick", choices=configs.PRESETS,
                    help="size of data, model and training (default: quick): smoke for the tests (its numbers "
                    "check the plumbing, nothing more), quick and full for a CPU, gpu and paper for a GPU; without "
                    "--data the preset's dataset is simulated first on first use. The measured times of published "
                    "runs are in docs/experiments.md and docs/benchmarks.md")
    ap.add_argument("--method", default="dino_rd", choices=registry.names(), help="registry name (default: dino_rd)")
    ap.add_argument("--data", help="dataset root holding train/ and val/, or a release-layout CSV "
                    "(default: the preset's simulated dataset in the checkout's data/<preset>, or "
                    "$FFJAX_DATA/<preset>)")
    ap.add_argument("--val", help="validation CSV (release layout) when --data is a CSV")
    ap.add_argument("--skip-bad-rows", action="store_true", help="CSV data: drop rows whose files or FT cells "
                    "are bad (count and first reasons logged) instead of stopping at the first one")
    ap.add_argument("--out", help="run folder (default: runs/<preset>-<method>)")
    ap.add_argument("--resume", nargs="?", const="yes", choices=("yes", "auto"), default=None,
                    help="continue the run in --out from its latest checkpoint (an error if it has none); "
                    "--resume=auto: continue if there is a checkpoint, else start (for restart-on-failure loops)")
    ap.add_argument("--pretrained", help="pretrained backbone folder (python -m ffjax.train.pretrain --out DIR)")
    ap.add_argument("--init", metavar="KIND:PATH", help="start from weights: dinov2:FILE|DIR, resnet18:FILE|DIR, "
                    "feelanyforce:FILE|DIR (the release checkpoint), pretrained:DIR")
    ap.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="config override, e.g. --set train.epochs=2 (repeatable)",
    )
    ap.add_argument("--max-steps", type=int, help="stop after this many steps (checkpointed; --resume goes on)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    if args.max_steps is not None and args.max_steps < 1:  # 0 used to run a step anyway and exit 0
        ap.error(f"--max-steps must be at least 1, got {args.max_steps} (leave it out to train every epoch)")
    args.cfg = configs.from_cli(ap, args.preset, args.overrides)  # a bad --set stops here, before any work
    return args


def describe(val: dict | None) -> str:
    if not val:
        return "no validation split"
    # n/a: an axis the training labels hold constant has no range to normalize by (ffjax.metrics)
    axes = ", ".join(f"{a} {v:.2f}%" if math.isfinite(v) else f"{a} n/a" for a, v in zip(("Fx", "Fy", "Fz"),
                                                                                         val["nl1_axes"]))
    mae = ", ".join(f"{a} {v:.3f}" for a, v in zip(("Fx", "Fy", "Fz"), val["mae_n"]))
    return f"normalized L1 {val['nl1']:.2f}% ({axes}); MAE N: {mae}; n={val['n']}"


def main(argv=None) -> int:
    args = parse_args(argv)

    spec = registry.get(args.method)
    out = Path(args.out or Path("runs") / f"{args.preset}-{args.method}")
    ckpts = out / "checkpoints"
    has_ckpt = ckpts.is_dir() and any(p.name.isdigit() for p in ckpts.iterdir())
    if args.resume == "yes" and not has_ckpt:
        return cli.fail(f"--resume: nothing to resume in {out} (no checkpoint in {ckpts}); drop --resume to start "
                        "a new run there (or --resume=auto to start when there is none)", cli.USAGE)
    resume = bool(args.resume)  # train() starts from step 0 when a killed run had not saved yet
    data_dir = _data(args)
    if isinstance(data_dir, int):  # an exit code: the arguments were refused
        return data_dir
    start = _start(args, spec, resume and has_ckpt)
    if isinstance(start, int):
        return start
    cfg, backbone, variables = start
    t0 = time.perf_counter()
    try:
        summary = train.train(
            cfg,
            spec,
            data_dir,
            out,
            resume=resume,
            init_backbone=backbone,
            init_variables=variables,
            max_steps=args.max_steps,
            progress=not args.quiet,
        )
    except (train.NonFiniteLossError, WriteError) as e:
        return cli.fail(e, cli.RUNTIME)
    except (FileExistsError, CheckpointError) as e:
        return cli.fail(e, cli.USAGE)
    wall = time.perf_counter() - t0
    print(
        f"run: {summary['run_dir']}  ({summary['steps']}/{summary['total_steps']} steps, "
        f"{summary['devices']} device(s), {wall:.1f} s this call)"
    )
    print(f"final validation force error: {describe(summary['val'])}")
    if summary["best_epoch"] is not None:
        print(f"best checkpoint: epoch {summary['best_epoch']} (val loss {summary['best_val_loss']:.4f})")
    return 0


def _data(args):
    """What train() takes as data: --data/--val CSV files (every row checked now, so a bad file stops the run
    before any work), a dataset folder, or the preset's simulated dataset (generated once); an exit code when
    the arguments are refused."""
    data_dir = args.data
    if args.val and not (data_dir and is_csv_path(data_dir)):
        return cli.fail("--val goes with --data TRAIN.csv", cli.USAGE)
    if data_dir and is_csv_path(data_dir):
        try:
            data_dir = {k: data.open_split(v, validate=True, skip_bad_rows=args.skip_bad_rows) if v else None
                        for k, v in (("train", data_dir), ("val", args.val))}
        except data.DataError as e:
            return cli.fail(e, cli.USAGE)
        if not args.val:
            print("note: no --val CSV: no validation, the best checkpoint is the last one", file=sys.stderr)
    elif data_dir is None:
        data_dir = dataset.default_root(args.preset)
        print(f"dataset: {data_dir} (simulated, preset {args.preset}; generated once, then reused)")
        dataset.generate(args.cfg, data_dir)
    return data_dir


def _start(args, spec, restoring: bool):
    """(cfg, backbone, variables) a run starts from: --init (converted weights; it may set model keys),
    --pretrained (a pretrain folder's backbone) or random init; an exit code when the arguments are refused."""
    cfg, backbone, variables = args.cfg, None, None
    if args.init and args.pretrained:
        return cli.fail("give --init or --pretrained, not both", cli.USAGE)
    if args.init:
        try:
            cfg, backbone, variables = init_weights.apply(cfg, spec, args.init)
        except (ValueError, FileNotFoundError) as e:
            return cli.fail(e, cli.USAGE)
    elif args.pretrained:
        if not Path(args.pretrained).is_dir():
            raise FileNotFoundError(f"--pretrained {args.pretrained}: no such folder (make one with python -m "
                                    "ffjax.train.pretrain --out DIR)")
        backbone = load_backbone(args.pretrained)
    elif spec.pretrained and not restoring:
        print(
            f"note: {spec.name} expects a pretrained backbone; none given (--pretrained DIR), "
            "so it starts from random init",
            file=sys.stderr,
        )
    return cfg, backbone, variables


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
