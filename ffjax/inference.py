"""Load a checkpoint and predict forces (newtons) from raw sensor frames.

    from ffjax import inference
    model = inference.load("runs/quick_dino_rd")     # a training run, a calibrated or a converted folder
    model.set_background(bg)                          # the sensor's no-contact frame, uint8 RGB (H, W, 3)
    forces = model.predict(frames)                    # (N, H, W, 3) or (H, W, 3) uint8 RGB -> (N, 3) float32 N
    model.last_out_of_range                           # (N,) bool: outside the training force range
    model.last_nonfinite                              # (N,) bool: NaN/inf forces (corrupt weights or input)
    depth = model.predict_depth(frames)               # (N, H, W) mm, when the model has a depth head

Inputs: uint8 frames, (H, W, 3) or (N, H, W, 3), channel order RGB (what `ffjax.data` reads and trains on).
Frames straight from OpenCV (`cv2.VideoCapture.read`, `cv2.imread`) are BGR: pass `bgr=True` to
set_background/predict/predict_depth, or convert once with `frame[..., ::-1]` / cv2.cvtColor(f, cv2.COLOR_BGR2RGB).
`ffjax.data.images.read_rgb`, PIL and imageio give RGB already. BGR passed as RGB is not an error (it cannot
be told apart per frame), but when the checkpoint has a reference background (see ffjax.store: model.json
"background_stats", a sensor.json, or a calibrated bundle's background.png) set_background warns if the
reversed channel order matches it better.

What is refused (raised) vs flagged (warned, per frame), so a control loop never dies on one bad frame:
  raised   None, a non-uint8 dtype, a rank other than 3/4, a channel count other than 3, a frame size other
           than the checkpoint's (strict_size=True) or the background's: these can never work
  flagged  all-black ("dark"), saturated ("saturated") or frames that do not look like the background
           ("background_mismatch": a background from another sensor, or the sensor moved / lighting changed):
           forces are still returned; `last_frame_issues` ((N,) str, "" when fine) says which, and a
           FrameWarning is given (a constant message: Python shows it once per call site, not every frame)
  warned   set_background: a dark or saturated background, or one whose per-channel mean/std differ from the
           checkpoint's recorded background (BackgroundWarning; compare with `background_check`)

Preprocessing is `ffjax.data.preprocess_image` with the checkpoint's statistics, the same function training
used (numpy/cv2, once per frame); the network is one jitted apply, compiled once per batch shape.

`load` accepts every folder `ffjax.store.load` reads (a training run, a calibrated bundle, converted release
weights) and where it finds the expected frame size (H, W). Frames of another size or channel count are
refused with a message; `strict_size=False` accepts any size that matches the background (a warning is given).
"""

from __future__ import annotations

import functools
import time
import warnings

import cv2
import jax
import numpy as np

from ffjax import data as fdata
from ffjax import store
from ffjax.store import CHANNELS, Trained


class ForceRangeWarning(UserWarning):
    """A prediction lies outside the force range the model was trained on."""


class NonFiniteWarning(UserWarning):
    """A prediction is NaN or infinite: the weights (or the input) are corrupt; never act on it."""


class FrameWarning(UserWarning):
    """A frame is dark, saturated, or does not look like the background; its forces are unreliable."""


class BackgroundWarning(UserWarning):
    """The background is dark/saturated or does not match the checkpoint's training background."""


# Frame checks, in uint8 grey levels. Matching frames differ from their background by ~3 levels (median, noise
# and the contact patch); a background of another sensor by ~15-60 (simulated Minis vs DIGIT).
DARK_MEAN = 10.0  # mean level below this: lights off, lens covered, a black frame from a failing camera
SATURATED_LEVEL, SATURATED_FRACTION = 250, 0.5  # over half the pixels clipped in some channel: over-exposed
MISMATCH_MEDIAN = 12.0  # median |frame - background| above this: the background is not this sensor's
BG_MEAN_TOL, BG_STD_RATIO = 15.0, 2.0  # background vs the recorded one: per-channel mean / std ratio tolerance


background_stats = fdata.stats.background_stats  # shared with training, which records it in model.json


def _level_issue(x: np.ndarray) -> str:
    """"dark", "saturated" or "" for one uint8 (H, W, 3) frame (subsampled: this runs per live frame)."""
    x = x[::4, ::4]
    if x.mean() < DARK_MEAN:
        return "dark"
    if (x >= SATURATED_LEVEL).mean(axis=(0, 1)).max() > SATURATED_FRACTION:
        return "saturated"
    return ""


