"""Artifacts a user saves or shares (runs, bundles, converted weights, exports) are verified on load, and no
command writes over its own input or over an existing output without --force (issue 29). Each test is a case
that failed before: the command exited 0 and destroyed the run, or a damaged file changed the forces silently."""

import json
import shutil
from pathlib import Path

import _smoke_run
import numpy as np
import pytest

from ffjax import cli, export, inference, store
from ffjax.calibrate import tool as calibrate_tool
from ffjax.convert import __main__ as convert_cli
from ffjax.errors import CheckpointError

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"
RELEASE = FIXTURES / "feelanyforce_tiny.pth.tar"


@pytest.fixture()
def run(tmp_path):
    """A private copy of the shared smoke run (these tests damage their copy)."""
    shutil.copytree(_smoke_run.smoke_run(), tmp_path / "run")
    return tmp_path / "run"


def _flip(path: Path, n: int, at: float = 0.5) -> None:
    b = bytearray(path.read_bytes())
    start = int(len(b) * at)
    for i in range(start, start + n):
        b[i] ^= 0xFF
    path.write_bytes(bytes(b))


def _forces(folder) -> np.ndarray:
    pred = inference.load(folder)
    frames = _smoke_run.presses(2, seed=3)
    pred.set_background(frames["background"])
    return pred.predict(frames["image"])


def test_export_into_its_own_run_is_refused_and_the_run_survives(run, tmp_path, capsys):
    """`--out RUN/model.json` used to exit 0 and replace the run's model.json with the export."""
    before = (run / "model.json").read_bytes()
    assert cli.run(export.main, ["--checkpoint", str(run), "--out", str(run / "model.json")]) == 2
    assert f"--out {run / 'model.json'} is inside {run}" in capsys.readouterr().err
    assert (run / "model.json").read_bytes() == before
    store.load(run)  # still loads (and so resumes: the checkpoints were never touched)


def test_an_existing_export_is_replaced_only_with_force(run, tmp_path, capsys):
    out = tmp_path / "f.jaxexport"
    assert export.main(["--checkpoint", str(run), "--out", str(out)]) == 0
    assert cli.run(export.main, ["--checkpoint", str(run), "--out", str(out)]) == 2
    assert "already exists; pass --force" in capsys.readouterr().err
    assert export.main(["--checkpoint", str(run), "--out", str(out), "--force"]) == 0
    export.load(out)  # the replaced file and its sidecar agree


def test_flipped_bytes_in_an_export_are_refused(run, tmp_path):
    """8 flipped bytes used to move Fz by a newton with no warning."""
    good = export.save(inference.load(run), tmp_path / "f.jaxexport")
    _flip(good, 8)
    with pytest.raises(CheckpointError, match=rf"{good} is corrupt.*sha256 differs from the one in f\.jaxexport\.json"):
        export.load(good)


def test_edited_statistics_in_model_json_are_refused(run):
    """Editing the normalization statistics used to change the forces while the run still loaded."""
    path = run / "model.json"
    info = json.loads(path.read_text())
    info["stats"]["mean"][1] += 0.05
    path.write_text(json.dumps(info, indent=2))
    with pytest.raises(CheckpointError, match=rf"{path} was changed after it was written"):
        store.load(run)


def test_edited_bundle_model_json_is_refused(run, tmp_path):
    bundle = store.save_bundle(tmp_path / "b", store.load(run))
    path = bundle / "model.json"
    info = json.loads(path.read_text())
    info["input_size"] = 64
    path.write_text(json.dumps(info))
    with pytest.raises(CheckpointError, match=rf"{path} was changed after it was written"):
        inference.load(bundle)


def test_a_bundle_is_never_written_into_its_own_run(run):
    with pytest.raises(FileExistsError, match=rf"{run / 'bundle'} is inside {run}"):
        store.save_bundle(run / "bundle", store.load(run))


def _convert(out, *extra) -> int:
    return convert_cli.main(["feelanyforce", str(RELEASE), "--out", str(out), "--heads", "2", *extra])


def test_converted_weights_are_verified(tmp_path):
    """16 flipped bytes used to move Fz silently; a truncated file failed with 'Unpack failed: incomplete
    input', naming no file; an edited convert.json loaded."""
    out = tmp_path / "release"
    assert _convert(out) == 0
    assert store.load(out).kind == "converted"
    weights, meta = out / "variables.msgpack", out / "convert.json"
    raw = weights.read_bytes()
    _flip(weights, 16)
    with pytest.raises(CheckpointError, match=rf"{weights} is corrupt or truncated"):
        store.load(out)
    weights.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(CheckpointError, match=rf"{weights} is corrupt or truncated"):
        store.load(out)
    weights.write_bytes(raw)
    edited = json.loads(meta.read_text())
    edited["input_size"] = 112
    meta.write_text(json.dumps(edited))
    with pytest.raises(CheckpointError, match=rf"{meta} was changed after it was written"):
        store.load(out)


def test_converted_folders_unverifiable_before_digests_still_name_a_truncated_file(tmp_path):
    """A folder written before convert.json carried digests: a truncated weights file names itself."""
    out = tmp_path / "old"
    assert _convert(out) == 0
    meta = json.loads((out / "convert.json").read_text())
    for key in ("sha256", "variables_sha256"):
        del meta[key]
    (out / "convert.json").write_text(json.dumps(meta))
    store.load(out)  # loads unchecked, as before
    raw = (out / "variables.msgpack").read_bytes()
    (out / "variables.msgpack").write_bytes(raw[: len(raw) // 3])
    with pytest.raises(CheckpointError, match=rf"{out / 'variables.msgpack'} is not readable"):
        store.load(out)


def test_convert_replaces_an_output_only_with_force_and_never_its_input(tmp_path, capsys):
    out = tmp_path / "release"
    assert _convert(out) == 0
    assert _convert(out) == 2
    assert "already exists; pass --force" in capsys.readouterr().err
    (out / "stray.txt").write_text("x")
    assert _convert(out, "--force") == 0
    assert not (out / "stray.txt").exists()  # the folder was replaced whole, not written into
    assert not list(tmp_path.glob(".release.*"))  # no staging folder left behind
    src = tmp_path / "src"
    src.mkdir()
    shutil.copy(RELEASE, src / "ckpt.pth.tar")
    assert convert_cli.main(["feelanyforce", str(src / "ckpt.pth.tar"), "--out", str(src), "--heads", "2",
                             "--force"]) == 2
    assert "holds" in capsys.readouterr().err and (src / "ckpt.pth.tar").is_file()


def test_calibration_never_writes_into_its_data_or_checkpoint(run, tmp_path):
    data = tmp_path / "calib"
    _smoke_run.write_split(data, 8, 5)
    for out in (data / "out", run / "calibrated"):
        with pytest.raises(FileExistsError, match=r"is inside .* which this command reads"):
            calibrate_tool.calibrate(run, data, out, steps=1, log=lambda *_: None)
        assert not out.exists()
