"""Ratios, the markdown report and the plots of `experiments.bench` (pure functions of results.json)."""

from __future__ import annotations

import math
from pathlib import Path

from experiments.common import md_table

DIGIT_FPS, GELSIGHT_FPS = 60.0, 25.0


def _g(d, *path, default=None):
    for p in path:
        if not isinstance(d, dict) or p not in d or d[p] is None:
            return default
        d = d[p]
    return d


def _div(a, b):
    try:
        a, b = float(a), float(b)
    except (TypeError, ValueError):
        return None
    return a / b if b and math.isfinite(a) and math.isfinite(b) else None


def collect_ratios(res: dict) -> dict:
    """name -> ratio. Speed ratios are written so that > 1 means the first-named side is faster."""
    r = {}
    peak = _g(res, "peak", "ffjax", "gflops")
    r["peak_matmul_ffjax_over_torch"] = _div(peak, _g(res, "peak", "torch", "gflops"))
    for name, m in (res.get("models") or {}).items():
        tj, tt = _g(m, "train", "ffjax", "ms"), _g(m, "train", "torch", "ms")
        r[f"train_{name}_ffjax_over_torch"] = _div(tt, tj)
        r[f"train_{name}_ffjax_over_torch_compile"] = _div(_g(m, "train", "torch_compile", "ms"), tj)
        r[f"train_{name}_fraction_of_peak"] = _div(_g(m, "train", "ffjax", "achieved_gflops"), peak)
        for b, d in (m.get("infer") or {}).items():
            r[f"infer_{name}_{b}_ffjax_over_torch"] = _div(_g(d, "torch", "ms"), _g(d, "ffjax", "ms"))
    b1 = _g(res, "models", "quick_vit", "infer", "b1")
    r["target_quick_b1_fps_over_digit60"] = _div(_div(1e3, _g(b1, "ffjax", "ms")), DIGIT_FPS)
    r["target_quick_b1_torch_fps_over_digit60"] = _div(_div(1e3, _g(b1, "torch", "ms")), DIGIT_FPS)
    bb = _g(res, "models", "vit_b14", "infer", "b1")
    r["target_b14_cpu_fps_over_gelsight25"] = _div(_div(1e3, _g(bb, "ffjax", "ms")), GELSIGHT_FPS)
    sim = res.get("data", {}).get("sim", {})
    r["sim_64_over_native"] = _div(_g(sim, "64x64", "samples_s"), _g(sim, "native", "samples_s"))
    pipe = _g(res, "data", "pipeline", default={})
    for k, v in pipe.items():
        if isinstance(v, dict):
            r[f"pipeline_{k}_over_train_consumption"] = v.get("ratio_to_train_consumption")
    r["pipeline_in_memory_over_streaming_w0"] = _div(_g(pipe, "in_memory", "batches_s"),
                                                     _g(pipe, "streaming_w0", "batches_s"))
    r["pipeline_streaming_w2_over_w0"] = _div(_g(pipe, "streaming_w2", "batches_s"),
                                              _g(pipe, "streaming_w0", "batches_s"))
    for k, v in (_g(res, "data", "loop_efficiency", default={}) or {}).items():
        r[f"loop_efficiency_{k}"] = v.get("efficiency")
        r[f"loop_efficiency_training_{k}"] = v.get("efficiency_training")
    f = res.get("fast", {})
    r["donation_speedup"] = _g(f, "donation", "speedup_donate")
    r["donation_peak_memory_ratio"] = _g(f, "donation", "peak_bytes_ratio_donate_over_no")
    r["decoder_tokens_over_paper_speed"] = _g(f, "decoders", "speedup_tokens_over_paper")
    r["bf16_speedup"] = _g(f, "bf16_speed", "speedup_bf16")
    r["bf16_val_loss_over_f32"] = _g(f, "bf16_accuracy", "val_loss_ratio_bf16_over_f32")
    r["bf16_val_force_l1_over_f32"] = _g(f, "bf16_accuracy", "val_force_l1_ratio_bf16_over_f32")
    for label, v in (res.get("bf16_methods") or {}).items():
        for k in ("speedup_bf16", "val_loss_ratio_bf16_over_f32", "val_force_l1_ratio_bf16_over_f32"):
            r[f"{k}_{label}"] = v.get(k)
    r["dp8_over_1dev_speed"] = _g(res, "dp", "speedup_all_over_one")
    for axis, pts in (res.get("scaling") or {}).items():
        if pts:
            r[f"scaling_{axis}_ms_last_over_first"] = _div(pts[-1]["ms"], pts[0]["ms"])
    return {k: v for k, v in r.items() if v is not None}


