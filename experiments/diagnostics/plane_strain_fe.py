"""An independent reference for the gel's stick solve: a plane-strain finite-element model of the layer.

The layer (thickness t, shear modulus G, nearly incompressible, nu = 0.499) is bonded to the glass at its base
and held at its far sides; a rigid cylinder presses it without friction (contact found by an active set on the
surface nodes), then sticks to the gel it touches and moves sideways, its load unchanged. The sideways step is
solved on the pressed mesh (the nodes moved by the press), so the body holds the gel on the walls of its pit
at their true depth and slope: what `elastic_layer.solve_stick(..., depth=d)` represents by one plane at the
contact's mean depth. Both are small-strain increments (no pre-stress stiffening). Q1 elements with selective
reduced integration (the volumetric part at one point, so the nearly incompressible layer does not lock).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import spsolve

NU = 0.499


@dataclasses.dataclass
class Mesh:
    x: np.ndarray  # (nx + 1,) node columns, mm (symmetric about 0)
    z: np.ndarray  # (nz + 1,) node rows, mm below the surface (0 .. t)
    nodes: np.ndarray  # (N, 2) positions (x, z), z down

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.z), len(self.x)

    def node(self, j, i):
        return np.asarray(j) * len(self.x) + np.asarray(i)


def mesh(thickness: float, half_width: float, fine_half: float, fine_dx: float, nz: int) -> Mesh:
    """Columns every fine_dx within |x| <= fine_half, then growing by 8% a step out to half_width; rows finer
    towards the surface (z ~ s^1.5)."""
    right = list(np.arange(0.0, fine_half + 1e-9, fine_dx))
    step = fine_dx
    while right[-1] < half_width:
        step *= 1.08
        right.append(min(right[-1] + step, half_width))
    right = np.asarray(right)
    x = np.concatenate([-right[:0:-1], right])
    z = thickness * np.linspace(0.0, 1.0, nz + 1) ** 1.5
    X, Z = np.meshgrid(x, z)
    return Mesh(x, z, np.stack([X.ravel(), Z.ravel()], -1))


def _elements(m: Mesh) -> np.ndarray:
    nzr, nxr = m.shape
    j, i = np.meshgrid(np.arange(nzr - 1), np.arange(nxr - 1), indexing="ij")
    j, i = j.ravel(), i.ravel()
    return np.stack([m.node(j, i), m.node(j, i + 1), m.node(j + 1, i + 1), m.node(j + 1, i)], -1)


def stiffness(m: Mesh, nodes: np.ndarray, shear_mpa: float) -> sparse.csr_matrix:
    """The global stiffness (2N x 2N, dofs (ux, uz) per node) on node positions `nodes`."""
    elems = _elements(m)
    lam = 2 * shear_mpa * NU / (1 - 2 * NU)
    xy = nodes[elems]  # (E, 4, 2)
    g = 1 / np.sqrt(3)
    gauss = [(-g, -g), (g, -g), (g, g), (-g, g)]
    ke = np.zeros((len(elems), 8, 8))
    shear = shear_mpa * np.diag([2.0, 2.0, 1.0])
    vol = lam * np.outer([1, 1, 0], [1, 1, 0])
    for points, D in ((gauss, shear), ([(0.0, 0.0)], vol)):
        w = 4.0 / len(points)
        for xi, eta in points:
            dn = 0.25 * np.array([[-(1 - eta), (1 - eta), (1 + eta), -(1 + eta)],
                                  [-(1 - xi), -(1 + xi), (1 + xi), (1 - xi)]])  # d/dxi, d/deta
            jac = np.einsum("ak,ekb->eab", dn, xy)  # (E, 2, 2)
            det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
            inv = np.stack([np.stack([jac[:, 1, 1], -jac[:, 0, 1]], -1),
                            np.stack([-jac[:, 1, 0], jac[:, 0, 0]], -1)], -2) / det[:, None, None]
            dxy = np.einsum("eab,bk->eak", inv, dn)  # (E, 2, 4): d/dx, d/dz
            B = np.zeros((len(elems), 3, 8))
            B[:, 0, 0::2], B[:, 1, 1::2] = dxy[:, 0], dxy[:, 1]
            B[:, 2, 0::2], B[:, 2, 1::2] = dxy[:, 1], dxy[:, 0]
            ke += np.einsum("eai,ab,ebj->eij", B, D, B) * (det * w)[:, None, None]
    dofs = np.stack([2 * elems, 2 * elems + 1], -1).reshape(len(elems), 8)
    rows = np.repeat(dofs, 8, 1).ravel()
    cols = np.tile(dofs, (1, 8)).ravel()
    n = 2 * len(nodes)
    return sparse.coo_matrix((ke.ravel(), (rows, cols)), shape=(n, n)).tocsr()


def _solve(K, fixed: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Displacements with `fixed` dofs prescribed to `values` (no other loads) and the reactions."""
    n = K.shape[0]
    u = np.zeros(n)
    u[fixed] = values
    free = np.setdiff1d(np.arange(n), fixed)
    u[free] = spsolve(K[free][:, free].tocsc(), -K[free][:, fixed] @ values)
    return u, K @ u


