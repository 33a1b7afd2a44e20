"""Contact mechanics of a thin gel layer on glass: penetration -> pressure, normal force, gel surface, shear.

- Normal: each gel column under the body is compressed by d = max(0, delta - h). Its pressure is the
  uniaxial neo-Hookean law p = (E/3) (1/lam^2 - lam), lam = 1 - d/t: Winkler p = (E/t) d at small
  strain, stiffening as the column is squeezed towards the glass (so every body reaches 15 N before
  bottoming out). Fz = sum(p) * pixel area; delta is solved for the requested Fz (Newton, monotone).
- Surface: the gel surface is d smoothed by a kernel scaled with the thickness (Taxim's idea), never
  below the body, with a shallow rim from incompressibility.
- Shear: stick displacement s = F_t / k_t, k_t = G (A/t + 16 a / 3) (thin layer + Mindlin's 8 G a / (2 - nu)
  at nu = 0.5 for contacts smaller than the layer), capped by Coulomb |F_t| <= mu Fz (slip flag). The
  tangential field decays away from the contact; incompressibility raises a bulge in front.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

MAX_STRAIN = 0.9  # presses needing a deeper column strain than this are refused (gel would bottom out)
SMOOTH_FRAC = 0.3  # gel-surface smoothing sigma = SMOOTH_FRAC * thickness
RIM_FRAC = 0.12  # rim height relative to the wide-smoothed penetration
SHEAR_DECAY_FRAC = 0.5  # decay length of the tangential field outside the contact, x thickness
BULGE_FRAC = 0.5  # part of the displaced volume that rises as a bulge (the rest spreads in the layer)
_BINS = 2048


def pressure(d, young: float, thickness: float):
    """Column pressure (MPa = N/mm^2) at compression d (mm)."""
    lam = 1.0 - np.asarray(d) / thickness
    return young / 3.0 * (1.0 / lam**2 - lam)


def _dpressure(d, young: float, thickness: float):
    lam = 1.0 - np.asarray(d) / thickness
    return young / 3.0 * (2.0 / lam**3 + 1.0) / thickness


def normal_force(h: np.ndarray, delta: float, cell_area: float, young: float, thickness: float) -> float:
    """Fz (N) for body heights h (mm) on a grid of cell_area (mm^2) pushed in by delta (mm)."""
    d = np.clip(delta - h, 0, None)
    return float(pressure(d, young, thickness).sum() * cell_area)


def solve_delta(h: np.ndarray, cell_area: float, young: float, thickness: float, fz: float) -> float:
    """Approach delta (mm) at which the body (heights h over the pad) carries Fz; ValueError if the gel
    would have to be compressed past MAX_STRAIN of its thickness."""
    hmin = float(h.min())
    if fz <= 0:
        return hmin
    dmax = MAX_STRAIN * thickness
    bw = dmax / _BINS
    rel = (h.ravel() - hmin) / bw
    rel = rel[rel < _BINS]
    counts = np.bincount(rel.astype(np.int64), minlength=_BINS)[:_BINS].astype(np.float64)
    hb = (np.arange(_BINS) + 0.5) * bw  # bin centres above hmin
    nz = counts > 0
    counts, hb = counts[nz], hb[nz]

    def f_and_df(pen):
        d = np.clip(pen - hb, 0, None)
        on = d > 0
        return (float((counts * pressure(d, young, thickness)).sum() * cell_area),
                float((counts[on] * _dpressure(d[on], young, thickness)).sum() * cell_area))

    pen = dmax
    f, df = f_and_df(pen)
    if f < fz:
        raise ValueError(
            f"Fz={fz:.3g} N is beyond what this gel takes for this body and pose: at {MAX_STRAIN:.0%} of the "
            f"{thickness} mm gel thickness it carries only {f:.3g} N")
    for _ in range(60):  # Newton from the right on a convex increasing F: monotone, no overshoot
        step = (f - fz) / max(df, 1e-12)
        pen = max(pen - step, 0.0)
        f, df = f_and_df(pen)
        if abs(f - fz) <= 1e-6 * fz or step < 1e-9:
            break
    return hmin + pen


def smooth(x: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian blur; wide kernels run on a downsampled copy (same result to the eye, ~10x faster)."""
    if sigma_px < 0.3:
        return x
    H, W = x.shape[:2]
    # downsampling factor: a common divisor of H and W, so block averaging stays mirror-symmetric
    f = max((k for k in range(1, int(sigma_px // 3) + 1) if H % k == 0 and W % k == 0), default=1)
    if f <= 1:
        return cv2.GaussianBlur(x, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
    small = cv2.resize(x, (max(1, W // f), max(1, H // f)), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), sigma_px / f, borderType=cv2.BORDER_REPLICATE)
    up = cv2.resize(small, (W, H), interpolation=cv2.INTER_LINEAR)
    # remove the bilinear kinks: their piecewise-constant slopes would show up as stripes in the shading
    return cv2.GaussianBlur(up, (0, 0), 0.6 * f, borderType=cv2.BORDER_REPLICATE)


def gel_surface(d: np.ndarray, thickness: float, mm_per_px: float) -> np.ndarray:
    """Gel surface displacement (mm, + = into the gel) from the column compression d (mm)."""
    sig = SMOOTH_FRAC * thickness / mm_per_px
    u = np.maximum(d, smooth(d, sig))
    rim = RIM_FRAC * smooth(d, 2.5 * sig)
    return np.maximum(d, u - rim)


@dataclasses.dataclass
class Shear:
    force: np.ndarray  # (2,) applied tangential force, N (capped)
    disp_mm: np.ndarray  # (2,) stick displacement of the contact, mm
    slip: bool
    stiffness: float  # k_t, N/mm
    field: np.ndarray | None  # (H, W) weight of the displacement, 1 in the contact, decaying outside


def shear(ft, fz: float, contact: np.ndarray, cell_area: float, shear_mpa: float, thickness: float,
          friction: float, mm_per_px: float, area: float | None = None) -> Shear:
    """Tangential response to the requested shear ft = (Fx, Fy) with the Coulomb cap mu * Fz.
    `area` (mm^2) overrides the contact area measured on `contact` (e.g. from a finer grid)."""
    ft = np.asarray(ft, dtype=np.float64)
    area = float(contact.sum()) * cell_area if area is None else area
    cap = friction * fz
    mag = float(np.hypot(*ft))
    slip = mag > cap + 1e-9
    applied = ft * (cap / mag) if slip else ft
    if area <= 0 or not np.any(applied) or not contact.any():
        return Shear(applied, np.zeros(2), slip, 0.0, None)
    a = np.sqrt(area / np.pi)
    k_t = shear_mpa * (area / thickness + 16.0 / 3.0 * a)
    g = smooth(contact.astype(np.float32), SHEAR_DECAY_FRAC * thickness / mm_per_px)
    field = np.clip(g / (0.5 * max(float(g.max()), 1e-6)), 0, 1)
    field = np.maximum(field, contact)
    return Shear(applied, applied / k_t, slip, k_t, field.astype(np.float32))


def shear_bulge(sh: Shear, thickness: float, mm_per_px: float) -> np.ndarray | float:
    """Surface displacement (mm, + = into the gel) from the layer's volume moving with the shear:
    dz = -(t/2) div(s w) for a displacement growing linearly through the thickness."""
    if sh.field is None:
        return 0.0
    gy, gx = np.gradient(sh.field, mm_per_px)
    return BULGE_FRAC * thickness / 2 * (sh.disp_mm[0] * gx + sh.disp_mm[1] * gy)
