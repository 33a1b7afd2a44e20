"""Kill/resume fault injection: SIGKILL training, dataset generation and the ablation sweep at random
points, resume each time, and check that nothing was lost.

    python tests/reliability/faults.py [--preset smoke] [--kills N] [--out DIR] [--ablation] [--seed S]
                                       [--cases | --only-cases]

Each part runs the real CLI in a subprocess: once uninterrupted (the reference), then again in a fresh
folder that is SIGKILLed after a random delay, resumed, killed again, N times, and finally run to the end.
After every kill the folder is checked (the newest checkpoint must load; finished dataset shards must
be untouched by the next resume). At the end the results must equal the reference: training params and
validation metrics bitwise, every dataset shard byte for byte, the ablation's tables. --cases also runs
issue 17's nine numbered cases (faults_cases.py beside this file: bad sources, NaN and corrupt weights, bad flags,
two writers, a full disk, a truncated checkpoint, one-line errors, bad training frames, a zip bomb), each
through the real CLIs, measured and checked; --only-cases runs just those (a few minutes). Writes
DIR/results.json and DIR/report.md (DIR: results/faults-<preset> under the repository root unless --out).

A developers' tool, beside the reliability tests that import it (test_rel_faults*.py); run from the repository
root after `pip install -e ".[test]"` (it imports experiments and ffjax, and faults_cases from this folder).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import faults_cases  # beside this file: the script's folder is on sys.path, and pytest's for the tests here
from tqdm import tqdm

from experiments import common, kernel

COMMAND = "python tests/reliability/faults.py"  # how it is run: its usage line and the command a report records
TRAIN_METHOD = "dino_rd_scratch"  # no pretraining stage: the kill points land in training itself
# A few more, smaller shards than the smoke preset so dataset kills land between shards.
DATA_SET = ("data.train_per_indenter=16", "data.shard_size=16")


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(prog=COMMAND, description=__doc__.strip().splitlines()[0])
    ap.add_argument("--preset", default="smoke", choices=("smoke", "quick"))
    ap.add_argument("--kills", type=int, default=5, help="SIGKILLs per part (default 5)")
    ap.add_argument("--out", default=None, help="results folder (default: results/faults-<preset>)")
    ap.add_argument("--epochs", type=int, default=6, help="training epochs (longer runs: more kill points)")
    ap.add_argument("--ablation", action="store_true", help="also kill/resume the smoke ablation sweep")
    ap.add_argument("--seed", type=int, default=0, help="seed of the kill points")
    ap.add_argument("--cases", action="store_true", help="also run issue 17's numbered cases (faults_cases)")
    ap.add_argument("--only-cases", action="store_true", help="run only the numbered cases, no kill/resume part")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    out = Path(args.out or common.ROOT / "results" / f"faults-{args.preset}").absolute()
    if args.kills < 0:
        ap.error("--kills must be >= 0")
    if args.only_cases and args.ablation:
        ap.error("--only-cases runs no kill/resume part: drop --ablation (or use --cases)")
    command = COMMAND + " " + " ".join(sys.argv[1:] if argv is None else argv)
    res = run(args.preset, args.kills, out, args.epochs, args.ablation, args.seed, progress=not args.quiet,
              command=command, cases=args.cases or args.only_cases, kill_parts=not args.only_cases)
    print(report_md(res))
    print(f"wrote {out}/results.json and report.md")
    return res


def run(preset: str, kills: int, out: Path, epochs: int, ablation: bool, seed: int, progress: bool = True,
        command: str = "", cases: bool = False, kill_parts: bool = True) -> dict:
    """Every kill/resume part (dataset, train, optionally ablation) unless not `kill_parts`, then the numbered
    cases if `cases`; writes and returns the results dict."""
    out.mkdir(parents=True, exist_ok=True)
    env = _env(out)
    t0 = time.perf_counter()
    parts = _kill_parts(preset, kills, out, epochs, ablation, seed, env, progress) if kill_parts else {}
    totals = {k: sum(p[k] for p in parts.values()) for k in ("kills_injected", "kills_landed", "survived")}
    totals["data_lost"] = any(p["data_lost"] for p in parts.values())
    totals["corrupt_checkpoints"] = sum(p.get("corrupt_found", 0) for p in parts.values())
    res = {"preset": preset, "kills_per_part": kills, "seed": seed, "epochs": epochs,
           "command": command, "commit": common.git_commit(), "totals": totals, "parts": parts}
    if cases:
        res["cases"] = faults_cases.run_cases(out, env, progress)
    res["wall_s"] = round(time.perf_counter() - t0, 1)
    common.write_json(out / "results.json", res)
    common.write_text(out / "report.md", report_md(res))
    return res


def _kill_parts(preset, kills, out, epochs, ablation, seed, env, progress) -> dict:
    """The kill/resume parts: dataset generation, training and (with `ablation`) the ablation sweep."""
    rng = random.Random(seed)
    ref_data = out / "data_ref"
    parts = {"dataset": dataset_part(preset, kills, out, ref_data, env, rng, progress),
             "train": train_part(preset, kills, out, ref_data, epochs, env, rng, progress)}
    if ablation:
        parts["ablation"] = ablation_part(preset, kills, out, ref_data, env, rng, progress)
    return parts


def _env(out: Path) -> dict:
    """Subprocess environment: a shared compile cache so a resumed run does not recompile (the cached executable is
    the same program: results stay bitwise equal): the caller's FFJAX_CACHE (the test suite's), else one under out."""
    env = dict(os.environ)
    env.setdefault("FFJAX_CACHE", str(out / "compile_cache"))
    env["PYTHONPATH"] = os.pathsep.join([str(common.ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    return env


def _run(cmd: list[str], env: dict, log: Path) -> tuple[int, float]:
    """Run to the end; (returncode, seconds)."""
    t = time.perf_counter()
    with open(log, "a") as f:
        rc = subprocess.run(cmd, env=env, stdout=f, stderr=subprocess.STDOUT, cwd=common.ROOT).returncode
    return rc, time.perf_counter() - t


def _run_killed(cmd: list[str], env: dict, log: Path, done, target: float, jitter: float) -> dict:
    """Start `cmd`; once done() = (progress: steps, shards; time of the last write) shows this process at
    `target`, wait `jitter` s more and SIGKILL it. Returns where the kill landed (landed False: the process
    had already finished)."""
    t0, wall0 = time.perf_counter(), time.time()
    with open(log, "a") as f:
        p = subprocess.Popen(cmd, env=env, stdout=f, stderr=subprocess.STDOUT, cwd=common.ROOT)
        while p.poll() is None:
            prog, wrote = done()
            if prog >= target and wrote >= wall0:  # past startup: this process itself has written
                break
            time.sleep(0.02)
        time.sleep(jitter)  # progress is seen in steps of a log flush / a shard: land anywhere in between
        landed = p.poll() is None
        if landed:
            p.send_signal(signal.SIGKILL)
        p.wait()
    return {"landed": landed, "at_s": round(time.perf_counter() - t0, 2), "progress_at_kill": done()[0]}


def _kill_loop(name, cmd, env, log, kills, done, total, rng, check, progress) -> dict:
    """Kill `cmd` `kills` times at random progress points (kill k uniform in the k-th of kills+1 equal parts
    of the work), running check() after each kill, then run it to the end."""
    points, corrupt, errors = [], 0, []
    for k in tqdm(range(kills), desc=f"faults {name}", disable=not progress):
        target = rng.uniform(k, k + 1) * total / (kills + 1)
        hit = _run_killed(cmd, env, log, done, target, rng.uniform(0.0, 0.5))
        state = check()
        corrupt += int(bool(state.get("corrupt")))
        points.append({"kill": k + 1, "target": round(target, 1), **hit, **state})
    rc, secs = _run(cmd, env, log)
    if rc != 0:
        errors.append(f"final run exited {rc}; see {log}")
    return {"points": points, "corrupt_found": corrupt, "final_rc": rc, "final_s": round(secs, 1), "errors": errors}


def _summary(name: str, loop: dict, equal: bool, how: str, extra: dict) -> dict:
    landed = sum(p["landed"] for p in loop["points"])
    ok = loop["final_rc"] == 0 and equal
    return {"kills_injected": len(loop["points"]), "kills_landed": landed, "survived": landed if ok else 0,
            "data_lost": not ok or loop["corrupt_found"] > 0, "equal_to_reference": equal, "comparison": how,
            **{k: loop[k] for k in ("corrupt_found", "final_rc", "errors", "points")}, **extra}


# ---- dataset generation -------------------------------------------------------------------------------


def _dataset_cmd(preset: str, folder: Path) -> list[str]:
    cmd = [sys.executable, "-m", "ffjax.simulate", "--preset", preset, "--out", str(folder), "--quiet",
           "--workers", "1"]
    return cmd + [a for s in DATA_SET for a in ("--set", s)]


def _shards(folder: Path) -> dict:
    """{relative path: (inode, mtime_ns)} of every finished shard."""
    return {str(p.relative_to(folder)): (p.stat().st_ino, p.stat().st_mtime_ns) for p in folder.rglob("shard_*.npz")}


def _digests(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.suffix in (".npz", ".png")}


def dataset_part(preset, kills, out, ref, env, rng, progress) -> dict:
    log = out / "dataset.log"
    rc, ref_s = _run(_dataset_cmd(preset, ref), env, log) if not (ref / "manifest.json").is_file() else (0, None)
    if rc:
        raise RuntimeError(f"reference dataset generation failed; see {log}")
    ref_s = ref_s or json.loads((ref / "manifest.json").read_text())["generation"]["seconds"] + 3
    folder = out / "data_faulted"
    _clear(folder)
    seen: dict = {}
    redone = []

    def check():
        now = _shards(folder)
        # a shard finished before an earlier kill must keep its inode and mtime: it was not redone
        redone.extend(k for k, v in seen.items() if now.get(k) != v)
        seen.update(now)
        partial = [str(p) for p in folder.rglob(".*.tmp*")]
        return {"shards_done": len(now), "partial_files": len(partial)}

    total = len(list(ref.rglob("shard_*.npz")))
    def done():
        shards = list(folder.rglob("shard_*.npz"))
        return len(shards), max((p.stat().st_mtime for p in shards), default=0.0)

    loop = _kill_loop("dataset", _dataset_cmd(preset, folder), env, log, kills, done, total, rng, check, progress)
    check()
    a, b = _digests(ref), _digests(folder)
    equal = a == b and (folder / "manifest.json").is_file()
    return _summary("dataset", loop, equal and not redone, "every shard and background byte-identical (sha256)",
                    {"files": len(a), "finished_shards_redone": sorted(set(redone)), "reference_s": round(ref_s, 1)})


# ---- training -----------------------------------------------------------------------------------------


def _train_cmd(preset: str, data: Path, folder: Path, epochs: int) -> list[str]:
    return [sys.executable, "-m", "ffjax.train", "--preset", preset, "--method", TRAIN_METHOD, "--data", str(data),
            "--out", str(folder), "--resume=auto", "--quiet", "--set", f"train.epochs={epochs}", "--set",
            "train.ckpt_every=3"]


def _latest_ok(folder: Path) -> dict:
    """Does the newest checkpoint load? (a kill may leave none yet, never a broken one)."""
    from ffjax import store

    try:
        store.load(folder, "latest")
    except FileNotFoundError:
        return {"ckpt_step": None, "corrupt": False}
    except Exception as e:  # anything else is a checkpoint a kill damaged
        return {"ckpt_step": None, "corrupt": True, "error": f"{type(e).__name__}: {e}"[:300]}
    steps = sorted(int(p.name) for p in (folder / "checkpoints").iterdir() if p.name.isdigit())
    return {"ckpt_step": steps[-1] if steps else None, "corrupt": False}


def _logged_step(run: Path) -> int:
    """The newest step in a run's train log (0 if none): the training progress a kill target is set in."""
    try:
        with open(run / "train_log.jsonl", "rb") as f:
            f.seek(max(0, f.seek(0, 2) - 4096))
            lines = f.read().decode(errors="replace").splitlines()
    except OSError:
        return 0
    for line in reversed(lines):
        try:
            return int(json.loads(line)["step"])
        except (ValueError, KeyError, TypeError):
            continue
    return 0


