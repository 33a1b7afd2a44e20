"""Faults: SIGKILL + resume loses nothing (training, dataset generation), a full or unwritable output
folder fails with a message and keeps the last good checkpoint, a non-finite step stops (naming the step
and batch) or is skipped."""

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest
from _tiny_data import write_tiny_dataset

import configs
from ffjax import store, train
from ffjax.errors import WriteError
from ffjax.store import checkpoints as ckpt_lib
from ffjax.train import loop as loop_lib
from ffjax.train import nonfinite

METHOD = "dino_rd"  # the smoke model test_train / test_resume compile too
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return write_tiny_dataset(tmp_path_factory.mktemp("rel_data"), 32, 8)


def _cfg(**kw):
    # 4 steps an epoch; checkpoints every 3 steps and at epoch ends
    return configs.get("smoke", {"train.epochs": 3, "train.ckpt_every": 3, **kw})


def _leaves(tree):
    return [np.asarray(x) for x in jax.tree.leaves(jax.device_get(tree))]


def _same(a, b):
    la, lb = _leaves(a), _leaves(b)
    return len(la) == len(lb) and all(np.array_equal(x, y) for x, y in zip(la, lb))


@pytest.fixture(scope="module")
def reference(data, tmp_path_factory):
    return train.train(_cfg(), METHOD, data, tmp_path_factory.mktemp("rel_ref"), progress=False)


def _env(tmp):
    env = dict(os.environ)  # the suite's compile cache (FFJAX_CACHE): the commands load what the tests compiled
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    return env


def _kill_when(cmd, env, ready, timeout=240.0) -> bool:
    """Run cmd; SIGKILL it as soon as ready() holds. True when it was killed while still running."""
    p = subprocess.Popen(cmd, env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    t0 = time.monotonic()
    while p.poll() is None and time.monotonic() - t0 < timeout:
        if ready():
            p.send_signal(signal.SIGKILL)
            p.wait()
            return True
        time.sleep(0.005)
    p.wait()
    return False


def _ckpt_steps(run: Path) -> list[int]:
    folder = run / "checkpoints"
    return sorted(int(p.name) for p in folder.iterdir() if p.name.isdigit()) if folder.is_dir() else []


def test_sigkill_twice_then_resume_equals_uninterrupted(data, reference, tmp_path):
    """Two SIGKILLs mid-training (each right after a new checkpoint appears), then a resume to the end: params,
    best checkpoint, validation metrics and every logged loss are bitwise those of an uninterrupted run."""
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "ffjax.train", "--preset", "smoke", "--method", METHOD, "--data", str(data),
           "--out", str(run), "--resume=auto", "--quiet", "--set", "train.epochs=3", "--set", "train.ckpt_every=3"]
    env = _env(tmp_path)
    seen = []
    for _ in range(2):
        before = _ckpt_steps(run)[-1:] or [0]
        _kill_when(cmd, env, lambda b=before[0]: any(s > b for s in _ckpt_steps(run)))
        seen.append(_ckpt_steps(run))
        # after every kill the newest checkpoint loads (a kill never leaves a broken one)
        store.load(run, which="latest")
    assert subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True).returncode == 0, seen
    summary = json.loads((run / "summary.json").read_text())
    assert summary["steps"] == 12 and summary["val"] == json.loads(json.dumps(reference["val"]))
    assert _same(store.load(run, "latest").variables, reference["state"].variables())
    ref_best = store.load(reference["run_dir"], "best").variables
    assert _same(store.load(run, "best").variables, ref_best)

    def rows(folder):
        return [(r["kind"], r["step"], r.get("loss")) for r in map(json.loads, open(Path(folder) / "train_log.jsonl"))]

    assert rows(run) == rows(reference["run_dir"])


def test_torn_log_line_is_dropped_on_resume(data, reference, tmp_path):
    train.train(_cfg(), METHOD, data, tmp_path, progress=False, max_steps=6)
    with open(tmp_path / "train_log.jsonl", "a") as f:
        f.write('{"kind": "train", "step": 7, "lo')  # what a kill mid-write leaves
    done = train.train(_cfg(), METHOD, data, tmp_path, resume=True, progress=False)
    assert _same(done["state"].params, reference["state"].params)
    steps = [json.loads(r)["step"] for r in open(tmp_path / "train_log.jsonl") if '"train"' in r]
    assert steps == list(range(1, 13))


