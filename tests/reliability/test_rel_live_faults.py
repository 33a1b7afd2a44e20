"""The live loop with a fake camera that drops frames, raises, disconnects and comes back: it skips and counts,
reconnects with backoff, or stops cleanly with forces.csv complete. Random-weight smoke model, no training."""

import csv

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import configs
from ffjax import data, inference, live, models, registry, sim, store

H, W, SIZE = 24, 32, 32
BG = sim.sensors.get_sensor("mini-1").background((H, W))


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
    assert sorted(p.name for p in tmp_path.iterdir()) == [".lock", "forces.csv"]
