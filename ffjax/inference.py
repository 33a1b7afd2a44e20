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
`ffjax.data.sources.read_rgb`, PIL and imageio give RGB already. BGR passed as RGB is not an error (it cannot
be told apart per frame), but when the checkpoint has a reference background (see read_checkpoint: model.json
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

Folders `load` accepts (`read_checkpoint` tells them apart):
  training run   RUN/model.json + RUN/best/ (+ checkpoints/), written by `ffjax.train`
  bundle         DIR/model.json + DIR/variables.msgpack, written by `ffjax.calibrate` (`save_bundle`)
  converted      DIR/convert.json + DIR/variables.msgpack, written by `python -m ffjax.convert feelanyforce`.
                 It holds no statistics: the release's are used (RELEASE_STATS: normalization mean/std and
                 depth range from its code, input 224 from convert.json, force range (-2,-2,0)..(2,2,15) N
                 approximated from the paper). A `stats.json` (a data.Stats dict) beside it overrides them.

Expected frame size (H, W), the first that applies: the `frame_size` argument; "frame_size" in model.json
(bundles record it); "frame_size" in a `sensor.json` beside the weights; 240x320 (GelSight Mini) for a
converted release checkpoint; else the run's cfg["data"]["render_size"] (the simulator frames of its
preset; `frame_size_source` says "assumed" then). Frames of another size or channel count are refused
with a message; `strict_size=False` accepts any size that matches the background (a warning is given).
"""

from __future__ import annotations

import functools
import hashlib
import json
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import jax
import numpy as np

from ffjax import data as fdata
from ffjax.jsontree import retuple

CHANNELS = "RGB"
BUNDLE_FORMAT = "ffjax.predictor/1"
MODEL_JSON, VARIABLES, SENSOR_JSON, STATS_JSON = "model.json", "variables.msgpack", "sensor.json", "stats.json"
RELEASE_FRAME = (240, 320)
# The FeelAnyForce release's normalization (REFERENCE.md); depth range is min - eps, max + eps, eps 5, in the
# release's depth units. Force range: approximate, from the paper's dataset description.
RELEASE_STATS = {
    "mean": [0.3654, 0.3716, 0.3693],
    "std": [0.2120, 0.2151, 0.2137],
    "depth_min": -8.3115 - 5.0,
    "depth_max": 27.0323 + 5.0,
    "force_min": [-2.0, -2.0, 0.0],
    "force_max": [2.0, 2.0, 15.0],
    "input_size": 224,
    "depth_eps": 5.0,
}


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


@dataclass
class Checkpoint:
    """Everything a predictor needs, whichever folder it came from."""

    cfg: dict  # full config (model section used to rebuild the network; calibrate section for defaults)
    spec: object  # registry.Method
    stats: fdata.Stats
    variables: dict
    input_size: int
    frame_size: tuple[int, int]
    frame_size_source: str
    kind: str  # "run" | "bundle" | "converted"
    path: str
    info: dict = field(default_factory=dict)
    background_stats: dict | None = None  # the training background's per-channel mean/std, when recorded

    def build_model(self):
        from ffjax import models

        return models.build(self.cfg["model"], self.spec, self.input_size)


def _read_json(path: Path) -> dict | None:
    """The JSON object in `path` (None if there is no file); CheckpointError naming the file otherwise."""
    from ffjax.train.checkpoint import CheckpointError

    if not path.is_file():
        return None
    try:
        obj = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as e:
        raise CheckpointError(f"{path} is not valid JSON (truncated, or not written by ffjax): {e}") from e
    if not isinstance(obj, dict):
        raise CheckpointError(f"{path} holds a JSON {type(obj).__name__}, not an object: not written by ffjax")
    return obj


def _frame_size(folder: Path, info: dict, override, fallback, fallback_source: str):
    if override is not None:
        return tuple(int(v) for v in override), "argument"
    if info.get("frame_size"):
        return tuple(int(v) for v in info["frame_size"]), MODEL_JSON
    sensor = _read_json(folder / SENSOR_JSON)
    if sensor and sensor.get("frame_size"):
        return tuple(int(v) for v in sensor["frame_size"]), SENSOR_JSON
    return tuple(int(v) for v in fallback), fallback_source


def read_checkpoint(path, which: str = "best", frame_size=None) -> Checkpoint:
    """Read a training run, a bundle (model.json + variables.msgpack) or a converted release folder.

    The training background's statistics ("background_stats": {"mean", "std"} per RGB channel) come from
    model.json, else a sensor.json beside the weights, else a background.png there (calibrated bundles keep
    the sensor's); set_background compares against them."""
    ckpt = _read_checkpoint(Path(path), which, frame_size)
    ckpt.background_stats = _reference_background(Path(path), ckpt.info)
    return ckpt


def _reference_background(folder: Path, info: dict) -> dict | None:
    for source in (info, _read_json(folder / SENSOR_JSON) or {}):
        if source.get("background_stats"):
            return source["background_stats"]
    if (folder / "background.png").is_file():
        from ffjax.data.sources import read_rgb

        try:
            return background_stats(read_rgb(folder / "background.png"))
        except Exception as e:  # noqa: BLE001 - a reference is optional: a bad file only loses the check
            warnings.warn(f"{folder / 'background.png'} unreadable ({e}): no background check", stacklevel=3)
    return None


def _read_checkpoint(folder: Path, which: str, frame_size) -> Checkpoint:

    import configs
    from ffjax import registry

    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such checkpoint folder")
    info = _read_json(folder / MODEL_JSON)
    if info is not None and (folder / VARIABLES).is_file():  # bundle
        return _read_bundle(folder, info, frame_size)
    if info is not None and info.get("format") == BUNDLE_FORMAT:  # not a run: "no best checkpoint" would mislead
        from ffjax.train.checkpoint import CheckpointError

        raise CheckpointError(f"{folder / VARIABLES} is missing: {folder} is a bundle (its {MODEL_JSON} says so) "
                              "without its weights; copy the whole folder again")
    if info is not None:  # training run
        from ffjax import train

        cfg, spec, stats, variables = train.load_checkpoint(folder, which)
        fs, src = _frame_size(folder, info, frame_size, cfg["data"]["render_size"], "assumed")
        return Checkpoint(cfg, spec, stats, variables, int(info["input_size"]), fs, src, "run", str(folder),
                          info)
    if (folder / "convert.json").is_file():
        from ffjax.convert import store

        meta = store.read_meta(folder)
        if meta["kind"] != "feelanyforce" or "regressor" not in meta["model"]:
            raise ValueError(f"{folder} holds converted {meta['kind']} backbone weights, not a force model: "
                             f"use it to start training (--init), then load the run")
        model_cfg, variables = store.load(folder)
        cfg = configs.get("paper")
        cfg["model"].update(retuple(model_cfg))
        size = int(meta.get("input_size", 224))
        stats_d = _read_json(folder / STATS_JSON) or {**RELEASE_STATS, "input_size": size}
        stats = fdata.Stats.from_dict(stats_d)
        fs, src = _frame_size(folder, {}, frame_size, RELEASE_FRAME, "release default (GelSight Mini)")
        spec = registry.get("dino_rd" if "decoder" in model_cfg else "dino_r")
        return Checkpoint(cfg, spec, stats, variables, size, fs, src, "converted", str(folder), meta)
    raise FileNotFoundError(
        f"{folder}: not a checkpoint folder; expected {MODEL_JSON} (a training run or calibrated bundle) or "
        f"convert.json + {VARIABLES} (python -m ffjax.convert feelanyforce ...)")


_BUNDLE_KEYS = ("method", "input_size", "stats", "cfg")


def _read_bundle(folder: Path, info: dict, frame_size) -> Checkpoint:
    """A calibrated/exported bundle, checked: ffjax's model.json keys, the weights' sha256 (recorded by
    save_bundle; older bundles carry none), and every tensor's shape against the model model.json describes."""
    from flax import serialization

    from ffjax.train.checkpoint import CheckpointError, saved_model

    missing = [k for k in _BUNDLE_KEYS if k not in info]
    if missing:
        raise CheckpointError(f"{folder / MODEL_JSON} lacks {missing}: not an ffjax model.json")
    raw = (folder / VARIABLES).read_bytes()
    digest = info.get("variables_sha256")
    if digest and hashlib.sha256(raw).hexdigest() != digest:
        raise CheckpointError(f"{folder / VARIABLES} is corrupt or truncated ({len(raw)} bytes): its sha256 differs "
                              f"from the one in {MODEL_JSON}; copy or export the bundle again")
    try:
        variables = serialization.msgpack_restore(raw)
        saved = saved_model(info, folder / MODEL_JSON)  # the reader training runs use too
    except Exception as e:  # noqa: BLE001 - msgpack, config and registry errors all mean one thing here
        raise CheckpointError(f"cannot read the bundle {folder} ({type(e).__name__}: {str(e)[:200]}): "
                              f"{VARIABLES} truncated or {MODEL_JSON} not ffjax's") from e
    cfg, stats, spec, size = saved.cfg, saved.stats, saved.spec, saved.input_size
    abstract = saved.abstract_variables()
    want = {k: abstract[k] for k in ("params", "batch_stats") if abstract.get(k)}
    got = {k: variables.get(k) for k in want}
    ok = jax.tree.structure(want) == jax.tree.structure(got) and all(
        tuple(a.shape) == tuple(np.shape(b)) for a, b in zip(jax.tree.leaves(want), jax.tree.leaves(got)))
    if not ok:
        raise CheckpointError(f"{folder / VARIABLES} does not hold the weights of the {spec.name} model "
                              f"{MODEL_JSON} describes (different tensors or shapes)")
    fs, src = _frame_size(folder, info, frame_size, cfg["data"]["render_size"], "assumed")
    return Checkpoint(cfg, spec, stats, variables, size, fs, src, "bundle", str(folder), info)


def save_bundle(out, ckpt: Checkpoint, variables: dict | None = None, frame_size=None, background=None,
                **extra) -> Path:
    """Write a self-contained folder (model.json + variables.msgpack) that `load` accepts.

    background: the sensor's no-contact frame (uint8 RGB); its statistics are recorded so a predictor can
    warn about a background from another sensor (default: the checkpoint's recorded ones, if any)."""
    import dataclasses

    from flax import serialization

    from ffjax.train.checkpoint import atomic_write_bytes, atomic_write_text

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tree = jax.tree.map(np.asarray, ckpt.variables if variables is None else variables)
    raw = serialization.msgpack_serialize(tree)
    atomic_write_bytes(out / VARIABLES, raw)
    info = {
        "format": BUNDLE_FORMAT,
        "method": ckpt.spec.name,
        "spec": dataclasses.asdict(ckpt.spec),
        "input_size": ckpt.input_size,
        "frame_size": list(frame_size or ckpt.frame_size),
        "channels": CHANNELS,
        "stats": ckpt.stats.to_dict(),
        "force_range": {"min": list(ckpt.stats.force_min), "max": list(ckpt.stats.force_max)},
        "cfg": json.loads(json.dumps(ckpt.cfg, default=list)),
        "parent": {"path": ckpt.path, "kind": ckpt.kind},
        "background_stats": background_stats(background) if background is not None else ckpt.background_stats,
        "variables_sha256": hashlib.sha256(raw).hexdigest(),
        **extra,
    }
    atomic_write_text(out / MODEL_JSON, json.dumps(info, indent=2) + "\n")
    return out


@functools.lru_cache(maxsize=16)
def _apply_fns(model):
    """Jitted force / depth applies, one pair per model config (linen modules hash by their fields), so
    re-loading a checkpoint of the same architecture reuses the compiled code."""
    return (jax.jit(lambda v, x: model.apply(v, x, train=False)["force"]),
            jax.jit(lambda v, x: model.apply(v, x, train=False)["depth"]))


class Predictor:
    """Forces from raw uint8 RGB frames (bgr=True for OpenCV's BGR); see the module docstring for what is
    refused and what is flagged. Not thread-safe (last_* attributes)."""

    def __init__(self, ckpt: Checkpoint, strict_size: bool = True, range_margin: float = 0.05):
        self.checkpoint = ckpt
        self.strict_size = strict_size
        self.range_margin = float(range_margin)
        self.model = ckpt.build_model()
        self.variables = jax.device_put(ckpt.variables)
        self._force_fn, depth_fn = _apply_fns(self.model)
        self._depth_fn = depth_fn if ckpt.spec.depth_head else None
        self.background: np.ndarray | None = None
        self.background_issues: list[str] = []
        self.last_out_of_range = np.zeros((0,), bool)
        self.last_nonfinite = np.zeros((0,), bool)
        self.last_frame_issues = np.zeros((0,), object)
        self.last_timing: dict = {}

    # -- what the checkpoint expects -------------------------------------------------------------------
    @property
    def stats(self) -> fdata.Stats:
        return self.checkpoint.stats

    @property
    def input_size(self) -> int:
        """Side of the square model input (after background subtraction, pad, resize)."""
        return self.checkpoint.input_size

    @property
    def frame_size(self) -> tuple[int, int]:
        """(H, W) of the frames the model was trained on (see the module docstring for where it comes from)."""
        return self.checkpoint.frame_size

    @property
    def frame_size_source(self) -> str:
        return self.checkpoint.frame_size_source

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
        return self.checkpoint.spec.name

    def describe(self) -> dict:
        return {"method": self.method, "kind": self.checkpoint.kind, "input_size": self.input_size,
                "frame_size": list(self.frame_size), "frame_size_source": self.frame_size_source,
                "channels": CHANNELS, "force_min": self.force_min.tolist(), "force_max": self.force_max.tolist(),
                "depth_head": self.has_depth, "background_stats": self.checkpoint.background_stats}

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
        hw = tuple(x.shape[-3:-1])
        if hw != self.frame_size:
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
        self.background_issues = background_check(bg, self.checkpoint.background_stats)
        for msg in self.background_issues:
            warnings.warn(msg, BackgroundWarning, stacklevel=2)
        self.background = bg

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
        d = fdata.depth_to_mm(np.asarray(self._depth_fn(self.variables, x)), self.stats)
        return np.stack([self._to_frame(m) for m in d]) if frame else d

    def _to_frame(self, d: np.ndarray) -> np.ndarray:
        import cv2

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
    """A Predictor for any folder `read_checkpoint` reads. which: "best" or "latest" (training runs)."""
    return Predictor(read_checkpoint(checkpoint_dir, which, frame_size), strict_size, range_margin)
