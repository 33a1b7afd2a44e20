"""ffjax.sim.dataset on the smoke preset: layout, balance, determinism, resume, config guard."""

import json
from pathlib import Path

import numpy as np
import pytest

import configs
from ffjax import data, sim
from ffjax.data import csv_layout
from ffjax.sim import dataset


@pytest.fixture(scope="module")
def cfg():
    return configs.get("smoke")


@pytest.fixture(scope="module")
def root(tmp_path_factory, cfg):
    out = tmp_path_factory.mktemp("ds") / "smoke"
    dataset.generate(cfg, out, workers=1, progress=False)
    return out


def _files(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != "manifest.json"}


def test_layout_and_labels(root, cfg):
    m = json.loads((root / "manifest.json").read_text())
    d = cfg["data"]
    want = {"train", "val"} | {f"unseen/{o}" for o in sim.UNSEEN_OBJECTS} \
        | {f"sensor/{k}" for k in dataset.SENSOR_KEYS} | {f"calib/{k}" for k in dataset.SENSOR_KEYS}
    assert set(m["splits"]) == want and len(want) == 32
    assert m["splits"]["train"]["count"] == 10 * d["train_per_indenter"]
    assert "sphere_big" not in m["splits"]["sensor/digit"]["shapes"]
    assert m["splits"]["calib/mini-2-gel1"]["shapes"] == ["sphere_big"]
    src = data.open_split(dataset.split_dir(root, "sensor", "digit"))
    rec = src[0]
    h, w = d["render_size"]
    assert rec["image"].shape == (w, h, 3) and rec["image"].dtype == np.uint8  # DIGIT is portrait
    assert rec["depth"].shape == (w, h) and rec["depth"].dtype == np.float32
    np.testing.assert_array_equal(rec["background"], dataset.sensor_of("digit", d).background((w, h)))
    train = data.open_split(dataset.split_dir(root, "train"))
    f, applied = train.forces, train.column("force_applied")
    assert f.dtype == np.float32 and np.all(applied[:, 2] > 0) and np.all(applied[:, 2] <= d["fz_max"] + 1e-4)
    np.testing.assert_allclose(applied[:, 2], train.column("requested_force")[:, 2], rtol=1e-6)
    # the labels are the F/T sensor's reading: what the gel carries plus its noise
    assert 0.5 * d["ft_noise"] < np.std(f - applied) < 1.5 * d["ft_noise"]
    # the oblique press: the shear comes from the tilted path, in stick below mu Fz
    assert d["loading"] == "oblique" and np.all(np.abs(train.column("requested_force")[:, :2]) == 0)
    assert np.all(np.hypot(applied[:, 0], applied[:, 1]) <= sim.get_sensor("mini-1").gel.friction * applied[:, 2])
    assert np.corrcoef(np.tan(np.radians(train.column("tilt_deg")[:, 0])) * f[:, 2], f[:, 0])[0, 1] > 0.5


def test_fz_histogram_near_uniform_per_indenter(root, cfg):
    d = cfg["data"]
    train = data.open_split(dataset.split_dir(root, "train"))
    shapes, fz = train.column("shape"), train.forces[:, 2]
    for name in sim.INDENTERS:
        counts, _ = np.histogram(fz[shapes == name], bins=4, range=(0.05, d["fz_max"]))
        assert counts.max() - counts.min() <= 1, (name, counts)


def test_seeds_disjoint_across_splits(root):
    seen = {}
    for name in ("train", "val", "unseen/banana", "sensor/mini-1-gel1", "calib/digit"):
        seeds = set(data.open_split(root / name).column("seed").tolist())
        for other, s in seen.items():
            assert not seeds & s, (name, other)
        seen[name] = seeds


def test_deterministic_resumable_and_guarded(root, cfg, tmp_path):
    other = tmp_path / "again"
    dataset.generate(cfg, other, workers=1, progress=False)
    assert _files(other) == _files(root)  # same seed, same bytes
    (other / "train" / "shard_00000.npz").unlink()
    (other / "val" / ".shard_00000.npz.tmp123").write_bytes(b"partial")  # a killed run's leftover
    m = dataset.generate(cfg, other, workers=1, progress=False)
    assert m["generation"]["rendered"] == cfg["data"]["shard_size"]  # only the deleted shard
    assert _files(other) == _files(root)
    assert dataset.generate(cfg, other, progress=False) == m  # nothing to do: reused as is
    changed = configs.get("smoke", {"seed": 1})
    with pytest.raises(FileExistsError, match="differs in: seed"):
        dataset.generate(changed, other, progress=False)
    small = {"seed": 1, "data.train_per_indenter": 1, "data.val_per_indenter": 1, "data.unseen_per_object": 1,
             "data.sensor_test_per_indenter": 1, "data.calib_samples": 1}  # --force only: a small set will do
    assert dataset.generate(configs.get("smoke", small), other, force=True, workers=1, progress=False)["seed"] == 1


