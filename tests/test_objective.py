"""The objective as data and method identity in the checkpoint (issue 15).

Worked example: a loss term added in one place (an entry of `objective.TERMS`, its weight a Method field)
appears in the step's metrics and loss, the train log, validation and epochs.csv. And a sweep variant (a
Method never registered) trains, then loads in a fresh process from its model.json alone."""

import csv
import dataclasses
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _tiny_data import write_tiny_dataset

import configs
from ffjax import registry, store, train
from ffjax.registry import Method
from ffjax.train import objective, run_log

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    return write_tiny_dataset(tmp_path_factory.mktemp("tiny_data"), 16, 8)


def test_the_default_objective_keeps_the_csv_columns_users_read():
    fields = run_log.csv_fields(objective.Objective.of(registry.get("dino_rd")))
    assert fields == ("epoch", "step", "train_loss", "train_force_l1", "val_loss", "val_force_l1", "val_depth_mse",
                      "val_nl1", "val_nl1_fx", "val_nl1_fy", "val_nl1_fz", "val_mae_fx", "val_mae_fy",
                      "val_mae_fz", "time_s")


def fz_l1(state, out, batch):
    """The toy term: |error| of the normal force alone."""
    return jnp.abs(out["force"][:, 2] - batch["force"][:, 2])


@dataclasses.dataclass(frozen=True)
class ToyMethod(Method):
    gamma: float = 0.5  # the toy term's weight


def test_a_new_term_is_one_entry(tiny_data, tmp_path, monkeypatch):
    # the one place: a Term in objective.TERMS (its weight, `gamma`, a Method field)
    monkeypatch.setattr(objective, "TERMS", (*objective.TERMS, objective.Term("fz_l1", "gamma", fz_l1)))
    spec = ToyMethod("toy_fz", "Toy (Fz term)", "vit", pretrained=False)
    cfg = configs.get("smoke", {"train.epochs": 2, "train.batch_size": 8})

    state = train.init_state(cfg, spec, jax.random.PRNGKey(0))
    assert state.objective.names == ("force_l1", "depth_mse", "fz_l1")
    batch = {k: v[:8] for k, v in _batch(cfg).items()}
    _, m = train.train_step(state, batch)
    assert set(m) == {"loss", "force_l1", "depth_mse", "fz_l1", "grad_norm"}
    want = spec.alpha * m["force_l1"] + spec.beta * m["depth_mse"] + spec.gamma * m["fz_l1"]
    np.testing.assert_allclose(float(m["loss"]), float(want), rtol=1e-5)

    run = train.train(cfg, spec, tiny_data, tmp_path, progress=False)
    assert "fz_l1" in run["val"] and np.isfinite(run["val"]["fz_l1"])  # validation
    rows = [json.loads(r) for r in open(tmp_path / run_log.LOG_NAME)]
    assert all("fz_l1" in r for r in rows)  # every train and val row of the log
    with open(tmp_path / run_log.CSV_NAME) as f:
        epochs = list(csv.DictReader(f))
    assert {"train_fz_l1", "val_fz_l1"} <= set(epochs[0]) and len(epochs) == 2
    assert float(epochs[-1]["val_fz_l1"]) == pytest.approx(run["val"]["fz_l1"])


def _batch(cfg):
    rng = np.random.default_rng(0)
    s, n = cfg["data"]["input_size"], 8
    return {"image": rng.normal(size=(n, s, s, 3)).astype(np.float32),
            "depth": rng.uniform(size=(n, s, s)).astype(np.float32),
            "force": rng.uniform(0, 5, size=(n, 3)).astype(np.float32)}


@pytest.fixture(scope="module")
def variant_run(tiny_data, tmp_path_factory):
    """A sweep variant of dino_rd, trained without ever being registered: (its Method, its run folder)."""
    base = registry.get("dino_rd")
    variant = dataclasses.replace(base, name="dino_rd_b3_a2", paper_name="DINO RD (beta 3, alpha 2)", beta=3.0,
                                  alpha=2.0, pretrained=False)
    assert variant.name not in registry.names()  # never registered
    out = tmp_path_factory.mktemp("variant")
    train.train(configs.get("smoke", {"train.epochs": 1, "train.batch_size": 8}), variant, tiny_data, out,
                progress=False)
    return variant, out


def test_a_sweep_variant_loads_in_a_fresh_process(variant_run):
    variant, tmp_path = variant_run
    loaded = store.load(tmp_path)
    spec, variables = loaded.spec, loaded.variables
    assert spec == variant

    code = textwrap.dedent(f"""
        import dataclasses, json
        import jax, numpy as np
        from ffjax import inference, registry, store
        assert {variant.name!r} not in registry.names()
        loaded = store.load({str(tmp_path)!r})
        spec, variables = loaded.spec, loaded.variables
        model = inference.load({str(tmp_path)!r})
        print(json.dumps({{"spec": dataclasses.asdict(spec), "predictor": model.trained.spec.name,
                          "sum": float(sum(np.abs(x).sum() for x in jax.tree.leaves(variables)))}}))
    """)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["spec"] == dataclasses.asdict(variant) and got["predictor"] == variant.name
    assert got["sum"] == pytest.approx(float(sum(np.abs(x).sum() for x in jax.tree.leaves(variables))), rel=1e-6)


def test_an_old_model_json_without_the_spec_falls_back_to_the_registry(variant_run, tmp_path):
    # the variant's weights are dino_rd's architecture: a model.json from before the spec named only "dino_rd"
    shutil.copytree(variant_run[1], tmp_path / "run")
    path = tmp_path / "run" / "model.json"
    info = json.loads(path.read_text())
    del info["spec"], info["sha256"]  # written before model.json recorded the spec (and its digest)
    info["method"] = "dino_rd"
    path.write_text(json.dumps(info))
    assert store.describe(tmp_path / "run").spec == registry.get("dino_rd")
    assert store.load(tmp_path / "run").spec == registry.get("dino_rd")


def test_a_weight_sweep_compiles_one_program():
    """The weights' values are an array of the state (loss_weights), not constants of the program: two betas lower
    to the same train step (so the persistent cache serves every beta of a sweep), and the loss still follows them."""
    from test_train import fixed_batch

    from ffjax.train import step

    cfg = configs.get("smoke")
    states = [train.init_state(cfg, dataclasses.replace(registry.get("dino_rd"), beta=b), jax.random.PRNGKey(0))
              for b in (10.0, 1.0)]
    batch = fixed_batch(cfg)
    texts = [step.train_step.lower(s, batch).as_text() for s in states]
    assert texts[0] == texts[1]
    evals = [step.eval_step(s, {**batch, "mask": np.ones(8, np.float32)}) for s in states]
    for ev, beta in zip(evals, (10.0, 1.0)):
        assert float(ev["loss"]) == pytest.approx(float(ev["force_l1"]) + beta * float(ev["depth_mse"]), rel=1e-5)
