"""What keeps the training loop at the speed of its step (issue 14), checked by behaviour, not by timing:
each split is preprocessed once however often the run validates, nothing compiles after step 1, and the
log interval's lagged read still logs every step once, in order."""

import json

import pytest
from _tiny_data import write_tiny_dataset

import configs
from ffjax import data as fdata
from ffjax import train
from ffjax.store import checksums
from ffjax.train import run_log
from ffjax.train import step as step_lib

METHOD = "dino_rd"  # has the regressor's feature_norm: validation refreshes it from training frames


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    return write_tiny_dataset(tmp_path_factory.mktemp("tiny_data"), 32, 12)


def test_splits_preprocessed_once_and_nothing_compiles_after_step_1(tiny_data, tmp_path, monkeypatch):
    loads = []
    real_load = fdata.load_arrays

    def counting_load(source, *a, **k):
        loads.append(len(source))
        return real_load(source, *a, **k)

    monkeypatch.setattr(fdata, "load_arrays", counting_load)
    monkeypatch.setattr(fdata.pipeline, "load_arrays", counting_load)
    programs = (step_lib.train_step, step_lib.eval_step, step_lib.feature_step, checksums._leaf_sums)
    seen = {}

    def at_step_1(step, state):
        if step == 1:
            seen["traces"] = dict(train.TRACE_COUNT)
            seen["cached"] = [f._cache_size() for f in programs]

    # batch 6 (a shape no other test compiles): 5 steps an epoch, 3 epochs, each validated; saves at 4, 8, 12, 15
    cfg = configs.get("smoke", {"train.epochs": 3, "train.batch_size": 6, "train.ckpt_every": 4})
    run = train.train(cfg, METHOD, tiny_data, tmp_path, progress=False, callback=at_step_1)
    assert run["complete"] and run["steps"] == 15
    assert sorted(loads) == [12, 32]  # val and train, once each, for 3 validations and the training batches
    assert dict(train.TRACE_COUNT) == seen["traces"]
    assert [f._cache_size() for f in programs] == seen["cached"]


def test_lagged_log_read_logs_every_step_once_in_order(tiny_data, tmp_path):
    # batch 1: 32 steps an epoch, so the 25-step log interval falls inside an epoch and reads all but step 25
    cfg = configs.get("smoke", {"train.epochs": 1, "train.batch_size": 1, "train.ckpt_every": 100})
    train.train(cfg, METHOD, tiny_data, tmp_path, progress=False)
    rows = [json.loads(r) for r in open(tmp_path / run_log.LOG_NAME)]
    assert [r["step"] for r in rows if r["kind"] == "train"] == list(range(1, 33))
