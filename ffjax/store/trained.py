"""A trained model, whichever folder it comes from: one type (`Trained`), one reader (`load`), one bundle writer.

Folders `load` reads (it tells them apart):
  training run   RUN/model.json + RUN/best/ (+ checkpoints/), written by `ffjax.train`
  bundle         DIR/model.json + DIR/variables.msgpack, written by `ffjax.calibrate` (`save_bundle`)
  converted      DIR/convert.json + DIR/variables.msgpack, written by `python -m ffjax.convert feelanyforce`.
                 It holds no statistics: the release's are used (RELEASE_STATS: normalization mean/std and
                 depth range from its code, input 224 from convert.json, force range (-2,-2,0)..(2,2,15) N
                 approximated from the paper). A `stats.json` (a data.Stats dict) beside it overrides them.

Everything is verified: model.json's own digest (model_json), run checkpoints' per-tensor checksums, the
bundle's and converted weights' sha256, every tensor's shape against the model the folder describes. A
model.json or convert.json written before it recorded its digests loads with an UnverifiedWarning saying so.

Expected frame size (H, W), the first that applies: the `frame_size` argument; "frame_size" in model.json
(runs and bundles record it); "frame_size" in a `sensor.json` beside the weights; 240x320 (GelSight Mini) for
a converted release checkpoint; else the run's cfg["data"]["render_size"] (the simulator frames of its preset;
`frame_size_source` says "assumed" then).

The training background's statistics ("background_stats": per-channel mean/std) come from model.json, else a
sensor.json beside the weights, else a background.png there (calibrated bundles keep the sensor's).
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import jax
import numpy as np
from flax import serialization

import configs
from ffjax import models, registry
from ffjax.data import stats as data_stats
from ffjax.data.images import read_rgb
from ffjax.errors import CheckpointError
from ffjax.files import atomic_write_bytes, check_output, read_json, sha256_bytes
from ffjax.store import checkpoints, converted, model_json
from ffjax.store.model_json import BUNDLE_FORMAT, MODEL_JSON

CHANNELS = "RGB"
VARIABLES, SENSOR_JSON, STATS_JSON = "variables.msgpack", "sensor.json", "stats.json"
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


@dataclasses.dataclass(frozen=True)
class Trained:
    """A trained model: what it is (config, method, data statistics, input and frame size) and its weights
    (`variables`; None from `describe`, which reads model.json only)."""

    cfg: dict  # the full config (model section rebuilds the network; calibrate section its defaults)
    spec: registry.Method
    stats: data_stats.Stats
    input_size: int
    frame_size: tuple[int, int]
    frame_size_source: str
    kind: str  # "run" | "bundle" | "converted"
    path: str
    variables: dict | None = None
    info: dict = dataclasses.field(default_factory=dict)  # model.json / convert.json as read
    background_stats: dict | None = None  # the training background's per-channel mean/std, when recorded

    def build(self):
        """The flax module (models.build of the saved config and method)."""
        return models.build(self.cfg["model"], self.spec, self.input_size)

    def abstract_variables(self) -> dict:
        """{"params", "batch_stats"} as shapes and dtypes (nothing allocated)."""
        model, size = self.build(), self.input_size
        dummy = jax.ShapeDtypeStruct((1, size, size, 3), np.float32)
        abstract = jax.eval_shape(lambda x: model.init(jax.random.PRNGKey(0), x, train=False), dummy)
        return {"params": abstract["params"], "batch_stats": abstract.get("batch_stats", {})}

    def with_variables(self, variables: dict) -> Trained:
        return dataclasses.replace(self, variables=variables)


def describe(folder, frame_size=None) -> Trained:
    """The model a run's or bundle's model.json describes, weights not read; CheckpointError when the file is
    damaged, edited or describes a model this ffjax cannot build."""
    folder = Path(folder)
    content = model_json.read(folder)
    d = model_json.describe(content, folder / MODEL_JSON)
    kind = "bundle" if content.get("format") == BUNDLE_FORMAT else "run"
    fs, src = _frame_size(folder, content, frame_size, d.cfg["data"]["render_size"], "assumed")
    trained = Trained(d.cfg, d.spec, d.stats, d.input_size, fs, src, kind, str(folder), None, content,
                      _reference_background(folder, content))
    try:
        trained.build()
    except (KeyError, TypeError, ValueError) as e:
        raise CheckpointError(f"{folder / MODEL_JSON} describes a model this ffjax cannot build: {e}") from e
    return trained


def load(folder, which: str = "best", frame_size=None) -> Trained:
    """A training run (which: "best" or "latest" weights), a bundle or a converted release folder, verified."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such checkpoint folder")
    if (folder / MODEL_JSON).is_file():
        trained = describe(folder, frame_size)
        if trained.kind == "bundle" or (folder / VARIABLES).is_file():
            return _with_bundle_weights(trained)
        return trained.with_variables(checkpoints.restore_variables(folder, which, trained.abstract_variables()))
    if (folder / converted.META).is_file():
        return _converted(folder, frame_size)
    raise FileNotFoundError(
        f"{folder}: not a checkpoint folder; expected {MODEL_JSON} (a training run or calibrated bundle) or "
        f"{converted.META} + {VARIABLES} (python -m ffjax.convert feelanyforce ...)")