def _f(x, nd=1):
    if x is None:
        return "–"
    if isinstance(x, str):
        return x
    return f"{x:,.{nd}f}" if abs(x) >= 0.1 or x == 0 else f"{x:.3g}"


def _on_gpu(res: dict) -> bool:
    return any("cuda" in d.lower() or "gpu" in d.lower() for d in res["machine"].get("devices", []))


def _device_line(res: dict) -> str:
    devices = res["machine"].get("devices", [])
    if _on_gpu(res):
        return (f"jax ran on {', '.join(devices)}, the PyTorch side on "
                f"{_g(res, 'torch', 'cuda_device') or 'its CPU'}.")
    return "jax and the PyTorch side ran on the CPU: no GPU numbers in this run."


def report(res: dict) -> str:
    m, r = res["machine"], res.get("ratios", {})
    env = res.get("_env", {})
    out = [f"# ffjax benchmarks ({res['mode']})\n",
           f"Commit `{res['commit']}`, {res['date_utc']}. Machine: {m.get('cpu_model')}, {m.get('cores')} cores, "
           f"{m.get('mem_gib')} GiB, SIMD {', '.join(m.get('simd', []))}; jax {m.get('jax')} "
           f"(devices {', '.join(m.get('devices', []))}), torch: "
           f"{_g(res, 'torch', 'torch') or _g(res, 'torch', 'skipped')} "
           f"({_g(res, 'torch', 'threads', default='?')} threads). Load average at start "
           f"{res['load_start'][0]:.1f}, end {res['load_end'][0]:.1f}. Times are medians after warm-up; compare "
           f"ratios within this run only. {_device_line(res)}\n"]
    out.append("## Steal and load per section\n")
    out.append(md_table(["section", "wall s", "steal %", "busy %", "load before", "load after"],
                        [[k, _f(v["wall_s"], 0), _f(100 * v["steal"]), _f(100 * v["busy"]), _f(v["load1_before"]),
                          _f(v["load1_after"])] for k, v in env.items()]))
    peak = res.get("peak", {})
    out.append(f"\nMachine peak (float32 matmul {_g(peak, 'ffjax', 'n')}^2, best of rounds): ffjax/XLA "
               f"{_f(_g(peak, 'ffjax', 'gflops'))} GFLOP/s, torch {_f(_g(peak, 'torch', 'gflops'))} GFLOP/s.\n")
    out.append("## 1. Training step (img/s; ratio > 1 = ffjax faster)\n")
    rows = []
    for name, c in res.get("models", {}).items():
        t = c.get("train")
        if not t:
            continue
        j, tt, tc = t["ffjax"], t.get("torch") or {}, t.get("torch_compile") or {}
        rows.append([name, f"{c['arch']['backbone']} @{t['ffjax']['input_size']}", j["batch"], _f(j["img_s"]),
                     _f(tt.get("img_s")), _f(r.get(f"train_{name}_ffjax_over_torch"), 2), _f(tc.get("img_s")),
                     _f(r.get(f"train_{name}_ffjax_over_torch_compile"), 2),
                     f"{j['params']:,} / {tt.get('params', '–'):,}" if tt.get("params") else f"{j['params']:,}",
                     _f(j["compile_s"])])
    out.append(md_table(["case", "model", "batch", "ffjax img/s", "torch eager img/s", "ffjax/eager",
                         "torch.compile img/s", "ffjax/compile", "params jax/torch", "ffjax compile s"], rows))
    if not any(r2[6] != "–" for r2 in rows):
        out.append("\ntorch.compile was not timed (default on a GPU only; `--torch-compile` asks for it).\n")
    out.append("\n## 2. Inference, force only (ms per call)\n")
    rows = []
    for name, c in res.get("models", {}).items():
        for b, d in c.get("infer", {}).items():
            j, tt = d["ffjax"], d.get("torch") or {}
            rows.append([name, b, _f(j["ms"], 2), _f(tt.get("ms"), 2), _f(j["img_s"]), _f(tt.get("img_s")),
                         _f(r.get(f"infer_{name}_{b}_ffjax_over_torch"), 2)])
    out.append(md_table(["case", "batch", "ffjax ms", "torch ms", "ffjax img/s", "torch img/s", "ffjax/torch"],
                        rows))
    where = "this GPU" if _on_gpu(res) else "this CPU"
    out.append(f"\nTargets: quick model at batch 1 runs {_f(r.get('target_quick_b1_fps_over_digit60'), 1)}x a "
               f"DIGIT's 60 fps on {where} (torch {_f(r.get('target_quick_b1_torch_fps_over_digit60'), 1)}x). "
               f"ViT-B/14 at 224, batch 1: {_f(r.get('target_b14_cpu_fps_over_gelsight25'), 2)}x a GelSight "
               "Mini's 25 fps.\n")
    out.append("## 3. FLOP/s of the train step vs the machine's peak\n")
    out.append("GFLOP/step counts the step's matrix products and convolutions from its program (backward "
               "included); XLA's cost analysis is shown beside it but not used (on GPU it leaves out cuBLAS "
               "calls). Achieved GFLOP/s = counted FLOPs / measured step time.\n")
    rows = [[n, _f(c["train"]["ffjax"]["gflop_per_step"]), _f(c["train"]["ffjax"].get("gflop_per_step_xla")),
             _f(c["train"]["ffjax"]["achieved_gflops"]),
             _f(100 * (r.get(f"train_{n}_fraction_of_peak") or float("nan")))]
            for n, c in res.get("models", {}).items() if c.get("train")]
    out.append(md_table(["case", "GFLOP/step (counted)", "GFLOP/step (XLA)", "achieved GFLOP/s",
                         "% of matmul peak"], rows))
    p = res.get("profile")
    if p:
        ph = p["phases"]
        out.append(f"\nProfile of the {p['method']} step (batch {p['batch']}, {p['input_size']}px), from a "
                   f"jax.profiler trace: {p['n_ops_seen']} XLA ops, {_f(p['op_ms_total'])} ms of op time per step "
                   f"(summed over threads) for {_f(p['step_ms_wall'])} ms wall. Phases (separately jitted): "
                   f"forward {_f(ph['forward'])} ms, backward {_f(ph['backward'])} ms, Adam + rest "
                   f"{_f(ph['optimizer_and_rest'])} ms of {_f(ph['full_step'])} ms.\n")
        out.append(md_table(["op kind", "ms/step", "share %"],
                            [[k["kind"], _f(k["ms"], 2), _f(100 * k["share"])] for k in p["by_kind"]]))
        out.append("\nTop ops:\n\n" + md_table(["op", "kind", "ms/step", "share %"],
                                                [[o["name"], o["kind"], _f(o["ms"], 2), _f(100 * o["share"])]
                                                 for o in p["top_ops"]]))
    d = res.get("data")
    if d:
        out.append("\n## 4. Simulator and input pipeline\n")
        out.append(md_table(["simulator", "render size", "samples/s"],
                            [[k, "x".join(map(str, v.get("render_size", ["64x48 (dataset path)"]))),
                              _f(v["samples_s"])] for k, v in d["sim"].items()]))
        pipe = d["pipeline"]
        out.append(f"\nTrain step consumes {_f(pipe['train_consumption_img_s'])} img/s (quick ViT).\n\n")
        out.append(md_table(["pipeline", "batches/s", "img/s", "x train consumption", "first batch s"],
                            [[k, _f(v["batches_s"]), _f(v["img_s"]), _f(v["ratio_to_train_consumption"], 1),
                              _f(v["first_batch_s"], 2)] for k, v in pipe.items() if isinstance(v, dict)]))
        out.append(loop_table(d.get("loop_efficiency")))
    sc = res.get("scaling")
    if sc:
        out.append("\n## 5. Scaling (quick ViT dino_rd train step; memory = XLA's compiled peak)\n")
        for axis, pts in sc.items():
            out.append(f"\n{axis}:\n\n" + md_table(
                [axis, "ms/step", "img/s", "GFLOP/s", "peak MiB", "params"],
                [[pt["x"], _f(pt["ms"]), _f(pt["img_s"]), _f(pt["achieved_gflops"]), _f(pt["peak_mib"]),
                  f"{pt['params']:,}"] for pt in pts]))
    dp = res.get("dp")
    if dp:
        if "error" in dp:
            out.append(f"\nData parallel: failed: `{dp['error'][-300:]}`\n")
        else:
            out.append(f"\nData parallel ({dp['devices']} virtual CPU devices, batch {dp['batch']}): "
                       f"{_f(dp['all_devices']['ms'])} ms/step vs {_f(dp['one_device']['ms'])} ms on one device "
                       f"(speed ratio {_f(dp['speedup_all_over_one'], 2)}; same 2 cores, so ~1 is the ideal); "
                       f"first-step loss difference {dp['first_step_loss_abs_diff']:.2e}.\n")
    f = res.get("fast", {})
    out.append("\n## 6. Make it fast: measured effects\n")
    rows = []
    if "recompile" in f:
        rc = f["recompile"]
        rows.append(["compile once (TRACE_COUNT)", f"{rc['traces_after']} retraces in {rc['steps']} steps "
                     f"(incl. a rebuilt state)", "ok" if rc["compiles_once"] else "FAIL"])
    if "donation" in f:
        dn = f["donation"]
        rows.append(["donate state (vs not)", f"{_f(dn['donate']['ms'])} vs {_f(dn['no_donate']['ms'])} ms",
                     f"speed x{_f(dn['speedup_donate'], 2)}, peak memory x"
                     f"{_f(dn.get('peak_bytes_ratio_donate_over_no'), 2)}"])
    if "decoders" in f:
        dc = f["decoders"]
        rows.append(["decoder: tokens (Dense+depth_to_space) vs paper (upsample+conv k5)",
                     f"{_f(dc['tokens']['ms'])} vs {_f(dc['paper']['ms'])} ms (no decoder {_f(dc['none']['ms'])})",
                     f"speed x{_f(dc['speedup_tokens_over_paper'], 2)}; decoder share of step: tokens "
                     f"{_f(100 * dc['decoder_share_tokens'])}%, paper {_f(100 * dc['decoder_share_paper'])}%"])
    if "bf16_speed" in f:
        bs = f["bf16_speed"]
        rows.append(["bfloat16 compute vs float32", f"{_f(bs['bfloat16']['ms'])} vs {_f(bs['float32']['ms'])} ms",
                     f"speed x{_f(bs['speedup_bf16'], 2)}"])
    if "bf16_accuracy" in f:
        ba = f["bf16_accuracy"]
        rows.append([f"bfloat16 accuracy ({ba['steps']} steps, {ba['preset']} model, {ba['input_size']}px)",
                     f"val loss {_f(ba['bfloat16']['val_loss'], 4)} vs {_f(ba['float32']['val_loss'], 4)}; "
                     f"force L1 {_f(ba['bfloat16']['val_force_l1'], 4)} vs {_f(ba['float32']['val_force_l1'], 4)}",
                     f"val loss x{_f(ba['val_loss_ratio_bf16_over_f32'], 3)}"])
    if r.get("pipeline_in_memory_over_streaming_w0"):
        rows.append(["in-memory pipeline vs streaming (0 workers)", "batches/s",
                     f"x{_f(r['pipeline_in_memory_over_streaming_w0'], 1)}"])
    out.append(md_table(["change", "measured", "effect"], rows))
    out.append("\n## All ratios\n")
    out.append(md_table(["ratio", "value"], [[k, _f(v, 3)] for k, v in r.items()]))
    if res.get("plots"):
        out.append("\n" + "\n".join(f"![{Path(p).stem}]({Path(p).name})" for p in res["plots"]) + "\n")
    return "\n".join(out)


