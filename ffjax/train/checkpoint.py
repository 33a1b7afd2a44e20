"""Run folders: orbax checkpoints (latest + best) and model.json, so a run is self-describing.

    RUN/model.json        cfg (full), method, input_size, data Stats, force range
    RUN/checkpoints/<step>/  state (params, batch_stats, opt_state, step, rng key), data (grain iterator
                          state, JSON), meta (epoch, best so far, epoch accumulators; JSON)
    RUN/best/<step>/      variables (params, batch_stats) of the lowest validation loss, meta
    RUN/train_log.jsonl   one row per step (train) and per epoch (val); RUN/epochs.csv; RUN/summary.json

Orbax saves asynchronously: every read waits for pending saves first.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import numpy as np
import orbax.checkpoint as ocp

MODEL_JSON = "model.json"


def _abstract(tree):
    return jax.tree.map(ocp.utils.to_shape_dtype_struct, tree)


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, bytes):
        return {"__bytes__": obj.decode("latin-1")}
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return obj


def _unjson(obj):
    if isinstance(obj, dict):
        if set(obj) == {"__bytes__"}:
            return obj["__bytes__"].encode("latin-1")
        return {k: _unjson(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_unjson(v) for v in obj]
    return obj


class Checkpointer:
    """Two orbax managers under one run folder: `checkpoints/` (latest, for resuming) and `best/`."""

    def __init__(self, run_dir, max_to_keep: int = 2):
        run_dir = Path(run_dir).absolute()  # orbax needs absolute paths
        self.run_dir = run_dir
        opts = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=True)
        self.latest = ocp.CheckpointManager(run_dir / "checkpoints", options=opts)
        self.best = ocp.CheckpointManager(
            run_dir / "best", options=ocp.CheckpointManagerOptions(max_to_keep=1, create=True)
        )

    def save_latest(self, step: int, state, data_state, meta: dict) -> None:
        if self.latest.latest_step() == step:
            return
        self.latest.save(
            step,
            args=ocp.args.Composite(
                state=ocp.args.StandardSave(state.arrays()),
                data=ocp.args.JsonSave(_jsonable({"iterator": data_state})),
                meta=ocp.args.JsonSave(_jsonable(meta)),
            ),
        )

    def save_best(self, step: int, state, meta: dict) -> None:
        self.best.wait_until_finished()
        variables = {"params": state.params, "batch_stats": state.batch_stats}
        self.best.save(
            step,
            args=ocp.args.Composite(
                variables=ocp.args.StandardSave(variables), meta=ocp.args.JsonSave(_jsonable(meta))
            ),
            force=True,
        )

    def restore_latest(self, state):
        """(state, data_state, meta) from the newest checkpoint, placed like `state`; None if none."""
        self.wait()
        step = self.latest.latest_step()
        if step is None:
            return None
        res = self.latest.restore(
            step,
            args=ocp.args.Composite(
                state=ocp.args.StandardRestore(_abstract(state.arrays())),
                data=ocp.args.JsonRestore(),
                meta=ocp.args.JsonRestore(),
            ),
        )
        return state.with_arrays(dict(res["state"])), _unjson(res["data"])["iterator"], _unjson(res["meta"])

    def latest_step(self) -> int | None:
        self.wait()
        return self.latest.latest_step()

    def wait(self) -> None:
        self.latest.wait_until_finished()
        self.best.wait_until_finished()

    def close(self) -> None:
        self.latest.close()
        self.best.close()


def write_model_json(run_dir, cfg: dict, spec, stats, input_size: int, frame_size=None) -> dict:
    """Write run_dir/model.json: all a predictor needs to rebuild the model and its preprocessing.

    frame_size: (H, W) of the training camera frames, so a predictor can refuse frames of another size.
    """
    info = {
        "method": spec.name,
        "spec": dataclasses.asdict(spec) if dataclasses.is_dataclass(spec) else {"name": spec.name},
        "input_size": int(input_size),
        "stats": stats.to_dict(),
        "force_range": {"min": list(stats.force_min), "max": list(stats.force_max)},
        "frame_size": None if frame_size is None else [int(v) for v in frame_size],
        "cfg": _jsonable(cfg),
    }
    path = Path(run_dir) / MODEL_JSON
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(info, indent=2))
    tmp.replace(path)
    return info


def read_model_json(run_dir) -> dict:
    path = Path(run_dir) / MODEL_JSON
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: not a training run folder (python -m ffjax.train ...)")
    return json.loads(path.read_text())


def _retuple(saved, template):
    """JSON turned tuples into lists; give them back where the preset has a tuple."""
    if isinstance(saved, dict) and isinstance(template, dict):
        return {k: _retuple(v, template.get(k)) for k, v in saved.items()}
    if isinstance(saved, list) and isinstance(template, tuple):
        return tuple(saved)
    return saved


def load_checkpoint(run_dir, which: str = "best"):
    """(cfg, spec, stats, variables) of a run: the best-validation weights or the latest ones.

    Works for any run folder written by `train` (model.json says how to rebuild the model).
    """
    import configs
    from ffjax import data, models, registry

    if which not in ("best", "latest"):
        raise ValueError(f"which must be 'best' or 'latest', got {which!r}")
    run_dir = Path(run_dir).absolute()
    info = read_model_json(run_dir)
    cfg = info["cfg"]
    try:
        cfg = _retuple(cfg, configs.get(cfg.get("preset", "smoke")))
    except ValueError:
        pass
    spec = registry.get(info["method"])
    stats = data.Stats.from_dict(info["stats"])
    size = int(info["input_size"])
    model = models.build(cfg["model"], spec, size)
    dummy = jax.ShapeDtypeStruct((1, size, size, 3), np.float32)
    abstract = jax.eval_shape(lambda x: model.init(jax.random.PRNGKey(0), x, train=False), dummy)
    target = {"params": abstract["params"], "batch_stats": abstract.get("batch_stats", {})}
    mgr = ocp.CheckpointManager(run_dir / ("best" if which == "best" else "checkpoints"))
    try:
        step = mgr.latest_step()
        if step is None:
            raise FileNotFoundError(f"{run_dir}: no {which} checkpoint yet")
        if which == "best":
            restored = mgr.restore(step, args=ocp.args.Composite(variables=ocp.args.StandardRestore(target)))
            out = restored["variables"]
        else:
            # The optimizer state's structure depends on the labels; restore without a target and keep
            # only the model's variables, checked against the model's shapes.
            restored = mgr.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore()))
            out = {
                "params": restored["state"]["params"],
                "batch_stats": restored["state"].get("batch_stats", {}),
            }
            jax.tree.map(lambda a, b: _same_shape(a, b), target["params"], out["params"])
    finally:
        mgr.close()
    variables = {"params": out["params"]}
    if out.get("batch_stats"):
        variables["batch_stats"] = out["batch_stats"]
    return cfg, spec, stats, variables


def _same_shape(a, b):
    if tuple(a.shape) != tuple(np.shape(b)):
        raise ValueError(f"checkpoint tensor {np.shape(b)} does not match the model's {a.shape}")
