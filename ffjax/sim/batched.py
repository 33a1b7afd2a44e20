"""The gel's two layer solves for a batch of presses at once, as jitted JAX programs on whatever device jax sees.

The same problems as the numpy reference in `ffjax.sim.elastic_layer` (its docstring has the physics), solved
for B presses of one sensor in lock step: `jax.vmap` of fixed-shape `lax.while_loop`s, each press frozen once
it has converged (a convergence mask), its FFTs batched with the others'. float32 throughout.

- `normal(hb, fz, layer, thickness)`: the frictionless normal contact with the layer's large-strain stiffening:
  Polonsky-Keer conjugate gradients whose target follows the approach (the reference runs the fixed point on the
  approach as an outer loop of whole solves, ~3 of them; here it converges inside one, in about half the
  iterations), stopping where the reference's loops both stop.
- `stick(held, force, layer, depths)`: the body stuck to the gel over its contact, holding it on the plane at
  each press's depth, loaded by the tangential force itself (the reference solves for unit displacements along
  x and y and combines them): the traction on the contact with the force's sum and the pressure change with
  zero sum, the held gel displaced uniformly. One right-hand side instead of two, the same solution (linear in
  the force). Each press brings its own kernels (the layer's at its depth).

Windows (`windows`): a solve whose loads are known to lie in a region of the grid (a stick solve's contact; a
lighter press of a body inside the contact the full force gives) runs on a small square window holding the region
at its corner, with the grid's own kernels at every offset between two cells of the region (`_aperiodic`: the
discrete-convolution FFT of Liu, Wang & Liu, Wear 243, 2000), the window at least twice the region's extent so its
images never fold onto the region: the whole grid's iterations to round-off, on a fraction of its cells. The
displacements the solution gives are then applied on the whole grid. Presses are solved in batches of one window
side each (WINDOW_SIDES), so a grid compiles few programs.

Batches are padded to one of BATCHES (copies of the first press, dropped after), so a sensor and grid compile
at most len(BATCHES) programs per solve; larger batches are cut into pieces of max_batch() presses: 32 on a
GPU, 8 on a CPU, where a batch runs until its slowest press converges and batching gains nothing (measured by
`python -m experiments.bench --only sim`). The pieces run one after another from the calling thread: jax 0.11's
CPU FFTs already spread over the cores, and two Python threads each running a program of FFTs on XLA's shared
pool deadlocked there (both pool threads waiting inside an FFT for work only a free pool thread could do). A
dataset's parallelism is processes (`ffjax.sim.dataset`), one pool each.
"""

from __future__ import annotations

import contextlib
import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from ffjax.sim.elastic_layer import FAR, Layer

BATCHES = (1, 8, 32)
MAX_BATCH: int | None = None  # None: max_batch() chooses by device; the benchmark sets it to time each size
_RECORD: list | None = None  # set inside record_solves()
RESTART = 1e-3  # x thickness: an approach that moves more than this in one iteration restarts the CG directions
RUNAWAY = 200  # iterations after which a press beyond the refused approach stops
STIFFEN_AFTER = 0.1  # the linear layer's solve runs until its pressure changes by less than this (relative) before
# the target follows the approach: the approach read off a pressure far from converged (the first iterations' spread
# over the whole body) can exceed the gel's thickness, and a target stiffened there pulls the load onto the body's
# lowest cell, a second, unphysical fixed point (one cell pressed to the glass) the solve then stays in. 0.1: no press
# of ~2,900 knife edges and corners off the reference (docs/simulator.md); 1e-2 costs 25-60% more iterations
_TINY = 1e-30  # guards divisions that are 0 / 0 only for a press already frozen


def on_accelerator() -> bool:
    """Whether jax runs on a GPU/TPU here (the solves then run there)."""
    return jax.default_backend() != "cpu"


def max_batch() -> int:
    """The most presses one call of a solve takes: MAX_BATCH when set (any size; one above BATCHES[-1] compiles
    programs of that size too), else 32 on an accelerator, 8 on a CPU."""
    return MAX_BATCH or (BATCHES[-1] if on_accelerator() else 8)


