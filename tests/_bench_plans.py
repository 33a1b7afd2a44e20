"""A tiny plan of experiments.bench (every section at toy sizes, seconds) and the checks of what it writes. The
smoke pipeline (tests/test_reproduce.py) runs the benchmark and the simulator's benchmark with it and applies
the checks; tests/test_bench.py times single parts with it."""

import json
import math

TINY = {
    "name": "test",
    "cases": {"quick_vit": {"preset": "smoke", "method": "dino_rd", "size": 32, "batch": 4, "infer": (1,)},
              "resnet": {"preset": "smoke", "method": "resnet_rd", "size": 32, "batch": 4, "infer": (1,)}},
    "vit_b14": None, "timing": (0, 1, 1), "infer_timing": (0, 1, 1), "peak_n": 128,
    "sim": {"n": {"64x64": 10}, "sizes": {"64x64": (24, 32)}}, "data": {"per_shape": 1, "batches": 2},
    "workers": (0,), "scaling": None, "dp": None, "bf16_acc": None, "profile": False,
    "fast": ("recompile", "donation"), "loop": {"train": 16, "val": 8, "epochs": 2, "val_every": (1, 2)},
}
# the simulator's part (`--only sim`): both paths at one size, agreement on two sensors, the path's steps, one
# batch's memory
TINY_SIM = {"sizes": {"24x32": (24, 32)}, "batches": (1, 4), "n": 4, "reference_n": 2, "agreement_size": (24, 32),
            "agreement_per_shape": 1, "agreement_sensors": ("mini-1-gel1", "digit"), "memory": (4, (24, 32)),
            "dataset": None, "path": {"n": 4, "steps": (1, 2), "reference": 4},
            "discretization": {"sizes": {"smoke": (24, 32)}, "per_shape": 1, "shapes": ("sphere_big", "cross")}}
# what the smoke pipeline's `experiments.bench --smoke` runs: TINY with a small scaling sweep (the pipeline skips
# no section) and the simulator's part, with the smoke dataset's time read from the one the ablation made
PIPELINE = {**TINY, "name": "smoke", "scaling": {"base": "smoke", "batch": (4,), "size": (16,), "model": ((16, 1, 2),)},
            "sim_speed": {**TINY_SIM, "dataset": "smoke"}}


def check_bench(out, res: dict) -> None:
    """A full benchmark run at TINY's sizes: every section, finite positive ratios, the step compiled once, the
    report's sections (also with sections missing, and for a GPU run with torch.compile), equal parameter counts
    on the PyTorch side when it ran."""
    import copy

    from experiments.bench import report as bench_report

    saved = json.loads((out / "results.json").read_text())
    for key in ("commit", "machine", "peak", "models", "data", "fast", "ratios", "_env", "date_utc"):
        assert key in saved, key
    assert saved["machine"]["cores"] >= 1
    case = saved["models"]["quick_vit"]
    assert case["train"]["ffjax"]["gflop_per_step"] > 0 and case["train"]["ffjax"]["gflop_per_step_xla"] > 0
    assert case["train"]["ffjax"]["memory"]["peak_bytes"] > 0
    assert set(case["infer"]) == {"b1"}
    assert {"in_memory", "streaming_w0", "train_consumption_img_s"} <= set(saved["data"]["pipeline"])
    loops = saved["data"]["loop_efficiency"]
    assert set(loops) == {"val_every_1", "val_every_2"}
    for v in loops.values():  # the real loop ran its 2 epochs of 4 steps, minus the 3 warm-up steps
        assert v["steps"] == 5 and v["steps_per_epoch"] == 4 and v["eval_s"] > 0
        assert 0 < v["efficiency"] <= v["efficiency_training"] and 0 < v["eval_share"] < 1
    for env in saved["_env"].values():
        assert 0 <= env["steal"] <= 1
    report = (out / "report.md").read_text()
    assert "## 1. Training step" in report and "no GPU numbers in this run" in report

    r = saved["ratios"]
    for key in ("train_quick_vit_fraction_of_peak", "donation_speedup", "pipeline_in_memory_over_streaming_w0",
                "loop_efficiency_val_every_1", "loop_efficiency_training_val_every_2",
                "target_quick_b1_fps_over_digit60"):
        assert key in r, key
    for k, v in r.items():
        assert math.isfinite(v) and v > 0, (k, v)
    rc = saved["fast"]["recompile"]
    assert rc["compiles_once"] and rc["traces_after"] == 0

    slim = {k: v for k, v in res.items() if k not in ("data", "fast", "profile", "scaling", "dp")}
    slim["ratios"] = bench_report.collect_ratios(slim)
    assert "## 6." in bench_report.report(slim)
    gpu = copy.deepcopy(res)  # a GPU run (device names as jax prints them), torch eager and torch.compile timed
    gpu["machine"]["devices"] = ["cuda:0"]
    gpu["torch"] = {"torch": "2.x", "cuda": True, "cuda_device": "NVIDIA H100"}
    t = gpu["models"]["quick_vit"]["train"]
    t["torch"] = {"ms": 4.0, "img_s": 1000.0, "params": t["ffjax"]["params"]}
    t["torch_compile"] = {"ms": 2.0, "img_s": 2000.0, "params": t["ffjax"]["params"]}
    gpu["ratios"] = bench_report.collect_ratios(gpu)
    text = bench_report.report(gpu)
    assert "NVIDIA H100" in text and "this GPU" in text and "torch.compile img/s" in text
    assert gpu["ratios"]["train_quick_vit_ffjax_over_torch_compile"] == 2.0 / t["ffjax"]["ms"]
    assert "ran on the CPU" in bench_report.report(res)
    if "skipped" not in res["torch"]:  # same architecture on both sides, ViT and ResNet (stem, decoder grid)
        for name in res["models"]:
            t = res["models"][name]["train"]
            assert t["torch"]["params"] == t["ffjax"]["params"], name
        assert res["ratios"]["train_quick_vit_ffjax_over_torch"] > 0


