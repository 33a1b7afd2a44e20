"""The exported (jax.export) function: preprocessing inside it equals ffjax.data's, forces equal the
Predictor's within 1e-4 N (float32 rounding: the resize is a matmul instead of cv2's loop), the sidecar
describes it, and it runs from the serialized bytes with jax alone."""

import json
import subprocess
import sys

import _smoke_run
import numpy as np
import pytest

from ffjax import data, export, inference

pytest.importorskip("flatbuffers", reason="jax.export serialization needs the flatbuffers package")
TOL = 1e-4  # newtons


@pytest.mark.parametrize("hw,size", [((240, 320), 224), ((320, 240), 224), ((24, 32), 32), ((24, 32), 64),
                                     ((30, 40), 37)])
def test_jax_preprocessing_equals_data_preprocess(hw, size):
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (2, *hw, 3), dtype=np.uint8)
    bg = rng.integers(0, 256, (*hw, 3), dtype=np.uint8)
    stats = {"mean": [0.4, 0.5, 0.45], "std": [0.2, 0.25, 0.3]}
    got = np.asarray(export.preprocess_fn(hw, size, stats["mean"], stats["std"])(img, bg))
    np.testing.assert_allclose(got, data.preprocess_image(img, bg, stats, size), atol=1e-5)


@pytest.fixture(scope="module")
def setup():
    pred = inference.load(_smoke_run.smoke_run())
    b = _smoke_run.presses(3, seed=9)
    pred.set_background(b["background"])
    return pred, b


def test_export_cli_matches_predictor_and_runs_without_ffjax(setup, tmp_path):
    pred, b = setup
    want = pred.predict(b["image"])
    out = tmp_path / "f.jaxexport"
    assert export.main(["--checkpoint", pred.trained.path, "--out", str(out), "--batch", "0"]) == 0
    info = json.loads((tmp_path / "f.jaxexport.json").read_text())
    assert info["frame_size"] == list(pred.frame_size) and info["channels"] == "RGB" and info["batch"] is None
    fn = export.load(out)
    np.testing.assert_allclose(fn(b["image"], b["background"]), want, atol=TOL)
    assert fn.last_out_of_range.tolist() == pred.last_out_of_range.tolist()
    with pytest.raises(ValueError, match="must be"):
        fn(np.zeros((3, 10, 10, 3), np.uint8), b["background"])
    np.save(tmp_path / "img.npy", b["image"])
    np.save(tmp_path / "bg.npy", b["background"])
    # the documented few lines, in a fresh interpreter that never imports ffjax; batch 2 (symbolic batch)
    code = (f"import sys, numpy as np; from jax import export; "
            f"fn = export.deserialize(open({str(out)!r}, 'rb').read()); "
            f"f = np.asarray(fn.call(np.load({str(tmp_path / 'img.npy')!r})[:2], "
            f"np.load({str(tmp_path / 'bg.npy')!r}))); "
            f"np.save({str(tmp_path / 'f.npy')!r}, f); assert 'ffjax' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
    np.testing.assert_allclose(np.load(tmp_path / "f.npy"), want[:2], atol=TOL)


def test_fixed_batch_export(setup, tmp_path):
    pred, b = setup
    path = export.save(pred, tmp_path / "f1.bin", batch=1)
    fn = export.load(path)
    assert json.loads((tmp_path / "f1.bin.json").read_text())["batch"] == 1
    np.testing.assert_allclose(fn(b["image"][0], b["background"]), pred.predict(b["image"][:1]), atol=TOL)
    # issue 33 (7): a wrong batch, RGBA or no frames get errors naming the file and the fix, not jax's shape errors
    with pytest.raises(ValueError, match=r"f1.bin takes batches of exactly 1 frame.*--batch 0"):
        fn(b["image"][:2], b["background"])
    rgba = np.concatenate([b["image"][:1], np.zeros_like(b["image"][:1, ..., :1])], -1)
    with pytest.raises(ValueError, match=r"images must be \(B, H, W, 3\).*alpha"):
        fn(rgba, b["background"])
    with pytest.raises(ValueError, match=r"background must be \(H, W, 3\)"):
        fn(b["image"][:1], b["background"][..., 0])
    assert fn(b["image"][:0], b["background"]).shape == (0, 3)


def test_a_damaged_or_missing_export_names_its_file(setup, tmp_path):
    """A truncated or foreign file used to fail inside flatbuffers/struct (`unpack_from requires a buffer of at least
    144210 bytes`) without naming it."""
    pred, _ = setup
    good = export.save(pred, tmp_path / "f.jaxexport")
    raw = good.read_bytes()
    for name, content in (("cut", raw[:1000]), ("foreign", b"garbage\n")):
        (tmp_path / name).write_bytes(content)
        with pytest.raises(ValueError, match=rf"{tmp_path / name} is not a readable jax export"):
            export.load(tmp_path / name)
    with pytest.raises(FileNotFoundError, match=rf"{tmp_path / 'nope'}: no such export file"):
        export.load(tmp_path / "nope")
    export.sidecar_path(good).write_text('{"frame_size": [24')  # a sidecar cut short
    with pytest.raises(ValueError, match=r"f\.jaxexport\.json is not valid JSON"):
        export.load(good)


def test_nonfinite_forces_from_an_export_are_flagged(setup, tmp_path):
    """One NaN weight in the last layer: the export's forces are flagged like Predictor.predict's, with a warning."""
    import dataclasses

    import jax

    pred, b = setup
    variables = jax.tree.map(np.array, pred.trained.variables)
    leaves = jax.tree_util.tree_leaves(variables["params"]["regressor"])
    [k for k in leaves if k.ndim == 2][-1][0, 0] = np.nan
    bad = inference.Predictor(dataclasses.replace(pred.trained, variables=variables))
    fn = export.load(export.save(bad, tmp_path / "nan.jaxexport", batch=3))
    with pytest.warns(inference.NonFiniteWarning, match="nan.jaxexport"):
        forces = fn(b["image"], b["background"])
    assert np.isnan(forces[:, 0]).all() and fn.last_nonfinite.all() and fn.last_out_of_range.all()
    fn = export.load(export.save(pred, tmp_path / "ok.jaxexport", batch=3))
    fn(b["image"], b["background"])
    assert not fn.last_nonfinite.any()