def loop_table(le: dict | None) -> str:
    """The training loop against its own step, one row per train.val_every ("" without the measurement)."""
    if not le:
        return ""
    head = ("\nThe training loop (`ffjax.train.loop.train`: data pipeline, logs, checkpoints, validation) against "
            "its own jitted step over the same steps at the same batch, on the loop's own batches staged on the "
            "device (pure step) and on one fixed batch (fixed, which stays in the CPU's caches). The loop's clock "
            "runs from its warm-up steps to train()'s return; one-time startup (preprocessing, compiling) is "
            "outside it. efficiency = pure step time / loop time; without evaluation = the same with the loop's "
            "evaluation time (feature-norm refresh, validation, best checkpoint) taken out of the loop time; "
            "CPU = the ratio of process CPU seconds (all threads), which other processes' load moves far less. "
            "Median of the rounds (by efficiency); every round in results.json.\n\n")
    return head + md_table(
        ["val_every (epochs)", "steps", "steps/epoch", "loop ms/step", "pure step ms", "fixed-batch step ms",
         "efficiency", "efficiency without evaluation", "the same against the fixed batch", "evaluation share",
         "CPU efficiency", "rounds: efficiency / without evaluation / CPU", "load"],
        [[v["val_every"], v["steps"], v["steps_per_epoch"], _f(v["loop_ms"]), _f(v["pure_ms"]),
          _f(v.get("fixed_ms")), _f(v["efficiency"], 3), _f(v["efficiency_training"], 3),
          _f(v.get("efficiency_training_fixed"), 3), _f(v["eval_share"], 3), _f(v.get("efficiency_cpu"), 3),
          "; ".join(f"{_f(x['efficiency'], 3)} / {_f(x['efficiency_training'], 3)} / "
                    f"{_f(x.get('efficiency_cpu'), 3)}" for x in v.get("rounds", [v])),
          "-".join(_f(x) for x in v.get("load1", []))]
         for v in le.values()])


