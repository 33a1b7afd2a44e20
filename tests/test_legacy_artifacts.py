"""What ffjax wrote before issue 29 changed its files (tests/fixtures/legacy, made at commit 337ea02 by
make_legacy_fixtures.py) still loads: a training run (best and latest weights, and it resumes), a bundle, a
converted release folder and a dataset, with the forces that code predicted."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import configs
from ffjax import inference, store, train
from ffjax.data import open_split
from ffjax.sim import dataset

# these artifacts predate the digests: their UnverifiedWarning is tested in reliability/test_rel_digests.py
pytestmark = pytest.mark.filterwarnings("ignore::ffjax.store.UnverifiedWarning")

LEGACY = Path(__file__).parent / "fixtures" / "legacy"
EXPECTED = json.loads((LEGACY / "expected.json").read_text())
# the data keys issue 32 added or changed, at the values the code used when the fixtures were made
THEN = {f"data.{k}": configs.KEYS[f"data.{k}"].old_value
        for k in ("loading", "tilt_max_deg", "ft_noise", "pattern_moving", "path_steps", "path_quadrature")}


def _frames():
    split = open_split(LEGACY / "data" / "train")
    return np.stack([split[i]["image"] for i in range(4)]), split[0]["background"]


@pytest.mark.parametrize("name", sorted(EXPECTED["forces"]))
def test_legacy_artifacts_predict_what_they_did(name):
    folder, _, which = name.partition("_")
    frames, background = _frames()
    kw = {"which": which} if which else {}
    if folder == "converted":
        kw["frame_size"] = frames.shape[1:3]
    pred = inference.load(LEGACY / folder, **kw)
    pred.set_background(background)
    # across CPU kinds XLA's float sums differ in the last digits (tests/_pins.py); on one machine they are equal
    np.testing.assert_allclose(pred.predict(frames), EXPECTED["forces"][name], rtol=1e-4, atol=1e-4)


def test_a_legacy_run_is_described_and_resumes(tmp_path):
    trained = store.describe(LEGACY / "run")
    assert trained.kind == "run" and trained.spec.name == "dino_rd" and "sha256" not in trained.info
    assert configs.validate(trained.cfg)  # upgraded to a full config of today
    run = tmp_path / "run"
    shutil.copytree(LEGACY / "run", run)
    cfg = configs.get("smoke", {**EXPECTED["sets"], **THEN, "train.epochs": 3})
    with pytest.warns(UserWarning, match=r"changed config: train.epochs: 2 -> 3$"):  # nothing else differs
        summary = train.train(cfg, "dino_rd", LEGACY / "data", run, resume=True, max_steps=11, progress=False)
    assert summary["steps"] == 11
    assert "sha256" in json.loads((run / "model.json").read_text())  # rewritten in today's form


def test_a_legacy_dataset_opens_and_is_not_taken_for_todays_simulator(tmp_path):
    """Its files still read; but it was made by an earlier simulator (dataset version 1, before issue 32), so a
    generate into its folder refuses it, naming the version, rather than reusing it."""
    cfg = configs.get("smoke", {**EXPECTED["sets"], **THEN})
    legacy = json.loads((LEGACY / "data" / "config.json").read_text())
    g = dataset.gen_config(cfg)
    assert g["seed"] == legacy["seed"] and {k: g["data"][k] for k in legacy["data"]} == legacy["data"]
    assert set(g["data"]) - set(legacy["data"]) == {"loading", "path_steps", "ft_noise", "pattern_moving",
                                                       "path_quadrature"}
    folder = tmp_path / "data"
    shutil.copytree(LEGACY / "data", folder)
    assert len(open_split(folder / "train")) == 20
    with pytest.raises(FileExistsError, match=r"differs in: .*version"):
        dataset._prepare(folder, dataset.gen_config(cfg), force=False)


def test_a_run_path_that_is_not_utf8_is_named(tmp_path):
    """Issue 33 (7): a non-UTF-8 byte in a run's path was reported as "its files are damaged"."""
    import os

    bad = Path(os.fsdecode(os.fsencode(tmp_path) + b"/run\xff"))
    shutil.copytree(LEGACY / "run", bad)
    from ffjax.errors import CheckpointError

    with pytest.raises(CheckpointError, match=r"run\\xff'?: the path holds bytes that are not UTF-8"):
        inference.load(bad)
