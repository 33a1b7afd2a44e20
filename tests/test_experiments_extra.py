"""The loss-weight sweep's and the stability experiment's parts, and the simulator notebook. Their smoke runs,
and the results notebook on them, are part of the whole pipeline's test (test_reproduce.py)."""

import math
from pathlib import Path

import _notebooks
import pytest

from experiments import stability, sweep_loss
from ffjax import registry

ROOT = Path(__file__).resolve().parent.parent


def test_variant_is_registry_data():
    base = registry.get("dino_rd")
    assert sweep_loss.variant(base, 10) is base
    assert sweep_loss.variant(base, 0).name == "dino_r"  # beta 0 = no depth head = DINO R
    v = sweep_loss.variant(base, 3)
    assert v.name == "dino_rd_b3" and v.beta == 3 and v.depth_head and registry.get(v.name) == v


def test_sweep_finding_judges_each_gap_against_the_spread():
    """The sweep's sentences call a gap 'helps' or 'hurts' only beyond the seeds' spread, and say that the lowest of
    several one-seed points is biased low."""
    def cell(beta, mean, std, n, name):
        ms = {"mean": mean, "std": std, "n": n}
        return {"beta": beta, "ratio": beta, "per_seed": [{}] * n, "paper_name": name,
                **{m: ms for m in sweep_loss.METRICS}}

    cells = {"0": cell(0.0, 5.0, 0.1, 3, "DINO R"), "10": cell(10.0, 5.4, 0.1, 3, "DINO RD"),
             "1": cell(1.0, 4.9, 0.0, 1, "b1"), "3": cell(3.0, 5.2, 0.0, 1, "b3")}
    res = {"base": "dino_rd", "per_beta": cells}
    text = sweep_loss.finding(res)
    assert "beta/alpha = 10 5.40 ± 0.10%: the head hurts (gap +0.40 beyond the seeds' spread, 0.14)" in text
    assert "beta/alpha, 1 (1 seed), 4.90%: a tie with no head" in text and "biased low" in text
    assert "helps" not in text


def test_doubles_at_on_hand_made_numbers():
    lv = [0, 1, 2, 4]
    assert stability.doubles_at(lv, [5, 6, 12, 20]) == pytest.approx(1 + (10 - 6) / (12 - 6))
    assert stability.doubles_at(lv, [5, 10, 11, 12]) == 1  # exactly 2x counts
    assert stability.doubles_at(lv, [5, 6, 7, 9.9]) is None
    assert stability.doubles_at(lv, [8, 2, 10, 16], ref=1) == pytest.approx(1 + (4 - 2) / (10 - 2))
    assert stability.doubles_at(lv, [5, math.nan, 6, 15]) == pytest.approx(2 + 4 / 9 * 2)  # NaN level skipped
    # a nominal level at the end: the departures lie below it (the big sphere's 40 mm against smaller spheres)
    assert stability.doubles_at(lv, [4.1, 5.3, 3.0, 2.1], ref=3) == pytest.approx(2 - (4.2 - 3.0) / (5.3 - 3.0))
    assert stability.doubles_at(lv, [9, 3, 4, 12], ref=2) == 3  # the nearer side's crossing (3 vs 0)
    assert stability.strongest({"levels": [4, 10, 40], "ref": 2}) == 0
    assert stability.strongest({"levels": [0, 1, 2], "ref": 1}) == 2
    entry = {"levels": [0, 1, 2, 4], "ref": 0,
             "methods": {"a": {"doubles_at": 3.0, "ratio_at_max": 2.5}, "b": {"doubles_at": 1.5, "ratio_at_max": 4},
                         "c": {"doubles_at": None, "ratio_at_max": 1.2}}}
    assert stability.breaks_first(entry) == "b"
    entry["ref"] = 3  # below the nominal level the first to break is the one that doubles nearest it
    assert stability.breaks_first(entry) == "a"


def test_pick_levels_keeps_nominal_and_strongest():
    import configs

    force = next(f for f in stability.factors(configs.get("quick")) if f.name == "force")
    two = stability.pick_levels(force, 2)
    assert two.levels == (force.levels[force.ref], force.levels[-1]) and two.ref == 0
    assert force.levels[-1] > configs.get("quick")["data"]["fz_max"]  # probes beyond the training range


def test_simulator_notebook_runs(tmp_path, monkeypatch):
    _notebooks.execute(ROOT / "notebooks" / "simulator.ipynb", tmp_path, monkeypatch)


