"""experiments.bench's parts at a tiny size: the compile-once check, FLOP counting, steal and HLO parsing, the
`--only loop|bf16` reports. A whole benchmark and `--only sim` run in the smoke pipeline (tests/test_reproduce.py,
checked by tests/_bench_plans.py). No timed assertions (these machines are shared; numbers are not checked, only
their shape)."""

import pytest
from _bench_plans import TINY

from experiments.bench import jax_step as bench_jax
from experiments.bench import suite as bench


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


def test_the_sim_plan_takes_its_accelerator_entries_on_a_gpu_only(monkeypatch):
    from experiments.bench import sim as bench_sim
    from ffjax.sim import batched

    plan = bench.PLANS["quick"]["sim_speed"]
    assert bench_sim.for_device(plan)["batches"] == (1, 8, 32) and "accelerator" not in bench_sim.for_device(plan)
    monkeypatch.setattr(batched, "on_accelerator", lambda: True)
    gpu = bench_sim.for_device(plan)
    assert gpu["batches"] == (1, 8, 32, 128, 256) and gpu["sizes"] == plan["sizes"] and "accelerator" not in gpu
    assert gpu["sample"]["preset"] == "paper"


def test_the_sim_report_states_a_gpu_runs_memory_and_the_paper_sample():
    from experiments.bench import report as bench_report

    rates = {"48x64": {"render_size": [48, 64], "reference_s": 3.0, "batched_s": {32: 300.0, 256: 900.0},
                       "speedup": {32: 100.0, 256: 300.0}, "loading": "oblique",
                       "steps": 4}}
    ss = {"rates": rates, "default_batch": 32,
          "memory": {"batch": 256, "render_size": [240, 320], "peak_rss_mib": 3000.0, "batch_growth_mib": 900.0,
                     "piece": 256, "device_peak_mib": 1234.0},
          "sample": {"preset": "paper", "presses": 2480, "seconds": 62.0, "workers": 1, "batch": 32,
                     "render_size": [240, 320], "bytes_per_press": 520000.0, "full_presses": 234000}}
    text = bench_report.sim_tables(ss)
    assert "300.00 (batch 256)" in text and "pieces of 256" in text and "the device's peak 1,234" in text
    assert "2,400 presses/min" in text and "1.6 h and 122 GB" in text


def test_a_made_datasets_time_is_read_only_when_its_call_is_the_measurement(tmp_path):
    """The simulator's benchmark reads the quick dataset's time from the pipeline's dataset instead of making a
    second one, but only from a manifest of the preset's whole dataset, rendered in one call by today's
    simulator with the default workers."""
    import json

    import configs
    from experiments.bench import sim as bench_sim
    from ffjax.sim import dataset

    cfg = configs.get("smoke")
    n = sum(s.count for s in dataset.split_specs(cfg))
    good = {"preset": "smoke", "sim_fingerprint": dataset.sim_fingerprint(), "data_config": cfg["data"],
            "generation": {"samples": n, "rendered": n, "seconds": 12.5,
                           "workers": dataset.default_workers(n)}}

    def made(**change):
        m = json.loads(json.dumps(good))
        for key, value in change.items():
            *path, last = key.split("__")
            d = m
            for k in path:
                d = d[k]
            d[last] = value
        (tmp_path / "manifest.json").write_text(json.dumps(m))
        return bench_sim.made_time(tmp_path, "smoke")

    assert bench_sim.made_time(tmp_path, "smoke") is None  # nothing made there
    t = made()
    assert t["seconds"] == 12.5 and t["presses"] == n and t["made_in"] == str(tmp_path) and t["load_before"] is None
    assert made(sim_fingerprint="0" * 16) is None  # another simulator
    assert made(generation__rendered=n - 1) is None  # resumed: part of it made by an earlier call
    assert made(generation__workers=good["generation"]["workers"] + 1) is None
    assert made(data_config__fz_max=99.0) is None  # another config
    assert made(preset="quick") is None


def test_the_sim_floor_reads_every_solve_and_leaves_the_recording_off():
    """The floor reads the solves of one call (batched.record_solves) and stops recording after; every press of
    the oblique path runs path_steps + 1 normal and path_steps stick solves (where it has a shear), each with its
    iterations, and its FFTs alone cost less than the whole press."""
    from experiments.bench import report
    from experiments.bench import sim as bench_sim
    from ffjax.sim import batched

    fl = bench_sim.floor(4, (24, 32))
    assert batched._RECORD is None
    assert fl["solves"]["normal"]["a_press"] == bench_sim.STEPS + 1
    assert 0 < fl["solves"]["stick"]["a_press"] <= bench_sim.STEPS
    assert all(v["iterations_mean"] >= 1 and v["fft_floor_ms_a_press"] > 0 for v in fl["solves"].values())
    assert 0 < fl["fft_floor_ms_a_press"] < fl["ms_a_press"]
    rates = {"24x32": {"render_size": [24, 32], "reference_s": 1.0, "batched_s": {8: 2.0},
                       "speedup": {8: 2.0}, "loading": "oblique", "steps": bench_sim.STEPS}}
    text = report.sim_tables({"rates": rates, "floor": fl})
    assert "Where a press's time goes (4 presses at 24x32" in text and "| both |" in text
