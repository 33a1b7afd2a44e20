"""Bad dataset input: every malformed CSV row, file or shard gives a DataError naming the file and line."""

import json
import logging

import cv2
import faults_cases
import numpy as np
import pytest

from ffjax import data
from ffjax.train import __main__ as cli

H, W = 12, 16


def make_csv(folder, n=6, seed=0):
    """A release-layout split: data.csv (tactile, depth, FT), tactile/*.png, depth/*.npy, background.png."""
    return faults_cases.release_csv(folder, n, H, W, seed)


def set_row(csv_path, row, text):
    """Replace data row `row` (0-based; file line row + 2) with `text`."""
    lines = csv_path.read_text().splitlines()
    lines[row + 1] = text
    csv_path.write_text("\n".join(lines) + "\n")


@pytest.fixture
def split(tmp_path):
    return make_csv(tmp_path / "split")


def test_good_split_opens_and_validates(split):
    src = data.open_split(split, validate=True)
    assert len(src) == 6 and src.skipped == []
    np.testing.assert_allclose(src[2]["force"], [2, -2, 3.5])


def test_missing_columns_and_empty_split(split):
    split.write_text("tactile,force\na.png,1 2 3\n")
    with pytest.raises(data.DataError, match=r"data\.csv: missing column\(s\) \['FT'\]"):
        data.open_split(split)
    split.write_text("tactile,depth,FT\n")
    with pytest.raises(data.DataError, match=r"data\.csv: no data rows"):
        data.open_split(split)


@pytest.mark.parametrize("cell, why", [
    ("1 2 nan 0 0 0", r"Fz is NaN"),
    ("1 inf 2 0 0 0", r"Fy is inf"),
    ("1 2", r"has 2 values, expected 6"),
    ("1 2 3 4", r"has 4 values"),
    ("1 x 3", r"Fy 'x' is not a number"),
    ("", r"has 0 values"),
    ("0 0 1_0 0 0 0", r"Fz '1_0' is not a number \(write plain decimals"),  # float() read it as 10 N
    ("1 2 3 0 0 Infinity", r"Tz is inf"),
    ("0x1 2 3", r"Fx '0x1' is not a number"),
    ("\uff11 2 3", r"Fx '\uff11' is not a number"),  # a full-width digit, which float() takes
    ("0,5 1,2 3,0", r"by commas and by spaces \(decimal commas\? write 0\.5"),  # not the labels 0 5 1 2 3 0
    ("0,1 0,2 3", r"by commas and by spaces"),
    ("1 2 1e999", r"Fz '1e999' is inf"),
])
def test_bad_ft_cell_names_line(split, cell, why):
    set_row(split, 3, f'tactile/003.png,depth/003.npy,"{cell}"')
    with pytest.raises(data.DataError, match=rf"data\.csv row 3 \(line 5\): .*{why}"):
        data.open_split(split)


@pytest.mark.parametrize("cell, force", [
    ("0.002000 0.005000 0.017000 -0.000100 -0.000000 0.000400", [0.002, 0.005, 0.017]),  # the release's cells
    ("1.5e-05 -2 +3 0 0 0", [1.5e-5, -2, 3]),  # csv_layout's %.9g, a sign
    (".5, 1., 2E1", [0.5, 1, 20]),
])
def test_good_ft_cells_parse(split, cell, force):
    set_row(split, 3, f'tactile/003.png,depth/003.npy,"{cell}"')
    np.testing.assert_allclose(data.open_split(split).forces[3], force, rtol=1e-6)


@pytest.mark.parametrize("row, why", [
    ("tactile/001.png,1 2 3 0 0 0", "2 cells, the header has 3"),
    ("tactile/001.png,depth/001.npy,1 2 3 0 0 0,extra", "4 cells, the header has 3"),
    (",depth/001.npy,1 2 3 0 0 0", "empty tactile path"),
])
def test_wrong_cell_count_and_empty_path(split, row, why):
    set_row(split, 1, row)
    with pytest.raises(data.DataError, match=rf"line 3\): {why}"):
        data.open_split(split)


def test_duplicate_rows(split):
    set_row(split, 4, "./tactile/002.png,depth/002.npy,2 -2 3.5 0 0 0")
    with pytest.raises(data.DataError, match=r"line 6\): duplicate row: .*002\.png is the file of line 4"):
        data.open_split(split)


