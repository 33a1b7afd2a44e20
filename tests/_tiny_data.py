"""A tiny labelled split in the on-disk shard layout, shared by the training, resume, metric and fault tests."""

from __future__ import annotations

import numpy as np

import configs
from ffjax.data.images import write_rgb


def write_tiny_split(path, n, seed):
    """Random forces, images a blob whose brightness and offset follow the force (so there is something to
    learn), plus a flat background; frames at the smoke preset's render size."""
    rng = np.random.default_rng(seed)
    path.mkdir(parents=True)
    h, w = configs.get("smoke")["data"]["render_size"]
    bg = np.full((h, w, 3), 120, np.uint8)
    force = np.stack([rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), rng.uniform(0, 15, n)], 1).astype(np.float32)
    yy, xx = np.mgrid[:h, :w]
    blobs = [np.exp(-((yy - h / 2 - f[1]) ** 2 + (xx - w / 2 - f[0]) ** 2) / (2 * (1 + f[2] / 5) ** 2)) for f in force]
    depth = np.stack(blobs).astype(np.float32) * force[:, 2, None, None] / 10
    image = np.clip(bg[None].astype(np.float32) + 80 * depth[..., None], 0, 255).astype(np.uint8)
    np.savez(path / "shard_00000.npz", image=image, depth=depth, force=force, shape=np.array(["blob"] * n))
    write_rgb(path / "background.png", bg)


def write_tiny_dataset(root, n_train: int = 32, n_val: int = 8, seed: int = 0):
    """root/train and root/val tiny splits (seeds `seed`, `seed + 1`); returns root."""
    write_tiny_split(root / "train", n_train, seed)
    write_tiny_split(root / "val", n_val, seed + 1)
    return root
