"""One tiny smoke-preset training run on simulated presses, shared by the inference/live/calibrate/export
tests: trained once per pytest run (a module-level cache; a file lock shares it between xdist workers); and
`shared`, any folder a test module builds once per run for every worker."""

from __future__ import annotations

import atexit
import fcntl
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

import configs
from ffjax import sim
from ffjax.data.images import write_rgb

METHOD = "dino_rd"  # the same smoke model as test_train / test_resume: its train step is already compiled
SENSOR = "mini-1"
_CACHE: dict = {}


def frame_size() -> tuple[int, int]:
    return tuple(configs.get("smoke")["data"]["render_size"])


def presses(n: int, seed: int, shape: str = "sphere_big", fz_max: float = 12.0) -> dict:
    """n simulated presses (random Fx, Fy in +-1 N, Fz in 0.5..fz_max N) on mini-1 at the smoke frame size:
    {"image" (n,H,W,3), "depth", "force" (n,3), "background" (H,W,3)} — RGB uint8 like a camera."""
    rng = np.random.default_rng(seed)
    f = np.stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), rng.uniform(0.5, fz_max, n)], 1)
    xy = rng.uniform(-3, 3, (n, 2))
    return sim.press_batch(shape, SENSOR, f, x_mm=xy[:, 0], y_mm=xy[:, 1], seeds=np.arange(n) + 1000 * seed,
                           size=frame_size())


def write_split(path: Path, n: int, seed: int) -> None:
    b = presses(n, seed)
    path.mkdir(parents=True)
    np.savez(path / "shard_00000.npz", image=b["image"], depth=b["depth"], force=b["force"],
             shape=np.array(["sphere_big"] * n))
    write_rgb(path / "background.png", b["background"])


def tmp_root() -> Path:
    """Per pytest run: under pytest-xdist all workers share one folder (keyed by the run's uid), so the
    model is trained once, by whichever worker asks first, while the others wait on a file lock."""
    if "root" not in _CACHE:
        uid = os.environ.get("PYTEST_XDIST_TESTRUNUID")
        if uid is None:
            root = Path(tempfile.mkdtemp(prefix="ffjax_smoke_"))
            atexit.register(shutil.rmtree, root, ignore_errors=True)
        else:  # shared by the workers, so nobody may delete it at exit: sweep day-old ones instead
            base = Path(tempfile.gettempdir())
            for old in base.glob("ffjax_smoke_xdist_*"):
                if time.time() - old.stat().st_mtime > 86400:
                    shutil.rmtree(old, ignore_errors=True)
            root = base / f"ffjax_smoke_xdist_{uid}"
            root.mkdir(exist_ok=True)
        _CACHE["root"] = root
    return _CACHE["root"]


def shared(name: str, build) -> tuple[Path, object]:
    """(folder, value): `build(folder)` run once per pytest run, by whichever xdist worker asks first, while the
    others wait on a file lock; its value is kept beside the folder as JSON (numbers exactly, anything else as
    text). A test that changes the folder must work on a copy."""
    if name not in _CACHE:
        root = tmp_root()
        folder, done = root / name, root / f"{name}.json"
        with open(root / f"{name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            try:
                if not done.exists():
                    shutil.rmtree(folder, ignore_errors=True)
                    folder.mkdir()
                    done.write_text(json.dumps({"value": build(folder)}, default=str))
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)
        _CACHE[name] = (folder, json.loads(done.read_text())["value"])
    return _CACHE[name]


def smoke_data() -> Path:
    """The smoke preset's whole dataset with its pretraining corpus and both pretrained backbones (what
    `experiments.ablation --preset smoke` makes before it trains), made once per test run for every worker. Read it,
    or copy it (shutil.copytree) where a command may write into its data folder."""
    def build(folder: Path) -> str:
        from experiments import common, kernel

        cfg, kinds = configs.get("smoke"), ["resnet", "vit"]
        root = common.ensure_data(cfg, folder, progress=False)
        kernel.pretraining_corpus(cfg, kinds, root, False, False)
        for kind in kinds:
            kernel.pretrained_backbone(cfg, kind, root, False, False)
        return str(root)

    return Path(shared("smoke_data", build)[1])


def smoke_run() -> Path:
    """Path of a trained smoke run folder (one epoch of 2 steps on 16 presses; numbers mean nothing)."""
    if "run" not in _CACHE:
        from ffjax import train

        root = tmp_root()
        with open(root / "lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            try:
                if not (root / "run" / "DONE").exists():
                    shutil.rmtree(root / "data", ignore_errors=True)
                    shutil.rmtree(root / "run", ignore_errors=True)
                    write_split(root / "data" / "train", 16, 0)
                    write_split(root / "data" / "val", 8, 1)
                    cfg = configs.get("smoke", {"train.epochs": 1})
                    train.train(cfg, METHOD, root / "data", root / "run", progress=False)
                    (root / "run" / "DONE").touch()
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)
        _CACHE["run"] = root / "run"
    return _CACHE["run"]