def test_csv_converter_round_trip(root, tmp_path):
    split = dataset.split_dir(root, "unseen", "banana")
    csv_layout.main(["--split", str(split), "--out", str(tmp_path / "banana")])
    a, b = data.open_split(split), data.open_split(tmp_path / "banana" / "data.csv")
    assert len(a) == len(b)
    for i in range(len(a)):
        ra, rb = a[i], b[i]
        for k in ("image", "background", "depth", "force"):
            np.testing.assert_array_equal(ra[k], rb[k])
    header = (tmp_path / "banana" / "data.csv").read_text().splitlines()[:2]
    assert header[0] == "tactile,depth,FT" and header[1].endswith(" 0 0 0")


def test_refused_pose_is_pulled_inwards():
    """Refused poses are pressed again, pulled towards the centre, in a batch per round; the others keep theirs."""
    sensor = sim.get_sensor("mini-1")
    x = 0.75 * sensor.fov_mm[1]  # off the pad: the simulator refuses it
    q = {"force": np.array([[0.1, 0.0, 5.0], [0.0, 0.2, 3.0]]), "x_mm": np.array([x, 1.0]),
         "y_mm": np.zeros(2), "yaw_deg": np.zeros(2), "tilt_deg": np.array([[1.0, 0.0], [0.0, 0.0]]),
         "seed": np.array([3, 4])}
    data = {"loading": "shear", "path_steps": 2, "path_quadrature": "power"}
    s = dataset._press_safe([sim.get_shape("cone")] * 2, sensor, q, (24, 32), data)
    assert s[0].meta["x_mm"] == pytest.approx(x / 2) and s[0].force[2] == pytest.approx(5.0)
    assert s[1].meta["x_mm"] == 1.0 and s[1].force[2] == pytest.approx(3.0)


@pytest.mark.parametrize("loading", ["oblique", "shear"])
def test_sampling_per_loading(loading):
    """Oblique: the request is the normal force, the tilt makes the shear. Shear (before issue 32): the requested
    shear follows Fz tan(tilt), redrawn within +-shear_max."""
    cfg = configs.get("smoke", {"data.loading": loading})
    spec = dataset.split_specs(cfg)[0]
    p = dataset.sample_presses(spec, cfg)
    f, tilt = p["force"], np.tan(np.radians(p["tilt_deg"]))
    assert np.all(np.abs(p["tilt_deg"]) <= cfg["data"]["tilt_max_deg"])
    if loading == "oblique":
        assert np.all(f[:, :2] == 0)
    else:
        assert np.all(np.abs(f[:, :2]) <= cfg["data"]["shear_max"])
        assert np.corrcoef(tilt[:, 0] * f[:, 2], f[:, 0])[0, 1] > 0.5


def test_ft_reading_is_per_press():
    """The F/T noise of a press comes from its own seed: the same wherever the shard boundaries fall."""
    f = np.tile([[0.1, -0.2, 3.0]], (6, 1))
    seeds = np.arange(100, 106)
    whole = dataset.ft_reading(f, seeds, 0.005)
    np.testing.assert_array_equal(np.concatenate([dataset.ft_reading(f[:2], seeds[:2], 0.005),
                                                  dataset.ft_reading(f[2:], seeds[2:], 0.005)]), whole)
    assert 0 < np.abs(whole - f).max() < 0.05 and dataset.ft_reading(f, seeds, 0.0).tolist() == \
        f.astype(np.float32).tolist()