def bf16_table(bm: dict | None) -> str:
    """bfloat16 against float32 per method ("" without the measurement)."""
    if not bm:
        return ""
    rows = []
    for label, v in bm.items():
        sp, a = v["speed"], v["accuracy"]
        rows.append([label, _f(sp["float32"]["ms"]), _f(sp["bfloat16"]["ms"]), _f(v["speedup_bf16"], 2),
                     _f(a["float32"]["val_loss"], 4), _f(a["bfloat16"]["val_loss"], 4),
                     _f(v["val_loss_ratio_bf16_over_f32"], 3), _f(v["val_force_l1_ratio_bf16_over_f32"], 3)])
    v0 = next(iter(bm.values()))
    a0, c0 = v0["accuracy"], v0["speed_case"]
    return (f"\nbfloat16 compute (float32 master weights) against float32. Speed: each method's train step, "
            f"{c0['preset']} model, batch {c0['batch']} at {c0['size']} px, the two dtypes timed in "
            f"{len(v0['speed']['float32']['ms_rounds'])} alternating rounds (median; > 1 = bf16 faster). "
            f"Accuracy: the same short run from the same init and batch order in each dtype ({a0['steps']} "
            f"steps, batch {a0['batch']}, {a0['preset']} model at {a0['input_size']} px), validated in "
            "float32.\n\n" + md_table(
                ["method", "float32 ms/step", "bfloat16 ms/step", "speed bf16/f32", "val loss f32", "val loss bf16",
                 "val loss bf16/f32", "val force L1 bf16/f32"], rows))


