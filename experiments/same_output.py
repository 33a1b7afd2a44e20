"""Whether a change to the simulator changed what it renders: the same presses rendered by the code of a base commit
and by HEAD, compared byte for byte; --certify records a match, so `experiments.status` does not count those
commits' changes to the simulator as changes of any result's numbers.

    python -m experiments.same_output --base REV [--certify]

The presses: every indenter and unseen object on the training sensor and every indenter on every other sensor, at
two forces and poses each, by both loadings (the oblique press in 4 and 2 steps, pressed-then-pushed), at two
render sizes, presses the simulator refuses (what it says must match too), and the first shards of a dataset's
splits (its sampling, pulls and F/T noise) at the smoke preset; images, depth, forces and every label compared.
Each revision renders in its own process, the base from a temporary git worktree, so HEAD's code cannot leak
into it. Same bytes on the same machine is the claim (the simulator is deterministic there); a speed-up that
keeps them lets the results stand, while the benchmarks that time the simulator are still stale (their
numbers are its speed: experiments.catalog's `speed`).

Certifications are kept in experiments/same_output.json: each names the base, the head and the simulator files
the commits between changed. Exit 1 when the outputs differ.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from experiments import common

# what the check can vouch for: the code that turns a press request into a frame and its labels
SIM_FILES = ("ffjax/sim/",)
RECORD = common.ROOT / "experiments" / "same_output.json"

# Run in each revision's own process and checkout (cwd first on sys.path): only the simulator's public API, which
# every revision since the batched solves has. Prints one JSON line {label: sha256 of that press's outputs}.
_RENDER = r"""
import hashlib, json, sys
import numpy as np
from ffjax import sim
from ffjax.sim import batched, dataset
import configs

small = sys.argv[1] == "small"
try:  # the compile cache's one home since it moved out of the simulator
    from ffjax import compile_cache
    compile_cache.enable()
except ImportError:
    batched.use_disk_cache()
digests = {}

def digest(label, s):
    h = hashlib.sha256()
    if isinstance(s, ValueError):
        h.update(b"refused:" + str(s).encode())
    else:
        for a in (s.image, s.depth, s.force):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(json.dumps(s.meta, sort_keys=True, default=repr).encode())
    digests[label] = h.hexdigest()

rng = np.random.default_rng(7)
train = "mini-1-gel1"
sensors = [train] if small else list(sim.SENSOR_NAMES)
sizes = [(24, 32)] if small else [(24, 32), (48, 64)]
loadings = [("oblique", 2)] if small else [("oblique", 4), ("oblique", 2), ("shear", 4)]
for key in sensors:
    shapes = list(sim.INDENTERS)[: 3 if small else None]
    if key == train and not small:
        shapes += list(sim.UNSEEN_OBJECTS)
    per = 1 if small else 2
    names = [s for s in shapes for _ in range(per)]
    n = len(names) + 1  # and one the gel cannot take
    fz = np.append(rng.uniform(0.2, 15.0, n - 1), 400.0)
    tilt = rng.uniform(-7.0, 7.0, (n, 2))
    x, y, yaw = rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(-180, 180, n)
    names.append(names[0])
    for size in sizes:
        for path, steps in loadings:
            forces = np.column_stack([np.zeros((n, 2)), fz])
            if path == "shear":
                forces[:, :2] = fz[:, None] * np.tan(np.radians(tilt)) * 0.7
            got = sim.press_many(names, key, forces, x, y, yaw, [tuple(t) for t in tilt], list(range(n)), size,
                                 path=path, steps=steps)
            for i, s in enumerate(got):
                digest(f"{key} {size[0]}x{size[1]} {path}/{steps} #{i} {names[i]}", s)
digest("press() one centred sphere", sim.press("sphere_small", train, (0.0, 0.0, 3.0), size=(24, 32)))
cfg = configs.get("smoke")
g = dataset.gen_config(cfg)
for spec in dataset.split_specs(cfg)[:: 1 if not small else 8]:
    p = dataset.sample_presses(spec, cfg)
    hi = min(spec.count, 4 if small else 8)
    shard = dataset.render_shard(spec, p, 0, hi, g["data"]["render_size"], g["data"])
    h = hashlib.sha256()
    for k in sorted(shard):
        h.update(k.encode() + np.ascontiguousarray(shard[k]).tobytes())
    digests[f"dataset smoke {spec.name} [0, {hi})"] = h.hexdigest()
