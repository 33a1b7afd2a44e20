"""Models: shapes for every registry entry, ViT pos-embed interpolation, weight norm, decoders, BatchNorm
state, and a paper-scale build counted with jax.eval_shape (no allocation)."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import configs
from ffjax import models, registry
from ffjax.models import heads, vit

KEY = jax.random.PRNGKey(0)


def _init_apply(model, *args, **kw):
    """init + apply under one jit: one compile instead of op-by-op dispatch (compiles dominate here)."""
    return jax.jit(lambda k: (v := model.init(k, *args), model.apply(v, *args, **kw)))(KEY)


@pytest.fixture(scope="module")
def smoke():
    cfg = configs.get("smoke")
    return cfg["model"], cfg["data"]["input_size"]


def _shapes(model, images, train=False):
    """Abstract init + apply: output shapes without compiling anything."""
    variables = jax.eval_shape(lambda k: model.init(k, images, train=False), KEY)
    mutable = ["batch_stats"] if train and "batch_stats" in variables else False
    out = jax.eval_shape(lambda v: model.apply(v, images, train=train, mutable=mutable), variables)
    return variables, out[0] if mutable else out


@pytest.mark.parametrize("name", registry.names())
def test_every_entry_builds(smoke, name):
    cfg_model, s = smoke
    spec = registry.get(name)
    images = jnp.zeros((2, s, s, 3))
    variables, out = _shapes(models.build(cfg_model, spec, s), images, train=True)
    want = {"backbone", "regressor"} | ({"decoder"} if spec.depth_head else set())
    assert set(variables["params"]) == want
    # BatchNorm statistics: the ResNet's, and the regressor's feature normalization (smoke has it on)
    assert ("backbone" in variables.get("batch_stats", {})) == (spec.backbone == "resnet")
    assert set(variables["batch_stats"]["regressor"]["feature_norm"]) == {"mean", "var"}
    assert out["force"].shape == (2, 3)
    assert out["feature"].shape[0] == 2
    assert ("depth" in out) == spec.depth_head
    if spec.depth_head:
        assert out["depth"].shape == (2, s, s)
    names = set(variables["params"]["regressor"])
    assert {"out", "norm_3"} <= names


def test_vit_forward_with_interpolated_pos_embed(smoke):
    cfg_model, s = smoke
    cfg_vit = {**cfg_model["vit"], "pos_grid": 6}  # 32/8 = 4x4 input grid, table trained at 6x6
    model = models.build_backbone({**cfg_model, "vit": cfg_vit}, "vit", s)
    images = jax.random.normal(KEY, (2, s, s, 3))
    variables, out = _init_apply(model, images)
    assert variables["params"]["pos_embed"].shape == (1, 37, cfg_vit["dim"])
    g = s // cfg_vit["patch"]
    assert out["tokens"].shape == (2, g, g, cfg_vit["dim"])
    assert out["feature"].shape == (2, cfg_vit["dim"])
    assert np.isfinite(np.asarray(out["feature"])).all()
    p = set(variables["params"]["blocks_0"])
    assert p == {"norm1", "attn", "ls1", "norm2", "mlp", "ls2"}
    assert set(variables["params"]["blocks_0"]["attn"]) == {"qkv", "proj"}


@pytest.mark.parametrize("grid", [(5, 5), (9, 7), (3, 3)])
def test_pos_embed_interpolation_is_torch_bicubic(grid):
    """offset=0 is a size-based bicubic (a=-0.75, half-pixel, clamped borders) == cv2 INTER_CUBIC."""
    rng = np.random.default_rng(0)
    table = rng.normal(size=(1, 1 + 6 * 6, 4)).astype(np.float32)
    got = np.asarray(vit.interpolate_pos_embed(jnp.asarray(table), grid, offset=0.0))
    ref = cv2.resize(table[0, 1:].reshape(6, 6, 4), (grid[1], grid[0]), interpolation=cv2.INTER_CUBIC)
    np.testing.assert_allclose(got[0, 1:].reshape(*grid, 4), ref, atol=1e-5)
    np.testing.assert_array_equal(got[0, 0], table[0, 0])
    same = vit.interpolate_pos_embed(jnp.asarray(table), (6, 6))
    np.testing.assert_array_equal(np.asarray(same), table)


def test_weight_norm_dense():
    layer = models.WeightNormDense(5)
    x = jax.random.normal(KEY, (3, 7))
    params = layer.init(KEY, x)["params"]
    assert params["v"].shape == (7, 5) and params["g"].shape == (5,) and params["bias"].shape == (5,)
    v = np.asarray(params["v"])
    np.testing.assert_allclose(np.asarray(params["g"]), np.linalg.norm(v, axis=0), rtol=1e-6)
    g = np.linspace(0.5, 2.0, 5).astype(np.float32)
    y = layer.apply({"params": {**params, "g": jnp.asarray(g)}}, x)
    w = g * v / np.linalg.norm(v, axis=0, keepdims=True)
    np.testing.assert_allclose(np.asarray(y), np.asarray(x) @ w + np.asarray(params["bias"]), rtol=1e-5, atol=1e-5)


def test_upsampling_ops():
    x = np.arange(2 * 2 * 3 * 8, dtype=np.float32).reshape(2, 2, 3, 8)
    np.testing.assert_array_equal(np.asarray(heads.upsample_nearest2(x)), x.repeat(2, 1).repeat(2, 2))
    y = np.asarray(heads.depth_to_space2(x))  # channel (dy, dx, c): out[2i+dy, 2j+dx, c]
    assert y.shape == (2, 4, 6, 2)
    np.testing.assert_array_equal(y[:, 1::2, 0::2, :], x[..., 4:6])


@pytest.mark.parametrize("kind", heads.DECODER_KINDS)
@pytest.mark.parametrize("size", [32, 28])  # 28: not a power-of-two multiple of the 4x4 grid / of 16
def test_decoders_output_full_resolution(smoke, kind, size):
    cfg_model, _ = smoke
    dec = heads.decoder_from_config({**cfg_model["decoder"], "kind": kind}, size)
    feature, tokens = jnp.ones((2, 32)), jnp.ones((2, 4, 4, 32))
    # shapes only: numerics are checked by the equivalence tests below and the release parity fixtures
    out = jax.eval_shape(lambda: dec.apply(dec.init(KEY, feature, tokens), feature, tokens))
    assert out.shape == (2, size, size)


def test_resnet_batch_stats(smoke):
    cfg_model, s = smoke
    # two stages keep the compile short (each conv shape costs ~1 s to compile here); names as torchvision
    resnet = {**cfg_model["resnet"], "widths": (4, 8), "blocks": (1, 1), "stem": "imagenet"}
    model = models.build_backbone({**cfg_model, "resnet": resnet}, "resnet", s)
    images = jax.random.normal(KEY, (2, s, s, 3)) * 2 + 1
    variables, (out, upd) = _init_apply(model, images, train=True, mutable=["batch_stats"])
    # eval mode: running stats, nothing mutable needed
    ev = jax.eval_shape(lambda v: model.apply(v, images, train=False), variables)
    assert set(variables["params"]) == {"conv1", "bn1", "layer1_0", "layer2_0"}
    assert set(variables["params"]["layer2_0"]) == {"conv1", "bn1", "conv2", "bn2", "downsample_0", "downsample_1"}
    assert set(variables["batch_stats"]["bn1"]) == {"mean", "var"}
    assert out["feature"].shape == (2, 8) and out["tokens"].shape == (2, s // 8, s // 8, 8)
    old, new = variables["batch_stats"]["bn1"]["mean"], upd["batch_stats"]["bn1"]["mean"]
    assert not np.allclose(np.asarray(old), np.asarray(new))
    assert ev["tokens"].shape == out["tokens"].shape
    full = models.build_backbone(cfg_model, "resnet", s)
    _, out = _shapes(full, images, train=True)
    stride = 8 if cfg_model["resnet"].get("stem") == "small" else 32
    assert out["tokens"].shape == (2, s // stride, s // stride, cfg_model["resnet"]["widths"][-1])
    small = models.build_backbone({**cfg_model, "resnet": {**cfg_model["resnet"], "stem": "small"}}, "resnet", s)
    _, out = _shapes(small, images)
    assert out["tokens"].shape[1] == s // 8


def test_paper_scale_counts():
    """ViT-B/14 at 224 with the release's heads: ~86.6M backbone, ~77.3M in the decoder's Linear."""
    cfg = configs.get("paper")
    cfg_model = {**cfg["model"], "vit": {**cfg["model"]["vit"], **vit.vit_config("b14")}}
    s = cfg["data"]["input_size"]
    model = models.build(cfg_model, registry.get("dino_rd"), s)
    variables, out = _shapes(model, jnp.zeros((1, s, s, 3)))
    p = variables["params"]
    n_backbone = models.count_params(p["backbone"])
    assert 85e6 < n_backbone < 88e6, n_backbone
    assert 76e6 < models.count_params(p["decoder"]["fc"]) < 78.5e6
    assert models.count_params(p["regressor"]) < 1e6
    assert out["depth"].shape == (1, s, s) and out["feature"].shape == (1, 768)
    s14 = models.count_params(
        jax.eval_shape(lambda k: models.ViT(**vit.vit_config("s14")).init(k, jnp.zeros((1, s, s, 3))), KEY)
    )
    assert 21e6 < s14 < 23e6, s14


def test_token_decoder_equals_stagewise_pixel_shuffle():
    """The block-layout TokenDecoder is Dense(4C) + depth_to_space2 per stage, written out here."""
    dec = heads.TokenDecoder((8, 6, 4), 32)
    tokens = jax.random.normal(KEY, (2, 4, 4, 5))

    @jax.jit
    def both():
        params = dec.init(KEY, None, tokens)["params"]
        x = tokens @ params["proj"]["kernel"][0, 0] + params["proj"]["bias"]
        for i in range(3):
            x = jax.nn.relu(x) @ params[f"up_{i}"]["kernel"] + params[f"up_{i}"]["bias"]
            x = heads.depth_to_space2(x)
        return dec.apply({"params": params}, None, tokens), jax.nn.leaky_relu(x, 0.01)[..., 0]

    got, ref = both()
    np.testing.assert_allclose(np.asarray(got), np.asarray(ref), atol=1e-5)


def test_fast_upconv_equals_upsample_then_conv():
    """UpConv5's low-resolution phase form is exactly nearest x2 + conv k5 (pad 2), borders included."""
    x = jax.random.normal(KEY, (2, 3, 5, 4))

    @jax.jit
    def both():
        params = jax.tree.map(lambda p: p + 0.1, heads.UpConv5(6).init(KEY, x))  # non-zero bias
        return heads.UpConv5(6, fast=True).apply(params, x), heads.UpConv5(6, fast=False).apply(params, x)

    fast, slow = both()
    assert fast.shape == (2, 6, 10, 6)
    np.testing.assert_allclose(np.asarray(fast), np.asarray(slow), atol=1e-5)