def _clamped(m: Mesh) -> np.ndarray:
    """The base and the far sides, both dofs."""
    nzr, nxr = m.shape
    base = m.node(nzr - 1, np.arange(nxr))
    sides = m.node(np.arange(nzr), 0), m.node(np.arange(nzr), nxr - 1)
    held = np.unique(np.concatenate([base, *sides]))
    return np.sort(np.concatenate([2 * held, 2 * held + 1]))


def press(m: Mesh, shear_mpa: float, heights, delta: float) -> dict:
    """A rigid frictionless body of heights h(x) (mm above the surface, a function) pressed delta into the layer:
    {"u": (N, 2) displacements, "contact": surface node indices, "force": N per mm of length}."""
    K = stiffness(m, m.nodes, shear_mpa)
    clamp = _clamped(m)
    top = m.node(0, np.arange(len(m.x)))
    target = delta - heights(m.x)  # the body's bottom, as depth below the surface
    contact = np.flatnonzero(target > 0)
    for _ in range(100):
        fixed = np.concatenate([clamp, 2 * top[contact] + 1])
        u, reaction = _solve(K, fixed, np.concatenate([np.zeros(len(clamp)), target[contact]]))
        uz = u[2 * top + 1]
        push = reaction[2 * top[contact] + 1]  # > 0: the body pushes the gel down
        keep = contact[push > 0]
        add = np.flatnonzero((uz < target - 1e-9) & ~np.isin(np.arange(len(top)), contact))  # gel above the body
        new = np.union1d(keep, add)
        if np.array_equal(new, contact):
            break
        contact = new
    force = float(reaction[2 * top[contact] + 1].sum())
    return {"u": u.reshape(-1, 2), "contact": contact, "force": force}


def stick(m: Mesh, shear_mpa: float, pressed: dict, deformed: bool = True) -> dict:
    """The pressed body stuck to the gel it touches and moved sideways by 1 mm, its normal load unchanged (it
    may rise or sink as a whole): solved on the pressed mesh (deformed=True) or on the flat one. Returns the
    tangential force per mm of length per mm of displacement and the surface: x (mm, where the surface nodes
    are), w (mm, + into the layer, per mm of displacement), contact mask."""
    nodes = m.nodes + pressed["u"] if deformed else m.nodes
    K = stiffness(m, nodes, shear_mpa)
    clamp = _clamped(m)
    top = m.node(0, np.arange(len(m.x)))
    held = top[pressed["contact"]]
    fixed = np.concatenate([clamp, 2 * held, 2 * held + 1])
    zeros = np.zeros(len(clamp))
    slide, rz_slide = _solve(K, fixed, np.concatenate([zeros, np.ones(len(held)), np.zeros(len(held))]))
    lift, rz_lift = _solve(K, fixed, np.concatenate([zeros, np.zeros(len(held)), np.ones(len(held))]))
    a = -rz_slide[2 * held + 1].sum() / rz_lift[2 * held + 1].sum()  # the body's vertical move: load unchanged
    u = slide + a * lift
    reaction = rz_slide + a * rz_lift
    on = np.zeros(len(top), bool)
    on[pressed["contact"]] = True
    return {"force": float(reaction[2 * held].sum()), "x": nodes[top, 0], "w": u[2 * top + 1], "contact": on}
