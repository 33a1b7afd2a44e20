"""Issue 61: numeric flags and config values that mean nothing are refused with one line naming them, before
anything is written (a seed the render seeds overflow on, a frame of 100k x 100k px, --seeds 0, --max-steps 0,
--workers 0, empty splits); training labels of Fz only train, with the normalized L1 over the axes that vary;
`python -m ffjax.sim.dataset` points to ffjax.simulate; Ctrl-C during training is one line and resumes."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _tiny_data import write_tiny_dataset

import configs
from experiments import ablation, pareto, pattern_share, sweep_loss
from ffjax import cli, data, metrics, simulate
from ffjax.sim import seeds
from ffjax.train import __main__ as train_cli
from ffjax.train.loop import with_output_affine

ROOT = Path(__file__).resolve().parents[2]


def _refused(capsys, main, argv, fragment: str) -> str:
    """main(argv) exits 2 through argparse with one error line holding `fragment`; that line."""
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    errors = [ln for ln in capsys.readouterr().err.splitlines() if "error: " in ln]
    assert len(errors) == 1 and fragment in errors[0], errors
    return errors[0]


def test_max_seed_is_what_the_render_seeds_hold():
    """The bound configs put on `seed` is where the last split's last render seed is int64's largest."""
    last = seeds.render_seeds(seeds.MAX_SEED, seeds.MAX_SPLITS - 1, seeds.BLOCK)
    assert last.dtype == np.int64 and int(last[-1]) == np.iinfo(np.int64).max
    with pytest.raises(ValueError, match="no render seed block for config seed"):
        seeds.render_seeds(seeds.MAX_SEED + 1, 0, 1)


@pytest.mark.parametrize("override, fragment", [
    ("seed=-1", f"seed must be >= 0 and <= {seeds.MAX_SEED}, got -1: split k of config seed s renders"),
    ("seed=1000000000", f"seed must be >= 0 and <= {seeds.MAX_SEED}, got 1000000000"),
    ("data.render_size=[100000,100000]", "data.render_size item 0 must be >= 1 and <= 640, got 100000: 640 px is "
                                         "twice the longest native frame side of the sensors"),
    ("data.input_size=100000", "data.input_size must be >= 1 and <= 640"),
    ("data.val_per_indenter=0", "data.val_per_indenter must be >= 1"),
    ("data.unseen_per_object=0", "data.unseen_per_object must be >= 1"),
    ("data.sensor_test_per_indenter=0", "data.sensor_test_per_indenter must be >= 1"),
    ("data.train_per_indenter=2000000", "a simulated split holds 1 to 16777216 presses"),
    ("pretrain.corpus_size=0", "pretrain.corpus_size (0) must be at least 1 for pretrain.steps (4) > 0"),
])
def test_simulate_refuses_values_it_cannot_use_before_writing(tmp_path, capsys, override, fragment):
    """A seed above ~1.3e8 was an OverflowError traceback in sample_presses, a negative one numpy's "expected
    non-negative integer", 100k x 100k px a 37 GiB allocation; val_per_indenter=0 made a dataset whose training
    then failed on the empty val folder. Each left a partial dataset folder."""
    out = tmp_path / "D"
    _refused(capsys, simulate.main, ["--preset", "smoke", "--out", str(out), "--set", override], fragment)
    assert not out.exists()


def test_seed_at_the_bound_samples_and_seeds_past_it_are_refused():
    cfg = configs.get("smoke", {"seed": seeds.MAX_SEED})
    from ffjax.sim import dataset

    spec = dataset.split_specs(cfg)[-1]  # a calibration split: one shape
    assert int(dataset.sample_presses(spec, cfg)["seed"][-1]) < np.iinfo(np.int64).max
    with pytest.raises(configs.ConfigError, match=r"seed \(134217727\) \+ seeds \(2\) - 1 must be at most"):
        configs.get("smoke", {"seed": seeds.MAX_SEED, "seeds": 2})


@pytest.mark.parametrize("main", [ablation.main, pareto.main, pattern_share.main, sweep_loss.main])
@pytest.mark.parametrize("flag, value, fragment", [
    ("--seeds", "0", "--seeds must be at least 1, got 0 (leave it out for the config's seeds, 1)"),
    ("--seeds", "-2", "--seeds must be at least 1, got -2"),
    ("--workers", "0", "--workers must be at least 1, got 0"),
])
def test_experiments_refuse_zero_counts_before_making_out(tmp_path, capsys, main, flag, value, fragment):
    """`--seeds 0` ran the preset's seed count (`args.seeds or cfg["seeds"]`); and the refusals came after --out
    was made."""
    out = tmp_path / "res"
    _refused(capsys, main, ["--preset", "smoke", "--out", str(out), flag, value], fragment)
    assert not out.exists()


def test_seeds_past_the_last_config_seed_are_refused(tmp_path, capsys):
    out = tmp_path / "res"
    _refused(capsys, ablation.main, ["--preset", "smoke", "--out", str(out), "--seeds", "3", "--set",
                                     f"seed={seeds.MAX_SEED - 1}"], "--seeds 3: invalid config")
    assert not out.exists()


@pytest.mark.parametrize("value", ["0", "-5"])
def test_train_refuses_max_steps_below_one(tmp_path, capsys, value):
    """--max-steps 0 ran a step, exited 0 and said "no validation split" with --val given."""
    out = tmp_path / "run"
    _refused(capsys, train_cli.main, ["--preset", "smoke", "--out", str(out), "--max-steps", value],
             f"--max-steps must be at least 1, got {value}")
    assert not out.exists()


def test_simulate_refuses_zero_workers(tmp_path, capsys):
    out = tmp_path / "D"
    _refused(capsys, simulate.main, ["--preset", "smoke", "--out", str(out), "--workers", "0"],
             "--workers must be at least 1, got 0")
    assert not out.exists()


def test_dataset_module_points_to_the_simulate_command(tmp_path):
    """It exited 0 and wrote nothing."""
    out = tmp_path / "X"
    p = subprocess.run([sys.executable, "-m", "ffjax.sim.dataset", "--preset", "smoke", "--out", str(out)],
                       capture_output=True, text=True, cwd=ROOT, timeout=300, stdin=subprocess.DEVNULL)
    assert p.returncode == 2
    assert p.stderr.strip().splitlines() == [f"error: ffjax.sim.dataset has no command line: run python -m "
                                             f"ffjax.simulate --preset smoke --out {out}"]
    assert not out.exists()


# ---- training labels with an axis that never varies ---------------------------------------------------------


def _labels(root: Path, keep: tuple) -> Path:
    """A tiny dataset (tests/_tiny_data) whose force axes outside `keep` are zero on every row."""
    write_tiny_dataset(root, 32, 8)
    for split in ("train", "val"):
        shard = root / split / "shard_00000.npz"
        arrays = dict(np.load(shard))
        arrays["force"][:, [a for a in range(3) if a not in keep]] = 0.0
        np.savez(shard, **arrays)
    return root


def test_metric_leaves_out_an_axis_the_training_labels_hold_constant():
    true = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 9.0]])
    pred = true + [[0.5, -0.5, 1.0], [0.5, 0.5, -1.0]]
    axes, mean = metrics.normalized_l1(pred, true, (0.0, 0.0, 1.0), (0.0, 0.0, 9.0))
    assert np.isnan(axes[:2]).all() and axes[2] == pytest.approx(12.5) and mean == pytest.approx(12.5)
    with pytest.raises(ValueError, match="must be positive on some axis"):
        metrics.normalized_l1(pred, true, (1.0, 1.0, 1.0), (1.0, 1.0, 1.0))


def test_fz_only_labels_train_and_report_fz(tmp_path, capsys):
    """Labels with Fx = Fy = 0 on every row stopped at the first validation ("force range must be positive on
    every axis"), no file named, model.json and train_log.jsonl already written. Now: a note names the file and
    the axes, the run completes, its normalized L1 is Fz's, and Fx, Fy are scaled like Fz (the floor scale
    would have left Fz ~1e-3 of the normalized force loss)."""
    root = _labels(tmp_path / "fz", keep=(2,))
    train = data.open_split(root / "train")
    with pytest.warns(UserWarning, match=r"train: Fx and Fy hold one value on every training row"):
        data.stats.check_force_range(train)
    stats = data.Stats.compute(train, configs.get("smoke")["data"])
    scale = with_output_affine(configs.get("smoke"), stats)["model"]["regressor"]["out_scale"]
    assert scale[0] == scale[1] == pytest.approx(scale[2])
    with pytest.warns(UserWarning, match="Fx and Fy hold one value"):
        rc = cli.run(train_cli.main, ["--preset", "smoke", "--method", "dino_rd", "--data", str(root), "--out",
                                      str(tmp_path / "run"), "--quiet"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    assert "(Fx n/a, Fy n/a, Fz " in out.out


def test_labels_constant_on_every_axis_are_refused_before_writing(tmp_path, capsys):
    root = _labels(tmp_path / "flat", keep=())
    run = tmp_path / "run"
    rc = cli.run(train_cli.main, ["--preset", "smoke", "--data", str(root), "--out", str(run), "--quiet"])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("error: ")]
    assert rc == 2 and len(err) == 1
    assert f"{root / 'train'}: the training labels hold one force on every row (Fx, Fy, Fz = 0, 0, 0 N)" in err[0]
    assert not run.exists() or not any(run.iterdir())  # no model.json, no log


# ---- Ctrl-C during training -----------------------------------------------------------------------------------

# `python -m ffjax.train` with Ctrl-C landing inside orbax's save of the 2nd checkpoint (where it left "coroutine
# 'AsyncCheckpointer._save' was never awaited" and "Save Finalize thread failed" after "interrupted"): the signal is
# sent from orbax's own run_sync, on the main thread, as a terminal's Ctrl-C would arrive there.
_INTERRUPTED_TRAIN = """
import os, runpy, signal, sys, threading
signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal, whatever the test runner inherited
from orbax.checkpoint._src.checkpointers import async_checkpointer as ac
run_sync, calls = ac.asyncio_utils.run_sync, []
def interrupted(coro):
    if threading.current_thread() is threading.main_thread():
        calls.append(1)
        if len(calls) == 2:
            os.kill(os.getpid(), signal.SIGINT)
    return run_sync(coro)