def frame_issues(frames: np.ndarray, background: np.ndarray) -> list[str]:
    """Per frame of (N, H, W, 3) uint8: "dark", "saturated", "background_mismatch" or "" (fine)."""
    bg = background[::4, ::4].astype(np.int16)
    out = []
    for f in frames:
        issue = _level_issue(f)
        if not issue and np.median(np.abs(f[::4, ::4].astype(np.int16) - bg)) > MISMATCH_MEDIAN:
            issue = "background_mismatch"
        out.append(issue)
    return out


def background_check(background, reference: dict | None) -> list[str]:
    """Problems with a uint8 RGB background (empty: none): dark/saturated, or per-channel statistics off
    the reference (model.json "background_stats") by more than BG_MEAN_TOL levels / a BG_STD_RATIO factor."""
    issue = _level_issue(background)
    if issue:
        return [f"the background is {issue} (mean level {background.mean():.0f}): take it with the sensor's "
                f"lights on and nothing touching the gel"]
    if not reference:
        return []
    got = background_stats(background)
    ref_m, ref_s = np.asarray(reference["mean"], float), np.asarray(reference["std"], float)
    m, sd = np.asarray(got["mean"]), np.asarray(got["std"])
    ratio = np.maximum(sd, 1e-3) / np.maximum(ref_s, 1e-3)
    if np.all(np.abs(m - ref_m) <= BG_MEAN_TOL) and np.all((ratio <= BG_STD_RATIO) & (ratio >= 1 / BG_STD_RATIO)):
        return []
    msg = (f"the background's per-channel mean {_r(m)} / std {_r(sd)} (RGB) differ from the checkpoint's "
           f"training background {_r(ref_m)} / {_r(ref_s)} (tolerance +-{BG_MEAN_TOL:g} levels, std x{BG_STD_RATIO:g}):"
           f" another sensor or gel? Forces may be off; calibrate for this sensor (python -m ffjax.calibrate)")
    if np.abs(m[::-1] - ref_m).max() < np.abs(m - ref_m).max() and np.abs(m[::-1] - ref_m).max() <= BG_MEAN_TOL:
        msg += "; the reversed channel order matches: is it BGR (OpenCV)? pass bgr=True"
    return [msg]


def _r(v) -> list[float]:
    return [round(float(x), 1) for x in v]


@functools.lru_cache(maxsize=16)
def _apply_fns(model):
    """Jitted force / depth applies, one pair per model config (linen modules hash by their fields), so
    re-loading a checkpoint of the same architecture reuses the compiled code."""
    return (jax.jit(lambda v, x: model.apply(v, x, train=False)["force"]),
            jax.jit(lambda v, x: model.apply(v, x, train=False)["depth"]))


