"""Simulate a preset's dataset: every split the paper's tables need (train, val, unseen, sensor, calib).

    python -m ffjax.simulate --preset quick --out data/quick [--force] [--workers N] [--set data.x=y]

The library side is `ffjax.sim.dataset.generate(cfg, out)` (the layout, sampling and resume rules are in its
docstring); this is its command line, here because the presets (configs) sit above the simulator.
"""

from __future__ import annotations

import argparse
import os
import sys

import configs
from ffjax import cli
from ffjax.sim import batched, dataset


def main(argv=None) -> int:
    # the solves take little of a GPU's memory (~0.6 GiB for 256 presses at 240x320) and worker processes share it:
    # none may take 75% up front (XLA's default), this one included (set before jax starts its backend)
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    ap = argparse.ArgumentParser(prog="python -m ffjax.simulate", description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="quick", choices=configs.PRESETS,
                    help="dataset size (default: quick). Measured: smoke seconds; quick 11,300 presses in 11 min "
                         "on a 2-core CPU, 36 s on one H200 with 8 workers; paper 234K at 240x320, for a GPU "
                         "(~46 min there, projected from a sample)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--force", action="store_true", help="delete a dataset made with another config")
    ap.add_argument("--workers", type=int, default=None,
                    help="processes (default: CPU count, max 8; on a GPU too, all sharing it)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override, e.g. "
                    "data.train_per_indenter=100")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    if args.workers is not None and args.workers < 1:
        ap.error(f"--workers must be at least 1, got {args.workers} (leave it out for the default)")
    cfg = configs.from_cli(ap, args.preset, args.set)
    if args.workers is None and batched.on_accelerator():
        # dataset.generate keeps a caller on a GPU to one process (its jax may hold most of the GPU's memory); here
        # nothing else holds it, and a press's optics and files, on the CPU, cost as much as its solves on the
        # GPU: on one H200 the quick dataset took 114 s in one process, 47 s with 4 workers and 36 s with 8
        args.workers = dataset.cpu_workers()
    m = dataset.generate(cfg, args.out, force=args.force, workers=args.workers, progress=not args.quiet)
    gen = m["generation"]
    print(f"{args.out}: {len(m['splits'])} splits, {gen['samples']} presses "
          f"({gen['rendered']} rendered in {gen['seconds']} s, {gen['samples_per_minute']:,}/min, "
          f"{gen['workers']} workers)")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
