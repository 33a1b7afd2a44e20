"""Smoothing filters for force streams (off by default; for control loops that want less jitter).

    from ffjax.live import filters
    f = filters.parse("ema:0.3")                            # y = a*x + (1-a)*y_prev, a in (0, 1]
    f = filters.parse("one-euro:1.0,0.05")                  # min_cutoff Hz, beta [, d_cutoff Hz]
    f = filters.parse("one-euro:min_cutoff=1,beta=0.05,d_cutoff=1")
    y = f(t_seconds, force_xyz)                             # per axis; f.reset() forgets the past

EMA lags by about (1 - a) / a frames at every speed. One-Euro (Casiez et al., CHI 2012) adapts its cutoff
to the signal's speed: heavy smoothing at rest (low jitter), little lag when the force changes fast;
raise min_cutoff for less lag at rest, raise beta for less lag in motion.
"""

from __future__ import annotations

import math

import numpy as np


class EMA:
    def __init__(self, alpha: float = 0.3):
        if not 0 < alpha <= 1:
            raise ValueError(f"EMA alpha must be in (0, 1], got {alpha}")
        self.alpha = float(alpha)
        self.reset()

    def reset(self) -> None:
        self.y = None

    def __call__(self, t: float, x) -> np.ndarray:
        x = np.asarray(x, np.float64)
        self.y = x.copy() if self.y is None else self.alpha * x + (1 - self.alpha) * self.y
        return self.y.astype(np.float32)

    def __repr__(self) -> str:
        return f"ema:{self.alpha}"


def _alpha(cutoff_hz: np.ndarray | float, dt: float):
    tau = 1.0 / (2 * math.pi * np.asarray(cutoff_hz))
    return 1.0 / (1.0 + tau / dt)


class OneEuro:
    def __init__(self, min_cutoff: float = 1.0, beta: float = 0.0, d_cutoff: float = 1.0):
        if min_cutoff <= 0 or d_cutoff <= 0 or beta < 0:
            raise ValueError("one-euro needs min_cutoff > 0, d_cutoff > 0, beta >= 0")
        self.min_cutoff, self.beta, self.d_cutoff = float(min_cutoff), float(beta), float(d_cutoff)
        self.reset()

    def reset(self) -> None:
        self.t = self.x = None
        self.dx = 0.0

    def __call__(self, t: float, x) -> np.ndarray:
        x = np.asarray(x, np.float64)
        if self.x is None:
            self.t, self.x, self.dx = t, x.copy(), np.zeros_like(x)
            return x.astype(np.float32)
        dt = max(float(t - self.t), 1e-6)  # a repeated timestamp must not divide by zero
        dx = (x - self.x) / dt
        a_d = _alpha(self.d_cutoff, dt)
        self.dx = a_d * dx + (1 - a_d) * self.dx
        a = _alpha(self.min_cutoff + self.beta * np.abs(self.dx), dt)
        self.x = a * x + (1 - a) * self.x
        self.t = t
        return self.x.astype(np.float32)

    def __repr__(self) -> str:
        return f"one-euro:min_cutoff={self.min_cutoff},beta={self.beta},d_cutoff={self.d_cutoff}"


def parse(spec: str | None):
    """A filter from "ema:A", "one-euro:MIN_CUTOFF[,BETA[,D_CUTOFF]]" (or key=value), or None/"none"."""
    if spec is None or spec.strip().lower() in ("", "none", "off"):
        return None
    name, _, args = spec.partition(":")
    name = name.strip().lower().replace("_", "-")
    parts = [a.strip() for a in args.split(",") if a.strip()]
    try:
        if name == "ema":
            return EMA(float(parts[0]) if parts else 0.3)
        if name in ("one-euro", "oneeuro", "1euro"):
            keys = ("min_cutoff", "beta", "d_cutoff")
            kw = {}
            for i, a in enumerate(parts):
                k, eq, v = a.partition("=")
                if eq:
                    if k.strip() not in keys:
                        raise ValueError(f"unknown one-euro parameter {k!r} (use {', '.join(keys)})")
                    kw[k.strip()] = float(v)
                else:
                    kw[keys[i]] = float(a)
            return OneEuro(**kw)
    except (IndexError, ValueError) as e:
        raise ValueError(f"bad filter {spec!r}: {e}") from None
    raise ValueError(f"unknown filter {spec!r}: use ema:ALPHA or one-euro:MIN_CUTOFF,BETA[,D_CUTOFF]")
