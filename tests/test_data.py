"""ffjax.data on fabricated splits: CSV round trip, preprocessing, statistics, pipeline, errors."""

import json

import cv2
import numpy as np
import pytest

from ffjax import data

H, W, S = 12, 16, 16


def fabricate(path, n=40, shard=16, seed=0, h=H, w=W):
    """A shard split with random frames, a smooth background and forces, like ffjax.sim.dataset writes."""
    rng = np.random.default_rng(seed)
    path.mkdir(parents=True, exist_ok=True)
    bg = (np.linspace(60, 200, h * w * 3).reshape(h, w, 3)).astype(np.uint8)
    cv2.imwrite(str(path / "background.png"), bg[..., ::-1])
    counts = []
    for k, a in enumerate(range(0, n, shard)):
        m = min(shard, n - a)
        np.savez(path / f"shard_{k:05d}.npz", image=rng.integers(0, 256, (m, h, w, 3), dtype=np.uint8),
                 depth=rng.uniform(0, 1.5, (m, h, w)).astype(np.float32),
                 force=rng.uniform([-2, -2, 0], [2, 2, 15], (m, 3)).astype(np.float32),
                 shape=np.array(["cube"] * m))
        counts.append(m)
    (path / "split.json").write_text(json.dumps({"count": n, "shard_counts": counts}))
    return path


@pytest.fixture
def split(tmp_path):
    return data.open_split(fabricate(tmp_path / "train"))


@pytest.fixture
def stats(split):
    return data.Stats.compute(split, {"input_size": S, "depth_eps": 0.05})


def test_background_subtraction_clips_not_wraps():
    img = np.array([[[0, 255, 100]]], np.uint8)
    bg = np.array([[[200, 10, 100]]], np.uint8)
    assert data.subtract_background(img, bg).tolist() == [[[0, 255, 127]]]


def test_pad_to_square_landscape_and_portrait():
    land = data.pad_to_square(np.ones((3, 5, 3)))
    assert land.shape == (5, 5, 3) and land[0].sum() == 0 and land[1:4].min() == 1
    port = data.pad_to_square(np.ones((2, 5, 3)), batched=True)
    assert port.shape == (2, 5, 5) and port[:, :, 0].sum() == 0
    assert data.pad_to_square(np.ones((2, 5, 3))).shape == (5, 5, 3)
    assert data.pad_to_square(np.ones((4, 6, 3, 3)), batched=True).shape == (4, 6, 6, 3)


def test_pipeline_shapes_and_normalization(split, stats):
    arrays = data.load_arrays(split, stats, S)
    assert arrays["image"].shape == (40, S, S, 3) and arrays["image"].dtype == np.float32
    np.testing.assert_allclose(arrays["image"].mean(axis=(0, 1, 2)), 0, atol=1e-4)
    np.testing.assert_allclose(arrays["image"].std(axis=(0, 1, 2)), 1, atol=1e-3)
    assert 0 <= arrays["depth"].min() and arrays["depth"].max() <= 1
    assert stats.depth_min < 0 and np.isclose(stats.depth_min, split.read_range()["depth"].min() - 0.05)
    # single record == batched path
    rec = split[7]
    one = data.preprocess_image(rec["image"], rec["background"], stats, S)
    np.testing.assert_allclose(one, arrays["image"][7], atol=1e-6)
    for in_memory in (True, False):
        ds = data.make_dataset(split, stats, S, batch_size=8, seed=1, num_epochs=1, in_memory=in_memory)
        batches = list(ds)
        assert len(batches) == 5
        b = batches[0]
        assert b["image"].shape == (8, S, S, 3) and b["depth"].shape == (8, S, S)
        assert b["force"].shape == (8, 3)
        assert all(v.dtype == np.float32 for v in b.values())
        forces = np.concatenate([b["force"] for b in batches])
        # one epoch holds every row once
        np.testing.assert_array_equal(np.sort(forces[:, 2]), np.sort(split.forces[:, 2]))
    # both paths give the same batches for the same seed
    a = next(iter(data.make_dataset(split, stats, S, 8, seed=3, in_memory=True)))
    b = next(iter(data.make_dataset(split, stats, S, 8, seed=3, in_memory=False)))
    np.testing.assert_allclose(a["image"], b["image"], atol=1e-6)
    assert data.Stats.from_dict(json.loads(json.dumps(stats.to_dict()))) == stats


