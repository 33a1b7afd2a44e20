"""experiments.catalog knows every published result; experiments.status says which are current at HEAD and why;
experiments.reproduce runs the pipeline's experiments with the command lines the catalog gives."""

import json
import subprocess
from pathlib import Path

import pytest

from experiments import catalog, common, reproduce, status

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results"
HEAD = subprocess.run(["git", "rev-parse", "HEAD"], cwd=common.ROOT, capture_output=True, text=True).stdout.strip()


def _result(folder: Path, **fields) -> Path:
    folder.mkdir(parents=True)
    (folder / "results.json").write_text(json.dumps(fields))
    return folder


def test_every_published_result_has_its_experiment():
    unknown = [str(f.relative_to(RESULTS)) for f in status.find(RESULTS)
               if catalog.kind_of(common.read_json(f / "results.json")) is None]
    assert not unknown


def test_the_pipeline_runs_an_experiment_after_the_one_it_reuses():
    order = [e.name for e in catalog.pipeline()]
    assert len(order) == len(set(order))
    for i, e in enumerate(catalog.pipeline()):
        if e.reuses:
            assert e.reuses in order[:i], e.name
    assert order[0] == "ablation"


class _Parsed(Exception):
    pass


def test_each_pipeline_command_parses(tmp_path, monkeypatch):
    """The flags the catalog gives every experiment are ones its parser takes (stopped right after parsing)."""
    import argparse

    def parse_args(self, args=None, namespace=None):
        _, unknown = self.parse_known_args(args, namespace)
        assert not unknown, f"{self.prog}: {unknown}"
        raise _Parsed

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_args)
    for e in catalog.pipeline():
        with pytest.raises(_Parsed):
            e.main()(reproduce.argv_for(e, "smoke", tmp_path, quiet=True, data=tmp_path / "data"))


def test_a_result_of_head_is_current_and_one_of_unknown_code_is_stale(tmp_path):
    if not HEAD:
        pytest.skip("not a git checkout")
    _result(tmp_path / "smoke" / "pareto", commit=HEAD, cells=[], fronts=[])
    _result(tmp_path / "smoke" / "sweep", commit=HEAD + "-dirty", per_beta={})
    _result(tmp_path / "smoke" / "stab", commit="0" * 40, factors={}, seed_spread={})
    _result(tmp_path / "smoke" / "mystery", commit=HEAD, something=1)
    rows = {r.folder.name: r for r in status.check_all(tmp_path)}
    assert rows["pareto"].state == "current"
    assert rows["sweep"].state == "stale" and "uncommitted" in rows["sweep"].why[0]
    assert rows["stab"].state == "stale" and "not in this history" in rows["stab"].why[0]
    assert rows["mystery"].state == "stale" and rows["mystery"].experiment is None


def test_a_changed_source_makes_a_result_stale_and_its_readers_too(tmp_path, monkeypatch):
    """Numbers sources changed: stale, the files named; figure sources only: replot; an experiment reading a
    stale ablation's runs is stale as well."""
    changes = {("ffjax",): ["ffjax/sim/optics.py", "ffjax/sim/press.py", "ffjax/models/vit.py"]}

    def changed(commit, paths, certificates=False):
        if "ffjax/sim/press.py" in paths and "experiments/sweep_loss.py" not in paths and "abl" in commit:
            return changes[("ffjax",)]
        if "experiments/tables.py" in paths and "sw" in commit:
            return ["experiments/tables.py"]
        return []

    monkeypatch.setattr(status, "changed_since", changed)
    _result(tmp_path / "quick" / "ablation", commit="abl", table1={})
    _result(tmp_path / "quick" / "stability", commit="st", factors={}, seed_spread={})
    _result(tmp_path / "other" / "sweep_loss", commit="sw", per_beta={})
    rows = {str(r.folder.relative_to(tmp_path)): r for r in status.check_all(tmp_path)}
    assert rows["quick/ablation"].state == "stale"
    assert status._why(rows["quick/ablation"]) == "ffjax/sim (2 files), ffjax/models (1 file)"
    assert rows["quick/stability"].state == "stale" and "ablation" in rows["quick/stability"].why[0]
    assert rows["other/sweep_loss"].state == "replot"  # its ablation is in another tree: not read


def test_status_cli_lists_checks_and_writes_the_index(tmp_path, capsys):
    if not HEAD:
        pytest.skip("not a git checkout")
    _result(tmp_path / "pareto", commit=HEAD, cells=[], fronts=[], preset="smoke")
    assert status.main([str(tmp_path), "--check", "--index"]) == 0
    out = capsys.readouterr().out
    assert "1 results: 1 current" in out
    page = (tmp_path / "README.md").read_text()
    assert "[pareto](pareto/)" in page and "Speed against accuracy" in page and HEAD[:7] in page
    _result(tmp_path / "old", commit="0" * 40, per_beta={})
    assert status.main([str(tmp_path), "--check", "--stale"]) == 1
    assert "pareto" not in capsys.readouterr().out.split("\n\n")[0]


