"""Train-set statistics: image normalization, depth range, force range (for the metric)."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from ffjax.data.preprocess import to_unit
from ffjax.errors import DataError

AXES = ("Fx", "Fy", "Fz")


@dataclasses.dataclass(frozen=True)
class Stats:
    """mean/std: per channel of the model input before normalization (bg-subtracted, padded, resized, /255);
    depth_min/depth_max: the depth normalization range in mm, eps already applied (train min - eps,
    max + eps); force_min/force_max: per-axis label range in newtons; count: records the stats saw."""

    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    depth_min: float
    depth_max: float
    force_min: tuple[float, float, float]
    force_max: tuple[float, float, float]
    input_size: int
    depth_eps: float = 0.0
    count: int = 0

    @classmethod
    def compute(cls, source, data_cfg: dict, input_size: int | None = None, max_samples: int | None = 20000,
                chunk: int = 512) -> Stats:
        """Statistics over `source` (the train split). Image mean/std and the depth range use up to
        `max_samples` evenly spaced records (all of them for CPU-scale splits); the force range uses all."""
        size = int(input_size or data_cfg["input_size"])
        eps = float(data_cfg["depth_eps"])
        n = len(source)
        if n == 0:
            raise ValueError(f"cannot compute statistics over an empty split ({source!r})")
        forces = np.asarray(source.forces, np.float32)
        take = n if max_samples is None or n <= max_samples else max_samples
        s1, s2 = np.zeros(3), np.zeros(3)
        pixels = 0
        dmin, dmax = np.inf, -np.inf
        if take == n:  # contiguous chunks: the shard fast path
            chunks = ((i, min(i + chunk, n)) for i in range(0, n, chunk))
            batches = (source.read_range(a, b) for a, b in chunks)
        else:
            idx = np.linspace(0, n - 1, take).round().astype(int)
            batches = (_stack([source[int(i)] for i in idx[a: a + chunk]]) for a in range(0, take, chunk))
        for b in batches:
            x = to_unit(b["image"], b.get("background", source_background(source)), size).astype(np.float64)
            s1 += x.sum(axis=(0, 1, 2))
            s2 += (x * x).sum(axis=(0, 1, 2))
            pixels += x.shape[0] * x.shape[1] * x.shape[2]
            dmin, dmax = min(dmin, float(b["depth"].min())), max(dmax, float(b["depth"].max()))
        mean = s1 / pixels
        std = np.sqrt(np.maximum(s2 / pixels - mean**2, 1e-12))
        return cls(mean=tuple(float(v) for v in mean), std=tuple(float(v) for v in std),
                   depth_min=dmin - eps, depth_max=dmax + eps,
                   force_min=tuple(float(v) for v in forces.min(0)),
                   force_max=tuple(float(v) for v in forces.max(0)),
                   input_size=size, depth_eps=eps, count=n)

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> Stats:
        fields = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - fields
        if unknown:
            raise ValueError(f"unknown Stats keys {sorted(unknown)}")
        return cls(**{k: tuple(float(x) for x in v) if isinstance(v, (list, tuple)) else v
                      for k, v in d.items()})

    @property
    def force_range(self) -> np.ndarray:
        """max - min per axis (the metric's normalizer)."""
        return np.asarray(self.force_max, np.float32) - np.asarray(self.force_min, np.float32)


def check_force_range(source) -> None:
    """Refuse training labels that never vary (nothing to learn, no range for the metric: DataError naming the
    split); warn about an axis that never varies (a sensor that records Fz only): the normalized L1 leaves it out
    (ffjax.metrics). Reads the labels only, so a training run checks them before it writes anything."""
    where = getattr(source, "csv_path", None) or getattr(source, "path", None) or repr(source)
    forces = np.asarray(source.forces, np.float32)
    lo, hi = forces.min(0), forces.max(0)
    constant = [a for a, l, h in zip(AXES, lo, hi, strict=True) if not h > l]
    if len(constant) == len(AXES):
        raise DataError(f"{where}: the training labels hold one force on every row ({', '.join(AXES)} = "
                        f"{', '.join(f'{v:g}' for v in lo)} N): nothing to learn; give a split whose forces vary "
                        "(a CSV's FT column, a shard's force array)")
    if constant:
        warnings.warn(f"{where}: {' and '.join(constant)} hold one value on every training row: the normalized L1 "
                      f"leaves {'it' if len(constant) == 1 else 'them'} out (their error in N is still reported)",
                      stacklevel=2)


def source_background(source):
    return getattr(source, "background", None)


def _stack(records: list[dict]) -> dict:
    return {k: np.stack([r[k] for r in records]) for k in ("image", "background", "depth", "force")}


def background_stats(background) -> dict:
    """Per-channel mean and std (grey levels, RGB) of a uint8 (H, W, 3) background, as model.json records it."""
    x = np.asarray(background, np.float64).reshape(-1, 3)
    return {"mean": x.mean(0).round(2).tolist(), "std": x.std(0).round(2).tolist(), "channels": "RGB"}
