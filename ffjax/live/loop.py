"""The live loop, `run(pred, frames, ...)`: the background taken from the stream (re-taken on key 'b' or
SIGUSR1, and optionally refreshed from frames without contact: `ffjax.live.background`), every frame predicted
and flagged, optionally smoothed, printed, shown, and recorded to forces.csv / annotated.mp4 (an earlier
recording in the folder is kept aside as forces.1.csv, ...). A full disk stops the recording with one error
naming the file and saying what was kept: forces.csv holds whole rows only, and an annotated.mp4 that cannot be
played (no frame written, or its index could not be) is removed."""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import shutil
import signal
import threading
import time
import warnings
from pathlib import Path

import cv2
import numpy as np

from ffjax import cli, inference
from ffjax.errors import WriteError
from ffjax.files import folder_lock
from ffjax.live.background import BackgroundRefresh
from ffjax.live.sources import CameraLost, VideoCut
from ffjax.live.view import Window, annotate

REFRESH_EVERY = 10  # quiet frames between two refreshes of the predictor's background (each one is checked)


def resizer(spec, pred):
    """frame -> frame at `spec` ("HxW", or "auto": the checkpoint's frame size); unchanged when spec is empty."""
    if not spec:
        return lambda f: f
    h, w = pred.frame_size if spec == "auto" else cli.frame_size(spec) if isinstance(spec, str) else spec

    def fn(frame):
        if frame.shape[:2] == (h, w):
            return frame
        interp = cv2.INTER_AREA if frame.shape[0] > h else cv2.INTER_LINEAR
        return cv2.resize(frame, (w, h), interpolation=interp)

    return fn


def run(pred: inference.Predictor, frames, out=None, headless=True, smoother=None, warmup=0, bg_frames=1,
        background=None, fps_cap=None, print_every=1, max_frames=None, resize=None, log=print,
        refresh: dict | None = None) -> dict:
    """Drive `pred` over `frames` (iterable of (t, rgb, label)); returns a summary dict.

    Frames before `warmup` are dropped; the next `bg_frames` are averaged into the background (unless
    `background` is given) and then predicted like every later frame. resize: "auto", (H, W) or "HxW".
    refresh ({"threshold": counts, "frames": n}, see `ffjax.live.background`): the background follows the frames
    that show no contact, handed to the predictor every REFRESH_EVERY quiet frames. A None/empty frame is skipped
    and counted; a CameraLost from the source ends the loop cleanly (summary "stopped": "camera_lost", "error"),
    so do a video that decoded fewer frames than it holds ("video_cut") and a failed write ("disk_full", the file
    named); their "error" ends with what was kept. An annotated.mp4 that cannot be played is removed. Dark,
    saturated or background-mismatched frames are still predicted, logged when the issue starts, and counted in
    summary "flagged". forces.csv is written a whole row at a time, unbuffered, so a crash, a kill or a full disk
    leaves whole rows only."""
    resize_fn = resizer(resize, pred)
    retake = {"flag": background is None}
    if background is not None:
        pred.set_background(background)
    old = None
    if headless and hasattr(signal, "SIGUSR1") and threading.current_thread() is threading.main_thread():
        def _on_usr1(signum, frame):
            retake["flag"] = True
        old = signal.signal(signal.SIGUSR1, _on_usr1)
    window = None if headless else Window()
    writer, csv_file, rows = None, None, None
    out = Path(out) if out is not None else None
    lock = contextlib.ExitStack()
    n_done, n_oor, skipped, pending = 0, 0, 0, []
    follow = None  # the BackgroundRefresh once a background is there
    refreshes = 0
    csv_path = video_path = None
    n_rows = n_video = 0  # rows in forces.csv, frames handed to the video writer
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
                if follow is not None:
                    follow.reset(bg)
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
                    # unbuffered, one write per row: a kill or a full disk leaves whole rows only
                    csv_path = _keep_old(out / "forces.csv", log)
                    csv_file = open(csv_path, "wb", buffering=0)
                    rows = True
                    _write_row(csv_file, csv_path, ["t", "fx", "fy", "fz", "out_of_range", "frame"]
                               + (["fx_raw", "fy_raw", "fz_raw"] if smoother else []))
                if rows is not None:
                    _write_row(csv_file, csv_path, [f"{t_i:.4f}", *(f"{v:.5f}" for v in force), int(oor), lab]
                               + ([f"{v:.5f}" for v in raw] if smoother else []))
                    n_rows += 1
                if print_every and n_done % print_every == 0:
                    log(f"t={t_i:9.3f}s  Fx={force[0]:+7.3f}  Fy={force[1]:+7.3f}  Fz={force[2]:+7.3f} N"
                        + ("  [NON-FINITE]" if pred.last_nonfinite[0] else "  [OUT OF RANGE]" if oor else "")
                        + (f"  {rate:6.1f} Hz" if rate else ""))
                if out is not None or window is not None:
                    vis = annotate(f_i, force, pred.force_min, pred.force_max, oor, rate)
                    if out is not None:
                        if writer is None:
                            video_path = _keep_old(out / "annotated.mp4", log)
                            writer = cv2.VideoWriter(str(video_path), cv2.VideoWriter_fourcc(*"mp4v"),
                                                     float(fps_cap or 25.0), (vis.shape[1], vis.shape[0]))
                        # OpenCV's writer fails a frame with a warning and goes on: check the room first
                        _room_for(video_path, 4 * vis.nbytes)
                        writer.write(vis)
                        n_video += 1
                    if window is not None:
                        key = window.show(vis)
                        if key in (ord("q"), 27):
                            raise KeyboardInterrupt
                        if key == ord("b"):
                            retake["flag"] = True
                if refresh and not retake["flag"]:  # the light drifts: follow it on frames without contact
                    follow = follow or BackgroundRefresh(pred.background, **refresh)
                    new = follow.update(f_i)
                    if new is not None and follow.quiet % REFRESH_EVERY == 0:
                        with warnings.catch_warnings():  # checked once, when the background was taken
                            warnings.simplefilter("ignore", inference.BackgroundWarning)
                            pred.set_background(new)
                        refreshes += 1
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
    except VideoCut as e:  # a damaged file: what was decoded is predicted and written; the loss is the error
        stopped, error = "video_cut", str(e)
    except WriteError as e:  # a full disk: stop recording, whole rows and a playable video are kept
        stopped, error = "disk_full", str(e)
    finally:
        if writer is not None:
            writer.release()
        if csv_file is not None:
            csv_file.close()
        # cv2 writes the video's index at release and says nothing when that fails (a full disk): a file it cannot
        # open again is no recording
        playable = video_path is None or _playable(video_path)
        if not playable:
            video_path.unlink(missing_ok=True)
        lock.close()
        if window is not None:
            window.close()
        if old is not None:
            signal.signal(signal.SIGUSR1, old)
    if not playable and error is None and n_video:  # frames were written and are lost (none: a bare header)
        stopped, error = "disk_full", f"{video_path}: could not be completed (is the disk full?)"
    if error is not None and stopped != "camera_lost":
        error += "; " + _kept(csv_path, n_rows, video_path, n_video, playable)
    wall = time.perf_counter() - t_start
    # the rate from the first prediction on: the first frame pays the one-off compile
    rate_hz = (n_done - 1) / (t_prev - t_first) if n_done > 1 and t_prev > t_first else 0.0
    summary = {"frames": n_done, "out_of_range": n_oor, "wall_s": wall, "rate_hz": rate_hz,
               "predict_ms_median": 1e3 * float(np.median(lat)) if lat else None,
               "background_taken": pred.background is not None, "stopped": stopped, "error": error,
               "dropped": empty + int(getattr(frames, "dropped", 0)),
               "reconnects": int(getattr(frames, "reconnected", 0)),
               "flagged": flagged, "csv": str(csv_path) if csv_path else None,
               "background_refreshes": refreshes, "quiet_frames": follow.quiet if follow else 0}
    if n_done == 0 and pred.background is None:
        log("no frame was predicted: the source ended before a background was taken "
            f"(warmup {warmup}, bg-frames {bg_frames})")
    return summary


