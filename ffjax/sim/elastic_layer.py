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

A body in stick holds the gel on the walls of the pit it has pressed, not on the flat reference surface: the
tangential load acts at depth. `buried_response` gives the layer's response to loads on a plane at depth d
(the layer cut there: displacement continuous, traction jumping by the load), at that depth and at the
surface, solved per wavenumber from the same Stokes-form equations (stream function (A + B z) e^{kz} +
(C + D z) e^{-kz} in each part, written with exponentials that decay away from each part's faces, so the
8 x 8 system stays well conditioned at any kt). At d = 0 it is C, C_L, C_T and C_N above; a buried tangential
load lifts the surface ahead of it far more than a surface one does (Mindlin's buried force against Cerruti's).
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


def _stream_basis(s: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The four stream functions of one part of the layer (k = 1), e^-s, s e^-s, e^-r, r e^-r with s the depth
    below the part's top and r the height above its bottom, as the state (u_L, u_z, sigma_Lz, sigma_zz)
    they give (G = 1; u_L = psi', u_z = -i psi): (..., 4 functions, 4 state entries)."""
    es, er = np.exp(-s), np.exp(-r)
    derivs = np.stack([  # psi, psi', psi'', psi''' (z down)
        np.stack([es, -es, es, -es], -1),
        np.stack([s * es, (1 - s) * es, (s - 2) * es, (3 - s) * es], -1),
        np.stack([er, er, er, er], -1),
        np.stack([r * er, (r - 1) * er, (r - 2) * er, (r - 3) * er], -1)], -2)
    psi, d1, d2, d3 = (derivs[..., j] for j in range(4))
    return np.stack([d1 + 0j, -1j * psi, d2 + psi + 0j, 1j * (d3 - 3 * d1)], -1)


def _faces(state: np.ndarray, rows: slice) -> np.ndarray:
    return state[:, :, rows].transpose(0, 2, 1)  # (n, state rows, functions)


def _buried_unit(kt: np.ndarray, kd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """buried_response in units k = G = 1 for 1-D arrays kt > 0, 0 <= kd < kt."""
    n = kt.size
    upper, lower, zero = kd, kt - kd, np.zeros(n)
    top_a, bottom_a = _stream_basis(zero, upper), _stream_basis(upper, zero)
    top_b, bottom_b = _stream_basis(zero, lower), _stream_basis(lower, zero)
    surface = kd < 1e-9  # the load on the surface itself: no upper part
    # in-plane (L, z): coefficients of the upper part (4) and the lower part (4)
    m = np.zeros((n, 8, 8), complex)
    m[:, 0:2, 0:4] = _faces(top_a, slice(2, 4))  # free surface
    m[:, 2:4, 0:4], m[:, 2:4, 4:8] = _faces(bottom_a, slice(0, 2)), -_faces(top_b, slice(0, 2))  # continuous
    m[:, 4:6, 0:4], m[:, 4:6, 4:8] = -_faces(bottom_a, slice(2, 4)), _faces(top_b, slice(2, 4))  # the load
    m[:, 6:8, 4:8] = _faces(bottom_b, slice(0, 2))  # bonded to the glass
    m[surface, :6] = 0
    m[surface, 0:4, 0:4] = np.eye(4)
    m[surface, 4:6, 4:8] = _faces(top_b[surface], slice(2, 4))
    rhs = np.zeros((n, 8, 2), complex)
    rhs[:, 4, 0] = rhs[:, 5, 1] = -1.0  # sigma below - sigma above = -load
    c = np.linalg.solve(m, rhs)
    at_depth = np.einsum("nfs,nfl->nsl", top_b[:, :, 0:2], c[:, 4:8])
    at_surface = np.where(surface[:, None, None], at_depth,
                          np.einsum("nfs,nfl->nsl", top_a[:, :, 0:2], c[:, 0:4]))
    # across the wavevector (T): u'' = u, sigma_Tz = u'; u = a e^-s + b e^-r in each part
    ea, eb, one = np.exp(-upper), np.exp(-lower), np.ones(n)
    t = np.zeros((n, 4, 4))
    t[:, 0, 0], t[:, 0, 1] = -1.0, ea
    t[:, 1] = np.stack([ea, one, -one, -eb], -1)
    t[:, 2] = np.stack([ea, -one, -one, eb], -1)
    t[:, 3, 2], t[:, 3, 3] = eb, 1.0
    t[surface, :3, :2] = 0
    t[surface, 0, 0] = t[surface, 1, 1] = 1.0
    rt = np.zeros((n, 4, 1))
    rt[:, 2] = -1.0
    ct = np.linalg.solve(t, rt)[..., 0]
    across_depth = ct[:, 2] + ct[:, 3] * eb
    across_surface = np.where(surface, across_depth, ct[:, 0] + ct[:, 1] * ea)

    def full(plane, across):
        out = np.zeros((n, 3, 3), complex)
        out[:, 0, 0], out[:, 0, 2], out[:, 2, 0], out[:, 2, 2] = (
            plane[:, 0, 0], plane[:, 0, 1], plane[:, 1, 0], plane[:, 1, 1])
        out[:, 1, 1] = across
        return out

    return full(at_depth, across_depth), full(at_surface, across_surface)


def buried_response(k: np.ndarray, thickness: float, shear_mpa: float, depth: float) -> tuple[np.ndarray, np.ndarray]:
    """The layer's response to loads on the plane at `depth` (mm, 0 <= depth < thickness): (at_depth,
    at_surface), each (..., 3, 3) complex in mm / MPa mapping the load (f_L, f_T, p) (along the wavevector,
    across it, and pressing into the layer) to the displacement (u_L, u_T, u_z) (u_z + into the layer) there and
    on the surface. At depth 0 both are the surface compliances (C_L, C_T, C on the diagonal, +-i C_N coupling);
    at k = 0 a uniform tangential load shears the part below the plane, (t - d) / G, and carries the part above."""
    if not 0.0 <= depth < thickness:
        raise ValueError(f"depth must be in [0, thickness = {thickness}) mm, got {depth!r}")
    k = np.asarray(k, dtype=np.float64)
    flat = k.ravel()
    at_depth, at_surface = (np.zeros((flat.size, 3, 3), complex) for _ in range(2))
    small = flat * thickness < 1e-3  # the series limit: the system degenerates as kt -> 0
    for out in (at_depth, at_surface):
        out[small, 0, 0] = out[small, 1, 1] = (thickness - depth) / shear_mpa
    big = ~small
    if big.any():
        kt = flat[big] * thickness
        d, s = _buried_unit(kt, np.minimum(flat[big] * depth, kt))
        scale = 1.0 / (shear_mpa * flat[big])[:, None, None]
        at_depth[big], at_surface[big] = d * scale, s * scale
    return at_depth.reshape(k.shape + (3, 3)), at_surface.reshape(k.shape + (3, 3))


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
        self._coupled: dict = {}  # depth -> kernels, built on first use: the normal solve does not need them

    def apply(self, p: np.ndarray) -> np.ndarray:
        """Surface displacement (mm, + = into the layer) under the pressure field p (MPa)."""
        return np.fft.irfft2(self.kernel * np.fft.rfft2(p), s=self.shape)

    def coupled(self, depth: float = 0.0) -> tuple[tuple, tuple]:
        """(hold, surface): the coupled kernels for tangential traction and pressure on the plane at `depth` (mm),
        giving the displacement on that plane (where a body in stick holds the gel) and on the surface. Each is
        (cxx, cxy, cyy, cnn, zq_x, zq_y, zp_x, zp_y), float32 on the rfft2 grid: the couplings are imaginary and
        given by their imaginary parts, zq the depth under a traction, zp the tangential displacement under a
        pressure. At depth 0 the two are the same (the closed forms)."""
        key = round(float(depth), 9)
        if key not in self._coupled:
            k = np.hypot(self._ky, self._kx)
            safe = np.where(k > 0, k, 1.0)  # k = 0: C_L = C_T, so any unit vector gives the uniform shear
            ex, ey = np.where(k > 0, self._kx / safe, 1.0), np.where(k > 0, self._ky / safe, 0.0)
            if key == 0.0:
                cl, ct, cn = tangential_compliance(k, self.thickness, self.shear_mpa)
                # Hermitian: depth (+ into the layer) = +i C_N q_L, and u_L = -i C_N p for a pressure p
                parts = [(cl, ct, self.kernel, cn, -cn)] * 2
            else:
                uniq, where = np.unique(k, return_inverse=True)
                parts = [(r[..., 0, 0].real, r[..., 1, 1].real, r[..., 2, 2].real, r[..., 2, 0].imag,
                          r[..., 0, 2].imag) for r in (x[where.reshape(k.shape)] for x in
                                                       buried_response(uniq, self.thickness, self.shear_mpa, key))]
            self._coupled[key] = tuple(tuple(np.asarray(a, np.float32) for a in (
                ll * ex**2 + tt * ey**2, (ll - tt) * ex * ey, ll * ey**2 + tt * ex**2, zz, zq * ex, zq * ey,
                zp * ex, zp * ey)) for ll, tt, zz, zq, zp in parts)
        return self._coupled[key]

    def apply_coupled(self, qx: np.ndarray, qy: np.ndarray, p: np.ndarray, kernels: tuple | None = None) -> np.ndarray:
        """Displacement (..., 3, H, W) = (ux, uy, depth) in mm under the tangential traction (qx, qy) and the
        pressure p (MPa), each (..., H, W); depth is + into the layer, as in `apply`. kernels: one of `coupled`'s
        (default: loads and displacement on the surface)."""
        cxx, cxy, cyy, cnn, zqx, zqy, zpx, zpy = kernels or self.coupled()[0]
        f = np.fft.rfft2(np.stack([qx, qy, p], -3))
        fx, fy, fp = f[..., 0, :, :], f[..., 1, :, :], f[..., 2, :, :]
        return np.fft.irfft2(np.stack([cxx * fx + cxy * fy + 1j * zpx * fp, cxy * fx + cyy * fy + 1j * zpy * fp,
                                       1j * zqx * fx + 1j * zqy * fy + cnn * fp], -3), s=self.shape)


def solve_stick(contact: np.ndarray, layer: Layer, tol: float = 1e-4, max_iter: int = 500,
                depth: float = 0.0) -> dict:
    """A rigid body stuck to the gel over `contact` (bool, the layer's grid), holding it on the plane at `depth`
    (mm: where the pit it pressed puts its walls; 0: the flat surface), and moved sideways by 1 mm
    along x, then along y, its load unchanged: the tangential tractions that hold the gel there and the
    change of pressure that keeps the gel on the body (the coupling would lift it ahead and drop it behind;
    the body only shifts up or down as a whole). Conjugate gradients on the contact (both directions at
    once), the pressure change kept at zero sum, until the rms displacement error on the contact is below
    tol (mm per mm of displacement).

    Returns K, the 2x2 tangential stiffness (N/mm; F = K s for a displacement s), and per unit displacement
    j the surface's change fields[j] (3, H, W) = (ux, uy, depth) in mm per mm of s over the whole grid, so
    a displacement s gives s_x fields[0] + s_y fields[1]: on the contact the held gel's, elsewhere the surface's.
    Raises ValueError for an empty contact.
    """
    if contact.shape != layer.shape:
        raise ValueError(f"contact {contact.shape} does not match the layer grid {layer.shape}")
    if not contact.any():
        raise ValueError("no contact: nothing holds the surface")
    on = contact.astype(np.float32)  # float32 throughout: 1e-4 is far above its round-off, and FFTs run faster
    n_on = float(on.sum())
    hold, surface = layer.coupled(depth)

    def residual_space(v):  # on the contact only; the pressure part with zero mean (its load is fixed)
        v *= on
        v[:, 2] -= on * (v[:, 2].sum((-2, -1), keepdims=True) / n_on)
        return v

    def dot(a, b):  # one inner product per direction
        return np.einsum("jcyx,jcyx->j", a, b, dtype=np.float64)[:, None, None, None]

    target = np.zeros((2, 3) + layer.shape, np.float32)
    target[0, 0], target[1, 1] = on, on
    t = target * (layer.shear_mpa / (layer.thickness - depth))  # the thin-film traction: a close start
    r = residual_space(target - layer.apply_coupled(*t.transpose(1, 0, 2, 3), hold))
    d, rr = r.copy(), dot(r, r)
    stop = tol**2 * n_on
    for _ in range(max_iter):
        if rr.max() <= stop:
            break
        ad = residual_space(layer.apply_coupled(*d.transpose(1, 0, 2, 3), hold))
        a = (rr / np.maximum(dot(d, ad), 1e-300)).astype(np.float32)
        t += a * d
        r -= a * ad
        rr, rr_old = dot(r, r), rr
        d = r + (rr / np.maximum(rr_old, 1e-300)).astype(np.float32) * d
    loads = t.transpose(1, 0, 2, 3)
    fields = np.where(contact, layer.apply_coupled(*loads, hold), layer.apply_coupled(*loads, surface))
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
