"""Live force view: a camera (or a video / folder of frames) in, forces out.

    python -m ffjax.live --checkpoint RUN --camera 0                    # window with arrow + Fz bar
    python -m ffjax.live --checkpoint RUN --camera 0 --headless --out log/   # robots without a screen
    python -m ffjax.live --checkpoint RUN --video press.mp4 --out out/  # -> out/forces.csv, out/annotated.mp4
    python -m ffjax.live --checkpoint RUN --images frames/ --out out/ --background frames/bg.png

GelSight Mini and DIGIT appear as ordinary video devices (--camera N is cv2.VideoCapture(N)). Frames are
converted from OpenCV's BGR to RGB before prediction. The background (no-contact frame) is the mean of
--bg-frames frames taken after --warmup frames (cameras need a moment to settle exposure), or --background
FILE. Re-take it with key 'b' in the window, or with `kill -USR1 <pid>` when headless: keep the sensor
untouched meanwhile. 'q' / Esc quits; so does Ctrl-C.

Each frame prints `t  Fx Fy Fz  [OUT OF RANGE]  rate` (every --print-every frames). With --out: forces.csv
(t, fx, fy, fz, out_of_range, frame; raw fx_raw.. columns too when --smooth is on) and annotated.mp4
(mp4v). t is seconds since start for a camera, the video's timestamp for --video, frame / --fps
(default 25) for --images. --fps caps the loop rate (sleeps); --smooth adds an EMA or One-Euro filter
(see ffjax.live_filters). --resize HxW|auto resizes frames (auto: the checkpoint's frame size).

Camera faults: a failed read (dropped frame) is skipped and counted; --max-drops (30) failed reads in a row,
or a read that raises, count as a disconnect: the camera is re-opened up to --reconnects (5) times, waiting
--reconnect-wait (0.5 s) doubling to at most 8 s. If that fails the loop stops, forces.csv (line-buffered)
and annotated.mp4 are closed, the reason is printed, and the exit code is 3. Dark, saturated or
background-mismatched frames are predicted but logged when the condition starts and ends; the closing
summary counts drops, reconnects and flagged frames.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import signal
import sys
import threading
import time
import warnings
from pathlib import Path

import cv2
import numpy as np

from ffjax import inference, live_filters
from ffjax.data.sources import read_rgb
from ffjax.files import check_output, folder_lock

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


# -- frame sources: iterables of (t_seconds, rgb uint8, label) -----------------------------------------
class CameraLost(RuntimeError):
    """The camera stopped delivering frames and every reconnect attempt failed."""


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
    return _read_video(cap)


def _read_video(cap):
    fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
    try:
        i = 0
        while True:
            ok, frame = cap.read()
            if not ok:
                return
            yield i / fps, frame[..., ::-1], i
            i += 1
    finally:
        cap.release()


def image_frames(folder, fps: float = 25.0, exclude=()):
    if not Path(folder).is_dir():
        raise FileNotFoundError(f"--images {folder}: no such folder")
    files = sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in IMAGE_EXTS
                   and p.resolve() not in {Path(e).resolve() for e in exclude})
    if not files:
        raise RuntimeError(f"no images ({', '.join(IMAGE_EXTS)}) in {folder}")
    for i, p in enumerate(files):
        yield i / fps, read_rgb(p), p.name


def _resizer(spec, pred):
    if not spec:
        return lambda f: f
    h, w = pred.frame_size if spec == "auto" else (int(v) for v in spec.lower().split("x"))

    def fn(frame):
        if frame.shape[:2] == (h, w):
            return frame
        interp = cv2.INTER_AREA if frame.shape[0] > h else cv2.INTER_LINEAR
        return cv2.resize(frame, (w, h), interpolation=interp)

    return fn


# -- drawing -------------------------------------------------------------------------------------------
def annotate(frame_rgb, force, force_min, force_max, out_of_range=False, rate=None, min_width=480):
    """BGR image for display / video: the frame enlarged, an Fx,Fy arrow from the centre (full length =
    half the frame at the training range's largest shear), an Fz bar on the right, and the numbers."""
    h, w = frame_rgb.shape[:2]
    k = max(1, int(np.ceil(min_width / w)))
    img = cv2.resize(np.ascontiguousarray(frame_rgb[..., ::-1]), (w * k, h * k), interpolation=cv2.INTER_NEAREST)
    H, W = img.shape[:2]
    bar_w = max(12, W // 20)
    canvas = np.zeros((H, W + bar_w + 8, 3), np.uint8)
    canvas[:, :W] = img
    fx, fy, fz = (float(v) for v in force)
    if not np.isfinite([fx, fy, fz]).all():  # corrupt weights: say so on the frame, draw no arrow or bar
        cv2.putText(canvas, "NON-FINITE FORCE (corrupt weights?)", (6, int(22 * max(0.4, W / 900) / 0.5)),
                    cv2.FONT_HERSHEY_SIMPLEX, max(0.4, W / 900), (0, 0, 255), 1, cv2.LINE_AA)
        return canvas
    shear = max(abs(force_min[0]), abs(force_max[0]), abs(force_min[1]), abs(force_max[1]), 1e-3)
    c = (W // 2, H // 2)
    scale = 0.5 * min(W, H) / shear
    tip = (int(c[0] + fx * scale), int(c[1] + fy * scale))  # image y points down, as the sensor's y axis
    colour = (0, 0, 255) if out_of_range else (0, 255, 0)
    cv2.arrowedLine(canvas, c, tip, colour, max(2, W // 160), tipLength=0.25)
    fz_top = max(float(force_max[2]), 1e-3)
    frac = float(np.clip(fz / fz_top, 0, 1))
    x0 = W + 4
    cv2.rectangle(canvas, (x0, 0), (x0 + bar_w, H - 1), (80, 80, 80), 1)
    cv2.rectangle(canvas, (x0, int(H * (1 - frac))), (x0 + bar_w, H - 1), colour, -1)
    text = f"Fx {fx:+.2f} Fy {fy:+.2f} Fz {fz:+.2f} N"
    fs = max(0.4, W / 900)
    cv2.putText(canvas, text, (6, int(22 * fs / 0.5)), cv2.FONT_HERSHEY_SIMPLEX, fs, (255, 255, 255), 1,
                cv2.LINE_AA)
    if rate is not None or out_of_range:
        extra = (f"{rate:.1f} Hz" if rate is not None else "") + ("  OUT OF RANGE" if out_of_range else "")
        cv2.putText(canvas, extra, (6, H - 8), cv2.FONT_HERSHEY_SIMPLEX, fs, colour, 1, cv2.LINE_AA)
    return canvas


# -- the loop ------------------------------------------------------------------------------------------
class _Window:
    """cv2.imshow when available; opencv-*-headless builds lack it, then we fall back to headless."""

    def __init__(self, name="ffjax.live"):
        self.name, self.ok = name, True

    def show(self, img) -> int:
        if not self.ok:
            return -1
        try:
            cv2.imshow(self.name, img)
            return cv2.waitKey(1) & 0xFF
        except cv2.error:
            self.ok = False
            print("no GUI support in this OpenCV build (opencv-*-headless): running headless; install "
                  "opencv-contrib-python for a window, or pass --headless", file=sys.stderr)
            return -1

    def close(self):
        if self.ok:
            try:
                cv2.destroyWindow(self.name)
            except cv2.error:
                pass


def run(pred: inference.Predictor, frames, out=None, headless=True, smoother=None, warmup=0, bg_frames=1,
        background=None, fps_cap=None, print_every=1, max_frames=None, resize=None, log=print) -> dict:
    """Drive `pred` over `frames` (iterable of (t, rgb, label)); returns a summary dict.

    Frames before `warmup` are dropped; the next `bg_frames` are averaged into the background (unless
    `background` is given) and then predicted like every later frame. A None/empty frame is skipped and
    counted; a CameraLost from the source ends the loop cleanly (summary "stopped": "camera_lost", "error").
    Dark, saturated or background-mismatched frames are still predicted, logged when the issue starts, and
    counted in summary "flagged". forces.csv is line-buffered, so a crash or kill loses at most one row."""
    resize_fn = _resizer(resize, pred)
    retake = {"flag": background is None}
    if background is not None:
        pred.set_background(background)
    old = None
    if headless and hasattr(signal, "SIGUSR1") and threading.current_thread() is threading.main_thread():
        def _on_usr1(signum, frame):
            retake["flag"] = True
        old = signal.signal(signal.SIGUSR1, _on_usr1)
    window = None if headless else _Window()
    writer, csv_file, rows = None, None, None
    out = Path(out) if out is not None else None
    lock = contextlib.ExitStack()
    n_done, n_oor, skipped, pending = 0, 0, 0, []
    lat, rate, t_start, t_prev, t_first = [], None, time.perf_counter(), None, None
    empty, flagged, last_issue, stopped, error = 0, {}, "", "end", None
    try:
        for t, frame, label in frames:
            loop_t0 = time.perf_counter()
            if frame is None or np.size(frame) == 0:  # a source that yields its failed reads: skip, count
                empty += 1
                continue
            if skipped < warmup and pred.background is None:
                skipped += 1
                continue
            frame = resize_fn(frame)
            if retake["flag"]:
                pending.append((t, frame, label))
                if len(pending) < bg_frames:
                    continue
                bg = np.mean([p[1] for p in pending], axis=0).round().astype(np.uint8)
                pred.set_background(bg)
                retake["flag"] = False
                if smoother is not None:
                    smoother.reset()
                log(f"background taken from {len(pending)} frame(s)")
                todo, pending = pending, []
            else:
                todo = [(t, frame, label)]
            for t_i, f_i, lab in todo:
                p0 = time.perf_counter()
                with warnings.catch_warnings():  # reported per frame below (out_of_range column, flag log)
                    warnings.simplefilter("ignore", inference.ForceRangeWarning)
                    warnings.simplefilter("ignore", inference.FrameWarning)
                    warnings.simplefilter("ignore", inference.NonFiniteWarning)
                    raw = pred.predict(f_i)[0]
                lat.append(time.perf_counter() - p0)
                oor = bool(pred.last_out_of_range[0])
                issue = str(pred.last_frame_issues[0])
                if pred.last_nonfinite[0]:
                    issue = "non-finite force (corrupt weights or input)"
                if issue:
                    flagged[issue] = flagged.get(issue, 0) + 1
                if issue != last_issue:  # log changes only: a covered lens for a minute is two lines
                    log(f"frame {lab}: " + (f"{issue} (forces unreliable)" if issue else f"{last_issue} cleared"))
                    last_issue = issue
                # a NaN fed to a filter would poison every later frame: NaN frames pass through unfiltered
                force = smoother(t_i, raw) if smoother is not None and np.isfinite(raw).all() else raw
                n_done += 1
                n_oor += oor
                now = time.perf_counter()
                t_first = now if t_first is None else t_first
                if t_prev is not None:
                    inst = 1.0 / max(now - t_prev, 1e-9)
                    rate = inst if rate is None else 0.9 * rate + 0.1 * inst
                t_prev = now
                if out is not None and rows is None:
                    # opened at the first prediction, not before: a source that fails to open leaves an
                    # earlier run's files as they were (and a new run moves them aside, never truncates);
                    # one live loop per --out (a second would move the first's files aside mid-run)
                    lock.enter_context(folder_lock(out, "live recording"))
                    # line-buffered: a kill loses at most one row
                    csv_file = open(_keep_old(out / "forces.csv", log), "w", newline="", buffering=1)
                    rows = csv.writer(csv_file)
                    rows.writerow(["t", "fx", "fy", "fz", "out_of_range", "frame"]
                                  + (["fx_raw", "fy_raw", "fz_raw"] if smoother else []))
                if rows is not None:
                    rows.writerow([f"{t_i:.4f}", *(f"{v:.5f}" for v in force), int(oor), lab]
                                  + ([f"{v:.5f}" for v in raw] if smoother else []))
                if print_every and n_done % print_every == 0:
                    log(f"t={t_i:9.3f}s  Fx={force[0]:+7.3f}  Fy={force[1]:+7.3f}  Fz={force[2]:+7.3f} N"
                        + ("  [NON-FINITE]" if pred.last_nonfinite[0] else "  [OUT OF RANGE]" if oor else "")
                        + (f"  {rate:6.1f} Hz" if rate else ""))
                if out is not None or window is not None:
                    vis = annotate(f_i, force, pred.force_min, pred.force_max, oor, rate)
                    if out is not None:
                        if writer is None:
                            writer = cv2.VideoWriter(str(_keep_old(out / "annotated.mp4", log)),
                                                     cv2.VideoWriter_fourcc(*"mp4v"),
                                                     float(fps_cap or 25.0), (vis.shape[1], vis.shape[0]))
                        writer.write(vis)
                    if window is not None:
                        key = window.show(vis)
                        if key in (ord("q"), 27):
                            raise KeyboardInterrupt
                        if key == ord("b"):
                            retake["flag"] = True
            if max_frames is not None and n_done >= max_frames:
                stopped = "max_frames"
                break
            if fps_cap:
                time.sleep(max(0.0, 1.0 / fps_cap - (time.perf_counter() - loop_t0)))
    except KeyboardInterrupt:
        stopped = "interrupted"
    except CameraLost as e:  # the source gave up reconnecting: stop here, everything so far is written
        stopped, error = "camera_lost", str(e)
        log(f"stopping: {e}")
    finally:
        if writer is not None:
            writer.release()
        if csv_file is not None:
            csv_file.close()
        lock.close()
        if window is not None:
            window.close()
        if old is not None:
            signal.signal(signal.SIGUSR1, old)
    wall = time.perf_counter() - t_start
    # the rate from the first prediction on: the first frame pays the one-off compile
    rate_hz = (n_done - 1) / (t_prev - t_first) if n_done > 1 and t_prev > t_first else 0.0
    summary = {"frames": n_done, "out_of_range": n_oor, "wall_s": wall, "rate_hz": rate_hz,
               "predict_ms_median": 1e3 * float(np.median(lat)) if lat else None,
               "background_taken": pred.background is not None, "stopped": stopped, "error": error,
               "dropped": empty + int(getattr(frames, "dropped", 0)),
               "reconnects": int(getattr(frames, "reconnected", 0)),
               "flagged": flagged}
    if n_done == 0 and pred.background is None:
        log("no frame was predicted: the source ended before a background was taken "
            f"(warmup {warmup}, bg-frames {bg_frames})")
    return summary


def _keep_old(path: Path, log=print) -> Path:
    """`path`, after moving an existing file there to the first free `stem.N.suffix` (said in the log)."""
    if path.exists():
        n = 1
        while (old := path.with_name(f"{path.stem}.{n}{path.suffix}")).exists():
            n += 1
        path.rename(old)
        log(f"kept the previous {path.name} as {old.name}")
    return path


def _fmt(v) -> str:
    return "(" + ", ".join(f"{float(x):.2f}" for x in v) + ")"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m ffjax.live", description=__doc__.splitlines()[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="\n".join(__doc__.splitlines()[1:]))
    p.add_argument("--checkpoint", required=True, help="training run, calibrated or converted folder")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--camera", type=int, help="video device index (cv2.VideoCapture)")
    src.add_argument("--video", help="a video file")
    src.add_argument("--images", help="a folder of frames (sorted by name)")
    p.add_argument("--out", help="folder for forces.csv and annotated.mp4")
    p.add_argument("--headless", action="store_true", help="no window (SIGUSR1 re-takes the background)")
    p.add_argument("--background", help="no-contact frame image file (else captured from the stream)")
    p.add_argument("--warmup", type=int, default=None, help="frames to drop first (camera 30, files 0)")
    p.add_argument("--bg-frames", type=int, default=None, help="frames averaged into the background "
                   "(camera 10, files 1)")
    p.add_argument("--smooth", default=None, help="ema:ALPHA or one-euro:MIN_CUTOFF,BETA[,D_CUTOFF]; off by "
                   "default")
    p.add_argument("--fps", type=float, default=None, help="cap the loop rate (and the --images timebase)")
    p.add_argument("--resize", default=None, help="HxW or 'auto' (the checkpoint's frame size)")
    p.add_argument("--frame-size", default=None, help="HxW the checkpoint expects, if it does not say")
    p.add_argument("--max-frames", type=int, default=None, help="stop after this many predictions")
    p.add_argument("--print-every", type=int, default=1, help="print every Nth frame (0: never)")
    p.add_argument("--which", default="best", choices=("best", "latest"))
    cam = p.add_argument_group("camera faults (--camera)")
    cam.add_argument("--max-drops", type=int, default=30, help="failed reads in a row that count as a "
                     "disconnect (single failed reads are skipped and counted)")
    cam.add_argument("--reconnects", type=int, default=5, help="re-open attempts per disconnect before exiting")
    cam.add_argument("--reconnect-wait", type=float, default=0.5, help="seconds before the first re-open; "
                     "doubles per attempt, at most 8 s")
    return p


def main(argv=None) -> int:
    a = build_parser().parse_args(argv)
    if a.out:  # recordings already there are kept aside, never replaced; but never inside what is read
        check_output(a.out, reads=[a.checkpoint, a.images], force=True)
    fs = tuple(int(v) for v in a.frame_size.lower().split("x")) if a.frame_size else None
    pred = inference.load(a.checkpoint, a.which, frame_size=fs)
    smoother = live_filters.parse(a.smooth)
    background = None
    if a.background:
        background = _resizer(a.resize, pred)(read_rgb(a.background, "background"))
    if a.camera is not None:
        frames = camera_frames(a.camera, max_drops=a.max_drops, reconnects=a.reconnects, backoff=a.reconnect_wait,
                               log=lambda m: print(m, file=sys.stderr, flush=True))
        warmup, bg_frames = 30, 10
    elif a.video:
        frames, warmup, bg_frames = video_frames(a.video), 0, 1
    else:
        excl = [a.background] if a.background else []
        frames, warmup, bg_frames = image_frames(a.images, a.fps or 25.0, excl), 0, 1
    warmup = warmup if a.warmup is None else a.warmup
    bg_frames = max(1, bg_frames if a.bg_frames is None else a.bg_frames)
    print(f"ffjax.live: {pred.method} ({pred.trained.kind}), frames {pred.frame_size[0]}x{pred.frame_size[1]} "
          f"RGB, training force range {_fmt(pred.force_min)}..{_fmt(pred.force_max)} N"
          + (f", filter {smoother!r}" if smoother else ""), flush=True)
    summary = run(pred, frames, out=a.out, headless=a.headless, smoother=smoother, warmup=warmup,
                  bg_frames=bg_frames, background=background, fps_cap=a.fps, print_every=a.print_every,
                  max_frames=a.max_frames, resize=a.resize, log=lambda s: print(s, flush=True))
    print(f"{summary['frames']} frames in {summary['wall_s']:.1f} s ({summary['rate_hz']:.1f} Hz after the first), "
          f"model {summary['predict_ms_median'] or 0:.2f} ms/frame median, "
          f"{summary['out_of_range']} out of range" + (f"; wrote {a.out}/forces.csv" if a.out else ""))
    faults = [f"{summary['dropped']} dropped frames"] * bool(summary["dropped"]) + \
        [f"{summary['reconnects']} reconnects"] * bool(summary["reconnects"]) + \
        [f"{n} {k}" for k, n in summary["flagged"].items()]
    if faults:
        print("faults: " + ", ".join(faults), flush=True)
    if summary["stopped"] == "camera_lost":
        print(f"error: {summary['error']}; forces up to the loss are in the CSV", file=sys.stderr, flush=True)
        return 3
    return 0 if summary["frames"] else 1


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
