"""A training run's checkpoints: orbax's latest (to resume) and best (to use), verified by per-tensor checksums.

    RUN/model.json        what the model is (ffjax.store.model_json)
    RUN/checkpoints/<step>/  packed (params, batch_stats, opt_state, step, rng key as one buffer per dtype,
                          packed.py; older runs: state, the same as a tensor tree), data (grain iterator
                          state, JSON), meta (epoch, best so far, epoch accumulators, the packed layout; JSON)
    RUN/best/<step>/      variables (params, batch_stats) of the lowest validation loss, meta
    RUN/train_log.jsonl   one row per step (train) and per epoch (val); RUN/epochs.csv; RUN/summary.json

Orbax saves asynchronously: every read waits for pending saves first.

Kill safety: orbax writes each step into a temporary folder and renames it when complete, so a kill
mid-save leaves the previous step as the newest one; our JSON files go through `atomic_write_text`
(temp file, fsync, os.replace). A failed save (disk full, folder gone read-only) raises
`WriteError`; the older checkpoints are untouched because a new one is written beside them.
A missing, partial or foreign checkpoint is refused with `CheckpointError` naming the path.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
from pathlib import Path

import jax
import numpy as np
import orbax.checkpoint as ocp

from ffjax.errors import CheckpointError, WriteError
from ffjax.files import atomic_write_bytes
from ffjax.store import packed
from ffjax.store.checksums import tree_checksums, verify_checksums
from ffjax.store.model_json import MODEL_JSON

# the run state's item in a resume checkpoint: packed (one buffer per dtype, packed.py) or, written before
# packing existed or for a state with typed keys, the tensor tree
PACKED, STATE = "packed", "state"


def _save_error(e: BaseException, what: str, good) -> WriteError:
    """A save failure as a WriteError that says which checkpoint is still good."""
    inner, chain = e, []
    for _ in range(20):  # follow the exception chain (orbax wraps) to the OSError, if any
        if inner is None or isinstance(inner, OSError):
            break
        chain.append(str(inner))
        inner = inner.__cause__ or inner.__context__
    code = inner.errno if isinstance(inner, OSError) else None
    # TensorStore reports ENOSPC as a ValueError("RESOURCE_EXHAUSTED: ... No space left on device")
    if code is None and any("RESOURCE_EXHAUSTED" in t or "No space left" in t for t in chain):
        code = errno.ENOSPC
    first = (str(e).strip().splitlines() or [type(e).__name__])[0][:300]
    why = "the disk is full" if code == errno.ENOSPC else f"{type(e).__name__}: {first}"
    keep = f"the last good checkpoint (step {good}) is untouched" if good is not None else "no checkpoint yet"
    return WriteError(code or errno.EIO, f"could not save {what}: {why}; {keep}. Free space / fix "
                                f"permissions, then resume (--resume)")


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


def _utf8(path: Path) -> Path:
    """`path`, when it can be handed to orbax/TensorStore (UTF-8 only); CheckpointError naming it otherwise (a
    Latin-1 file name in it was reported as "its files are damaged")."""
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        raise CheckpointError(f"{os.fsencode(path)!r}: the path holds bytes that are not UTF-8, which the checkpoint "
                              "library cannot open; rename the folder") from None
    return path


class Checkpointer:
    """Two orbax managers under one run folder: `checkpoints/` (latest, for resuming) and `best/`."""

    def __init__(self, run_dir, max_to_keep: int = 2):
        run_dir = _utf8(Path(run_dir).absolute())  # orbax needs absolute paths
        self.run_dir = run_dir
        # model.json as the checkpoints were written with it: a resume refused as another model's puts it back
        self._model_json = (run_dir / MODEL_JSON).read_bytes() if (run_dir / MODEL_JSON).is_file() else None
        for sub in ("checkpoints", "best"):
            _drop_interrupted_deletes(run_dir / sub)
        # cleanup_tmp_directories: a save a kill interrupted is an unfinished `<step>.orbax-checkpoint-tmp*`
        # folder; orbax never lists it as a step, and this removes it when the run is reopened.
        opts = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=True, cleanup_tmp_directories=True)
        self._saved_layout = None
        self._opts = opts
        self.latest = ocp.CheckpointManager(run_dir / "checkpoints", options=opts)
        self.best = ocp.CheckpointManager(
            run_dir / "best",
            options=ocp.CheckpointManagerOptions(max_to_keep=1, create=True, cleanup_tmp_directories=True),
        )

    def save_latest(self, step: int, state, data_state, meta: dict) -> None:
        # async: a failed write surfaces at the next save or wait, so name the folder, not this step
        with self._saving(f"a checkpoint in {self.run_dir / 'checkpoints'} (at or before step {step})"):
            if self.latest.latest_step() == step:
                return
            self._save_latest(step, state, data_state, meta)

    def _save_latest(self, step: int, state, data_state, meta: dict) -> None:
        arrays = state.arrays()
        meta = {**meta, "checksums": tree_checksums(arrays)}
        if packed.packable(arrays):  # one buffer per dtype: far less of orbax's per-tensor CPU (packed.py)
            meta["layout"] = self._layout(arrays)
            item = {PACKED: ocp.args.StandardSave(packed.pack(arrays))}
        else:
            item = {STATE: ocp.args.StandardSave(arrays)}
        self.latest.save(
            step,
            args=ocp.args.Composite(
                **item,
                data=ocp.args.JsonSave(_jsonable({"iterator": data_state})),
                meta=ocp.args.JsonSave(_jsonable(meta)),
            ),
        )

    def _layout(self, arrays) -> list:
        """packed.layout of the run state, computed once: its structure is fixed for the run."""
        if self._saved_layout is None:
            self._saved_layout = packed.layout(arrays)
        return self._saved_layout

    def save_best(self, step: int, state, meta: dict) -> None:
        with self._saving(f"the best checkpoint in {self.run_dir / 'best'}"):
            self.best.wait_until_finished()
        if step in self.best.all_steps():
            # A resumed run replays steps a killed one already finished: that best checkpoint is the same
            # bytes (the replay is exact), and keeping it means there is never a moment without one.
            return
        variables = _best_variables(state)
        meta = {**meta, "checksums": tree_checksums(variables)}
        with self._saving(f"best checkpoint step {step} in {self.run_dir / 'best'}"):
            self.best.save(
                step,
                args=ocp.args.Composite(
                    variables=ocp.args.StandardSave(variables), meta=ocp.args.JsonSave(_jsonable(meta))
                ),
                force=True,
            )

    def compile_checksums(self, state) -> None:
        """Compile the programs of both saves (the run state's checksums and packing; the best variables'
        checksums) now. Each is one program over every tensor, seconds to compile on a CPU, which would
        otherwise stall the first save."""
        tree_checksums(state.arrays())
        if packed.packable(state.arrays()):
            packed.pack(state.arrays())
        tree_checksums(_best_variables(state))

    def _saving(self, what: str):
        """Context that turns any write failure (raised now or by the async writer) into WriteError."""

        @contextlib.contextmanager
        def ctx():
            try:
                yield
            except WriteError:
                raise
            except Exception as e:  # orbax may wrap the OSError; _save_error digs it out
                raise _save_error(e, what, self._good_step()) from e

        return ctx()

    def _good_step(self):
        """The newest step whose folder is complete on disk (orbax already lists a step whose save failed)."""
        folder = self.run_dir / "checkpoints"
        done = [int(p.name) for p in folder.iterdir() if p.name.isdigit() and (p / "_CHECKPOINT_METADATA").is_file()] \
            if folder.is_dir() else []
        return max(done, default=None)

    def restore_latest(self, state, log=print):
        """(state, data_state, meta) from the newest intact checkpoint, placed like `state`; None if none.

        A checkpoint that cannot be read or fails its checksums is moved aside (`<step>.corrupt`, kept for
        inspection) and the next older one is used, saying so; CheckpointError when none is intact."""
        self.wait()
        folder, refused = self.run_dir / "checkpoints", []
        for step in sorted(self.latest.all_steps(), reverse=True):
            path = folder / str(step)
            try:
                arrays, res = self._restore_step(step, state.arrays())
                meta = _unjson(res["meta"])
                meta.pop("layout", None)
                verify_checksums(arrays, meta.pop("checksums", None), path)
            except Exception as e:
                same = _same_model(path, state.params)
                if same is False and not refused:  # the run is another model's: no older step is better
                    self._keep_model_json()
                    raise CheckpointError(f"cannot resume from {path}: {_why(e, False)}") from e
                refused.append(str(e) if isinstance(e, CheckpointError) else f"{path} is unreadable: "
                               f"{_why(e, same)}")
                continue
            if refused:
                self._move_aside([s for s in self.latest.all_steps() if s > step])
                log(f"warning: {'; '.join(refused)}; resuming from step {step}, the newest intact checkpoint "
                    "(the damaged ones are kept as checkpoints/<step>.corrupt)")
            return state.with_arrays(dict(arrays)), _unjson(res["data"])["iterator"], meta
        if refused:
            raise CheckpointError("; ".join(refused) + "; no intact checkpoint is left: start a new run")
        return None

    def _restore_step(self, step: int, template) -> tuple:
        """(the run state's arrays placed like `template`, orbax's restored items) of one step, packed or not."""
        packed_item = (self.run_dir / "checkpoints" / str(step) / PACKED).is_dir()
        target = _abstract(packed.pack(template) if packed_item else template)
        res = self.latest.restore(step, args=ocp.args.Composite(
            **{PACKED if packed_item else STATE: ocp.args.StandardRestore(target)},
            data=ocp.args.JsonRestore(), meta=ocp.args.JsonRestore()))
        if not packed_item:
            return res[STATE], res
        return packed.unpack(dict(res[PACKED]), _unjson(res["meta"])["layout"], template), res

    def _keep_model_json(self) -> None:
        """Put back the model.json this run's checkpoints were written with: the trainer rewrites it before
        restoring, and a refused resume must not leave another architecture's beside these weights."""
        path = self.run_dir / MODEL_JSON
        if self._model_json is not None and (not path.is_file() or path.read_bytes() != self._model_json):
            atomic_write_bytes(path, self._model_json)

    def _move_aside(self, steps: list[int]) -> None:
        """Rename damaged steps to `<step>.corrupt` (orbax ignores them) and reopen the manager, so the resumed
        run writes those steps afresh instead of skipping them as already saved."""
        self.latest.close()
        for step in steps:
            src = self.run_dir / "checkpoints" / str(step)
            dst = src.with_name(f"{step}.corrupt")
            if dst.exists():
                shutil.rmtree(dst)
            src.rename(dst)
        self.latest = ocp.CheckpointManager(self.run_dir / "checkpoints", options=self._opts)

    def latest_step(self) -> int | None:
        self.wait()
        return self.latest.latest_step()

    def wait(self) -> None:
        with self._saving(f"checkpoint in {self.run_dir}"):
            self.latest.wait_until_finished()
            self.best.wait_until_finished()

    def close(self) -> None:
        try:
            self.latest.close()
        finally:
            self.best.close()