def test_iterator_state_restore(split, stats):
    it = iter(data.make_dataset(split, stats, S, batch_size=8, seed=0))
    for _ in range(7):  # past an epoch boundary
        next(it)
    state = it.get_state()
    want = [next(it)["force"] for _ in range(4)]
    it2 = iter(data.make_dataset(split, stats, S, batch_size=8, seed=0))
    it2.set_state(state)
    for w in want:
        np.testing.assert_array_equal(next(it2)["force"], w)


def test_csv_round_trip(split, tmp_path):
    csv_path = data.write_csv(split, tmp_path / "csv", progress=False)
    back = data.open_split(csv_path)
    assert len(back) == len(split)
    for i in (0, 17, len(split) - 1):
        a, b = split[i], back[i]
        for k in ("image", "background", "depth", "force"):
            np.testing.assert_array_equal(a[k], b[k])
    assert data.open_split(tmp_path / "csv").read_range(3, 5)["image"].shape == (2, H, W, 3)


def _write_csv(folder, rows, header="tactile,depth,FT"):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "data.csv").write_text(header + "\n" + "\n".join(rows) + "\n")
    return folder / "data.csv"


def test_errors_name_file_and_row(split, tmp_path):
    out = tmp_path / "csv"
    data.write_csv(split, out, progress=False)
    lines = (out / "data.csv").read_text().splitlines()
    bad = list(lines[1:])
    bad[3] = bad[3].rsplit(",", 1)[0] + ",1.0 2.0 nan 0 0 0"
    with pytest.raises(data.DataError, match=r"data\.csv row 3 .*NaN"):
        data.open_split(_write_csv(out, bad))
    bad[3] = bad[3].rsplit(",", 1)[0] + ",1.0 2.0"
    with pytest.raises(data.DataError, match=r"data\.csv row 3 .*2 values"):
        data.open_split(_write_csv(out, bad))
    good = _write_csv(out, lines[1:])
    (out / "tactile" / "000005.png").unlink()
    src = data.open_split(good)
    with pytest.raises(data.DataError, match=r"data\.csv row 5 .*missing tactile image.*000005\.png"):
        src[5]
    raw = (out / "tactile" / "000006.png").read_bytes()
    (out / "tactile" / "000006.png").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(data.DataError, match=r"row 6 .*000006\.png"):
        src[6]
    cv2.imwrite(str(out / "tactile" / "000007.png"), np.zeros((H + 1, W, 3), np.uint8))
    with pytest.raises(data.DataError, match=r"row 7 .*differs|row 7 .*background is"):
        src[7]
    with pytest.raises(data.DataError, match="missing column"):
        data.open_split(_write_csv(tmp_path / "nocol", ["a.png,1 2 3"], header="tactile,force"))
    (out / "background.png").unlink()
    with pytest.raises(data.DataError, match="no background"):
        data.open_split(good)
    assert len(data.open_split(good, background=split.background)) == len(split)


def test_csv_background_column(split, tmp_path):
    out = tmp_path / "csv"
    data.write_csv(split, out, progress=False)
    lines = (out / "data.csv").read_text().splitlines()
    (out / "background.png").rename(out / "bg_unit7.png")
    rows = [line + ",bg_unit7.png" for line in lines[1:]]
    src = data.open_split(_write_csv(out, rows, header="tactile,depth,FT,background"))
    np.testing.assert_array_equal(src[2]["background"], split.background)
    b = src.read_range(0, 4)
    assert b["background"].shape == (4, H, W, 3)
    st = data.Stats.compute(src, {"input_size": S, "depth_eps": 0.05})
    assert data.load_arrays(src, st, S)["image"].shape == (len(split), S, S, 3)


def test_portrait_frames_pad_sideways():
    img = np.full((2, 8, 6, 3), 200, np.uint8)
    bg = np.full((8, 6, 3), 100, np.uint8)
    st = data.Stats((0, 0, 0), (1, 1, 1), 0, 1, (0, 0, 0), (1, 1, 1), 8)
    x = data.preprocess_image(img, bg, st, 8)
    assert x.shape == (2, 8, 8, 3) and x[:, :, 0].max() == 0 and np.allclose(x[:, :, 1:7], 227 / 255)


def test_hosts_get_disjoint_slices(split, stats):
    got = []
    for host in (0, 1):
        ds = data.make_dataset(split, stats, S, batch_size=4, seed=5, num_epochs=1, process_index=host,
                               process_count=2)
        got.append(np.concatenate([b["force"] for b in ds]))
    assert len(got[0]) == len(got[1]) == 20
    both = np.concatenate(got)
    assert len(np.unique(both[:, 2])) == len(split)