def sim_tables(ss: dict | None) -> str:
    """The simulator's speed and agreement (`--only sim`; "" without it)."""
    if not ss:
        return ""
    rates = ss["rates"]
    batches = sorted({int(b) for v in rates.values() for b in v["batched_s"]})

    def best(v):
        b, x = max(v["speedup"].items(), key=lambda kv: kv[1])
        return f"{_f(x, 2)} (batch {b})"

    cols = [f"batched, batch {b}" for b in batches]
    rows = [[k, _f(v["reference_s"]), *(_f(v["batched_s"][b]) for b in batches), best(v)] for k, v in rates.items()]
    first = next(iter(rates.values()))
    how = (f"pressed as the dataset presses ({first['loading']}, {first['steps']} steps: {first['steps'] + 1} normal "
           f"and {first['steps']} stick solves per press)" if first.get("loading") else "pressed, then pushed")
    out = ["\n## The simulator: batched layer solves against the numpy reference\n",
           f"Presses per second in one process over mixed indenters with the dataset's ranges of force and pose, "
           f"{how}; the reference presses one at a time (its rate does not depend on a batch). "
           "Measured in this run; compiling is not counted.\n",
           md_table(["render size", "reference presses/s", *cols, "best speedup"], rows)]
    if ss.get("default_batch"):
        out.append(f"\nThe simulator presses in batches of up to {ss['default_batch']} on this device "
                   "(`ffjax.sim.batched.max_batch`).\n")
    ag = ss.get("agreement")
    if ag:
        out += ["\nAgreement on the same presses (every indenter and unseen object, per sensor): the largest force "
                "difference (relative), depth difference (um; max and 99th percentile over presses), presses whose "
                "contact differs by a border cell, and the share of pixels more than 1 count apart. The presses over "
                "1 um are pressed again with the reference converged 100x further (pressure 1e-8, approach 1e-6 of "
                "the thickness): the last two columns are each path's largest depth difference to that (um).\n",
                md_table(["sensor", "presses", "force", "depth max um", "depth p99 um", "presses > 1 um",
                          "contact differs", "pixels > 1 count %", "refused by one", "batched to converged",
                          "reference to converged"],
                         [[k, v["presses"], f"{v['force_rel_max']:.1e}", _f(v["depth_um_max"], 3),
                           _f(v["depth_um_p99"], 3), v["presses_over_1um"], v["contact_differs"],
                           _f(100 * v["pixels_over_1_count"], 4), v["refused_by_one"],
                           *((_f(v["over_1um_to_converged_um"][p], 3) if v["presses_over_1um"] else "-")
                             for p in ("batched", "reference"))] for k, v in ag.items()])]
    fl = ss.get("floor")
    if fl:
        out += [f"\nWhere a press's time goes ({fl['presses']} presses at {'x'.join(map(str, fl['render_size']))}, "
                f"pressed in one call on one thread, batches of {fl['batch']}): {_f(fl['ms_a_press'])} ms a press, "
                "against what its layer solves' FFTs alone take (each solve's rfft2/irfft2 pairs on its window, "
                "timed alone at that batch, times its iterations): a floor for these solves with these iterations on "
                "this machine, which no fusion or saved overhead gets under; only fewer solves, fewer iterations "
                "or smaller grids do.\n",
                md_table(["solve", "solves a press", "on a window %", "iterations (mean)", "iterations (p90)",
                          "FFT floor ms a press"],
                         [[k, _f(v["a_press"], 2), _f(100 * v["windowed"]), _f(v["iterations_mean"]),
                           _f(v["iterations_p90"]), _f(v["fft_floor_ms_a_press"], 2)]
                          for k, v in fl["solves"].items()]
                         + [["both", "", "", "", "", _f(fl["fft_floor_ms_a_press"], 2)]])]
    pc = ss.get("path")
    if pc:
        d = pc["default"]
        pct = lambda r, k: _f(100 * r[k], 2) if k in r else "-"  # noqa: E731
        out += [f"\nThe oblique path's steps ({pc['presses']} presses at {'x'.join(map(str, pc['render_size']))} on "
                f"{pc['sensor']}, {pc['sheared']} of them sheared by more than {pc['sheared_above_n']} N): each "
                f"variant's distance to the same presses pressed in {pc['reference_steps']} steps with the power-law "
                "quadrature, the path converged (`ffjax.sim.mechanics.oblique_batch`): the tangential force's "
                "relative to its size, the depth's in um, the share of pixels more than 1 count apart; and its time a "
                f"press in one call. The default is {d['steps']} steps, {d['quadrature']}.\n",
                md_table(["steps", "quadrature", "ms a press", "shear off, median %", "p90 %", "max %",
                          "depth off, median um", "max um", "pixels > 1 count %"],
                         [[r["steps"], r["quadrature"] + (" (default)" if (r["steps"], r["quadrature"]) ==
                                                          (d["steps"], d["quadrature"]) else ""),
                           _f(r["ms_a_press"]), pct(r, "ft_rel_median"), pct(r, "ft_rel_p90"), pct(r, "ft_rel_max"),
                           _f(r["depth_um_median"]), _f(r["depth_um_max"]), _f(100 * r["pixels_over_1_count"], 2)]
                          for r in pc["rows"]])]
    dz = ss.get("discretization")
    if dz:
        sizes = dz["sizes"]

        def pct(e, k):
            return "-" if not e or not e[k] else f"{_f(100 * e[k]['median'], 2)} ({_f(100 * e[k]['max'], 1)})"

        shapes = list(next(iter(sizes.values()))["shapes"])
        head = [f"{k} {'x'.join(map(str, v['grid']))}: {what}" for k, v in sizes.items()
                for what in ("shear %", "approach %")]
        out += [f"\nThe solve grid's discretization ({dz['per_shape']} presses a shape on {dz['sensor']}, pressed as "
                "the dataset presses): each preset's frame solved on the grid its size takes (`sim.solve_size`) "
                "against the same presses solved on a grid twice as fine each way, rendered alike. The tangential "
                f"force's error relative to its size (presses sheared by more than {dz['sheared_above_n']} N) and "
                "the approach's, median (max) over the presses, in %.\n",
                md_table(["shape", *head], [[name, *(pct(v["shapes"].get(name) if name != "all" else v["all"], k)
                                                     for v in sizes.values() for k in ("shear_rel", "approach_rel"))]
                                            for name in [*shapes, "all"]])]
    mem = ss.get("memory")
    if mem:
        device = (f"; the device's peak {_f(mem['device_peak_mib'])} MiB (jax's allocator)"
                  if mem.get("device_peak_mib") is not None else "")
        out.append(f"\nPeak resident memory of a fresh process pressing one batch of {mem['batch']} at "
                   f"{'x'.join(map(str, mem['render_size']))} (solved in pieces of "
                   f"{mem.get('piece', ss.get('default_batch', '?'))}): {_f(mem['peak_rss_mib'])} MiB "
                   f"({_f(mem['batch_growth_mib'])} MiB above the process before the batch){device}.\n")
    ds = ss.get("dataset")
    if ds:
        load = (f"load average before {ds['load_before'][0]:.2f}, after {ds['load_after'][0]:.2f}"
                if ds.get("load_before") else "timed by the call that made the pipeline's dataset, "
                f"{ds['made_in']} (its manifest; that call recorded no load)")
        out.append(f"\nThe {ds['preset']} dataset end to end ({ds['presses']:,} presses, {ds['workers']} worker "
                   f"processes): {_f(ds['seconds'])} s; {load}.\n")
    sm = ss.get("sample")
    if sm:
        rate, gb = sm["presses"] / sm["seconds"], sm["full_presses"] * sm["bytes_per_press"] / 1e9
        out.append(f"\nA sample of the {sm['preset']} preset's dataset, every split and sensor at "
                   f"{'x'.join(map(str, sm['render_size']))} ({sm['presses']:,} presses, {sm['workers']} worker "
                   f"process(es), solves in batches of {sm['batch']}; compiling each sensor's programs included): "
                   f"{_f(sm['seconds'])} s, {rate * 60:,.0f} presses/min, {sm['bytes_per_press'] / 1e6:.2f} MB per "
                   f"press on disk. At that rate its {sm['full_presses']:,} presses would take "
                   f"{sm['full_presses'] / rate / 3600:.1f} h and {gb:,.0f} GB (a projection, not a run).\n")
    return "\n".join(out)