@pytest.mark.parametrize("link", ["symlink", "hardlink"])
def test_a_link_to_another_rows_frame_is_a_duplicate(split, link):
    """Issue 33 (4): a symlink or a hard link to a frame another row names, with other labels, is the same frame."""
    import os

    folder = split.parent
    (os.symlink if link == "symlink" else os.link)(folder / "tactile/002.png", folder / "tactile/alias.png")
    set_row(split, 4, "tactile/alias.png,depth/004.npy,9 9 9 0 0 0")
    with pytest.raises(data.DataError, match=r"line 6\): duplicate row: tactile image tactile/alias\.png is the file "
                                             r"of line 4"):
        data.open_split(split)


def test_an_implausible_label_names_its_row(split):
    """Issue 33 (2): a force no tactile sensor takes (1e30, a unit error) is refused with its row, not trained on."""
    set_row(split, 2, "tactile/002.png,depth/002.npy,1e30 2 3 0 0 0")
    with pytest.raises(data.DataError, match=r"row 2 \(line 4\): FT cell .*Fx = 1e\+30 N is beyond 200 N"):
        data.open_split(split)
    set_row(split, 2, "tactile/002.png,depth/002.npy,1 2 -250 0 0 0")
    with pytest.raises(data.DataError, match=r"Fz = -250 N is beyond 200 N"):
        data.open_split(split)
    src = data.open_split(split, skip_bad_rows=True)  # or dropped, and said so
    assert len(src) == 5 and "beyond 200 N" in src.skipped[0][1]


def test_a_column_named_twice_is_refused(split):
    """Issue 33 (3): `tactile,depth,FT,FT` used the last FT silently."""
    lines = split.read_text().splitlines()
    split.write_text("\n".join(["tactile,depth,FT,FT"] + [f"{line},0 0 0 0 0 0" for line in lines[1:]]) + "\n")
    with pytest.raises(data.DataError, match=r"data\.csv: the header names 'FT' \(columns 3, 4\) more than once"):
        data.open_split(split)


def _truncate(path, keep=0.5):
    raw = path.read_bytes()
    path.write_bytes(raw[: int(len(raw) * keep)])


@pytest.mark.parametrize("damage, why", [
    (lambda d: (d / "tactile/002.png").unlink(), r"missing tactile image .*002\.png"),
    (lambda d: _truncate(d / "tactile/002.png"), r"truncated tactile image .*002\.png"),
    (lambda d: (d / "tactile/002.png").write_bytes(b""), r"empty tactile image .*002\.png"),
    (lambda d: cv2.imwrite(str(d / "tactile/002.png"), np.zeros((H + 2, W, 3), np.uint8)),
     r"002\.png is 14x16 px, the background is 12x16 px"),
    (lambda d: cv2.imwrite(str(d / "tactile/002.png"), np.full((H, W, 3), 1500, np.uint16)),
     r"002\.png has uint16 pixels, not 8-bit"),
    (lambda d: cv2.imwrite(str(d / "tactile/002.png"), np.full((H, W), 100, np.uint8)), r"002\.png is grayscale"),
    (lambda d: (d / "depth/002.npy").unlink(), r"missing depth file .*002\.npy"),
    (lambda d: _truncate(d / "depth/002.npy", 0.3), r"unreadable depth file .*002\.npy"),
    (lambda d: np.save(d / "depth/002.npy", np.zeros((H, W + 1))), r"depth file .*002\.npy is \(12, 17\)"),
    (lambda d: np.save(d / "depth/002.npy", np.array(["a"] * H * W).reshape(H, W)), r"dtype <U1"),
])
def test_bad_files_fail_on_open_when_validating(split, damage, why):
    damage(split.parent)
    data.open_split(split)  # cell checks only: opens, the row fails when read
    with pytest.raises(data.DataError, match=rf"data\.csv row 2 \(line 4\): .*{why}"):
        data.open_split(split, validate=True)


def _loop(path):
    path.unlink()
    path.symlink_to(path.name)  # a link to itself


def _dangling(path):
    path.unlink()
    path.symlink_to("gone.png")


def _directory(path):
    path.unlink()
    path.mkdir()


