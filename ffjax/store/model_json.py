"""model.json: what a trained model is, beside its weights (training runs and bundles), and its one reader.

    {"method", "spec" (every registry.Method field), "input_size", "stats" (data.Stats), "force_range",
     "frame_size", ["background_stats"], "cfg" (the full config), [a bundle's "format", "parent",
     "variables_sha256", ...], "sha256"}

"sha256" is the digest of everything else in the file (canonical JSON), so an edit that would change the
forces (the normalization statistics, the spec, the config) is refused, naming the file, instead of loading a
different model. Files written before the digest existed carry none: they load, with an UnverifiedWarning that
says how to write them again with it.

`read` checks a file and `describe` turns it into the config (upgraded to today's keys by configs.upgrade), the
method and the statistics; nothing else in ffjax parses model.json.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import configs
from ffjax import registry
from ffjax.data.stats import Stats
from ffjax.errors import CheckpointError
from ffjax.files import as_json, atomic_write_json, json_digest, read_json
from ffjax.jsontree import retuple
from ffjax.store.checksums import warn_unverified

MODEL_JSON = "model.json"
REQUIRED = ("method", "input_size", "stats", "cfg")
DIGEST, WEIGHTS_DIGEST = "sha256", "variables_sha256"  # a bundle's model.json also records its weights' digest
BUNDLE_FORMAT = "ffjax.predictor/1"


def info(cfg: dict, spec, stats, input_size: int, frame_size=None, background_stats: dict | None = None,
         **extra) -> dict:
    """model.json's content (JSON types), its digest included.

    frame_size: (H, W) of the training camera frames, so a predictor can refuse frames of another size.
    background_stats: the training background's per-channel statistics, so a predictor can warn when it is
    handed a background from another sensor. extra: what a bundle adds (format, parent, weights' sha256)."""
    body = {
        "method": spec.name,
        "spec": dataclasses.asdict(spec),
        "input_size": int(input_size),
        "stats": stats.to_dict(),
        "force_range": {"min": list(stats.force_min), "max": list(stats.force_max)},
        "frame_size": None if frame_size is None else [int(v) for v in frame_size],
        **({"background_stats": background_stats} if background_stats else {}),
        **extra,
        "cfg": cfg,
    }
    body = as_json(body)
    return {**body, DIGEST: json_digest(body)}


def write(folder, content: dict) -> Path:
    """Write FOLDER/model.json atomically; returns its path."""
    path = Path(folder) / MODEL_JSON
    atomic_write_json(path, content, indent=2)
    return path


def read(folder) -> dict:
    """FOLDER/model.json, checked: ffjax's keys and, where recorded, its digest; CheckpointError naming the file."""
    path = Path(folder) / MODEL_JSON
    content = read_json(path)
    if content is None:
        raise FileNotFoundError(f"{path} not found: not a training run folder (python -m ffjax.train ...) or a "
                                "bundle")
    missing = [k for k in REQUIRED if k not in content]
    if missing:
        raise CheckpointError(f"{path} is not an ffjax model.json: missing {', '.join(missing)}")
    verify(content, path)
    return content


def verify(content: dict, path) -> None:
    """CheckpointError naming `path` when model.json's content no longer matches its recorded digest; an
    UnverifiedWarning when it records none (written before model.json carried one)."""
    recorded = content.get(DIGEST)
    if recorded is None:
        _warn_unverified(content, Path(path))
        return
    if json_digest({k: v for k, v in content.items() if k != DIGEST}) != recorded:
        raise CheckpointError(f"{path} was changed after it was written (its content does not match the sha256 "
                              "recorded in it): the statistics, method or config in it may not be the ones the "
                              "weights were trained with. Restore the file from the run or bundle it came with")


def _warn_unverified(content: dict, path: Path) -> None:
    """The UnverifiedWarning of a model.json without its digest: a run's is written again by resuming the run,
    a bundle's by saving the bundle again."""
    bundle = content.get("format") == BUNDLE_FORMAT
    missing = [DIGEST] + ([WEIGHTS_DIGEST] if bundle and not content.get(WEIGHTS_DIGEST) else [])
    what = "the statistics, method and config in it" + (" and the weights beside it" if len(missing) > 1 else "")
    folder = path.parent
    how = (f"save the bundle again from an unedited copy (Python: store.save_bundle(NEW, store.load('{folder}')))"
           if bundle else f"resume the run from an unedited copy (python -m ffjax.train --out {folder} --resume with "
           "its preset, method and data: that writes model.json again with its digest)")
    warn_unverified(path, missing, what + " are", how)


@dataclasses.dataclass(frozen=True)
class Described:
    """What a model.json says: the config (tuples restored, upgraded to today's keys), the method (its full
    spec), the data statistics and the input size; `content` is the file's JSON as read."""

    content: dict
    cfg: dict
    spec: registry.Method
    stats: Stats
    input_size: int


def describe(content: dict, path) -> Described:
    """Described from model.json's JSON (`path` names it in errors). The method comes from its "spec", so a
    variant that was never registered in this process loads; a model.json written before the spec was recorded
    names a registry method."""
    try:
        return Described(content, config_of(content["cfg"]), method_of(content), Stats.from_dict(content["stats"]),
                         int(content["input_size"]))
    except (KeyError, TypeError, ValueError) as e:
        raise CheckpointError(f"{path} describes a model this ffjax cannot build: {e}") from e


def config_of(saved: dict) -> dict:
    """A saved config as today's: JSON lists back to tuples, keys it predates filled in (configs.upgrade)."""
    try:
        template = configs.get(saved.get("preset", "smoke"))
    except configs.ConfigError:  # a preset this ffjax lacks: the defaults' types
        template = configs.base.CONFIG
    return configs.upgrade(retuple(saved, template))


def method_of(content: dict) -> registry.Method:
    """The registry Method of model.json's JSON: from its full "spec" (every Method field), else the registry
    entry its name is (a model.json written before the spec was recorded); ValueError for fields this ffjax
    lacks."""
    spec = content.get("spec")
    if not (isinstance(spec, dict) and set(spec) != {"name"}):
        return registry.get(content["method"])
    if spec.get("name") != content["method"]:  # edited by hand or written by something else: which one is it?
        raise ValueError(f"its method {content['method']!r} is not its spec's {spec.get('name')!r}")
    unknown = sorted(set(spec) - {f.name for f in dataclasses.fields(registry.Method)})
    if unknown:
        raise ValueError(f"method {spec.get('name')!r} has fields this ffjax does not know: {unknown}")
    return registry.Method(**spec)