def only_report(res: dict) -> str:
    """report.md of `experiments.bench --only <part>`."""
    m = res["machine"]
    steal = next(iter(res.get("_env", {}).values()), {}).get("steal", float("nan"))
    return "\n".join([
        f"# ffjax benchmarks ({res['mode']})\n",
        f"Commit `{res['commit']}`, {res['date_utc']}. Machine: {m.get('cpu_model')}, {m.get('cores')} cores; jax "
        f"{m.get('jax')} (devices {', '.join(m.get('devices', []))}). Load average at start "
        f"{res['load_start'][0]:.1f}, end {res['load_end'][0]:.1f}; steal {_f(100 * steal)}%.\n",
        loop_table(_g(res, "data", "loop_efficiency")),
        bf16_table(res.get("bf16_methods")),
        sim_tables(res.get("sim_speed")),
        *(f"\n![{Path(p).stem}]({Path(p).name})\n" for p in res.get("plots", [])),
    ])


def _save(fig, res: dict, out: Path, name: str) -> str:
    """Stamp a figure with the commit it measured, write it to out/name; its path."""
    fig.text(0.995, 0.005, f"ffjax bench · commit {str(res.get('commit', '?'))[:7]}", ha="right", va="bottom",
             fontsize=7, color="0.35")
    fig.tight_layout()
    path = Path(out) / name
    fig.savefig(path, dpi=110)
    return str(path)