@pytest.mark.parametrize("fault, why", [
    (_directory, r"tactile image \S*002\.png is a directory, not a file"),
    (_loop, r"tactile image \S*002\.png is a symlink loop"),
    (_dangling, r"tactile image \S*002\.png is a symlink to \S*tactile/gone\.png, which does not exist"),
])
def test_a_tactile_path_that_is_not_a_file_says_what_it_is(split, fault, why):
    """Issue 61 (5): a directory or a looping symlink at a tactile path was reported as a missing image."""
    fault(split.parent / "tactile/002.png")
    with pytest.raises(data.DataError, match=rf"data\.csv row 2 \(line 4\): {why}"):
        data.open_split(split, validate=True)
    with pytest.raises(data.DataError, match=rf"data\.csv row 2 \(line 4\): {why}"):
        data.open_split(split)[2]  # unvalidated: found when the row is read


def test_other_paths_that_are_not_files_say_what_they_are(split):
    folder = split.parent
    _directory(folder / "depth/002.npy")
    with pytest.raises(data.DataError, match=r"row 2 \(line 4\): depth file \S*002\.npy is a directory, not a file"):
        data.open_split(split, validate=True)
    with pytest.raises(data.DataError, match=r"row 2 \(line 4\): depth file \S*002\.npy is a directory"):
        data.open_split(split)[2]
    _loop(folder / "background.png")  # not passed over as "no background"
    with pytest.raises(data.DataError, match=r"background \S*background\.png is a symlink loop"):
        data.open_split(split)
    _directory(split)  # a folder whose data.csv is a folder: not "not a split"
    with pytest.raises(data.DataError, match=r"CSV \S*data\.csv is a directory, not a file"):
        data.open_split(folder)
    with pytest.raises(data.DataError, match=r"missing split \S*nowhere"):
        data.open_split(folder / "nowhere")


def test_an_alpha_channel_is_dropped(tmp_path):
    rgba = np.zeros((H, W, 4), np.uint8)
    rgba[..., 0], rgba[..., 1], rgba[..., 2], rgba[..., 3] = 10, 20, 30, 255  # BGRA on disk
    cv2.imwrite(str(tmp_path / "a.png"), rgba)
    assert (data.images.read_rgb(tmp_path / "a.png") == [30, 20, 10]).all()


def test_load_time_errors_name_row_and_file(split):
    """Damage the header checks cannot see (or made after opening) still names the row when read."""
    src = data.open_split(split, validate=True)
    raw = bytearray((split.parent / "tactile/001.png").read_bytes())
    raw[40:60] = b"\x00" * 20  # corrupt the image data, keep header and trailer
    (split.parent / "tactile/001.png").write_bytes(bytes(raw))
    with pytest.raises(data.DataError, match=r"row 1 \(line 3\): .*001\.png"):
        src[1]
    d = np.zeros((H, W))
    d[3, 4] = np.nan
    np.save(split.parent / "depth/004.npy", d)
    with pytest.raises(data.DataError, match=r"row 4 \(line 6\): depth file .*004\.npy has 1 NaN/inf"):
        src[4]


def test_strict_error_counts_all_bad_rows(split):
    set_row(split, 1, "tactile/001.png,depth/001.npy,nan 0 0")
    set_row(split, 3, "tactile/003.png,depth/003.npy,1 2")
    (split.parent / "tactile/005.png").unlink()
    with pytest.raises(data.DataError) as e:
        data.open_split(split, validate=True)
    msg = str(e.value)
    assert msg.startswith(f"{split} row 1 (line 3): FT cell")
    assert "3 bad rows" in msg and "line 5" in msg and "missing tactile image" in msg and "--skip-bad-rows" in msg


def test_skip_bad_rows_drops_and_reports(split, caplog):
    set_row(split, 1, "tactile/001.png,depth/001.npy,nan 0 0")
    _truncate(split.parent / "tactile/003.png")
    with caplog.at_level(logging.WARNING, logger="ffjax.data"):
        src = data.open_split(split, skip_bad_rows=True)
    assert len(src) == 4
    np.testing.assert_allclose(src.forces[:, 0], [0, 2, 4, 5])
    assert [w.split("(line ")[1][0] for w, _ in src.skipped] == ["3", "5"]
    assert "skipped 2 of 6 rows" in caplog.text and "Fx is NaN" in caplog.text and "truncated" in caplog.text
    assert src[1]["image"].shape == (H, W, 3)  # indices are over the kept rows
    (split.parent / "depth/004.npy").unlink()  # a row that goes bad later still names its own line
    with pytest.raises(data.DataError, match=r"row 4 \(line 6\): missing depth"):
        src[2]


