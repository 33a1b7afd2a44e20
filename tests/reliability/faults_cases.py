"""Issue 17's nine numbered reliability cases and issue 33's, each exercised as a user would and measured.

    python tests/reliability/faults.py --only-cases [--out DIR]     # or --cases beside the kill/resume parts

Every case runs the real command lines (`python -m ffjax.live ...`) in subprocesses from the repository
root, then measures what a user would see: the exit code, the stderr lines, the key line, and the files
before and after. `run_cases` builds the shared fixtures once under OUT/cases/_shared (a small simulated
smoke dataset, a 2-epoch run of it, a bundle of that run, an 11-frame video), runs each case in its own
folder (OUT/cases/case1, ..., case7_inputs, case7_models, ...; every command's stdout and stderr kept there) and
returns one row per command: what was done, what was expected, what was measured and
the named checks whose conjunction is the row's "pass". `cases_md` renders the rows as a Markdown table.
Cases 5 and 33-6 need a tmpfs (`mount`, root only); where mounting fails they are reported as skipped.
"""

from __future__ import annotations

import json
import os
import pickle
import re
import shutil
import subprocess
import sys
import time
import traceback
import zipfile
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from experiments import common

METHOD = "dino_rd_scratch"  # no pretraining stage
# a smaller smoke dataset than the preset's: 80 training frames (10 steps an epoch), 20 validation frames
SMALL_DATA = ("data.train_per_indenter=8", "data.val_per_indenter=2", "data.unseen_per_object=1",
              "data.sensor_test_per_indenter=1", "data.calib_samples=2")
TIMEOUT = 600.0
# a torch zip's data.pkl naming one float tensor of 4 elements in storage "0" (torch.save's layout)
ONE_TENSOR_PKL = (b"\x80\x02ccollections\nOrderedDict\n)RX\x01\x00\x00\x00wctorch._utils\n_rebuild_tensor_v2\n(("
                  b"X\x07\x00\x00\x00storagectorch\nFloatStorage\nX\x01\x00\x00\x000X\x03\x00\x00\x00cpuK\x04tQ"
                  b"K\x00K\x04\x85K\x01\x85\x89tRs.")
BROADCAST_N = 1 << 28  # ONE_TENSOR_PKL's 4-element storage viewed with stride 0 as 2^28 elements: 1 GiB
BROADCAST_PKL = ONE_TENSOR_PKL.replace(b"K\x04\x85K\x01\x85",
                                       b"J" + BROADCAST_N.to_bytes(4, "little") + b"\x85K\x00\x85")
ERRORS = "exit 1/2, one `error:` line, no traceback"
FULL_DISK = ("train into a 40 MiB tmpfs, fill it after the first checkpoint; free it, `--resume`",
             "rc 1, last line 'error: could not save … the disk is full' naming an intact step; resume rc 0")


@dataclass
class Shared:
    """The fixtures the cases share; the trained-model ones are None where a caller needs only data."""

    env: dict
    data: Path
    run: Path | None = None
    bundle: Path | None = None
    video: Path | None = None
    n_frames: int = 0


class _Payload:
    """Unpickling this runs `echo pwned`: what a crafted .pth does to an unrestricted torch.load."""

    def __reduce__(self):
        """Pickled as a call of os.system."""
        return (os.system, ("echo pwned",))


# ---- running commands ---------------------------------------------------------------------------------


def _start(folder: Path, name: str, env: dict, *args, module: bool = True, group: bool = False,
           cwd: Path = common.ROOT) -> subprocess.Popen:
    """Start `python -m args` (`python args` if not `module`) from `cwd` (the repository root), stdout and stderr
    to folder/name.stdout and .stderr; group: in a process group of its own (a terminal's Ctrl-C goes to a group)."""
    args = ["-m"] * module + [str(a) for a in args]
    with open(folder / f"{name}.stdout", "w") as out, open(folder / f"{name}.stderr", "w") as err:
        p = subprocess.Popen([sys.executable, *args], env=env, cwd=cwd, stdout=out, stderr=err,
                             start_new_session=group, preexec_fn=terminal_sigint if group else None)
    p.logs, p.cmd, p.t0 = (folder / f"{name}.stdout", folder / f"{name}.stderr"), "python " + " ".join(args), \
        time.perf_counter()
    return p


def terminal_sigint() -> None:
    """Ctrl-C as in a terminal, whatever this harness inherited (a script's background job ignores SIGINT)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _wait(p: subprocess.Popen, timeout: float = TIMEOUT) -> dict:
    """Wait for a _start()ed process (SIGKILLed after `timeout` s): rc, stdout, stderr, command, seconds."""
    try:
        p.wait(timeout)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()
    out, err = (f.read_text(errors="replace") for f in p.logs)
    return {"rc": p.returncode, "out": out, "err": err, "cmd": p.cmd, "seconds": round(time.perf_counter() - p.t0, 1)}


def _cli(folder: Path, name: str, env: dict, *args, module: bool = True) -> dict:
    """Run `python -m args` to the end; see _start and _wait."""
    return _wait(_start(folder, name, env, *args, module=module))


# Runs argv[2:] and writes its peak RSS (KiB) to the file argv[1]. A child's ru_maxrss on Linux starts at its
# parent's RSS (the mm it forked from counts until exec): spawned from this small process, the command's is its own.
_RSS_WRAPPER = ("import resource, subprocess, sys; rc = subprocess.call(sys.argv[2:]); "
                "open(sys.argv[1], 'w').write(str(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)); "
                "sys.exit(rc)")


def _cli_rss(folder: Path, name: str, env: dict, *args) -> dict:
    """Run `python args` to the end (see _wait), adding its peak resident memory in MiB ("peak_mib")."""
    rss = folder / f"{name}.maxrss_kib"
    res = _cli(folder, name, env, "-c", _RSS_WRAPPER, rss, sys.executable, *args, module=False)
    res["peak_mib"] = int(rss.read_text()) / 1024 if rss.is_file() else float("nan")
    res["cmd"] = "python " + " ".join(map(str, args))
    return res


def _wait_until(cond, p: subprocess.Popen, timeout: float = 300.0) -> bool:
    """Poll cond() every 20 ms while p runs; whether it came true."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if cond():
            return True
        if p.poll() is not None:
            return bool(cond())
        time.sleep(0.02)
    return False