def plots(res: dict, out: Path) -> list[str]:
    """One PNG per scaling axis: ms/step and compiled peak memory; the simulator's rates (sim_plot)."""
    files = [sim_plot(res, out)] if res.get("sim_speed") else []
    if (res.get("sim_speed") or {}).get("path"):
        files.append(path_plot(res, out))
    sc = res.get("scaling")
    if not sc:
        return files
    from experiments import style

    labels = {"batch": "batch size", "size": "image size (px)", "model": "ViT dim/depth/heads"}
    for axis, pts in sc.items():
        if not pts:
            continue
        # time and memory side by side: twin y axes drew the two curves on top of each other, without a legend
        fig, (ax, ax2) = style.figure(1, 2, figsize=(8.5, 3.4))
        xs = [str(p["x"]) for p in pts]
        ax.plot(xs, [p["ms"] for p in pts], "o-", color="C0")
        ax.set_ylabel("train step (ms)")
        ax2.plot(xs, [p["peak_mib"] for p in pts], "s-", color="C1")
        ax2.set_ylabel("compiled peak memory (MiB)")
        for a in (ax, ax2):
            a.set_xlabel(labels.get(axis, axis))
            a.set_ylim(bottom=0)
            a.grid(alpha=0.3)
        fig.suptitle(f"Quick ViT (DINO RD) train step: scaling with {labels.get(axis, axis)} "
                     f"({len(pts)} points, {'GPU' if _on_gpu(res) else 'CPU'})", fontsize=9)
        files.append(_save(fig, res, out, f"scaling_{axis}.png"))
    return files


