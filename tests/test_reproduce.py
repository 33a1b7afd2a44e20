"""The whole pipeline at the smoke preset, end to end: `experiments.reproduce` runs every experiment of the
catalog's pipeline, each reusing the ablation's trained runs, publishes each result without its runs, writes
reproduce.json and the index, and `experiments.status` then calls every published result current.

One test, not several: the pipeline is the expensive part, and under pytest-xdist a module fixture would run
once per worker that draws one of the module's tests."""

import json
import math
import re
import shutil
from pathlib import Path

import _bench_plans
import _notebooks
import _smoke_run
import jax
import pytest

import configs
from experiments import catalog, common, doc_numbers, doc_tables, kernel, mappings, pareto, reproduce, status
from experiments.bench import suite as bench_suite
from ffjax import registry
from ffjax.tasks import pushing

ROOT = Path(__file__).resolve().parents[1]


def _done_runs(tree):
    """Every run folder trained (finished) under a tree: the folders whose stage.json says done."""
    return {p.parent for p in tree.rglob("stage.json")
            if (common.read_json(p) or {}).get("status") == "done" and p.parent.name.startswith("seed")}


def test_the_smoke_pipeline_end_to_end(tmp_path, monkeypatch):
    work, published, data = tmp_path / "work", tmp_path / "published", tmp_path / "data"
    # the benchmarks at toy sizes (the smoke plan's numbers mean nothing either; this keeps the suite short)
    monkeypatch.setitem(bench_suite.PLANS, "smoke", _bench_plans.PIPELINE)
    # the suite's smoke dataset and backbones (made by ensure_data with the default workers, as the ablation would:
    # its manifest's time is what the simulator's benchmark reads); the pipeline trains, scores and times from there
    shutil.copytree(_smoke_run.smoke_data(), data)
    record = reproduce.main(["--preset", "smoke", "--work", str(work), "--publish", str(published),
                             "--data", str(data), "--quiet"])
    pipeline = catalog.one_command()
    assert set(record["experiments"]) == {e.name for e in pipeline} and record["ran"] == [e.name for e in pipeline]
    assert [e.name for e in catalog.pipeline() if e.on_request] == ["pattern_share"]  # named with --only only

    # every experiment published: the folder its catalog entry names, a results.json of its own kind, no runs
    for e in pipeline:
        res = common.read_json(published / e.name / "results.json")
        assert res is not None, e.name
        assert catalog.kind_of(res) is e, e.name
        assert record["experiments"][e.name]["wall_s"] > 0 and record["experiments"][e.name]["commit"]
    assert not [p for p in published.rglob("*") if p.name in ("runs", "checkpoints", "stage.json")]

    # nothing trained twice: the sweep trains only the betas between the ablation's, the chart only the other
    # sizes; their reused cells point into the ablation's runs
    ablation_runs = _done_runs(work / "ablation")
    # trained common.default_workers() at a time (two on a 2-core CPU: the pool of pinned worker processes)
    assert common.read_json(work / "ablation" / "results.json")["timings"]["train_workers"] == common.default_workers()
    assert ablation_runs and all(p.is_relative_to(work / "ablation" / "runs") for p in ablation_runs)
    sweep = json.loads((published / "sweep_loss" / "results.json").read_text())
    for beta in ("0", "10"):
        assert all(d.startswith(str(work / "ablation")) for d in sweep["per_beta"][beta]["run_dirs"]), beta
    for p in _done_runs(work / "sweep_loss"):
        assert "dino_rd_b" in str(p)  # a variant the ablation does not train
    zero = sweep["per_beta"]["0"]
    assert not zero["depth_head"] and registry.get(zero["method"]).beta == 0
    assert sweep["checkpoints"][zero["method"]] == zero["run_dirs"]  # so stability can score the sweep's models
    for m in ("unseen_objects", "unseen_sensors", "digit"):
        assert 0 < zero[m]["mean"] < 200, m
    assert "no head reads" in sweep["finding"] and "| seeds |" in (published / "sweep_loss" / "sweep.md").read_text()

    chart = json.loads((published / "pareto" / "results.json").read_text())
    own = {c["label"]: c for c in chart["cells"] if c["size"] in ("vit-s", "resnet")}
    assert own and all(r.startswith(str(work / "ablation")) for c in own.values() for r in c["runs"])
    assert {p.parent.parent.name for p in _done_runs(work / "pareto")} <= {"vit-xs", "vit-m"}
    for c in chart["cells"]:
        for k in ("latency_b1_ms", "latency_b32_ms", "train_img_s", "b32_img_s", "params_total"):
            assert c[k] > 0 and math.isfinite(c[k]), (c["label"], k)
        assert 0 < c["table1"]["mean"] < 1e3 and 0 < c["table2"]["mean"] < 1e3, c["label"]
    by_label = {c["label"]: c for c in chart["cells"]}
    assert by_label["dino_rd@vit-xs"]["params_total"] < by_label["dino_rd@vit-m"]["params_total"]
    assert {p[0] for p in pareto.PANELS} == set(chart["fronts"]) and all(chart["fronts"].values())

    # stability and the downstream tasks read the ablation's checkpoints
    stab = json.loads((published / "stability" / "results.json").read_text())
    assert all(r.startswith(str(work / "ablation")) for runs in stab["checkpoints"].values() for r in runs)
    assert {"noise", "illumination", "force", "shear_angle", "drift", "tilt_shear"} <= set(stab["factors"])
    for e in stab["factors"].values():
        assert all(n > 0 for n in e["n"]) and all(len(v["nl1"]) == len(e["levels"]) for v in e["methods"].values())
    assert not (published / "stability" / "seeds.png").exists()  # one seed at smoke: no seed plot
    down = json.loads((published / "downstream" / "results.json").read_text())
    assert all(r.startswith(str(work / "ablation")) for runs in down["checkpoints"].values() for r in runs)
    perfect = down["pushing"]["table"]["perfect"]
    for obj in pushing.OBJECTS:  # a perfect tactile sensor: only the reference's drift and noise remain
        assert perfect[obj.name]["weight_error"]["mean"] < 0.05 * obj.mass_kg, obj.name
    assert "Weight(1)" in (published / "downstream" / "table4.md").read_text()

    # both benchmarks: every section of the whole one, the simulator's paths and their agreement
    _bench_plans.check_bench(published / "bench", common.read_json(published / "bench" / "results.json"))
    sim_res = common.read_json(published / "bench-sim" / "results.json")
    _bench_plans.check_sim(published / "bench-sim", sim_res)
    made = sim_res["sim_speed"]["dataset"]  # the ablation's dataset, timed by the call that made it: not made twice
    assert made["made_in"] == str(data.absolute()) and made["seconds"] > 0 and made["presses"] > 0
    assert "timed by the call that made the pipeline's dataset" in (published / "bench-sim" / "report.md").read_text()

    # a cell the ablation trained takes every further seed it finished (here: a copy re-keyed as seed 1)
    cfg, spec = configs.get("smoke"), registry.get("dino_rd")
    runs = work / "ablation" / "runs" / "dino_rd"
    shutil.copytree(runs / "seed0", runs / "seed1")
    shutil.copytree(runs / "seed0", runs / "seed2")  # seed 0's key: a run trained with another key is never taken
    stage = common.read_json(runs / "seed1" / "stage.json")
    common.write_json(runs / "seed1" / "stage.json", {**stage, "key": kernel.train_key(cfg, spec, 1, data)})
    assert kernel.seeds_for(cfg, spec, 1, data, work / "ablation") == [0, 1]
    assert kernel.seeds_for(cfg, spec, 1, data, None) == [0]

    # the results notebook shows the published tree (Tables I-III and every companion) without its runs
    monkeypatch.setenv("FFJAX_RESULTS", str(published / "ablation" / "results.json"))
    _notebooks.execute(ROOT / "notebooks" / "results.ipynb", published / "ablation", monkeypatch)

    # the index: every result with its command and wall time; status calls them current at this commit
    index = (published / "README.md").read_text()
    for e in pipeline:
        assert f"--only {e.name}`" in index, e.name
    assert f"The last call ran {', '.join(e.name for e in pipeline)} at `{common.git_commit()[:12]}` on " in index
    saved = json.loads((published / "reproduce.json").read_text())
    assert saved["preset"] == "smoke" and set(saved["experiments"]) == set(record["experiments"])
    rows = status.check_all(published)
    assert len(rows) == len(pipeline)
    if not common.git_commit().endswith("-dirty") and common.git_commit() != "unknown":  # a clean checkout (CI)
        assert [r.state for r in rows] == ["current"] * len(rows), [(r.folder.name, r.why) for r in rows]
    _docs_regenerate_from(published, tmp_path / "repo", monkeypatch)  # last: it moves common.ROOT off the checkout