def _progress(run: Path) -> tuple[int, float]:
    """(newest logged step, when the log was last written)."""
    try:
        return _logged_step(run), (run / "train_log.jsonl").stat().st_mtime
    except OSError:
        return 0, 0.0


def _params_equal(a: Path, b: Path, which: str) -> bool:
    import jax
    import numpy as np

    from ffjax import store

    va, vb = (store.load(x, which).variables for x in (a, b))
    la, lb = jax.tree.leaves(va), jax.tree.leaves(vb)
    return len(la) == len(lb) and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))


def _train_losses(folder: Path) -> list:
    rows = [json.loads(r) for r in (folder / "train_log.jsonl").read_text().splitlines() if r]
    return [(r["kind"], r["step"], r.get("loss")) for r in rows]


def train_part(preset, kills, out, data, epochs, env, rng, progress) -> dict:
    log = out / "train.log"
    ref = out / "train_ref"
    _clear(ref)
    rc, ref_s = _run(_train_cmd(preset, data, ref, epochs), env, log)
    if rc:
        raise RuntimeError(f"reference training failed; see {log}")
    folder = out / "train_faulted"
    _clear(folder)
    total = json.loads((ref / "summary.json").read_text())["total_steps"]
    loop = _kill_loop("train", _train_cmd(preset, data, folder, epochs), env, log, kills,
                      lambda: _progress(folder), total, rng, lambda: _latest_ok(folder), progress)
    equal = False
    if loop["final_rc"] == 0:
        sa, sb = (json.loads((x / "summary.json").read_text()) for x in (ref, folder))
        equal = (sa["val"] == sb["val"] and sa["best_step"] == sb["best_step"] and sa["steps"] == sb["steps"]
                 and _params_equal(ref, folder, "latest") and _params_equal(ref, folder, "best")
                 and _train_losses(ref) == _train_losses(folder))
    return _summary("train", loop, equal, "latest and best params bitwise, validation metrics and every logged "
                    "loss exactly equal", {"reference_s": round(ref_s, 1), "method": TRAIN_METHOD, "epochs": epochs})


