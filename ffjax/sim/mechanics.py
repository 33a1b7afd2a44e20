"""Contact mechanics of a thin gel layer on glass: requested Fz -> approach, pressure, gel surface, shear.

- Normal: the gel is an incompressible elastic layer bonded to the glass (`ffjax.sim.elastic_layer`: exact
  small-strain compliance, Polonsky-Keer contact solve on a grid with a margin of SOLVE_MARGIN_T
  thicknesses around the pad). So a flat face loads its edges when small against the thickness and the
  layer stiffens strongly when the contact is wide against it (the gel must flow out sideways), and the
  free surface around the contact is dragged down and pushed up by the displaced volume. Large strain:
  the layer's linear displacement v is mapped pointwise through the uniaxial neo-Hookean law
  v / t = psi(u / t), psi(e) = ((1 - e)^-2 - (1 - e)) / 3, so a column squeezed towards the glass
  stiffens (psi(e) = e + e^2 + ...) and every body reaches 15 N before bottoming out. This is an
  approximation: the stiffening is local, the layer coupling linear.
- Shear: stick displacement s = F_t / k_t, k_t = G (A/t + 16 a / 3) (thin layer + Mindlin's 8 G a / (2 - nu)
  at nu = 0.5 for contacts smaller than the layer), capped by Coulomb |F_t| <= mu Fz (slip flag). The
  tangential field decays away from the contact; incompressibility raises a bulge in front.
"""

from __future__ import annotations

import dataclasses
import functools

import cv2
import numpy as np

from ffjax.sim import elastic_layer

MAX_STRAIN = 0.9  # presses needing a deeper compression than this x thickness are refused (gel bottoms out)
SOLVE_MARGIN_T = 2.0  # layer beyond the pad in the solve, x thickness: its response decays over ~t
SHEAR_DECAY_FRAC = 0.5  # decay length of the tangential field outside the contact, x thickness
BULGE_FRAC = 0.5  # part of the displaced volume that rises as a bulge (the rest spreads in the layer)
_EPS = np.linspace(0.0, 0.98, 4096)  # compressive strain table for psi and its inverse
_PSI = ((1.0 - _EPS) ** -2 - (1.0 - _EPS)) / 3.0
_OUTER_TOL = 1e-4  # fixed point on the approach: stop when it moves less than this x thickness


def stiffen(u, thickness: float):
    """Linear-layer displacement that carries the load of a real compression u (mm): t psi(u / t);
    identity for u <= 0 (the gel rising), as psi'(0) = 1."""
    u = np.asarray(u, dtype=np.float64)
    return np.where(u <= 0, u, thickness * np.interp(u / thickness, _EPS, _PSI, right=np.inf))


def soften(v, thickness: float):
    """Inverse of `stiffen`: the real compression (mm) for a linear-layer displacement v."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0, v, thickness * np.interp(v / thickness, _PSI, _EPS))


def _fast_len(n: int) -> int:
    """The smallest 5-smooth integer >= n (FFT sizes with only factors 2, 3, 5 are the fast ones)."""
    while True:
        k = n
        for f in (2, 3, 5):
            while k % f == 0:
                k //= f
        if k == 1:
            return n
        n += 1


@functools.lru_cache(maxsize=64)  # the pretraining corpus cycles through 24 randomized gels
def _layer(shape: tuple[int, int], dx: float, thickness: float, shear_mpa: float) -> elastic_layer.Layer:
    return elastic_layer.Layer(shape, dx, thickness, shear_mpa)


@dataclasses.dataclass
class Normal:
    delta: float  # approach (mm) from the first touch: the deepest compression
    surface: np.ndarray  # (H, W) gel surface displacement on the pad grid, mm (+ = into the gel)
    contact: np.ndarray  # (H, W) bool
    pressure: np.ndarray  # (H, W) MPa


def solve_normal(h: np.ndarray, mm_per_px: float, shear_mpa: float, thickness: float, fz: float) -> Normal:
    """The layer's response to a rigid frictionless body of heights h (mm over the pad grid; >= FAR/2 = no
    body) pressed until it carries Fz (N). ValueError if the gel would be compressed past MAX_STRAIN."""
    H, W = h.shape
    body_pad = h < elastic_layer.FAR / 2
    if fz <= 0 or not body_pad.any():
        zero = np.zeros((H, W))
        return Normal(0.0, zero, zero.astype(bool), zero)
    m = int(np.ceil(SOLVE_MARGIN_T * thickness / mm_per_px))
    hb = np.full((_fast_len(H + 2 * m), _fast_len(W + 2 * m)), elastic_layer.FAR)  # extra margin: fast FFT
    hb[m:m + H, m:m + W] = np.where(body_pad, h - float(h[body_pad].min()), elastic_layer.FAR)
    body = hb < elastic_layer.FAR / 2
    layer = _layer(hb.shape, float(mm_per_px), float(thickness), float(shear_mpa))
    target, delta, p = hb, None, None
    for _ in range(30):  # fixed point on the approach: the stiffened target depends on it
        r = elastic_layer.solve_contact(target, layer, fz, tol=1e-6, p0=p)
        p = r["p"]
        on = r["contact"]
        new = float(np.mean(hb[on] + soften(r["u"][on], thickness)))
        done = delta is not None and abs(new - delta) < _OUTER_TOL * thickness
        delta = new
        if done:
            break
        target = np.where(body, -stiffen(np.minimum(delta, _EPS[-1] * thickness) - hb, thickness),
                          elastic_layer.FAR)
    if delta > MAX_STRAIN * thickness:
        raise ValueError(
            f"Fz={fz:.3g} N is beyond what this gel takes for this body and pose: it would compress the "
            f"{thickness} mm gel past {MAX_STRAIN:.0%} of its thickness")
    inner = (slice(m, m + H), slice(m, m + W))
    surface = np.maximum(soften(r["u"], thickness), delta - hb)[inner]  # never inside the body
    return Normal(delta, surface, r["contact"][inner], r["p"][inner])


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