def _write_row(f, path: Path, values) -> None:
    """One CSV row in one write; on a failed or short write the file is cut back to its last whole row and a
    WriteError names it."""
    line = io.StringIO()
    csv.writer(line).writerow(values)
    data = line.getvalue().encode()
    pos = f.tell()
    try:
        if f.write(data) != len(data):
            raise OSError(errno.ENOSPC, "short write")
    except OSError as e:
        with contextlib.suppress(OSError):
            f.truncate(pos)
        raise WriteError(errno.ENOSPC if e.errno is None else e.errno,
                         f"{path}: cannot write ({e.strerror or e}); recording stopped") from e


def _room_for(path: Path, nbytes: int) -> None:
    """WriteError naming `path` when its disk has less than nbytes free."""
    free = shutil.disk_usage(path.parent).free
    if free < nbytes:
        raise WriteError(errno.ENOSPC, f"{path}: no space left on the device ({free} bytes free); recording "
                                       "stopped")


def _playable(path: Path) -> bool:
    """cv2 opens the video and finds frames in it."""
    cap = cv2.VideoCapture(str(path))
    try:
        return cap.isOpened() and cap.get(cv2.CAP_PROP_FRAME_COUNT) > 0
    finally:
        cap.release()


def _kept(csv_path, n_rows: int, video_path, n_video: int, playable: bool) -> str:
    """What a stopped recording left on disk, for its error line."""
    if csv_path is None:
        return "nothing was written"
    kept = f"kept {csv_path.name} ({n_rows} row{'s' * (n_rows != 1)})"
    if video_path is None:
        return kept
    return f"{kept} and {video_path.name} ({n_video} frame{'s' * (n_video != 1)})" if playable else \
        f"{kept}; {video_path.name} could not be played and was removed"


def _keep_old(path: Path, log=print) -> Path:
    """`path`, after moving an existing file there to the first free `stem.N.suffix` (said in the log)."""
    if path.exists():
        n = 1
        while (old := path.with_name(f"{path.stem}.{n}{path.suffix}")).exists():
            n += 1
        path.rename(old)
        log(f"kept the previous {path.name} as {old.name}")
    return path
