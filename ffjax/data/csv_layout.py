"""Write a split in the FeelAnyForce release layout (what the real data and users' own recordings use).

    python -m ffjax.data.csv_layout --split DIR/unseen/banana --out OUT

OUT/data.csv (columns tactile, depth, FT = "Fx Fy Fz Tx Ty Tz", torques 0), OUT/tactile/000000.png
(colour PNGs, correct for cv2 and any viewer), OUT/depth/000000.npy (float64 mm, like the release),
OUT/background.png. Paths in the CSV are relative to its folder, so OUT can be moved.
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ffjax import cli
from ffjax.data.csv_source import CSV_NAME
from ffjax.data.images import BACKGROUND_NAME, write_rgb
from ffjax.data.sources import open_split
from ffjax.files import atomic_write_text, check_output


def write_csv(source, out, progress: bool = True) -> Path:
    """Write every record of `source` to the release layout under `out`; returns the CSV path."""
    out = Path(out)
    (out / "tactile").mkdir(parents=True, exist_ok=True)
    (out / "depth").mkdir(parents=True, exist_ok=True)
    if source.background is None:
        raise ValueError(f"{source!r} has per-row backgrounds; this writer expects one background per split")
    write_rgb(out / BACKGROUND_NAME, source.background)
    rows = []
    n = len(source)
    bar = tqdm(total=n, desc=f"csv {out.name}", disable=not progress, leave=False)
    for a in range(0, n, 256):
        b = source.read_range(a, min(a + 256, n))
        for j in range(len(b["force"])):
            i = a + j
            img_rel, depth_rel = f"tactile/{i:06d}.png", f"depth/{i:06d}.npy"
            write_rgb(out / img_rel, b["image"][j])
            np.save(out / depth_rel, b["depth"][j].astype(np.float64))
            f = b["force"][j]
            # repr-exact float32 -> text: %.9g round-trips float32 exactly
            ft = " ".join(f"{float(v):.9g}" for v in f) + " 0 0 0"
            rows.append((img_rel, depth_rel, ft))
        bar.update(len(b["force"]))
    bar.close()
    text = io.StringIO()
    w = csv.writer(text)
    w.writerow(["tactile", "depth", "FT"])
    w.writerows(rows)
    atomic_write_text(out / CSV_NAME, text.getvalue())
    return out / CSV_NAME


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m ffjax.data.csv_layout", description=cli.description(__doc__))
    p.add_argument("--split", required=True, help="a shard directory (or any split open_split reads)")
    p.add_argument("--out", required=True,
                   help="output folder (data.csv, tactile/, depth/, background.png)")
    p.add_argument("--force", action="store_true", help="write into an existing --out (its files are replaced)")
    args = p.parse_args(argv)
    check_output(args.out, reads=[args.split], force=args.force)
    src = open_split(args.split)
    path = write_csv(src, cli.check_out(p, args.out))
    print(f"wrote {path}")


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
