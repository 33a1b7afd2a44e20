"""How good a pretrained backbone's frozen features are: a ridge linear probe from features to force on the
simulated dataset (random init vs pretrained vs pooled pixels), collapse checks on the features, and the
report as probe.json and a markdown table (`python -m ffjax.train.pretrain --probe`)."""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ffjax import data, metrics, models
from ffjax.files import atomic_write_json
from ffjax.train.pretrain.cache import load_backbone


def features(cfg: dict, kind: str, params, batch_stats, images, batch: int = 256) -> np.ndarray:
    """Frozen backbone features (N, D) of preprocessed images (N,S,S,3), eval mode."""
    net = models.build_backbone(cfg["model"], kind, int(cfg["data"]["input_size"]))
    variables = {"params": params, **({"batch_stats": batch_stats} if batch_stats else {})}
    fn = jax.jit(lambda x: net.apply(variables, x, train=False)["feature"])
    out = [np.asarray(fn(jnp.asarray(images[a: a + batch]))) for a in range(0, len(images), batch)]
    return np.concatenate(out).astype(np.float64)


def linear_probe(train_x, train_y, evals: dict, force_range=None, lambdas=(1e-5, 1e-4, 1e-3, 1e-2, 0.1, 1.0, 10.0),
                 folds: int = 5) -> dict:
    """Ridge regression from frozen features to force. Features are standardized on train, lambda is
    chosen by k-fold CV on train only; returns {split: metrics.summarize(...)} plus "lambda"."""
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