# ---- ablation sweep -----------------------------------------------------------------------------------


def _ablation_cmd(preset: str, data: Path, folder: Path) -> list[str]:
    return [sys.executable, "-m", "experiments.ablation", "--preset", preset, "--methods", TRAIN_METHOD,
            "--data", str(data), "--out", str(folder), "--quiet"] + [a for s in DATA_SET for a in ("--set", s)]


def _tables(folder: Path) -> dict:
    r = json.loads((folder / "results.json").read_text())
    return {k: v for k, v in r.items() if k not in ("timings", "commit", "checkpoints", "data", "findings")}


def ablation_part(preset, kills, out, data, env, rng, progress) -> dict:
    log = out / "ablation.log"
    ref = out / "ablation_ref"
    _clear(ref)
    rc, ref_s = _run(_ablation_cmd(preset, data, ref), env, log)
    if rc:
        raise RuntimeError(f"reference ablation failed; see {log}")
    folder = out / "ablation_faulted"
    _clear(folder)
    finished: dict = {}
    redone = []

    def check():
        for st in folder.rglob("stage.json"):
            info = json.loads(st.read_text())
            if info.get("status") == "done":
                if str(st) in finished and finished[str(st)] != info["finished"]:
                    redone.append(str(st))
                finished.setdefault(str(st), info["finished"])
        return {"stages_done": len(finished), **_latest_ok(run_dir)}

    run_dir = kernel.run_dir(folder, TRAIN_METHOD, 0)
    total = json.loads((kernel.run_dir(ref, TRAIN_METHOD, 0) / "summary.json").read_text())["total_steps"] + 1

    def done():  # training steps, then one more unit for the evaluation stage
        step, wrote = _progress(run_dir)
        ev = run_dir / "eval.json"
        return (step + 1, ev.stat().st_mtime) if ev.is_file() else (step, wrote)

    loop = _kill_loop("ablation", _ablation_cmd(preset, data, folder), env, log, kills, done, total, rng, check,
                      progress)
    check()
    equal = loop["final_rc"] == 0 and _tables(ref) == _tables(folder)
    return _summary("ablation", loop, equal and not redone, "results.json tables equal (timings excluded)",
                    {"reference_s": round(ref_s, 1), "finished_stages_redone": redone})


