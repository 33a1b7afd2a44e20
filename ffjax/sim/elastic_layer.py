"""Contact mechanics of a linear-elastic, incompressible layer (nu = 0.5, shear modulus G, thickness t)
bonded to a rigid base, pressed by a rigid frictionless body.

The simulator's normal solve (`ffjax.sim.mechanics.solve_normal` adds large-strain stiffening and the pad's
grid) and, at a finer grid, the yardstick of experiments.layer_check. It solves the exact small-strain
problem on a grid, so it has what independent columns (the simulator's model before issue 13) lack:
pressure concentrated at a flat punch's edges when the contact is small against t (half-space, p ~ 1/sqrt(a^2 - r^2)), a
pressure dome and strong stiffening when it is large against t (the squeezed layer must flow out
sideways, F = 3 pi G delta a^4 / (8 t^3) for a disc), and the free surface around the contact dragged down
and pushed up by the layer's volume. It has no large-strain stiffening (the columns' neo-Hookean law has),
no friction on the contact and an unbounded layer (a real pad ends at its frame).

Surface compliance in Fourier space (displacement into the layer per unit pressure, wavenumber k):
    C(k) = (sinh 2kt - 2kt) / (2 G k (cosh 2kt + 2 (kt)^2 + 1))
which tends to the half-space 1/(2 G k) for kt >> 1 and to the thin-layer (lubrication) k^2 t^3 / (3 G)
for kt << 1. The contact problem (p >= 0, gap >= 0, p * gap = 0, sum p = F) is solved with the
conjugate-gradient method of Polonsky & Keer (Wear 231, 1999) on a periodic grid whose margin around the
body is several thicknesses wide (the layer's response decays over ~t, so the periodic images are negligible).
"""

from __future__ import annotations

import numpy as np

FAR = 1e3  # mm: "no body here" in height maps, as in ffjax.sim.shapes


def compliance(k: np.ndarray, thickness: float, shear_mpa: float) -> np.ndarray:
    """C(k) in mm / MPa for angular wavenumbers k (rad/mm); 0 at k = 0 (an incompressible bonded layer
    does not sink under a uniform pressure)."""
    k = np.asarray(k, dtype=np.float64)
    x = k * thickness
    out = np.zeros_like(k)
    thin = (x > 0) & (x < 1e-3)
    out[thin] = k[thin] ** 2 * thickness**3 / (3.0 * shear_mpa)  # series limit: avoids 0/0 round-off
    mid = (x >= 1e-3) & (x < 20)
    xm, km = x[mid], k[mid]
    out[mid] = (np.sinh(2 * xm) - 2 * xm) / (2 * shear_mpa * km * (np.cosh(2 * xm) + 2 * xm**2 + 1))
    thick = x >= 20  # sinh/cosh -> 1 within 1e-17: half-space
    out[thick] = 1.0 / (2 * shear_mpa * k[thick])
    return out


class Layer:
    """The layer's influence operator on an (H, W) grid of spacing dx (mm): u = apply(p)."""

    def __init__(self, shape: tuple[int, int], dx: float, thickness: float, shear_mpa: float):
        ky = 2 * np.pi * np.fft.fftfreq(shape[0], d=dx)
        kx = 2 * np.pi * np.fft.rfftfreq(shape[1], d=dx)
        self.shape, self.dx = tuple(shape), float(dx)
        self.kernel = compliance(np.hypot(ky[:, None], kx[None, :]), thickness, shear_mpa)

    def apply(self, p: np.ndarray) -> np.ndarray:
        """Surface displacement (mm, + = into the layer) under the pressure field p (MPa)."""
        return np.fft.irfft2(self.kernel * np.fft.rfft2(p), s=self.shape)


def solve_contact(h: np.ndarray, layer: Layer, force_n: float, tol: float = 1e-7, max_iter: int = 2000,
                  p0: np.ndarray | None = None) -> dict:
    """Pressure under a rigid frictionless body with heights h (mm above its lowest point; >= FAR/2 = no
    body) carrying force_n (N). Returns p (MPa), u (surface displacement, mm), delta (approach, mm, from
    the first touch), contact (bool), iterations and the final relative pressure change. p0: a starting
    pressure (e.g. the solution of a nearby problem); uniform over the body if None."""
    if h.shape != layer.shape:
        raise ValueError(f"height map {h.shape} does not match the layer grid {layer.shape}")
    if not force_n > 0:
        raise ValueError(f"force_n must be > 0, got {force_n}")
    cell = layer.dx**2
    h = np.asarray(h, dtype=np.float64) - float(h.min())
    body = h < FAR / 2
    if p0 is not None and (p0 * body).sum() > 0:
        p = np.where(body, p0, 0.0) * (force_n / ((p0 * body).sum() * cell))
    else:
        p = np.where(body, force_n / (body.sum() * cell), 0.0)
    t = np.zeros_like(p)
    g_old, conj, change, it = 1.0, False, np.inf, 0
    while it < max_iter:
        it += 1
        u = layer.apply(p)
        g = h + u
        on = p > 0
        gbar = g[on].mean()
        g = g - gbar
        gg = float(np.sum(g[on] ** 2))
        t = np.where(on, g + (gg / g_old if conj else 0.0) * t, 0.0)
        g_old = max(gg, 1e-300)
        r = layer.apply(t)
        r = r - r[on].mean()
        denom = float(np.sum(r[on] * t[on]))
        tau = float(np.sum(g[on] * t[on])) / denom if denom > 0 else 0.0
        p_prev = p
        p = np.where(on, p - tau * t, 0.0)
        p = np.maximum(p, 0.0)
        overlap = (p == 0) & (g < 0) & body  # the body would pass through the surface here: load it
        conj = not overlap.any()
        if not conj:
            p[overlap] -= tau * g[overlap]
        p *= force_n / (p.sum() * cell)
        change = float(np.abs(p - p_prev).sum() / p.sum())
        if change < tol:
            break
    u = layer.apply(p)
    contact = p > 0
    delta = float(np.mean((h + u)[contact]))
    return {"p": p, "u": u, "delta": delta, "contact": contact, "iterations": it, "change": change}
