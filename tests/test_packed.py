"""Resume checkpoints hold the run state packed (one buffer per dtype): exact round trips, refusals that name
the tensor, and runs saved before packing still resume and load."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _tiny_data import write_tiny_dataset

import configs
from ffjax import store, train
from ffjax.store import checkpoints as ckpt_lib
from ffjax.store import packed

TREE = {"params": {"a": {"kernel": jnp.arange(6.0).reshape(2, 3)}, "b": jnp.ones(4)},
        "batch_stats": {"bn": {"mean": jnp.full((2,), 0.5)}},
        "opt_state": (jnp.zeros(3), {"count": jnp.int32(7)}), "key": jnp.array([1, 2], jnp.uint32)}


def test_pack_unpack_is_exact():
    bufs = packed.pack(TREE)
    assert {k: v.shape for k, v in bufs.items()} == {"float32": (6 + 4 + 2 + 3,), "int32": (1,), "uint32": (2,)}
    back = packed.unpack(bufs, packed.layout(TREE), TREE)
    assert jax.tree.structure(back) == jax.tree.structure(TREE)
    for a, b in zip(jax.tree.leaves(back), jax.tree.leaves(TREE)):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    v = packed.variables_from(bufs, packed.layout(TREE))
    assert np.array_equal(v["params"]["a"]["kernel"], TREE["params"]["a"]["kernel"])
    assert np.array_equal(v["batch_stats"]["bn"]["mean"], TREE["batch_stats"]["bn"]["mean"])


def test_another_models_layout_is_refused_by_name():
    wider = {**TREE, "params": {**TREE["params"], "b": jnp.ones(5)}}
    with pytest.raises(ValueError, match=r"\['params', 'b'\].*\[5\]"):
        packed.unpack(packed.pack(wider), packed.layout(wider), TREE)
    with pytest.raises(ValueError, match="float32 buffer"):
        packed.unpack_leaves(packed.pack(TREE), packed.layout(wider))


def _leaves_equal(a, b):
    return all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


def test_a_run_saved_before_packing_resumes_and_loads(tmp_path, monkeypatch):
    data = write_tiny_dataset(tmp_path / "data", 32, 12)
    cfg = configs.get("smoke", {"train.epochs": 2, "train.ckpt_every": 3})
    whole = train.train(cfg, "dino_rd", data, tmp_path / "whole", progress=False)
    with monkeypatch.context() as m:  # the tensor-tree format every run had before packing
        m.setattr(packed, "packable", lambda tree: False)
        train.train(cfg, "dino_rd", data, tmp_path / "old", progress=False, max_steps=2)
    step = next(p for p in (tmp_path / "old" / "checkpoints").iterdir() if p.name.isdigit())
    assert (step / ckpt_lib.STATE).is_dir() and not (step / ckpt_lib.PACKED).exists()
    variables = store.load(tmp_path / "old", "latest").variables
    assert set(variables) >= {"params"}
    done = train.train(cfg, "dino_rd", data, tmp_path / "old", resume=True, progress=False)
    assert _leaves_equal(done["state"].arrays(), whole["state"].arrays())
    newest = max(int(p.name) for p in (tmp_path / "old" / "checkpoints").iterdir() if p.name.isdigit())
    assert (tmp_path / "old" / "checkpoints" / str(newest) / ckpt_lib.PACKED).is_dir()
    latest = store.load(tmp_path / "whole", "latest").variables
    assert _leaves_equal(latest["params"], whole["state"].params)
