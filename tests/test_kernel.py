"""experiments.kernel without training: the run folder layout and when another experiment's run is reused."""

import json

import pytest

from experiments import common, kernel
from ffjax import registry


def test_run_dir_layout():
    assert kernel.run_dir("/r/out", "dino_rd", 3).as_posix() == "/r/out/runs/dino_rd/seed3"
    assert kernel.run_dir("/r/out", "dino_rd", 0, "vit-xs").as_posix() == "/r/out/runs/vit-xs/dino_rd/seed0"
    assert kernel.seeds({"seed": 5}, 3) == [5, 6, 7]


@pytest.fixture
def ablation_run(tmp_path):
    """A finished run of dino_rd seed 0 in an ablation folder, and the config and data it was trained on."""
    cfg = {k: {"x": 1} for k in ("data", "model", "train", "pretrain")}
    data_root = tmp_path / "data"
    data_root.mkdir()
    (data_root / "manifest.json").write_text(json.dumps({"config": {"n": 1}}))
    spec = registry.get("dino_rd")
    folder = kernel.run_dir(tmp_path / "abl", spec.name, 0)
    stage = common.Stage(folder, kernel.train_key(cfg, spec, 0, data_root))
    return tmp_path / "abl", cfg, spec, data_root, stage


def test_reuses_only_a_finished_run_with_the_same_key(ablation_run):
    abl, cfg, spec, data_root, stage = ablation_run
    assert kernel.reusable(abl, cfg, spec, 0, data_root) is None  # started, not finished
    stage.finish()
    assert kernel.reusable(abl, cfg, spec, 0, data_root) == stage.folder and stage.folder.is_absolute()
    assert kernel.reusable(None, cfg, spec, 0, data_root) is None
    assert kernel.reusable(abl, cfg, spec, 1, data_root) is None  # another seed
    assert kernel.reusable(abl, cfg, registry.get("dino_r"), 0, data_root) is None  # another method
    other = {**cfg, "train": {"x": 2}}
    assert kernel.reusable(abl, other, spec, 0, data_root) is None  # trained with another config


def test_run_uses_the_reused_folder_without_training(ablation_run, monkeypatch):
    abl, cfg, spec, data_root, stage = ablation_run
    stage.finish()
    monkeypatch.setattr(kernel, "train", lambda *a, **k: pytest.fail("a reusable run was trained again"))
    monkeypatch.setattr(kernel, "evaluate", lambda c, folder, d, force=False: {"folder": folder})
    r = kernel.run(cfg, spec, 0, data_root, abl.parent / "sweep", reuse_from=abl)
    assert r.reused and r.dir == stage.folder and r.result == {"folder": stage.folder}


def test_keys_the_config_gained_keep_older_runs_valid(tmp_path):
    """A config key added at the value the code used before leaves the training key as it was; another value
    changes it."""
    import configs

    cfg, spec = configs.get("smoke"), registry.get("dino_rd")
    before = {**cfg, "data": {k: v for k, v in cfg["data"].items() if k != "train_sensor"}}
    assert kernel.train_key(before, spec, 0, tmp_path) == kernel.train_key(cfg, spec, 0, tmp_path)
    other = {**cfg, "data": {**cfg["data"], "train_sensor": "mini-2-gel1"}}
    assert kernel.train_key(other, spec, 0, tmp_path) != kernel.train_key(cfg, spec, 0, tmp_path)


def test_run_all_pools_pairs_of_runs_that_need_training(ablation_run, monkeypatch):
    """With 2 workers, the runs left to train go to the pool in pairs (the odd one trains here on every core),
    a reusable or finished run never does, and a pooled run reports its worker's seconds."""
    abl, cfg, spec, data_root, stage = ablation_run
    stage.finish()  # dino_rd seed 0 is reusable from the ablation
    out = abl.parent / "sweep"
    jobs = [kernel.Job(cfg, spec, seed, data_root, out, reuse_from=abl) for seed in range(4)]
    pooled_calls = []

    def pooled(js, workers, force, progress, desc):
        pooled_calls.append([j.seed for j in js])
        for j in js:  # what a worker leaves: the run trained
            common.Stage(j.folder(), kernel.train_key(cfg, spec, j.seed, data_root)).finish()
        return {j.folder(): (100.0 + j.seed, 1.0) for j in js}

    trained_here = []

    def train(c, s, seed, d, folder, *a, **k):  # as kernel.train: a finished stage is left as it is
        if not kernel.trained(folder, c, s, seed, d):
            trained_here.append(seed)
            common.Stage(folder, kernel.train_key(c, s, seed, d)).finish()

    monkeypatch.setattr(kernel, "_train_pooled", pooled)
    monkeypatch.setattr(kernel, "train", train)
    monkeypatch.setattr(kernel, "evaluate", lambda c, folder, d, force=False: {"folder": folder})
    runs = kernel.run_all(jobs, workers=2, progress=False)
    assert pooled_calls == [[1, 2]] and trained_here == [3]
    assert [r.reused for r in runs] == [True, False, False, False]
    assert [r.train_s for r in runs[1:3]] == [101.0, 102.0] and [r.eval_s for r in runs[1:3]] == [1.0, 1.0]
    assert [r.dir for r in runs[1:]] == [j.folder() for j in jobs[1:]]

    pooled_calls.clear()
    kernel.run_all(jobs, workers=2, progress=False)  # all finished now: nothing to pool, nothing trained
    assert pooled_calls == [] and trained_here == [3]
    kernel.run_all(jobs[1:], workers=1, progress=False)  # one worker: never a pool
    assert pooled_calls == []


def test_runs_of_another_size_pool_only_in_whole_groups(ablation_run):
    """pareto's cells: one run of each size is never paired (one would train alone on one core at the end)."""
    abl, cfg, spec, data_root, _ = ablation_run
    jobs = [kernel.Job(cfg, spec, seed, data_root, abl, size=size)
            for size, seed in (("vit-xs", 0), ("vit-m", 0), (None, 0), (None, 1), (None, 2))]
    assert [(j.size, j.seed) for j in kernel._poolable(jobs, 2)] == [(None, 0), (None, 1)]
    assert kernel._poolable(jobs[:2], 2) == []
