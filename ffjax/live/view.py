"""What the live loop shows and records: the annotated frame (Fx,Fy arrow, Fz bar, the numbers) and the OpenCV
window, which falls back to headless where the OpenCV build has no GUI."""

from __future__ import annotations

import sys

import cv2
import numpy as np


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


class Window:
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