def _solve_pieces(call, n: int) -> list:
    """[device_get(call(a, b, m)) for each piece (a, b, m) of n presses], in order, from this thread."""
    return [jax.device_get(call(*piece)) for piece in _pieces(n)]


@contextlib.contextmanager
def record_solves():
    """Inside the block, each solve of `normal` and `stick` appends (kind, window side (0: the whole grid), grid
    shape, iterations) for each of its presses to the list this yields (the benchmark's floor reads it)."""
    global _RECORD
    before, _RECORD = _RECORD, []
    try:
        yield _RECORD
    finally:
        _RECORD = before


def _recorded(kind: str, windows, shape, iterations) -> None:
    if _RECORD is not None:
        sides = windows[:, 4] if windows is not None else np.zeros(len(iterations), int)
        _RECORD.extend((kind, int(s), tuple(shape), int(i)) for s, i in zip(sides, iterations))


def _stiffen(u, t, eps, psi):
    """mechanics.stiffen for compressions up to the table's end (the solve clips the approach there): the table
    interpolated directly (its strains are evenly spaced), no search."""
    x = u / t
    pos = jnp.clip(x / (eps[1] - eps[0]), 0.0, len(eps) - 1.0)
    i = jnp.minimum(pos.astype(jnp.int32), len(eps) - 2)
    return jnp.where(x <= 0, u, t * (psi[i] + (pos - i) * (psi[i + 1] - psi[i])))


def _soften(v, t, eps, psi):
    """mechanics.soften, the inverse of psi(e) = ((1 - e)^-2 - (1 - e)) / 3 by Newton's method on y = 1 - e
    (y^3 + 3 x y^2 - 1 = 0), where the reference interpolates the table: the two differ by the table's
    interpolation error (~1e-8 of the thickness)."""
    x = jnp.maximum(v / t, 0.0)
    y = jnp.clip(1.0 - x / (1.0 + x), 0.02, 1.0)  # within a few percent of the root for every x
    for _ in range(4):
        f = y * y * (y + 3 * x) - 1.0
        y = y - f / (y * (3 * y + 6 * x))
    return jnp.where(v <= 0, v, t * jnp.minimum(1.0 - y, eps[-1]))


def _masked_mean(x, on, n_on):
    return jnp.sum(jnp.where(on, x, 0.0)) / n_on


