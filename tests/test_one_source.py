"""One source for each closed set (issue 15): a new sensor is one entry in ffjax/sim/sensors.py, a new backbone
a module, an entry in models.BACKBONES and a config section; the config keys added for knobs the code read
as constants leave numbers and existing data folders as they were."""

import copy
import dataclasses
import json
import sys
import types
from pathlib import Path

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import configs
from ffjax import models, registry, sim
from ffjax.sim import dataset, sensors


def test_a_new_sensor_is_one_entry_in_sensors_py(monkeypatch):
    """The worked example of docs/layout.md: sensors.py with one more PRESETS entry (here added to its source
    and run as a fresh module, as an edit of the file would) names, finds and renders the new sensor."""
    entry = '''
PRESETS["toy"] = Sensor(  # a bare-LED sensor with its own gel: two white LEDs, landscape 120x160
    name="toy", gel_id=1, gel=Gel(young_mpa=0.4, shear_mpa=0.13, thickness_mm=4.0, texture_seed=5),
    leds=(LED(0, 5.0, (1.0, 1.0, 1.0)), LED(180, 5.0, (1.0, 0.9, 0.8))), native_size=(120, 160),
    native_mm_per_px=0.12, falloff=2.0,
)
'''
    src = Path(sensors.__file__).read_text()
    anchor = "\nMINI_NAMES = tuple(_MINIS)"
    assert src.count(anchor) == 1
    edited = types.ModuleType("sensors_with_toy")
    monkeypatch.setitem(sys.modules, edited.__name__, edited)  # dataclasses look their module up
    exec(compile(src.replace(anchor, entry + anchor), sensors.__file__, "exec"), edited.__dict__)

    assert edited.SENSOR_NAMES == sensors.SENSOR_NAMES + ("toy",) and edited.SENSORS[-1] == ("toy", 1)
    toy = edited.get_sensor("toy")
    assert toy.key == "toy"
    with pytest.raises(ValueError, match="one gel"):
        edited.get_sensor("toy", 2)
    frame = sim.press("cross", toy, force=(0.3, 0.0, 5.0), seed=0, size=(24, 32))
    assert frame.image.shape == (24, 32, 3) and frame.image.dtype == np.uint8
    assert np.abs(frame.image.astype(int) - toy.background((24, 32)).astype(int)).max() > 10  # the press shows


def test_sensor_names_have_one_source():
    assert all(key == s.key for key, s in sensors.PRESETS.items())
    assert sim.SENSOR_NAMES == tuple(sensors.PRESETS) and dataset.SENSOR_KEYS is sim.SENSOR_NAMES
    assert set(dataset.MINI_KEYS) == set(sim.SENSOR_NAMES) - {"digit"}
    check = configs.RULES["data.train_sensor"]
    assert all(check(k) is None for k in sim.SENSOR_NAMES) and check("mini-4-gel1")
    assert sim.get_sensor("mini-2", 3) is sim.get_sensor("mini-2-gel3")
    # a sensor derived from a preset (the pretraining corpus's) keeps its key, and with it its background noise
    assert dataclasses.replace(sim.get_sensor("digit"), name="rand-0").key == "rand-0-gel1"


class _Toy(nn.Module):
    """A toy backbone: one strided conv. The module file of a new backbone."""

    width: int

    @nn.compact
    def __call__(self, images, train: bool = False):
        del train
        tokens = nn.relu(nn.Conv(self.width, (8, 8), strides=(8, 8), name="patch")(images))
        return {"feature": tokens.mean(axis=(1, 2)), "tokens": tokens}


def test_a_new_backbone_is_a_module_an_entry_and_a_config_section(monkeypatch):
    """(1) the module (_Toy above), (2) its entry in models.BACKBONES (ffjax/models/model.py), (3) its section
    in configs/base.py; the registry, the model and the train step take it from there."""
    from ffjax import train

    monkeypatch.setitem(models.BACKBONES, "toy", lambda section: _Toy(section["width"]))  # (2)
    cfg = configs.get("smoke")
    cfg["model"]["toy"] = {"width": 16}  # (3)
    spec = registry.Method("toy_rd", "Toy RD", "toy", pretrained=False)
    s, n = cfg["data"]["input_size"], cfg["train"]["batch_size"]
    out = models.build(cfg["model"], spec, s).init_with_output(jax.random.PRNGKey(0), jnp.zeros((2, s, s, 3)))[0]
    assert out["force"].shape == (2, 3) and out["depth"].shape == (2, s, s)

    state = train.init_state(cfg, spec, jax.random.PRNGKey(0))
    rng = np.random.default_rng(0)
    batch = {"image": rng.normal(size=(n, s, s, 3)).astype(np.float32),
             "depth": rng.uniform(size=(n, s, s)).astype(np.float32),
             "force": rng.uniform(0, 5, (n, 3)).astype(np.float32)}
    state, metrics = train.train_step(state, batch)
    assert np.isfinite(float(metrics["loss"]))
    with pytest.raises(ValueError, match="backbone must be one of"):
        registry.Method("bad", "bad", "convnext")


_LATER_DATA_KEYS = ("fz_min", "tilt_max_deg", "shear_noise", "train_sensor", "loading", "path_steps", "ft_noise",
                    "pattern_moving", "path_quadrature")  # issues 15 (knobs), 32 (oblique press), 30 (its quadrature)