def _best_variables(state) -> dict:
    return {"params": state.params, "batch_stats": state.batch_stats}


def _drop_interrupted_deletes(folder: Path) -> None:
    """Remove older step folders that a kill left half-deleted (orbax drops old steps after the new one is
    complete, metadata file first). The newest step is never touched."""
    if not folder.is_dir():
        return
    steps = sorted((int(p.name), p) for p in folder.iterdir() if p.name.isdigit() and p.is_dir())
    for _, path in steps[:-1]:
        if not (path / "_CHECKPOINT_METADATA").is_file():
            shutil.rmtree(path, ignore_errors=True)


def _saved_param_shapes(item_dir: Path) -> dict | None:
    """{("params", "dense", "kernel"): shape} from an orbax item's _METADATA, or for a packed run state from
    the layout in its meta (no array data read); None when that file is missing or unreadable."""
    try:
        if item_dir.name == PACKED:
            entries = json.loads((item_dir.parent / "meta" / "metadata").read_text())["layout"]
            return {tuple(p): tuple(s) for p, _, s in entries if isinstance(p, list) and p[0] == "params"}
        tree = json.loads((item_dir / "_METADATA").read_text())["tree_metadata"]
        out = {}
        for entry in tree.values():
            keys = tuple(str(k["key"]) for k in entry["key_metadata"])
            if keys and keys[0] == "params":
                out[keys] = tuple(entry["value_metadata"]["write_shape"])
        return out
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _same_model(path: Path, params) -> bool | None:
    """Whether the checkpoint's saved parameter tree and shapes are `params`'s (None: cannot tell). `path`: a
    step folder (its run state, packed or not, or its best variables) or one item folder in it."""
    if path.name.isdigit():
        path = next((path / i for i in (PACKED, STATE, "variables") if (path / i).is_dir()), path / STATE)
    saved = _saved_param_shapes(path)
    if not saved:
        return None
    ours = {("params", *(str(getattr(k, "key", k)) for k in path)): tuple(x.shape)
            for path, x in jax.tree_util.tree_flatten_with_path(params)[0]}
    return saved == ours


