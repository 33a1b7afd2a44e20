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