def test_publish_leaves_the_trained_runs_behind(tmp_path):
    src = tmp_path / "work" / "ablation"
    (src / "runs" / "dino_rd" / "seed0").mkdir(parents=True)
    (src / "runs" / "dino_rd" / "seed0" / "model.json").write_text("{}")
    (src / "results.json").write_text("{}")
    (src / "table1.md").write_text("t")
    (src / "share0" / "runs" / "x").mkdir(parents=True)  # a folder of runs only: not published, not even empty
    (src / "share1" / "runs").mkdir(parents=True)
    (src / "share1" / "note.md").write_text("n")
    dst = tmp_path / "pub" / "ablation"
    dst.mkdir(parents=True)
    (dst / "stale.md").write_text("old")
    reproduce.publish(src, dst)
    assert sorted(str(p.relative_to(dst)) for p in dst.rglob("*")) == ["results.json", "share1", "share1/note.md",
                                                                       "table1.md"]


def test_an_only_call_keeps_the_other_experiments_records(tmp_path):
    path = tmp_path / "reproduce.json"
    common.write_json(path, {"preset": "quick", "commit": "a" * 40,
                             "experiments": {"ablation": {"wall_s": 10.0, "commit": "a" * 40}}})
    merged = reproduce.merged_record(path, {"preset": "quick", "commit": "b" * 40,
                                            "experiments": {"sweep_loss": {"wall_s": 5.0, "commit": "b" * 40}}})
    assert set(merged["experiments"]) == {"ablation", "sweep_loss"} and merged["commit"] == "b" * 40
    assert merged["experiments"]["ablation"]["commit"] == "a" * 40  # each entry keeps the commit it ran
    # a re-run that reused every cached stage keeps the cost of the run that did the work
    common.write_json(path, merged)
    again = reproduce.merged_record(path, {"preset": "quick", "commit": "c" * 40, "experiments": {
        "ablation": {"wall_s": 0.5, "commit": "c" * 40, "fresh": False}}})
    assert again["experiments"]["ablation"]["work"] == {"wall_s": 10.0, "commit": "a" * 40}


def test_an_only_call_leaves_each_earlier_entry_the_machine_it_ran_on(tmp_path):
    """The top-level machine is the last call's; an entry made by an earlier call on another machine keeps that
    one (a --help cost must not put the ablation's minutes on the machine that only re-ran a benchmark)."""
    path = tmp_path / "reproduce.json"
    zen, xeon = {"cpu_model": "AMD EPYC", "cores": 2}, {"cpu_model": "Intel Xeon", "cores": 2}
    common.write_json(path, {"preset": "quick", "commit": "a" * 40, "machine": zen, "experiments": {
        "ablation": {"wall_s": 10.0, "commit": "a" * 40}, "old": {"wall_s": 1.0, "commit": "0" * 40}}})
    merged = reproduce.merged_record(path, {"preset": "quick", "commit": "b" * 40, "machine": xeon, "experiments": {
        "bench": {"wall_s": 5.0, "commit": "b" * 40, "machine": xeon}}})
    assert merged["machine"] == xeon and merged["experiments"]["bench"]["machine"] == xeon
    assert merged["experiments"]["ablation"]["machine"] == zen  # made by the call that recorded zen
    assert "machine" not in merged["experiments"]["old"]  # made by a call before that one: not known


def _commit(repo: Path, files: dict, message: str) -> str:
    for name, text in files.items():
        path = repo / name
        if text is None:
            subprocess.run(["git", "rm", "-q", name], cwd=repo, check=True)
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        subprocess.run(["git", "add", name], cwd=repo, check=True)
    subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", message], cwd=repo, check=True)
    return subprocess.run(["git", "rev-parse", "HEAD"], cwd=repo, capture_output=True, text=True).stdout.strip()


