"""Benchmarks: ffjax against the same architectures in PyTorch and against this machine's limit.

    python -m experiments.bench [--quick] [--device auto|cpu|gpu] [--out DIR] [--torch-python PYTHON]

Writes DIR/results.json (every number, commit, machine, steal/load per section), DIR/report.md (every
ratio) and PNG plots. The PyTorch side (experiments/bench/torch_twin.py) runs in this interpreter when torch
imports here, else under --torch-python as a subprocess (optional extra: `pip install torch==2.13.0`);
without either it is skipped and said so. Times are medians over rounds after compilation and warm-up;
the VMs here lose CPU to neighbours, so compare only ratios taken in one run (steal is recorded).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

from experiments import common
from experiments.bench import jax_step as bj
from experiments.common import ROOT, git_commit, write_json, write_text

# What each mode measures: (preset, method, input size, train batch, infer batches, overrides, vit preset).
# "smoke" is for the tests (its numbers check the plumbing); "quick" the short run reproduce publishes; "full" the
# longest (measured times: docs/results/quick/reproduce.json, docs/benchmarks.md).
S14 = {"preset": "paper", "vit": "s14", "overrides": {"model.decoder.kind": "tokens"}}
PLANS = {
    "smoke": {
        "cases": {"quick_vit": {"preset": "smoke", "method": "dino_rd", "size": 32, "batch": 8, "infer": (1, 8)},
                  "resnet": {"preset": "smoke", "method": "resnet_rd", "size": 32, "batch": 8, "infer": (1,)}},
        "vit_b14": None, "timing": (1, 1, 2), "infer_timing": (1, 2, 2), "peak_n": 256,
        "sim": {"n": {"64x64": 10}, "sizes": {"64x64": (24, 32)}}, "data": {"per_shape": 4, "batches": 3},
        "sim_speed": {"sizes": {"24x32": (24, 32)}, "batches": (1, 8), "n": 8, "reference_n": 4,
                      "agreement_size": (24, 32), "agreement_per_shape": 1, "memory": (8, (24, 32)), "dataset": None,
                      "floor": 4, "path": {"n": 4, "steps": (1, 2), "reference": 4},
                      "discretization": {"sizes": {"smoke": (24, 32)}, "per_shape": 1}},
        "workers": (0,),
        "scaling": {"base": "smoke", "batch": (4, 8), "size": (16, 32), "model": ((16, 1, 2), (32, 2, 2))},
        "dp": None, "bf16_acc": {"preset": "smoke", "steps": 12, "batch": 8}, "profile": True,
        "loop": {"train": 32, "val": 8, "epochs": 2, "val_every": (1, 2)},
    },
    "quick": {
        "cases": {"quick_vit": {"preset": "quick", "method": "dino_rd", "size": 64, "batch": 64, "infer": (1, 32)},
                  "vit_s14": {**S14, "method": "dino_rd", "size": 224, "batch": 2, "infer": (1, 8),
                              "timing": (1, 1, 2), "infer_timing": (1, 1, 3)},
                  "resnet": {"preset": "quick", "method": "resnet_rd", "size": 64, "batch": 64, "infer": (1, 32)}},
        "vit_b14": {"batch": 1, "timing": (1, 1, 3)}, "timing": (2, 2, 3), "infer_timing": (3, 10, 3),
        "peak_n": 2048, "sim": {"n": {"64x64": 100, "native": 10}, "sizes": {"64x64": (48, 64), "native": (240, 320)}},
        # the layer solves batched against the numpy reference per render size and batch; the quick dataset
        "sim_speed": {"sizes": {"48x64": (48, 64), "120x160": (120, 160), "240x320": (240, 320)},
                      "batches": (1, 8, 32), "n": 128, "reference_n": 32, "agreement_size": (48, 64),
                      "agreement_per_shape": 3, "memory": (256, (240, 320)), "dataset": "quick",
                      "floor": 128,  # presses timed against their transforms alone (at agreement_size)
                      # the oblique path in 2, 4 and 8 steps, per quadrature, against 32 power-law steps
                      "path": {"n": 48, "steps": (2, 4, 8), "reference": 32},
                      # each preset's frame size solved on its grid and on one twice as fine, every shape
                      "discretization": {"sizes": {"smoke": (24, 32), "quick": (48, 64), "paper": (240, 320)},
                                         "per_shape": 4},
                      # the agreement on one Mini per gel and the DIGIT: the three Minis of a gel solve alike
                      # (sim.mechanics_key) and agreed to the last digit on every column at d6bb2a3
                      "agreement_sensors": ("mini-1-gel1", "mini-1-gel2", "mini-1-gel3", "digit"),
                      # on a GPU: larger batches (timed over 4 calls each), one call of 256 for the memory, and a
                      # sample of the paper preset's dataset (2,480 presses at 240x320 over all its splits and
                      # sensors)
                      "accelerator": {"batches": (1, 8, 32, 128, 256), "n": 16, "calls": 4, "reference_n": 16,
                                      "agreement_per_shape": 2, "memory_piece": 256,
                                      "sample": {"preset": "paper", "set": {
                                          "train_per_indenter": 200, "val_per_indenter": 10,
                                          "unseen_per_object": 10, "sensor_test_per_indenter": 2,
                                          "calib_samples": 10}}}},
        "data": {"per_shape": 40, "batches": 30}, "workers": (0, 2),
        "scaling": {"base": "quick", "batch": (16, 64), "size": (32, 64), "model": ((64, 2, 4), (128, 4, 4))},
        "dp": {"batch": 64, "warmup": 1, "steps": 2, "rounds": 2},
        "bf16_acc": {"preset": "smoke", "size": 64, "steps": 100, "batch": 32}, "profile": True,
        # half the quick preset's epoch (3,000 presses, 300 for validation: the same share), validated every
        # epoch or every 5th; the whole epoch's rounds cost 11 of the one command's minutes (d6bb2a3)
        "loop": {"train": 3000, "val": 300, "epochs": 5, "val_every": (1, 5), "rounds": 2},
    },
    "full": {
        "cases": {"quick_vit": {"preset": "quick", "method": "dino_rd", "size": 64, "batch": 64, "infer": (1, 32)},
                  "vit_s14": {**S14, "method": "dino_rd", "size": 224, "batch": 8, "infer": (1, 32),
                              "timing": (1, 2, 3), "infer_timing": (1, 2, 3)},
                  "resnet": {"preset": "quick", "method": "resnet_rd", "size": 64, "batch": 64, "infer": (1, 32)}},
        "vit_b14": {"batch": 1, "timing": (1, 2, 5)}, "timing": (2, 4, 5), "infer_timing": (5, 20, 5),
        "peak_n": 2048, "sim": {"n": {"64x64": 400, "native": 40}, "sizes": {"64x64": (48, 64), "native": (240, 320)}},
        "data": {"per_shape": 100, "batches": 60}, "workers": (0, 2),
        "scaling": {"base": "quick", "batch": (8, 16, 32, 64, 128), "size": (32, 48, 64, 96, 128),
                    "model": ((64, 2, 4), (96, 3, 4), (128, 4, 4), (192, 6, 6), (256, 8, 8))},
        "dp": {"batch": 64, "warmup": 1, "steps": 3, "rounds": 3},
        "bf16_acc": {"preset": "quick", "size": 64, "steps": 150, "batch": 64}, "profile": True,
        "loop": {"train": 6000, "val": 600, "epochs": 5, "val_every": (1, 5), "rounds": 3},
    },
}


# ---------------------------------------------------------------- machine, steal, load
def cpu_times() -> list[int]:
    with open("/proc/stat") as f:
        return [int(v) for v in f.readline().split()[1:]]


def steal_between(before: list[int], after: list[int]) -> dict:
    """Share of CPU time stolen by the hypervisor (and busy share) between two /proc/stat readings."""
    d = [a - b for a, b in zip(after, before)]
    total = max(sum(d[:8]), 1)
    return {"steal": d[7] / total if len(d) > 7 else 0.0, "busy": 1 - (d[3] + d[4]) / total}


class Section:
    """Records wall time, load average and steal share around a block: results[name]["_env"]."""

    def __init__(self, results: dict, name: str, log):
        self.results, self.name, self.log = results, name, log

    def __enter__(self):
        self.t0, self.c0, self.l0 = time.perf_counter(), cpu_times(), os.getloadavg()[0]
        self.log(f"[bench] {self.name} ...")
        return self

    def __exit__(self, *exc):
        env = {"wall_s": time.perf_counter() - self.t0, "load1_before": self.l0, "load1_after": os.getloadavg()[0],
               **steal_between(self.c0, cpu_times())}
        self.results.setdefault("_env", {})[self.name] = env
        if self.results.get("_out"):  # partial results survive a killed run
            write_json(Path(self.results["_out"]) / "results.partial.json",
                       {k: v for k, v in self.results.items() if k != "_out"})
        self.log(f"[bench] {self.name} done in {env['wall_s']:.0f}s (steal {env['steal']:.0%}, "
                 f"load {env['load1_after']:.1f})")
        return False


# ---------------------------------------------------------------- torch side
class TorchSide:
    """torch_twin in-process when torch imports here, else a `--serve` subprocess under torch_python."""

    def __init__(self, torch_python: str | None = None, device: str = "cpu"):
        self.proc, self.local, self.why, self.device = None, None, None, device
        try:
            from experiments.bench import torch_twin

            self.local = torch_twin
        except ImportError:
            if torch_python:
                env = {**os.environ, "OMP_NUM_THREADS": "2", "PYTHONPATH": str(ROOT)}
                twin = ROOT / "experiments" / "bench" / "torch_twin.py"
                self.proc = subprocess.Popen([torch_python, str(twin), "--serve"], stdin=subprocess.PIPE,
                                             stdout=subprocess.PIPE, text=True, env=env)
            else:
                self.why = "torch not importable here and no --torch-python given"
        self.info = self.ask({"op": "info"}) if self.available else None
        if self.info and "error" in self.info:
            self.why, self.info = self.info["error"], None
            self.close()
        elif self.info and device == "cuda" and not self.info.get("cuda"):
            self.why, self.info = "--device gpu, but torch sees no CUDA device", None
            self.close()

    @property
    def available(self) -> bool:
        return self.local is not None or self.proc is not None

    def ask(self, req: dict) -> dict | None:
        req = {"device": self.device, **req}
        if self.local is not None:
            return self.local.handle(req)
        if self.proc is None:
            return None
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            self.why = f"torch subprocess ended (rc={self.proc.poll()})"
            self.proc = None
            return None
        return json.loads(line)

    def close(self):
        if self.proc is not None:
            self.proc.stdin.close()
            self.proc.wait(timeout=30)
            self.proc = None


# ---------------------------------------------------------------- sections
def _cfg(case: dict):
    return bj.case_cfg(case["preset"], case.get("overrides"), case.get("vit"))


def run_models(plan: dict, torch: TorchSide, res: dict) -> None:
    """Train step and inference, ffjax then torch back to back per case (ratios: ffjax speed / torch)."""
    for name, case in plan["cases"].items():
        cfg, m, s = _cfg(case), case["method"], case["size"]
        arch = bj.arch_of(cfg, m, s)
        w, k, r = case.get("timing", plan["timing"])
        out = {"arch": arch, "train": {"ffjax": bj.train_case(cfg, m, case["batch"], s, w, k, r)}}
        if torch.available:
            req = {"op": "train", "arch": arch, "batch": case["batch"], "warmup": w, "steps": k, "rounds": r}
            out["train"]["torch"] = torch.ask(req)
            if plan.get("torch_compile"):
                out["train"]["torch_compile"] = torch.ask({**req, "compile": True})
        out["infer"] = {}
        wi, ki, ri = case.get("infer_timing", plan["infer_timing"])
        for bsz in case["infer"]:
            kk = max(1, ki // bsz) if bsz > 1 else ki
            d = {"ffjax": bj.infer_case(cfg, m, bsz, s, wi, kk, ri)}
            if torch.available:
                d["torch"] = torch.ask({"op": "infer", "arch": arch, "batch": bsz, "warmup": wi, "steps": kk,
                                        "rounds": ri})
            out["infer"][f"b{bsz}"] = d
        res[name] = out
    if plan.get("vit_b14"):
        v = plan["vit_b14"]
        cfg = bj.case_cfg("paper", {"model.decoder.kind": "tokens"}, "b14")
        arch = bj.arch_of(cfg, "dino_rd", 224)
        w, k, r = v["timing"]
        d = {"ffjax": bj.infer_case(cfg, "dino_rd", v["batch"], 224, w, k, r)}
        if torch.available:
            d["torch"] = torch.ask({"op": "infer", "arch": arch, "batch": v["batch"], "warmup": w, "steps": k,
                                    "rounds": r})
        res["vit_b14"] = {"arch": arch, "infer": {f"b{v['batch']}": d}}


def run_scaling(plan: dict, res: dict, base_case: dict | None) -> None:
    """Train-step time and compiled memory of the quick ViT (dino_rd) as batch, image and model grow."""
    sc = plan["scaling"]
    base = bj.case_cfg(sc["base"])
    b0, s0, m0 = base["train"]["batch_size"], base["data"]["input_size"], base["model"]["vit"]
    w, k, r = 1, 2, 2
    out = {"batch": [], "size": [], "model": []}

    def one(cfg, bsz, size):
        if base_case and (bsz, size, cfg["model"]["vit"]) == (base_case["batch"], base_case["input_size"], m0):
            return base_case
        return bj.train_case(cfg, "dino_rd", bsz, size, w, k, r)

    for bsz in sc["batch"]:
        out["batch"].append({"x": bsz, **_slim(one(base, bsz, s0))})
    for size in sc["size"]:
        out["size"].append({"x": size, **_slim(one(base, b0, size))})
    for dim, depth, heads in sc["model"]:  # (dim, depth, heads): the preset's ViT is one of them
        cfg = bj.case_cfg(sc["base"], {"model.vit.dim": dim, "model.vit.depth": depth, "model.vit.heads": heads})
        out["model"].append({"x": f"{dim}/{depth}/{heads}", **_slim(one(cfg, b0, s0))})
    res.update(out)


def _slim(r: dict) -> dict:
    keys = ("ms", "img_s", "params", "gflop_per_step", "gflop_per_step_xla", "achieved_gflops", "compile_s", "batch",
            "input_size")
    return {k: r[k] for k in keys} | {"peak_mib": (r["memory"] or {}).get("peak_bytes", 0) / 2**20}


def run_dp(plan: dict) -> dict:
    dp = plan["dp"]
    env = {**os.environ, "XLA_FLAGS": (os.environ.get("XLA_FLAGS", "") +
                                       " --xla_force_host_platform_device_count=8").strip()}
    arg = json.dumps({"preset": "quick", "method": "dino_rd", **dp})
    p = subprocess.run([sys.executable, "-m", "experiments.bench.dp", arg], env=env, capture_output=True,
                       text=True, cwd=ROOT, timeout=900)
    if p.returncode != 0:
        return {"error": p.stderr[-2000:]}
    return json.loads(p.stdout.strip().splitlines()[-1])


def run_data(plan: dict, res: dict, main_case: dict, tmp: Path) -> None:
    from experiments.bench import loop as bd
    from ffjax import data

    sim = plan["sim"]
    res["sim"] = bd.sim_rates(sim["sizes"], sim["n"])
    cfg = bj.case_cfg(plan["cases"]["quick_vit"]["preset"])
    size, batch = main_case["input_size"], main_case["batch"]
    cfg["data"]["render_size"] = tuple(plan["sim"]["sizes"]["64x64"])
    folder, rate = bd.make_split(tmp, cfg, "train", 0, plan["data"]["per_shape"])
    res["sim"]["dataset_path_64x64"] = {"samples_s": rate, "samples": plan["data"]["per_shape"] * 10}
    src = data.open_split(folder)
    stats = data.Stats.compute(src, cfg["data"], size)
    res["pipeline"] = bd.pipeline_rates(src, stats, size, batch, plan["data"]["batches"], plan["workers"])
    need = main_case["img_s"]  # what the train step consumes, img/s
    for v in res["pipeline"].values():
        v["ratio_to_train_consumption"] = v["img_s"] / need
    res["pipeline"]["train_consumption_img_s"] = need
    res["loop_efficiency"] = run_loop(plan, src, size, batch)
    res["_arrays"] = (src, stats, size)


def run_loop(plan: dict, src, size: int, batch: int) -> dict:
    """Loop efficiency (loop.loop_efficiency) for each train.val_every of the plan, `rounds` times,
    the rounds of the settings interleaved so load changes weigh on all; the median round is reported,
    every round's figures beside it."""
    from experiments.bench import loop as bd

    lp, case = plan["loop"], plan["cases"]["quick_vit"]
    runs: dict = {v: [] for v in lp["val_every"]}
    for _ in range(int(lp.get("rounds", 1))):
        for v in lp["val_every"]:
            cfg = bj.case_cfg(case["preset"], {"train.val_every": v})
            runs[v].append(bd.loop_efficiency(cfg, case["method"], src, size, batch, lp["train"], lp["val"],
                                              lp["epochs"]))
    out = {}
    for v, rs in runs.items():
        rs = sorted(rs, key=lambda r: r["efficiency"])
        keep = ("efficiency", "efficiency_training", "efficiency_cpu", "efficiency_training_fixed", "loop_ms",
                "pure_ms", "fixed_ms", "eval_s", "load1")
        out[f"val_every_{v}"] = {**rs[len(rs) // 2], "rounds": [{k: r[k] for k in keep} for r in rs]}
    return out


def bf16_methods(plan: dict, src) -> dict:
    """bfloat16 against float32 for every registry method (and dino_rd with the paper's decoder): the train
    step's speed on the main case (timed interleaved, jax_step.paired_ms) and the validation loss after the
    same short run from the same init (jax_step.bf16_accuracy, the plan's bf16_acc sizes)."""
    from ffjax import data, registry

    case, acc = plan["cases"]["quick_vit"], plan["bf16_acc"]
    acfg = bj.case_cfg(acc["preset"])
    asize = acc.get("size", acfg["data"]["input_size"])
    arrays = data.load_arrays(src, data.Stats.compute(src, acfg["data"], asize), asize)
    n_val = max(acc["batch"], len(arrays["force"]) // 5)
    val = {k: v[:n_val] for k, v in arrays.items()}
    tr = {k: v[n_val:] for k, v in arrays.items()}
    names = plan.get("bf16_methods") or registry.names()
    variants = [(n, n, "tokens") for n in names]
    if "dino_rd" in names:
        variants.append(("dino_rd_paper_decoder", "dino_rd", "paper"))
    out = {}
    for label, method, decoder in variants:
        over = {**case.get("overrides", {}), "model.decoder.kind": decoder}
        cfg = bj.case_cfg(case["preset"], over)
        speed = bj.paired_ms({d: bj.with_dtype(cfg, d) for d in ("float32", "bfloat16")}, method, case["batch"],
                             case["size"])
        a = bj.bf16_accuracy(bj.case_cfg(acc["preset"], {"model.decoder.kind": decoder}), method, tr, val,
                             acc["steps"], acc["batch"])
        a.update(preset=acc["preset"], input_size=asize)
        out[label] = {"speed": speed, "accuracy": a, "speedup_bf16": speed["bfloat16"]["speed_over_float32"],
                      "speed_case": {"preset": case["preset"], "batch": case["batch"], "size": case["size"]},
                      "val_loss_ratio_bf16_over_f32": a["val_loss_ratio_bf16_over_f32"],
                      "val_force_l1_ratio_bf16_over_f32": a["val_force_l1_ratio_bf16_over_f32"]}
    return out


ONLY = {"loop": "the training loop against its own step", "bf16": "bfloat16 against float32, every method",
        "sim": "the simulator's batched solves against the numpy reference, and a preset's dataset"}


def run_only(part: str, mode: str | dict, out: str | Path | None = None, log=print, made=None) -> dict:
    """One part of `mode` (a PLANS name or a plan dict with a "name") on its own (`--only loop|bf16|sim`; loop and
    bf16 on a split the simulator renders): results.json and report.md in results/bench-<part>-<mode>. made: a
    made dataset whose manifest may give sim's dataset time (bench.sim.made_time)."""
    from experiments.bench import loop as bd
    from experiments.bench import report as bench_report
    from ffjax import data

    plan, t_start = (PLANS[mode] if isinstance(mode, str) else mode), time.perf_counter()
    mode = mode if isinstance(mode, str) else plan.get("name", "custom")
    out = Path(out or ROOT / "results" / f"bench-{part}-{mode}").absolute()
    out.mkdir(parents=True, exist_ok=True)
    res: dict = {"experiment": "bench", "mode": f"{mode}, {part} only", "commit": git_commit(),
                 "date_utc": datetime.now(UTC).isoformat(timespec="seconds"), "machine": common.machine(),
                 "load_start": list(os.getloadavg()), "data": {}}
    case = plan["cases"]["quick_vit"]
    with Section(res, part, log), tempfile.TemporaryDirectory() as tmp:
        if part == "sim":
            from experiments.bench import sim as bench_sim

            res["sim_speed"] = bench_sim.run(plan["sim_speed"], log, made)
        else:
            cfg = bj.case_cfg(case["preset"])
            cfg["data"]["render_size"] = tuple(plan["sim"]["sizes"]["64x64"])
            folder, _ = bd.make_split(Path(tmp), cfg, "train", 0, plan["data"]["per_shape"])
            src = data.open_split(folder)
            if part == "loop":
                res["data"]["loop_efficiency"] = run_loop(plan, src, case["size"], case["batch"])
            else:
                res["bf16_methods"] = bf16_methods(plan, src)
    res["ratios"] = ratios(res)
    res["wall_s"], res["load_end"] = time.perf_counter() - t_start, list(os.getloadavg())
    res["plots"] = bench_report.plots(res, out)
    write_json(out / "results.json", res)
    write_text(out / "report.md", bench_report.only_report(res))
    log(f"[bench] wrote {out}/results.json and report.md in {res['wall_s']:.0f}s")
    return res


FAST_ITEMS = ("recompile", "donation", "decoders", "bf16_speed", "bf16_accuracy")


def run_fast(plan: dict, res: dict, models_res: dict, data_ctx) -> None:
    """Donation, compile-once, decoder kinds, bfloat16 (speed and accuracy), in-memory vs streaming."""
    case = plan["cases"]["quick_vit"]
    cfg, m, s, b = _cfg(case), case["method"], case["size"], case["batch"]
    main = models_res["quick_vit"]["train"]["ffjax"]
    w, k, r = plan["timing"]
    items = plan.get("fast", FAST_ITEMS)
    if "recompile" in items:
        res["recompile"] = bj.recompile_check(cfg, m, b, s)
    if "donation" in items:
        res["donation"] = bj.donation(cfg, m, b, s, w, k, r, done={"donate": main})
    if "decoders" in items:
        res["decoders"] = bj.decoder_kinds(case["preset"], b, s, w, k, r, case.get("overrides"),
                                           done={"tokens": main})
    if "bf16_speed" in items:
        res["bf16_speed"] = bj.bf16_speed(cfg, m, b, s, w, k, r, done={"float32": main})
    acc = plan["bf16_acc"]
    if data_ctx is not None and "bf16_accuracy" in items:
        from ffjax import data

        src, _, _ = data_ctx
        acfg = bj.case_cfg(acc["preset"])
        asize = acc.get("size", acfg["data"]["input_size"])
        stats = data.Stats.compute(src, acfg["data"], asize)
        arrays = data.load_arrays(src, stats, asize)
        n_val = max(acc["batch"], len(arrays["force"]) // 5)
        val = {k2: v[:n_val] for k2, v in arrays.items()}
        tr = {k2: v[n_val:] for k2, v in arrays.items()}
        res["bf16_accuracy"] = bj.bf16_accuracy(acfg, "dino_rd", tr, val, acc["steps"], acc["batch"])
        res["bf16_accuracy"]["preset"], res["bf16_accuracy"]["input_size"] = acc["preset"], asize


def run(mode: str | dict = "quick", out: str | Path | None = None, torch_python: str | None = None,
        log=print, skip: tuple[str, ...] = (), torch_compile: bool | None = None) -> dict:
    """Run every section of `mode` ("smoke" | "quick" | "full", or a plan dict shaped like PLANS' with a
    "name") on jax's default device (see `select_device`); write results.json, report.md and plots to `out`.
    The PyTorch side runs on CUDA when jax does; torch_compile (default: on a GPU only, as inductor's CPU
    compile of a backward takes minutes) adds torch.compile timings of the train step."""
    import jax

    plan = dict(PLANS[mode] if isinstance(mode, str) else mode)
    on_gpu = jax.default_backend() == "gpu"
    plan["torch_compile"] = on_gpu if torch_compile is None else torch_compile
    mode = mode if isinstance(mode, str) else plan.get("name", "custom")
    out = Path(out or ROOT / "results" / f"bench-{mode}").absolute()
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    res: dict = {"experiment": "bench", "mode": mode, "commit": git_commit(),
                 "date_utc": datetime.now(UTC).isoformat(timespec="seconds"), "machine": common.machine(),
                 "load_start": list(os.getloadavg()), "_out": str(out)}
    torch = TorchSide(torch_python, "cuda" if on_gpu else "cpu")
    res["torch"] = torch.info or {"skipped": torch.why}
    try:
        with Section(res, "peak", log):
            res["peak"] = {"ffjax": bj.matmul_peak(plan["peak_n"])}
            if torch.available:
                res["peak"]["torch"] = torch.ask({"op": "peak", "n": plan["peak_n"]})
        with Section(res, "models", log):
            res["models"] = {}
            run_models(plan, torch, res["models"])
    finally:
        torch.close()
    main = res["models"]["quick_vit"]["train"]["ffjax"]
    if plan["profile"] and "profile" not in skip:
        with Section(res, "profile", log):
            c = plan["cases"]["quick_vit"]
            res["profile"] = bj.profile_step(_cfg(c), c["method"], c["batch"], c["size"])
    data_ctx = None
    if "data" not in skip:
        with Section(res, "data", log), tempfile.TemporaryDirectory() as tmp:
            res["data"] = {}
            run_data(plan, res["data"], main, Path(tmp))
            data_ctx = res["data"].pop("_arrays")
            with Section(res, "fast", log):
                res["fast"] = {}
                run_fast(plan, res["fast"], res["models"], data_ctx)
    else:
        with Section(res, "fast", log):
            res["fast"] = {}
            run_fast(plan, res["fast"], res["models"], None)
    if "scaling" not in skip:
        with Section(res, "scaling", log):
            res["scaling"] = {}
            run_scaling(plan, res["scaling"], main)
    if plan["dp"] and "dp" not in skip:
        with Section(res, "dp", log):
            res["dp"] = run_dp(plan)
    res.pop("_out", None)
    (out / "results.partial.json").unlink(missing_ok=True)
    res["ratios"] = ratios(res)
    res["wall_s"] = time.perf_counter() - t_start
    res["load_end"] = list(os.getloadavg())
    write_json(out / "results.json", res)
    from experiments.bench import report as bench_report

    res["plots"] = bench_report.plots(res, out)
    write_text(out / "report.md", bench_report.report(res))
    write_json(out / "results.json", res)
    log(f"[bench] wrote {out}/results.json and report.md in {res['wall_s']:.0f}s")
    return res


def ratios(res: dict) -> dict:
    """Every headline ratio, flat: name -> float (>1 means the first-named side is faster/larger)."""
    from experiments.bench.report import collect_ratios

    return collect_ratios(res)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m experiments.bench", description=common.description(__doc__))
    measured = common.measured_cost("bench", "quick")
    ap.add_argument("--quick", action="store_true", help="the shorter version (fewer rounds, smaller sweeps)"
                    + (f"; {measured}" if measured else ""))
    ap.add_argument("--smoke", action="store_true",
                    help="tiny sizes, for the tests: its numbers check the plumbing and mean nothing")
    ap.add_argument("--out", default=None, help="results folder (default results/bench-<mode>)")
    ap.add_argument("--torch-python", default=None,
                    help="python with torch for the PyTorch side when torch is not importable here")
    ap.add_argument("--skip", action="append", default=[], choices=("profile", "data", "scaling", "dp"),
                    help="leave a part out (repeatable): profile, the train step's per-op profile; data, the "
                         "simulator, input pipeline and training loop rates; scaling, the step as batch, image and "
                         "model grow; dp, data parallel over 8 virtual CPU devices")
    ap.add_argument("--only", choices=tuple(ONLY), default=None,
                    help="one part alone, in results/bench-<part>-<mode>: "
                         + "; ".join(f"{k}: {v}" for k, v in ONLY.items()))
    ap.add_argument("--device", choices=("auto", "cpu", "gpu"), default="auto",
                    help="where jax and the PyTorch side run (auto: a GPU when jax has one)")
    ap.add_argument("--torch-compile", action=argparse.BooleanOptionalAction, default=None,
                    help="also time torch.compile (default: on a GPU only)")
    ap.add_argument("--data", default=None, help="--only sim: a made dataset of the preset, whose manifest gives "
                                                  "the dataset's time where today's simulator made it whole in one "
                                                  "call (else the benchmark makes one)")
    a = ap.parse_args(argv)
    select_device(a.device)
    mode = "smoke" if a.smoke else "quick" if a.quick else "full"
    if a.only:
        run_only(a.only, mode, a.out, made=a.data)
        return
    run(mode, a.out, a.torch_python, skip=tuple(a.skip), torch_compile=a.torch_compile)


def select_device(device: str) -> None:
    """Pin jax to "cpu" or "gpu" (before its first computation); "auto" keeps jax's choice. A GPU is not
    preallocated (XLA takes 75% of it by default, and the PyTorch side shares the device)."""
    import jax

    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    if device != "auto":
        jax.config.update("jax_platforms", {"cpu": "cpu", "gpu": "cuda"}[device])
    if device == "gpu" and jax.default_backend() != "gpu":
        raise SystemExit("error: --device gpu, but jax finds no GPU (install jax[cuda12] or use --device cpu)")


if __name__ == "__main__":
    main()
