"""The loss-weight sweep, the stability experiment and both notebooks at the smoke preset.

One smoke ablation of a method that needs no pretrained backbone (dino_rd_scratch) is shared: the sweep
reuses it as its beta = 10 run, stability scores its checkpoint, the results notebook shows it.
"""

import json
import math
import os
import sys
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

from experiments import ablation, stability, sweep_loss
from ffjax import registry

ROOT = Path(__file__).resolve().parent.parent
METHOD = "dino_rd_scratch"


@pytest.fixture(scope="module")
def abl(tmp_path_factory):
    root = tmp_path_factory.mktemp("extra")
    data, out = root / "data", root / "ablation"
    ablation.main(["--preset", "smoke", "--methods", METHOD, "--out", str(out), "--data", str(data), "--quiet"])
    return root, data, out


def test_sweep_writes_files_and_reuses_the_ablation_run(abl):
    root, data, out_abl = abl
    out = root / "sweep"
    res = sweep_loss.main(["--preset", "smoke", "--base", METHOD, "--betas", "0", "10", "--seeds", "1",
                           "--ablation", str(out_abl), "--out", str(out), "--data", str(data), "--quiet"])
    for name in ("results.json", "sweep.md", "sweep.csv", "sweep.png"):
        assert (out / name).stat().st_size > 0, name
    saved = json.loads((out / "results.json").read_text())
    assert saved["preset"] == "smoke" and saved["seeds"] == [0] and set(saved["per_beta"]) == {"0", "10"}
    zero, ten = saved["per_beta"]["0"], saved["per_beta"]["10"]
    assert not zero["depth_head"] and registry.get(zero["method"]).beta == 0
    assert ten["method"] == METHOD and ten["run_dirs"] == [str(out_abl / "runs" / METHOD / "seed0")]  # reused
    assert saved["checkpoints"][zero["method"]] == zero["run_dirs"]  # so stability can score the sweep's models
    for m in ("unseen_objects", "unseen_sensors", "digit"):
        assert 0 < zero[m]["mean"] < 200 and zero[m]["n"] == 1
    assert "depth head" in res["finding"] and "beta" in (out / "sweep.md").read_text()


def test_a_reused_beta_takes_every_seed_the_ablation_finished(abl, tmp_path):
    import shutil

    import configs
    from experiments import common, kernel

    root, data, out_abl = abl
    cfg, spec = configs.get("smoke"), registry.get(METHOD)
    runs = tmp_path / "ablation" / "runs" / METHOD
    for seed in (0, 1, 2):
        shutil.copytree(out_abl / "runs" / METHOD / "seed0", runs / f"seed{seed}")
    stage = common.read_json(runs / "seed1" / "stage.json")
    common.write_json(runs / "seed1" / "stage.json", {**stage, "key": kernel.train_key(cfg, spec, 1, data)})
    # seed2 keeps seed 0's key: a run trained with another key is never taken
    assert kernel.seeds_for(cfg, spec, 1, data, tmp_path / "ablation") == [0, 1]
    assert kernel.seeds_for(cfg, spec, 1, data, None) == [0]
    out = tmp_path / "sweep"
    sweep_loss.main(["--preset", "smoke", "--base", METHOD, "--betas", "10", "--seeds", "1", "--ablation",
                     str(tmp_path / "ablation"), "--out", str(out), "--data", str(data), "--quiet"])
    ten = json.loads((out / "results.json").read_text())["per_beta"]["10"]
    assert ten["seeds"] == [0, 1] and ten["unseen_objects"]["n"] == 2
    assert "2 seed(s)" in (out / "sweep.md").read_text()


def test_variant_is_registry_data():
    base = registry.get("dino_rd")
    assert sweep_loss.variant(base, 10) is base
    assert sweep_loss.variant(base, 0).name == "dino_r"  # beta 0 = no depth head = DINO R
    v = sweep_loss.variant(base, 3)
    assert v.name == "dino_rd_b3" and v.beta == 3 and v.depth_head and registry.get(v.name) == v