def sim_plot(res: dict, out: Path) -> str:
    """sim_speed.png: presses/s of the batched solves against the batch size, per render size (one thread, and
    the pieces solved one per core where measured), with the numpy reference's rate as a flat line."""
    from experiments import style

    rates = res["sim_speed"]["rates"]
    fig, ax = style.figure(figsize=(6.4, 4.0))
    for i, (size, v) in enumerate(rates.items()):
        colour = f"C{i}"
        bs = sorted(v["batched_s"], key=int)
        ax.plot([int(b) for b in bs], [v["batched_s"][b] for b in bs], "o-", color=colour, label=f"{size} batched")
        ax.axhline(v["reference_s"], color=colour, ls=":", lw=1.5, label=f"{size} numpy reference")
    from matplotlib.ticker import FuncFormatter, NullFormatter

    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xticks(sorted({int(b) for v in rates.values() for b in v["batched_s"]}))
    plain = FuncFormatter(lambda v, _: f"{v:g}")
    ax.xaxis.set_major_formatter(plain)
    ax.yaxis.set_major_formatter(plain)
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_yticks([t for t in (1, 1.5, 2, 3, 5, 10, 20, 30, 50, 100, 200, 300, 500, 1000)
                   if 0.8 * min(v["reference_s"] for v in rates.values()) <= t
                   <= 1.25 * max(max(v["batched_s"].values()) for v in rates.values())] or [1])
    first = next(iter(rates.values()))
    counts = set(first.get("presses", {}).values()) or {first.get("n", "?")}
    each = f"{min(counts)}" if len(counts) == 1 else f"{min(counts)}-{max(counts)}"
    ax.set_xlabel(f"piece size (presses per solve; each timed call presses {each})")
    ax.set_ylabel("presses per second (one process)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, ncol=len(rates), loc="upper center", bbox_to_anchor=(0.5, -0.16), frameon=False)
    m = res.get("machine", {})
    where = "the GPU" if _on_gpu(res) else f"{m.get('cpu_model', 'the CPU')}, {m.get('cores', '?')} cores"
    ax.set_title(f"Simulator, {first.get('loading', '')} presses ({first.get('steps', '?')} path steps)\non {where}",
                 fontsize=9)  # two lines: a CPU's model name alone can fill the width
    return _save(fig, res, out, "sim_speed.png")


def path_plot(res: dict, out: Path) -> str:
    """path_convergence.png: the oblique path's distance to its converged self against its time a press, per
    quadrature, each point a number of steps: the tangential force (median, and p90 dashed) and the depth (max)."""
    from experiments import style

    pc = res["sim_speed"]["path"]
    default = (pc["default"]["steps"], pc["default"]["quadrature"])
    fig, (ax, ax2) = style.figure(1, 2, figsize=(9.0, 3.8))
    quadratures = sorted({r["quadrature"] for r in pc["rows"]})
    by_q = {q: sorted((r for r in pc["rows"] if r["quadrature"] == q), key=lambda r: r["steps"]) for q in quadratures}
    for i, (q, rows) in enumerate(by_q.items()):
        ms = [r["ms_a_press"] for r in rows]
        if all("ft_rel_median" in r for r in rows):
            ax.plot(ms, [100 * r["ft_rel_median"] for r in rows], "o-", color=f"C{i}", label=f"{q}, median")
            ax.plot(ms, [100 * r["ft_rel_p90"] for r in rows], "v--", color=f"C{i}", mfc="white", label=f"{q}, p90")
        for r in rows:
            mark = " (default)" if (r["steps"], r["quadrature"]) == default else ""
            if "ft_rel_median" in r:
                ax.annotate(f"{r['steps']}{mark}", (r["ms_a_press"], 100 * r["ft_rel_median"]), fontsize=7,
                            xytext=(4, 4 if q == "midpoint" else -10), textcoords="offset points", color=f"C{i}")
    # the quadrature weighs the force only (the held gel moves as the tool does), so the depths are one curve
    # unless a run says otherwise
    same = len({tuple(r["depth_um_max"] for r in rows) for rows in by_q.values()}) == 1
    for i, (q, rows) in enumerate(by_q.items()):
        if same and i:
            break
        name = "either quadrature" if same else q
        colour = "0.3" if same else f"C{i}"
        ms = [r["ms_a_press"] for r in rows]
        ax2.plot(ms, [r["depth_um_max"] for r in rows], "o-", color=colour, label=f"{name}, max over presses")
        ax2.plot(ms, [r["depth_um_median"] for r in rows], "v--", color=colour, mfc="white", label=f"{name}, median")
        for r in rows:
            ax2.annotate(f"{r['steps']}", (r["ms_a_press"], r["depth_um_max"]), fontsize=7, xytext=(4, 4),
                         textcoords="offset points", color=colour)
    ax.set_ylabel("shear |Ft| off the converged path (% of |Ft|)")
    ax2.set_ylabel("depth off the converged path (um)")
    for a in (ax, ax2):
        a.set_xlabel("ms a press (one call; labels: path steps)")
        a.set_ylim(bottom=0)
        a.grid(alpha=0.3)
        a.legend(fontsize=7, frameon=False)
    size = "x".join(map(str, pc["render_size"]))
    fig.suptitle(f"Oblique path against itself in {pc['reference_steps']} power-law steps: {pc['presses']} presses "
                 f"at {size} on {pc['sensor']} ({pc['sheared']} sheared)", fontsize=9)
    return _save(fig, res, out, "path_convergence.png")
