"""Self-supervised pretraining of CPU-scale backbones: DINO self-distillation on an unlabeled corpus.

    python -m ffjax.train.pretrain --preset quick --backbone vit|resnet|all --out DIR [--force] [--probe]

pretrains each backbone into DIR/<kind> (reusing a matching cache) and, with --probe, reports a linear probe.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import configs
from ffjax import cli
from ffjax.sim import dataset
from ffjax.train.pretrain.cache import run_dir
from ffjax.train.pretrain.loop import ensure
from ffjax.train.pretrain.model import KINDS
from ffjax.train.pretrain.report import format_report, probe_report


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m ffjax.train.pretrain", description=cli.description(__doc__))
    ap.add_argument("--preset", default="quick", choices=configs.PRESETS,
                    help="corpus and schedule size (default: quick); each backbone is cached after its first run "
                    "(measured times: docs/training.md)")
    ap.add_argument("--backbone", default="all", choices=(*KINDS, "all"), help="which to pretrain (default: all)")
    ap.add_argument("--out", default=None, help="output folder (default data/<preset>/pretrained)")
    ap.add_argument("--force", action="store_true", help="pretrain again even if a matching cache exists")
    ap.add_argument("--probe", action="store_true", help="also run the linear probe (random vs pretrained)")
    ap.add_argument("--data", default=None, help="labelled dataset for the probe (default data/<preset>)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    args = ap.parse_args(argv)
    cfg = configs.from_cli(ap, args.preset, args.set)
    out = Path(args.out or dataset.default_root(args.preset) / "pretrained")
    cli.check_out(ap, out)  # before pretraining: a read-only or mistyped --out fails now, named
    for kind in KINDS if args.backbone == "all" else (args.backbone,):
        folder = ensure(cfg, kind, run_dir(out, kind), force=args.force, progress=not args.quiet)
        if args.probe:
            data = Path(args.data or dataset.default_root(args.preset))
            if not (data / "train").exists():
                dataset.generate(cfg, data, progress=not args.quiet)
            print(format_report(probe_report(cfg, kind, folder, data, progress=not args.quiet)))


if __name__ == "__main__":
    sys.exit(cli.run(main))
