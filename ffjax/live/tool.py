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
(see ffjax.live.filters). --resize HxW|auto resizes frames (auto: the checkpoint's frame size).

The background follows a drifting light (--refresh-background, on by default for --camera, off for files:
a recording replays the same): each frame without a contact moves it 1/--refresh-frames (50) of the way to
that frame; a frame is taken for one without contact when its difference to the background, less each channel's
uniform shift, stays below --refresh-threshold (3) counts everywhere once smoothed over 2 px (see
ffjax.live.background). A real GelSight Mini's LEDs drift by up to 3.5 counts in 3 minutes after start-up.

A full disk stops the recording with one error naming the file and what was kept (exit 1); forces.csv keeps
whole rows only, an annotated.mp4 that cannot be played is removed. A source that gives no frame to predict (an
empty video) is an error (exit 1), and nothing is written. A video that decodes fewer frames than its header
gives (damaged frames are skipped) is predicted as far as it goes, then an error says how many of how many were
read (exit 1). SIGTERM stops the loop like Ctrl-C, with forces.csv and annotated.mp4 closed.

Camera faults: a failed read (dropped frame) is skipped and counted; --max-drops (30) failed reads in a row,
or a read that raises, count as a disconnect: the camera is re-opened up to --reconnects (5) times, waiting
--reconnect-wait (0.5 s) doubling to at most 8 s. If that fails the loop stops, forces.csv (line-buffered)
and annotated.mp4 are closed, the reason is printed, and the exit code is 3. Dark, saturated or
background-mismatched frames are predicted but logged when the condition starts and ends; the closing
summary counts drops, reconnects and flagged frames.
"""

from __future__ import annotations

import argparse
import sys

from ffjax import cli, inference
from ffjax.data.images import read_rgb
from ffjax.files import check_output
from ffjax.live import filters
from ffjax.live.loop import resizer, run
from ffjax.live.sources import camera_frames, image_frames, video_frames


def _fmt(v) -> str:
    return "(" + ", ".join(f"{float(x):.2f}" for x in v) + ")"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m ffjax.live", description=cli.description(__doc__),
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="\n".join(__doc__.splitlines()[1:]))
    p.add_argument("--checkpoint", required=True, help="training run, calibrated or converted folder")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--camera", type=cli.integer(0), help="video device index (cv2.VideoCapture), 0 for the first")
    src.add_argument("--video", help="a video file")
    src.add_argument("--images", help="a folder of frames (sorted by name)")
    p.add_argument("--out", help="folder for forces.csv and annotated.mp4")
    p.add_argument("--headless", action="store_true", help="no window (SIGUSR1 re-takes the background)")
    p.add_argument("--background", help="no-contact frame image file (else captured from the stream)")
    p.add_argument("--warmup", type=cli.integer(0, "0: none"), default=None,
                   help="frames to drop first (camera 30, files 0)")
    p.add_argument("--bg-frames", type=cli.integer(1), default=None, help="frames averaged into the background "
                   "(camera 10, files 1)")
    p.add_argument("--smooth", default=None, help="ema:ALPHA or one-euro:MIN_CUTOFF,BETA[,D_CUTOFF]; off by "
                   "default")
    p.add_argument("--fps", type=cli.number(0), default=None, help="cap the loop rate (and the --images timebase)")
    p.add_argument("--resize", type=_resize_spec, default=None, help="HxW or 'auto' (the checkpoint's frame size)")
    p.add_argument("--frame-size", type=cli.frame_size, default=None,
                   help="HxW the checkpoint expects, if it does not say")
    p.add_argument("--max-frames", type=cli.integer(1), default=None,
                   help="stop after this many predictions (default: when the source ends)")
    p.add_argument("--print-every", type=cli.integer(0, "0: never"), default=1,
                   help="print every Nth frame (0: never)")
    p.add_argument("--which", default="best", choices=("best", "latest"), help=cli.WHICH_HELP)
    p.add_argument("--refresh-background", default="auto", choices=("auto", "on", "off"),
                   help="follow a drifting light on frames without contact (auto: on for --camera)")
    p.add_argument("--refresh-threshold", type=cli.number(0), default=3.0,
                   help="counts: a frame whose smoothed difference to the background stays below is without contact")
    p.add_argument("--refresh-frames", type=cli.integer(1), default=50,
                   help="quiet frames the refreshed background averages")
    cam = p.add_argument_group("camera faults (--camera)")
    cam.add_argument("--max-drops", type=cli.integer(1), default=30, help="failed reads in a row that count as a "
                     "disconnect (single failed reads are skipped and counted)")
    cam.add_argument("--reconnects", type=cli.integer(0, "0: exit at the first disconnect"), default=5,
                     help="re-open attempts per disconnect before exiting")
    cam.add_argument("--reconnect-wait", type=cli.number(0, inclusive=True), default=0.5,
                     help="seconds before the first re-open; doubles per attempt, at most 8 s")
    return p


def _resize_spec(text: str):
    """argparse type of --resize: 'auto' or HxW as (H, W)."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return cli.frame_size(text)
    except cli.BadValue:
        raise cli.BadValue(f"expected HxW such as 240x320 (both >= 1) or 'auto', got {text!r}") from None


def main(argv=None) -> int:
    ap = build_parser()
    a = ap.parse_args(argv)
    if a.out:  # recordings already there are kept aside, never replaced; but never inside what is read
        check_output(a.out, reads=[a.checkpoint, a.images], force=True)
        cli.check_out(ap, a.out)  # a read-only or impossible folder: a usage error naming --out, before the camera
    pred = inference.load(a.checkpoint, a.which, frame_size=a.frame_size)
    smoother = filters.parse(a.smooth)
    background = None
    if a.background:
        background = resizer(a.resize, pred)(read_rgb(a.background, "background"))
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
    bg_frames = bg_frames if a.bg_frames is None else a.bg_frames
    print(f"ffjax.live: {pred.method} ({pred.trained.kind}), frames {pred.frame_size[0]}x{pred.frame_size[1]} "
          f"RGB, training force range {_fmt(pred.force_min)}..{_fmt(pred.force_max)} N"
          + (f", filter {smoother!r}" if smoother else ""), flush=True)
    follow = a.refresh_background == "on" or (a.refresh_background == "auto" and a.camera is not None)
    with cli.sigterm_as_interrupt():  # a stopped loop closes its files as on Ctrl-C: the video stays playable
        summary = run(pred, frames, out=a.out, headless=a.headless, smoother=smoother, warmup=warmup,
                      bg_frames=bg_frames, background=background, fps_cap=a.fps, print_every=a.print_every,
                      max_frames=a.max_frames, resize=a.resize, log=lambda s: print(s, flush=True),
                      refresh={"threshold": a.refresh_threshold, "frames": a.refresh_frames} if follow else None)
    if summary["frames"] == 0 and summary["stopped"] == "end":
        source = a.video or a.images or f"camera {a.camera}"
        return cli.fail(f"{source}: no frame to predict (the source is empty or ended before a background was "
                        f"taken: warmup {warmup}, bg-frames {bg_frames}); nothing written")
    print(f"{summary['frames']} frames in {summary['wall_s']:.1f} s ({summary['rate_hz']:.1f} Hz after the first), "
          f"model {summary['predict_ms_median'] or 0:.2f} ms/frame median, "
          f"{summary['out_of_range']} out of range" + (f"; wrote {summary['csv']}" if summary["csv"] else "")
          + (f"; background refreshed {summary['background_refreshes']} times" if follow else ""))
    faults = [f"{summary['dropped']} dropped frames"] * bool(summary["dropped"]) + \
        [f"{summary['reconnects']} reconnects"] * bool(summary["reconnects"]) + \
        [f"{n} {k}" for k, n in summary["flagged"].items()]
    if faults:
        print("faults: " + ", ".join(faults), flush=True)
    if summary["stopped"] == "camera_lost":
        print(f"error: {summary['error']}; forces up to the loss are in the CSV", file=sys.stderr, flush=True)
        return 3
    if summary["stopped"] in ("disk_full", "video_cut"):
        return cli.fail(summary["error"])
    return 0 if summary["frames"] else 1
