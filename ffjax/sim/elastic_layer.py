"""Contact mechanics of a linear-elastic, incompressible layer (nu = 0.5, shear modulus G, thickness t)
bonded to a rigid base, pressed by a rigid frictionless body, then sheared in stick.

The simulator's normal solve (`ffjax.sim.mechanics.solve_normal` adds large-strain stiffening and the pad's
grid) and, at a finer grid, the yardstick of experiments.diagnostics.layer_check. It solves the exact small-strain
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

Tangential traction q (the same layer; derived from the Stokes-form equations of an incompressible solid
with the base fixed and the surface loaded): along the wavevector (L) and across it (T)
    C_L(k) = (sinh 2kt + 2kt) / (2 G k (cosh 2kt + 2 (kt)^2 + 1)),   C_T(k) = tanh(kt) / (G k),
both t / G for kt << 1 (simple shear of a thin film) and 1/(2 G k), 1/(G k) for kt >> 1 (Cerruti's
half-space at nu = 0.5). The layer also couples the two: a tangential traction raises the surface ahead of
it, w = -i C_N(k) q_L with C_N(k) = (kt)^2 / (G k (cosh 2kt + 2 (kt)^2 + 1)) (upward), which vanishes in
both limits. `solve_stick` finds the traction under a rigid body stuck to the surface over its contact and
displaced sideways (a linear problem, conjugate gradients): its stiffness is set by where the gel is held,
so a body touching through fine asperities (knurl, grooves) at a pitch well under t holds the gel across
its whole face, as a smooth face does. The normal solve ignores the coupling (the body is frictionless
while it presses), and stick is assumed over the whole contact (no partial slip at its edge).
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


def tangential_compliance(k: np.ndarray, thickness: float, shear_mpa: float):
    """(C_L, C_T, C_N) in mm / MPa for angular wavenumbers k (rad/mm): the surface's tangential displacement
    per unit tangential traction along and across the wavevector, and the upward displacement per unit
    traction along it (module docstring). At k = 0: t / G, t / G and 0."""
    k = np.asarray(k, dtype=np.float64)
    x = k * thickness
    cl, ct, cn = (np.zeros_like(k) for _ in range(3))
    zero, thin = x == 0, (x > 0) & (x < 1e-3)
    cl[zero | thin] = ct[zero | thin] = thickness / shear_mpa  # series limits: avoid 0/0 round-off
    cn[thin] = k[thin] * thickness**2 / (2 * shear_mpa)
    mid = (x >= 1e-3) & (x < 20)
    xm, km = x[mid], k[mid]
    den = shear_mpa * km * (np.cosh(2 * xm) + 2 * xm**2 + 1)
    cl[mid] = (np.sinh(2 * xm) + 2 * xm) / (2 * den)
    cn[mid] = xm**2 / den
    thick = x >= 20  # half-space within 1e-17
    cl[thick] = 1.0 / (2 * shear_mpa * k[thick])
    big = x >= 1e-3
    ct[big] = np.tanh(x[big]) / (shear_mpa * k[big])
    return cl, ct, cn


class Layer:
    """The layer's influence operators on an (H, W) grid of spacing dx (mm): u = apply(p) for a pressure,
    (ux, uy, depth) = apply_coupled(qx, qy, p) for tangential traction and pressure together."""

    def __init__(self, shape: tuple[int, int], dx: float, thickness: float, shear_mpa: float):
        ky = 2 * np.pi * np.fft.fftfreq(shape[0], d=dx)
        kx = 2 * np.pi * np.fft.rfftfreq(shape[1], d=dx)
        self.shape, self.dx = tuple(shape), float(dx)
        self.thickness, self.shear_mpa = float(thickness), float(shear_mpa)
        self._ky, self._kx = ky[:, None], kx[None, :]
        self.kernel = compliance(np.hypot(self._ky, self._kx), thickness, shear_mpa)
        self._coupled = None

    def apply(self, p: np.ndarray) -> np.ndarray:
        """Surface displacement (mm, + = into the layer) under the pressure field p (MPa)."""
        return np.fft.irfft2(self.kernel * np.fft.rfft2(p), s=self.shape)

    def _coupled_kernels(self):
        if self._coupled is None:  # built on first use: the normal solve does not need them
            k = np.hypot(self._ky, self._kx)
            cl, ct, cn = tangential_compliance(k, self.thickness, self.shear_mpa)
            safe = np.where(k > 0, k, 1.0)  # k = 0: C_L = C_T, so any unit vector gives the uniform shear
            ex, ey = np.where(k > 0, self._kx / safe, 1.0), np.where(k > 0, self._ky / safe, 0.0)
            # Hermitian: depth (+ into the layer) = +i C_N q_L, and u_L = -i C_N p for a pressure p
            self._coupled = tuple(k.astype(np.complex64 if np.iscomplexobj(k) else np.float32) for k in (
                cl * ex**2 + ct * ey**2, (cl - ct) * ex * ey, cl * ey**2 + ct * ex**2, 1j * cn * ex, 1j * cn * ey,
                self.kernel))
        return self._coupled

    def apply_coupled(self, qx: np.ndarray, qy: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Surface displacement (..., 3, H, W) = (ux, uy, depth) in mm under the tangential traction (qx, qy)
        and the pressure p (MPa), each (..., H, W); depth is + into the layer, as in `apply`."""
        cxx, cxy, cyy, zx, zy, cnn = self._coupled_kernels()
        f = np.fft.rfft2(np.stack([qx, qy, p], -3))
        fx, fy, fp = f[..., 0, :, :], f[..., 1, :, :], f[..., 2, :, :]
        return np.fft.irfft2(np.stack([cxx * fx + cxy * fy - zx * fp, cxy * fx + cyy * fy - zy * fp,
                                       zx * fx + zy * fy + cnn * fp], -3), s=self.shape)