def _train(data: Path, out: Path, *sets: str, extra=()) -> list:
    """ffjax.train arguments: the smoke preset, no pretraining, --set for each of `sets`."""
    return ["ffjax.train", "--preset", "smoke", "--method", METHOD, "--data", data, "--out", out, "--quiet",
            *extra, *(a for s in sets for a in ("--set", s))]


# ---- measuring ----------------------------------------------------------------------------------------


def _error_lines(err: str) -> list[str]:
    """`error: ...` lines (argparse's are `prog: error: ...`)."""
    return [ln for ln in err.splitlines() if ln.startswith("error:") or ": error: " in ln]


def _key_line(res: dict) -> str:
    """The line that says what happened: the last error line, else the last line of stderr or stdout."""
    errs = _error_lines(res["err"])
    lines = errs or res["err"].strip().splitlines() or res["out"].strip().splitlines() or [""]
    return lines[-1]


def _line(text: str, pattern: str) -> str:
    """The last line of `text` matching the regex `pattern` ('' if none)."""
    return next((ln for ln in reversed(text.splitlines()) if re.search(pattern, ln)), "")


def _error_checks(res: dict, codes=(1, 2), must=(), absent=()) -> dict:
    """The one-line-error contract: exit code in `codes`, one error line saying each of `must`, no traceback
    (nor any of `absent`) in stdout or stderr."""
    errs = _error_lines(res["err"])
    text = res["out"] + res["err"]
    checks = {f"rc {'/'.join(map(str, codes))}": res["rc"] in codes, "one error line": len(errs) == 1}
    checks.update({f"says '{m}'": bool(errs) and m in errs[-1] for m in must})
    checks.update({f"no '{a}'": a not in text for a in ("Traceback", *absent)})
    return checks


def _row(case: str, what: str, expected: str, res: dict, checks: dict, key: str | None = None,
         note: str = "") -> dict:
    """One report row; "pass" is the conjunction of the measured `checks` (name -> bool)."""
    checks = {k: bool(v) for k, v in checks.items()}
    return {"case": case, "what": what, "expected": expected, "rc": res["rc"],
            "stderr_lines": len(res["err"].splitlines()), "key_line": _key_line(res) if key is None else key,
            "note": note, "checks": checks, "pass": bool(checks) and all(checks.values()), "cmd": res["cmd"],
            "seconds": res["seconds"]}


def _skipped(case: str, what: str, expected: str, reason: str) -> dict:
    """A row for a case this machine cannot run: neither passed nor failed."""
    return {"case": case, "what": what, "expected": expected, "skipped": reason, "checks": {}, "pass": None}


def _steps(folder: Path) -> list[int]:
    """Finished checkpoint steps (orbax renames a step's temporary folder to the bare number when done)."""
    return sorted(int(p.name) for p in folder.iterdir() if p.name.isdigit()) if folder.is_dir() else []


def _log_rows(run: Path) -> list[tuple]:
    """(kind, step) of every train_log.jsonl row."""
    text = (run / "train_log.jsonl").read_text() if (run / "train_log.jsonl").is_file() else ""
    return [(r["kind"], r["step"]) for r in map(json.loads, text.splitlines())]


def _summary_steps(run: Path) -> tuple:
    """(steps, total_steps) from a run's summary.json (None, None without one)."""
    s = common.read_json(run / "summary.json") or {}
    return s.get("steps"), s.get("total_steps")


# ---- fixtures -----------------------------------------------------------------------------------------


def build_shared(folder: Path, env: dict) -> Shared:
    """Simulate a small smoke dataset, train it 2 epochs (checkpoints at steps 18 and 20), bundle the run
    and write an 11-frame video of its validation frames (the first one the sensor's background)."""
    _clear(folder)
    folder.mkdir(parents=True)
    data, run = folder / "data", folder / "run"
    gen = _cli(folder, "dataset", env, "ffjax.simulate", "--preset", "smoke", "--out", data, "--quiet",
               "--workers", min(2, os.cpu_count() or 1), *(a for s in SMALL_DATA for a in ("--set", s)))
    trained = gen["rc"] == 0 and _cli(folder, "train", env, *_train(data, run, "train.epochs=2",
                                                                    "train.ckpt_every=3"))["rc"] == 0
    if not trained:
        raise RuntimeError(f"shared fixtures failed; see {folder}/*.stderr")
    from ffjax import store

    bundle = store.save_bundle(folder / "bundle", store.load(run))
    n = _write_video(data / "val", folder / "press.mp4")
    return Shared(env, data, run, bundle, folder / "press.mp4", n)


def _write_video(split: Path, path: Path, n: int = 10) -> int:
    """The split's background then its first `n` frames as an mp4v video; the frame count."""
    import cv2
    import numpy as np

    frames = np.load(sorted(split.glob("shard_*.npz"))[0])["image"][:n]
    bgr = [cv2.imread(str(split / "background.png"))] + [f[..., ::-1] for f in frames]
    h, w = bgr[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (w, h))
    for f in bgr:
        writer.write(np.ascontiguousarray(f))
    writer.release()
    return len(bgr)


def _nan_bundle(run: Path, out: Path) -> str:
    """A bundle of `run` whose last regressor kernel has a NaN at [0, 0]; that tensor's path."""
    import jax
    import numpy as np

    from ffjax import store

    ckpt = store.load(run)
    variables = jax.tree.map(np.array, ckpt.variables)  # writable copies
    leaves = jax.tree_util.tree_flatten_with_path(variables["params"]["regressor"])[0]
    path, kernel = [(p, x) for p, x in leaves if x.ndim == 2][-1]
    kernel[0, 0] = np.nan
    store.save_bundle(out, ckpt, variables)
    return "regressor" + jax.tree_util.keystr(path)


def _flip_middle(path: Path, n: int = 4) -> None:
    """Invert `n` bytes in the middle of a file."""
    raw = bytearray(path.read_bytes())
    mid = len(raw) // 2
    raw[mid:mid + n] = bytes(b ^ 0xFF for b in raw[mid:mid + n])
    path.write_bytes(bytes(raw))


