"""LED drift as a real GelSight Mini shows it at rest, added to training frames so that a model learns not to read
it as force (issue 64). `train.drift_minutes` > 0 turns it on.

A frame taken t minutes after its background differs from it, with nothing touching the gel, by a uniform shift
per colour channel (the LEDs' gain and offset drift) and a smooth field across the pad. Both rates, per channel
and per minute, are measured by `experiments.diagnostics.rest_recording` on the authors' release recording at rest
(docs/results/real/rest_recording/results.json: `drift_per_min`, the fitted rate of the mean, and
`drift_field_rms_per_min`, the rms of what offset + gain x level leave). Each training frame draws t uniformly in
[0, drift_minutes], one sign for its three channels (a warming LED dims, a cooling one brightens: the recording shows
one direction, the augmentation both), and a smooth field of unit rms per channel; what it adds in counts is
t x (sign x shift + field_rate x field). The recording gives the field's size, not its spatial spectrum: it is
drawn on a coarse grid (FIELD_CELLS across the short side) and upsampled, smoother than any contact's imprint.
Padding (the rows `pad_to_square` adds) is left as it is.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import grain
import numpy as np

from ffjax.errors import DataError

MEASURED = Path(__file__).resolve().parents[2] / "docs" / "results" / "real" / "rest_recording" / "results.json"
SOURCE = "GelSight Mini (real)"
FIELD_CELLS = 4  # the drift field's coarse grid across the input's short side


@dataclasses.dataclass(frozen=True)
class DriftRates:
    """Counts per minute, per channel (R, G, B): the uniform shift and the rms of the smooth field."""

    shift: tuple[float, float, float]
    field: tuple[float, float, float]

    @classmethod
    def measured(cls, path: str | Path = MEASURED) -> DriftRates:
        """The rates the rest-recording diagnostic measured on the real Mini; DataError naming the file if it is
        missing or lacks them."""
        path = Path(path)
        try:
            src = json.loads(path.read_text())["sources"][SOURCE]
            rates = cls(tuple(float(v) for v in src["drift_per_min"]),
                        tuple(float(v) for v in src["drift_field_rms_per_min"]))
        except FileNotFoundError:
            raise DataError(f"{path}: no such file; the drift augmentation (train.drift_minutes) reads the real "
                            "Mini's drift rates from it (python -m experiments.diagnostics.rest_recording)") from None
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise DataError(f"{path}: no drift rates of {SOURCE!r} (drift_per_min, drift_field_rms_per_min): "
                            f"{type(e).__name__}: {e}") from None
        if len(rates.shift) != 3 or len(rates.field) != 3:
            raise DataError(f"{path}: drift rates of {SOURCE!r} need 3 channels, got {rates}")
        return rates


def smooth_field(rng: np.random.Generator, n: int, size: int) -> np.ndarray:
    """(n, size, size, 3) float32 smooth random fields, each channel of unit rms: Gaussian values on a coarse grid,
    upsampled bicubically."""
    cells = FIELD_CELLS + 1
    coarse = rng.standard_normal((n, cells, cells, 3)).astype(np.float32)
    field = np.stack([cv2.resize(c, (size, size), interpolation=cv2.INTER_CUBIC) for c in coarse])
    field -= field.mean(axis=(1, 2), keepdims=True)
    return field / np.maximum(np.sqrt(np.mean(field**2, axis=(1, 2), keepdims=True)), 1e-6)


class DriftAugment(grain.transforms.RandomMap):
    """A batch {"image": (B, S, S, 3) normalized, ...} -> the same with each frame drifted as above. `mean`, `std`:
    the train set's per-channel statistics (data.Stats), which map counts to the model's input units."""

    def __init__(self, rates: DriftRates, minutes: float, mean, std):
        if not minutes > 0:
            raise ValueError(f"drift minutes must be > 0, got {minutes!r}")
        self.minutes = float(minutes)
        std = np.asarray(std, np.float32).reshape(3)
        self.shift = np.asarray(rates.shift, np.float32) / (255 * std)  # input units per minute
        self.field = np.asarray(rates.field, np.float32) / (255 * std)
        self.pad = (np.float32(0) - np.asarray(mean, np.float32).reshape(3)) / std  # what padding normalizes to

    def random_map(self, batch: dict, rng: np.random.Generator) -> dict:
        image = np.asarray(batch["image"], np.float32)
        n, size = image.shape[0], image.shape[1]
        t = rng.uniform(0.0, self.minutes, n).astype(np.float32)[:, None, None, None]
        sign = rng.choice(np.array([-1.0, 1.0], np.float32), n)[:, None, None, None]
        drift = t * (sign * self.shift + self.field * smooth_field(rng, n, size))
        on_pad = np.all(image == self.pad, axis=-1, keepdims=True)
        return {**batch, "image": np.where(on_pad, image, image + drift).astype(np.float32)}


def augment(cfg_train: dict, stats) -> DriftAugment | None:
    """The drift augmentation train.drift_minutes asks for (None when 0), on the real Mini's measured rates."""
    minutes = float(cfg_train.get("drift_minutes", 0.0))
    if minutes == 0:
        return None
    return DriftAugment(DriftRates.measured(), minutes, stats.mean, stats.std)
