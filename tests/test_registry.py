"""Registry: ablations are data; lookup, defaults, and adding a variant."""

import dataclasses

import pytest

from ffjax import registry
from ffjax.registry import Method


def test_paper_set_in_table_order():
    assert registry.PAPER_SET == ("resnet_rd", "dino_f_r", "dino_f_rd", "dino_r", "dino_rd")
    assert set(registry.PAPER_SET) <= set(registry.names())
    assert registry.get("dino_f_r").paper_name == "DINO_F R"


@pytest.mark.parametrize(
    "name, backbone, frozen, depth, beta",
    [
        ("resnet_rd", "resnet", False, True, 10.0),
        ("dino_f_r", "vit", True, False, 0.0),
        ("dino_f_rd", "vit", True, True, 10.0),
        ("dino_r", "vit", False, False, 0.0),
        ("dino_rd", "vit", False, True, 10.0),
    ],
)
def test_entries(name, backbone, frozen, depth, beta):
    m = registry.get(name)
    got = (m.backbone, m.frozen_backbone, m.depth_head, m.beta, m.alpha)
    assert got == (backbone, frozen, depth, beta, 1.0)
    assert m.pretrained
    assert m.trains == ("heads" if frozen else "all")


def test_scratch_variant_and_lrs():
    m = registry.get("dino_rd_scratch")
    assert not m.pretrained and m.depth_head
    train = {"lr_backbone": 1e-5, "lr_heads": 5e-5}
    assert m.lrs(train) == (1e-5, 5e-5)
    assert registry.get("dino_f_rd").lrs(train) == (0.0, 5e-5)


def test_unknown_name_lists_choices():
    with pytest.raises(KeyError, match="dino_rd"):
        registry.get("nope")


def test_register_one_entry(monkeypatch):
    monkeypatch.setattr(registry, "_METHODS", dict(registry._METHODS))
    m = registry.register(Method("dino_rd_b5", "DINO RD (beta 5)", "vit", beta=5.0))
    assert registry.get("dino_rd_b5") is m and "dino_rd_b5" in registry.names()
    with pytest.raises(ValueError, match="already"):
        registry.register(Method("dino_rd_b5", "x", "vit"))
    with pytest.raises(ValueError, match="depth head"):
        Method("bad", "bad", "vit", depth_head=False, beta=1.0)
    with pytest.raises(ValueError, match="backbone"):
        Method("bad", "bad", "convnext")
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.alpha = 2.0
