"""Checkpoint refusal: a missing, partial or foreign checkpoint (another method or architecture, or not an
ffjax run at all) and torch files that would need unrestricted unpickling are refused with a message that
names the path and what is wrong."""

import json
import pickle
import shutil
import struct
import zipfile

import numpy as np
import pytest
from _tiny_data import write_tiny_split

import configs
from ffjax import convert, store, train
from ffjax.convert import reader
from ffjax.errors import CheckpointError

METHOD = "dino_rd"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One finished smoke run (1 epoch of 4 steps on a random split)."""
    root = tmp_path_factory.mktemp("ck_data")
    write_tiny_split(root / "train", 32, 0)
    write_tiny_split(root / "val", 8, 1)
    out = tmp_path_factory.mktemp("ck_run")
    train.train(configs.get("smoke"), METHOD, root, out, progress=False)
    return {"dir": out, "data": root}


def _copy(run, tmp_path):
    dst = tmp_path / "copy"
    shutil.copytree(run["dir"], dst)
    return dst


def test_missing_checkpoint_is_refused(run, tmp_path):
    with pytest.raises(FileNotFoundError, match=rf"{tmp_path}: not a checkpoint folder; expected model.json"):
        store.load(tmp_path)
    dst = _copy(run, tmp_path)
    shutil.rmtree(dst / "best")
    with pytest.raises(FileNotFoundError, match=rf"{dst / 'best'}.* no best checkpoint"):
        store.load(dst, "best")


def test_partial_checkpoint_is_refused(run, tmp_path):
    dst = _copy(run, tmp_path)
    step = max(int(p.name) for p in (dst / "checkpoints").iterdir() if p.name.isdigit())
    state = dst / "checkpoints" / str(step) / "packed"
    for p in state.rglob("*"):  # an interrupted copy: the array data is gone
        if p.is_file() and ("ocdbt" in str(p) or p.parent.name == "d"):
            p.unlink()
    with pytest.raises(CheckpointError, match=rf"{dst / 'checkpoints' / str(step)}: its files are damaged"):
        store.load(dst, "latest")


def test_other_architecture_is_refused(run, tmp_path):
    dst = _copy(run, tmp_path)
    info = json.loads((dst / "model.json").read_text())
    info["cfg"]["model"]["vit"]["dim"] = 48  # model.json now describes a wider model than the weights
    (dst / "model.json").write_text(json.dumps(info))
    with pytest.raises(CheckpointError, match=rf"{dst / 'model.json'} was changed after it was written"):
        store.load(dst, "best")
    del info["sha256"]  # as a model.json written before it carried its digest: the weights' shapes tell
    (dst / "model.json").write_text(json.dumps(info))
    with pytest.raises(CheckpointError, match=rf"{dst / 'best'}.*another model"):
        store.load(dst, "best")
    with pytest.raises(CheckpointError, match=rf"{dst / 'checkpoints'}.*another model"):
        store.load(dst, "latest")


def test_resume_with_another_method_or_architecture_is_refused(run, tmp_path):
    dst = _copy(run, tmp_path)
    with pytest.raises(CheckpointError, match=rf"{dst}.* method 'dino_rd', not 'dino_r'"):
        train.train(configs.get("smoke", {"train.epochs": 2}), "dino_r", run["data"], dst, resume=True,
                    progress=False)
    before = (dst / "model.json").read_bytes()
    wider = configs.get("smoke", {"train.epochs": 2, "model.vit.dim": 48})
    with pytest.warns(UserWarning, match="changed config") as warned:
        with pytest.raises(CheckpointError, match=rf"cannot resume from {dst / 'checkpoints'}.*another model"):
            train.train(wider, METHOD, run["data"], dst, resume=True, progress=False)
    assert {w.filename for w in warned if "changed config" in str(w.message)} == {__file__}  # points at the caller
    # the refused resume used to leave the wider model's model.json beside these weights: the run no longer loaded
    assert (dst / "model.json").read_bytes() == before
    store.load(dst)


@pytest.mark.parametrize("text", ["{not json", json.dumps({"hello": 1}), json.dumps([1, 2])])
def test_foreign_model_json_is_refused(run, tmp_path, text):
    dst = _copy(run, tmp_path)
    (dst / "model.json").write_text(text)
    with pytest.raises(CheckpointError, match=rf"{dst / 'model.json'}"):
        store.load(dst)


def test_unknown_method_is_refused(run, tmp_path):
    dst = _copy(run, tmp_path)
    info = json.loads((dst / "model.json").read_text())
    info["method"] = "someone_elses_net"
    del info["sha256"]  # (with it, the edit itself is refused: test_rel_artifacts)
    (dst / "model.json").write_text(json.dumps(info))
    with pytest.raises(CheckpointError, match=rf"{dst / 'model.json'}.*cannot build"):
        store.load(dst)


# protocol 2, by hand: OrderedDict w -> _rebuild_tensor_v2(<persistent storage "0">, 0, (4,), (1,), False)
_ONE_TENSOR_PKL = (b"\x80\x02ccollections\nOrderedDict\n)RX\x01\x00\x00\x00wctorch._utils\n_rebuild_tensor_v2\n(("
                   b"X\x07\x00\x00\x00storagectorch\nFloatStorage\nX\x01\x00\x00\x000X\x03\x00\x00\x00cpuK\x04tQ"
                   b"K\x00K\x04\x85K\x01\x85\x89tRs.")


def _torch_zip(path, pkl: bytes, storages: dict | None = None):
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("archive/data.pkl", pkl)
        zf.writestr("archive/byteorder", "little")
        for k, v in (storages or {}).items():
            zf.writestr(f"archive/data/{k}", v)


class _Evil:
    def __reduce__(self):
        return (eval, ("1 + 1",))


def test_torch_file_needing_unrestricted_unpickling_is_refused(tmp_path):
    evil = tmp_path / "evil.pt"
    _torch_zip(evil, pickle.dumps({"w": _Evil()}, protocol=2))
    with pytest.raises(convert.UnsafePickleError, match=r"evil\.pt.*(__builtin__|builtins)\.eval.*weights_only"):
        reader.load(evil)
    legacy = tmp_path / "legacy.pth"  # torch < 1.6 format: a bare pickle stream
    legacy.write_bytes(pickle.dumps({"w": _Evil()}))
    with pytest.raises(ValueError, match=r"legacy\.pth.*unrestricted unpickling"):
        reader.load(legacy)


def test_partial_torch_and_safetensors_files_are_refused(tmp_path):
    cut = tmp_path / "cut.pth"
    _torch_zip(cut, pickle.dumps({}, protocol=2))
    cut.write_bytes(cut.read_bytes()[:30])  # a download cut short
    with pytest.raises(ValueError, match=r"cut\.pth.*truncated or corrupt"):
        reader.load(cut)
    from safetensors.numpy import save_file

    st = tmp_path / "w.safetensors"
    save_file({"a": np.ones((64, 64), np.float32)}, str(st))
    st.write_bytes(st.read_bytes()[:100])
    with pytest.raises(ValueError, match=r"w\.safetensors.*partial or corrupt"):
        reader.load(st)


def test_torch_storage_larger_than_its_file_is_refused_before_inflating(tmp_path):
    """A small .pth whose deflated storage inflates to far more than the file (torch never compresses)."""
    path = tmp_path / "bomb.pth"
    _torch_zip(path, _ONE_TENSOR_PKL)
    with zipfile.ZipFile(path, "a", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("archive/data/0", bytes(32 << 20))  # 32 MiB of zeros: ~32 KiB on disk
    assert path.stat().st_size < 1 << 20
    with pytest.raises(ValueError, match=r"bomb\.pth.*data/0 declares 33,554,432 bytes, more than the whole file"):
        reader.read_state_dict(path)


def test_torch_tensor_larger_than_its_file_is_refused_before_allocating(tmp_path):
    """A 4-element storage viewed with stride 0 as 16M elements: 64 MiB out of a file of a few hundred bytes (the
    same at 10^9 elements took 4 GB before)."""
    n = 1 << 24
    pkl = _ONE_TENSOR_PKL.replace(b"K\x04\x85K\x01\x85", b"J" + struct.pack("<i", n) + b"\x85K\x00\x85")
    path = tmp_path / "broadcast.pth"
    _torch_zip(path, pkl, {"0": np.ones(4, np.float32).tobytes()})
    with pytest.raises(ValueError, match=rf"broadcast\.pth: w: tensor \({n},\) float32 declares {4 * n:,} bytes, "
                                         "more than the whole file"):
        reader.read_state_dict(path)
    fits = tmp_path / "fits.pth"  # the same view over 4 elements reads
    _torch_zip(fits, _ONE_TENSOR_PKL.replace(b"K\x01\x85", b"K\x00\x85"),
               {"0": np.arange(4, dtype=np.float32).tobytes()})
    np.testing.assert_array_equal(reader.read_state_dict(fits)["w"], [0, 0, 0, 0])


def test_torch_file_missing_a_storage_is_refused(tmp_path):
    """A zip whose pickle names a tensor storage that is not in the archive (a partial re-pack)."""
    path = tmp_path / "partial.pth"
    _torch_zip(path, _ONE_TENSOR_PKL)
    with pytest.raises(ValueError, match=r"partial\.pth.*data/0 is missing"):
        reader.read_state_dict(path)
