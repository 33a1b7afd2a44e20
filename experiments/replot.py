"""Re-render an experiment's tables and figures from its results.json with the current code (no training).

    python -m experiments.replot docs/results/quick/ablation [more folders ...]

For the folders of every experiment in `experiments.catalog` that re-renders: `experiments.ablation` (Tables
I-III), `.stability`, `.sweep_loss`, `.pareto`, and the figures of `.bench`, `.downstream` and the diagnostics
`.diagnostics.contact_probe`, `.layer_check` and `.object_probe`. The numbers are read back unchanged, only
the text (Tables I-III's verdict sentences included) and plots are written again (the commit the numbers came
from stays in results.json and on every figure).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from experiments import common


def replot(folder, commit: str | None = None) -> str:
    """Re-render one folder; returns its experiment's name. ValueError for a folder no experiment re-renders.
    commit: the code it is drawn with (default: HEAD now), read before any folder is re-rendered: a re-render
    rewrites tracked files (results.json, the tables), which would make the commit read after it "-dirty"."""
    commit = commit or common.git_commit()
    from experiments import catalog

    folder = Path(folder)
    results = common.read_json(folder / "results.json")
    if results is None:
        raise FileNotFoundError(f"{folder / 'results.json'}: no such file")
    exp = catalog.kind_of(results)
    if exp is None or exp.replot is None:
        known = ", ".join(e.module for e in catalog.EXPERIMENTS if e.replot)
        raise ValueError(f"{folder}: results.json is not from an experiment that re-renders ({known})")
    try:
        exp.replot(results, folder)
    except (KeyError, ValueError) as e:  # e.g. a key the figures need that an old results.json lacks: name the file
        said = f"{folder / 'results.json'}: {e.args[0] if e.args else e}"
        raise (KeyError if isinstance(e, KeyError) else ValueError)(said) from e
    # the commit it was drawn with (status: "replot" until the figures' sources change again); the numbers'
    # commit stays. Read again: a re-render may rewrite results.json (the ablation's findings).
    drawn = common.read_json(folder / "results.json") or results
    common.write_json(folder / "results.json", {**drawn, "replotted": commit})
    return exp.name


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog=common.prog(), description=common.description(__doc__))
    ap.add_argument("folders", nargs="+", help="folders holding a results.json")
    commit = common.git_commit()  # before the first re-render changes a tracked file
    for folder in ap.parse_args(argv).folders:
        print(f"{folder}: re-rendered ({replot(folder, commit)})")
    return 0


if __name__ == "__main__":
    import sys

    from ffjax import cli

    sys.exit(cli.run(main))
