"""Suite-wide guard, in CI: the tests never write into the user's own data/, runs/ or results/ folders."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

from experiments import mappings

ROOT = Path(__file__).resolve().parents[1]
# Tests run the smoke preset: a command that forgot its --data/--out would land in one of these defaults
# (data/<preset>, runs/<preset>-<method>, results/<experiment>-<preset>; under the repo or the working directory).
DEFAULTS = ("data/smoke", "runs/smoke-*", "results/*-smoke")
_OWN_CACHE: list[str] = []


def pytest_configure(config):
    """jax's compile cache (ffjax.compile_cache) in one folder for the run, shared by the xdist workers and every
    command a test starts (they inherit FFJAX_CACHE): a program one of them compiled, the others load. A fresh
    folder each run, removed at its end, so no entry of an earlier checkout is read."""
    if "FFJAX_CACHE" not in os.environ and not hasattr(config, "workerinput"):
        os.environ["FFJAX_CACHE"] = tempfile.mkdtemp(prefix="ffjax-test-cache-")
        _OWN_CACHE.append(os.environ["FFJAX_CACHE"])
    from ffjax import compile_cache

    compile_cache.enable()


def pytest_unconfigure(config):
    for folder in _OWN_CACHE:
        shutil.rmtree(folder, ignore_errors=True)


def _snapshot() -> dict[str, int]:
    """Every path under those defaults with its modification time."""
    seen = {}
    for base in {ROOT, Path.cwd().resolve()}:
        for top in (p for pattern in DEFAULTS for p in base.glob(pattern)):
            for p in (top, *top.rglob("*")):
                try:
                    seen[str(p)] = p.stat().st_mtime_ns
                except FileNotFoundError:  # removed while we looked: a change the comparison still sees
                    pass
    return seen


@pytest.fixture(scope="session", autouse=True)
def users_folders_untouched():
    if os.environ.get("CI") != "true":  # only a fresh CI clone is sure to have no other smoke run writing there
        yield
        return
    before = _snapshot()
    yield
    after = _snapshot()
    changed = sorted(p for p in before.keys() | after.keys() if before.get(p) != after.get(p))
    assert not changed, f"the tests wrote into the user's folders (pass --data/--out under tmp_path): {changed[:5]}"


@pytest.fixture(autouse=True)
def compiled_programs_released():
    """A worker of the whole suite compiles thousands of programs: past half the kernel's limit on mappings
    (experiments.mappings) jax's caches are dropped, so the worker never reaches it."""
    yield
    mappings.release_if_crowded()


# The suite's longest files, started first. pyproject's addopts deal whole files to the xdist workers
# (--dist loadfile): a module's fixtures are built once, not once per worker, and no worker waits on a lock
# (_smoke_run.shared) for the other to build what both drew. They are dealt in collection order
# (--no-loadscope-reorder; xdist would otherwise deal the files with the most tests first, and the pipeline test's
# file of four came last): one of these drawn last would leave the other worker idle for its whole length.
# test_reproduce builds the suite's smoke dataset first thing; the files that read it (test_rel_cli_errors,
# test_ablation) come after enough other work not to wait for it.
FIRST = ("tests/test_reproduce.py", "tests/test_bench.py", "tests/reliability/test_rel_faults.py",
         "tests/reliability/test_rel_faults_cases.py", "tests/test_compute_dtype.py",
         "tests/reliability/test_rel_cli_errors.py")


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(FIRST)))  # stable: the rest keep their order