def test_docstrings_comments_and_moves_out_are_no_change_of_numbers(tmp_path):
    """Only code counts: a docstring, comment or layout change leaves a result current, a file moved out of
    its sources (the importer's change is what is named) too; a code change or a deletion does not."""
    repo = tmp_path / "repo"
    repo.mkdir()
    subprocess.run(["git", "init", "-q"], cwd=repo, check=True)
    code = '"""A module."""\n\n\ndef f(x):\n    """Twice x."""\n    return 2 * x\n'
    drawing = "def draw():\n    return 1\n" + "# filler so git sees the move as a rename\n" * 8
    first = _commit(repo, {"lib/a.py": code, "lib/draw.py": drawing, "lib/data.txt": "1\n"}, "first")
    _commit(repo, {"lib/a.py": '"""A module, said better."""\n\n\ndef f(x):  # why\n    """Two x."""\n\n'
                                '    return 2 * x\n'}, "words")
    assert status.changed_since(first, ["lib"], root=repo) == []
    (repo / "lib" / "draw.py").rename(repo / "lib" / "moved.py")
    subprocess.run(["git", "add", "-A"], cwd=repo, check=True)
    _commit(repo, {}, "move within")
    assert status.changed_since(first, ["lib"], root=repo) == []  # a rename inside with the same code
    subprocess.run(["git", "mv", "lib/moved.py", "figures.py"], cwd=repo, check=True)
    _commit(repo, {}, "move out")
    assert status.changed_since(first, ["lib"], root=repo) == []
    _commit(repo, {"lib/a.py": '"""A module."""\n\n\ndef f(x):\n    return 3 * x\n'}, "code")
    assert status.changed_since(first, ["lib"], root=repo) == ["lib/a.py"]
    _commit(repo, {"lib/data.txt": None}, "delete")
    assert sorted(status.changed_since(first, ["lib"], root=repo)) == ["lib/a.py", "lib/data.txt"]
    assert status.changed_since("0" * 40, ["lib"], root=repo) is None


def test_a_certified_change_of_the_simulator_is_no_change_of_numbers(tmp_path):
    """A certificate (experiments.same_output: base and head rendered the same bytes) clears its files for results
    that ran the base's code, while HEAD holds the head's; a later change, or a result of other code, is not
    cleared."""
    repo = tmp_path / "repo"
    repo.mkdir()
    subprocess.run(["git", "init", "-q"], cwd=repo, check=True)
    first = _commit(repo, {"ffjax/sim/a.py": "x = 1\n", "lib/b.py": "y = 1\n"}, "first")
    second = _commit(repo, {"ffjax/sim/a.py": "x = 1  # faster\nz = 2\n", "lib/b.py": "y = 2\n"}, "speed-up")
    paths = ["ffjax", "lib"]
    assert sorted(status.changed_since(first, paths, root=repo, certificates=True)) == ["ffjax/sim/a.py",
                                                                                         "lib/b.py"]
    record = {"certified": [{"base": first, "head": second, "files": ["ffjax/sim/a.py"]}]}
    _commit(repo, {"experiments/same_output.json": json.dumps(record)}, "certify")
    assert status.changed_since(first, paths, root=repo, certificates=True) == ["lib/b.py"]
    assert sorted(status.changed_since(first, paths, root=repo)) == ["ffjax/sim/a.py", "lib/b.py"]  # a benchmark
    assert status.changed_since(second, paths, root=repo, certificates=True) == []
    third = _commit(repo, {"ffjax/sim/a.py": "x = 3\n"}, "new physics")
    assert sorted(status.changed_since(first, paths, root=repo, certificates=True)) == ["ffjax/sim/a.py",
                                                                                         "lib/b.py"]
    # certificates chain: first's code -> second's, then second's -> third's
    record["certified"].append({"base": second, "head": third, "files": ["ffjax/sim/a.py"]})
    _commit(repo, {"experiments/same_output.json": json.dumps(record)}, "certify again")
    assert status.changed_since(first, paths, root=repo, certificates=True) == ["lib/b.py"]


def test_the_benchmarks_alone_time_the_simulator():
    """Only the results whose numbers are speeds ignore certificates."""
    assert {e.name for e in catalog.EXPERIMENTS if e.speed} == {"bench", "bench-sim"}


def test_a_replotted_result_is_current_until_its_figures_change_again(tmp_path, monkeypatch):
    """experiments.replot records the commit it drew with; status compares the figures' sources from there."""
    asked = []

    def changed(commit, paths, certificates=False):
        asked.append(commit)
        return ["experiments/tables.py"] if "experiments/tables.py" in paths and commit == "old" else []

    monkeypatch.setattr(status, "changed_since", changed)
    _result(tmp_path / "a" / "sweep_loss", commit="old", per_beta={})
    _result(tmp_path / "b" / "sweep_loss", commit="old", per_beta={}, replotted="new")
    _result(tmp_path / "c" / "sweep_loss", commit="old", per_beta={}, replotted="new-dirty")
    rows = {r.folder.parent.name: r.state for r in status.check_all(tmp_path)}
    assert rows == {"a": "replot", "b": "current", "c": "replot"}