def _normal_one(hb, fz, kernel, eps, psi, cell, thickness, tol, outer_tol, max_iter, refuse_above, stiffening):
    """mechanics' normal solve of one press on the padded grid: (delta, u, p, iterations); u is the linear
    layer's displacement at the solution.

    Polonsky-Keer conjugate gradients (elastic_layer.solve_contact) on a target that follows the approach: once the
    linear layer's solve has settled (STIFFEN_AFTER; the heights as they are until then), each iteration restiffens
    the body's heights at the approach the current pressure gives, so the fixed point on the approach converges
    inside one CG instead of over three solves.
    It stops where both the reference's loops stop: the pressure changes by less than `tol` (relative) and
    the approach by less than `outer_tol` x thickness; and, past RUNAWAY iterations (a converging press needs
    fewer than half of them), a press whose approach is beyond `refuse_above` (mm), which the caller refuses:
    the gel cannot carry that force, and its stiffening would keep the whole batch iterating."""
    shape = hb.shape
    apply = lambda x: jnp.fft.irfft2(kernel * jnp.fft.rfft2(x), s=shape)  # noqa: E731
    body = hb < FAR / 2
    p = jnp.where(body, fz / (jnp.sum(body) * cell), 0.0)

    def cond(c):
        it, p, t, g_old, conj, change, delta, moved = c
        runaway = (it > RUNAWAY) & (delta > refuse_above)
        return (it < max_iter) & ((change >= tol) | (moved >= outer_tol * thickness)) & ~runaway

    def step(c):
        it, p, t, g_old, conj, change, delta_before, moved_before = c
        u = apply(p)
        on = p > 0
        n_on = jnp.sum(on)
        # the linear layer until its solve has settled (STIFFEN_AFTER); moved stays inf until the target follows
        first = jnp.isinf(moved_before) & (change >= STIFFEN_AFTER)
        if stiffening:
            delta = jnp.where(first, 0.0, _masked_mean(hb + _soften(u, thickness, eps, psi), on, n_on))
            target = -_stiffen(jnp.minimum(delta, eps[-1] * thickness) - hb, thickness, eps, psi)
        else:  # the linear layer (elastic_layer.solve_contact): its closed-form checks
            delta, target = _masked_mean(hb + u, on, n_on), hb
        h = jnp.where(body, jnp.where(first, hb, target), FAR)
        h = h - jnp.min(h)
        inside = h < FAR / 2  # where the stiffened target rises past FAR / 2 the body no longer reaches (as the
        p = jnp.where(inside, p, 0.0)  # reference, which re-reads its body from each pass's target)
        on = p > 0
        n_on = jnp.sum(on)
        moved = jnp.where(first, jnp.inf, jnp.abs(delta - delta_before))
        conj = conj & (first | (moved < RESTART * thickness))  # a target that moved a lot starts the directions afresh
        g = h + u
        g = g - _masked_mean(g, on, n_on)
        gg = jnp.sum(jnp.where(on, g * g, 0.0))
        t = jnp.where(on, g + jnp.where(conj, gg / g_old, 0.0) * t, 0.0)
        r = apply(t)
        r = r - _masked_mean(r, on, n_on)
        denom = jnp.sum(jnp.where(on, r * t, 0.0))
        tau = jnp.where(denom > 0, jnp.sum(jnp.where(on, g * t, 0.0)) / jnp.where(denom > 0, denom, 1.0), 0.0)
        p_new = jnp.maximum(jnp.where(on, p - tau * t, 0.0), 0.0)
        overlap = (p_new == 0) & (g < 0) & inside  # the body would pass through the surface here: load it
        p_new = jnp.where(overlap, p_new - tau * g, p_new)
        p_new = p_new * (fz / (jnp.sum(p_new) * cell))
        change = jnp.sum(jnp.abs(p_new - p)) / jnp.sum(p_new)
        return it + 1, p_new, t, jnp.maximum(gg, _TINY), ~jnp.any(overlap), change, delta, moved

    zero = jnp.zeros((), hb.dtype)
    state = (0, p, jnp.zeros_like(p), zero + 1, jnp.asarray(False), zero + jnp.inf, zero, zero + jnp.inf)
    it, p, *_ = lax.while_loop(cond, step, state)
    u = apply(p)
    on = p > 0
    soft = _soften(u, thickness, eps, psi) if stiffening else u
    return _masked_mean(hb + soft, on, jnp.sum(on)), u, p, it


@functools.lru_cache(maxsize=2)
def _normal_program(stiffening: bool):
    """The batch's normal solve; the cell, the thickness and the tolerances are arguments, not constants, so every
    gel on a grid shares one compiled program."""
    def run(hb, fz, kernel, eps, psi, cell, thickness, tol, outer_tol, max_iter, refuse):
        one = lambda h, f: _normal_one(h, f, kernel, eps, psi, cell, thickness, tol, outer_tol,  # noqa: E731
                                       max_iter, refuse, stiffening)
        return jax.vmap(one)(hb, fz)

    return jax.jit(run)


@functools.lru_cache(maxsize=32)
def _kernels(layer: Layer):
    """The layer's normal compliance on the device."""
    return jnp.asarray(layer.kernel, jnp.float32)


def _pieces(n: int):
    """(start, stop, padded size) of the calls a batch of n presses takes. On a CPU a last piece that would be
    mostly padding is solved one press at a time instead (a CPU call costs in proportion to its presses)."""
    top, cpu = max_batch(), not on_accelerator()
    for a in range(0, n, top):
        m = min(top, n - a)
        size = next((b for b in BATCHES if b >= m), top)  # above BATCHES: MAX_BATCH, set by hand
        if cpu and 2 * m <= size:
            yield from ((k, k + 1, 1) for k in range(a, a + m))
        else:
            yield a, a + m, size


