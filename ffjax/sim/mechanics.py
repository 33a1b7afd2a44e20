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
- Shear: the body sticks to the gel over its contact and moves sideways by s = K^-1 F_t, where K (2x2) is the
  same layer's tangential stiffness for that contact (`elastic_layer.solve_stick`: G A / (t - d) for a wide
  face, Mindlin's 16 G a / 3 for a small one, and every contact shape between; a face touching through fine
  asperities holds the gel across the whole face). The body holds the gel on the walls of the pit it pressed,
  represented by the plane at the contact's mean depth d (`hold_depth`): checked against a plane-strain
  finite-element model of the pressed layer (experiments.diagnostics.buried_load_check). The solve gives the
  surface's tangential displacement everywhere (the gel around the contact dragged along, decaying over ~t)
  and the rise ahead of the motion and the dip behind it. |F_t| is capped by Coulomb's mu Fz (slip flag); no
  partial slip at the contact edge.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools

import cv2
import numpy as np

from ffjax.sim import batched, elastic_layer

MAX_STRAIN = 0.9  # presses needing a deeper compression than this x thickness are refused (gel bottoms out)
SOLVE_MARGIN_T = 2.0  # layer beyond the pad in the solve, x thickness: its response decays over ~t
NESTED_MARGIN_PX = 2  # room around the contact a lighter press of the same body is solved in (`within`)
# How high above its lowest point a body can touch the gel, x MAX_STRAIN x thickness: the deepest approach the gel
# takes and the free surface's rise around a contact. A press is solved on a window around that part of its body,
# and solved again on the whole grid if its solution presses the gel through the body beyond it (checked).
REACH = 1.3
_EPS = np.linspace(0.0, 0.98, 4096)  # compressive strain table for psi and its inverse
_PSI = ((1.0 - _EPS) ** -2 - (1.0 - _EPS)) / 3.0
_OUTER_TOL = 1e-4  # fixed point on the approach: stop when it moves less than this x thickness
_INNER_TOL = 1e-6  # the reference's contact solve: stop when the pressure changes less than this (relative)
# Below a nanonewton a press is no contact: far under any sensor's resolution, and a subnormal force
# (5e-324 N, found by the property tests) spread over the body underflows the pressure to 0, leaving no
# contact cell for the solve to balance.
FZ_NONE = 1e-9


def stiffen(u, thickness: float):
    """Linear-layer displacement that carries the load of a real compression u (mm): t psi(u / t);
    identity for u <= 0 (the gel rising), as psi'(0) = 1."""
    u = np.asarray(u, dtype=np.float64)
    return np.where(u <= 0, u, thickness * np.interp(u / thickness, _EPS, _PSI, right=np.inf))


