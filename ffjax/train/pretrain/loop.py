"""Pretraining a backbone: `ensure` reuses a matching cache or runs `pretrain`, which builds (or loads) the
corpus, runs the DINO steps on it and writes the teacher's backbone with pretrain.json and log.jsonl."""

from __future__ import annotations

import json
import time
from pathlib import Path

import jax
import numpy as np
from tqdm import tqdm

from ffjax.files import atomic_write_json
from ffjax.train.pretrain import corpus
from ffjax.train.pretrain.augment import multicrop
from ffjax.train.pretrain.cache import BACKBONE_FILE, META_FILE, is_cached, jsonable, save_backbone, settings
from ffjax.train.pretrain.update import init_state, make_update

# XLA options for compiling the update. Tests halve the compile with
# monkeypatch.setitem(pretrain.COMPILER_OPTIONS, "xla_backend_optimization_level", 0): change it in place, as the
# package re-exports this very dict (rebinding the name there would not reach this module).
COMPILER_OPTIONS: dict = {}


def ensure(cfg: dict, kind: str, folder, force: bool = False, progress: bool = True) -> Path:
    """Pretrain `kind` into `folder` unless a matching cache is there; returns the folder."""
    folder = Path(folder)
    if not force and is_cached(cfg, kind, folder):
        if progress:
            print(f"pretrain[{kind}]: reusing {folder}")
        return folder
    pretrain(cfg, kind, folder, progress=progress)
    return folder


def pretrain(cfg: dict, kind: str, folder, progress: bool = True) -> dict:
    """Run DINO for cfg pretrain.steps on the corpus; writes the teacher backbone + pretrain.json."""
    folder = Path(folder)
    st = settings(cfg, kind)
    if int(st["pretrain"]["steps"]) <= 0:
        raise ValueError(f"preset {cfg.get('preset')!r} sets pretrain.steps=0: it loads real weights "
                         "(python -m ffjax.convert) instead of pretraining")
    folder.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    images, cmeta = corpus.load_or_build(cfg, folder.parent, progress=progress)
    t_corpus = time.perf_counter() - t0
    x = images.astype(np.float32) / 255.0
    norm = (x.mean((0, 1, 2)).tolist(), (x.std((0, 1, 2)) + 1e-3).tolist())
    state, history, t_train, t_first = _dino_steps(cfg, kind, images, norm, folder / "log.jsonl", progress)
    teacher = jax.device_get(state["teacher"])
    save_backbone(folder / BACKBONE_FILE, teacher["params"]["backbone"], teacher["batch_stats"].get("backbone", {}))
    p = st["pretrain"]
    steps, bs = int(p["steps"]), int(p["batch_size"])
    meta = {"settings": jsonable(st), "input_norm": {"mean": norm[0], "std": norm[1]},
            "corpus": {"hash": cmeta.get("hash"), "size": len(images), "sim_available": cmeta.get("sim_available"),
                       "kinds": {k: cmeta["kinds"].count(k) for k in set(cmeta["kinds"])}},
            "final": history[-1] if history else {}, "first": history[0] if history else {},
            "timings": {"corpus_s": round(t_corpus, 1), "train_s": round(t_train, 1),
                        "compile_s": round(t_first or 0.0, 1),
                        "img_per_s": round(steps * bs / max(t_train - (t_first or 0), 1e-9), 1)},
            "backend": jax.default_backend()}
    atomic_write_json(folder / META_FILE, meta)
    if progress:
        print(f"pretrain[{kind}]: {steps} steps in {t_train:.0f}s, loss {meta['first'].get('loss', 0):.3f} -> "
              f"{meta['final'].get('loss', 0):.3f}; saved {folder / BACKBONE_FILE}")
    return meta


def _dino_steps(cfg: dict, kind: str, images: np.ndarray, norm, log_path: Path, progress: bool):
    """(state, logged metrics, train seconds, first-step seconds) of the DINO steps on `images`; every 10th
    step's metrics go to `log_path`, and a non-finite loss stops the run."""
    st = settings(cfg, kind)
    p = st["pretrain"]
    key = jax.random.PRNGKey(st["seed"])
    state = init_state(cfg, kind, jax.random.fold_in(key, 1))
    update = None
    aug_key = jax.random.fold_in(key, 2)
    bs, steps, S = int(p["batch_size"]), int(p["steps"]), st["input_size"]
    log = open(log_path, "w")
    history, t_first = [], None
    bar = tqdm(range(steps), desc=f"pretrain {kind}", disable=not progress)
    t1 = time.perf_counter()
    for i in bar:
        idx = np.random.default_rng([st["seed"], 11, i]).choice(len(images), bs, replace=len(images) < bs)
        batch = multicrop(images[idx], np.random.default_rng([st["seed"], 12, i]), p, S, norm)
        if update is None:  # compiled once, from the first batch's shapes
            update = jax.jit(make_update(cfg, kind), donate_argnums=0).lower(state, batch, aug_key).compile(
                compiler_options=COMPILER_OPTIONS or None)
        state, m = update(state, batch, aug_key)
        if i == 0:
            jax.block_until_ready(m)
            t_first = time.perf_counter() - t1
        if i % 10 == 0 or i == steps - 1:
            m = {k: float(v) for k, v in m.items()}
            if not np.isfinite(m["loss"]):
                raise FloatingPointError(f"pretrain[{kind}]: non-finite loss at step {i}: {m}")
            m["step"] = i
            history.append(m)
            log.write(json.dumps(m) + "\n")
            log.flush()
            bar.set_postfix(loss=f"{m['loss']:.3f}", H_t=f"{m['teacher_entropy']:.2f}",
                            fstd=f"{m['feature_std']:.3f}")
    log.close()
    jax.block_until_ready(state)
    return state, history, time.perf_counter() - t1, t_first
