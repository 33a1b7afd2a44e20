"""Self-supervised pretraining of CPU-scale backbones: DINO self-distillation on an unlabeled corpus.

Real DINOv2 / ImageNet weights are out of reach here, so the "pretrained" ViT and ResNet of the ablation
get their features from DINO (Caron et al. 2021): a student and an EMA teacher copy of the backbone, each
with a projection head (MLP -> L2-normalized bottleneck -> weight-normed prototypes); the student matches
the teacher's centred, sharpened distribution across multi-crop views. The corpus (train/corpus.py) holds
procedural images and frames of randomized simulated sensors, never the evaluation sensors' labelled data.

    python -m ffjax.train.pretrain --preset quick --backbone vit|resnet|all --out DIR [--force] [--probe]
    params, batch_stats = load_backbone("DIR/vit")       # -> params["backbone"] of the force model

DIR/<kind>/ holds backbone.msgpack (the teacher's backbone, flax.serialization), pretrain.json (the
config it was made from + final metrics), log.jsonl, and probe.json when probed. The corpus is cached
once in DIR/<kind>/.. as corpus_<hash>.npy. A rerun with a matching config reuses the cache.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from functools import partial
from pathlib import Path

import cv2
import flax
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from ffjax.files import atomic_write_bytes, atomic_write_json
from ffjax.models.model import BACKBONES
from ffjax.train import corpus as corpus_lib

VERSION = 1
BACKBONE_FILE = "backbone.msgpack"
META_FILE = "pretrain.json"
KINDS = tuple(BACKBONES)  # every backbone kind pretrains with DINO
# XLA options for compiling the update (tests set {"xla_backend_optimization_level": 0}: half the compile)
COMPILER_OPTIONS: dict = {}

# Defaults for keys a preset's "pretrain" section may leave out (every preset sets them explicitly).
DEFAULTS = {
    "steps": 100, "batch_size": 32, "lr": 5e-4, "corpus_size": 1000, "out_dim": 1024,
    "warmup_steps": 20, "min_lr_ratio": 0.05, "weight_decay": 0.04, "grad_clip": 3.0,
    "head_hidden": 512, "head_bottleneck": 128, "freeze_last_steps": 10, "init_layerscale": 0.1,
    "head_bn": True, "local_crops": 4, "local_size": 32, "global_scale": (0.4, 1.0), "local_scale": (0.1, 0.4),
    "student_temp": 0.1, "teacher_temp": 0.04, "teacher_temp_start": 0.04, "teacher_temp_warmup": 0,
    "momentum": 0.996, "center_momentum": 0.9,
    "flip": 0.5, "color_jitter": 0.4, "blur": 0.5, "noise": 0.1, "corpus_sim_fraction": 0.5,
}


def settings(cfg: dict, kind: str) -> dict:
    """Everything that determines a pretrained backbone (also the cache key). Config keys that hold the value
    the code used before they were keys are left out, so backbones pretrained before then stay valid."""
    import configs

    p = {k: cfg["pretrain"].get(k, v) for k, v in DEFAULTS.items()}
    p = {k: list(v) if isinstance(v, tuple) else v for k, v in p.items()}
    model = configs.without_before_keys({"model": cfg["model"]})["model"]
    return {"version": VERSION, "kind": kind, "model": _jsonable(model[kind]),
            "input_size": int(cfg["data"]["input_size"]), "seed": int(cfg["seed"]), "pretrain": p,
            "corpus": corpus_lib.corpus_settings(cfg)}


def _jsonable(x):
    return json.loads(json.dumps(x, default=list))


# ----------------------------------------------------------------------------- model
class DINOHead(nn.Module):
    """MLP -> L2-normalized bottleneck -> weight-normed prototype layer (norm fixed at 1, as DINO).

    bn: BatchNorm in the MLP (DINO's use_bn_in_head). At CPU scale it matters: a freshly initialised
    backbone's feature barely varies across images, so without it every image gets nearly the same
    logits, centering leaves a flat teacher distribution and training stays in that (uniform) collapse.
    """

    out_dim: int
    hidden: int = 512
    bottleneck: int = 128
    bn: bool = True

    @nn.compact
    def __call__(self, x, train: bool = True):
        for i in (1, 2):
            x = nn.Dense(self.hidden, name=f"fc{i}")(x)
            if self.bn:
                x = nn.BatchNorm(use_running_average=not train, momentum=0.9, name=f"bn{i}")(x)
            x = nn.gelu(x)
        x = nn.Dense(self.bottleneck, name="fc3")(x)
        x = x / (jnp.linalg.norm(x, axis=-1, keepdims=True) + 1e-6)
        v = self.param("prototypes", nn.initializers.truncated_normal(0.02), (self.bottleneck, self.out_dim))
        return x @ (v / jnp.linalg.norm(v, axis=0, keepdims=True))


class DINO(nn.Module):
    """backbone + head; params {"backbone", "head"} so the backbone subtree is the model's as is."""

    backbone: nn.Module
    head: nn.Module

    def __call__(self, images, train: bool = True):
        feature = self.backbone(images, train=train)["feature"]
        return self.head(feature, train=train), feature


def build(cfg: dict, kind: str) -> DINO:
    from ffjax import models

    p, S = settings(cfg, kind)["pretrain"], int(cfg["data"]["input_size"])
    cfg_model = cfg["model"]
    if kind == "vit":
        vit = dict(cfg_model["vit"])
        # pos_grid None sizes the table from the first input; pin it to the input grid so local crops
        # interpolate it (same param shapes as models.build_backbone at input_size; identity there)
        vit["pos_grid"] = vit.get("pos_grid") or S // int(vit["patch"])
        # LayerScale 1e-5 (DINOv2's init) leaves the CLS feature all but independent of the image at
        # init: every view then gets the same (uniform) teacher output and DINO never leaves it. DINO v1
        # has no LayerScale; start from a larger one (values only: the param tree is unchanged).
        if p["init_layerscale"]:
            vit["layerscale"] = float(p["init_layerscale"])
        cfg_model = {**cfg_model, "vit": vit}
    return DINO(backbone=models.build_backbone(cfg_model, kind, S),
                head=DINOHead(int(p["out_dim"]), int(p["head_hidden"]), int(p["head_bottleneck"]), bool(p["head_bn"])))


# ----------------------------------------------------------------------------- augmentation (host)
# Crops, flips, colour and blur run in numpy/cv2 on the host (an in-jit version tripled the compile
# time for no speed-up on CPU); pixel noise is added inside the jitted step from its key.
def _crop_box(rng, S: int, scale) -> tuple[int, int, int, int]:
    """Random resized crop box (y0, x0, h, w): area fraction in `scale`, aspect ratio in [3/4, 4/3]."""
    area = rng.uniform(*scale) * S * S
    ratio = math.exp(rng.uniform(math.log(3 / 4), math.log(4 / 3)))
    h = int(round(min(S, max(4, math.sqrt(area / ratio)))))
    w = int(round(min(S, max(4, math.sqrt(area * ratio)))))
    return int(rng.integers(0, S - h + 1)), int(rng.integers(0, S - w + 1)), h, w


def augment_view(img: np.ndarray, rng: np.random.Generator, out: int, scale, p: dict) -> np.ndarray:
    """One view of a uint8 (S,S,3) image in [0, 1] float32: random resized crop, flips, brightness /
    contrast / per-channel (LED) gain, Gaussian blur."""
    y0, x0, h, w = _crop_box(rng, img.shape[0], scale)
    crop = img[y0: y0 + h, x0: x0 + w]
    interp = cv2.INTER_AREA if min(h, w) > out else cv2.INTER_LINEAR
    x = cv2.resize(crop, (out, out), interpolation=interp).astype(np.float32) * np.float32(1 / 255)
    if rng.random() < p["flip"]:
        x = x[:, ::-1]
    if rng.random() < p["flip"]:
        x = x[::-1]
    cj = p["color_jitter"]
    if cj > 0:
        mean = x.mean()
        contrast, gain = 1 + cj * rng.uniform(-1, 1), 1 + cj * rng.uniform(-1, 1)
        chan = (1 + 0.5 * cj * rng.uniform(-1, 1, 3)).astype(np.float32)
        x = ((x - mean) * contrast + mean) * gain * chan
    if rng.random() < p["blur"]:
        x = cv2.GaussianBlur(np.ascontiguousarray(x), (0, 0), rng.uniform(0.1, 1.5) * out / img.shape[0])
    return np.clip(x, 0.0, 1.0)


def multicrop(images: np.ndarray, rng: np.random.Generator, p: dict, input_size: int, norm) -> dict:
    """uint8 (B,S,S,3) -> {"global": (2B,S,S,3) [view 0 batch, view 1 batch], "local": (L*B,s,s,3)},
    normalized by the corpus mean/std."""
    mean, std = np.asarray(norm[0], np.float32), np.asarray(norm[1], np.float32)

    def views(n, out, scale):
        v = np.stack([augment_view(im, rng, out, scale, p) for _ in range(n) for im in images])
        return (v - mean) / std

    batch = {"global": views(2, input_size, p["global_scale"])}
    if p["local_crops"]:
        batch["local"] = views(int(p["local_crops"]), int(p["local_size"]), p["local_scale"])
    return batch


# ----------------------------------------------------------------------------- state and step
def schedules(p: dict):
    """lr, teacher momentum (cosine 0.996 -> 1) and teacher temperature (linear warmup) per step."""
    steps = max(int(p["steps"]), 1)
    lr = optax.warmup_cosine_decay_schedule(0.0, p["lr"], min(int(p["warmup_steps"]), steps - 1) or 0,
                                            steps, p["lr"] * p["min_lr_ratio"])

    def momentum(step):
        return 1 - (1 - p["momentum"]) * (jnp.cos(jnp.pi * jnp.minimum(step, steps) / steps) + 1) / 2

    def teacher_temp(step):
        w = max(int(p["teacher_temp_warmup"]), 1)
        frac = jnp.minimum(step / w, 1.0)
        return p["teacher_temp_start"] + frac * (p["teacher_temp"] - p["teacher_temp_start"])

    return lr, momentum, teacher_temp


def make_optimizer(p: dict):
    lr, _, _ = schedules(p)
    decay_mask = partial(jax.tree.map, lambda x: x.ndim > 1)  # no weight decay on biases / norms
    return optax.chain(optax.clip_by_global_norm(p["grad_clip"]),
                       optax.adamw(lr, weight_decay=p["weight_decay"], mask=decay_mask))


def init_state(cfg: dict, kind: str, key) -> dict:
    """{"step", "student": {params, batch_stats}, "teacher": {...}, "opt_state", "center"} (a pytree)."""
    model, p = build(cfg, kind), settings(cfg, kind)["pretrain"]
    S = int(cfg["data"]["input_size"])
    variables = model.init(key, jnp.zeros((2, S, S, 3)), train=False)
    student = {"params": variables["params"], "batch_stats": variables.get("batch_stats", {})}
    teacher = jax.tree.map(jnp.array, student)  # a copy, not an alias (the step donates its input)
    return {"step": jnp.zeros((), jnp.int32), "student": student, "teacher": teacher,
            "opt_state": make_optimizer(p).init(student["params"]),
            "center": jnp.zeros((1, int(p["out_dim"])), jnp.float32)}


def _apply(model, vars_, images, train: bool):
    """(logits, features, new batch_stats); ResNet BatchNorm state threads through functionally."""
    if vars_["batch_stats"]:
        (logits, feat), upd = model.apply({"params": vars_["params"], "batch_stats": vars_["batch_stats"]},
                                          images, train=train, mutable=["batch_stats"])
        return logits, feat, upd["batch_stats"]
    logits, feat = model.apply({"params": vars_["params"]}, images, train=train)
    return logits, feat, vars_["batch_stats"]


def dino_loss(student_logits, teacher_probs, student_temp: float):
    """Cross-entropy of every student view against every teacher (global) view but its own.
    student_logits (V,B,K), teacher_probs (2,B,K)."""
    logp = jax.nn.log_softmax(student_logits / student_temp, axis=-1)
    total, terms = 0.0, 0
    for iq in range(teacher_probs.shape[0]):
        for v in range(student_logits.shape[0]):
            if v == iq:
                continue
            total += jnp.mean(-jnp.sum(teacher_probs[iq] * logp[v], axis=-1))
            terms += 1
    return total / terms


def _noisy(x, key, level: float):
    """Camera-like Gaussian pixel noise, a random strength per view (in normalized units)."""
    ks, kn = jax.random.split(key)
    return x + level * jax.random.uniform(ks, (x.shape[0], 1, 1, 1)) * jax.random.normal(kn, x.shape)


def make_update(cfg: dict, kind: str):
    """update(state, batch, key) -> (state, metrics): the pure DINO step (jit it once). batch = multicrop's
    views; key draws the per-view pixel noise."""
    model, p = build(cfg, kind), settings(cfg, kind)["pretrain"]
    tx = make_optimizer(p)
    lr_fn, momentum_fn, temp_fn = schedules(p)
    freeze_last = int(p["freeze_last_steps"])

    def update(state, batch, key):
        step = state["step"]
        kg, kl = jax.random.split(jax.random.fold_in(key, step))
        glob, loc = _noisy(batch["global"], kg, p["noise"]), batch.get("local")
        loc = None if loc is None else _noisy(loc, kl, p["noise"])
        B = glob.shape[0] // 2
        t_logits, _, t_stats = _apply(model, state["teacher"], glob, train=True)
        t_logits = jax.lax.stop_gradient(t_logits)
        t_probs = jax.nn.softmax((t_logits - state["center"]) / temp_fn(step), axis=-1).reshape(2, B, -1)

        def loss_fn(params):
            vars_ = {"params": params, "batch_stats": state["student"]["batch_stats"]}
            g_logits, feat, stats = _apply(model, vars_, glob, train=True)
            logits = [g_logits.reshape(2, B, -1)]
            if loc is not None:
                l_logits, _, stats = _apply(model, {"params": params, "batch_stats": stats}, loc, train=True)
                logits.append(l_logits.reshape(-1, B, l_logits.shape[-1]))
            loss = dino_loss(jnp.concatenate(logits, 0), t_probs, p["student_temp"])
            return loss, (feat, stats)

        (loss, (feat, s_stats)), grads = jax.value_and_grad(loss_fn, has_aux=True)(state["student"]["params"])
        # DINO keeps the prototype layer fixed for the first steps: it stabilises the start
        protos = jnp.where(step < freeze_last, 0.0, grads["head"]["prototypes"])
        grads = {**grads, "head": {**grads["head"], "prototypes": protos}}
        updates, opt_state = tx.update(grads, state["opt_state"], state["student"]["params"])
        params = optax.apply_updates(state["student"]["params"], updates)
        m = momentum_fn(step)
        t_params = jax.tree.map(lambda t, s: m * t + (1 - m) * s, state["teacher"]["params"], params)
        center = p["center_momentum"] * state["center"] + (1 - p["center_momentum"]) * t_logits.mean(0, keepdims=True)
        metrics = {"loss": loss, "lr": lr_fn(step), "momentum": m, "teacher_temp": temp_fn(step),
                   **_collapse_monitors(t_probs, feat)}
        new = {"step": step + 1, "student": {"params": params, "batch_stats": s_stats},
               "teacher": {"params": t_params, "batch_stats": t_stats}, "opt_state": opt_state,
               "center": center}
        return new, metrics

    return update


def _collapse_monitors(t_probs, feat) -> dict:
    """Per-sample teacher entropy falls with sharpening; the entropy of the batch-mean distribution stays high
    unless every image maps to the same prototypes; a collapsed backbone's normalized features stop varying."""
    mean_probs = t_probs.mean((0, 1))
    featn = feat / (jnp.linalg.norm(feat, axis=-1, keepdims=True) + 1e-6)
    return {
        "teacher_entropy": -jnp.sum(t_probs * jnp.log(t_probs + 1e-12), -1).mean(),
        "teacher_batch_entropy": -jnp.sum(mean_probs * jnp.log(mean_probs + 1e-12)),
        "feature_std": featn.std(0).mean(),
    }


# ----------------------------------------------------------------------------- run, cache, load
def run_dir(out, kind: str) -> Path:
    return Path(out) / kind


def is_cached(cfg: dict, kind: str, folder) -> bool:
    meta = Path(folder) / META_FILE
    if not (meta.exists() and (Path(folder) / BACKBONE_FILE).exists()):
        return False
    return json.loads(meta.read_text()).get("settings") == _jsonable(settings(cfg, kind))


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
    images, cmeta = corpus_lib.load_or_build(cfg, folder.parent, progress=progress)
    t_corpus = time.perf_counter() - t0
    x = images.astype(np.float32) / 255.0
    norm = (x.mean((0, 1, 2)).tolist(), (x.std((0, 1, 2)) + 1e-3).tolist())
    state, history, t_train, t_first = _dino_steps(cfg, kind, images, norm, folder / "log.jsonl", progress)
    teacher = jax.device_get(state["teacher"])
    save_backbone(folder / BACKBONE_FILE, teacher["params"]["backbone"], teacher["batch_stats"].get("backbone", {}))
    p = st["pretrain"]
    steps, bs = int(p["steps"]), int(p["batch_size"])
    meta = {"settings": _jsonable(st), "input_norm": {"mean": norm[0], "std": norm[1]},
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
    from tqdm import tqdm

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


def save_backbone(path, params, batch_stats=None) -> None:
    """{"params", "batch_stats"} of a backbone as msgpack (atomic)."""
    tree = {"params": jax.device_get(params), "batch_stats": jax.device_get(batch_stats or {})}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, flax.serialization.msgpack_serialize(tree))


def load_backbone(path, kind: str | None = None):
    """(params, batch_stats) of a pretrained backbone: `path` is the backbone file, its folder
    (DIR/<kind>), or the --out DIR with `kind` given (or holding exactly one kind). batch_stats is {} for
    the ViT."""
    path = Path(path)
    if path.is_dir():
        if (path / BACKBONE_FILE).exists():
            path = path / BACKBONE_FILE
        else:
            found = [k for k in KINDS if (path / k / BACKBONE_FILE).exists() and kind in (None, k)]
            if len(found) != 1:
                raise FileNotFoundError(f"no unique pretrained backbone in {path} (found {found or 'none'}; "
                                        "pass kind= or the DIR/<kind> folder)")
            path = path / found[0] / BACKBONE_FILE
    tree = flax.serialization.msgpack_restore(path.read_bytes())
    return tree["params"], tree.get("batch_stats") or {}


# ----------------------------------------------------------------------------- linear probe
def features(cfg: dict, kind: str, params, batch_stats, images, batch: int = 256) -> np.ndarray:
    """Frozen backbone features (N, D) of preprocessed images (N,S,S,3), eval mode."""
    from ffjax import models

    net = models.build_backbone(cfg["model"], kind, int(cfg["data"]["input_size"]))
    variables = {"params": params, **({"batch_stats": batch_stats} if batch_stats else {})}
    fn = jax.jit(lambda x: net.apply(variables, x, train=False)["feature"])
    out = [np.asarray(fn(jnp.asarray(images[a: a + batch]))) for a in range(0, len(images), batch)]
    return np.concatenate(out).astype(np.float64)


def linear_probe(train_x, train_y, evals: dict, force_range=None, lambdas=(1e-5, 1e-4, 1e-3, 1e-2, 0.1, 1.0, 10.0),
                 folds: int = 5) -> dict:
    """Ridge regression from frozen features to force. Features are standardized on train, lambda is
    chosen by k-fold CV on train only; returns {split: metrics.summarize(...)} plus "lambda"."""
    from ffjax import metrics

    mu, sd = train_x.mean(0), train_x.std(0) + 1e-8
    ymu = train_y.mean(0)

    def fit(x, y, lam):
        z = (x - mu) / sd
        return np.linalg.solve(z.T @ z + lam * len(z) * np.eye(z.shape[1]), z.T @ (y - ymu))

    def predict(w, x):
        return ((x - mu) / sd) @ w + ymu

    fold = np.random.default_rng(0).permutation(len(train_x)) % folds
    cv = {lam: np.mean([np.abs(predict(fit(train_x[fold != k], train_y[fold != k], lam), train_x[fold == k])
                               - train_y[fold == k]).mean() for k in range(folds)]) for lam in lambdas}
    lam = min(cv, key=cv.get)
    w = fit(train_x, train_y, lam)
    lo, hi = force_range if force_range is not None else (train_y.min(0), train_y.max(0))
    out = {name: metrics.summarize(predict(w, x), y, lo, hi) for name, (x, y) in
           {"train": (train_x, train_y), **evals}.items()}
    out["lambda"] = float(lam)
    return out


def _pooled_pixels(images: np.ndarray, grid: int = 8) -> np.ndarray:
    """Images (N,S,S,3) average-pooled to grid x grid x 3 and flattened: a reference probe input."""
    n, S = images.shape[:2]
    return images.reshape(n, grid, S // grid, grid, S // grid, 3).mean((2, 4)).reshape(n, -1).astype(np.float64)


def feature_health(x: np.ndarray) -> dict:
    """Collapse checks on frozen features: std across images of the L2-normalized feature (mean over
    dims) and the effective rank (participation ratio of the covariance spectrum)."""
    xn = x / (np.linalg.norm(x, axis=1, keepdims=True) + 1e-12)
    ev = np.clip(np.linalg.eigvalsh(np.cov(x.T)), 0, None)
    return {"feature_std": float(xn.std(0).mean()), "effective_rank": float(ev.sum() ** 2 / (ev**2).sum()),
            "dim": int(x.shape[1])}


def probe_report(cfg: dict, kind: str, folder, data_dir, sensors=("mini-2-gel1", "mini-3-gel2", "digit"),
                 progress: bool = True) -> dict:
    """Linear probe of random-init vs pretrained `kind` backbones on the simulated dataset: train on
    "train", evaluate on "val", all "unseen/*" objects together and a few other sensors; writes
    folder/probe.json and returns it."""
    from ffjax import data, models

    t0 = time.perf_counter()
    data_dir, S = Path(data_dir), int(cfg["data"]["input_size"])
    train_src = data.open_split(data_dir / "train")
    stats = data.Stats.compute(train_src, cfg["data"], S)
    splits = {"train": data_dir / "train", "val": data_dir / "val"}
    unseen = sorted((data_dir / "unseen").glob("*/"))
    splits.update({f"sensor/{s}": data_dir / "sensor" / s for s in sensors if (data_dir / "sensor" / s).exists()})
    arrays = {k: data.load_arrays(data.open_split(v), stats, S) for k, v in splits.items()}
    if unseen:
        parts = [data.load_arrays(data.open_split(u), stats, S) for u in unseen]
        arrays["unseen"] = {k: np.concatenate([q[k] for q in parts]) for k in ("image", "force")}
    net = models.build_backbone(cfg["model"], kind, S)
    init = net.init(jax.random.PRNGKey(int(cfg["seed"])), jnp.zeros((1, S, S, 3)), train=False)
    candidates = {"random_init": (init["params"], init.get("batch_stats", {})),
                  "pretrained": load_backbone(folder), "pixels_8x8": None}  # a no-network reference
    fr = (np.asarray(stats.force_min), np.asarray(stats.force_max))
    report = {"kind": kind, "data": str(data_dir), "preset": cfg.get("preset"), "probe": "ridge on frozen features",
              "metric": "normalized L1 % (train-label range per axis, mean over Fx, Fy, Fz)", "results": {}}
    for name, cand in candidates.items():
        feats = {k: features(cfg, kind, *cand, a["image"]) if cand else _pooled_pixels(a["image"])
                 for k, a in arrays.items()}
        evals = {k: (feats[k], arrays[k]["force"].astype(np.float64)) for k in arrays if k != "train"}
        res = linear_probe(feats["train"], arrays["train"]["force"].astype(np.float64), evals, fr)
        res["health"] = feature_health(feats["val"])
        report["results"][name] = res
        if progress:
            print(f"probe[{kind}] {name}: " + ", ".join(f"{k} {v['nl1']:.2f}%" for k, v in res.items()
                                                       if isinstance(v, dict) and "nl1" in v))
    report["seconds"] = round(time.perf_counter() - t0, 1)
    atomic_write_json(Path(folder) / "probe.json", report)
    return report


def format_report(report: dict) -> str:
    """A markdown table: rows = random init / pretrained, columns = splits (normalized L1 %)."""
    res = report["results"]
    cols = [k for k, v in next(iter(res.values())).items() if isinstance(v, dict) and "nl1" in v]
    lines = [f"linear probe, {report['kind']} ({report['metric']})", "",
             "| backbone | " + " | ".join(cols) + " | feature std | eff. rank |",
             "|---" * (len(cols) + 3) + "|"]
    for name, r in res.items():
        lines.append(f"| {name} | " + " | ".join(f"{r[c]['nl1']:.2f}" for c in cols)
                     + f" | {r['health']['feature_std']:.3f} | {r['health']['effective_rank']:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> None:
    import configs

    ap = argparse.ArgumentParser(prog="python -m ffjax.train.pretrain", description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="quick", choices=configs.PRESETS,
                    help="corpus and schedule size (default: quick). Measured on a 2-core CPU: quick and full: "
                    "1-1.5 min for the ViT, 1.5-3.5 min for the ResNet (cached after, per backbone)")
    ap.add_argument("--backbone", default="all", choices=(*KINDS, "all"), help="which to pretrain (default: all)")
    ap.add_argument("--out", default=None, help="output folder (default data/<preset>/pretrained)")
    ap.add_argument("--force", action="store_true", help="pretrain again even if a matching cache exists")
    ap.add_argument("--probe", action="store_true", help="also run the linear probe (random vs pretrained)")
    ap.add_argument("--data", default=None, help="labelled dataset for the probe (default data/<preset>)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    cfg = configs.from_cli(ap, args.preset, args.set)
    out = Path(args.out or Path("data") / args.preset / "pretrained")
    from ffjax import cli

    cli.check_out(ap, out)  # before pretraining: a read-only or mistyped --out fails now, named
    for kind in KINDS if args.backbone == "all" else (args.backbone,):
        folder = ensure(cfg, kind, run_dir(out, kind), force=args.force, progress=not args.quiet)
        if args.probe:
            data = Path(args.data or Path("data") / args.preset)
            if not (data / "train").exists():
                from ffjax.sim import dataset

                dataset.generate(cfg, data, progress=not args.quiet)
            print(format_report(probe_report(cfg, kind, folder, data, progress=not args.quiet)))


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