def _clear(folder: Path) -> None:
    import shutil

    if folder.exists():
        shutil.rmtree(folder)


def report_md(res: dict) -> str:
    """The kill/resume table and totals (when those parts ran), then the numbered cases' table (when run)."""
    text = f"# Fault injection ({res['preset']} preset)\n\n`{res['command']}` — {res['wall_s']} s wall, " \
           f"commit {res['commit']}\n\n"
    if res["parts"]:
        text += _parts_md(res)
    if "cases" in res:
        text += "\n## Numbered cases (issue 17)\n\nSmoke preset, each through the real CLI in a subprocess; " \
                "OUT is the results folder.\n\n" + faults_cases.cases_md(res["cases"])
    return text


def _parts_md(res: dict) -> str:
    """The kill/resume parts' table and totals."""
    t = res["totals"]
    rows = [[name, p["kills_injected"], p["kills_landed"], p["survived"], p["corrupt_found"],
             "yes" if p["data_lost"] else "no", p["comparison"]] for name, p in res["parts"].items()]
    head = ["part", "kills injected", "landed (process alive)", "survived", "corrupt checkpoints", "data lost",
            "compared with the uninterrupted reference"]
    return (common.md_table(head, rows)
            + f"\nTotal: {t['kills_injected']} SIGKILLs injected, {t['kills_landed']} landed while the process "
            f"ran, {t['survived']} survived; corrupt checkpoints found: {t['corrupt_checkpoints']}; data lost: "
            f"{'YES' if t['data_lost'] else 'no'}.\n")


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
