"""The live loop with a fake camera that drops frames, raises, disconnects and comes back: it skips and counts,
reconnects with backoff, or stops cleanly with forces.csv complete. Random-weight smoke model, no training."""

import csv
import os
import signal

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import configs
from ffjax import cli, data, inference, live, models, registry, sim, store

H, W, SIZE = 24, 32, 32
BG = sim.sensors.get_sensor("mini-1").background((H, W))
REAL_CAPTURE = cv2.VideoCapture


@pytest.fixture(scope="module")
def ckpt():
    cfg = configs.get("smoke")
    spec = registry.get("dino_r")
    variables = models.build(cfg["model"], spec, SIZE).init(jax.random.PRNGKey(0), jnp.zeros((1, SIZE, SIZE, 3)),
                                                            train=False)
    stats = data.Stats(mean=(0.5,) * 3, std=(0.1,) * 3, depth_min=0.0, depth_max=1.0, force_min=(-2.0, -2.0, 0.0),
                       force_max=(2.0, 2.0, 15.0), input_size=SIZE)
    return store.Trained(cfg, spec, stats, SIZE, (H, W), "argument", "run", "memory", variables)


@pytest.fixture()
def pred(ckpt):
    return inference.Predictor(ckpt)


class FakeCapture:
    """cv2.VideoCapture look-alike playing a script: "f" a frame, "d" (False, None), "n" (True, None),
    "x" read raises; after the script, reads fail forever (unplugged). `opened=False`: open failed."""

    def __init__(self, script="", opened=True):
        self.script, self.opened, self.released = list(script), opened, False

    def isOpened(self):  # noqa: N802 - OpenCV's name
        return self.opened

    def read(self):
        ev = self.script.pop(0) if self.script else "d"
        if ev == "x":
            raise cv2.error("fake: device vanished")
        return {"f": (True, np.ascontiguousarray(BG[..., ::-1])), "d": (False, None), "n": (True, None)}[ev]

    def release(self):
        self.released = True


class FakeDevice:
    """open_fn: each open plays the next session's script; when none are left, opening fails."""

    def __init__(self, *sessions):
        self.sessions, self.caps, self.waits = list(sessions), [], []

    def open(self, index):
        if isinstance(index, str):  # a file: the loop checks the annotated.mp4 it wrote
            return REAL_CAPTURE(index)
        cap = FakeCapture(self.sessions.pop(0)) if self.sessions else FakeCapture(opened=False)
        self.caps.append(cap)
        return cap

    def frames(self, **kw):
        kw = {"max_drops": 3, "reconnects": 3, "backoff": 0.5, "log": lambda m: None, **kw}
        return live.CameraFrames(0, open_fn=self.open, sleep=self.waits.append, **kw)


def rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_drops_are_skipped_then_a_lost_camera_stops_cleanly(pred, tmp_path):
    dev = FakeDevice("fdfnff")  # 4 frames, 2 failed reads, then unplugged for good
    logs = []
    s = live.run(pred, dev.frames(), out=tmp_path, background=BG, print_every=0, log=logs.append)
    assert s["frames"] == 4 and s["stopped"] == "camera_lost" and "3 reconnect attempts" in s["error"]
    assert s["dropped"] == 2 + 3 and s["reconnects"] == 0  # 2 single drops + the 3 in a row that meant "gone"
    assert dev.waits == [0.5, 1.0, 2.0]  # backoff doubles
    assert all(c.released for c in dev.caps)
    assert len(rows(tmp_path / "forces.csv")) == 4  # every predicted frame is in the (closed) CSV
    assert any(line.startswith("stopping: camera 0 lost") for line in logs)


def test_reconnects_after_an_exception_and_keeps_going(pred):
    dev = FakeDevice("ffx", "", "fff")  # read raises; the first re-open delivers nothing; the next one works
    cam = dev.frames(max_drops=2)
    s = live.run(pred, cam, background=BG, print_every=0, max_frames=5, log=lambda m: None)
    assert s["frames"] == 5 and s["stopped"] == "max_frames" and s["error"] is None
    assert cam.disconnects == 2 and s["reconnects"] == 2
    assert dev.waits == [0.5, 0.5]  # attempts start afresh once a re-open succeeded
    assert all(c.released for c in dev.caps)


