"""Weight converters: the safe torch-file reader, the mapping tables and parity with PyTorch reference
outputs stored in tests/fixtures (made by tests/fixtures/make_parity_fixtures.py; torch is not imported)."""

import os
import pickle
import zipfile
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import configs
from ffjax import convert, inference, models, registry, store
from ffjax.convert import __main__ as cli
from ffjax.convert import from_dinov2, from_release, mapping, reader
from ffjax.models import vit
from ffjax.store import converted

FIX = Path(__file__).parent / "fixtures"
TOL = 1e-5  # float32 rounding: the bound docs/models.md ("Parity") states


def _ref(name):
    return {k: v.astype(np.float32) for k, v in np.load(FIX / name).items()}


def _close(a, b, tol=TOL):
    np.testing.assert_allclose(np.asarray(a), b, rtol=0, atol=tol)


# ---------------------------------------------------------------------------------------------- reader
def test_reader_reads_torch_zip_exactly():
    sd = convert.read_state_dict(FIX / "misc.pth")
    ref = _ref("misc.npz")
    assert sd["bf16"].dtype.name == "bfloat16" and sd["inner.half"].dtype == np.float16
    assert sd["int64"].dtype == np.int64 and sd["scalar"].shape == ()
    for key in ("bf16", "transposed", "view", "int64", "scalar"):  # views of shared/strided storages
        np.testing.assert_array_equal(sd[key].astype(np.float32), ref[key])
    np.testing.assert_array_equal(sd["inner.half"].astype(np.float32), ref["half"])
    meta = reader.load(FIX / "misc.pth")["meta"]
    assert meta["epoch"] == 3 and meta["pair"] == (1, 2.5) and meta["none"] is None and meta["np"] == 0.125


def _evil_checkpoint(path: Path, victim: Path):
    class Evil:
        def __reduce__(self):
            return os.remove, (str(victim),)

    with zipfile.ZipFile(path, "w") as z:
        z.writestr("archive/data.pkl", pickle.dumps({"w": Evil()}, protocol=2))
        z.writestr("archive/version", "3\n")