def _padded(x: np.ndarray, size: int) -> np.ndarray:
    return x if len(x) == size else np.concatenate([x, np.repeat(x[:1], size - len(x), 0)])


def normal(hb: np.ndarray, fz: np.ndarray, layer: Layer, thickness: float, eps: np.ndarray | None,
           psi: np.ndarray | None, refuse_above: float = np.inf, tol: float = 1e-6, outer_tol: float = 1e-4,
           max_iter: int = 2000, windows: np.ndarray | None = None) -> dict:
    """The normal solve of B presses: hb (B, *layer.shape) heights above each body's lowest point (FAR where
    there is no body), fz (B,) N > 0; eps/psi the stiffening table (None: the linear layer); refuse_above (mm)
    the approach the caller refuses (a press past it stops early); windows (B, 5) (`windows`): each press's body
    kept to its region, the solve run on its window (None: the whole grid). Returns numpy arrays: delta (B,) mm,
    u (B, H, W) the linear layer's displacement on the whole grid, p (B, H, W) MPa, iterations (B,)."""
    hb, fz = np.asarray(hb, np.float32), np.asarray(fz, np.float32)
    solve = functools.partial(_normal_grid, thickness=thickness, eps=eps, psi=psi, refuse_above=refuse_above,
                              tol=tol, outer_tol=outer_tol, max_iter=max_iter)
    if windows is None:
        out = solve(hb, fz, layer, _kernels(layer))
        _recorded("normal", None, layer.shape, out["iterations"])
        return out
    out = {"delta": np.empty(len(hb), np.float32), "u": None, "p": np.zeros_like(hb),
           "iterations": np.empty(len(hb), np.int32)}
    for side, idx in _groups(windows):
        if not side:
            r = solve(hb[idx], fz[idx], layer, _kernels(layer))
            out["p"][idx] = r["p"]
        else:
            r = solve(np.stack([_into_window(hb[i], w, FAR) for i, w in zip(idx, windows[idx])]), fz[idx], layer,
                      _window_kernel(layer, side))
            _place(out["p"], idx, r["p"], windows[idx])
        out["delta"][idx], out["iterations"][idx] = r["delta"], r["iterations"]
    kernel = _kernels(layer)
    out["u"] = np.concatenate(_solve_pieces(lambda a, b, m: _apply(_padded(out["p"][a:b], m), kernel)[: b - a],
                                            len(hb)))
    _recorded("normal", windows, layer.shape, out["iterations"])
    return out


@jax.jit
def _apply(p, kernel):
    """The displacement under each pressure of the batch p (B, H, W), the grid's kernel on its rfft2 grid."""
    return jnp.fft.irfft2(kernel * jnp.fft.rfft2(p), s=p.shape[-2:])


def _normal_grid(hb, fz, layer: Layer, kernel, thickness, eps, psi, refuse_above, tol, outer_tol, max_iter) -> dict:
    """`normal` on the grid of hb with `kernel`: the layer's own (its whole grid) or a window's."""
    run = _normal_program(eps is not None)
    table = tuple(jnp.asarray(np.zeros(2) if t is None else t, jnp.float32) for t in (eps, psi))
    scalars = (*(np.float32(v) for v in (float(layer.dx) ** 2, thickness, tol, outer_tol)), np.int32(max_iter),
               np.float32(refuse_above))
    parts = _solve_pieces(lambda a, b, m: run(_padded(hb[a:b], m), _padded(fz[a:b], m), kernel, *table, *scalars),
                          len(hb))
    return _joined(parts, len(hb), ("delta", "u", "p", "iterations"))


def _joined(parts, n: int, names) -> dict:
    """The pieces' outputs, padding dropped, joined along the batch: {name: (n, ...)}."""
    return {k: np.concatenate([np.asarray(part[i])[: b - a] for part, (a, b, _) in zip(parts, _pieces(n))])
            for i, k in enumerate(names)}


