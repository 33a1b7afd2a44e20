"""Re-render an experiment's tables and figures from its results.json with the current code (no training).

    python -m experiments.replot docs/results/ablation-quick [more folders ...]

For the folders of `experiments.ablation` (Tables I-III), `.stability`, `.sweep_loss`, `.pareto`, and the
figures of `.bench`, `.downstream` and the diagnostics `.diagnostics.contact_probe`, `.layer_check` and
`.object_probe`. The numbers are read back unchanged, only the text (Tables I-III's verdict sentences included)
and plots are written again (the commit the numbers came from stays in results.json and on every figure).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from experiments import common


def replot(folder) -> str:
    """Re-render one folder; returns its kind. ValueError for a folder of another kind."""
    folder = Path(folder)
    results = common.read_json(folder / "results.json")
    if results is None:
        raise FileNotFoundError(f"{folder / 'results.json'}: no such file")
    if "table1" in results:
        from experiments import tables, training_report

        results["findings"] = tables.findings(results)  # the verdicts too: written by the code of the run's day
        tables.write_all(results, folder)
        if results.get("training"):
            training_report.write(results["training"], folder, results["preset"], results.get("seeds", []),
                                  results.get("commit", "?"))
        return "ablation"
    if "factors" in results and "seed_spread" in results:
        from experiments import stability

        stability.write_all(results, folder)
        return "stability"
    if "per_beta" in results:
        from experiments import sweep_loss

        sweep_loss.write_all(results, folder)
        return "sweep_loss"
    if "cells" in results and "fronts" in results:
        from experiments import pareto

        pareto.write_all({**results, "markdown": pareto.markdown(results)}, folder)
        return "pareto"
    if "models" in results and "scaling" in results:
        from experiments.bench import report as bench_report

        bench_report.plots(results, folder)  # the figures only: report.md is tied to the bench version that ran
        return "bench"
    if "pushing" in results and "grasping" in results:
        from ffjax.tasks import report

        report.plots(results, folder, results.get("push_trace"))  # figures only: the tables come with the run
        return "downstream"
    for kind, keys in (("contact_probe", ("edge_mm", "per_shape")), ("layer_check", ("margin_thicknesses",)),
                       ("object_probe", ("signal", "readout"))):
        if all(k in results for k in keys):
            import importlib

            probe = importlib.import_module(f"experiments.diagnostics.{kind}")
            probe.plot(results, folder / f"{kind}.png")  # figure only
            return kind
    raise ValueError(f"{folder}: results.json is not from experiments.ablation, .stability, .sweep_loss, .pareto, "
                     ".bench, .downstream, .diagnostics.contact_probe, .layer_check or .object_probe")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog=common.prog(), description=__doc__.strip().splitlines()[0])
    ap.add_argument("folders", nargs="+", help="folders holding a results.json")
    for folder in ap.parse_args(argv).folders:
        print(f"{folder}: re-rendered ({replot(folder)})")
    return 0


if __name__ == "__main__":
    import sys

    from ffjax import cli

    sys.exit(cli.run(main))