def test_reader_refuses_disallowed_global(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("still here")
    evil = tmp_path / "evil.pth"
    _evil_checkpoint(evil, victim)
    with pytest.raises(convert.UnsafePickleError, match=r"evil\.pth.*(posix|os|nt)\.remove"):
        convert.read_state_dict(evil)
    assert victim.exists()


def _tensor_pickle(size: tuple, stride: tuple) -> bytes:
    """A hand-assembled torch.save pickle of one float tensor over storage "0" (no torch needed)."""

    def s(text):
        raw = text.encode()
        return b"X" + len(raw).to_bytes(4, "little") + raw

    def ints(values):
        return b"(" + b"".join(b"K" + bytes([v]) for v in values) + b"t"

    storage = b"(" + s("storage") + b"ctorch\nFloatStorage\n" + s("0") + s("cpu") + b"K\x04tQ"
    hooks = b"ccollections\nOrderedDict\n)R"
    args = b"(" + storage + b"K\x00" + ints(size) + ints(stride) + b"\x89" + hooks + b"t"
    return b"\x80\x02ctorch._utils\n_rebuild_tensor_v2\n" + args + b"R."


def test_reader_bounds_checks_tensor_views(tmp_path):
    for name, size, stride, ok in (("fits", (2, 2), (2, 1), True), ("past_end", (4, 4), (4, 1), False)):
        path = tmp_path / f"{name}.pth"
        with zipfile.ZipFile(path, "w") as z:
            z.writestr(
                "archive/data.pkl",
                b"\x80\x02}X\x01\x00\x00\x00w" + _tensor_pickle(size, stride)[2:-1] + b"s.",
            )
            z.writestr("archive/data/0", np.arange(4, dtype=np.float32).tobytes())
        if ok:
            np.testing.assert_array_equal(convert.read_state_dict(path)["w"], [[0, 1], [2, 3]])
        else:
            with pytest.raises(ValueError, match="exceeds its storage"):
                convert.read_state_dict(path)


def test_reader_rejects_legacy_format(tmp_path):
    legacy = tmp_path / "old.pth"
    legacy.write_bytes(pickle.dumps({"a": 1}))
    with pytest.raises(ValueError, match="not a zip-format torch checkpoint"):
        reader.load(legacy)


def test_state_dict_unwraps_nesting_and_prefixes():
    a = np.ones((2, 2), np.float32)
    assert list(reader.state_dict({"model": {"module.x.w": a}, "epoch": 1})) == ["x.w"]
    assert list(reader.state_dict({"state_dict": {"_orig_mod.module.y": a}})) == ["y"]
    assert list(reader.state_dict({"backbone": {"z": a}, "head": a})) == ["backbone.z", "head"]
    with pytest.raises(ValueError, match="no state dict found"):
        reader.state_dict({"epoch": 1, "config": {"lr": 1e-3}})


# ---------------------------------------------------------------------------------------------- parity
def test_dinov2_parity_native_and_interpolated_grid():
    ref = _ref("dinov2_tiny.npz")
    cfg, params = convert.dinov2(FIX / "dinov2_tiny.pth", heads=2)
    assert cfg["pos_grid"] == 4 and cfg["depth"] == 2 and cfg["dim"] == 32 and cfg["patch"] == 8
    model = vit.from_config(cfg)
    for tag in ("native", "interp"):  # 32 px = the table's 4x4 grid; 48 px = 6x6, bicubic from 4x4
        out = model.apply({"params": params}, jnp.asarray(ref[f"x_{tag}"]))
        _close(out["feature"], ref[f"feature_{tag}"])
        _close(out["tokens"], ref[f"tokens_{tag}"])
    _close(vit.interpolate_pos_embed(jnp.asarray(params["pos_embed"]), (6, 6)), ref["pos_interp"])


def test_resnet18_parity_from_safetensors():
    ref = _ref("resnet18_tiny.npz")
    cfg, params, stats = convert.resnet18(FIX / "resnet18_tiny.safetensors")
    assert cfg == {"widths": (8, 8, 16, 16), "blocks": (2, 2, 2, 2), "stem": "imagenet"}
    out = models.ResNet(**cfg).apply({"params": params, "batch_stats": stats}, jnp.asarray(ref["x"]))
    _close(out["feature"], ref["feature"])


def test_release_checkpoint_parity_through_models_build():
    ref = _ref("feelanyforce_tiny.npz")
    for channel in (0, 1, 2):  # the release decoder's 3 channels, one at a time
        cfg, variables = convert.feelanyforce(FIX / "feelanyforce_tiny.pth.tar", heads=2, depth_channel=channel)
        assert cfg["decoder"]["kind"] == "paper" and cfg["decoder"]["channels"] == (16, 16, 8, 8)
        assert cfg["regressor"]["widths"] == (32, 16, 16, 8) and cfg["vit"]["pos_grid"] == 5
        out = models.build(cfg, registry.get("dino_rd"), 32).apply(variables, jnp.asarray(ref["x"]))
        _close(out["depth"], ref["depth"][:, channel])
    _close(out["feature"], ref["feature"])
    _close(out["force"], ref["force"])


def test_release_without_decoder():
    cfg, variables = convert.feelanyforce(FIX / "feelanyforce_tiny.pth.tar", heads=2, with_decoder=False)
    assert set(variables["params"]) == {"backbone", "regressor"}
    out = models.build(cfg, registry.get("dino_r"), 32).apply(variables, jnp.zeros((1, 32, 32, 3)))
    assert out["force"].shape == (1, 3)


def test_the_documented_python_path_builds_the_model_the_cli_loads(tmp_path):
    """Issue 61 (17): `cfg, variables = convert.feelanyforce(path)` then `models.build(cfg, registry.get("dino_rd"),
    224)`, as its docstring says, raised KeyError: 'fast' (the config held only the weights' sections). The same
    lines on the tiny release (heads 2, crop size 32) now build the model `python -m ffjax.convert` +
    `inference.load` run, with the same outputs."""
    path, size = FIX / "feelanyforce_tiny.pth.tar", 32
    cfg, variables = convert.feelanyforce(path, heads=2)
    model = models.build(cfg, registry.get("dino_rd"), size)
    images = jnp.asarray(_ref("feelanyforce_tiny.npz")["x"])
    out = model.apply(variables, images)
    assert cli.main(["feelanyforce", str(path), "--out", str(tmp_path / "release"), "--heads", "2"]) == 0
    pred = inference.load(tmp_path / "release")
    assert pred.trained.input_size == size and pred.trained.cfg["model"] == cfg
    ref = pred.model.apply(pred.variables, images)
    for key in ("force", "depth", "feature"):
        np.testing.assert_array_equal(np.asarray(out[key]), np.asarray(ref[key]))


def test_a_converted_folder_written_before_the_decoder_had_fast_builds():
    """The legacy converted folder (tests/fixtures/legacy, written before decoder.fast existed) builds the same
    complete config the Python path gives."""
    with pytest.warns(store.UnverifiedWarning):  # it records no digests (test_rel_digests)
        sections, _ = convert.load(FIX / "legacy" / "converted")
    assert "fast" not in sections["decoder"]
    cfg = converted.release_model(sections)
    assert cfg["decoder"]["fast"] is configs.get("paper")["model"]["decoder"]["fast"]
    models.build(cfg, registry.get("dino_rd"), 32)


# ------------------------------------------------------------------------------------- error reporting
def test_every_mapping_problem_reported_at_once():
    state = convert.read_state_dict(FIX / "dinov2_tiny.pth")
    del state["blocks.0.ls1.gamma"], state["norm.bias"]
    state["blocks.1.attn.qkv.weight"] = state["blocks.1.attn.qkv.weight"][:, :16]
    state["register_tokens"] = np.zeros((1, 4, 32), np.float32)
    state["blocks.0.mlp.w12.weight"] = np.zeros((8, 32), np.float32)
    with pytest.raises(mapping.ConversionError) as info:
        from_dinov2.convert_state(state, heads=2, source="tiny")
    p = info.value.problems
    assert len(p["missing Flax params"]) == 2 and len(p["shape mismatches"]) == 1
    assert len(p["unmapped torch keys"]) == 2
    msg = str(info.value)
    for name in (
        "blocks_0/ls1/gamma",
        "norm/bias",
        "blocks.1.attn.qkv.weight (96, 16)",
        "register_tokens (1, 4, 32)",
        "blocks.0.mlp.w12.weight",
    ):
        assert name in msg


def test_release_aliases_must_agree():
    obj = reader.load(FIX / "feelanyforce_tiny.pth.tar")
    state = reader.state_dict(obj)
    state["regressor.bottleneck2.weight_g"] = state["regressor.bottleneck2.weight_g"] + 1.0
    with pytest.raises(mapping.ConversionError, match=r"bottleneck2\.weight_g.* both map to params/regressor/fc_1/g"):
        from_release.convert_state(state, from_release.release_config(obj), heads=2)


def test_heads_needed_when_not_inferable():
    with pytest.raises(ValueError, match="pass heads="):
        convert.dinov2(FIX / "dinov2_tiny.pth")


# ------------------------------------------------------------------------------------------------- CLI
def test_cli_writes_loadable_output(tmp_path, capsys):
    out = tmp_path / "faf"
    assert cli.main(["feelanyforce", str(FIX / "feelanyforce_tiny.pth.tar"), "--out", str(out), "--heads", "2"]) == 0
    assert "regressor" in capsys.readouterr().out
    cfg, variables = convert.load(out)
    ref_cfg, ref_vars = convert.feelanyforce(FIX / "feelanyforce_tiny.pth.tar", heads=2)
    assert converted.release_model(cfg) == ref_cfg  # convert.json holds the sections, feelanyforce the whole
    np.testing.assert_array_equal(variables["params"]["decoder"]["fc"]["v"], ref_vars["params"]["decoder"]["fc"]["v"])
    assert converted.read_meta(out)["input_size"] == 32

    res = tmp_path / "resnet"
    cli.main(["resnet18", str(FIX / "resnet18_tiny.safetensors"), "--out", str(res)])
    params, stats = convert.load_backbone(res)
    assert convert.load(res)[0] == {"resnet": {"widths": (8, 8, 16, 16), "blocks": (2, 2, 2, 2), "stem": "imagenet"}}
    assert stats["bn1"]["var"].shape == (8,) and params["conv1"]["kernel"].shape == (7, 7, 3, 8)

    assert cli.main(["dinov2", str(FIX / "dinov2_tiny.pth"), "--out", str(tmp_path / "d")]) == 2  # no --heads
    assert "pass heads=" in capsys.readouterr().err


@pytest.mark.skipif(not os.environ.get("FFJAX_PAPER_SCALE_DIR"), reason="set FFJAX_PAPER_SCALE_DIR (see fixtures)")
def test_release_parity_paper_scale():
    """ViT-B/14 (37x37 table run at 16x16), paper heads and the 77M-parameter decoder at 224 px."""
    root = Path(os.environ["FFJAX_PAPER_SCALE_DIR"])
    ref = {k: v.astype(np.float32) for k, v in np.load(root / "ref.npz").items()}
    cfg, variables = convert.feelanyforce(root / "checkpoint_v1.pth.tar")
    assert cfg["vit"]["heads"] == 12 and cfg["vit"]["pos_grid"] == 37
    out = models.build(cfg, registry.get("dino_rd"), 224).apply(variables, jnp.asarray(ref["x"]))
    _close(out["feature"], ref["feature"])
    _close(out["force"], ref["force"])
    _close(out["depth"], ref["depth"][:, 0])
    vit_cfg, params = convert.dinov2(root / "dinov2_vitb14_pretrain.pth")
    assert vit_cfg == cfg["vit"]
    _close(vit.from_config(vit_cfg).apply({"params": params}, jnp.asarray(ref["x"]))["feature"], ref["feature"])