def test_sigkill_dataset_generation_keeps_finished_shards(tmp_path):
    from ffjax.sim import dataset

    sets = ["data.shard_size=16", "data.train_per_indenter=6", "data.unseen_per_object=2",
            "data.sensor_test_per_indenter=1", "data.calib_samples=4"]
    cfg = configs.get("smoke", dict(configs.parse_override(s) for s in sets))
    ref = tmp_path / "ref"
    dataset.generate(cfg, ref, progress=False)
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "ffjax.simulate", "--preset", "smoke", "--out", str(out), "--quiet",
           "--workers", "1"] + [a for s in sets for a in ("--set", s)]
    shards = lambda: sorted(out.rglob("shard_*.npz"))  # noqa: E731
    _kill_when(cmd, _env(tmp_path), lambda: len(shards()) >= 3)
    kept = {p: p.stat().st_ino for p in shards()}
    assert kept and not (out / "manifest.json").exists()
    (out / "train" / ".shard_00007.npz.tmp123").write_bytes(b"PK\x03\x04 partial")  # a torn shard
    m = dataset.generate(cfg, out, progress=False)
    assert m["generation"]["rendered"] < m["generation"]["samples"]  # only the missing shards were rendered
    assert all(p.stat().st_ino == ino for p, ino in kept.items())  # finished shards were not redone
    assert not list(out.rglob(".*.tmp*"))
    for p in ref.rglob("shard_*.npz"):
        assert p.read_bytes() == (out / p.relative_to(ref)).read_bytes(), p