def test_number_sources_are_the_code_a_command_runs_less_its_drawing():
    """The import closure of the experiment's module: the simulator and the training for Table I, not the live
    loop; the modules that only draw are figure sources; a command outside the graph takes the whole library."""
    ablation = catalog.get("ablation").number_sources
    for f in ("configs", "pyproject.toml", "experiments/ablation.py", "experiments/aggregate.py",
              "experiments/kernel.py", "ffjax/sim/press.py", "ffjax/train/loop.py", "ffjax/calibrate/__init__.py"):
        assert f in ablation, f
    assert not [f for f in ablation if f.startswith(("ffjax/live", "ffjax/export"))]
    assert not {"experiments/tables.py", "experiments/training_figures.py", "experiments/style.py"} & set(ablation)
    assert "ffjax/tasks/pushing.py" in catalog.get("downstream").number_sources
    assert "experiments/downstream_report.py" not in catalog.get("downstream").number_sources
    assert "ffjax" in catalog.get("faults").number_sources


def test_each_diagnostic_is_told_apart_and_stale_only_by_what_it_runs():
    """low_force's results.json (a list under "physics") is not taken for shear_probe's (a dict); a diagnostic's
    numbers come from the files its module runs, not from every diagnostic in the folder."""
    assert catalog.kind_of({"physics": [], "render_size": [48, 64]}).name == "low_force"
    assert catalog.kind_of({"physics": {"rows": [], "sign_ok": True}}).name == "shear_probe"
    sources = catalog.get("buried_load_check").number_sources
    assert "experiments/diagnostics/plane_strain_fe.py" in sources
    assert "experiments/diagnostics/low_force.py" not in sources


def test_seeds_column_spans_the_cells_of_every_kind():
    one, three = {"per_seed": [{}]}, {"per_seed": [{}, {}, {}]}
    exp = {e.name: e for e in catalog.EXPERIMENTS}
    assert status._seeds({"per_beta": {"0": three, "1": one}}, exp["sweep_loss"]) == "1-3"
    assert status._seeds({"cells": [{"seeds": [0]}, {"seeds": [0, 1, 2]}]}, exp["pareto"]) == "1-3"
    assert status._seeds({"seeds": [0], "per_share": {"0": {"methods": {"dino_rd": one}},
                                                      "0.5": {"methods": {"dino_rd": three}}}},
                         exp["pattern_share"]) == "1-3"
    assert status._seeds({"seeds": [0, 1, 2]}) == "3"


def test_the_index_gives_the_default_command_time_only_when_one_call_made_it(tmp_path):
    """The default command's time is stated only when all its experiments ran at one commit on one machine; an
    --only call's entries (another commit) or a missing experiment leave it unsaid."""
    machine = {"cpu_model": "Test CPU", "cores": 2}
    names = [e.name for e in catalog.one_command()]
    entries = {n: {"wall_s": 60.0, "commit": "a" * 40, "machine": machine} for n in names}
    record = {"preset": "quick", "commit": "a" * 40, "machine": machine, "experiments": entries}
    line = status._default_command(record)
    assert line and f"{len(names)} min wall" in line and "Test CPU (2 cores)" in line and "a" * 12 in line
    on_request = [e.name for e in catalog.pipeline() if e.on_request]
    assert all(n in line for n in on_request)  # said to be left out
    other = {**entries, names[0]: {**entries[names[0]], "commit": "b" * 40}}
    assert status._default_command({**record, "experiments": other}) is None
    assert status._default_command({**record, "experiments": dict(list(entries.items())[1:])}) is None


def test_an_only_call_keeps_the_default_commands_last_whole_run(tmp_path):
    """An --only call at another commit replaces one entry: the default command's last whole run (its commit,
    machine and summed time) stays in reproduce.json and on the index."""
    machine = {"cpu_model": "Test CPU", "cores": 2}
    names = [e.name for e in catalog.one_command()]
    path = tmp_path / "reproduce.json"
    common.write_json(path, {"preset": "quick", "commit": "a" * 40, "machine": machine,
                             "experiments": {n: {"wall_s": 60.0, "commit": "a" * 40} for n in names}})
    merged = reproduce.merged_record(path, {"preset": "quick", "commit": "b" * 40, "machine": machine,
                                            "experiments": {names[-1]: {"wall_s": 6.0, "commit": "b" * 40}}})
    assert status.default_call(merged) is None  # the entries now span two commits
    kept = merged["default_command"]
    assert kept["commit"] == "a" * 40 and kept["wall_s"] == 60.0 * len(names) and kept["machine"] == machine
    assert f"`{'a' * 12}`" in status._default_command(merged)
    common.write_json(path, merged)  # a further --only call keeps it still
    again = reproduce.merged_record(path, {"preset": "quick", "commit": "c" * 40, "machine": machine,
                                           "experiments": {names[0]: {"wall_s": 5.0, "commit": "c" * 40}}})
    assert again["default_command"] == kept
