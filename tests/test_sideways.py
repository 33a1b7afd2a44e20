"""data.sideways_share: oblique datasets with a share of presses pushed sideways after contact, their shear drawn
apart from the tool's lean (issue 64)."""

import numpy as np

import configs
from ffjax.sim import dataset

SHARE = 0.5


def _cfg(share=SHARE):
    return configs.get("smoke", {"data.sideways_share": share})


def test_the_share_is_off_by_default_and_named_in_the_config_only_when_used():
    assert configs.get("smoke")["data"]["sideways_share"] == 0
    assert "sideways_share" not in dataset.gen_config(configs.get("smoke"))["data"]  # older folders stay valid
    assert dataset.gen_config(_cfg())["data"]["sideways_share"] == SHARE


def test_train_and_val_take_the_share_per_shape_and_the_tests_keep_the_papers_presses():
    cfg, plain = _cfg(), configs.get("smoke")
    for spec in dataset.split_specs(cfg):
        p, p0 = dataset.sample_presses(spec, cfg), dataset.sample_presses(spec, plain)
        if spec.name not in ("train", "val"):
            assert "sideways" not in p and all(np.array_equal(p[k], p0[k]) for k in p0), spec.name
            continue
        side = p["sideways"]
        for si in range(len(spec.shapes)):  # round(share x n) of every shape
            assert side[p["shape_index"] == si].sum() == round(SHARE * spec.per_shape), (spec.name, si)
        # the oblique presses and every pose are what the split draws without the share
        assert all(np.array_equal(p[k], p0[k]) for k in p0 if k != "force")
        np.testing.assert_array_equal(p["force"][:, 2], p0["force"][:, 2])
        assert not p["force"][~side, :2].any()  # an oblique request is the normal force alone
        push = p["force"][side, :2]
        assert np.abs(push).max() <= cfg["data"]["shear_max"] and (push > 0).any() and (push < 0).any()


def test_a_sideways_push_is_drawn_apart_from_the_lean():
    cfg = configs.get("smoke", {"data.sideways_share": 1.0, "data.train_per_indenter": 200})
    p = dataset.sample_presses(dataset.split_specs(cfg)[0], cfg)
    for axis in (0, 1):  # an oblique press's shear follows tan(tilt); these do not
        r = np.corrcoef(p["force"][:, axis], np.tan(np.radians(p["tilt_deg"][:, axis])))[0, 1]
        assert abs(r) < 0.1, (axis, r)


def test_a_shard_carries_the_flag_and_the_gel_the_push_up_to_coulomb():
    cfg = _cfg(1.0)
    spec, data = dataset.split_specs(cfg)[0], dataset.gen_config(cfg)["data"]
    p = dataset.sample_presses(spec, cfg)
    out = dataset.render_shard(spec, p, 0, 6, cfg["data"]["render_size"], data)
    assert out["sideways"].all() and out["image"].shape[0] == 6
    applied, asked = out["force_applied"], out["requested_force"]
    stick = ~out["slip"].astype(bool)
    assert stick.any()
    np.testing.assert_allclose(applied[stick, :2], asked[stick, :2], atol=0.02)  # stick: the push, as asked
    assert np.all(np.linalg.norm(applied[:, :2], axis=1) <= np.linalg.norm(asked[:, :2], axis=1) + 1e-3)
