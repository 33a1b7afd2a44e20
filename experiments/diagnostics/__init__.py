"""Diagnostics: one-off probes of the simulator and of trained models, from the investigation of Table I.

    python -m experiments.diagnostics.contact_probe --preset quick   # contact area, pad border, change per newton
    python -m experiments.diagnostics.object_probe --preset quick [--runs RUN_DIR ...]  # signal and read-out per object
    python -m experiments.diagnostics.layer_check --preset quick     # the simulator's gel against the exact layer
    python -m experiments.diagnostics.shear_probe [--data DIR] [--runs RUN_DIR ...]  # is shear visible, on which axis
    python -m experiments.diagnostics.rest_recording --recording DIR  # a real sensor at rest against the simulator's
    python -m experiments.diagnostics.buried_load_check              # the stick's hold against finite elements
    python -m experiments.diagnostics.low_force [--data DIR] [--runs RUN_DIR ...]  # Fz at light loads, wide contacts

They are kept because docs/results.md and docs/experiments.md cite their results (docs/results/*_probe-*/,
layer_check-*/); they are not part of the paper's experiments, and nothing else in experiments/ runs them
(`experiments.replot` redraws their figures).
"""


def publish(out, name: str, res: dict, report, plot) -> dict:
    """A diagnostic's outputs in `out`: results.json, NAME.md (report(res)) and NAME.png (plot(res, path)); the
    report printed too. Returns res."""
    from pathlib import Path

    from experiments import common

    out = Path(out)
    common.write_json(out / "results.json", res)
    common.write_text(out / f"{name}.md", report(res))
    plot(res, out / f"{name}.png")
    print(report(res))
    return res
