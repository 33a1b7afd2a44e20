"""Following a sensor whose light drifts: the background refreshed from frames that show no contact.

A real GelSight Mini's LEDs drift after start-up (the release's recording at rest: -3.5 counts in red over 3
minutes, docs/simulator.md), so a background taken once leaves a growing offset in every difference image. The
rule, from the frame alone (no model, so a model's error cannot feed back into its own background):
- the difference to the current background, each channel less its median (a uniform shift: drift), smoothed
  over SMOOTH_PX pixels (the camera's noise averages out, a contact's imprint does not);
- a frame is quiet when the largest smoothed residual is below `threshold` counts: a contact leaves a local
  structure well above it, a drifting light a near-uniform shift well below it;
- each quiet frame moves the background a step 1/`frames` of the way to it (an exponential average of
  `frames` frames); a frame with a contact leaves it as it is.
"""

from __future__ import annotations

import cv2
import numpy as np

SMOOTH_PX = 2.0  # Gaussian sigma of the residual's smoothing, pixels


class BackgroundRefresh:
    """Refreshes a background from quiet frames: `update(frame)` returns the new background (uint8) or None when
    the frame shows a contact (the background stays)."""

    def __init__(self, background, threshold: float = 3.0, frames: int = 50):
        if threshold <= 0 or frames < 1:
            raise ValueError(f"threshold must be > 0 counts and frames >= 1, got {threshold}, {frames}")
        self.threshold, self.frames = float(threshold), int(frames)
        self.reset(background)

    def reset(self, background) -> None:
        """Start again from a background (a re-take)."""
        self.mean = np.asarray(background, np.float32).copy()
        self.quiet = self.busy = 0

    def residual(self, frame) -> float:
        """The largest local difference to the background (counts), after removing each channel's uniform shift."""
        d = np.asarray(frame, np.float32) - self.mean
        d -= np.median(d.reshape(-1, d.shape[-1]), axis=0)
        return float(np.abs(cv2.GaussianBlur(d, (0, 0), SMOOTH_PX)).max())

    def update(self, frame) -> np.ndarray | None:
        if self.residual(frame) >= self.threshold:
            self.busy += 1
            return None
        self.quiet += 1
        self.mean += (np.asarray(frame, np.float32) - self.mean) / self.frames
        return np.clip(self.mean.round(), 0, 255).astype(np.uint8)