def test_one_writer_per_folder_and_strays_are_named(root, cfg, tmp_path):
    """Issue 33 (5): a second generate into a folder being written is refused, naming the first; a shard of another
    config's size is redone, and one this config does not write is named (a rerun used to call such a folder
    complete)."""
    import shutil

    from ffjax.errors import DataError, FolderLockedError
    from ffjax.files import folder_lock

    busy = tmp_path / "busy"
    with folder_lock(busy, "dataset generation"), pytest.raises(FolderLockedError, match="another dataset generation"):
        dataset.generate(cfg, busy, progress=False)
    assert [p.name for p in busy.iterdir()] == []  # nothing written; the holder's lock file went with its release
    copy = tmp_path / "copy"
    shutil.copytree(root, copy)
    first = copy / "val" / "shard_00000.npz"
    small = {k: v[:1] for k, v in np.load(first).items()}
    dataset.save_npz(first, small)  # another writer's shard of one press
    (copy / "manifest.json").unlink()
    m = dataset.generate(cfg, copy, workers=1, progress=False)
    assert m["generation"]["rendered"] == len(data.open_split(copy / "val"))  # that shard only
    assert _files(copy) == _files(root)  # redone to this config's bytes
    shutil.copy(copy / "val" / "shard_00000.npz", copy / "val" / "shard_00007.npz")
    with pytest.raises(DataError, match=r"val holds shard\(s\) this config does not write \(shard_00007\.npz\)"):
        dataset.generate(cfg, copy, progress=False)


def test_seating_of_training_presses(root, cfg, tmp_path):
    """low_force's seating table: a tilted small sphere makes about the contact it makes untilted at the same Fz (a
    sphere is the same body at any tilt), while a tilted 14 mm face touches on its edge, so the cube is less seated."""
    from experiments.diagnostics import low_force

    got = low_force.main(["--preset", "smoke", "--data", str(root), "--out", str(tmp_path)])["training"]
    assert set(got) == set(sim.INDENTERS)

    def median_ratio(shape):
        ratios = [b["median_ratio"] for b in got[shape]["seating"] if b["n"]]
        assert ratios and sum(b["n"] for b in got[shape]["seating"]) == got[shape]["n"]
        return float(np.median(ratios))

    assert 0.8 < median_ratio("sphere_small") < 1.2
    assert median_ratio("cube") < 0.8 * median_ratio("sphere_small")
    assert "How seated the training presses are" in (tmp_path / "low_force.md").read_text()
    assert (tmp_path / "low_force.png").stat().st_size > 0


def test_the_cli_shares_a_gpu_among_workers_and_takes_none_of_its_memory_up_front(monkeypatch, tmp_path):
    """On a GPU `python -m ffjax.simulate` starts a worker per core (at most 8; the optics and files are on the
    CPU) and no process preallocates the GPU; `--workers` still decides; on a CPU the library's default stands."""
    import os

    from ffjax import simulate
    from ffjax.sim import batched, dataset

    seen = []
    fake = {"splits": {}, "generation": {"samples": 0, "rendered": 0, "seconds": 0.0, "samples_per_minute": 0,
                                          "workers": 1}}
    monkeypatch.setattr(dataset, "generate", lambda cfg, out, force, workers, progress: seen.append(workers) or fake)
    monkeypatch.delenv("XLA_PYTHON_CLIENT_PREALLOCATE", raising=False)
    simulate.main(["--preset", "smoke", "--out", str(tmp_path), "--quiet"])
    assert os.environ["XLA_PYTHON_CLIENT_PREALLOCATE"] == "false"
    monkeypatch.setattr(batched, "on_accelerator", lambda: True)
    simulate.main(["--preset", "smoke", "--out", str(tmp_path), "--quiet"])
    simulate.main(["--preset", "smoke", "--out", str(tmp_path), "--quiet", "--workers", "3"])
    assert seen == [None, min(os.cpu_count() or 1, 8), 3]



def test_worker_processes_write_the_bytes_one_process_writes(tmp_path, monkeypatch):
    """A dataset made by 2 worker processes (as the quick one is) is the bytes one process makes: what the pipeline
    publishes does not depend on how many workers simulated it."""
    small = configs.get("smoke", {"data.train_per_indenter": 2, "data.val_per_indenter": 2, "data.shard_size": 8})
    every = dataset.split_specs
    monkeypatch.setattr(dataset, "split_specs", lambda c: [s for s in every(c) if s.name in ("train", "val")])
    made = {}
    for workers in (2, 1):
        dataset.generate(small, tmp_path / str(workers), workers=workers, progress=False)
        made[workers] = _files(tmp_path / str(workers))
    assert sum(k.endswith(".npz") for k in made[1]) == 6 and made[2] == made[1]