# The benchmarks run toy plans here (_bench_plans.PIPELINE, and no torch in the test venv): the sections the docs
# quote from the quick plan's profile, decoders, bf16, solve floor and frame size are not made, so those two files
# are left out of this check (doc_tables --check holds their blocks to the published quick results).
_TOY_PLANS = re.compile(r"docs/results/quick/bench(-sim)?/(results\.json|report\.md) ")


def _docs_regenerate_from(published: Path, fake_root: Path, monkeypatch) -> None:
    """Issue 62: a reproduce followed by the doc generator is the whole update. README and docs/*.md, beside this
    call's results published over a copy of docs/results (as reproduce publishes: the real-sensor results and the
    on-request experiments stay, reproduce.json merges), regenerate: every value a block quotes is one the pipeline
    writes (but for the benchmarks' toy plans, _TOY_PLANS), and no measured number is typed by hand outside them."""
    results = fake_root / "docs" / "results"
    shutil.copytree(ROOT / "docs" / "results", results, ignore=shutil.ignore_patterns("*.png"))
    quick = results / "quick"
    for made in published.iterdir():
        if made.is_dir():
            shutil.rmtree(quick / made.name, ignore_errors=True)
            shutil.copytree(made, quick / made.name)
    common.write_json(quick / "reproduce.json",
                      reproduce.merged_record(quick / "reproduce.json", common.read_json(published / "reproduce.json")))
    monkeypatch.setattr(common, "ROOT", fake_root)
    renders = {doc_tables._BLOCK: doc_tables._render, doc_tables._INCLUDE: doc_tables._include,
               doc_tables._TEXT: doc_tables._text}
    missing, quoted = [], 0
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = doc.read_text()
        for block, render in renders.items():  # every block that fails, not only the first
            for m in block.finditer(text):
                quoted += 1
                try:
                    render(m)
                except (KeyError, FileNotFoundError, ValueError) as e:
                    if not _TOY_PLANS.search(str(e) + " "):
                        missing.append(f"{doc.name}: {e}")
        assert doc_numbers.hand_typed(text) == [], doc.name
    assert quoted > 100
    assert not missing, "blocks quote what the pipeline did not write:\n" + "\n".join(missing)