def _why(e: BaseException, same_model: bool | None = None) -> str:
    """A restore failure in words. same_model (from the saved metadata, see _same_model) tells a damaged
    checkpoint of this model from one of another architecture; without it, the error text decides."""
    text = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    text = text.split(" See full TensorStore details")[0]
    low = str(e).lower()
    if same_model is None:
        same_model = not ("shape" in low or "structure" in low or "mismatch" in low or "not found in" in low
                          or "keys" in low) and None
    if same_model is False:
        return f"it was written for another model/optimizer (different parameter tree or shapes): {text[:300]}"
    if same_model:
        return f"its files are damaged (truncated or corrupt): {type(e).__name__}: {text[:300]}"
    return f"it is partial, corrupt or not an ffjax checkpoint ({type(e).__name__}: {text[:300]})"


def restore_variables(run_dir, which: str, target: dict) -> dict:
    """{"params", "batch_stats"} of a run's best checkpoint (the lowest validation loss) or its latest one,
    checked against `target` (the model's abstract variables) and the checksums saved with it; CheckpointError
    naming the step folder otherwise."""
    if which not in ("best", "latest"):
        raise ValueError(f"which must be 'best' or 'latest', got {which!r}")
    run_dir = _utf8(Path(run_dir).absolute())
    folder = run_dir / ("best" if which == "best" else "checkpoints")
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder} not found: {run_dir} has no {which} checkpoint yet")
    mgr = ocp.CheckpointManager(folder)
    try:
        step = mgr.latest_step()
        if step is None:
            raise FileNotFoundError(f"{folder}: no complete {which} checkpoint yet")
        out = _restore_variables(mgr, step, which, target, folder / str(step))
    finally:
        mgr.close()
    variables = {"params": out["params"]}
    if out.get("batch_stats"):
        variables["batch_stats"] = out["batch_stats"]
    return variables


