"""experiments.bench at a tiny size: results structure, finite positive ratios, the compile-once check.
No timed assertions (these machines are shared; numbers are not checked, only their shape)."""

import json
import math
import os
import shutil

import pytest

from experiments import bench, bench_jax, bench_report

TINY = {
    "name": "test",
    "cases": {"quick_vit": {"preset": "smoke", "method": "dino_rd", "size": 32, "batch": 4, "infer": (1,)},
              "resnet": {"preset": "smoke", "method": "resnet_rd", "size": 32, "batch": 4, "infer": (1,)}},
    "vit_b14": None, "timing": (0, 1, 1), "infer_timing": (0, 1, 1), "peak_n": 128,
    "sim": {"n": {"64x64": 10}, "sizes": {"64x64": (24, 32)}}, "data": {"per_shape": 1, "batches": 2},
    "workers": (0,), "scaling": None, "dp": None, "bf16_acc": None, "profile": False,
    "fast": ("recompile", "donation"),
}


def _torch_python():
    return os.environ.get("FFJAX_TORCH_PYTHON")


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    res = bench.run(TINY, out, torch_python=_torch_python(), log=lambda *_: None, skip=("scaling", "dp"))
    return out, res


def test_results_structure(results):
    out, res = results
    saved = json.loads((out / "results.json").read_text())
    for key in ("commit", "machine", "peak", "models", "data", "fast", "ratios", "_env", "date_utc"):
        assert key in saved, key
    assert saved["machine"]["cores"] >= 1
    case = saved["models"]["quick_vit"]
    assert case["train"]["ffjax"]["gflop_per_step"] > 0
    assert case["train"]["ffjax"]["memory"]["peak_bytes"] > 0
    assert set(case["infer"]) == {"b1"}
    assert {"in_memory", "streaming_w0", "train_consumption_img_s"} <= set(saved["data"]["pipeline"])
    for env in saved["_env"].values():
        assert 0 <= env["steal"] <= 1
    report = (out / "report.md").read_text()
    assert "## 1. Training step" in report and "GPU part was not run" in report


def test_ratios_positive_finite(results):
    _, res = results
    r = res["ratios"]
    for key in ("train_quick_vit_fraction_of_peak", "donation_speedup", "pipeline_in_memory_over_streaming_w0",
                "target_quick_b1_fps_over_digit60"):
        assert key in r, key
    for k, v in r.items():
        assert math.isfinite(v) and v > 0, (k, v)


def test_compile_once(results):
    _, res = results
    rc = res["fast"]["recompile"]
    assert rc["compiles_once"] and rc["traces_after"] == 0


def test_recompile_check_detects_retrace():
    # a different batch shape must trace again: the check is not vacuous
    from ffjax import train

    cfg = bench_jax.case_cfg("smoke")
    before = train.TRACE_COUNT["train"]
    bench_jax.recompile_check(cfg, "dino_rd", 4, 32, steps=1)
    mid = train.TRACE_COUNT["train"]
    bench_jax.recompile_check(cfg, "dino_rd", 2, 32, steps=1)
    assert train.TRACE_COUNT["train"] == mid + 1 and mid - before <= 1


def test_steal_and_hlo_parsing():
    s = bench.steal_between([0] * 10, [10, 0, 5, 80, 0, 0, 0, 5, 0, 0])
    assert s["steal"] == pytest.approx(0.05) and s["busy"] == pytest.approx(0.2)
    hlo = """HloModule m
%fused_computation (p: f32[2,2]) -> f32[2,2] {
  %p = f32[2,2]{1,0} parameter(0)
  ROOT %d = f32[2,2]{1,0} dot(%p, %p), lhs_contracting_dims={1}, rhs_contracting_dims={0}
}
ENTRY %main (a: f32[2,2]) -> f32[2,2] {
  %a = f32[2,2]{1,0} parameter(0)
  ROOT %fusion.1 = f32[2,2]{1,0} fusion(%a), kind=kOutput, calls=%fused_computation
}
"""
    kinds = bench_jax._hlo_kinds(hlo)
    assert kinds["fusion.1"] == "fusion:kOutput(dot)"


def test_report_tolerates_missing_sections(results):
    _, res = results
    slim = {k: v for k, v in res.items() if k not in ("data", "fast", "profile", "scaling", "dp")}
    slim["ratios"] = bench_report.collect_ratios(slim)
    assert "## 6." in bench_report.report(slim)


@pytest.mark.skipif(not (_torch_python() and shutil.which(_torch_python() or "")),
                    reason="set FFJAX_TORCH_PYTHON to a python with torch to test the PyTorch side")
def test_torch_side_same_params(results):
    _, res = results
    for case in res["models"]:  # same architecture on both sides, ViT and ResNet (stem, decoder grid) alike
        t = res["models"][case]["train"]
        assert t["torch"]["params"] == t["ffjax"]["params"], case
    assert res["ratios"]["train_quick_vit_ffjax_over_torch"] > 0