print(json.dumps(digests))
"""


def _git(*args, cwd=None) -> str:
    return subprocess.run(["git", *args], cwd=cwd or common.ROOT, capture_output=True, text=True,
                          check=True).stdout.strip()


def render(checkout: Path, small: bool = False) -> dict:
    """{press label: digest} of the check's presses rendered by the code in `checkout`, in a fresh process."""
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    r = subprocess.run([sys.executable, "-c", _RENDER, "small" if small else "all"], cwd=checkout, env=env,
                       capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(f"rendering with the code at {checkout} failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def compare(base: dict, head: dict) -> dict:
    """The labels whose outputs differ, or that one side rendered and the other did not."""
    differ = sorted(k for k in base.keys() & head.keys() if base[k] != head[k])
    only = sorted(base.keys() ^ head.keys())
    return {"presses": len(base.keys() & head.keys()), "differ": differ, "only_one_side": only,
            "same": not differ and not only}


def changed_sim_files(base: str, head: str) -> list[str]:
    """The simulator's files that the commits base..head change."""
    out = _git("diff", "--name-only", base, head, "--", *SIM_FILES)
    return sorted(out.splitlines()) if out else []


def check(base: str, small: bool = False) -> dict:
    """Render at `base` and at HEAD, each from a temporary worktree (committed code only), and compare."""
    base_sha, head_sha = _git("rev-parse", f"{base}^{{commit}}"), _git("rev-parse", "HEAD")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for sha, where in ((base_sha, "base"), (head_sha, "head")):
            _git("worktree", "add", "--detach", "-q", str(Path(tmp) / where), sha)
        try:
            got = {k: render(Path(tmp) / k, small) for k in ("base", "head")}
        finally:
            for where in ("base", "head"):
                subprocess.run(["git", "worktree", "remove", "--force", str(Path(tmp) / where)], cwd=common.ROOT,
                               capture_output=True)
    return {"base": base_sha, "head": head_sha, "files": changed_sim_files(base_sha, head_sha),
            **compare(got["base"], got["head"]), "seconds": round(time.perf_counter() - t0, 1),
            "machine": _machine()}


def _machine() -> str:
    m = common.machine()
    return f"{m['cpu_model']}, {m['cores']} cores"


def certificates(root=None) -> list[dict]:
    """The recorded certificates (base, head, files), oldest first."""
    path = Path(root) / "experiments" / "same_output.json" if root else RECORD
    return (common.read_json(path) or {}).get("certified", [])


def certify(result: dict) -> None:
    """Append a passed check to the record (atomically)."""
    record = common.read_json(RECORD) or {"certified": []}
    keep = ("base", "head", "files", "presses", "seconds", "machine")
    record["certified"].append({k: result[k] for k in keep} | {"date": time.strftime("%Y-%m-%d")})
    common.write_text(RECORD, json.dumps(record, indent=1) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog=common.prog(), description=common.description(__doc__))
    ap.add_argument("--base", required=True, help="the commit to compare HEAD with (e.g. HEAD~1)")
    ap.add_argument("--certify", action="store_true",
                    help=f"on a match, record it in {RECORD.relative_to(common.ROOT)} (commit that file)")
    ap.add_argument("--small", action="store_true", help="a few presses on one sensor (a smoke check)")
    args = ap.parse_args(argv)
    if args.certify and _git("status", "--porcelain", "--untracked-files=no", "--", *SIM_FILES):
        raise SystemExit("the simulator has uncommitted changes: commit them first (a certificate names commits)")
    r = check(args.base, args.small)
    files = ", ".join(r["files"]) or "none"
    print(f"{r['presses']} presses and dataset shards, base {r['base'][:7]} vs HEAD {r['head'][:7]} "
          f"(simulator files changed: {files}), {r['seconds']:.0f} s")
    if not r["same"]:
        for label in (r["differ"] + r["only_one_side"])[:20]:
            print(f"  differs: {label}")
        print(f"outputs differ ({len(r['differ'])} presses, {len(r['only_one_side'])} on one side only)")
        return 1
    print("same bytes")
    if args.certify:
        if args.small:
            ap.error("--certify needs the whole check (without --small)")
        if not r["files"]:
            print("nothing to certify: the simulator's files did not change")
        else:
            certify(r)
            print(f"recorded in {RECORD.relative_to(common.ROOT)}")
    return 0


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