def test_skip_bad_rows_all_bad_is_an_error(split):
    for i in range(6):
        (split.parent / f"tactile/{i:03d}.png").unlink()
    with pytest.raises(data.DataError, match=r"all 6 rows are bad"):
        data.open_split(split, skip_bad_rows=True)


def test_per_row_background_column(split):
    lines = split.read_text().splitlines()
    (split.parent / "background.png").rename(split.parent / "bg_a.png")
    rows = [line + ",bg_a.png" for line in lines[1:]]
    rows[2] = lines[3] + ",bg_missing.png"
    split.write_text("tactile,depth,FT,background\n" + "\n".join(rows) + "\n")
    with pytest.raises(data.DataError, match=r"line 4\): missing background image .*bg_missing\.png"):
        data.open_split(split, validate=True)
    assert len(data.open_split(split, skip_bad_rows=True)) == 5


def test_frames_of_two_sizes_in_one_split_name_their_files(split):
    """Issue 33 (7): per-row backgrounds (and frames) of two sizes stopped training on 'all input arrays must have
    the same shape', naming no file, after its folders were made."""
    folder = split.parent
    lines = split.read_text().splitlines()
    (folder / "background.png").rename(folder / "bg_a.png")
    cv2.imwrite(str(folder / "bg_b.png"), np.full((H + 4, W, 3), 100, np.uint8))
    cv2.imwrite(str(folder / "tactile/005.png"), np.full((H + 4, W, 3), 120, np.uint8))
    np.save(folder / "depth/005.npy", np.zeros((H + 4, W)))
    rows = [line + ",bg_a.png" for line in lines[1:-1]] + [lines[-1] + ",bg_b.png"]
    split.write_text("tactile,depth,FT,background\n" + "\n".join(rows) + "\n")
    with pytest.raises(data.DataError, match=r"background bg_a\.png is 12x16 px but bg_b\.png is 16x16 px"):
        data.open_split(split, validate=True)
    src = data.open_split(split)  # unvalidated: found when the rows are read together
    with pytest.raises(data.DataError, match=r"row 5 \(line 7\): frame tactile/005\.png is \(16, 16\), "
                                             r"tactile/000\.png is \(12, 16\)"):
        src.read_range()


@pytest.mark.parametrize("bad", [np.zeros((H, W), complex), np.zeros((H, W), bool)])
def test_a_depth_file_of_complex_or_bool_values_is_refused(split, bad):
    """Issue 33 (7): complex depth lost its imaginary part and bool became 0/1 silently when a split was opened
    without validation."""
    np.save(split.parent / "depth/002.npy", bad)
    with pytest.raises(data.DataError, match=rf"row 2 .*depth file .*002\.npy holds {bad.dtype} values"):
        data.open_split(split)[2]


# --- the training CLI: validates CSVs before any work, --skip-bad-rows passes through


@pytest.fixture
def fake_train(monkeypatch):
    seen = {}

    def train(cfg, spec, data_arg, out, **kw):
        seen["data"] = data_arg
        return {"run_dir": str(out), "steps": 0, "total_steps": 0, "devices": 1, "val": None, "best_epoch": None}

    monkeypatch.setattr("ffjax.train.train", train)
    return seen