def _coupled_apply(kern, q):
    """(ux, uy, depth) (3, H, W) under the traction and pressure q = (qx, qy, p) (3, H, W), with the kernels of
    `Layer.coupled` (cxx, cxy, cyy, cnn real; the couplings zq, zp imaginary, given by their imaginary parts).
    The products are written on the transforms' real and imaginary parts (faster than complex arithmetic on a
    CPU)."""
    cxx, cxy, cyy, cnn, zqx, zqy, zpx, zpy = kern
    f = jnp.fft.rfft2(q)
    fr, fi = jnp.real(f), jnp.imag(f)
    re = jnp.stack([cxx * fr[0] + cxy * fr[1] - zpx * fi[2], cxy * fr[0] + cyy * fr[1] - zpy * fi[2],
                    cnn * fr[2] - zqx * fi[0] - zqy * fi[1]])
    im = jnp.stack([cxx * fi[0] + cxy * fi[1] + zpx * fr[2], cxy * fi[0] + cyy * fi[1] + zpy * fr[2],
                    cnn * fi[2] + zqx * fr[0] + zqy * fr[1]])
    return jnp.fft.irfft2(lax.complex(re, im), s=q.shape[-2:])


def _stick_traction(held, force, hold, cell, tol, max_iter):
    """The force-controlled stick solve of one press with its kernels on the held plane: the traction and pressure
    change t (3, H, W) on the contact, and the iterations."""
    on = held.astype(jnp.float32)
    n_on = jnp.sum(on)

    def project(v):  # on the contact, zero mean per channel: what the uniform displacements leave
        v = v * on
        return v - on * (jnp.sum(v, (-2, -1), keepdims=True) / n_on)

    t = jnp.stack([on * (force[0] / (n_on * cell)), on * (force[1] / (n_on * cell)), jnp.zeros_like(on)])
    u = _coupled_apply(hold, t)
    s = jnp.sqrt(jnp.sum((jnp.sum(u[:2] * on, (-2, -1)) / n_on) ** 2))  # the size of the displacement: the scale
    r = -project(u)
    rr = jnp.sum(r * r)

    def cond(c):
        it, t, r, d, rr = c
        return (it < max_iter) & (rr > (tol * s) ** 2 * n_on)

    def step(c):
        it, t, r, d, rr = c
        ad = project(_coupled_apply(hold, d))
        a = rr / jnp.maximum(jnp.sum(d * ad), _TINY)
        t, r = t + a * d, r - a * ad
        rr_new = jnp.sum(r * r)
        return it + 1, t, r, r + (rr_new / jnp.maximum(rr, _TINY)) * d, rr_new

    it, t, *_ = lax.while_loop(cond, step, (0, t, r, r, rr))
    return t, it


def _stick_fields(held, t, hold, surface):
    """The displacements the stick traction t gives: fields (3, H, W) = (ux, uy, depth) mm, the held gel's on the
    contact, the surface's elsewhere; and s (2,) mm, the held gel's mean displacement (the body's)."""
    at_hold = _coupled_apply(hold, t)
    on = held.astype(jnp.float32)
    return jnp.where(held, at_hold, _coupled_apply(surface, t)), jnp.sum(at_hold[:2] * on, (-2, -1)) / jnp.sum(on)


# the cell and the tolerance are arguments: every gel on a grid shares the program
_traction_program = jax.jit(jax.vmap(_stick_traction, in_axes=(0, 0, 0, None, None, None)))


@functools.lru_cache(maxsize=32)
def _fields_program(crop: tuple | None):
    """The fields of a batch, cut to crop = (y0, x0, h, w) inside the program (None: the whole grid): a pad is a
    fifth of its grid, so the rest is never copied out."""
    def run(held, t, hold, surface):
        fields, s = _stick_fields(held, t, hold, surface)
        if crop is not None:
            y0, x0, h, w = crop
            fields = fields[:, y0:y0 + h, x0:x0 + w]
        return fields, s

    return jax.jit(jax.vmap(run))


@functools.lru_cache(maxsize=1024)
def _depth_kernel(layer: Layer, depth: float, j: int) -> np.ndarray:
    """(8, H, W // 2 + 1): `layer.coupled(depth)[j]` as one array (stacked once per depth, not once per press)."""
    return np.stack(layer.coupled(depth)[j])