def _largest(folder: Path) -> Path:
    """The largest file directly in `folder`."""
    return max((p for p in folder.iterdir() if p.is_file()), key=lambda p: p.stat().st_size)


def _torch_zip(path: Path, pkl: bytes, storage: bytes | None = None) -> Path:
    """A torch.save-style zip: archive/data.pkl, and archive/data/0 deflated when `storage` is given."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("archive/data.pkl", pkl)
        zf.writestr("archive/byteorder", "little")
        if storage is not None:
            zf.writestr("archive/data/0", storage)
    return path


# ---- the cases ----------------------------------------------------------------------------------------


def case1(d: Path, sh: Shared) -> list[dict]:
    """live --out LOG keeps LOG/forces.csv byte-identical when a second run's source fails to open."""
    log, csv = d / "log", d / "log" / "forces.csv"
    live = ["ffjax.live", "--checkpoint", sh.run, "--out", log, "--headless"]
    good = _cli(d, "good", sh.env, *live, "--video", sh.video)
    before = csv.read_bytes() if csv.is_file() else b""
    names = sorted(os.listdir(log)) if log.is_dir() else []
    rows = [_row("1a", "`live --video GOOD --out LOG`", "rc 0, LOG/forces.csv with a row per frame", good,
                 {"rc 0": good["rc"] == 0, f"{sh.n_frames} csv rows": len(before.splitlines()) == sh.n_frames + 1},
                 key=_line(good["out"], "wrote"), note=f"forces.csv {len(before)} B")]
    for tag, src, what in (("1b", ("--video", d / "mistyped.mp4"), "--video MISSING.mp4"),
                           ("1c", ("--camera", 99), "--camera 99")):
        r = _cli(d, tag, sh.env, *live, *src)
        after = csv.read_bytes() if csv.is_file() else b""
        checks = {**_error_checks(r), "forces.csv byte-identical": after == before,
                  "nothing moved aside": (sorted(os.listdir(log)) if log.is_dir() else []) == names}
        rows.append(_row(tag, f"then `live {what} --out LOG` (same LOG)", "exit 1/2, one error line, "
                         "LOG/forces.csv unchanged", r,
                         checks, note=f"forces.csv {len(before)} B before, {len(after)} B after"))
    return rows


def case2(d: Path, sh: Shared) -> list[dict]:
    """NaN weights are flagged frame by frame without a crash; flipped checkpoint bytes are refused."""
    where = _nan_bundle(sh.run, d / "nan_bundle")
    r = _cli(d, "nan", sh.env, "ffjax.live", "--checkpoint", d / "nan_bundle", "--video", sh.video, "--out",
             d / "log", "--headless")
    faults = _line(r["out"], r"^faults:")
    counted = re.search(r"(\d+) non-finite", faults)
    csv = d / "log" / "forces.csv"
    nan_rows = sum("nan" in ln.split(",")[1:4] for ln in csv.read_text().splitlines()) if csv.is_file() else 0
    n = sh.n_frames
    rows = [_row("2a", f"`live` on a bundle with NaN at {where}[0, 0]", "rc 0, every frame flagged non-finite", r,
                 {"rc 0": r["rc"] == 0, f"{n} [NON-FINITE] lines": r["out"].count("[NON-FINITE]") == n,
                  f"faults line counts {n}": bool(counted) and int(counted.group(1)) == n,
                  f"{n} NaN csv rows": nan_rows == n, "no 'Traceback'": "Traceback" not in r["out"] + r["err"]},
                 key=faults)]
    copy = d / "run_copy"
    shutil.copytree(sh.run, copy)
    target = _largest(next((copy / "best").glob("*/variables/ocdbt.process_0/d")))
    _flip_middle(target)
    r = _cli(d, "flipped", sh.env, "ffjax.live", "--checkpoint", copy, "--video", sh.video, "--headless")
    rows.append(_row("2b", f"`live` on a run copy with 4 bytes flipped in best/.../d/{target.name[:8]}…",
                     "exit 2, one error line 'is corrupt'", r, _error_checks(r, (2,), ["is corrupt"])))
    return rows


def case3(d: Path, sh: Shared) -> list[dict]:
    """calibrate refuses a NaN or negative learning rate and a zero batch before any work."""
    rows = []
    for tag, flag, value in (("3a", "--lr", "nan"), ("3b", "--lr", "-1"), ("3c", "--batch-size", "0")):
        out = d / f"out_{tag}"
        r = _cli(d, tag, sh.env, "ffjax.calibrate", "--checkpoint", d / "run", "--data", d / "calib.csv", "--out",
                 out, flag, value)
        rows.append(_row(tag, f"`calibrate {flag} {value}`", "exit 2, no --out folder", r,
                         {**_error_checks(r, (2,), [flag]), "no --out folder": not out.exists()}))
    return rows


def case4(d: Path, sh: Shared) -> list[dict]:
    """A second training into a folder another one is writing is refused at once; the first is unharmed."""
    run, sets = d / "run", ("train.epochs=15",)
    a = _start(d, "A", sh.env, *_train(sh.data, run, *sets))
    try:
        locked = _wait_until(lambda: (run / ".lock").is_file() and (run / ".lock").stat().st_size > 0, a)
        b = _cli(d, "B", sh.env, *_train(sh.data, run, *sets))
        a_alive = a.poll() is None
    finally:
        ra = _wait(a)
    logged = _log_rows(run)
    steps, total = _summary_steps(run)
    rows = [_row("4a", "`train --out RUN` while training A holds RUN/.lock", "B exits 1 naming A's pid", b,
                 {**_error_checks(b, (1,), [f"is in use by another training run (pid {a.pid} "]),
                  "A held the lock": locked, "A still running": a_alive})]
    rows.append(_row("4b", "training A, after B was refused", "A rc 0, no duplicate log rows", ra,
                     {"rc 0": ra["rc"] == 0, "no duplicate (kind, step)": len(set(logged)) == len(logged) > 0,
                      "all steps done": steps is not None and steps == total},
                     key=_line(ra["out"], r"^run: "), note=f"{len(logged)} log rows, {steps}/{total} steps"))
    return rows


