"""Configs: one base (configs/base.py) plus per-preset differences; every merged preset pinned value for value,
every key checked, every backbone kind configured."""

import json
from pathlib import Path

import pytest

import configs
from configs import base
from configs.checks import Key, derive

PINNED = Path(__file__).parent / "fixtures" / "configs_pinned.json"


def _flat(tree: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in tree.items():
        out.update(_flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
    return out


@pytest.mark.parametrize("preset", configs.PRESETS)
def test_merged_preset_matches_the_pinned_one(preset):
    """Every preset's merged config, value and type (tuple vs list, int vs float), as before the base/differences
    split (issue 15; the snapshot adds only the keys that split gave a name: fz_min, tilt_max_deg, shear_noise,
    train_sensor, decoder.fast, vit.interpolate_offset, seeds, each at the value the code used before; issue 32
    turned tilt_max_deg to 15 and added loading, path_steps, ft_noise and pattern_moving; issue 30 added
    path_quadrature and turned path_steps from 4 to 2; issue 64 added train.drift_minutes and data.sideways_share,
    both off)."""
    got = {k: repr(v) for k, v in _flat(configs.get(preset)).items()}
    assert got == json.loads(PINNED.read_text())[preset]


def test_every_key_has_a_check_and_every_check_a_key():
    keys = set(_flat(base.CONFIG))
    assert set(configs.RULES) == keys
    assert all(callable(check) for check in configs.RULES.values())
    for preset in configs.PRESETS:
        assert set(_flat(configs.get(preset))) - {"preset"} == keys, preset
    assert all(isinstance(k, Key) for k in _flat(base.SPEC).values())


def test_base_defaults_pass_their_checks():
    for key, value in _flat(base.CONFIG).items():
        assert configs.RULES[key](value) is None, key


def test_every_backbone_kind_has_a_config_section():
    from ffjax import models

    for kind in models.BACKBONES:
        assert isinstance(base.CONFIG["model"][kind], dict), kind


def test_new_keys_reach_set_and_are_checked():
    cfg = configs.get("smoke", {"data.fz_min": 1, "data.train_sensor": "digit", "model.decoder.fast": False,
                                "model.vit.interpolate_offset": 0.0, "seeds": 2})
    assert (cfg["data"]["fz_min"], cfg["data"]["train_sensor"], cfg["seeds"]) == (1.0, "digit", 2)
    assert cfg["model"]["decoder"]["fast"] is False and cfg["model"]["vit"]["interpolate_offset"] == 0.0
    for key, value, fragment in [("data.train_sensor", "mini-9-gel1", "data.train_sensor must be one of"),
                                 ("data.fz_min", 20.0, r"data.fz_min \(20.0\) must be below data.fz_max"),
                                 ("data.tilt_max_deg", 90.0, "data.tilt_max_deg must be >= 0 and < 90"),
                                 ("seeds", 0, "seeds must be >= 1"),
                                 ("model.decoder.fast", 1, "expects bool")]:
        with pytest.raises(configs.ConfigError, match=fragment):
            configs.get("smoke", {key: value})
    with pytest.raises(configs.UnknownKeyError, match="data.fz_mni"):
        configs.get("smoke", {"data.fz_mni": 1.0})


def test_old_configs_without_the_new_keys_still_validate():
    cfg = configs.get("quick")
    for section, key in (("data", "fz_min"), ("data", "train_sensor"), ("data", "shear_noise")):
        del cfg[section][key]
    del cfg["model"]["decoder"]["fast"], cfg["model"]["vit"]["interpolate_offset"], cfg["seeds"]
    configs.validate(cfg)


def test_derive_refuses_a_key_the_parent_lacks():
    with pytest.raises(KeyError, match="train.epoch"):
        derive(base.CONFIG, {"train": {"epoch": 3}})


def test_before_keys_are_left_out_of_cache_keys_while_they_hold_the_old_values():
    for preset in configs.PRESETS:
        cfg = configs.get(preset)
        kept = _flat(configs.without_before_keys(cfg))
        assert set(_flat(cfg)) - set(kept) == set(configs.BEFORE_KEYS), preset
        assert all(kept[k] == v for k, v in _flat(cfg).items() if k in kept)
    changed = configs.get("smoke", {"data.train_sensor": "digit", "model.decoder.fast": False})
    kept = _flat(configs.without_before_keys(changed))
    assert kept["data.train_sensor"] == "digit" and kept["model.decoder.fast"] is False
    assert set(configs.BEFORE_KEYS) <= set(_flat(base.CONFIG))
