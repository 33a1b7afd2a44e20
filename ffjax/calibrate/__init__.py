"""Adapting a trained model to a new sensor from ~100 labelled frames (paper section IV-B)."""

from ffjax.calibrate.core import (
    LAYERS,
    features,
    fit_regressor,
    predict_from_features,
    regressor_stats,
    trainable_mask,
    with_regressor,
)

__all__ = [
    "LAYERS", "features", "fit_regressor", "predict_from_features", "regressor_stats", "trainable_mask",
    "with_regressor",
]