@pytest.mark.parametrize("side, stride, kernel", [(4, 2, 3), (2, 1, 3), (2, 1, 1), (8, 2, 3), (3, 2, 7)])
def test_resnet_conv_equals_the_library_convolution(side, stride, kernel):
    # the ResNet's convolution takes one matrix product where the window outgrows the map it makes
    # (ffjax.models.resnet._conv_op); the forward and both gradients equal lax's convolution
    from jax import lax

    from ffjax.models import resnet

    k1, k2 = jax.random.split(jax.random.PRNGKey(0))
    x = jax.random.normal(k1, (3, side, side + 1, 5))
    w = jax.random.normal(k2, (kernel, kernel, 5, 6))
    pad = ((kernel // 2,) * 2,) * 2
    dims = lax.conv_dimension_numbers(x.shape, w.shape, ("NHWC", "HWIO", "NHWC"))

    def loss(conv):
        return lambda x, w: jnp.sum(jnp.sin(conv(x, w, (stride, stride), pad, dimension_numbers=dims)))

    ours, lib = loss(resnet._conv_op), loss(lax.conv_general_dilated)
    made = (side + 2 * (kernel // 2) - kernel) // stride + 1
    assert ("conv_general_dilated" in str(jax.make_jaxpr(ours)(x, w))) == (made >= kernel)
    np.testing.assert_allclose(ours(x, w), lib(x, w), rtol=1e-5)
    for a, b in zip(jax.grad(ours, (0, 1))(x, w), jax.grad(lib, (0, 1))(x, w)):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)


def test_resnet_conv_leaves_other_layouts_to_the_library():
    # the matrix product is written for NHWC / HWIO (what flax's Conv passes); any other layout, or none
    # (lax's NCHW default), takes lax's convolution and gives its result
    from jax import lax

    from ffjax.models import resnet

    x, w = jnp.arange(2 * 5 * 2 * 2.0).reshape(2, 5, 2, 2), jnp.ones((6, 5, 3, 3))
    pad = ((1, 1), (1, 1))
    for dims in (None, ("NCHW", "OIHW", "NCHW")):
        jaxpr = str(jax.make_jaxpr(lambda x, w, d=dims: resnet._conv_op(x, w, (1, 1), pad, dimension_numbers=d))(x, w))
        assert "conv_general_dilated" in jaxpr and "dot_general" not in jaxpr
        np.testing.assert_array_equal(resnet._conv_op(x, w, (1, 1), pad, dimension_numbers=dims),
                                      lax.conv_general_dilated(x, w, (1, 1), pad, dimension_numbers=dims))
