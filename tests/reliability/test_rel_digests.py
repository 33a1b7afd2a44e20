"""Issue 61 (9, 10). A model.json or convert.json without its digests used to load without a word, edited or not
(a run's stats.mean changed and its "sha256" deleted gave other forces, silently); now it loads with one
UnverifiedWarning naming the file, what is unverified and how to make it verified again. And `python -m
ffjax.convert` refuses a file of another kind, a --heads that cannot be, or a missing optional extra in one line,
writing nothing into --out."""

import json
import shutil
import sys
import warnings
from pathlib import Path

import pytest

from ffjax import cli, inference, store
from ffjax.convert import __main__ as convert_cli
from ffjax.errors import CheckpointError
from ffjax.files import json_digest
from ffjax.store import converted
from ffjax.train import init_weights

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"
LEGACY = FIXTURES / "legacy"
RELEASE = FIXTURES / "feelanyforce_tiny.pth.tar"


def _warnings(load, *args) -> tuple:
    """(load(*args), the messages of the UnverifiedWarnings it gave)."""
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        out = load(*args)
    return out, [str(w.message) for w in seen if issubclass(w.category, store.UnverifiedWarning)]


def _unverified(load, *args) -> tuple:
    """(load(*args), the one UnverifiedWarning it gave); fails on none or more than one."""
    out, got = _warnings(load, *args)
    assert len(got) == 1, got
    return out, got[0]


def _edit_json(path: Path, edit) -> None:
    content = json.loads(path.read_text())
    edit(content)
    path.write_text(json.dumps(content))


@pytest.fixture()
def run(tmp_path):
    """The legacy run, its model.json written with a digest as today's runs are."""
    folder = tmp_path / "run"
    shutil.copytree(LEGACY / "run", folder)
    _edit_json(folder / "model.json", lambda c: c.update(sha256=json_digest(c)))
    return folder


def test_a_run_model_json_edited_with_its_digest_deleted_warns_and_loads(run):
    assert not _warnings(inference.load, run)[1]  # with its digest: verified, nothing said
    mean = json.loads((run / "model.json").read_text())["stats"]["mean"]

    def edit(content):
        content["stats"]["mean"] = [m + 0.1 for m in mean]

    _edit_json(run / "model.json", edit)
    with pytest.raises(CheckpointError, match=r"was changed after it was written"):  # with it: refused
        inference.load(run)
    _edit_json(run / "model.json", lambda c: c.pop("sha256"))
    pred, msg = _unverified(inference.load, run)
    assert pred.trained.stats.mean[0] == pytest.approx(mean[0] + 0.1)  # it loads, as the file says
    assert msg.startswith(f"{run / 'model.json'} records no sha256 ")
    assert "the statistics, method and config in it are not verified" in msg
    assert f"python -m ffjax.train --out {run} --resume" in msg
    _unverified(store.describe, run)  # the reader that resuming training uses


def test_a_bundle_without_its_digests_names_the_weights_too(run, tmp_path):
    bundle = store.save_bundle(tmp_path / "bundle", store.load(run))
    assert not _warnings(inference.load, bundle)[1]
    _edit_json(bundle / "model.json", lambda c: (c.pop("sha256"), c.pop("variables_sha256")))
    _, msg = _unverified(inference.load, bundle)
    assert msg.startswith(f"{bundle / 'model.json'} records no sha256 and no variables_sha256 ")
    assert "and the weights beside it are not verified" in msg
    assert f"store.save_bundle(NEW, store.load('{bundle}'))" in msg


def test_a_converted_folder_without_digests_warns_once_in_every_loader(tmp_path, capsys):
    out = tmp_path / "release"
    assert convert_cli.main(["feelanyforce", str(RELEASE), "--out", str(out), "--heads", "2"]) == 0
    assert not _warnings(store.load, out)[1]
    _edit_json(out / "convert.json", lambda c: (c.pop("sha256"), c.pop("variables_sha256")))
    raw = bytearray((out / "variables.msgpack").read_bytes())
    raw[-3] ^= 0xFF  # a flipped byte in the last tensor: nothing can tell any more
    (out / "variables.msgpack").write_bytes(bytes(raw))
    pred, msg = _unverified(inference.load, out)
    assert pred.trained.kind == "converted"
    assert msg.startswith(f"{out / 'convert.json'} records no sha256 and no variables_sha256 ")
    assert "the model config in convert.json and the weights in variables.msgpack are not verified" in msg
    assert msg.endswith(f"convert the weights again: python -m ffjax.convert feelanyforce {RELEASE} --out {out} "
                        "--heads 2 --force")
    _unverified(converted.load_backbone, out)  # --init / pretrain
    _unverified(init_weights._converted, "feelanyforce", out)  # train --init feelanyforce:DIR
    _edit_json(out / "convert.json", lambda c: c.update(input_size=64))  # still no digest: loads as edited
    assert _unverified(store.load, out)[0].input_size == 64