class Predictor:
    """Forces from raw uint8 RGB frames (bgr=True for OpenCV's BGR); see the module docstring for what is
    refused and what is flagged. Not thread-safe (last_* attributes)."""

    def __init__(self, trained: Trained, strict_size: bool = True, range_margin: float = 0.05):
        self.trained = trained
        self.strict_size = strict_size
        self.range_margin = float(range_margin)
        self.model = trained.build()
        self.variables = jax.device_put(trained.variables)
        self._force_fn, depth_fn = _apply_fns(self.model)
        self._depth_fn = depth_fn if trained.spec.depth_head else None
        self.background: np.ndarray | None = None
        self.background_issues: list[str] = []
        self.last_out_of_range = np.zeros((0,), bool)
        self.last_nonfinite = np.zeros((0,), bool)
        self.last_frame_issues = np.zeros((0,), object)
        self.last_timing: dict = {}

    # -- what the checkpoint expects -------------------------------------------------------------------
    @property
    def stats(self) -> fdata.Stats:
        return self.trained.stats

    @property
    def input_size(self) -> int:
        """Side of the square model input (after background subtraction, pad, resize)."""
        return self.trained.input_size

    @property
    def frame_size(self) -> tuple[int, int]:
        """(H, W) of the frames the model was trained on (see the module docstring for where it comes from)."""
        return self.trained.frame_size

    @property
    def frame_size_source(self) -> str:
        return self.trained.frame_size_source

    @property
    def force_min(self) -> np.ndarray:
        return np.asarray(self.stats.force_min, np.float32)

    @property
    def force_max(self) -> np.ndarray:
        return np.asarray(self.stats.force_max, np.float32)

    @property
    def has_depth(self) -> bool:
        return self._depth_fn is not None

    @property
    def method(self) -> str:
        return self.trained.spec.name

    def describe(self) -> dict:
        return {"method": self.method, "kind": self.trained.kind, "input_size": self.input_size,
                "frame_size": list(self.frame_size), "frame_size_source": self.frame_size_source,
                "channels": CHANNELS, "force_min": self.force_min.tolist(), "force_max": self.force_max.tolist(),
                "depth_head": self.has_depth, "background_stats": self.trained.background_stats}

    # -- inputs ----------------------------------------------------------------------------------------
    def _check(self, images, bgr: bool, what: str) -> np.ndarray:
        """Raise for inputs that can never work (naming `what`, expected vs got); RGB uint8 out."""
        if images is None:
            raise TypeError(f"{what} is None, expected a uint8 array (H, W, 3) RGB (a failed camera read? check "
                            f"the `ok` flag of cap.read())")
        x = np.asarray(images)
        if x.dtype != np.uint8:
            hint = (" (floats in [0, 1]? use (x * 255).round().astype(np.uint8))" if x.dtype.kind == "f" else
                    " (16-bit frames? scale to 8 bits: (x >> 8).astype(np.uint8))" if x.dtype == np.uint16 else "")
            raise TypeError(f"{what} must be uint8 (raw camera pixels), got {x.dtype}{hint}")
        if x.ndim not in (3, 4):
            hint = " (a grayscale frame? this model needs the sensor's colour frames)" if x.ndim == 2 else ""
            raise ValueError(f"{what} must be (H, W, 3) or (N, H, W, 3), got shape {x.shape}{hint}")
        if x.shape[-1] != 3:
            hint = " (BGRA/RGBA: drop the alpha channel)" if x.shape[-1] == 4 else \
                " (grayscale: this model needs the sensor's colour frames)" if x.shape[-1] == 1 else \
                " (channels first? use (H, W, 3) order, e.g. x.transpose(1, 2, 0))" if x.shape[-3] == 3 else ""
            raise ValueError(f"{what} has {x.shape[-1]} channels (shape {x.shape}), the model needs 3 ({CHANNELS})"
                             f"{hint}")
        hw = tuple(int(v) for v in x.shape[-3:-1])
        if hw != tuple(int(v) for v in self.frame_size):  # a list [24, 32] is the same size as (24, 32)
            msg = (f"{what} is {hw[0]}x{hw[1]} (HxW) but this checkpoint was trained on {self.frame_size[0]}x"
                   f"{self.frame_size[1]} frames (from {self.frame_size_source}); resize/crop the camera frames "
                   f"to that size, calibrate for this sensor (python -m ffjax.calibrate), or load with "
                   f"frame_size=/strict_size=False")
            if self.strict_size:
                raise ValueError(msg)
            warnings.warn(msg, stacklevel=3)
        if bgr:
            x = x[..., ::-1]
        return np.ascontiguousarray(x)

    def set_background(self, background, bgr: bool = False) -> None:
        """The no-contact frame (uint8 (H, W, 3), RGB; bgr=True for OpenCV frames); re-take it when lighting
        or the gel changes. Warns (BackgroundWarning) when it is dark/saturated or its statistics differ from
        the checkpoint's training background; `background_issues` keeps the messages."""
        x = np.asarray(background) if background is not None else None
        if x is not None and x.ndim == 4 and x.shape[0] == 1:
            x = x[0]  # a batch of one frame is one frame
        bg = self._check(x, bgr, "background")
        if bg.ndim != 3:
            raise ValueError(f"background must be one frame (H, W, 3), got shape {bg.shape} (average several "
                             f"frames with np.mean(frames, 0).round().astype(np.uint8))")
        self.background_issues = background_check(bg, self.trained.background_stats)
        for msg in self.background_issues:
            warnings.warn(msg, BackgroundWarning, stacklevel=2)
        # a copy, read-only: a camera buffer the caller reuses must not change every later prediction
        self.background = bg.copy()
        self.background.setflags(write=False)

    def preprocess(self, images, bgr: bool = False) -> np.ndarray:
        """Raw frames -> the model input (N, S, S, 3) float32, exactly as in training. Sets
        `last_frame_issues` ((N,) str: "dark", "saturated", "background_mismatch" or "")."""
        if self.background is None:
            raise RuntimeError("no background: call set_background(no_contact_frame) first")
        x = self._check(images, bgr, "image")
        if x.shape[-3:] != self.background.shape:
            raise ValueError(f"image is {x.shape[-3]}x{x.shape[-2]} but the background is "
                             f"{self.background.shape[0]}x{self.background.shape[1]} (HxW): take the background "
                             f"from the same camera at the same resolution")
        batch = x[None] if x.ndim == 3 else x
        self.last_frame_issues = np.array(frame_issues(batch, self.background), dtype=object)
        if any(self.last_frame_issues):
            kinds = sorted({i for i in self.last_frame_issues if i})
            # constant text per kind: Python's default filter then shows it once, not every frame
            warnings.warn(f"frame(s) flagged {'/'.join(kinds)}: forces for them are unreliable (see "
                          f"last_frame_issues)", FrameWarning, stacklevel=3)
        return fdata.preprocess_image(batch, self.background, self.stats, self.input_size)

    # -- outputs ---------------------------------------------------------------------------------------
    def out_of_range(self, forces) -> np.ndarray:
        """(N,) bool: any axis outside [min, max] of the training labels widened by range_margin * span;
        zero (no contact) always counts as inside, so an unloaded sensor is not flagged; NaN/inf is outside."""
        f = np.asarray(forces, np.float32).reshape(-1, 3)
        lo, hi = np.minimum(self.force_min, 0), np.maximum(self.force_max, 0)
        tol = self.range_margin * (hi - lo)
        return np.any((f < lo - tol) | (f > hi + tol) | ~np.isfinite(f), axis=1)

    def predict(self, images, bgr: bool = False) -> np.ndarray:
        """(N, H, W, 3) or (H, W, 3) uint8 -> forces (N, 3) float32 in newtons (Fx, Fy, Fz).

        Sets `last_out_of_range` ((N,) bool, NaN/inf included), `last_nonfinite` ((N,) bool: NaN or inf, with
        a NonFiniteWarning), `last_frame_issues` ((N,) str, see preprocess) and
        `last_timing` (preprocess_s, model_s); warns with ForceRangeWarning when a prediction is outside the
        training range and FrameWarning for flagged frames. Flagged frames still get forces (a control loop
        decides what to do with them); only inputs that can never work raise."""
        t0 = time.perf_counter()
        x = self.preprocess(images, bgr)
        t1 = time.perf_counter()
        forces = np.asarray(self._force_fn(self.variables, x), np.float32)
        self.last_timing = {"preprocess_s": t1 - t0, "model_s": time.perf_counter() - t1}
        self.last_out_of_range = self.out_of_range(forces)
        self.last_nonfinite = ~np.isfinite(forces).all(axis=1)
        if self.last_nonfinite.any():
            warnings.warn("non-finite (NaN/inf) forces: the checkpoint's weights or the input are corrupt; do not "
                          "act on them (see last_nonfinite)", NonFiniteWarning, stacklevel=2)
        elif self.last_out_of_range.any():
            # a constant message: Python's default filter then shows it once, not every frame
            lo, hi = ([round(float(v), 3) for v in r] for r in (self.force_min, self.force_max))
            warnings.warn(f"predictions outside the training force range {lo}..{hi} N (see last_out_of_range)",
                          ForceRangeWarning, stacklevel=2)
        return forces

    def predict_depth(self, images, bgr: bool = False, frame: bool = True) -> np.ndarray:
        """Gel deformation depth in mm: (N, H, W) on the frame's grid (frame=True: un-padded and resized
        back), or (N, S, S) on the model's square input grid (frame=False)."""
        if self._depth_fn is None:
            raise ValueError(f"method {self.method!r} has no depth head; use a *_rd checkpoint for depth")
        x = self.preprocess(images, bgr)
        if not len(x):  # no frames, no depth maps (as predict gives (0, 3))
            h, w = self.background.shape[:2] if frame else x.shape[1:3]
            return np.zeros((0, h, w), np.float32)
        d = fdata.depth_to_mm(np.asarray(self._depth_fn(self.variables, x)), self.stats)
        return np.stack([self._to_frame(m) for m in d]) if frame else d

    def _to_frame(self, d: np.ndarray) -> np.ndarray:
        h, w = self.background.shape[:2]
        side = max(h, w)
        top, left = (side - h) // 2, (side - w) // 2
        full = cv2.resize(d, (side, side), interpolation=cv2.INTER_LINEAR)
        return full[top:top + h, left:left + w]

    def warmup(self, batch: int = 1) -> None:
        """Compile for this batch size now (first predict otherwise pays it); needs a background."""
        if self.background is None:
            raise RuntimeError("no background: call set_background first")
        self.predict(np.repeat(self.background[None], batch, 0))


def load(checkpoint_dir, which: str = "best", frame_size=None, strict_size: bool = True,
         range_margin: float = 0.05) -> Predictor:
    """A Predictor for any folder `ffjax.store.load` reads. which: "best" or "latest" (training runs)."""
    return Predictor(store.load(checkpoint_dir, which, frame_size), strict_size, range_margin)
