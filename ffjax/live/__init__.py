"""Live force view: a camera (or a video / folder of frames) in, forces out. `python -m ffjax.live`: see
ffjax.live.tool for the command line, its flags and what it writes.

    sources  frames from a camera (dropped frames, reconnects, CameraLost), a video file (VideoCut) or an image
             folder
    filters  EMA and One-Euro smoothing of the force stream (--smooth)
    view     the annotated frame (arrow, Fz bar, numbers) and the window
    loop     run(): background, prediction and flags per frame, forces.csv and annotated.mp4
    tool     build_parser, main
"""

from ffjax.live.loop import run
from ffjax.live.sources import CameraFrames, CameraLost, VideoCut, camera_frames, image_frames, video_frames
from ffjax.live.tool import build_parser, main
from ffjax.live.view import annotate

__all__ = [
    "CameraFrames", "CameraLost", "VideoCut", "annotate", "build_parser", "camera_frames", "image_frames", "main",
    "run", "video_frames",
]
