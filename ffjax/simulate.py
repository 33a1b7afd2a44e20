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
    # the solves take little of a GPU's memory (docs/benchmarks.md, the simulator on a GPU) and worker processes
    # share it: none may take 75% up front (XLA's default), this one included (set before jax starts its backend)
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    ap = argparse.ArgumentParser(prog="python -m ffjax.simulate", description=cli.description(__doc__))
    ap.add_argument("--preset", default="quick", choices=configs.PRESETS,
                    help="dataset size (default: quick): smoke for the tests, quick and full for a CPU, paper "
                         "(240x320 renders) for a GPU; the measured times are in docs/benchmarks.md")
    ap.add_argument("--out", required=True, help="dataset folder to write, e.g. data/quick")
    ap.add_argument("--force", action="store_true", help="delete a dataset made with another config")
    ap.add_argument("--workers", type=int, default=None,
                    help="processes (default: CPU count, max 8; on a GPU too, all sharing it)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override, e.g. "
                    "data.train_per_indenter=100")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    if args.workers is not None and args.workers < 1:
        ap.error(f"--workers must be at least 1, got {args.workers} (leave it out for the default)")
    cfg = configs.from_cli(ap, args.preset, args.set)
    if args.workers is None and batched.on_accelerator():
        # dataset.generate keeps a caller on a GPU to one process (its jax may hold most of the GPU's memory); here
        # nothing else holds it, and a press's optics and files, on the CPU, cost as much as its solves on the
        # GPU, so workers speed it up there too (docs/benchmarks.md, the simulator on a GPU)
        args.workers = dataset.cpu_workers()
    m = dataset.generate(cfg, args.out, force=args.force, workers=args.workers, progress=not args.quiet)
    gen = m["generation"]
    print(f"{args.out}: {len(m['splits'])} splits, {gen['samples']} presses "
          f"({gen['rendered']} rendered in {gen['seconds']} s, {gen['samples_per_minute']:,}/min, "
          f"{gen['workers']} workers)")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