def test_tilt_shear_factor_turns_only_the_lean():
    import numpy as np

    import configs
    from ffjax import sim

    cfg = configs.get("smoke")
    f = next(x for x in stability.factors(cfg) if x.name == "tilt_shear")
    sensor = sim.get_sensor(cfg["data"]["train_sensor"])
    base, turned = (stability.presses(cfg, f, f.levels.index(a), 60, sensor) for a in (0.0, 180.0))
    np.testing.assert_array_equal(base["force"], turned["force"])  # same forces and poses, only the lean moves
    np.testing.assert_array_equal(base["x_mm"], turned["x_mm"])
    np.testing.assert_allclose(turned["tilt_deg"], -base["tilt_deg"], atol=1e-12)
    # at the nominal level the push follows the lean, as the oblique press's shear does on average
    lean = base["force"][:, 2:] * np.tan(np.radians(base["tilt_deg"]))
    np.testing.assert_allclose(base["force"][:, :2], stability.PUSH_RATIO * lean)
    assert stability.loading(cfg, f) == "shear"  # pressed, then pushed: the lean and the push can differ
    assert stability.loading(cfg, next(x for x in stability.factors(cfg) if x.name == "noise")) == "oblique"


def test_pigment_factor_keeps_the_mechanics():
    """Texture against mechanics: level 1 is the training gel's mechanics with gel 2's pigment, level 2 the pigment
    frozen (the whole fine pattern the camera's, the same total); the camera and the mechanics never change."""
    import dataclasses

    import configs
    from ffjax.sim import dataset

    cfg = configs.get("smoke")
    nominal = dataset.sensor_of(cfg["data"]["train_sensor"], cfg["data"])
    own, _ = stability.sensors_for("pigment", 0.0, nominal)
    other, other_bg = stability.sensors_for("pigment", 1.0, nominal)
    frozen, _ = stability.sensors_for("pigment", 2.0, nominal)
    assert own is nominal and other is other_bg
    mech = lambda s: dataclasses.replace(s.gel, texture_seed=0, pigment=0.0)  # noqa: E731
    assert mech(other) == mech(frozen) == mech(nominal)
    assert other.gel.texture_seed == dataset.sensor_of("mini-1-gel2", cfg["data"]).gel.texture_seed \
        != nominal.gel.texture_seed
    assert other.gel.pigment > 0 and frozen.gel.pigment == 0
    total = lambda s: s.gel.pigment ** 2 + s.pixel_pattern ** 2  # noqa: E731
    assert abs(total(frozen) - total(nominal)) < 1e-12
    assert dataclasses.replace(other, gel=nominal.gel) == nominal  # the camera side is the training sensor's


def test_stability_solves_levels_that_share_presses_once_with_the_same_frames(monkeypatch):
    """The camera, lighting, pigment, marker and drift levels press the very same presses on one gel: render_sets
    solves them once (press_many_seen) and gives each level the frames pressing it alone gives."""
    import numpy as np

    import configs
    from ffjax import sim
    from ffjax.sim import dataset

    cfg = configs.get("smoke")
    chosen = {f.name: f for f in stability.factors(cfg)}
    jobs = [(chosen[n], li) for n, li in (("noise", 0), ("noise", 5), ("drift", 0), ("drift", 5), ("pigment", 1),
                                         ("markers", 1), ("edge", 3))]
    calls = []
    seen = sim.press_many_seen
    monkeypatch.setattr(sim, "press_many_seen", lambda *a, **k: calls.append(len(a[1])) or seen(*a, **k))
    sets = stability.render_sets(cfg, jobs, 4)
    assert sorted(calls) == [1, 4]  # edge's poses on their own; the rest one solve seen by 4 distinct sensors
    nominal = dataset.sensor_of(cfg["data"]["train_sensor"], cfg["data"])
    size = dataset.render_size(nominal, cfg["data"]["render_size"])
    for f, li in jobs:
        frame, background = stability.sensors_for(f.name, f.levels[li], nominal)
        p = stability.presses(cfg, f, li, 4, nominal)
        alone = sim.press_many([p["shapes"][k] for k in p["shape_index"]], frame, p["force"], p["x_mm"], p["y_mm"],
                               p["yaw_deg"], p["tilt_deg"], [int(v) for v in p["seed"]], size,
                               path=stability.loading(cfg, f), steps=int(cfg["data"]["path_steps"]))
        got = sets[f.name, li]
        np.testing.assert_array_equal(got["image"], np.stack([s.image for s in alone]))
        np.testing.assert_array_equal(got["force"], np.stack([s.force for s in alone]))
        np.testing.assert_array_equal(got["background"], background.background(size))
    mini2 = sim.get_sensor("mini-3-gel2")
    with pytest.raises(ValueError, match="solves presses differently"):
        sim.press_many_seen(["sphere_small"], [nominal, mini2], [(0, 0, 1.0)], [0], [0], [0], [(0, 0)], [0], size)


