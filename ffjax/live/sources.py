"""Frame sources of the live loop, iterables of (t seconds, RGB uint8 frame, label): a camera that survives
dropped frames and disconnects (CameraLost when every reconnect fails), a video file (VideoCut when it decodes
fewer frames than its header gives), a folder of images."""

from __future__ import annotations

import time
from pathlib import Path

import cv2

from ffjax.data.images import read_rgb

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
# failed reads in a row that end a video before its frame count: a damaged frame fails one read (the decoder goes
# on with the next), a file cut short fails every one
VIDEO_BAD_READS = 30


class CameraLost(RuntimeError):
    """The camera stopped delivering frames and every reconnect attempt failed."""


class VideoCut(RuntimeError):
    """A video file decoded fewer frames than its header gives: damaged frames, or the file is cut short."""


class CameraFrames:
    """(t, rgb, i) from a camera that may drop frames or disconnect; `for t, rgb, i in CameraFrames(0)`.

    A read that fails (ok False, None or an empty frame) is a drop: skipped and counted (`dropped`).
    `max_drops` drops in a row, or an exception from read(), is a disconnect: the device is released and
    re-opened up to `reconnects` times, waiting `backoff` s before the first try and doubling up to
    `max_backoff`; the attempts start afresh once frames flow again. When all fail: CameraLost. A camera
    that cannot be opened at all fails at once (wrong index, not plugged in). OpenCV gives BGR: converted
    to RGB here. `open_fn` (cv2.VideoCapture) and `sleep` are for tests' fake cameras."""

    def __init__(self, index, max_drops: int = 30, reconnects: int = 5, backoff: float = 0.5,
                 max_backoff: float = 8.0, open_fn=None, sleep=None, log=print):
        if max_drops < 1 or reconnects < 0 or backoff < 0:
            raise ValueError(f"need max_drops >= 1, reconnects >= 0, backoff >= 0; got {max_drops}, {reconnects}, "
                             f"{backoff}")
        self.index, self.max_drops, self.reconnects = index, int(max_drops), int(reconnects)
        self.backoff, self.max_backoff = float(backoff), float(max_backoff)
        # looked up at use, not at import: tests (and users) may swap cv2.VideoCapture / time.sleep
        self.open_fn = open_fn or (lambda i: cv2.VideoCapture(i))
        self.sleep = sleep or (lambda s: time.sleep(s))
        self.log = log
        self.dropped = self.disconnects = self.reconnected = 0
        self._cap = None

    def _open(self):
        """An opened capture, or None (a failed open is not an error while reconnecting)."""
        try:
            cap = self.open_fn(self.index)
        except Exception:  # noqa: BLE001 - a driver may raise anything while the device is gone
            return None
        if cap is not None and cap.isOpened():
            return cap
        self._release(cap)
        return None

    @staticmethod
    def _release(cap) -> None:
        try:
            if cap is not None:
                cap.release()
        except Exception:  # noqa: BLE001 - releasing a vanished device must not hide why we stopped
            pass

    def _read(self):
        """(rgb frame or None, exception or None)."""
        try:
            got = self._cap.read()
        except Exception as e:  # noqa: BLE001 - USB unplugged mid-read raises cv2.error or OSError
            return None, e
        ok, frame = got if isinstance(got, tuple) and len(got) == 2 else (False, None)
        if not ok or frame is None or getattr(frame, "size", 0) == 0:
            return None, None
        return frame[..., ::-1], None

    def _reconnect(self, reason: str) -> None:
        """Re-open with backoff, or raise CameraLost."""
        self.disconnects += 1
        self._release(self._cap)
        self._cap, waited = None, 0.0
        self.log(f"camera {self.index}: {reason}; reconnecting (up to {self.reconnects} attempts)")
        for attempt in range(1, self.reconnects + 1):
            wait = min(self.backoff * 2 ** (attempt - 1), self.max_backoff)
            self.sleep(wait)
            waited += wait
            self._cap = self._open()
            if self._cap is not None:
                self.reconnected += 1
                self.log(f"camera {self.index}: reconnected (attempt {attempt})")
                return
        raise CameraLost(f"camera {self.index} lost ({reason}); {self.reconnects} reconnect attempts over "
                         f"{waited:.1f} s failed (is it unplugged? check the cable / `v4l2-ctl --list-devices`)")

    def __iter__(self):
        self._cap = self._open()
        if self._cap is None:
            raise RuntimeError(f"cannot open camera {self.index} (is the sensor plugged in? try another index; "
                               f"on Linux `v4l2-ctl --list-devices` lists them)")
        t0, i, in_a_row = time.monotonic(), 0, 0
        try:
            while True:
                frame, err = self._read()
                if frame is not None:
                    in_a_row = 0
                    yield time.monotonic() - t0, frame, i
                    i += 1
                    continue
                self.dropped += 1
                in_a_row += 1
                if err is not None or in_a_row >= self.max_drops:
                    self._reconnect(f"read raised {type(err).__name__}: {err}" if err is not None else
                                    f"{in_a_row} failed reads in a row")
                    in_a_row = 0
        finally:
            self._release(self._cap)
            self._cap = None


def camera_frames(index: int, **kw) -> CameraFrames:
    """Frames from video device `index`, surviving drops and disconnects (see CameraFrames)."""
    return CameraFrames(index, **kw)


def video_frames(path):
    """(t, RGB frame, index) of a video file; a missing or unreadable file is refused here, not at the first frame."""
    if not Path(path).is_file():
        raise FileNotFoundError(f"--video {path}: no such file")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise RuntimeError(f"cannot open video {path}: not a video cv2 can decode")
    return _read_video(cap, path)


def _read_video(cap, path):
    """The decoded frames; a frame that fails to decode is skipped. VideoCut at the end when fewer frames were
    decoded than the container's frame count (when it gives one)."""
    fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
    total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))  # <= 0: not known, the first failed read is the end
    i = failed = 0  # frames decoded; failed reads in a row
    try:
        while True:
            ok, frame = cap.read()
            if ok:
                failed = 0
                yield i / fps, frame[..., ::-1], i
                i += 1
            elif i >= total or (failed := failed + 1) >= VIDEO_BAD_READS:
                break
    finally:
        cap.release()
    if i < total:
        raise VideoCut(f"--video {path}: only {i} of its {total} frames could be decoded (the file is damaged or "
                       "cut short)")


def image_frames(folder, fps: float = 25.0, exclude=()):
    """(t = index / fps, RGB frame, file name) of the images in `folder`, sorted by name; the files in
    `exclude` (the --background frame) are left out. A missing or image-less folder is refused here."""
    if not Path(folder).is_dir():
        raise FileNotFoundError(f"--images {folder}: no such folder")
    files = sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in IMAGE_EXTS
                   and p.resolve() not in {Path(e).resolve() for e in exclude})
    if not files:
        raise RuntimeError(f"no images ({', '.join(IMAGE_EXTS)}) in {folder}")
    for i, p in enumerate(files):
        yield i / fps, read_rgb(p), p.name
