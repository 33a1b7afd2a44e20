"""Every experiment that publishes a result, as data: its name, the command that makes it, what it answers, whose
trained runs it reuses, which sources its numbers and its figures come from, and how its results.json is told
apart. `experiments.reproduce` runs them in order, `experiments.replot` re-renders them, `experiments.status`
says which published result is stale; adding an experiment here is the only edit any of them needs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

# what every experiment's numbers come from beside the code its command runs: the presets (read by name) and the
# dependencies; for a command outside the import graph (tests/), the whole library and shared machinery
_CORE = ("configs", "pyproject.toml")
_DRAWS = ("experiments/tables.py", "experiments/style.py")  # a diagnostic that only draws with them
_TRAINS = ("--quiet", "--data", "--workers")  # an experiment that trains runs: kernel.run_all's workers too
_WHOLE = ("ffjax", "experiments/common.py", "experiments/kernel.py", "experiments/paper_numbers.py")


@dataclasses.dataclass(frozen=True)
class Experiment:
    """One published experiment.

    name: its folder in a preset's results tree (docs/results/<preset>/<name>); module: run as
    `python -m <module>`; question: what it answers, for the index; args(preset, work): its flags beyond
    --out in experiments.reproduce's tree `work` (WORK/ablation holds the runs it reuses); reuses: the
    experiment whose trained runs it reads;
    numbers: the sources (files or folders) its numbers depend on beyond the code its module imports (a change
    there makes it stale); figures: the sources of its tables' text and plots (a change there needs only
    `experiments.replot`);
    matches: whether a results.json is this experiment's; replot: re-renders a folder from its results.json;
    cell_seeds: the number of seeds of each of its cells, from its results.json, where cells differ (a sweep's
    cells reused from the ablation carry its seeds; None: the result's own seeds); speed: its numbers are the
    speed of the code it runs, so a change certified to give the same outputs (experiments.same_output) still
    changes them; on_request: `reproduce` runs it only when named; flags: which of reproduce's --quiet, --data
    (the pipeline's dataset) and --workers its command takes."""

    name: str
    module: str
    question: str
    matches: Callable[[dict], bool]
    replot: Callable | None = None
    args: Callable = lambda preset, work: ["--preset", preset]
    reuses: str | None = None
    numbers: tuple = ()
    figures: tuple = ()
    in_pipeline: bool = True
    on_request: bool = False  # in the pipeline, run only when named (`reproduce --only NAME`): too long for the rest
    flags: tuple = ("--quiet", "--data")  # the common flags its command takes (reproduce gives them)
    cell_seeds: Callable[[dict], list] | None = None
    speed: bool = False

    def main(self) -> Callable:
        """Its command's main(argv): the module's own, or its package's suite's (experiments.bench)."""
        import importlib

        module = importlib.import_module(self.module)
        return getattr(module, "main", None) or importlib.import_module(f"{self.module}.suite").main

    @property
    def number_sources(self) -> tuple:
        """Every source its numbers depend on: the presets, the dependencies, `numbers`, and every file its
        command runs (the import closure of its module and of the modules under `numbers`, so a change to the
        live loop does not make Table I stale), less the files that only draw (`figures`)."""
        from experiments import imports

        known = imports.modules()
        roots = {self.module} | {m for m, path in known.items()
                                 if any(_within(str(path.relative_to(imports.ROOT)), n) for n in self.numbers)}
        if self.module not in known:  # run from outside the graph (tests/): everything it could reach
            return _CORE + _WHOLE + self.numbers
        ran = [f for f in imports.files(imports.closure(roots)) if not any(_within(f, g) for g in self.figures)]
        return _CORE + tuple(dict.fromkeys([*self.numbers, *ran]))


def _within(path: str, source: str) -> bool:
    """Whether a repository path is the source (a file) or lies under it (a folder)."""
    return path == source or path.startswith(source.rstrip("/") + "/")


def _replot_ablation(results: dict, folder) -> None:
    from experiments import tables, training_figures

    results["findings"] = tables.findings(results)  # the verdicts too: written by the code of the run's day
    tables.write_all(results, folder)
    if results.get("training"):
        training_figures.write(results["training"], folder, results["preset"], results.get("seeds", []),
                              results.get("commit", "?"))


def _replot_stability(results: dict, folder) -> None:
    from experiments import stability

    stability.write_all(results, folder)


def _replot_sweep(results: dict, folder) -> None:
    from experiments import sweep_loss

    sweep_loss.write_all(results, folder)


def _replot_pareto(results: dict, folder) -> None:
    from experiments import pareto

    pareto.write_all({**results, "markdown": pareto.markdown(results)}, folder)


def _replot_pattern(results: dict, folder) -> None:
    from experiments import pattern_share

    pattern_share.write_all(results, folder)


def _pattern_args(preset: str, work) -> list:
    """The ablation's runs at the preset's share, NEW_CELL_SEEDS at the others; smoke one other share, one method."""
    small = ["--shares", "0.5", "1", "--methods", "dino_rd"] if preset == "smoke" else []
    return [*_trains_seeds(preset, work), *small]


def _replot_bench(results: dict, folder) -> None:
    from experiments.bench import report

    report.plots(results, folder)  # the figures only: report.md is tied to the bench version that ran


def _replot_downstream(results: dict, folder) -> None:
    from experiments import downstream_report

    downstream_report.draw(results, folder)


def _replot_probe(kind: str) -> Callable:
    def replot(results: dict, folder) -> None:
        import importlib
        from pathlib import Path

        importlib.import_module(f"experiments.diagnostics.{kind}").plot(results, Path(folder) / f"{kind}.png")

    return replot


def _has(*keys) -> Callable[[dict], bool]:
    return lambda r: all(k in r for k in keys)


SEEDS = {"smoke": 1}  # the ablation's seeds per method in the pipeline; 3 elsewhere (smoke checks the plumbing)
# Seeds of the cells only the sweep and the speed/accuracy chart train (the betas and sizes between the ablation's);
# the cells they reuse take all the ablation's seeds. Quick keeps one: three would add more than an hour on a 2-core
# CPU, and the ablation's 3-seed spreads say how far a one-seed point can be trusted.
NEW_CELL_SEEDS = {"smoke": 1, "quick": 1}


def _seeds(preset: str) -> list:
    return ["--seeds", str(SEEDS.get(preset, 3))]


def _reads_ablation(preset: str, work) -> list:
    return ["--preset", preset, "--ablation", str(work / "ablation")]


def _trains_seeds(preset: str, work) -> list:
    """Reads the ablation's runs (with all their seeds) and trains its own cells with NEW_CELL_SEEDS."""
    return [*_reads_ablation(preset, work), "--seeds", str(NEW_CELL_SEEDS.get(preset, 3))]


def _bench(only: str | None) -> Callable:
    def args(preset: str, work) -> list:
        mode = {"smoke": ["--smoke"], "quick": ["--quick"]}.get(preset, [])
        return [*mode, *(["--only", only] if only else [])]

    return args


EXPERIMENTS = (
    Experiment("ablation", "experiments.ablation",
               "Tables I-III: every method's force error on unseen objects, other sensors, and after calibration; "
               "the training report", _has("table1"), _replot_ablation,
               args=lambda preset, work: ["--preset", preset, *_seeds(preset)],
               figures=("experiments/tables.py", "experiments/training_figures.py", "experiments/style.py"),
               flags=_TRAINS),
    Experiment("sweep_loss", "experiments.sweep_loss",
               "Does the depth head help? DINO's error against the depth-loss weight beta/alpha",
               _has("per_beta"), _replot_sweep, args=_trains_seeds,
               reuses="ablation", figures=("experiments/tables.py", "experiments/style.py"),
               cell_seeds=lambda r: [len(v["per_seed"]) for v in r["per_beta"].values()], flags=_TRAINS),
    # on request: its two more datasets (shares 0 and 0.5) and their trainings cost more than the sweep, the chart
    # and stability together (its measured time: docs/results/<preset>/reproduce.json); it probes a parameter no
    # frame can measure, where the rest are the paper's results and their companions
    Experiment("pattern_share", "experiments.pattern_share",
               "Table II when none, half or all of the sensor's fine fixed pattern is the gel's pigment (a share no "
               "frame at rest can measure)", _has("per_share", "nominal_share"), _replot_pattern,
               args=_pattern_args, reuses="ablation", figures=("experiments/tables.py", "experiments/style.py"),
               on_request=True,
               cell_seeds=lambda r: [len(v["per_seed"]) for c in r["per_share"].values()
                                     for v in c["methods"].values()],
               flags=_TRAINS),
    Experiment("pareto", "experiments.pareto",
               "Speed against accuracy: error against latency, training throughput and size, per method and size",
               _has("cells", "fronts"), _replot_pareto, args=_trains_seeds, reuses="ablation",
               figures=("experiments/tables.py", "experiments/style.py"),  # tables: the footer's seeds in words
               cell_seeds=lambda r: [len(c["seeds"]) for c in r["cells"] if isinstance(c, dict) and "seeds" in c],
               flags=_TRAINS),
    Experiment("stability", "experiments.stability",
               "Where each method fails: the seed spread and the error against noise, lighting, force, shear, "
               "drift and more", _has("factors", "seed_spread"), _replot_stability, args=_reads_ablation,
               reuses="ablation", figures=("experiments/tables.py", "experiments/style.py")),
    Experiment("downstream", "experiments.downstream",
               "Weighing by pushing (Table IV) and grasping with the trained models in the loop",
               _has("pushing", "grasping"), _replot_downstream, args=_reads_ablation, reuses="ablation",
               figures=("experiments/downstream_report.py", "experiments/tables.py", "experiments/style.py")),
    Experiment("bench-sim", "experiments.bench",
               "The simulator's speed: batched solves against the numpy reference, their agreement, the oblique "
               "path against itself converged, a dataset's time",
               lambda r: r.get("experiment") == "bench" and "sim_speed" in r, _replot_bench,
               args=_bench("sim"), numbers=("experiments/bench",), flags=("--data",), speed=True),
    Experiment("bench", "experiments.bench",
               "ffjax against PyTorch: train and inference speed, scaling, the loop against its step",
               lambda r: r.get("experiment") == "bench", _replot_bench, args=_bench(None),
               numbers=("experiments/bench",), flags=(), speed=True),
    Experiment("contact_probe", "experiments.diagnostics.contact_probe",
               "Where a contact's edge is read: the layer's contact against the rendered frame",
               _has("edge_mm", "per_shape"), _replot_probe("contact_probe"),
               figures=_DRAWS, in_pipeline=False),
    Experiment("layer_check", "experiments.diagnostics.layer_check",
               "Is the gel's solve converged in its margin and grid?", _has("margin_thicknesses"),
               _replot_probe("layer_check"), figures=_DRAWS, in_pipeline=False),
    Experiment("object_probe", "experiments.diagnostics.object_probe",
               "What a trained model reads of an object: signal against readout", _has("signal", "readout"),
               _replot_probe("object_probe"), in_pipeline=False),
    Experiment("shear_probe", "experiments.diagnostics.shear_probe",
               "How much of a shear the frames carry, and which features read it",
               lambda r: isinstance(r.get("physics"), dict) and "sign_ok" in r["physics"],
               in_pipeline=False),
    Experiment("rest_recording", "experiments.diagnostics.rest_recording",
               "A sensor at rest: a real GelSight Mini's noise, fixed pattern, drift and colour against the simulator",
               _has("sources", "highpass_px"), _replot_probe("rest_recording"),
               figures=_DRAWS, in_pipeline=False, flags=()),
    Experiment("buried_load_check", "experiments.diagnostics.buried_load_check",
               "Where a body in stick holds the gel: the layer's stick solve against a finite-element model",
               _has("cases", "all_within_band"), _replot_probe("buried_load_check"),
               figures=_DRAWS, in_pipeline=False, flags=()),
    Experiment("low_force", "experiments.diagnostics.low_force",
               "How well can a frame tell Fz at light loads on wide contacts, and what do models read there?",
               _has("physics", "render_size"), _replot_probe("low_force"),
               figures=_DRAWS, in_pipeline=False, flags=()),
    Experiment("faults", "tests.reliability.faults",
               "What holds and what fails when a user or a fault misuses the tools", _has("kills_per_part"),
               numbers=("tests/reliability",), in_pipeline=False),
)


def get(name: str) -> Experiment:
    for e in EXPERIMENTS:
        if e.name == name:
            return e
    raise KeyError(f"unknown experiment {name!r}; known: {', '.join(e.name for e in EXPERIMENTS)}")


def kind_of(results: dict) -> Experiment | None:
    """The experiment a results.json comes from (the first that matches), or None."""
    return next((e for e in EXPERIMENTS if e.matches(results)), None)


def pipeline() -> tuple:
    """The experiments `experiments.reproduce` can run, in order (an experiment after the one it reuses)."""
    return tuple(e for e in EXPERIMENTS if e.in_pipeline)


def one_command() -> tuple:
    """The pipeline's experiments that `experiments.reproduce` runs when none is named."""
    return tuple(e for e in pipeline() if not e.on_request)
