"""`python -m ffjax.train` on the FeelAnyForce release layout (CSV + PNG + .npy) and from release weights."""

import json
import re
from pathlib import Path

import _smoke_run
import pytest

from ffjax import data
from ffjax.data import csv_layout
from ffjax.train import __main__ as cli
from ffjax.train import init_weights

FIXTURES = Path(__file__).parent / "fixtures"


@pytest.fixture(scope="module")
def release_csvs(tmp_path_factory):
    """A tiny dataset in the release layout, written by the test: train and val CSVs."""
    root = tmp_path_factory.mktemp("release")
    for split, n, seed in (("train", 16, 3), ("val", 8, 4)):
        _smoke_run.write_split(root / "shards" / split, n, seed)
        csv_layout.write_csv(data.open_split(root / "shards" / split), root / split, progress=False)
    return root / "train" / "data.csv", root / "val" / "data.csv"


def test_trains_on_release_csv(release_csvs, tmp_path, capsys):
    train_csv, val_csv = release_csvs
    assert train_csv.read_text().splitlines()[0].split(",")[:3] == ["tactile", "depth", "FT"]
    rc = cli.main(["--preset", "smoke", "--method", "dino_rd", "--data", str(train_csv), "--val", str(val_csv),
                   "--out", str(tmp_path / "run"), "--quiet"])
    assert rc == 0
    assert "final validation force error" in capsys.readouterr().out
    info = json.loads((tmp_path / "run" / "model.json").read_text())
    assert info["frame_size"] == list(_smoke_run.frame_size())


@pytest.mark.parametrize("entry", ["ffjax.train.__main__:parse_args", "ffjax.train.pretrain.__main__:main"])
def test_help_names_the_default_preset_and_its_cost(entry, capsys):
    """Nobody starts a run of minutes without --help saying where its measured time is published; the time itself
    is not typed in (issue 62: it would go stale)."""
    import importlib

    module, fn = entry.split(":")
    with pytest.raises(SystemExit):
        getattr(importlib.import_module(module), fn)(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: quick)" in text and "docs/" in text
    assert not re.search(r"\d\s?(?:s|min|ms)\b", text), text


def test_val_without_csv_is_refused(tmp_path, capsys):
    assert cli.main(["--preset", "smoke", "--val", "x.csv", "--out", str(tmp_path)]) == 2
    assert "--val goes with --data TRAIN.csv" in capsys.readouterr().err


def test_resume_with_nothing_to_resume_is_an_error(release_csvs, tmp_path, capsys):
    """It used to start a fresh run silently (after simulating a dataset)."""
    assert cli.main(["--preset", "smoke", "--out", str(tmp_path / "new"), "--resume"]) == 2
    assert "nothing to resume" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()
    # --resume=auto is for restart loops: it starts when there is nothing to resume
    train_csv, val_csv = release_csvs
    assert cli.main(["--preset", "smoke", "--out", str(tmp_path / "new"), "--resume=auto", "--max-steps", "1",
                     "--quiet", "--data", str(train_csv), "--val", str(val_csv)]) == 0
    assert (tmp_path / "new" / "model.json").exists()


def test_init_from_release_checkpoint(release_csvs, tmp_path):
    from ffjax.convert import __main__ as convert_cli

    train_csv, val_csv = release_csvs
    converted = tmp_path / "release"
    assert convert_cli.main(["feelanyforce", str(FIXTURES / "feelanyforce_tiny.pth.tar"), "--heads", "2",
                             "--out", str(converted)]) == 0
    rc = cli.main(["--preset", "smoke", "--method", "dino_rd", "--data", str(train_csv), "--val", str(val_csv),
                   "--init", f"feelanyforce:{converted}", "--max-steps", "1",
                   "--out", str(tmp_path / "run"), "--quiet"])
    assert rc == 0
    cfg = json.loads((tmp_path / "run" / "model.json").read_text())["cfg"]
    size = json.loads((converted / "convert.json").read_text())["input_size"]
    assert cfg["data"]["input_size"] == size and cfg["model"]["regressor"]["out_scale"] is None


def test_init_errors_name_the_problem(tmp_path):
    from ffjax import registry

    with pytest.raises(ValueError, match="KIND:PATH"):
        init_weights.parse("nonsense")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        init_weights.parse(f"dinov2:{tmp_path / 'missing.pth'}")
    with pytest.raises(ValueError, match="uses resnet"):
        init_weights.apply({}, registry.get("resnet_rd"), f"dinov2:{FIXTURES / 'dinov2_tiny.pth'}")