def test_sweep_says_which_betas_have_which_seeds():
    """The sweep's own betas are seed 0, the betas reused from the ablation 0-2: said per group, not as the union,
    from what each beta records; a results.json from before `reused` was recorded is refused by name, not guessed."""
    def beta(seeds, folder, method):
        return {"seeds": seeds, "per_seed": [{}] * len(seeds), "reused": [folder == "ablation"] * len(seeds),
                "run_dirs": [f"/r/{folder}/runs/{method}/seed{k}" for k in seeds]}

    res = {"seeds": [0], "per_beta": {"0": beta([0, 1, 2], "ablation", "dino_r"), "1": beta([0], "sweep", "b1"),
                                      "10": beta([0, 1, 2], "ablation", "dino_rd"), "30": beta([0], "sweep", "b30")}}
    want = "0 for the sweep's own cells (beta 1, 30); 0-2 for the cells reused from the ablation (beta 0, 10)"
    assert sweep_loss.seeds_said(res, names=True) == want
    res["per_beta"]["10"]["reused"] = [True, False, True]
    assert sweep_loss.seeds_said(res) == ("0 for the sweep's own cells; 0-2 for the cells partly reused from the "
                                          "ablation and the cells reused from the ablation")
    del res["per_beta"]["30"]["reused"]
    with pytest.raises(ValueError, match=r"per_beta\['30'\] has no 'reused'"):
        sweep_loss.seeds_said(res)


def test_downstream_names_the_checkpoint_a_figure_shows():
    from experiments import downstream_report

    res = {"checkpoints": {"dino_rd": ["/r/ablation/runs/dino_rd/seed2", "/r/ablation/runs/dino_rd/seed0"]}}
    assert downstream_report.first_checkpoint(res, "dino_rd") == "one DINO RD checkpoint (seed 2)"
    res = {"checkpoints": {"dino_rd": ["/r/runs/quick-dino_rd"]}}
    assert downstream_report.first_checkpoint(res, "dino_rd") == "one DINO RD checkpoint (quick-dino_rd)"


def test_help_costs_come_from_the_published_record(tmp_path, monkeypatch):
    """--help's measured time is read from docs/results/<preset>/reproduce.json, not written in the source; none
    published (or not run afresh): the plain description alone."""
    import json

    from experiments import common

    rec = tmp_path / "docs" / "results" / "quick" / "reproduce.json"
    rec.parent.mkdir(parents=True)
    rec.write_text(json.dumps({"commit": "c" * 40, "machine": {"cpu_model": "CPU X", "cores": 2},
                               "experiments": {"sweep_loss": {"wall_s": 597.8, "fresh": True, "commit": "a" * 40},
                                               "pattern_share": {"wall_s": 2.4, "fresh": False}}}))
    monkeypatch.setattr(common, "ROOT", tmp_path)
    assert common.measured_cost("sweep_loss", "quick") == ("measured 10 min at aaaaaaa on CPU X, 2 cores "
                                                           "(docs/results/quick/reproduce.json)")
    assert common.measured_cost("pattern_share", "quick") is None
    assert common.measured_cost("sweep_loss", "full") is None
    costs = common.base_parser("x", costs={"quick": "reuses runs"}, experiment="sweep_loss").get_default("_costs")
    assert costs["quick"].startswith("reuses runs; measured 10 min")
    # an entry run on another VM names its own machine, not the record's last one
    record = json.loads(rec.read_text())
    record["experiments"]["sweep_loss"]["machine"] = {"cpu_model": "CPU Y", "cores": 2}
    rec.write_text(json.dumps(record))
    assert "on CPU Y, 2 cores" in common.measured_cost("sweep_loss", "quick")
    assert "measured" not in common.base_parser("x", costs={"quick": "q"}).get_default("_costs")["quick"]