def case5(d: Path, sh: Shared) -> list[dict]:
    """A disk that fills mid-run: one clear error naming an intact step; --resume after freeing space."""
    mnt = d / "tmpfs"
    mnt.mkdir()
    m = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=40m", "tmpfs", str(mnt)], capture_output=True, text=True)
    if m.returncode:
        return [_skipped("5", FULL_DISK[0], FULL_DISK[1], f"mount failed: {(m.stderr or m.stdout).strip()[:200]}")]
    try:
        return _full_disk(d, mnt, sh)
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def _full_disk(d: Path, mnt: Path, sh: Shared) -> list[dict]:
    """Case 5 inside the mounted tmpfs `mnt`: train, fill the disk after the first checkpoint, then resume."""
    run, sets = mnt / "run", ("train.epochs=4", "train.ckpt_every=2")
    p = _start(d, "train", sh.env, *_train(sh.data, run, *sets))
    try:
        saved = _wait_until(lambda: bool(_steps(run / "checkpoints")), p)
        filled = _fill(mnt / "filler")
    finally:
        r = _wait(p)
    last = (r["err"].strip().splitlines() or [""])[-1]
    named = re.search(r"last good checkpoint \(step (\d+)\)", last)
    intact = bool(named) and _loads(run, int(named.group(1)), d / "named_step")
    (mnt / "filler").unlink(missing_ok=True)
    again = _cli(d, "resume", sh.env, *_train(sh.data, run, *sets, extra=["--resume"]))
    steps, total = _summary_steps(run)
    checks = {"checkpoint before the fill": saved, "rc 1": r["rc"] == 1,
              "last line 'error: could not save'": last.startswith("error: could not save"),
              "says 'the disk is full'": "the disk is full" in last, "named step loads": intact,
              "no 'Traceback'": "Traceback" not in r["out"] + r["err"], "resume rc 0": again["rc"] == 0,
              "resume finished": steps is not None and steps == total}
    note = f"filled {filled / 2**20:.1f} MiB; resume rc {again['rc']}, {steps}/{total} steps"
    return [_row("5", *FULL_DISK, r, checks, key=last, note=note)]


def _fill(path: Path, leave: int = 4096) -> int:
    """Write zeros until `leave` bytes are left on path's filesystem (or it refuses); bytes written."""
    st = os.statvfs(path.parent)
    left, written = st.f_bavail * st.f_frsize - leave, 0
    try:
        with open(path, "wb") as f:
            while written < left:
                written += f.write(bytes(min(1 << 20, left - written)))
                f.flush()
    except OSError:
        pass
    return written


def _loads(run: Path, step: int, scratch: Path) -> bool:
    """Does checkpoint `step` of `run` restore, checksums included? (copied alone into `scratch`)"""
    from ffjax import store

    src = run / "checkpoints" / str(step)
    if not src.is_dir():
        return False
    shutil.copytree(src, scratch / "checkpoints" / str(step))
    shutil.copy2(run / "model.json", scratch / "model.json")
    try:
        store.load(scratch, "latest")
    except Exception:  # noqa: BLE001 - any failure to restore means the step is not intact
        return False
    return True