@pytest.mark.parametrize("name, missing", [("run", "sha256"), ("bundle", "sha256"),
                                           ("converted", "sha256 and no variables_sha256")])
def test_legacy_artifacts_still_load_and_say_they_are_unverified(name, missing):
    """tests/fixtures/legacy was written before the digests existed (commit 337ea02): each loads, with one
    warning (the legacy bundle does record its weights' digest)."""
    trained, msg = _unverified(store.load, LEGACY / name)
    file = "convert.json" if name == "converted" else "model.json"
    assert trained.variables and msg.startswith(f"{LEGACY / name / file} records no {missing} (")


# ------------------------------------------------------------------------------------- convert refusals
def _refused(capsys, argv, out, rc=2, main=convert_cli.main) -> str:
    assert main(argv) == rc
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    assert not out.exists()
    return err[0]


def test_a_file_of_another_kind_is_named_with_the_converter_that_reads_it(tmp_path, capsys):
    """`convert resnet18 dinov2_tiny.pth` said "cannot convert ...:" and nothing after the colon."""
    out = tmp_path / "out"
    msg = _refused(capsys, ["resnet18", str(FIXTURES / "dinov2_tiny.pth"), "--out", str(out)], out)
    assert msg == (f"error: cannot convert {FIXTURES / 'dinov2_tiny.pth'}: it holds a DINOv2/ViT state dict (keys "
                   "like patch_embed.proj.weight, blocks.0.attn.proj.bias), not a torchvision ResNet-18: use "
                   "`python -m ffjax.convert dinov2` (convert.dinov2)")
    msg = _refused(capsys, ["dinov2", str(RELEASE), "--out", str(out)], out)
    assert "it holds a FeelAnyForce release checkpoint (keys like tactile_backbone.patch_embed" in msg
    assert msg.endswith("not a DINOv2 ViT: use `python -m ffjax.convert feelanyforce` (convert.feelanyforce)")
    msg = _refused(capsys, ["feelanyforce", str(FIXTURES / "resnet18_tiny.safetensors"), "--out", str(out)], out)
    assert "a torchvision ResNet state dict" in msg and msg.endswith("use `python -m ffjax.convert resnet18` "
                                                                     "(convert.resnet18)")
    msg = _refused(capsys, ["dinov2", str(FIXTURES / "misc.pth"), "--out", str(out)], out)
    assert msg.endswith("holds no DINOv2, ResNet or FeelAnyForce weights (keys like bf16, inner.half, int64), not a "
                        "DINOv2 ViT: give a DINOv2 ViT's weight file (e.g. dinov2_vitb14_pretrain.pth)")


@pytest.mark.parametrize("kind, source", [("dinov2", "dinov2_tiny.pth"), ("feelanyforce", "feelanyforce_tiny.pth.tar")])
def test_heads_that_do_not_divide_the_width_are_refused(kind, source, tmp_path, capsys):
    """--heads 7 was a 44-line reshape traceback; --heads 0 a ZeroDivisionError."""
    out = tmp_path / "out"
    msg = _refused(capsys, [kind, str(FIXTURES / source), "--out", str(out), "--heads", "7"], out)
    assert msg == (f"error: {FIXTURES / source}: --heads 7 (heads=) must divide the ViT width 32: use one of 1, 2, "
                   "4, 8, 16, 32")
    with pytest.raises(SystemExit) as exit_:
        convert_cli.main([kind, str(FIXTURES / source), "--out", str(out), "--heads", "0"])
    assert exit_.value.code == 2 and not out.exists()
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(
        "error: --heads 0: must be at least 1 (the ViT's attention heads, a divisor of its width)")


def test_safetensors_without_the_weights_extra_says_what_to_install(tmp_path, capsys, monkeypatch):
    """Without safetensors installed, a .safetensors input was a 25-line ModuleNotFoundError."""
    monkeypatch.setitem(sys.modules, "safetensors", None)  # as if not installed: importing it fails
    monkeypatch.setitem(sys.modules, "safetensors.numpy", None)
    out = tmp_path / "out"
    source = FIXTURES / "resnet18_tiny.safetensors"
    msg = _refused(capsys, ["resnet18", str(source), "--out", str(out)], out, rc=1,
                   main=lambda argv: cli.run(convert_cli.main, argv))
    assert msg == (f"error: {source}: reading .safetensors needs the optional extra ffjax[weights]: "
                   "pip install -e \".[weights]\" (or pip install safetensors)")