def test_cli_refuses_bad_csv_and_skips_with_flag(split, tmp_path, fake_train, capsys, caplog):
    val = make_csv(tmp_path / "val", n=3, seed=1)
    _truncate(split.parent / "tactile/002.png")
    args = ["--preset", "smoke", "--data", str(split), "--val", str(val), "--out", str(tmp_path / "run"), "--quiet"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert "row 2 (line 4): truncated tactile image" in err and "data" not in fake_train
    with caplog.at_level(logging.WARNING, logger="ffjax.data"):
        assert cli.main(args + ["--skip-bad-rows"]) == 0
    assert "skipped 1 of 6 rows" in caplog.text
    assert len(fake_train["data"]["train"]) == 5 and len(fake_train["data"]["val"]) == 3


@pytest.mark.parametrize("fault", [_directory, _loop])
def test_cli_names_a_tactile_path_that_is_not_a_file(split, tmp_path, fake_train, capsys, fault):
    """Issue 61 (5) from the command line: one error line naming the row, before any work or write."""
    fault(split.parent / "tactile/002.png")
    out = tmp_path / "run"
    assert cli.main(["--preset", "smoke", "--data", str(split), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) >= 1 and err[0].startswith("error: ") and "row 2 (line 4): tactile image" in err[0]
    assert ("is a directory" if fault is _directory else "is a symlink loop") in err[0]
    assert "data" not in fake_train and not out.exists()


def test_cli_takes_an_upper_case_csv_extension(split, tmp_path, fake_train):
    """Issue 61 (7): --data .../DATA.CSV was taken for a dataset folder: 'not a split directory or a .csv file'."""
    upper = split.rename(split.with_name("DATA.CSV"))
    val = make_csv(tmp_path / "val", n=3, seed=1)
    val = val.rename(val.with_name("Val.Csv"))
    args = ["--preset", "smoke", "--data", str(upper), "--val", str(val), "--out", str(tmp_path / "run"), "--quiet"]
    assert cli.main(args) == 0
    assert len(fake_train["data"]["train"]) == 6 and len(fake_train["data"]["val"]) == 3
    assert data.sources.is_csv_path("a/b.CSV") and not data.sources.is_csv_path("a/csv")


def test_a_typed_calibration_force_is_parsed_strictly():
    """Issue 61 (6), its sibling: a typed '1_0' was recorded as Fz = 10 N, 'nan' as a NaN label."""
    from ffjax.calibrate import record

    np.testing.assert_allclose(record.parse_force("1.5e-1 0 2"), [0.15, 0, 2])
    for typo in ("1_0", "nan", "inf", "1_0g"):
        with pytest.raises(ValueError, match="cannot read a force"):
            record.parse_force(typo)


# --- simulated shard splits


def make_shards(folder, counts=(4, 4, 3)):
    rng = np.random.default_rng(0)
    folder.mkdir(parents=True)
    cv2.imwrite(str(folder / "background.png"), np.full((H, W, 3), 90, np.uint8))
    for k, m in enumerate(counts):
        np.savez(folder / f"shard_{k:05d}.npz", image=rng.integers(0, 256, (m, H, W, 3), dtype=np.uint8),
                 depth=np.zeros((m, H, W), np.float32), force=rng.uniform(0, 5, (m, 3)).astype(np.float32))
    (folder / "split.json").write_text(json.dumps({"count": sum(counts), "shard_counts": list(counts)}))
    return folder


def test_shards_missing_file_and_bad_manifest(tmp_path):
    d = make_shards(tmp_path / "s")
    assert len(data.open_split(d, validate=True)) == 11
    (d / "shard_00001.npz").unlink()
    with pytest.raises(data.DataError, match=r"split\.json lists 3 shards .*missing \['shard_00001\.npz'\]"):
        data.open_split(d)
    d = make_shards(tmp_path / "t")
    (d / "split.json").write_text(json.dumps({"count": 12, "shard_counts": [4, 5, 3]}))
    with pytest.raises(data.DataError, match=r"shard_00001\.npz: 4 records, but .*split\.json says 5"):
        data.open_split(d, validate=True)
    (d / "split.json").write_text(json.dumps({"count": 12, "shard_counts": [4, 4, 3]}))
    with pytest.raises(data.DataError, match=r"split\.json: count 12 != sum of shard_counts 11"):
        data.open_split(d)
    (d / "split.json").write_text("{not json")
    with pytest.raises(data.DataError, match=r"split\.json: unreadable manifest"):
        data.open_split(d)


def test_shards_corrupt_file(tmp_path):
    d = make_shards(tmp_path / "s")
    _truncate(d / "shard_00002.npz")
    src = data.open_split(d)  # the manifest alone opens it; the shard fails when read
    with pytest.raises(data.DataError, match=r"shard_00002\.npz: unreadable shard"):
        src[10]
    with pytest.raises(data.DataError, match=r"shard_00002\.npz: unreadable shard"):
        data.open_split(d, validate=True)
    d = make_shards(tmp_path / "t")
    with np.load(d / "shard_00000.npz") as z:
        arrays = dict(z)
    arrays["force"][2, 1] = np.nan
    np.savez(d / "shard_00000.npz", **arrays)
    with pytest.raises(data.DataError, match=r"shard_00000\.npz: force label of record 2 .*NaN"):
        data.open_split(d, validate=True)