def test_backoff_is_capped_and_bounded():
    dev = FakeDevice("f")
    cam = dev.frames(max_drops=1, reconnects=6, backoff=1.0, max_backoff=4.0)
    with pytest.raises(live.CameraLost, match="6 reconnect attempts over 19.0 s"):
        list(cam)
    assert dev.waits == [1.0, 2.0, 4.0, 4.0, 4.0, 4.0]


def test_a_camera_that_never_opens_fails_fast():
    dev = FakeDevice()
    with pytest.raises(RuntimeError, match="cannot open camera 0"):
        list(dev.frames())
    assert dev.waits == []
    with pytest.raises(ValueError, match="max_drops >= 1"):
        live.CameraFrames(0, max_drops=0)


def test_none_frames_skipped_and_bad_frames_flagged(pred):
    dark = np.zeros_like(BG)
    stream = [(0.0, BG, 0), (0.1, None, 1), (0.2, dark, 2), (0.3, dark, 3), (0.4, BG, 4)]
    logs = []
    s = live.run(pred, iter(stream), background=BG, print_every=0, log=logs.append)
    assert s["frames"] == 4 and s["dropped"] == 1 and s["flagged"] == {"dark": 2}
    assert logs == ["frame 2: dark (forces unreliable)", "frame 4: dark cleared"]  # logged on change only


def test_cli_exits_3_with_the_csv_written(ckpt, tmp_path, monkeypatch, capsys):
    store.save_bundle(tmp_path / "model", ckpt)
    dev = FakeDevice("f" * 6)
    monkeypatch.setattr(live.sources.cv2, "VideoCapture", dev.open)
    monkeypatch.setattr(live.sources.time, "sleep", dev.waits.append)
    code = live.main(["--checkpoint", str(tmp_path / "model"), "--camera", "0", "--headless", "--out",
                      str(tmp_path / "out"), "--warmup", "0", "--bg-frames", "1", "--print-every", "0",
                      "--max-drops", "2", "--reconnects", "2", "--reconnect-wait", "0.1"])
    assert code == 3
    assert len(rows(tmp_path / "out" / "forces.csv")) == 6
    err = capsys.readouterr().err
    assert "reconnecting (up to 2 attempts)" in err and "error: camera 0 lost" in err
    assert dev.waits == [0.1, 0.2]


def test_a_second_live_recording_into_a_busy_out_folder_is_refused(pred, tmp_path):
    """A second live loop on the same --out would move the first one's forces.csv aside mid-recording."""
    from ffjax.errors import FolderLockedError
    from ffjax.files import folder_lock

    (tmp_path / "forces.csv").write_text("t,fx,fy,fz\n0.0,1,2,3\n")
    with folder_lock(tmp_path, "live recording"), pytest.raises(FolderLockedError, match="another live recording"):
        live.run(pred, iter([(0.0, BG, 0)]), out=tmp_path, background=BG, print_every=0, log=lambda m: None)
    assert (tmp_path / "forces.csv").read_text() == "t,fx,fy,fz\n0.0,1,2,3\n"  # the holder's file untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["forces.csv"]  # nothing new; the released lock removed


class _Usage:
    def __init__(self, free):
        self.free = free


def test_a_full_disk_stops_the_recording_with_whole_rows(pred, tmp_path, monkeypatch):
    """Issue 33 (6): the disk fills while the video is written: the loop stops with one error naming the file,
    forces.csv holds whole rows only (OpenCV's writer would have failed frame after frame with a warning)."""
    from ffjax.live import loop as live_loop

    free = iter([10**9] * 3)
    monkeypatch.setattr(live_loop.shutil, "disk_usage", lambda p: _Usage(next(free, 100)))
    stream = ((i / 10, BG, i) for i in range(10))
    s = live.run(pred, stream, out=tmp_path, background=BG, print_every=0, log=lambda m: None)
    assert s["stopped"] == "disk_full" and "annotated.mp4: no space left" in s["error"]
    got = rows(tmp_path / "forces.csv")
    assert len(got) == 4 and all(len(r) == 6 and None not in r.values() for r in got)
    # issue 61: the error says what was kept, and that is so (the video plays)
    assert s["error"].endswith("; kept forces.csv (4 rows) and annotated.mp4 (3 frames)"), s["error"]
    assert cv2.VideoCapture(str(tmp_path / "annotated.mp4")).get(cv2.CAP_PROP_FRAME_COUNT) == 3
    assert not (tmp_path / ".lock").exists()  # issue 61: the released lock leaves no file