def solve_stick(contact: np.ndarray, layer: Layer, tol: float = 1e-4, max_iter: int = 500) -> dict:
    """A rigid body stuck to the surface over `contact` (bool, the layer's grid) and moved sideways by 1 mm
    along x, then along y, its load unchanged: the tangential tractions that hold the gel there and the
    change of pressure that keeps the gel on the body (the coupling would lift it ahead and drop it behind;
    the body only shifts up or down as a whole). Conjugate gradients on the contact (both directions at
    once), the pressure change kept at zero sum, until the rms displacement error on the contact is below
    tol (mm per mm of displacement).

    Returns K, the 2x2 tangential stiffness (N/mm; F = K s for a displacement s), and per unit displacement
    j the surface's change fields[j] (3, H, W) = (ux, uy, depth) in mm per mm of s over the whole grid, so
    a displacement s gives s_x fields[0] + s_y fields[1]. Raises ValueError for an empty contact.
    """
    if contact.shape != layer.shape:
        raise ValueError(f"contact {contact.shape} does not match the layer grid {layer.shape}")
    if not contact.any():
        raise ValueError("no contact: nothing holds the surface")
    on = contact.astype(np.float32)  # float32 throughout: 1e-4 is far above its round-off, and FFTs run 2x faster
    n_on = float(on.sum())

    def residual_space(v):  # on the contact only; the pressure part with zero mean (its load is fixed)
        v *= on
        v[:, 2] -= on * (v[:, 2].sum((-2, -1), keepdims=True) / n_on)
        return v

    def dot(a, b):  # one inner product per direction
        return np.einsum("jcyx,jcyx->j", a, b, dtype=np.float64)[:, None, None, None]

    target = np.zeros((2, 3) + layer.shape, np.float32)
    target[0, 0], target[1, 1] = on, on
    t = target * (layer.shear_mpa / layer.thickness)  # the thin-film traction: a close start
    r = residual_space(target - layer.apply_coupled(*t.transpose(1, 0, 2, 3)))
    d, rr = r.copy(), dot(r, r)
    stop = tol**2 * n_on
    for _ in range(max_iter):
        if rr.max() <= stop:
            break
        ad = residual_space(layer.apply_coupled(*d.transpose(1, 0, 2, 3)))
        a = (rr / np.maximum(dot(d, ad), 1e-300)).astype(np.float32)
        t += a * d
        r -= a * ad
        rr, rr_old = dot(r, r), rr
        d = r + (rr / np.maximum(rr_old, 1e-300)).astype(np.float32) * d
    fields = layer.apply_coupled(*t.transpose(1, 0, 2, 3))
    K = t[:, :2].sum((-2, -1), dtype=np.float64).T * layer.dx**2  # K[:, j]: the force for a unit displacement along j
    return {"K": K, "fields": [fields[0], fields[1]]}


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
