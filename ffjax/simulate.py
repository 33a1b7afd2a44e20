"""Simulate a preset's dataset: every split the paper's tables need (train, val, unseen, sensor, calib).

    python -m ffjax.simulate --preset quick --out data/quick [--force] [--workers N] [--set data.x=y]

The library side is `ffjax.sim.dataset.generate(cfg, out)` (the layout, sampling and resume rules are in its
docstring); this is its command line, here because the presets (configs) sit above the simulator.
"""

from __future__ import annotations

import argparse
import sys

import configs
from ffjax import cli
from ffjax.sim import batched, dataset


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ffjax.simulate", description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="quick", choices=configs.PRESETS,
                    help="dataset size (default: quick). Measured on a 2-core CPU: smoke seconds; quick 11,300 "
                         "presses in ~6 min; paper ~235K at 240x320, meant for a GPU")
    ap.add_argument("--out", required=True)
    ap.add_argument("--force", action="store_true", help="delete a dataset made with another config")
    ap.add_argument("--workers", type=int, default=None, help="processes (default: CPU count, max 8; one on a GPU)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override, e.g. "
                    "data.train_per_indenter=100")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    cfg = configs.from_cli(ap, args.preset, args.set)
    batched.use_disk_cache()  # this process's compiled solves, for the next run
    m = dataset.generate(cfg, args.out, force=args.force, workers=args.workers, progress=not args.quiet)
    gen = m["generation"]
    print(f"{args.out}: {len(m['splits'])} splits, {gen['samples']} presses "
          f"({gen['rendered']} rendered in {gen['seconds']} s, {gen['samples_per_minute']:,}/min, "
          f"{gen['workers']} workers)")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