def _without_new_keys(cfg: dict) -> dict:
    """The config as it was before these data keys existed (an older model.json)."""
    cfg = {**cfg, "data": dict(cfg["data"])}
    for key in _LATER_DATA_KEYS:
        del cfg["data"][key]
    return cfg


@pytest.mark.parametrize("preset", configs.PRESETS)
def test_old_data_configs_read_as_they_were_made(preset):
    """A config saved before the data keys existed reads them as the code then used them (the press-then-shear
    loading, +-7 deg, no F/T noise, the whole fixed pattern on the gel), so its dataset is told apart from today's
    (gen_config) rather than taken for it."""
    cfg = configs.get(preset)
    g = dataset.gen_config(cfg)
    old = configs.upgrade(_without_new_keys(cfg))  # how a config saved before the keys is read
    before = {k: configs.KEYS[f"data.{k}"].old_value for k in _LATER_DATA_KEYS}
    assert before["loading"] == "shear" and before["tilt_max_deg"] == 7.0 and before["ft_noise"] == 0.0
    assert {k: old["data"][k] for k in _LATER_DATA_KEYS} == before
    then = dataset.gen_config(configs.get(preset, {f"data.{k}": v for k, v in before.items()}))
    assert dataset.gen_config(old) == then and then != g
    assert set(g["data"]) == set(dataset.GEN_KEYS)
    assert [s.sensor for s in dataset.split_specs(cfg)] == [s.sensor for s in dataset.split_specs(old)]


def test_another_train_sensor_is_another_dataset(tmp_path):
    cfg = configs.get("smoke", {"data.train_sensor": "mini-2-gel1"})
    assert dataset.gen_config(cfg)["data"]["train_sensor"] == "mini-2-gel1"
    specs = {s.name: s.sensor for s in dataset.split_specs(cfg)}
    assert specs["train"] == specs["val"] == specs["unseen/banana"] == "mini-2-gel1"
    assert specs["sensor/mini-1-gel1"] == "mini-1-gel1"
    (tmp_path / "config.json").write_text(json.dumps(dataset.gen_config(configs.get("smoke"))))
    with pytest.raises(FileExistsError, match="train_sensor"):
        dataset._prepare(tmp_path, dataset.gen_config(cfg), force=False)


def test_old_configs_are_upgraded_in_one_place():
    """A config saved before a key existed (an old model.json) is read through configs.upgrade: the keys it lacks
    get the values the code used then, the keys it has stay; nothing else falls back to a default of its own."""
    cfg = configs.get("smoke")
    old = copy.deepcopy(_without_new_keys(cfg))
    del old["model"]["vit"]["interpolate_offset"], old["model"]["decoder"]["fast"]
    del old["train"]["schedule"], old["data"]["depth_eps"], old["pretrain"]
    up = configs.upgrade(old)
    assert up["data"]["train_sensor"] == "mini-1-gel1" and up["model"]["vit"]["interpolate_offset"] == 0.1
    assert up["train"]["schedule"] == "constant" and up["data"]["depth_eps"] == 0.0  # what the code did then
    assert up["pretrain"]["steps"] == 100 and up["model"]["decoder"]["fast"] is True
    assert up["data"]["loading"] == "shear" and up["data"]["tilt_max_deg"] == 7.0  # issue 32 changed these
    same = lambda d: {k: v for k, v in d.items() if k not in ("depth_eps", *_LATER_DATA_KEYS[4:], "tilt_max_deg")}  # noqa: E731
    assert same(up["data"]) == same(cfg["data"])
    assert configs.upgrade(cfg) == cfg  # a full config is left as it is
    assert configs.validate(up) is up


def test_caches_ignore_new_keys_at_their_old_values():
    """A pretrained backbone cached before model.vit.interpolate_offset was a key keeps matching; another value
    is another backbone."""
    from ffjax.train import pretrain

    cfg = configs.get("smoke")
    before = copy.deepcopy(cfg)
    del before["model"]["vit"]["interpolate_offset"]
    assert pretrain.settings(cfg, "vit") == pretrain.settings(before, "vit")
    assert pretrain.settings(configs.get("smoke", {"model.vit.interpolate_offset": 0.0}), "vit") != \
        pretrain.settings(cfg, "vit")


def test_the_default_dataset_folder_never_depends_on_the_working_folder(tmp_path, monkeypatch):
    """Issue 33 (8): without --data, every tool keeps a preset's dataset in one documented place (the checkout's
    data/<preset>, or $FFJAX_DATA/<preset>), not in whatever folder it was started from."""
    from experiments import common

    monkeypatch.delenv(dataset.DATA_ENV, raising=False)
    monkeypatch.chdir(tmp_path)
    assert dataset.default_root("smoke") == common.ROOT / "data" / "smoke"
    monkeypatch.setenv(dataset.DATA_ENV, str(tmp_path / "cache"))
    assert dataset.default_root("quick") == tmp_path / "cache" / "quick"
    # every tool asks default_root: none builds a data path of its own relative to the working folder
    for f in ("ffjax/train/__main__.py", "ffjax/train/pretrain/__main__.py", "experiments/common.py",
              "experiments/pattern_share.py", "experiments/diagnostics/object_probe.py"):
        text = (common.ROOT / f).read_text()
        assert "default_root(" in text and 'Path("data")' not in text and 'ROOT / "data"' not in text, f