def _depth_kernels(layer: Layer, depths, j: int) -> np.ndarray:
    """(B, 8, H, W // 2 + 1): the coupled kernels `layer.coupled(d)[j]` (0: on the held plane, 1: at the surface)
    of each depth."""
    return np.stack([_depth_kernel(layer, float(d), j) for d in depths])


def _hold_kernels(layer: Layer, side: int, depths) -> np.ndarray:
    """The kernels on the held plane of each depth: on a window of `side` (`_window_coupled`), 0: the whole grid."""
    if not side:
        return _depth_kernels(layer, depths, 0)
    return np.stack([_window_coupled(layer, side, float(d)) for d in depths])


def stick(held: np.ndarray, force: np.ndarray, layer: Layer, depths=None, tol: float = 1e-4,
          max_iter: int = 500, windows: np.ndarray | None = None, crop: tuple | None = None) -> dict:
    """The stick solve of B presses: held (B, *layer.shape) bool, each a non-empty contact; force (B, 2) N the
    tangential load; depths (B,) mm, the plane each body holds the gel on (None: the surface; see
    `Layer.coupled`); windows (B, 5) (`windows` of the contacts): each press's conjugate gradients run on its
    window (None: the whole grid); crop (y0, x0, h, w): the part of the grid the fields are wanted on (None: all).
    Returns numpy arrays: fields (B, 3, h, w) = (ux, uy, depth) mm on the crop, s (B, 2) the body's displacement
    in mm, iterations (B,). The CG stops when the rms displacement error on
    the contact is below tol x |s| (the reference's tolerance per mm of displacement)."""
    held, force = np.asarray(held, bool), np.asarray(force, np.float32)
    depths = np.zeros(len(held)) if depths is None else np.asarray(depths, np.float64)
    groups = [(0, np.arange(len(held)))] if windows is None else _groups(windows)
    solved: list = [None] * len(held)  # each press's traction: (on its window, the window) or (the grid, None)
    iterations = np.empty(len(held), np.int32)
    scalars = (np.float32(float(layer.dx) ** 2), np.float32(tol), np.int32(max_iter))
    for side, idx in groups:
        h = np.stack([_into_window(held[i], w, False) for i, w in zip(idx, windows[idx])]) if side else held[idx]
        f, d = force[idx], depths[idx]
        parts = _solve_pieces(lambda a, b, m: _traction_program(  # noqa: B023
            _padded(h[a:b], m), _padded(f[a:b], m), _hold_kernels(layer, side, _padded(d[a:b], m)),  # noqa: B023
            *scalars), len(idx))
        r = _joined(parts, len(idx), ("t", "iterations"))
        iterations[idx] = r["iterations"]
        for t, i in zip(r["t"], idx):
            solved[i] = (t, windows[i] if side else None)

    def traction(a: int, b: int, m: int) -> np.ndarray:
        """The traction of presses [a, b) on the whole grid, padded to m with the first: built for each call, as
        the batch's whole (N, 3, H, W) would be ~0.25 MB a press (264 MB for a quick shard's 1,000 solves)."""
        out = np.zeros((m, 3) + layer.shape, np.float32)
        for k, i in enumerate([*range(a, b), *[a] * (m - (b - a))]):
            t, w = solved[i]
            if w is None:
                out[k] = t
            else:
                _put(out[k], t, w)
        return out

    fields = _fields_program(None if crop is None else tuple(int(v) for v in crop))
    parts = _solve_pieces(lambda a, b, m: fields(_padded(held[a:b], m), traction(a, b, m),
                                                 _depth_kernels(layer, _padded(depths[a:b], m), 0),
                                                 _depth_kernels(layer, _padded(depths[a:b], m), 1)),
                          len(held))
    _recorded("stick", windows, layer.shape, iterations)
    return {**_joined(parts, len(held), ("fields", "s")), "iterations": iterations}


WINDOW_SIDES = (32, 48, 64, 80, 96, 120)  # sides of the windowed solves' grids (5-smooth: fast FFTs); few: few programs


