"""experiments.bench at a tiny size: results structure, finite positive ratios, the compile-once check.
No timed assertions (these machines are shared; numbers are not checked, only their shape)."""

import json
import math
import os
import shutil

import pytest

from experiments.bench import jax_step as bench_jax
from experiments.bench import report as bench_report
from experiments.bench import suite as bench

TINY = {
    "name": "test",
    "cases": {"quick_vit": {"preset": "smoke", "method": "dino_rd", "size": 32, "batch": 4, "infer": (1,)},
              "resnet": {"preset": "smoke", "method": "resnet_rd", "size": 32, "batch": 4, "infer": (1,)}},
    "vit_b14": None, "timing": (0, 1, 1), "infer_timing": (0, 1, 1), "peak_n": 128,
    "sim": {"n": {"64x64": 10}, "sizes": {"64x64": (24, 32)}}, "data": {"per_shape": 1, "batches": 2},
    "workers": (0,), "scaling": None, "dp": None, "bf16_acc": None, "profile": False,
    "fast": ("recompile", "donation"), "loop": {"train": 16, "val": 8, "epochs": 2, "val_every": (1, 2)},
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


def test_ratios_positive_finite(results):
    _, res = results
    r = res["ratios"]
    for key in ("train_quick_vit_fraction_of_peak", "donation_speedup", "pipeline_in_memory_over_streaming_w0",
                "loop_efficiency_val_every_1", "loop_efficiency_training_val_every_2",
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


def test_program_flops_counts_matmuls_and_convs_exactly():
    import jax
    import jax.numpy as jnp
    x, w = jnp.ones((4, 8)), jnp.ones((8, 16))
    assert bench_jax.program_flops(lambda x, w: x @ w, x, w) == 2 * 4 * 8 * 16
    # the gradient of a product with respect to both operands is two more products of the same size
    assert bench_jax.program_flops(jax.grad(lambda x, w: (x @ w).sum(), (0, 1)), x, w) == 3 * 2 * 4 * 8 * 16
    img, k = jnp.ones((2, 3, 8, 8)), jnp.ones((5, 3, 3, 3))   # NCHW, OIHW, stride 2 -> 4x4 outputs
    conv = lambda img, k: jax.lax.conv(img, k, (2, 2), "SAME")  # noqa: E731
    fwd = 2 * (2 * 5 * 4 * 4) * (3 * 3 * 3)
    assert bench_jax.program_flops(conv, img, k) == fwd
    # input and kernel gradients of a strided conv cost what its forward does (no zeros counted)
    assert bench_jax.program_flops(jax.grad(lambda i, k: conv(i, k).sum(), (0, 1)), img, k) == 3 * fwd
    # scans count once per iteration
    scanned = lambda x, w: jax.lax.scan(lambda c, _: (c @ w[:, :8], None), x, None, length=5)[0]  # noqa: E731
    assert bench_jax.program_flops(scanned, x, w) == 5 * 2 * 4 * 8 * 8


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


def test_report_names_the_device_and_torch_compile(results):
    """A GPU run (device names as jax prints them) with torch eager and torch.compile timings."""
    import copy

    _, res = results
    gpu = copy.deepcopy(res)
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


@pytest.mark.skipif(not (_torch_python() and shutil.which(_torch_python() or "")),
                    reason="set FFJAX_TORCH_PYTHON to a python with torch to test the PyTorch side")
def test_torch_side_same_params(results):
    _, res = results
    for case in res["models"]:  # same architecture on both sides, ViT and ResNet (stem, decoder grid) alike
        t = res["models"][case]["train"]
        assert t["torch"]["params"] == t["ffjax"]["params"], case
    assert res["ratios"]["train_quick_vit_ffjax_over_torch"] > 0


def test_only_parts_write_their_own_report(tmp_path):
    """`--only loop` and `--only bf16` at a tiny size: their tables, ratios and every round recorded."""
    plan = {**TINY, "loop": {**TINY["loop"], "val_every": (2,), "rounds": 2},
            "bf16_acc": {"preset": "smoke", "steps": 3, "batch": 4}, "bf16_methods": ("resnet_rd",)}
    res = bench.run_only("loop", plan, tmp_path / "loop", log=lambda *_: None)
    le = res["data"]["loop_efficiency"]["val_every_2"]
    assert len(le["rounds"]) == 2 and le["efficiency_cpu"] > 0 and le["startup_s"] > 0
    assert le["staged_batches"] >= 1 and le["fixed_ms"] > 0 and le["efficiency_training_fixed"] > 0
    assert "efficiency without evaluation" in (tmp_path / "loop" / "report.md").read_text()
    res = bench.run_only("bf16", plan, tmp_path / "bf16", log=lambda *_: None)
    assert set(res["bf16_methods"]) == {"resnet_rd"} and res["ratios"]["speedup_bf16_resnet_rd"] > 0
    assert "val loss bf16/f32" in (tmp_path / "bf16" / "report.md").read_text()


def test_only_sim_compares_the_batched_solves_with_the_reference(tmp_path):
    """`--only sim` at a tiny size: rates of both paths per size and batch, their agreement on every indenter and
    unseen object, one batch's peak memory; all in the report."""
    plan = {**TINY, "sim_speed": {"sizes": {"24x32": (24, 32)}, "batches": (1, 4), "n": 4, "reference_n": 2,
                                  "agreement_size": (24, 32), "agreement_per_shape": 1,
                                  "agreement_sensors": ("mini-1-gel1", "digit"), "memory": (4, (24, 32)),
                                  "dataset": None}}
    res = bench.run_only("sim", plan, tmp_path / "sim", log=lambda *_: None)
    r = res["sim_speed"]["rates"]["24x32"]
    assert r["reference_s"] > 0 and set(r["batched_s"]) == {1, 4} and all(v > 0 for v in r["speedup"].values())
    ag = res["sim_speed"]["agreement"]
    assert set(ag) == {"mini-1-gel1", "digit"}
    for v in ag.values():  # the same physics on both paths (the bench's own measure, loose: a tiny grid)
        assert v["presses"] > 0 and v["refused_by_one"] == 0 and v["force_rel_max"] < 0.01
    assert res["sim_speed"]["memory"]["peak_rss_mib"] > 0
    text = (tmp_path / "sim" / "report.md").read_text()
    assert "batched layer solves against the numpy reference" in text and "Agreement on the same presses" in text


def test_a_released_vit_keeps_the_presets_other_keys():
    """The quick bench's ViT-S/14 case: the released architecture over the preset's ViT keys (the model reads
    interpolate_offset, which the released architecture does not name), and the model builds at 224."""
    import jax
    import jax.numpy as jnp

    import configs
    from ffjax.models import vit

    cfg = bench_jax.case_cfg("paper", {"model.decoder.kind": "tokens"}, vit="s14")
    assert cfg["model"]["vit"]["dim"] == 384 and cfg["model"]["vit"]["pos_grid"] == 37
    assert cfg["model"]["vit"]["interpolate_offset"] == configs.get("paper")["model"]["vit"]["interpolate_offset"]
    params = jax.eval_shape(vit.from_config(cfg["model"]["vit"]).init, jax.random.PRNGKey(0),
                            jnp.zeros((1, 224, 224, 3)))
    assert params