def test_corrupt_shard_is_redone(tmp_path):
    from ffjax.sim import dataset

    cfg = configs.get("smoke", {"data.sensor_test_per_indenter": 1, "data.calib_samples": 4})
    dataset.generate(cfg, tmp_path, progress=False)
    shard = tmp_path / "val" / "shard_00000.npz"
    good = shard.read_bytes()
    shard.write_bytes(good[: len(good) // 2])  # e.g. a copy cut short
    m = dataset.generate(cfg, tmp_path, progress=False)
    assert m["generation"]["rendered"] == 40 and shard.read_bytes() == good


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores directory permissions")
def test_unwritable_output_fails_before_any_work(data, tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        with pytest.raises(WriteError, match=r"locked.* not writable"):
            train.train(_cfg(), METHOD, data, locked / "run", progress=False)
        from ffjax.sim import dataset

        with pytest.raises(OSError, match="not writable"):
            dataset.generate(configs.get("smoke"), locked / "data", progress=False)
    finally:
        locked.chmod(0o700)


def test_a_second_training_into_a_busy_run_folder_is_refused(data, tmp_path):
    """Two trainings with the same --out used to interleave their logs; the second now stops at once, naming
    the first, and leaves the folder as it was. The lock goes with its holder (no stale lock)."""
    from ffjax.errors import FolderLockedError
    from ffjax.files import folder_lock

    with folder_lock(tmp_path, "training run"):  # what a running training holds
        busy = rf"{tmp_path} is in use by another training run \(pid {os.getpid()}"
        with pytest.raises(FolderLockedError, match=busy):
            train.train(_cfg(), METHOD, data, tmp_path, progress=False)
        assert not (tmp_path / "train_log.jsonl").exists() and not (tmp_path / "model.json").exists()
    train.train(_cfg(), METHOD, data, tmp_path, progress=False, max_steps=1)  # released: it trains


def test_output_under_a_file_fails_before_any_work(data, tmp_path):
    """Works as root too (chmod does not bite there): the output's parent is a file, so mkdir fails."""
    (tmp_path / "file").write_text("x")
    with pytest.raises(WriteError, match=r"file/run is not writable"):
        train.train(_cfg(), METHOD, data, tmp_path / "file" / "run", progress=False)
    from ffjax.sim import dataset

    with pytest.raises(OSError, match=r"file/data is not writable"):
        dataset.generate(configs.get("smoke"), tmp_path / "file" / "data", progress=False)


def test_no_space_for_a_checkpoint_fails_fast(data, tmp_path, monkeypatch):
    monkeypatch.setattr(ckpt_lib.shutil, "disk_usage", lambda p: type("U", (), {"free": 1024})())
    with pytest.raises(WriteError, match=r"1\.0 KiB|0\.0 MiB free"):
        train.train(_cfg(), METHOD, data, tmp_path, progress=False)
    assert not (tmp_path / "train_log.jsonl").exists()


def test_disk_full_mid_save_keeps_last_good_checkpoint(data, reference, tmp_path, monkeypatch):
    """The writer raises ENOSPC while checkpoint 9 is being written: a clear error, checkpoint 6 intact,
    and resuming (space freed) ends bitwise equal to the uninterrupted run."""
    from orbax.checkpoint._src.handlers import json_checkpoint_handler as jch

    real = jch.JsonCheckpointHandler._save_fn

    async def full_disk(self, x, directory):
        if "checkpoints/9." in str(directory):
            raise OSError(errno.ENOSPC, "No space left on device")
        return await real(self, x, directory)

    monkeypatch.setattr(jch.JsonCheckpointHandler, "_save_fn", full_disk)
    with pytest.raises(WriteError, match=r"disk is full.*last good checkpoint \(step 6\)"):
        train.train(_cfg(), METHOD, data, tmp_path, progress=False)
    monkeypatch.setattr(jch.JsonCheckpointHandler, "_save_fn", real)
    assert _ckpt_steps(tmp_path)[-1] == 6
    store.load(tmp_path, which="latest")
    done = train.train(_cfg(), METHOD, data, tmp_path, resume=True, progress=False)
    assert _same(done["state"].arrays(), reference["state"].arrays())


def _nan_at(step, seen):
    """train_step that feeds a NaN image batch at `step` (1-based) and records the batch it saw."""
    real = loop_lib.train_step

    def step_fn(state, batch):
        if int(state.step) + 1 == step:
            seen.append(np.asarray(batch["force"]))
            batch = {**batch, "image": np.full_like(batch["image"], np.nan)}
        return real(state, batch)

    return step_fn


def test_nonfinite_stops_naming_step_and_batch(data, tmp_path, monkeypatch):
    seen = []
    monkeypatch.setattr(loop_lib, "train_step", _nan_at(7, seen))
    with pytest.raises(train.NonFiniteLossError, match=r"at step 7 .*train records \[.*Last good checkpoint: step 6"):
        train.train(_cfg(), METHOD, data, tmp_path, progress=False)
    # the records the message names are the batch that step trained on
    from ffjax import data as fdata

    src = fdata.open_split(data / "train")
    idx = nonfinite.batch_records(len(src), 0, 8, 7)
    np.testing.assert_allclose(np.stack([src[i]["force"] for i in idx]), seen[0])
    v = store.load(tmp_path, which="latest").variables
    assert all(np.isfinite(x).all() for x in _leaves(v))


def test_nonfinite_skip_drops_the_update_and_goes_on(data, reference, tmp_path, monkeypatch):
    monkeypatch.setattr(loop_lib, "train_step", _nan_at(7, []))
    with pytest.warns(UserWarning, match="1 non-finite step"):
        out = train.train(_cfg(**{"train.nonfinite": "skip"}), METHOD, data, tmp_path, progress=False)
    assert out["complete"] and out["nonfinite_skipped"] == [7]
    assert all(np.isfinite(x).all() for x in _leaves(out["state"].params))
    assert np.isfinite(out["val"]["nl1"])
    bad = _cfg()
    bad["train"]["nonfinite"] = "ignore"
    with pytest.raises(ValueError, match="train.nonfinite"):
        train.train(bad, METHOD, data, tmp_path / "x", progress=False)


def test_step_drops_a_nonfinite_update_without_recompiling(data, reference):
    from ffjax.train import step as step_lib

    state = jax.tree.map(lambda x: jax.numpy.array(x, copy=True), reference["state"])  # train_step donates it
    step0 = int(state.step)
    batch = {"image": np.full((8, 32, 32, 3), np.nan, np.float32), "depth": np.zeros((8, 32, 32), np.float32),
             "force": np.zeros((8, 3), np.float32)}
    before = _leaves(state.params)
    n = step_lib.train_step._cache_size()
    new, m = step_lib.train_step(state, batch)
    assert not np.isfinite(float(m["loss"])) and int(new.step) == step0 + 1
    assert all(np.array_equal(a, b) for a, b in zip(_leaves(new.params), before))
    assert n == 0 or step_lib.train_step._cache_size() == n  # the select is inside the one compiled step


def test_faults_harness_reads_progress_past_a_torn_line(tmp_path):
    import faults  # tests/reliability/faults.py, the fault-injection harness

    assert faults._logged_step(tmp_path) == 0
    (tmp_path / "train_log.jsonl").write_text('{"kind": "train", "step": 5}\n{"kind": "train", "st')
    assert faults._logged_step(tmp_path) == 5