def _restore_variables(mgr, step: int, which: str, target: dict, path: Path) -> dict:
    """params/batch_stats of one step, checked against the model's shapes and the saved checksums;
    CheckpointError otherwise."""
    try:
        if which == "best":
            restored = mgr.restore(step, args=ocp.args.Composite(variables=ocp.args.StandardRestore(target),
                                                                 meta=ocp.args.JsonRestore()))
            out = restored["variables"]
        else:
            # The optimizer state's structure depends on the labels; restore without a target and keep
            # only the model's variables, checked against the model's shapes.
            item = PACKED if (path / PACKED).is_dir() else STATE
            restored = mgr.restore(step, args=ocp.args.Composite(**{item: ocp.args.StandardRestore()},
                                                                 meta=ocp.args.JsonRestore()))
            if item == PACKED:
                out = packed.variables_from(dict(restored[PACKED]), _unjson(restored["meta"])["layout"])
            else:
                out = {"params": restored[STATE]["params"], "batch_stats": restored[STATE].get("batch_stats", {})}
        jax.tree.map(lambda a, b: _same_shape(a, b), target["params"], out["params"])
    except Exception as e:
        same = _same_model(path, target["params"])
        hint = _LATEST_HINT if which == "best" and same is not False else ""
        raise CheckpointError(f"refusing {path}: {_why(e, same).rstrip('.')}{hint}") from e
    saved = (_unjson(restored["meta"]) or {}).get("checksums") or {}
    try:
        verify_checksums(out, {k: v for k, v in saved.items() if k.startswith(("['params']", "['batch_stats']"))},
                         path)
    except CheckpointError as e:
        if which != "best":
            raise
        raise CheckpointError(f"{str(e).rstrip('.')}{_LATEST_HINT}") from None
    return out


# what to do when the best weights are damaged: the resume checkpoints are separate files
_LATEST_HINT = "; the run's latest checkpoint may be intact: load it with --which latest (which='latest')"


def _same_shape(a, b):
    if tuple(a.shape) != tuple(np.shape(b)):
        raise ValueError(f"shape mismatch: checkpoint tensor {np.shape(b)} vs the model's {a.shape}")