def test_a_failed_csv_write_leaves_whole_rows(tmp_path):
    """A write that lands half a row and then fails (ENOSPC): the file is cut back to its last whole row and the
    error names it."""
    import errno

    from ffjax.errors import WriteError
    from ffjax.live import loop as live_loop

    path = tmp_path / "forces.csv"

    class HalfFull:
        def __init__(self):
            self.f = open(path, "wb", buffering=0)
            self.writes = 0

        def write(self, data):
            self.writes += 1
            if self.writes == 3:  # half the row reaches the disk, then it is full
                self.f.write(data[: len(data) // 2])
                raise OSError(errno.ENOSPC, "No space left on device")
            return self.f.write(data)

        def tell(self):
            return self.f.tell()

        def truncate(self, pos):
            return self.f.truncate(pos)

    f = HalfFull()
    live_loop._write_row(f, path, ["t", "fx"])
    live_loop._write_row(f, path, ["0.1000", "1.00000"])
    with pytest.raises(WriteError, match=r"forces.csv: cannot write \(No space left on device\)"):
        live_loop._write_row(f, path, ["0.2000", "2.00000"])
    f.f.close()
    assert path.read_bytes() == b"t,fx\r\n0.1000,1.00000\r\n"


def test_cli_full_disk_and_nothing_to_predict_are_one_error_line(ckpt, tmp_path, monkeypatch, capsys):
    """Issue 33 (6, 7): a full disk exits 1 with one error naming the file; a source that ends before a background
    was taken exits 1 with an error line and writes nothing (it used to claim a forces.csv)."""
    from ffjax.live import loop as live_loop

    store.save_bundle(tmp_path / "model", ckpt)
    dev = FakeDevice("f" * 6)
    monkeypatch.setattr(live.sources.cv2, "VideoCapture", dev.open)
    monkeypatch.setattr(live_loop.shutil, "disk_usage", lambda p: _Usage(100))
    base = ["--checkpoint", str(tmp_path / "model"), "--headless", "--print-every", "0"]
    code = live.main([*base, "--camera", "0", "--out", str(tmp_path / "out"), "--warmup", "0", "--bg-frames", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len([e for e in err if e.startswith("error:")]) == 1
    assert "annotated.mp4: no space left on the device" in err[-1]
    assert len(rows(tmp_path / "out" / "forces.csv")) == 1  # the row before the video frame that did not fit
    # issue 61: the video had no frame (258 bytes cv2 cannot open): removed, and the error line says so
    assert err[-1].endswith("; kept forces.csv (1 row); annotated.mp4 could not be played and was removed"), err
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["forces.csv"]
    monkeypatch.undo()
    video = tmp_path / "two.mp4"
    w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (W, H))
    for _ in range(2):
        w.write(np.ascontiguousarray(BG[..., ::-1]))
    w.release()
    code = live.main([*base, "--video", str(video), "--out", str(tmp_path / "empty"), "--warmup", "5"])
    captured = capsys.readouterr()
    assert code == 1 and "two.mp4: no frame to predict" in captured.err and "nothing written" in captured.err
    assert "wrote" not in captured.out and not (tmp_path / "empty" / "forces.csv").exists()


def test_cli_an_out_that_cannot_be_written_is_a_usage_error(ckpt, tmp_path, capsys):
    """Issue 33 (7): an --out that cannot be a folder (under a file; read-only disks alike) is refused before the
    camera opens, exit 2 naming --out."""
    store.save_bundle(tmp_path / "model", ckpt)
    (tmp_path / "notes.txt").write_text("a file")
    with pytest.raises(SystemExit) as e:
        live.main(["--checkpoint", str(tmp_path / "model"), "--camera", "0", "--out",
                   str(tmp_path / "notes.txt" / "rec")])
    assert e.value.code == 2 and "--out" in capsys.readouterr().err


def test_the_background_follows_a_drifting_light_but_not_a_contact(pred):
    """Issue 33: a synthetic sequence whose LEDs dim by 4.5% (a real Mini's red over 3 minutes) with a pressed
    contact in the middle: with the refresh the background follows the drift and ignores the contact; without it
    the offset stays."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:H, :W]
    disc = ((yy - H // 2) ** 2 + (xx - W // 2) ** 2 < 25)[..., None]
    n, touching = 200, range(80, 100)

    def frames():
        for i in range(n):
            f = BG * (1 - 0.045 * i / (n - 1)) + rng.normal(0, 1.5, BG.shape) + 40 * disc * (i in touching)
            yield i / 25, np.clip(f.round(), 0, 255).astype(np.uint8), i

    def run(refresh):
        p = inference.Predictor(pred.trained)
        return p, live.run(p, frames(), background=BG, print_every=0, log=lambda m: None, refresh=refresh)

    followed, s = run({"threshold": 3.0, "frames": 20})
    assert s["quiet_frames"] == n - len(touching) and s["background_refreshes"] == (n - len(touching)) // 10
    end = BG * (1 - 0.045)
    assert np.abs(followed.background - end).mean() < 1.0  # within a count of the drifted light
    stuck, _ = run(None)
    assert np.abs(stuck.background - end).mean() > 4.0  # the start-up background: 4.5% off


@pytest.mark.parametrize("bad", [5, [240], [240, "320"], [0, 320], [240.5, 320], True])
def test_a_bad_frame_size_in_model_json_is_one_error_naming_it(ckpt, tmp_path, capsys, bad):
    """Issue 33 (7): model.json "frame_size": 5 was a 25-line TypeError in ffjax.live."""
    import json

    from ffjax import cli

    store.save_bundle(tmp_path / "model", ckpt)
    mj = tmp_path / "model" / "model.json"
    info = json.loads(mj.read_text())
    info["frame_size"] = bad
    info.pop("sha256", None)  # as a file written before model.json carried its checksum (still read)
    mj.write_text(json.dumps(info))
    code = cli.run(live.main, ["--checkpoint", str(tmp_path / "model"), "--camera", "0", "--headless"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "Traceback" not in err[0], err
    assert 'model.json: "frame_size" is' in err[0] and "expected [height, width]" in err[0]


class _BrokenWriter:
    """cv2.VideoWriter whose index never reaches the disk (a disk that fills at release): cv2 says nothing."""

    def __init__(self, path, *args):
        self.path = path

    def write(self, frame):
        pass

    def release(self):
        with open(self.path, "wb") as f:
            f.write(b"\0" * 258)


def test_a_video_that_cannot_be_completed_is_removed_and_named(pred, tmp_path, monkeypatch):
    """Issue 61 (13): a recording whose annotated.mp4 cv2 cannot open is not a recording: removed, the run ends
    with an error saying so and what was kept."""
    from ffjax.live import loop as live_loop

    monkeypatch.setattr(live_loop.cv2, "VideoWriter", _BrokenWriter)
    stream = ((i / 10, BG, i) for i in range(3))
    s = live.run(pred, stream, out=tmp_path, background=BG, print_every=0, log=lambda m: None)
    assert s["stopped"] == "disk_full" and s["error"] == (
        f"{tmp_path / 'annotated.mp4'}: could not be completed (is the disk full?); kept forces.csv (3 rows); "
        "annotated.mp4 could not be played and was removed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["forces.csv"] and len(rows(tmp_path / "forces.csv")) == 3


class FakeVideo(FakeCapture):
    """A video file's capture: `frames` frames in its header, the script's reads ("f" a frame, "d" a frame that
    fails to decode), then every read fails (the file's end)."""

    def __init__(self, script, frames):
        super().__init__(script)
        self.frames = frames

    def get(self, prop):
        return {cv2.CAP_PROP_FPS: 25.0, cv2.CAP_PROP_FRAME_COUNT: float(self.frames)}[prop]


def test_a_video_that_ends_early_says_how_many_frames_were_read(ckpt, tmp_path, monkeypatch, capsys):
    """Issue 61 (13): a damaged video decoding 12 of 21 frames ended rc 0, without a word about the rest. A frame
    that fails to decode is skipped (the decoder goes on with the next); a file that ends before its header's
    frame count is an error (exit 1) saying how many of how many were read, with the forces of those kept."""
    store.save_bundle(tmp_path / "model", ckpt)
    video = tmp_path / "damaged.mp4"
    video.write_bytes(b"stands in for a video")
    fake = {str(video): lambda: FakeVideo("f" * 9 + "d" + "f" * 3, 21)}
    monkeypatch.setattr(live.sources.cv2, "VideoCapture", lambda p: fake[p]() if p in fake else REAL_CAPTURE(p))
    code = cli.run(live.main, ["--checkpoint", str(tmp_path / "model"), "--video", str(video), "--headless",
                               "--print-every", "0", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and err == [f"error: --video {video}: only 12 of its 21 frames could be decoded (the file is "
                                 "damaged or cut short); kept forces.csv (12 rows) and annotated.mp4 (12 frames)"]
    assert [r["frame"] for r in rows(tmp_path / "out" / "forces.csv")] == [str(i) for i in range(12)]
    fake[str(video)] = lambda: FakeVideo("f" * 21, 21)
    assert live.main(["--checkpoint", str(tmp_path / "model"), "--video", str(video), "--headless", "--print-every",
                      "0"]) == 0  # whole: as before


def test_sigterm_stops_the_live_loop_like_ctrl_c(ckpt, tmp_path, monkeypatch):
    """Issue 61 (16): SIGTERM (a supervisor stopping the robot's tools) ended the process at once: a 0-byte .lock
    and an annotated.mp4 without its index stayed. Now the loop stops as on Ctrl-C: both files closed, the lock
    file removed."""
    class Stopped(FakeCapture):
        def read(self):
            if len(self.script) == 2:
                os.kill(os.getpid(), signal.SIGTERM)
            return super().read()

    store.save_bundle(tmp_path / "model", ckpt)
    monkeypatch.setattr(live.sources.cv2, "VideoCapture", lambda i: REAL_CAPTURE(i) if isinstance(i, str) else
                        Stopped("f" * 6))
    code = live.main(["--checkpoint", str(tmp_path / "model"), "--camera", "0", "--headless", "--out",
                      str(tmp_path / "out"), "--warmup", "0", "--bg-frames", "1", "--print-every", "0"])
    assert code == 0 and sorted(p.name for p in (tmp_path / "out").iterdir()) == ["annotated.mp4", "forces.csv"]
    n = len(rows(tmp_path / "out" / "forces.csv"))
    assert 3 <= n <= 5 and cv2.VideoCapture(str(tmp_path / "out" / "annotated.mp4")).get(cv2.CAP_PROP_FRAME_COUNT) == n


def test_a_lock_released_between_open_and_flock_is_taken_afresh(tmp_path, monkeypatch):
    """Issue 61 (16): the lock file is removed on release. A process that opened it just before (and then got the
    flock of the unlinked file) must not believe it holds the folder: it locks the file the path names now, so a
    third process is refused."""
    from ffjax import files
    from ffjax.errors import FolderLockedError

    holder = files.folder_lock(tmp_path, "live recording")
    holder.__enter__()
    flock, released = files.fcntl.flock, []

    def holder_releases_first(f, op):
        if not released:  # the next process has opened the holder's file; the holder releases (and unlinks) it
            released.append(True)
            holder.__exit__(None, None, None)
        return flock(f, op)

    monkeypatch.setattr(files.fcntl, "flock", holder_releases_first)
    with files.folder_lock(tmp_path, "live recording"):
        with pytest.raises(FolderLockedError, match="in use by another live recording"):
            with files.folder_lock(tmp_path, "live recording"):
                pass
    assert released and list(tmp_path.iterdir()) == []