def _with_bundle_weights(trained: Trained) -> Trained:
    """A bundle's weights, checked: the sha256 recorded in model.json (older bundles carry none) and every
    tensor's shape against the model model.json describes."""
    folder = Path(trained.path)
    path = folder / VARIABLES
    if not path.is_file():  # not a run: "no best checkpoint" would mislead
        raise CheckpointError(f"{path} is missing: {folder} is a bundle (its {MODEL_JSON} says so) without its "
                              "weights; copy the whole folder again")
    raw = path.read_bytes()
    digest = trained.info.get("variables_sha256")
    if digest and sha256_bytes(raw) != digest:
        raise CheckpointError(f"{path} is corrupt or truncated ({len(raw)} bytes): its sha256 differs from the one "
                              f"in {MODEL_JSON}; copy or export the bundle again")
    try:
        variables = serialization.msgpack_restore(raw)
    except Exception as e:  # noqa: BLE001 - msgpack's errors name no file
        raise CheckpointError(f"cannot read the bundle {folder} ({type(e).__name__}: {str(e)[:200]}): {VARIABLES} "
                              "truncated or not ffjax's") from e
    abstract = trained.abstract_variables()
    want = {k: abstract[k] for k in ("params", "batch_stats") if abstract.get(k)}
    got = {k: variables.get(k) for k in want}
    ok = jax.tree.structure(want) == jax.tree.structure(got) and all(
        tuple(a.shape) == tuple(np.shape(b)) for a, b in zip(jax.tree.leaves(want), jax.tree.leaves(got)))
    if not ok:
        raise CheckpointError(f"{path} does not hold the weights of the {trained.spec.name} model {MODEL_JSON} "
                              "describes (different tensors or shapes)")
    return dataclasses.replace(trained, variables=variables, kind="bundle")


def _converted(folder: Path, frame_size) -> Trained:
    """Converted release weights, with the release's statistics (or a stats.json beside them)."""
    meta = converted.read_meta(folder)
    if meta["kind"] != "feelanyforce" or "regressor" not in meta["model"]:
        raise ValueError(f"{folder} holds converted {meta['kind']} backbone weights, not a force model: use it "
                         "to start training (--init), then load the run")
    sections, variables = converted.load(folder)
    cfg = configs.get("paper")
    cfg["model"] = converted.release_model(sections)
    size = int(meta.get("input_size", 224))
    stats = data_stats.Stats.from_dict(read_json(folder / STATS_JSON) or {**RELEASE_STATS, "input_size": size})
    fs, src = _frame_size(folder, {}, frame_size, RELEASE_FRAME, "release default (GelSight Mini)")
    spec = registry.get("dino_rd" if "decoder" in sections else "dino_r")
    return Trained(cfg, spec, stats, size, fs, src, "converted", str(folder), variables, meta,
                   _reference_background(folder, {}))


def _frame_size(folder: Path, content: dict, override, fallback, fallback_source: str):
    if override is not None:
        return _size(override, "the frame_size argument"), "argument"
    if content.get("frame_size"):
        return _size(content["frame_size"], f"{folder / MODEL_JSON}: \"frame_size\""), MODEL_JSON
    sensor = read_json(folder / SENSOR_JSON)
    if sensor and sensor.get("frame_size"):
        return _size(sensor["frame_size"], f"{folder / SENSOR_JSON}: \"frame_size\""), SENSOR_JSON
    return tuple(int(v) for v in fallback), fallback_source


def _size(value, where: str) -> tuple[int, int]:
    """(H, W) from a [height, width] pair of positive whole numbers; CheckpointError naming `where` otherwise."""
    ok = isinstance(value, (list, tuple)) and len(value) == 2 and all(
        isinstance(v, int) and not isinstance(v, bool) and v > 0 or isinstance(v, float) and v.is_integer() and v > 0
        for v in value)
    if not ok:
        raise CheckpointError(f"{where} is {value!r}, expected [height, width] in pixels (e.g. [240, 320])")
    return int(value[0]), int(value[1])


def _reference_background(folder: Path, content: dict) -> dict | None:
    for source in (content, read_json(folder / SENSOR_JSON) or {}):
        if source.get("background_stats"):
            return source["background_stats"]
    if (folder / "background.png").is_file():
        try:
            return data_stats.background_stats(read_rgb(folder / "background.png"))
        except Exception as e:  # noqa: BLE001 - a reference is optional: a bad file only loses the check
            warnings.warn(f"{folder / 'background.png'} unreadable ({e}): no background check", stacklevel=3)
    return None


def save_bundle(out, trained: Trained, variables: dict | None = None, frame_size=None, background=None,
                **extra) -> Path:
    """Write a self-contained folder (model.json + variables.msgpack) that `load` accepts and verifies.

    background: the sensor's no-contact frame (uint8 RGB); its statistics are recorded so a predictor can
    warn about a background from another sensor (default: the trained model's recorded ones, if any).
    `out` may never be inside the folder the model comes from (a command checks beforehand, with
    files.check_output, that it does not replace an output the user did not ask to replace)."""
    out = check_output(out, reads=[trained.path] if Path(trained.path).exists() else [], force=True)
    out.mkdir(parents=True, exist_ok=True)
    tree = jax.tree.map(np.asarray, trained.variables if variables is None else variables)
    raw = serialization.msgpack_serialize(tree)
    atomic_write_bytes(out / VARIABLES, raw)
    bg = data_stats.background_stats(background) if background is not None else trained.background_stats
    content = model_json.info(trained.cfg, trained.spec, trained.stats, trained.input_size,
                              frame_size or trained.frame_size, bg, format=BUNDLE_FORMAT, channels=CHANNELS,
                              parent={"path": trained.path, "kind": trained.kind},
                              variables_sha256=sha256_bytes(raw), **extra)
    model_json.write(out, content)
    return out