def check_sim(out, res: dict) -> None:
    """`--only sim` at TINY_SIM: rates of both paths per size and batch, their agreement on two sensors, one
    batch's peak memory; all in the report."""
    r = res["sim_speed"]["rates"]["24x32"]
    assert r["reference_s"] > 0 and {int(b) for b in r["batched_s"]} == {1, 4}  # JSON keys: strings
    assert all(v > 0 for v in r["speedup"].values()) and r["loading"] == "oblique"
    ag = res["sim_speed"]["agreement"]
    assert set(ag) == {"mini-1-gel1", "digit"}
    for v in ag.values():  # the same physics on both paths (the bench's own measure, loose: a tiny grid)
        assert v["presses"] > 0 and v["refused_by_one"] == 0 and v["force_rel_max"] < 0.01
    pc = {(r["steps"], r["quadrature"]): r for r in res["sim_speed"]["path"]["rows"]}
    assert set(pc) == {(n, q) for n in (1, 2) for q in ("midpoint", "power")} and res["sim_speed"]["path"]["sheared"]
    one, two = (pc[1, "midpoint"], pc[1, "power"]), (pc[2, "midpoint"], pc[2, "power"])
    assert one[0]["ft_rel_median"] == one[1]["ft_rel_median"]  # one step: nothing to fit, the midpoint rule
    assert two[1]["ft_rel_median"] < two[0]["ft_rel_median"]  # measured 0.9% against 9.4% on these presses
    assert all(a["depth_um_max"] == b["depth_um_max"] for a, b in (one, two))  # the quadrature weighs only forces
    assert all(r["ms_a_press"] > 0 for r in pc.values())
    assert res["sim_speed"]["memory"]["peak_rss_mib"] > 0
    dz = res["sim_speed"]["discretization"]["sizes"]["smoke"]
    assert dz["grid"] == [24, 32] and dz["finer"] == [48, 64] and set(dz["shapes"]) == {"sphere_big", "cross"}
    for e in (*dz["shapes"].values(), dz["all"]):  # the grids differ, so do the answers, by less than the answer
        assert e["presses"] and 0 < e["approach_rel"]["median"] <= e["approach_rel"]["max"] < 1
    text = (out / "report.md").read_text()
    assert "batched layer solves against the numpy reference" in text and "Agreement on the same presses" in text
    assert (out / "sim_speed.png").stat().st_size > 10_000 and "![sim_speed](sim_speed.png)" in text
    assert "The solve grid's discretization (1 presses a shape" in text and "| smoke 24x32: shear % |" in text
    assert "The oblique path's steps (4 presses" in text  # the default, 2 power-law steps, among the rows
    assert "| 2 | power (default) |" in text and "midpoint (default)" not in text
    assert (out / "path_convergence.png").stat().st_size > 10_000 and "(path_convergence.png)" in text
