"""Config and CLI-override validation: unknown keys (with the closest valid ones), wrong types and impossible
values are rejected by configs.get, naming the key, before any work starts."""

import pytest

import configs


@pytest.mark.parametrize("preset", configs.PRESETS)
def test_every_preset_validates(preset):
    cfg = configs.get(preset)
    assert configs.validate(cfg) is cfg


@pytest.mark.parametrize("override, fragment", [
    ("train.lerning_rate=1", r"'train.lerning_rate'; did you mean 'train.lr_heads' or 'train.lr_backbone'"),
    ("trian.epochs=3", r"unknown config key 'trian' \(in override 'trian.epochs'\); did you mean 'train.epochs'"),
    ("train.zzz=1", r"unknown config key 'train.zzz' \(keys under 'train': batch_size, epochs"),
    ("train.lr_heads=fast", r"'train.lr_heads' expects float .*got str 'fast'"),
    ("train.batch_size=8.5", r"'train.batch_size' expects int .*got float"),
    ("train.epochs=True", r"'train.epochs' expects int, got True"),
    ("data.render_size=(24, 32, 3)", r"'data.render_size' expects 2 values like \(24, 32\), got 3"),
    ("data.render_size=24", r"'data.render_size' expects tuple"),
])
def test_cli_overrides_unknown_keys_and_wrong_types(override, fragment):
    with pytest.raises(configs.ConfigError, match=fragment):
        configs.get("smoke", dict([configs.parse_override(override)]))


@pytest.mark.parametrize("key, value, fragment", [
    ("data.fz_max", -1.0, "data.fz_max must be > 0"),
    ("data.shear_max", -0.5, "data.shear_max must be >= 0"),
    ("data.render_size", (0, 32), "data.render_size item 0 must be >= 1"),
    ("data.render_size", (2, 2), r"data.render_size \(\(2, 2\)\) must be at least 16 px"),
    ("train.batch_size", 0, "train.batch_size must be >= 1"),
    ("train.epochs", 0, "train.epochs must be >= 1"),
    ("train.lr_backbone", 0.0, "train.lr_backbone must be > 0"),
    ("train.lr_heads", -1e-3, "train.lr_heads must be > 0"),
    ("train.lr_heads", float("nan"), "train.lr_heads must be a number > 0"),
    ("train.schedule", "cosine", "train.schedule must be one of 'constant', 'warmup_cosine'"),
    ("train.nonfinite", "ignore", "train.nonfinite must be one of 'stop', 'skip'"),
    ("data.input_size", 36, r"data.input_size \(36\) must be divisible by model.vit.patch \(8\)"),
    ("model.vit.heads", 3, r"model.vit.dim \(32\) must be divisible by model.vit.heads \(3\)"),
    ("model.vit.pos_grid", "big", "model.vit.pos_grid must be an integer >= 1"),
    ("model.resnet.blocks", (1, 1), r"widths \(4 stages\) and model.resnet.blocks \(2\)"),
    ("pretrain.flip", 1.5, "pretrain.flip must be >= 0 and <= 1"),
    ("pretrain.corpus_sim_fraction", -0.1, "pretrain.corpus_sim_fraction must be >= 0 and <= 1"),
    ("pretrain.local_scale", (0.5, 0.2), "pretrain.local_scale must be .low, high. with low <= high"),
    ("calibrate.holdout", 1.0, "calibrate.holdout must be >= 0 and < 1"),
])
def test_impossible_values_name_the_key(key, value, fragment):
    with pytest.raises(configs.ConfigError, match=fragment):
        configs.get("smoke", {key: value})


def test_all_problems_reported_at_once_and_nonfinite_accepted():
    with pytest.raises(configs.ConfigError) as e:
        configs.get("quick", {"train.batch_size": 0, "train.epochs": 0, "data.fz_max": -1.0})
    msg = str(e.value)
    assert "preset 'quick'" in msg and all(k in msg for k in ("train.batch_size", "train.epochs", "data.fz_max"))
    cfg = configs.get("smoke")
    for mode in ("stop", "skip"):
        cfg["train"]["nonfinite"] = mode
        configs.validate(cfg)
    cfg["train"].pop("nonfinite")
    configs.validate(cfg)  # optional: configs written before the key existed still validate


def test_old_error_types_still_caught():
    """Callers that caught KeyError / TypeError before validation existed keep working."""
    with pytest.raises(KeyError):
        configs.get("smoke", {"train.nope": 1})
    with pytest.raises(TypeError):
        configs.get("smoke", {"train.epochs": "3"})
    with pytest.raises(ValueError, match="unknown preset 'fast'"):
        configs.get("fast")


def test_parse_override():
    assert configs.parse_override("train.lr_heads=1e-3") == ("train.lr_heads", 1e-3)
    assert configs.parse_override("data.render_size=(48, 64)") == ("data.render_size", (48, 64))
    assert configs.parse_override("train.schedule=constant") == ("train.schedule", "constant")
    assert configs.get("smoke", dict([configs.parse_override("data.render_size=[48, 64]")]))["data"][
        "render_size"] == (48, 64)
    for bad in ("train.epochs", "=3"):
        with pytest.raises(configs.ConfigError, match="override"):
            configs.parse_override(bad)


def test_train_cli_rejects_before_any_work(tmp_path, capsys):
    from ffjax.train import __main__ as cli

    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exit_:
        cli.main(["--preset", "smoke", "--method", "dino_r", "--out", str(out), "--set", "train.batch_size=0"])
    assert exit_.value.code == 2  # argparse usage error, no traceback
    assert "train.batch_size must be >= 1" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "data").exists()