def windows(masks: np.ndarray, margin: int = 0) -> np.ndarray:
    """(B, 5) = (y0, x0, h, w, side): for each mask (B, H, W), each non-empty, its region (the bounding box grown by
    `margin` cells on every side, inside the grid) and the side of the square window its solve runs on: the
    smallest of WINDOW_SIDES at least twice the region's extent less one, else 0 (the whole grid).

    A window solve is the whole grid's solve restricted to the region: every load lives there, and the window's
    kernels (`_aperiodic`) are the layer's, periodic images and all, at every offset between two cells of the
    region, the window wide enough that its own images never fold onto the region. So it agrees with the whole
    grid's to round-off, at a fraction of the FFTs."""
    masks = np.asarray(masks, bool)
    _, H, W = masks.shape
    out = np.zeros((len(masks), 5), np.int64)
    for i, m in enumerate(masks):
        ys, xs = np.nonzero(m.any(1))[0], np.nonzero(m.any(0))[0]
        y0, x0 = max(ys[0] - margin, 0), max(xs[0] - margin, 0)
        h, w = min(ys[-1] + margin + 1, H) - y0, min(xs[-1] + margin + 1, W) - x0
        side = next((s for s in WINDOW_SIDES if s >= 2 * max(h, w) - 1 and s < min(H, W)), 0)
        out[i] = y0, x0, h, w, side
    return out


def _region(window) -> tuple[slice, slice]:
    y0, x0, h, w, _ = (int(v) for v in window)
    return slice(y0, y0 + h), slice(x0, x0 + w)


def _into_window(x: np.ndarray, window, fill) -> np.ndarray:
    """The region of the grid x at the corner of a window's grid, `fill` elsewhere."""
    side = int(window[4])
    out = np.full((side, side), fill, x.dtype)
    out[: window[2], : window[3]] = x[_region(window)]
    return out


def _put(grid: np.ndarray, solution: np.ndarray, window) -> None:
    """A window's solution (..., side, side) into its region of the grid (whose other cells stay as they are)."""
    grid[(...,) + _region(window)] = solution[..., : window[2], : window[3]]


def _place(grids: np.ndarray, idx, solutions: np.ndarray, windows) -> None:
    """Each window's solution into its region of grids[i] (`_put`; 0 elsewhere where a solve's loads cannot lie)."""
    for i, x, w in zip(idx, solutions, windows):
        _put(grids[i], x, w)


def _groups(windows: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """The presses of each window side (0: the whole grid): [(side, indices)], one batch of solves each."""
    sides = windows[:, 4]
    return [(int(s), np.flatnonzero(sides == s)) for s in np.unique(sides)]


def _aperiodic(kernel: np.ndarray, shape: tuple[int, int], side: int, odd: bool) -> np.ndarray:
    """A kernel of the (H, W) grid (on its rfft2 grid, real; odd: the imaginary part of an imaginary one) on a
    side x side window: its real-space values at the offsets below side / 2, the rest 0, transformed back."""
    g = np.fft.irfft2(kernel.astype(np.float64) * (1j if odd else 1.0), s=shape)
    o = np.arange(side)
    o = np.where(o <= side // 2, o, o - side)
    keep = (np.abs(o) < side / 2).astype(np.float64)
    f = np.fft.rfft2(g[np.ix_(o % shape[0], o % shape[1])] * keep[:, None] * keep[None, :])
    return (f.imag if odd else f.real).astype(np.float32)


@functools.lru_cache(maxsize=16)
def _window_kernel(layer: Layer, side: int):
    """The layer's normal compliance on a window of `side` (`_aperiodic`), on the device."""
    return jnp.asarray(_aperiodic(layer.kernel, layer.shape, side, False))


@functools.lru_cache(maxsize=1024)
def _window_coupled(layer: Layer, side: int, depth: float) -> np.ndarray:
    """(8, side, side // 2 + 1): the coupled kernels on the held plane at `depth` (`Layer.coupled(depth)[0]`) on a
    window of `side`: the four direct ones even, the four couplings odd."""
    return np.stack([_aperiodic(k, layer.shape, side, j >= 4) for j, k in enumerate(layer.coupled(depth)[0])])