def test_each_finished_experiment_is_recorded_before_the_next_starts(tmp_path, monkeypatch):
    """A pipeline killed (here: crashed) in its third experiment keeps the wall times of the first two in
    WORK/reproduce.json: hours of measured work are not lost with the call."""
    names = [e.name for e in catalog.pipeline()][:3]

    def fake_run(exp, argv):
        if exp.name == names[2]:
            raise KeyboardInterrupt
        return 12.5

    monkeypatch.setattr(reproduce, "run_one", fake_run)
    work = tmp_path / "work"
    try:
        reproduce.main(["--preset", "smoke", "--only", *names, "--work", str(work), "--no-publish", "--quiet"])
    except KeyboardInterrupt:
        pass
    saved = json.loads((work / "reproduce.json").read_text())
    assert set(saved["experiments"]) == set(names[:2])
    assert all(e["wall_s"] == 12.5 and e["fresh"] for e in saved["experiments"].values())



def test_the_pipeline_releases_compiled_programs_between_experiments(tmp_path, monkeypatch, capsys):
    """The experiments share one process: after each, past half the kernel's limit on memory mappings, jax's
    caches are dropped (experiments.mappings), and the call says so."""
    names = [e.name for e in catalog.pipeline()][:2]
    monkeypatch.setattr(reproduce, "run_one", lambda exp, argv: 1.0)
    calls = []
    monkeypatch.setattr(mappings, "release_if_crowded", lambda: calls.append(1) or True)
    reproduce.main(["--preset", "smoke", "--only", *names, "--work", str(tmp_path / "w"), "--no-publish", "--quiet"])
    assert len(calls) == 2
    assert capsys.readouterr().err.count("released jax's compiled programs") == 2


def test_release_if_crowded_drops_jax_caches_only_past_the_share(monkeypatch):
    f = jax.jit(lambda x: x + 1)
    f(1)
    assert f._cache_size() == 1
    if mappings.count() is None:
        pytest.skip("no /proc/self/maps here")
    monkeypatch.setattr(mappings, "limit", lambda: 10**9)  # far above what any process holds: nothing happens
    assert not mappings.release_if_crowded()
    assert f._cache_size() == 1
    monkeypatch.setattr(mappings, "limit", lambda: 2 * mappings.count() - 2)  # just past half of it
    assert mappings.release_if_crowded()
    assert f._cache_size() == 0
    assert f(1) == 2  # compiles again
