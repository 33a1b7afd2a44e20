"""The converged-regime recipe: the regressor's feature normalization (training, frozen backbones, calibration's
cached-feature path, the release architecture), the per-axis normalized force loss, the gpu preset, and the
training report (validation error beside the constant-prediction level, accuracy-against-time curves)."""

import jax
import numpy as np
import pytest
from _tiny_data import write_tiny_split

import configs
from experiments import training_figures, training_report
from ffjax import calibrate, models, registry, train
from ffjax.models import heads


@pytest.fixture(scope="module")
def cfg():
    return configs.get("smoke")


def _batch(cfg, n=8, seed=0):
    rng = np.random.default_rng(seed)
    s = cfg["data"]["input_size"]
    force = np.stack([rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), rng.uniform(0, 15, n)], 1)
    return {"image": rng.normal(size=(n, s, s, 3)).astype(np.float32),
            "depth": rng.uniform(size=(n, s, s)).astype(np.float32), "force": force.astype(np.float32)}


def test_feature_norm_standardizes_across_images():
    # a feature that is one big constant vector plus a small image-dependent part, as the ViT's CLS is
    rng = np.random.default_rng(0)
    x = (5.0 + 0.3 * rng.normal(size=(64, 16))).astype(np.float32)
    bn = heads.Regressor((8, 8), feature_norm=True)
    v = bn.init(jax.random.PRNGKey(0), x)
    assert set(v["batch_stats"]["feature_norm"]) == {"mean", "var"}
    # in training the batch statistics standardize it: the constant part and the per-dimension scale vanish
    shifted = bn.apply(v, 3.0 * (x + rng.normal(size=(1, 16)).astype(np.float32)), train=True, mutable=["batch_stats"])
    out, upd = bn.apply(v, x, train=True, mutable=["batch_stats"])
    assert out.shape == (64, 3)
    np.testing.assert_allclose(np.asarray(shifted[0]), np.asarray(out), rtol=2e-3, atol=2e-3)
    # the running mean moves 10% of the way per step (momentum 0.9)
    assert np.allclose(upd["batch_stats"]["feature_norm"]["mean"], 0.1 * x.mean(0), atol=1e-5)  # momentum 0.9
    # the release's head has no such layer (converted weights map one to one)
    plain = heads.Regressor((8, 8)).init(jax.random.PRNGKey(0), x)
    assert "batch_stats" not in plain and "feature_norm" not in plain["params"]


@pytest.mark.parametrize("name", ["dino_f_r", "dino_rd"])
def test_heads_normalization_trains_even_with_a_frozen_backbone(cfg, name):
    state = train.init_state(cfg, registry.get(name), jax.random.PRNGKey(0))
    before = jax.device_get(state.batch_stats)["regressor"]["feature_norm"]["mean"].copy()
    bb = jax.device_get(state.params["backbone"])
    state, m = train.train_step(state, _batch(cfg))
    after = jax.device_get(state.batch_stats)["regressor"]["feature_norm"]["mean"]
    assert np.isfinite(float(m["loss"])) and not np.allclose(before, after)
    if registry.get(name).frozen_backbone:
        assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(bb),
                                                           jax.tree.leaves(jax.device_get(state.params["backbone"]))))


def test_calibrating_last_layers_keeps_the_statistics(cfg):
    state = train.init_state(cfg, registry.get("dino_rd"), jax.random.PRNGKey(0), trainable="last")
    assert not state.head_bn_train and not state.bn_train
    before = jax.device_get(state.batch_stats)
    state, _ = train.train_step(state, _batch(cfg))
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(before), jax.tree.leaves(jax.device_get(
        state.batch_stats))))


def test_cached_feature_path_equals_the_model(cfg):
    """Evaluation and calibration run the regressor on cached features: with the feature normalization's
    statistics passed along, that is exactly the model's force."""
    spec = registry.get("dino_rd")
    state = train.init_state(cfg, spec, jax.random.PRNGKey(0))
    for seed in range(3):  # move the running statistics away from their init
        state, _ = train.train_step(state, _batch(cfg, seed=seed))
    variables = jax.device_get(state.variables())
    model = models.build(cfg["model"], spec, cfg["data"]["input_size"])
    images = _batch(cfg, seed=5)["image"]
    direct = np.asarray(model.apply(variables, images, train=False)["force"])
    feats = calibrate.features(model, variables, images)
    reg, stats = variables["params"]["regressor"], calibrate.regressor_stats(variables)
    assert stats is not None
    np.testing.assert_allclose(calibrate.predict_from_features(cfg["model"]["regressor"], reg, feats, stats), direct,
                               rtol=1e-4, atol=1e-4)
    tuned = calibrate.fit_regressor(cfg["model"]["regressor"], reg, feats, _batch(cfg, seed=5)["force"],
                                    layers="regressor", steps=3, reg_stats=stats)
    # the normalization's scale/bias train with the whole regressor; its statistics are not params
    assert not np.array_equal(tuned["feature_norm"]["scale"], reg["feature_norm"]["scale"])
    last = calibrate.fit_regressor(cfg["model"]["regressor"], reg, feats, _batch(cfg, seed=5)["force"],
                                   layers="last", steps=3, reg_stats=stats)
    assert np.array_equal(last["feature_norm"]["scale"], reg["feature_norm"]["scale"])


