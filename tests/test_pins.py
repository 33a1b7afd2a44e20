"""tests/_pins.py: which pin is this machine's, and the cross-CPU comparison."""

import json

import _pins


def test_close_numbers_and_strings_pass_and_far_ones_fail():
    want = {"a": [19.047, 0.158], "s": "DINO RD < DINO R (6.1% vs 6.0%)", "n": 3}
    near = {"a": [18.961, 0.169], "s": "DINO RD < DINO R (6.2% vs 6.0%)", "n": 3}
    assert _pins.differences(near, want) == []
    assert _pins.differences({**near, "a": [20.0, 0.158]}, want) == [".a[0]: 20.0 != 19.047"]
    assert _pins.differences({**near, "s": "DINO R < DINO RD (6.1% vs 6.0%)"}, want)  # words must match
    assert _pins.differences({**near, "n": 4}, want) == [".n: 4 != 3"]
    assert _pins.differences({"a": []}, want) == [": keys ['n', 's'] differ"]


def test_the_pin_of_this_cpu_kind_is_found(tmp_path, monkeypatch):
    here = {"vendor": "V", "family": "1", "model": "2", "isa": ["avx2"]}
    monkeypatch.setattr(_pins, "PINS", tmp_path)
    monkeypatch.setattr(_pins, "cpu_kind", lambda: here)
    (tmp_path / "x").mkdir()
    for name, cpu, jax in (("a", {"vendor": "V"}, "1"), ("b", {**here, "model": "3"}, "1"), ("c", here, "2")):
        (tmp_path / "x" / f"{name}.json").write_text(json.dumps({"cpu": cpu, "jax": jax, "v": name}))
    own, others = _pins.load("x", "1")  # a vendor-only pin matches every CPU of that vendor
    assert own["v"] == "a" and [p["v"] for p in others] == ["b"]
    own, others = _pins.load("x", "2")
    assert own["v"] == "c" and others == []


def test_a_pin_marked_not_bitwise_is_held_within_the_tolerance_on_its_own_kind(tmp_path, monkeypatch):
    here = {"vendor": "V", "family": "1", "model": "2"}
    monkeypatch.setattr(_pins, "PINS", tmp_path)
    monkeypatch.setattr(_pins, "cpu_kind", lambda: here)
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "a.json").write_text(json.dumps({"cpu": {"vendor": "V"}, "jax": "1", "bitwise": False,
                                                       "why": "made before a change", "v": 1}))
    own, others = _pins.load("x", "1")
    assert own is None and [_pins.strip_meta(p) for p in others] == [{"v": 1}]