def test_doubles_at_on_hand_made_numbers():
    lv = [0, 1, 2, 4]
    assert stability.doubles_at(lv, [5, 6, 12, 20]) == pytest.approx(1 + (10 - 6) / (12 - 6))
    assert stability.doubles_at(lv, [5, 10, 11, 12]) == 1  # exactly 2x counts
    assert stability.doubles_at(lv, [5, 6, 7, 9.9]) is None
    assert stability.doubles_at(lv, [8, 2, 10, 16], ref=1) == pytest.approx(1 + (4 - 2) / (10 - 2))
    assert stability.doubles_at(lv, [5, math.nan, 6, 15]) == pytest.approx(2 + 4 / 9 * 2)  # NaN level skipped
    entry = {"methods": {"a": {"doubles_at": 3.0, "ratio_at_max": 2.5}, "b": {"doubles_at": 1.5, "ratio_at_max": 4},
                         "c": {"doubles_at": None, "ratio_at_max": 1.2}}}
    assert stability.breaks_first(entry) == "b"


def test_pick_levels_keeps_nominal_and_strongest():
    import configs

    force = next(f for f in stability.factors(configs.get("quick")) if f.name == "force")
    two = stability.pick_levels(force, 2)
    assert two.levels == (force.levels[force.ref], force.levels[-1]) and two.ref == 0
    assert force.levels[-1] > configs.get("quick")["data"]["fz_max"]  # probes beyond the training range


def test_stability_writes_files(abl):
    root, data, out_abl = abl
    out = root / "stability"
    res = stability.main(["--preset", "smoke", "--methods", METHOD, "--ablation", str(out_abl), "--levels", "2",
                          "--per-level", "9", "--out", str(out), "--data", str(data), "--quiet"])
    names = ["results.json", "stability.md", "stability.csv", "seeds.csv", "stability.png"]
    names += [f"stability_{f}.png" for f in res["factors"]]
    for name in names:
        assert (out / name).stat().st_size > 0, name
    assert not (out / "seeds.png").exists()  # one seed: no seed plot
    saved = json.loads((out / "results.json").read_text())
    assert set(saved["factors"]) == {"noise", "illumination", "edge", "force", "shear_angle", "drift", "flat_size",
                                      "face_texture", "sphere_radius", "elongation", "tilt_shear"}
    for e in saved["factors"].values():
        v = e["methods"][METHOD]
        assert len(e["levels"]) == 2 and len(v["nl1"]) == 2 and all(n > 0 for n in e["n"])
    assert saved["seed_spread"][METHOD]["unseen_objects"]["n"] == 1
    assert saved["checkpoints"][METHOD] == [str(out_abl / "runs" / METHOD / "seed0")]
    assert "Hypothesis" in saved["summary"]


def _execute(path: Path, cwd: Path, monkeypatch) -> None:
    # the kernelspec runs "python": put this interpreter's venv first so the kernel imports ffjax
    monkeypatch.setenv("PATH", os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", ""))
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(cwd)}}).execute()


def test_results_notebook_runs(abl, monkeypatch):
    _, _, out_abl = abl
    monkeypatch.setenv("FFJAX_RESULTS", str(out_abl / "results.json"))
    _execute(ROOT / "notebooks" / "results.ipynb", out_abl, monkeypatch)


def test_simulator_notebook_runs(tmp_path, monkeypatch):
    _execute(ROOT / "notebooks" / "simulator.ipynb", tmp_path, monkeypatch)


def test_tilt_shear_factor_turns_only_the_lean():
    import numpy as np

    import configs
    from ffjax import sim

    cfg = configs.get("smoke")
    f = next(x for x in stability.factors(cfg) if x.name == "tilt_shear")
    sensor = sim.get_sensor(cfg["data"]["train_sensor"])
    base, turned = (stability.presses(cfg, f, f.levels.index(a), 12, sensor) for a in (0.0, 180.0))
    np.testing.assert_array_equal(base["force"], turned["force"])  # same forces and poses, only the lean moves
    np.testing.assert_array_equal(base["x_mm"], turned["x_mm"])
    np.testing.assert_allclose(turned["tilt_deg"], -base["tilt_deg"], atol=1e-12)
    # at the nominal level the shear points along the lean, as the dataset samples it
    t, ft = base["tilt_deg"], base["force"][:, :2]
    assert np.mean(np.sum(np.sign(t) == np.sign(ft), axis=1) == 2) > 0.6