def soften(v, thickness: float):
    """Inverse of `stiffen`: the real compression (mm) for a linear-layer displacement v."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0, v, thickness * np.interp(v / thickness, _PSI, _EPS))


# The padded grids' sides: few (each a compiled program), 5-smooth (fast FFTs), so gels of other thicknesses and
# cells mostly land on a grid already compiled for
GRID_SIDES = (32, 40, 48, 64, 80, 96, 120, 128, 160, 192, 240, 256, 320, 384, 480, 512, 640, 768, 960, 1024, 1280,
              1536, 1920, 2048, 2560)


def grid_side(n: int) -> int:
    """The smallest of GRID_SIDES >= n (a side past the last is refused: no sensor's pad comes near it)."""
    for side in GRID_SIDES:
        if side >= n:
            return side
    raise ValueError(f"a solve grid of {n} cells a side is past the largest supported ({GRID_SIDES[-1]})")


@functools.lru_cache(maxsize=64)  # the pretraining corpus cycles through 24 randomized gels
def _layer(shape: tuple[int, int], dx: float, thickness: float, shear_mpa: float) -> elastic_layer.Layer:
    return elastic_layer.Layer(shape, dx, thickness, shear_mpa)


def _padded_layer(size: tuple[int, int], mm_per_px: float, thickness: float, shear_mpa: float):
    """(margin m, Layer) for a pad grid of `size` with SOLVE_MARGIN_T thicknesses of free gel around it
    (a little more, to one of GRID_SIDES); the pad sits at [m:m+H, m:m+W]."""
    H, W = size
    m = int(np.ceil(SOLVE_MARGIN_T * thickness / mm_per_px))
    return m, _layer((grid_side(H + 2 * m), grid_side(W + 2 * m)), float(mm_per_px), float(thickness),
                     float(shear_mpa))


def _windows(masks, m: int, layer, margin: int = 0) -> np.ndarray:
    """`batched.windows` of pad masks (B, H, W) on the padded layer's grid (the pad at offset m)."""
    B, H, W = masks.shape
    full = np.zeros((B,) + layer.shape, bool)
    full[:, m:m + H, m:m + W] = masks
    return batched.windows(full, margin)


@dataclasses.dataclass
class Normal:
    delta: float  # approach (mm) from the first touch: the deepest compression
    surface: np.ndarray  # (H, W) gel surface displacement on the pad grid, mm (+ = into the gel)
    contact: np.ndarray  # (H, W) bool
    pressure: np.ndarray  # (H, W) MPa


def solve_normal(h: np.ndarray, mm_per_px: float, shear_mpa: float, thickness: float, fz: float,
                 reference: bool = False) -> Normal:
    """The layer's response to a rigid frictionless body of heights h (mm over the pad grid; >= FAR/2 = no
    body) pressed until it carries Fz (N). ValueError if the gel would be compressed past MAX_STRAIN.
    The batch of one of `solve_normal_batch`."""
    out = solve_normal_batch(np.asarray(h)[None], mm_per_px, shear_mpa, thickness, [fz], reference)[0]
    if isinstance(out, ValueError):
        raise out
    return out


def solve_normal_batch(hs, mm_per_px: float, shear_mpa: float, thickness: float, fzs,
                       reference: bool = False, within=None) -> list:
    """solve_normal for B presses on one pad grid (hs (B, H, W), fzs (B,)): a Normal per press, or the
    ValueError it raises. The layer solves run batched on the device (`ffjax.sim.batched`); reference=True runs
    the numpy reference (`elastic_layer.solve_contact`, one press at a time), which they agree with.
    within (B, H, W) bool: where each contact is known to lie (the contact of the same body at the same pose pressed
    harder: contacts grow with the load), each solve kept to it and NESTED_MARGIN_PX cells around and run on a
    window (`batched.windows`); None: the whole grid."""
    hs = np.asarray(hs, np.float64)
    B, H, W = hs.shape
    out: list = [None] * B
    m, layer = _padded_layer((H, W), mm_per_px, thickness, shear_mpa)
    todo, hbs = [], []
    for i, (h, fz) in enumerate(zip(hs, fzs)):
        body_pad = h < elastic_layer.FAR / 2
        if fz <= FZ_NONE or not body_pad.any():
            zero = np.zeros((H, W))
            out[i] = Normal(0.0, zero, zero.astype(bool), zero)
            continue
        hb = np.full(layer.shape, elastic_layer.FAR)
        hb[m:m + H, m:m + W] = np.where(body_pad, h - float(h[body_pad].min()), elastic_layer.FAR)
        todo.append(i)
        hbs.append(hb)
    if not todo:
        return out
    fz = np.asarray([fzs[i] for i in todo], np.float64)
    if reference:
        solved = [_reference_normal(hb, f, layer, thickness) for hb, f in zip(hbs, fz)]
        delta, u, p = (np.stack([r[k] for r in solved]) for k in range(3))
    else:
        hb = np.stack(hbs)
        reach = hb <= REACH * MAX_STRAIN * thickness
        wins = batched.windows(reach) if within is None else _windows(np.asarray(within, bool)[todo], m, layer,
                                                                      NESTED_MARGIN_PX)
        solve = functools.partial(batched.normal, layer=layer, thickness=thickness, eps=_EPS, psi=_PSI,
                                  refuse_above=MAX_STRAIN * thickness)
        r = solve(hb, fz, windows=wins)
        again = np.flatnonzero(_beyond(hb, r, reach, thickness) & (wins[:, 4] > 0)) if within is None else []
        if len(again):
            for k, v in solve(hb[again], fz[again]).items():
                r[k][again] = v
        delta, u, p = r["delta"].astype(np.float64), r["u"], r["p"]
    inner = (slice(None), slice(m, m + H), slice(m, m + W))
    hb = np.stack(hbs)
    surface = np.maximum(soften(u[inner], thickness), delta[:, None, None] - hb[inner])  # never inside the body
    for j, i in enumerate(todo):
        if delta[j] > MAX_STRAIN * thickness:
            out[i] = ValueError(
                f"Fz={fzs[i]:.3g} N is beyond what this gel takes for this body and pose: it would compress the "
                f"{thickness} mm gel past {MAX_STRAIN:.0%} of its thickness")
        else:
            out[i] = Normal(float(delta[j]), surface[j], (p[j] > 0)[m:m + H, m:m + W], p[j][m:m + H, m:m + W])
    return out


def _beyond(hb: np.ndarray, r: dict, reach: np.ndarray, thickness: float) -> np.ndarray:
    """(B,) bool: the solved surface (batched.normal's r) passes through the body somewhere outside `reach`, where
    its solve could not put pressure (the contact condition of batched._normal_one, on the whole grid)."""
    body = hb < elastic_layer.FAR / 2
    approach = np.minimum(r["delta"].astype(np.float64), _EPS[-1] * thickness)[:, None, None]
    g = np.where(body, -stiffen(approach - hb, thickness), elastic_layer.FAR) + r["u"]
    on = r["p"] > 0
    level = (g * on).sum((1, 2)) / np.maximum(on.sum((1, 2)), 1)
    return ((g < level[:, None, None]) & body & ~reach).any((1, 2))


@contextlib.contextmanager
def reference_tolerance(inner: float, outer: float):
    """The numpy reference's normal solve run to other tolerances inside the block (the benchmark converges it
    further to tell solver tolerance from disagreement)."""
    global _INNER_TOL, _OUTER_TOL
    before = _INNER_TOL, _OUTER_TOL
    _INNER_TOL, _OUTER_TOL = inner, outer
    try:
        yield
    finally:
        _INNER_TOL, _OUTER_TOL = before


def _reference_normal(hb: np.ndarray, fz: float, layer, thickness: float):
    """(delta, u, p) of the fixed point on the approach with the numpy reference contact solve."""
    body = hb < elastic_layer.FAR / 2
    target, delta, p = hb, None, None
    for _ in range(30):  # fixed point on the approach: the stiffened target depends on it
        r = elastic_layer.solve_contact(target, layer, fz, tol=_INNER_TOL, p0=p)
        p = r["p"]
        on = r["contact"]
        new = float(np.mean(hb[on] + soften(r["u"][on], thickness)))
        done = delta is not None and abs(new - delta) < _OUTER_TOL * thickness
        delta = new
        if done:
            break
        target = np.where(body, -stiffen(np.minimum(delta, _EPS[-1] * thickness) - hb, thickness),
                          elastic_layer.FAR)
    return delta, r["u"], r["p"]


def smooth(x: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian blur; wide kernels run on a downsampled copy (same result to the eye, and much faster)."""
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
    disp_mm: np.ndarray  # (2,) stick displacement of the body (and the gel it holds), mm
    slip: bool
    stiffness: float  # |F_t| / |s| along the applied force, N/mm (0 without shear)
    field: np.ndarray | None  # (H, W, 2) tangential displacement of the gel surface on the pad grid, mm
    bulge: np.ndarray | None  # (H, W) surface displacement it causes, mm (+ = into the gel, - = rising)
    hold_mm: float = 0.0  # depth of the plane the body holds the gel on (`hold_depth`), mm


def shear(ft, fz: float, contact: np.ndarray, mm_per_px: float, shear_mpa: float, thickness: float,
          friction: float, reference: bool = False, depth: float = 0.0) -> Shear:
    """Tangential response to the requested shear ft = (Fx, Fy) with the Coulomb cap mu * Fz, for a body in
    stick over `contact` (bool, the pad grid of spacing mm_per_px: the normal solve's), holding the gel at
    `depth` (mm, `hold_depth`). The batch of one of `shear_batch`."""
    return shear_batch([ft], [fz], np.asarray(contact)[None], mm_per_px, shear_mpa, thickness, friction,
                       reference, [depth])[0]


_NO_SHEAR = 1e-9  # N
HOLD_STEP_MM = 0.05  # the hold depth is rounded to this: the layer's kernels are built once per depth


def hold_depth(normal: Normal, thickness: float) -> float:
    """The depth (mm) of the plane a pressed body holds the gel on in stick: the mean depth of the gel's surface
    over the contact (the pit's walls), to HOLD_STEP_MM, below MAX_STRAIN x thickness; 0 without contact."""
    if not normal.contact.any():
        return 0.0
    d = float(np.mean(normal.surface[normal.contact]))
    return float(np.clip(np.round(d / HOLD_STEP_MM) * HOLD_STEP_MM, 0.0, MAX_STRAIN * thickness))


def shear_batch(fts, fzs, contacts, mm_per_px: float, shear_mpa: float, thickness: float, friction: float,
                reference: bool = False, depths=None) -> list[Shear]:
    """`shear` for B presses on one pad grid (contacts (B, H, W), depths (B,) mm or None for the surface): the
    stick solves of those with a shear and a contact run batched on the device (`ffjax.sim.batched.stick`);
    reference=True runs the numpy reference (`elastic_layer.solve_stick`: unit displacements along x and y,
    combined), which they agree with."""
    depths = np.zeros(len(fts)) if depths is None else np.asarray(depths, np.float64)
    contacts = np.asarray(contacts, bool)
    out: list = [None] * len(contacts)
    todo = []
    for i, (ft, fz) in enumerate(zip(fts, fzs)):
        ft = np.asarray(ft, dtype=np.float64)
        cap = friction * fz
        mag = float(np.hypot(*ft))
        slip = mag > cap + 1e-9
        applied = ft * (cap / mag) if slip else ft
        if mag < _NO_SHEAR or not contacts[i].any():  # below a nN nothing moves a pixel (and float32 is 0)
            out[i] = Shear(applied, np.zeros(2), slip, 0.0, None, None, float(depths[i]))
        else:
            todo.append((i, applied, slip))
    if not todo:
        return out
    fields, s = _stick(contacts[[i for i, _, _ in todo]], np.stack([a for _, a, _ in todo]),
                       depths[[i for i, _, _ in todo]], mm_per_px, shear_mpa, thickness, reference)
    for j, (i, applied, slip) in enumerate(todo):
        out[i] = _shear(applied, s[j], slip, fields[j], float(depths[i]))
    return out


def _shear(force, disp, slip: bool, fields, hold_mm: float) -> Shear:
    """A Shear from the force applied, the body's displacement, the fields (3, H, W) = (ux, uy, depth) and the
    depth the body holds the gel at."""
    return Shear(np.asarray(force, np.float64), np.asarray(disp, np.float64), slip,
                 float(np.hypot(*force) / np.hypot(*disp)), np.stack(fields[:2], -1).astype(np.float32),
                 fields[2].astype(np.float32), hold_mm)


def _stick(contacts, forces, depths, mm_per_px: float, shear_mpa: float, thickness: float, reference: bool):
    """The stick solves of N presses on one pad grid (contacts (N, H, W), each non-empty, forces (N, 2) N, depths
    (N,) mm): fields (N, 3, H, W) = (ux, uy, depth) on the pad, the bodies' displacements s (N, 2) mm."""
    N, H, W = contacts.shape
    m, layer = _padded_layer((H, W), mm_per_px, thickness, shear_mpa)
    held = np.zeros((N,) + layer.shape, bool)
    held[:, m:m + H, m:m + W] = contacts
    if reference:
        fields, s = [], []
        for h, f, d in zip(held, forces, depths):
            r = elastic_layer.solve_stick(h, layer, depth=float(d))
            s.append(np.linalg.solve(r["K"], f))
            fields.append(s[-1][0] * r["fields"][0] + s[-1][1] * r["fields"][1])
        fields, s = np.stack(fields), np.stack(s)
    else:
        r = batched.stick(held, forces, layer, depths, windows=_windows(contacts, m, layer), crop=(m, m, H, W))
        return r["fields"], r["s"].astype(np.float64)
    return fields[:, :, m:m + H, m:m + W], s


def _approach_at_ends(f_mid, d_mid, fz: float, d_end: float, steps: int) -> np.ndarray:
    """The approach at the steps' end forces fz (j / steps)^1.5, j = 0..steps, from the solves at the middle
    forces and at fz: interpolated on log-log axes (exact for any power law delta ~ F^p: a sphere's 2/3, a flat
    face's 1, a wedge's 1/2), 0 at j = 0."""
    f = np.concatenate([f_mid, [fz]])
    d = np.maximum(np.concatenate([d_mid, [d_end]]), 1e-12)
    ends = fz * (np.arange(steps + 1) / steps) ** 1.5
    out = np.zeros(steps + 1)
    out[1:] = np.exp(np.interp(np.log(ends[1:]), np.log(f), np.log(d)))
    if steps > 1:  # below the first middle force: the first segment's power law, not a constant
        p = np.log(d[1] / d[0]) / np.log(f[1] / f[0])
        low = ends[1:] < f[0]
        out[1:][low] = d[0] * (ends[1:][low] / f[0]) ** p
    out[-1] = d_end
    return np.maximum.accumulate(out)


# The oblique press's path, the default of every press and of the config (data.path_steps, data.path_quadrature):
# chosen on bench --only sim's "The oblique path's steps": 2 power-law steps put its shear closer to the path
# converged than the 4 midpoint steps before did, in about half their time; only more steps shrink the depth's path
# error. docs/benchmarks.md has the measured table at today's +-15 deg.
PATH_STEPS = 2
QUADRATURES = ("midpoint", "power")
PATH_QUADRATURE = "power"  # how a step's stiffness stands for it (`oblique_batch`)


def _power_weights(mids, stiff, ends) -> np.ndarray:
    """Per step, the path's stiffness integrated over the step's approach [ends[j], ends[j+1]] over the midpoint
    rule's stiff[j] x its length: stiffness taken as a power law of the approach between the steps' middle
    approaches `mids` (log-log linear; below the first and beyond the last, the nearest segment's law, which
    reaches 0 at no approach). Exact for any power law K ~ delta^q (a sphere on a half-space: q = 1/2, where the
    midpoint rule's first step, growing from a point, is the one it gets most wrong); 1 where it cannot tell (one
    step, middles out of order, a stiffness not positive). A stiffness that falls between two middles is held
    constant there."""
    m, k = np.asarray(mids, float), np.asarray(stiff, float)
    n = len(m)
    if n < 2 or np.any(np.diff(m) <= 0) or np.any(k <= 0):
        return np.ones(n)
    q = np.clip(np.diff(np.log(k)) / np.diff(np.log(m)), 0.0, 3.0)  # a stiffness that falls is held constant

    def integral(x0: float, x1: float) -> float:  # of the piecewise law over [x0, x1]
        total, cuts = 0.0, [-np.inf, *m[1:-1], np.inf]
        for j in range(n - 1):
            a, b = max(x0, cuts[j]), min(x1, cuts[j + 1])
            if b > a:  # K = k[j] (x / m[j])^q[j]
                total += k[j] * (b ** (q[j] + 1) - a ** (q[j] + 1)) / ((q[j] + 1) * m[j] ** q[j])
        return total

    e = np.asarray(ends, float)
    return np.array([integral(e[j], e[j + 1]) / (k[j] * (e[j + 1] - e[j])) for j in range(n)])


def oblique_batch(hs, mm_per_px: float, shear_mpa: float, thickness: float, friction: float, fzs, slopes,
                  steps: int = PATH_STEPS, reference: bool = False,
                  quadrature: str = PATH_QUADRATURE) -> tuple[list, list]:
    """The paper's press for B bodies (hs (B, H, W) heights on the pad grid): the tool moves along its tilted axis
    until the gel carries Fz, so per unit of approach the body also moves sideways by slope = (tan tilt_x,
    tan tilt_y), and every point of gel it touches stays held from its first touch on (stick, nested growing
    contacts: Mindlin-Deresiewicz's monotonic oblique loading, where no partial slip arises). The tangential
    force is the path's, sum_j K(C_j) slope d(delta_j): `steps` increments, each with the contact at its middle
    force and the approach at its ends interpolated in F^(2/3) (exact for a sphere on a half-space, for which
    Ft / Fz = (2/3) tan a). Each increment's stick solve is loaded along the sideways motion and scaled to its
    displacement along it (the body's small motion across it on an anisotropic contact is left free). Capped by
    mu Fz (slip). quadrature: how each increment's stiffness stands for its step, "midpoint" (the contact at the
    middle force) or "power" (`_power_weights`: the stiffness a power law of the approach through the steps'
    middles, exact for a sphere; the same solves). Returns (normals, shears): per press its final Normal (or the
    ValueError it raised) and Shear."""
    if not (isinstance(steps, (int, np.integer)) and steps >= 1):
        raise ValueError(f"steps must be a whole number >= 1, got {steps!r}")
    if quadrature not in QUADRATURES:
        raise ValueError(f"quadrature must be one of {QUADRATURES}, got {quadrature!r}")
    hs = np.asarray(hs, np.float64)
    slopes = np.asarray(slopes, np.float64).reshape(len(hs), 2)
    normals = solve_normal_batch(hs, mm_per_px, shear_mpa, thickness, fzs, reference)
    shears: list = [None] * len(hs)
    todo = []
    for i, n in enumerate(normals):
        if isinstance(n, ValueError):
            continue
        if n.contact.any() and np.hypot(*slopes[i]) > 0:
            todo.append(i)
        else:
            shears[i] = Shear(np.zeros(2), np.zeros(2), False, 0.0, None, None)
    if not todo:
        return normals, shears
    frac = ((np.arange(steps) + 0.5) / steps) ** 1.5  # middle forces: the approach grows ~ F^(2/3)
    by_step, inside = [None] * steps, [normals[i].contact for i in todo]
    for j in reversed(range(steps)):  # heaviest first: each lighter press lies inside the contact of the one before
        by_step[j] = solve_normal_batch(hs[todo], mm_per_px, shear_mpa, thickness, [fzs[i] * frac[j] for i in todo],
                                        reference, np.stack(inside))
        inside = [n.contact if isinstance(n, Normal) and n.contact.any() else c for n, c in zip(by_step[j], inside)]
    mids = [by_step[j][k] for k in range(len(todo)) for j in range(steps)]
    loads, contacts, depths, span, at = [], [], [], {}, {}
    for k, i in enumerate(todo):
        fz, mid = float(fzs[i]), mids[k * steps:(k + 1) * steps]
        approach = np.array([n.delta for n in mid], float)
        ends = _approach_at_ends(fz * frac, approach, fz, normals[i].delta, steps)
        direction = slopes[i] / np.hypot(*slopes[i])
        for j, (n, d_delta) in enumerate(zip(mid, np.diff(ends))):
            if n.contact.any() and d_delta > 0:
                at.setdefault(k, []).append(len(loads))
                loads.append((k, direction, np.hypot(*slopes[i]) * d_delta))
                contacts.append(n.contact)
                depths.append(hold_depth(n, thickness))
                span.setdefault(k, []).append((approach[j], ends[j], ends[j + 1]))
    fields, s = _stick(np.stack(contacts), np.stack([d for _, d, _ in loads]), np.asarray(depths), mm_per_px,
                       shear_mpa, thickness, reference)
    weight = np.ones(len(loads))
    if quadrature == "power":
        along = np.array([float(direction @ disp) for (_, direction, _), disp in zip(loads, s)])
        for k, steps_k in span.items():
            m, lo, hi = (np.array(v) for v in zip(*steps_k))
            if np.all(hi[:-1] == lo[1:]):  # a whole path: no step left out (one without contact or motion)
                weight[at[k]] = _power_weights(m, 1.0 / along[at[k]], np.append(lo, hi[-1]))
    total = {k: [np.zeros(2), np.zeros(2), 0.0] for k in range(len(todo))}
    for (k, direction, move), field, disp, w in zip(loads, fields, s, weight):
        scale = move / float(direction @ disp)  # the unit load's displacement along the motion, to the move
        total[k][0] = total[k][0] + w * scale * direction  # the force is the stiffness's integral; the gel held
        # moves with the body, so the displacements are the move's whatever the quadrature
        total[k][1] = total[k][1] + scale * disp
        total[k][2] = total[k][2] + scale * field
    for k, i in enumerate(todo):
        force, disp, field = total[k]
        cap, mag = friction * float(fzs[i]), float(np.hypot(*force))
        slip = mag > cap + 1e-9
        hold = hold_depth(normals[i], thickness)  # where the final contact holds the gel
        if mag < _NO_SHEAR:
            shears[i] = Shear(np.zeros(2), np.zeros(2), False, 0.0, None, None, hold)
            continue
        if slip:  # the body slides: the traction saturates at mu Fz along the push (full slide, no partial slip)
            force, disp, field = (v * (cap / mag) for v in (force, disp, field))
        shears[i] = _shear(force, disp, slip, field, hold)
    return normals, shears


def shear_bulge(sh: Shear) -> np.ndarray:
    """The surface displacement (mm, + = into the gel) that a shear with a field adds: the gel rising ahead of
    the motion and sinking behind it (a function, so experiments.diagnostics.shear_probe can render without it)."""
    return sh.bulge
