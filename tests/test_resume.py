"""The loop: kill + resume equals an uninterrupted run; a non-finite loss stops and keeps the last good
checkpoint; the run folder is self-describing (load_checkpoint)."""

import json

import jax
import numpy as np
import pytest
from _tiny_data import write_tiny_dataset

import configs
from ffjax import store, train

METHOD = "dino_rd"  # the same smoke model and optimizer as test_train: one compiled step for both files


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    return write_tiny_dataset(tmp_path_factory.mktemp("tiny_data"), 32, 12)


@pytest.fixture(scope="module")
def cfg():
    # 4 steps an epoch, 3 epochs, checkpoints every 5 steps and at epoch ends (4, 5, 8, 10, 12).
    return configs.get("smoke", {"train.epochs": 3, "train.ckpt_every": 5})


def _leaves(tree):
    return [np.asarray(x) for x in jax.tree.leaves(jax.device_get(tree))]


@pytest.fixture(scope="module")
def uninterrupted(cfg, tiny_data, tmp_path_factory):
    out = tmp_path_factory.mktemp("run_a")
    return train.train(cfg, METHOD, tiny_data, out, progress=False)


def test_run_folder_is_self_describing(uninterrupted):
    run = uninterrupted["run_dir"]
    assert uninterrupted["complete"] and uninterrupted["steps"] == 12
    info = json.loads(open(f"{run}/model.json").read())
    assert info["method"] == METHOD and info["input_size"] == 32 and len(info["stats"]["force_max"]) == 3
    val = uninterrupted["val"]
    assert val["n"] == 12 and len(val["nl1_axes"]) == 3 and np.isfinite(val["nl1"])
    rows = [json.loads(r) for r in open(f"{run}/train_log.jsonl")]
    assert [r["step"] for r in rows if r["kind"] == "train"] == list(range(1, 13))
    assert len(open(f"{run}/epochs.csv").read().splitlines()) == 1 + 3
    loaded = store.load(run, which="latest")
    cfg_l, spec, stats, variables = loaded.cfg, loaded.spec, loaded.stats, loaded.variables
    assert spec.name == METHOD and cfg_l["model"]["vit"]["dim"] == 32
    assert stats.force_max == tuple(info["stats"]["force_max"])
    for a, b in zip(_leaves(variables["params"]), _leaves(uninterrupted["state"].params)):
        np.testing.assert_array_equal(a, b)
    best = store.load(run, which="best").variables
    assert jax.tree.structure(best["params"]) == jax.tree.structure(variables["params"])


def test_val_every_skips_validation_but_always_validates_the_last_epoch(cfg, tiny_data, uninterrupted, tmp_path):
    import csv

    run = train.train(configs.get("smoke", {"train.epochs": 3, "train.ckpt_every": 5, "train.val_every": 2}),
                      METHOD, tiny_data, tmp_path / "run", progress=False)
    rows = list(csv.DictReader(open(tmp_path / "run" / "epochs.csv")))
    assert [r["epoch"] for r in rows] == ["1", "2", "3"]
    assert [r["val_loss"] != "" for r in rows] == [False, True, True]  # epoch 2 (every 2nd) and the last
    vals = [json.loads(r) for r in open(tmp_path / "run" / "train_log.jsonl")]
    assert [r["epoch"] for r in vals if r["kind"] == "val"] == [2, 3]
    assert run["best_epoch"] in (2, 3) and run["eval_time_s"] > 0
    # the same training: validation only reads, so the weights equal the every-epoch run's
    for a, b in zip(_leaves(run["state"].params), _leaves(uninterrupted["state"].params)):
        np.testing.assert_array_equal(a, b)


def test_kill_and_resume_matches_uninterrupted(cfg, tiny_data, uninterrupted, tmp_path):
    class Killed(RuntimeError):
        pass

    def kill_at_7(step, state):
        if step == 7:  # after the step-5 checkpoint, before the epoch-2 one
            raise Killed

    with pytest.raises(Killed):
        train.train(cfg, METHOD, tiny_data, tmp_path, progress=False, callback=kill_at_7)
    with pytest.raises(FileExistsError):
        train.train(cfg, METHOD, tiny_data, tmp_path, progress=False)
    resumed = train.train(cfg, METHOD, tiny_data, tmp_path, resume=True, progress=False)
    assert resumed["steps"] == 12
    for a, b in zip(_leaves(resumed["state"].arrays()), _leaves(uninterrupted["state"].arrays())):
        np.testing.assert_array_equal(a, b)
    assert resumed["val"]["nl1"] == uninterrupted["val"]["nl1"]
    assert resumed["best_step"] == uninterrupted["best_step"]

    def losses(run):
        rows = [json.loads(r) for r in open(f"{run}/train_log.jsonl")]
        return [(r["step"], r["loss"]) for r in rows if r["kind"] == "train"]

    assert losses(tmp_path) == losses(uninterrupted["run_dir"])


def test_max_steps_then_resume_matches(cfg, tiny_data, uninterrupted, tmp_path):
    part = train.train(cfg, METHOD, tiny_data, tmp_path, progress=False, max_steps=6)
    assert part["steps"] == 6 and not part["complete"]
    done = train.train(cfg, METHOD, tiny_data, tmp_path, resume=True, progress=False)
    for a, b in zip(_leaves(done["state"].params), _leaves(uninterrupted["state"].params)):
        np.testing.assert_array_equal(a, b)


def test_non_finite_loss_stops_and_keeps_last_good_checkpoint(cfg, tiny_data, tmp_path):
    def poison_at_7(step, state):
        if step == 7:  # the step-8 loss becomes NaN
            return state.replace(params=jax.tree.map(lambda p: p * np.nan, state.params))
        return None

    with pytest.raises(train.NonFiniteLossError, match=r"step 8 .*Last good checkpoint: step 5"):
        train.train(cfg, METHOD, tiny_data, tmp_path, progress=False, callback=poison_at_7)
    variables = store.load(tmp_path, which="latest").variables
    assert all(np.isfinite(x).all() for x in _leaves(variables["params"]))
    best = store.load(tmp_path, which="best").variables  # epoch 1 (step 4)
    assert all(np.isfinite(x).all() for x in _leaves(best["params"]))