def case6(d: Path, sh: Shared) -> list[dict]:
    """A truncated newest checkpoint: --resume moves it aside and continues from the step before."""
    run = d / "run"
    shutil.copytree(sh.run, run)
    *_, older, newest = _steps(run / "checkpoints")
    target = _largest(run / "checkpoints" / str(newest) / "packed" / "ocdbt.process_0" / "d")
    target.write_bytes(target.read_bytes()[: target.stat().st_size // 2])
    r = _cli(d, "resume", sh.env, *_train(sh.data, run, "train.epochs=3", "train.ckpt_every=3", extra=["--resume"]))
    steps, total = _summary_steps(run)
    text = r["out"] + r["err"]
    return [_row("6", f"truncate the largest state file of checkpoint {newest} to half, `--resume` to 3 epochs",
                 f"rc 0, 'resuming from step {older}', {newest}.corrupt kept", r,
                 {"rc 0": r["rc"] == 0, f"'resuming from step {older}'": f"resuming from step {older}," in text,
                  f"{newest}.corrupt exists": (run / "checkpoints" / f"{newest}.corrupt").is_dir(),
                  "all steps done": steps is not None and steps == total, "no 'Traceback'": "Traceback" not in text},
                 key=_line(text, "resuming from step"), note=f"{steps}/{total} steps")]


def case7_inputs(d: Path, sh: Shared) -> list[dict]:
    """One-line errors for bad paths, flags and files that need no trained model."""
    evil = d / "EVIL.pth"
    evil.write_bytes(pickle.dumps(_Payload()))
    evil_zip = _torch_zip(d / "EVIL_ZIP.pth", pickle.dumps({"w": _Payload()}, protocol=2))
    (d / "FILE").write_text("a regular file\n")
    (d / "empty").mkdir()
    specs = [
        ("7a", "`export --checkpoint MISSING`", ["ffjax.export", "--checkpoint", d / "MISSING", "--out",
                                                 d / "x.jaxexport"], ["MISSING"]),
        ("7b", "`live --checkpoint MISSING`", ["ffjax.live", "--checkpoint", d / "MISSING", "--video",
                                               d / "v.mp4", "--headless"], ["MISSING"]),
        ("7e", "`train --resume` into an empty folder", _train(sh.data, d / "empty", extra=["--resume"]),
         ["nothing to resume"]),
        ("7f", "`train --pretrained MISSING`", _train(sh.data, d / "r_f", extra=["--pretrained", d / "MISSING"]),
         ["--pretrained"]),
        ("7g", "`train --init dinov2:EVIL.pth` (a plain pickle running `echo pwned`)",
         _train(sh.data, d / "r_g", extra=["--init", f"dinov2:{evil}"]), ["EVIL.pth"]),
        ("7h", "`train --init dinov2:EVIL_ZIP.pth` (the same payload in a torch zip)",
         _train(sh.data, d / "r_h", extra=["--init", f"dinov2:{evil_zip}"]), ["EVIL_ZIP.pth"]),
        ("7i", "`train --set train.batch_size=100000`", _train(sh.data, d / "r_i", "train.batch_size=100000"),
         ["batch"]),
        ("7m", "`experiments.ablation --methods bogus`", ["experiments.ablation", "--preset", "smoke", "--data",
                                                          sh.data, "--out", d / "abl", "--methods", "bogus"],
         ["bogus"]),
        ("7n", "`experiments.ablation --out FILE/sub` (FILE a regular file)",
         ["experiments.ablation", "--preset", "smoke", "--data", sh.data, "--out", d / "FILE" / "sub", "--methods",
          METHOD], ["FILE"]),
    ]
    return [_refusal(d, sh.env, *s, absent=("pwned",) if s[0] in ("7g", "7h") else ()) for s in specs]


def _refusal(d: Path, env: dict, tag: str, what: str, args: list, must: list, absent=()) -> dict:
    """Run one command that must fail with a one-line error."""
    r = _cli(d, tag, env, *args)
    return _row(tag, what, ERRORS, r, _error_checks(r, (1, 2), must, absent))


def case7_models(d: Path, sh: Shared) -> list[dict]:
    """One-line errors for a good model with a bad source, and for damaged bundles."""
    live = ["ffjax.live", "--video", sh.video, "--headless", "--checkpoint"]
    no_json = shutil.copytree(sh.run, d / "run_no_model_json")  # checkpoints, but model.json lost
    (no_json / "model.json").unlink()
    damaged = {}
    for name, damage in (("truncated", lambda b: _halve(b / "variables.msgpack")),
                         ("foreign", lambda b: (b / "model.json").write_text('{"hello": 1}')),
                         ("cut", lambda b: _halve(b / "model.json"))):
        damaged[name] = shutil.copytree(sh.bundle, d / f"bundle_{name}")
        damage(damaged[name])
    specs = [
        ("7c", "`live --video MISSING.mp4`", ["ffjax.live", "--checkpoint", sh.run, "--video", d / "MISSING.mp4",
                                              "--headless"], ["MISSING.mp4"]),
        ("7d", "`live --camera 99`", ["ffjax.live", "--checkpoint", sh.run, "--camera", 99, "--headless"],
         ["camera 99"]),
        ("7j", "`live` on a bundle with variables.msgpack cut in half", live + [damaged["truncated"]],
         ["variables.msgpack"]),
        ("7k", "`live` on a bundle whose model.json is `{\"hello\": 1}`", live + [damaged["foreign"]], ["model.json"]),
        ("7l", "`live` on a bundle whose model.json is cut in half", live + [damaged["cut"]], ["model.json"]),
        ("7o", "`train --resume` into a run folder with checkpoints but no model.json",
         _train(sh.data, no_json, extra=["--resume"]), ["model.json"]),
    ]
    return [_refusal(d, sh.env, *s) for s in specs]


def _halve(path: Path) -> None:
    """Cut a file to its first half."""
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def case8(d: Path, sh: Shared) -> list[dict]:
    """Training refuses a 16-bit or a grayscale frame in a CSV split, and a 2x2 render size, before any work."""
    import cv2
    import numpy as np

    rows = []
    for tag, name, frame, must in (("8a", "16-bit", np.full((24, 32, 3), 1500, np.uint16), ["002.png", "uint16",
                                                                                          "8-bit"]),
                                   ("8b", "grayscale", np.full((24, 32), 100, np.uint8), ["002.png", "grayscale"])):
        train_csv, val_csv = _csv_split(d / tag / "train", 6, 0), _csv_split(d / tag / "val", 3, 1)
        cv2.imwrite(str(train_csv.parent / "tactile" / "002.png"), frame)
        out = d / tag / "run"
        r = _cli(d, tag, sh.env, *_train(train_csv, out, extra=["--val", val_csv]))
        rows.append(_row(tag, f"`train --data TRAIN.csv --val VAL.csv`, row 2's frame {name}",
                         "exit 2 naming the file, before any work", r,
                         {**_error_checks(r, (2,), must), "no --out folder": not out.exists()}))
    out = d / "8c_run"
    r = _cli(d, "8c", sh.env, *_train(sh.data, out, "data.render_size=[2,2]"))
    rows.append(_row("8c", "`train --set data.render_size=[2,2]`", "exit 2 (config refused)", r,
                     {**_error_checks(r, (2,), ["render_size"]), "no --out folder": not out.exists()}))
    return rows


def _csv_split(folder: Path, n: int, seed: int) -> Path:
    """A release-layout split: data.csv (tactile, depth, FT), tactile/*.png, depth/*.npy, background.png."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(seed)
    (folder / "tactile").mkdir(parents=True)
    (folder / "depth").mkdir()
    cv2.imwrite(str(folder / "background.png"), np.full((24, 32, 3), 100, np.uint8))
    lines = ["tactile,depth,FT"]
    for i in range(n):
        cv2.imwrite(str(folder / f"tactile/{i:03d}.png"), rng.integers(0, 256, (24, 32, 3), dtype=np.uint8))
        np.save(folder / f"depth/{i:03d}.npy", rng.uniform(0, 1, (24, 32)))
        lines.append(f"tactile/{i:03d}.png,depth/{i:03d}.npy,{i} -{i} {i + 1}.5 0 0 0")
    (folder / "data.csv").write_text("\n".join(lines) + "\n")
    return folder / "data.csv"


def case9(d: Path, sh: Shared) -> list[dict]:
    """Small .pth files declaring huge tensors are refused before anything is allocated: a 32 KiB file whose
    storage inflates to 32 MiB, and a 4-element storage viewed with stride 0 as a 1 GiB tensor."""
    declared = 32 << 20
    bomb = _torch_zip(d / "BOMB.pth", ONE_TENSOR_PKL, bytes(declared))
    wide = _torch_zip(d / "BROADCAST.pth", BROADCAST_PKL, bytes(16))
    # the baseline imports what the train CLI imports before it reads a weight file (configs, ffjax.sim's
    # sensor list, the CLI module): the growth measured is then the file's alone
    base = _cli_rss(d, "baseline", sh.env, "-c", "import ffjax.train.__main__")
    rows = []
    for tag, path, size, what in (("9a", bomb, declared, "a storage inflating to"),
                                  ("9b", wide, 4 * BROADCAST_N, "a stride-0 tensor of")):
        out = d / f"run_{tag}"
        r = _cli_rss(d, tag, sh.env, "-m", *_train(sh.data, out, extra=["--init", f"dinov2:{path}"]))
        grew = r["peak_mib"] - base["peak_mib"]
        rows.append(_row(tag, f"`train --init dinov2:{path.name}` ({path.stat().st_size / 1024:.1f} KiB file, {what} "
                         f"{size >> 20} MiB)", "exit 2 'declares … more than the whole file'; peak RSS far below "
                         f"baseline + {size >> 20} MiB", r,
                         {**_error_checks(r, (2,), [path.name, "declares", "more than the whole file"]),
                          "baseline rc 0": base["rc"] == 0, "peak RSS < baseline + 8 MiB": grew < 8,
                          "no --out folder": not out.exists()},
                         note=f"peak RSS {r['peak_mib']:.0f} MiB vs {base['peak_mib']:.0f} MiB for a bare "
                         f"`import ffjax.train.__main__` (+{grew:.1f} MiB)"))
    return rows


def release_csv(folder: Path, n: int = 6, h: int = 12, w: int = 16, seed: int = 0) -> Path:
    """A release-layout split of n random frames: data.csv (tactile, depth, FT "i -i i+1.5 0 0 0"), tactile/*.png,
    depth/*.npy, background.png; its data.csv."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(seed)
    (folder / "tactile").mkdir(parents=True)
    (folder / "depth").mkdir()
    cv2.imwrite(str(folder / "background.png"), np.full((h, w, 3), 100, np.uint8))
    lines = ["tactile,depth,FT"]
    for i in range(n):
        cv2.imwrite(str(folder / f"tactile/{i:03d}.png"), rng.integers(0, 256, (h, w, 3), dtype=np.uint8))
        np.save(folder / f"depth/{i:03d}.npy", rng.uniform(0, 1, (h, w)))
        lines.append(f"tactile/{i:03d}.png,depth/{i:03d}.npy,{i} -{i} {i + 1}.5 0 0 0")
    (folder / "data.csv").write_text("\n".join(lines) + "\n")
    return folder / "data.csv"


def _csv_variant(d: Path, name: str, edit) -> Path:
    """A fresh CSV split under d/name with edit(folder, lines) -> lines applied to its data.csv."""
    csv = release_csv(d / name)
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(edit(csv.parent, lines)) + "\n")
    return csv


def case33(d: Path, sh: Shared) -> list[dict]:
    """Issue 33's cases a user meets without a trained model: labels, CSV layout, folders, --out."""
    import cv2
    import numpy as np

    from ffjax.files import folder_lock

    def implausible(f, lines):
        return lines[:3] + ["tactile/002.png,depth/002.npy,1e30 2 3 0 0 0"] + lines[4:]

    def twice(f, lines):
        return ["tactile,depth,FT,FT"] + [f"{ln},0 0 0 0 0 0" for ln in lines[1:]]

    def alias(f, lines):
        os.symlink(f / "tactile/002.png", f / "tactile/alias.png")
        return lines[:5] + ["tactile/alias.png,depth/004.npy,9 9 9 0 0 0"] + lines[6:]

    def two_sizes(f, lines):
        (f / "background.png").rename(f / "bg_a.png")
        cv2.imwrite(str(f / "bg_b.png"), np.full((16, 16, 3), 100, np.uint8))
        cv2.imwrite(str(f / "tactile/005.png"), np.full((16, 16, 3), 120, np.uint8))
        np.save(f / "depth/005.npy", np.zeros((16, 16)))
        return (["tactile,depth,FT,background"] + [ln + ",bg_a.png" for ln in lines[1:-1]]
                + [lines[-1] + ",bg_b.png"])

    (d / "FILE").write_text("a regular file\n")
    specs = [
        ("33-2", "`train --data BAD.csv`, one FT row `1e30 2 3 0 0 0`", _train(_csv_variant(d, "s2", implausible),
                                                                              d / "r2"), ["row 2", "beyond 200 N"]),
        ("33-3", "`train --data X.csv` whose header is `tactile,depth,FT,FT`",
         _train(_csv_variant(d, "s3", twice), d / "r3"), ["'FT' (columns 3, 4)"]),
        ("33-4", "`train --data X.csv`, a row naming a symlink to another row's frame with other labels",
         _train(_csv_variant(d, "s4", alias), d / "r4"), ["duplicate row", "alias.png"]),
        ("33-7a", "`train --data X.csv` with per-row backgrounds of two sizes",
         _train(_csv_variant(d, "s7", two_sizes), d / "r7"), ["bg_a.png", "bg_b.png"]),
        ("33-7b", "`live --out FILE/sub` (FILE a regular file)",
         ["ffjax.live", "--checkpoint", d / "MISSING", "--camera", "0", "--out", d / "FILE" / "sub"], ["--out"]),
        ("33-7c", "`calibrate --out FILE/sub`", ["ffjax.calibrate", "--checkpoint", d / "MISSING", "--data",
                                                 d / "x.csv", "--out", d / "FILE" / "sub"], ["--out"]),
    ]
    rows = [_refusal(d, sh.env, *s) for s in specs]
    # a second writer into a dataset folder another process is writing (this harness holds its lock)
    with folder_lock(d / "busy", "dataset generation"):
        r = _cli(d, "33-5", sh.env, "ffjax.simulate", "--preset", "smoke", "--out", d / "busy", "--quiet")
    rows.append(_row("33-5", "`simulate --out DATA` while another generation writes DATA",
                     "rc 1, one error line naming the holder; nothing written", r,
                     {**_error_checks(r, (1,), ["in use by another dataset generation"]),
                      "nothing written": sorted(os.listdir(d / "busy")) == []}))
    return rows


def case33_models(d: Path, sh: Shared) -> list[dict]:
    """Issue 33's cases with a trained model: a bad frame_size, a non-UTF-8 run path, an empty source, Ctrl-C."""
    import signal

    bad = d / "bad_size"
    shutil.copytree(sh.bundle, bad)
    info = json.loads((bad / "model.json").read_text())
    info["frame_size"] = 5
    info.pop("sha256", None)  # as a model.json written before it carried its checksum (still read)
    (bad / "model.json").write_text(json.dumps(info))
    latin = Path(os.fsdecode(os.fsencode(d) + b"/run\xe9"))
    shutil.copytree(sh.run, latin)
    specs = [
        ("33-7d", "`live` with model.json `\"frame_size\": 5`", ["ffjax.live", "--checkpoint", bad, "--camera", "0",
                                                                "--headless"], ['"frame_size" is 5']),
        ("33-7e", "`live --checkpoint RUN` where RUN's name holds a Latin-1 byte",
         ["ffjax.live", "--checkpoint", latin, "--video", sh.video, "--headless"], ["not UTF-8"]),
    ]
    rows = [_refusal(d, sh.env, *s) for s in specs]
    r = _cli(d, "33-7f", sh.env, "ffjax.live", "--checkpoint", sh.bundle, "--video", sh.video, "--headless",
             "--warmup", 1000, "--out", d / "empty")
    rows.append(_row("33-7f", "`live --video V --warmup 1000 --out O` (the video ends before a background)",
                     "rc 1, one error line, nothing written", r,
                     {**_error_checks(r, (1,), ["no frame to predict"]),
                      "no forces.csv": not (d / "empty" / "forces.csv").exists(),
                      "no 'wrote'": "wrote" not in r["out"]}))
    p = _start(d, "33-7g", sh.env, "ffjax.simulate", "--preset", "smoke", "--out", d / "data", "--workers", 2,
               "--quiet", "--set", "data.shard_size=8", group=True)  # small shards: most work still ahead at Ctrl-C
    if _wait_until(lambda: bool(list((d / "data").rglob("shard_*.npz"))), p) and p.poll() is None:
        os.killpg(p.pid, signal.SIGINT)
    r = _wait(p)
    rows.append(_row("33-7g", "Ctrl-C (SIGINT to the process group) while `simulate --workers 2` renders",
                     "rc 130, one line, finished shards kept", r,
                     {"rc 130": r["rc"] == 130, "one line": r["err"].strip().splitlines() == ["interrupted"],
                      "no 'Traceback'": "Traceback" not in r["err"],
                      "shards kept": bool(list((d / "data").rglob("shard_*.npz")))}))
    return rows



# Issue 33's Python-API cases, run in a fresh interpreter against the shared bundle; prints one JSON object.
_API_SCRIPT = """
import json, sys, warnings
import cv2, numpy as np
from ffjax import export, inference

bundle, split, exported = sys.argv[1:4]
frames = np.load(sorted(__import__("pathlib").Path(split).glob("shard_*.npz"))[0])["image"][:2]
bg = np.ascontiguousarray(cv2.imread(split + "/background.png")[..., ::-1])
warnings.simplefilter("ignore")
out = {}
p = inference.load(bundle)
buf = bg.copy()
p.set_background(buf)
before = p.predict(frames)
buf[:] = 0  # a camera reading its next frame into the same buffer
out["unchanged"] = bool(np.array_equal(p.predict(frames), before))
try:
    p.background[0, 0, 0] = 1
    out["read_only"] = False
except ValueError:
    out["read_only"] = True
out["depth_of_0"] = list(p.predict_depth(frames[:0]).shape)
out["forces_of_0"] = list(p.predict(frames[:0]).shape)
export.save(p, exported, batch=1)
fn = export.load(exported)
rgba = np.concatenate([frames[:1], frames[:1, ..., :1]], -1)
for name, args in (("batch_2", (frames, bg)), ("rgba", (rgba, bg)), ("gray_background", (frames[:1], bg[..., 0]))):
    try:
        fn(*args)
        out[name] = "no error"
    except ValueError as e:
        out[name] = "ValueError: " + str(e)
    except Exception as e:
        out[name] = type(e).__name__ + ": " + str(e)[:200]
out["export_of_0"] = list(fn(frames[:0], bg).shape)
print(json.dumps(out))
"""


def case33_api(d: Path, sh: Shared) -> list[dict]:
    """Issue 33's Python-API cases (a kept background, 0 frames, export misuse) and live on a real full disk."""
    r = _cli(d, "33-api", sh.env, "-c", _API_SCRIPT, sh.bundle, sh.data / "val", d / "f1.jaxexport", module=False)
    got = json.loads((r["out"].strip().splitlines() or ["{}"])[-1]) if r["rc"] == 0 else {}
    size = list(json.loads((sh.bundle / "model.json").read_text())["frame_size"])
    no_tb = {"no 'Traceback'": "Traceback" not in r["err"]}
    rows = [
        _row("33-1", "`Predictor.set_background(buf)`, then `buf[:] = 0`", "later predictions unchanged; "
             "the kept background read-only", r, {"rc 0": r["rc"] == 0, "predictions unchanged": got.get("unchanged")
                                                   is True, "read-only": got.get("read_only") is True},
             key=f"unchanged: {got.get('unchanged')}, read-only: {got.get('read_only')}"),
        _row("33-7h", "`predict_depth` and `predict` on 0 frames", f"shapes (0, {size[0]}, {size[1]}) and (0, 3)",
             r, {"depth (0, H, W)": got.get("depth_of_0") == [0, *size], "forces (0, 3)": got.get("forces_of_0") ==
                 [0, 3], **no_tb}, key=f"depth {got.get('depth_of_0')}, forces {got.get('forces_of_0')}")]
    for tag, case, must in (("33-7i", "batch_2", ["f1.jaxexport", "batches of exactly 1", "--batch 0"]),
                            ("33-7j", "rgba", ["f1.jaxexport", "alpha"]),
                            ("33-7k", "gray_background", ["f1.jaxexport", "background must be (H, W, 3)"])):
        msg = got.get(case, "")
        what = {"batch_2": "a `--batch 1` export called with 2 frames", "rgba": "an export called with RGBA frames",
                "gray_background": "an export called with a one-channel background"}[case]
        rows.append(_row(tag, what, "ValueError naming the file and the fix", r,
                         {"ValueError": msg.startswith("ValueError"), **{f"says '{m}'": m in msg for m in must}},
                         key=msg[:240]))
    rows.append(_row("33-7l", "an export called with 0 frames", "shape (0, 3)", r,
                     {"(0, 3)": got.get("export_of_0") == [0, 3]}, key=f"{got.get('export_of_0')}"))
    return rows + _live_full_disk(d, sh) + [_data_home(d, sh)]


def _data_home(d: Path, sh: Shared) -> dict:
    """Issue 33 (8): `ffjax.train` without --data, started from another folder, simulates into $FFJAX_DATA."""
    work, cache = d / "work", d / "cache"
    work.mkdir()
    smoke = (*SMALL_DATA, "train.epochs=1")
    p = _start(d, "33-8", {**sh.env, "FFJAX_DATA": str(cache), "PYTHONPATH": str(common.ROOT)}, "ffjax.train",
               "--preset", "smoke", "--method", METHOD, "--out", d / "run", "--quiet",
               *(a for s in smoke for a in ("--set", s)), cwd=work)
    r = _wait(p)
    made = sorted(str(x.relative_to(d)) for x in work.rglob("*"))
    return _row("33-8", "`ffjax.train --preset smoke` without --data, started in an empty folder, FFJAX_DATA=CACHE",
                "rc 0; the dataset in CACHE/smoke; nothing in the working folder", r,
                {"rc 0": r["rc"] == 0, "shards in CACHE/smoke": bool(list((cache / "smoke").rglob("shard_*.npz"))),
                 "working folder empty": not made}, key=f"working folder: {made or 'empty'}")


LIVE_FULL = ("`live --video V --out O` with O on a 1 MiB tmpfs filled to 8 KiB free",
             "rc 1, one error line naming the file; forces.csv whole rows only; no OpenCV write warnings")


def _live_full_disk(d: Path, sh: Shared) -> list[dict]:
    """Issue 33 (6) on a real full disk: a 1 MiB tmpfs (root only; skipped where mounting fails)."""
    import csv

    mnt = d / "tmpfs"
    mnt.mkdir()
    m = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], capture_output=True, text=True)
    if m.returncode:
        return [_skipped("33-6", *LIVE_FULL, f"mount failed: {(m.stderr or m.stdout).strip()[:200]}")]
    try:
        _fill(mnt / "filler", leave=8 << 10)
        r = _cli(d, "33-6", sh.env, "ffjax.live", "--checkpoint", sh.bundle, "--video", sh.video, "--headless",
                 "--print-every", 0, "--out", mnt / "out")
        path = mnt / "out" / "forces.csv"
        text = path.read_bytes().decode(errors="replace") if path.is_file() else ""
        lines = list(csv.reader(text.splitlines()))
        whole = bool(lines) and text.endswith("\n") and all(len(ln) == len(lines[0]) for ln in lines)
        checks = {**_error_checks(r, (1,), ["no space left", str(mnt / "out")]), "whole rows": whole,
                  "no 'Failed to write'": "Failed to write" not in r["err"]}
        return [_row("33-6", *LIVE_FULL, r, checks, note=f"forces.csv: {max(len(lines) - 1, 0)} rows")]
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)

CASES = [("1", case1), ("2", case2), ("3", case3), ("4", case4), ("5", case5), ("6", case6), ("7", case7_inputs),
         ("7", case7_models), ("8", case8), ("9", case9), ("33", case33), ("33", case33_models), ("33", case33_api)]


# ---- driver and report --------------------------------------------------------------------------------


def run_cases(out: Path, env: dict, progress: bool) -> list[dict]:
    """Build the shared fixtures, run every case in OUT/cases/<its function>/, return the rows (sorted by case)."""
    root = out / "cases"
    if progress:
        print("faults cases: building the shared fixtures (a dataset, a 2-epoch run, a bundle, a video)",
              file=sys.stderr, flush=True)
    sh = build_shared(root / "_shared", env)
    rows = []
    for name, fn in tqdm(CASES, desc="faults cases", disable=not progress):
        rows += run_case(fn, root / fn.__name__, sh, name)
    return [_shorten(r, out) for r in sorted(rows, key=lambda r: r["case"])]


def run_case(fn, folder: Path, sh: Shared, name: str) -> list[dict]:
    """fn's rows, run in a fresh `folder`; a harness exception is a failing row (traceback in folder/error.txt)."""
    _clear(folder)
    folder.mkdir(parents=True)
    try:
        return fn(folder, sh)
    except Exception as e:  # noqa: BLE001 - reported as this case's failure, the other cases still run
        (folder / "error.txt").write_text(traceback.format_exc())
        res = {"rc": None, "out": "", "err": f"harness error: {type(e).__name__}: {e}", "cmd": "", "seconds": None}
        return [_row(name, fn.__doc__.splitlines()[0], "", res, {"harness ran": False})]


def _shorten(row: dict, out: Path) -> dict:
    """Paths under `out` as OUT/... in the texts a report shows."""
    for k in ("key_line", "note", "cmd", "what"):
        if isinstance(row.get(k), str):
            row[k] = row[k].replace(str(out), "OUT")
    return row


def _clear(folder: Path) -> None:
    """Remove `folder` and everything in it, if it exists."""
    if folder.exists():
        shutil.rmtree(folder)


def _code(text: str, limit: int = 240) -> str:
    """`text` as a Markdown table cell's code span; a longer one keeps its first and last limit/2 characters."""
    text = text if len(text) <= limit else text[: limit // 2] + " … " + text[-limit // 2:]
    return "`` " + text.replace("``", "` `") + " ``" if text else "–"


def _measured(row: dict) -> str:
    """The measured cell: rc, stderr line count, key line, note and every check with its outcome."""
    if row.get("skipped"):
        return f"skipped: {row['skipped']}"
    checks = ", ".join(f"{k} {'✓' if v else '✗'}" for k, v in row["checks"].items())
    note = f"; {row['note']}" if row["note"] else ""
    return f"rc {row['rc']}, {row['stderr_lines']} stderr line(s): {_code(row['key_line'])}{note}; checks: {checks}"


def cases_md(rows: list[dict]) -> str:
    """The rows as a Markdown table (case | what was done | expected | measured | pass) and a count."""
    head = ["case", "what was done", "expected", "measured (rc, stderr lines, the key line, checks)", "pass"]
    table = [[c.replace("|", "\\|") for c in (r["case"], r["what"], r["expected"], _measured(r))]
             + ["skipped" if r["pass"] is None else "yes" if r["pass"] else "**NO**"] for r in rows]
    passed = sum(r["pass"] is True for r in rows)
    skipped = sum(r["pass"] is None for r in rows)
    return common.md_table(head, table) + (f"\n{passed} of {len(rows)} commands pass"
                                           + (f", {skipped} skipped" if skipped else "") + ".\n")