def test_normalized_force_loss_weighs_axes_like_the_metric(cfg):
    c = configs.get("smoke")
    c["model"]["regressor"].update(out_scale=[2.0, 2.0, 7.5], out_shift=[0.0, 0.0, 7.5])
    w = train.state.force_weights(c, c["train"])
    assert np.isclose(np.mean(w), 1.0) and np.isclose(w[0] / w[2], 7.5 / 2.0) and w[0] == w[1]
    assert train.state.force_weights(c, {**c["train"], "force_loss": "newton"}) is None
    # the loss is the weighted L1, the logged force_l1 stays in plain newtons
    state = train.init_state(c, registry.get("dino_r"), jax.random.PRNGKey(0))
    assert state.force_weights == w
    batch = _batch(c)
    ev = train.eval_step(state, batch)
    err = np.abs(np.asarray(ev["force"]) - batch["force"])
    np.testing.assert_allclose(float(ev["force_l1"]), err.mean(), rtol=1e-5)
    np.testing.assert_allclose(float(ev["loss"]), (err * np.asarray(w)).mean(), rtol=1e-5)
    # a state built before the loop knows the range weighs axes equally; the release head cannot normalize
    assert train.init_state(cfg, registry.get("dino_r"), jax.random.PRNGKey(0)).force_weights is None
    with pytest.raises(configs.ConfigError, match="normalize_output"):
        configs.get("smoke", {"model.regressor.normalize_output": False})


def test_gpu_preset_validates_and_its_step_traces():
    cfg = configs.get("gpu")
    assert cfg["train"]["batch_size"] > configs.get("quick")["train"]["batch_size"]
    state = train.abstract_state(cfg, registry.get("dino_rd"))
    s = cfg["data"]["input_size"]
    batch = {"image": jax.ShapeDtypeStruct((2, s, s, 3), np.float32), "force": jax.ShapeDtypeStruct((2, 3), np.float32),
             "depth": jax.ShapeDtypeStruct((2, s, s), np.float32)}
    _, m = jax.eval_shape(train.step._train_step, state, batch)
    assert m["loss"].shape == ()


def test_training_report_compares_with_the_constant_level(tmp_path):
    root = tmp_path / "data"
    write_tiny_split(root / "train", 24, 0)
    write_tiny_split(root / "val", 12, 1)
    runs = {}
    for method, nl1 in (("dino_rd", (20.0, 9.0)), ("dino_r", (25.0, 30.0))):
        run = tmp_path / method
        run.mkdir()
        rows = ["epoch,step,val_nl1,val_mae_fx,val_mae_fy,val_mae_fz,time_s"]
        rows += [f"{i + 1},{10 * (i + 1)},{v},{v / 50},{v / 40},{v / 10},{5.0 * (i + 1)}" for i, v in enumerate(nl1)]
        (run / "epochs.csv").write_text("\n".join(rows) + "\n")
        runs[method] = [run]
    report = training_report.summarize(runs, root)
    const = report["constant"]
    assert const["nl1"] > 0 and len(const["mae_n"]) == 3
    r = report["methods"]["dino_rd"]
    assert r["val_nl1"]["mean"] == 9.0 and r["steps"] == 20 and r["mae_n"] == [0.18, 0.225, 0.9]
    assert np.isclose(r["shear_vs_constant"][0], round(0.18 / const["mae_n"][0], 3))
    training_figures.write(report, tmp_path / "out", "smoke")
    text = (tmp_path / "out" / "training.md").read_text()
    assert "constant (training median)" in text and "DINO RD" in text
    curves = (tmp_path / "out" / "training_curves.csv").read_text().splitlines()
    assert len(curves) == 1 + 4
    assert (tmp_path / "out" / "training_curves.png").stat().st_size > 10_000


def test_flat_punch_is_the_cube_at_14mm_and_the_contact_probe_runs(tmp_path):
    from experiments.diagnostics import contact_probe
    from ffjax import sim
    from ffjax.sim.shapes import flat_punch

    assert np.array_equal(flat_punch(14.0).height, sim.get_shape("cube").height)
    with pytest.raises(ValueError, match="side_mm"):
        flat_punch(0.0)
    res = contact_probe.run(configs.get("smoke"), tmp_path, per_shape=2, progress=False)
    assert set(res["shapes"]) == set(sim.INDENTERS) | set(sim.UNSEEN_OBJECTS)
    cube, sphere = res["shapes"]["cube"], res["shapes"]["sphere_big"]
    assert cube["n"] > 0 and cube["sens_train"] > 0 and 0 <= cube["edge_share"] <= 1
    assert cube["area_mm2"] > res["shapes"]["sphere_small"]["area_mm2"] > 0 and sphere["penetration_mm"] > 0
    assert "contact area" in (tmp_path / "contact_probe.md").read_text()
    assert (tmp_path / "contact_probe.png").stat().st_size > 10_000