ac.asyncio_utils.run_sync = interrupted
sys.argv = ["ffjax.train", *sys.argv[1:]]
runpy.run_module("ffjax.train", run_name="__main__")
"""


def test_ctrl_c_during_training_is_one_line_and_resumes(tmp_path, capsys):
    root = write_tiny_dataset(tmp_path / "data", 32, 8)
    run = tmp_path / "run"
    args = ["--preset", "smoke", "--data", str(root), "--out", str(run), "--quiet", "--set", "train.ckpt_every=2",
            "--set", "train.epochs=3"]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "FFJAX_DEBUG": ""}
    p = subprocess.Popen([sys.executable, "-c", _INTERRUPTED_TRAIN, *args], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env, stdin=subprocess.DEVNULL)
    _, err = p.communicate(timeout=600)
    lines = [ln for ln in err.splitlines() if not ln.startswith("note: ")]
    assert p.returncode == 130 and lines == ["interrupted"], err
    assert any(d.name.isdigit() for d in (run / "checkpoints").iterdir())
    rc = cli.run(train_cli.main, [*args, "--resume"])
    assert rc == 0, capsys.readouterr().err
    assert "(12/12 steps" in capsys.readouterr().out


@pytest.mark.parametrize("module, argv, fragment", [
    ("experiments.stability", ["--levels", "0"], "argument --levels: expected an integer >= 1, got '0'"),
    ("experiments.stability", ["--per-level", "0"], "argument --per-level: expected an integer >= 1"),
    ("experiments.sweep_loss", ["--betas", "1", "-1"], "argument --betas: expected a finite number >= 0, got '-1'"),
    ("experiments.sweep_loss", ["--alpha", "0"], "argument --alpha: expected a finite number > 0, got '0'"),
    ("experiments.diagnostics.contact_probe", ["--per-shape", "0"], "argument --per-shape: expected an integer >= 1"),
    ("experiments.diagnostics.rest_recording", ["--sim-frames", "0"], "argument --sim-frames: expected an integer"),
    ("experiments.diagnostics.rest_recording", ["--fps", "-5"], "argument --fps: expected a finite number > 0"),
    ("ffjax.sim.gallery", ["--size", "1", "32"], "argument --size: expected an integer >= 2, got '1'"),
])
def test_experiment_counts_of_zero_are_refused_not_read_as_the_default(tmp_path, capsys, module, argv, fragment):
    """`--levels 0` / `--per-level 0` ran the default count (`args.levels or N_LEVELS`), like `--seeds 0` did."""
    import importlib

    with pytest.raises(SystemExit) as e:
        importlib.import_module(module).main([*argv, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and fragment in err[-1], err
    assert not (tmp_path / "out").exists()
