"""Force readers for the tasks: a trained checkpoint (via ffjax.inference) with fixed-size batches, so
the jitted network compiles once however many frames a scene hands it."""

from __future__ import annotations

import warnings

import numpy as np

from ffjax import inference
from ffjax.inference import ForceRangeWarning


class ModelSensor:
    """estimate(frames (N,H,W,3) uint8, background (H,W,3) uint8) -> forces (N, 3) in N."""

    BUCKETS = (16,)  # the one batch shape compiled: every call is cut or padded to it

    def __init__(self, run_dir, which: str = "best"):
        self.run_dir = str(run_dir)
        self.predictor = inference.load(run_dir, which=which)
        self.method = self.predictor.method
        self.out_of_range = 0
        self.frames_seen = 0
        self._said: set[str] = set()

    @property
    def frame_size(self) -> tuple[int, int]:
        return tuple(self.predictor.frame_size)

    def __call__(self, frames: np.ndarray, background: np.ndarray) -> np.ndarray:
        frames = np.asarray(frames)
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            self.predictor.set_background(background)
        for w in said:  # a scene alternates sensors (the gripper's two jaws): each warning once, not per call
            if str(w.message) not in self._said:
                self._said.add(str(w.message))
                warnings.warn(w.message, stacklevel=2)
        out = np.empty((len(frames), 3), np.float32)
        big = self.BUCKETS[-1]
        for i in range(0, len(frames), big):
            part = frames[i : i + big]
            n = len(part)
            size = next(b for b in self.BUCKETS if b >= n)
            if n < size:  # pad to a compiled batch shape
                part = np.concatenate([part, np.repeat(part[-1:], size - n, 0)])
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ForceRangeWarning)
                pred = self.predictor.predict(part)
            self.out_of_range += int(self.predictor.last_out_of_range[:n].sum())
            out[i : i + n] = pred[:n]
        self.frames_seen += len(frames)
        return out
