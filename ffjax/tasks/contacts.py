"""Contact patches of the downstream objects as height maps (mm) for `sim.Shape.from_heightmap`.

Axes are the sensor's: x = image columns (horizontal in the world for both tasks), y = image rows
(pointing down, along gravity), the gel normal is the pushing / squeezing direction. Each map is the
body's surface seen from the gel: h = 0 touches first, larger h is further away.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from ffjax import sim

MM_PER_PX = 0.05
EXTENT_MM = 16.0  # half-width: the 20.3 x 15.2 mm pad plus pose offsets
FAR = np.inf  # "no body here" (Shape.from_heightmap maps non-finite values to its FAR)


def _grid():
    n = int(round(EXTENT_MM / MM_PER_PX))
    c = np.arange(-n, n + 1) * MM_PER_PX
    return np.meshgrid(c, c)


def _noise(shape, sigma_px, seed):
    """Smooth unit-variance noise (sigma in map pixels, (sx, sy) or one value)."""
    sx, sy = sigma_px if isinstance(sigma_px, tuple) else (sigma_px, sigma_px)
    n = cv2.GaussianBlur(
        np.random.default_rng(seed).standard_normal(shape).astype(np.float32), (0, 0), sx, sigmaY=sy
    )
    return n / (n.std() + 1e-9)


def _circle(u, R):
    """Sagitta of a circle of radius R: how far its surface recedes at distance u from the touch line."""
    return np.where(np.abs(u) < R, R - np.sqrt(np.maximum(R * R - u * u, 0)), FAR)


# ------------------------------------------------------------------------- weighing by pushing
def flat_face(pitch_deg: float = 1.5, edge_y_mm: float = -6.0, edge_r_mm: float = 1.0):
    """Side face of a 1 kg steel block weight. A flat face wider than the pad would load the whole pad
    evenly (no image gradient to read); a real mount is never exactly parallel: the sensor leans by
    `pitch_deg`, so contact starts at the block's top edge (rounded chamfer at y = edge_y_mm, above
    it nothing) and spreads down the face as the push force grows. Fine milling marks as texture."""
    X, Y = _grid()
    below = Y - edge_y_mm  # distance below the top edge
    chamfer = np.where(
        below < edge_r_mm, edge_r_mm - np.sqrt(np.maximum(edge_r_mm**2 - (edge_r_mm - below) ** 2, 0)), 0.0
    )
    h = chamfer + np.tan(np.radians(pitch_deg)) * np.maximum(below, 0) + 0.004 * np.sin(2 * np.pi * X / 0.5)
    return np.where(below > 0, h, FAR)


def cylinder_wall(radius_mm: float = 30.0, line_pitch_mm: float = 1.8):
    """Side of an upright plastic graduated cylinder (axis vertical = y): curves away along x, with
    printed graduation lines (raised ink, 15 um) every `line_pitch_mm` on the left half."""
    X, Y = _grid()
    lines = 0.015 * (np.abs(((Y / line_pitch_mm) + 0.5) % 1 - 0.5) * line_pitch_mm < 0.12) * (X < 1.0)
    return _circle(X, radius_mm) - lines  # ink stands proud of the wall: it touches first


def bottle_wall(radius_mm: float = 36.0, barrel_mm: float = 400.0):
    """Side of a glass bottle: 72 mm body, a slight barrel along its axis (y), smooth glass with a
    mould seam (a 40 um ridge) running vertically 3 mm off the touch line and faint waviness."""
    X, Y = _grid()
    seam = 0.04 * np.exp(-((X - 3.0) ** 2) / (2 * 0.15**2))
    return _circle(X, radius_mm) + Y**2 / (2 * barrel_mm) - seam + 0.003 * _noise(X.shape, 40, 7)


# ------------------------------------------------------------------------- grasping
def cup_rim(
    rim_radius_mm: float = 37.5,
    bead_radius_mm: float = 1.25,
    wall_recess_mm: float = 0.9,
    taper_deg: float = 6.0,
):
    """Rolled rim of a plastic cup squeezed from the side: the bead (a tube of radius
    `bead_radius_mm`) runs along x and curves away with the rim's radius; above it (y < 0) there is
    nothing, below it the thin conical wall sits `wall_recess_mm` back and tapers away. A slim line
    contact unlike any training indenter."""
    X, Y = _grid()
    along = X**2 / (2 * rim_radius_mm)
    bead = np.where(
        np.abs(Y) <= bead_radius_mm, bead_radius_mm - np.sqrt(np.maximum(bead_radius_mm**2 - Y**2, 0)), FAR
    )
    wall = np.where(Y > 0, wall_recess_mm + (Y - 0.0) * np.tan(np.radians(taper_deg)), FAR)
    h = np.minimum(bead, wall) + along
    return np.where(Y >= -bead_radius_mm, h, FAR)


def tomato(radius_mm: float = 32.0):
    """A round tomato: a 64 mm sphere with low shallow lobes and a glossy (almost smooth) skin."""
    X, Y = _grid()
    return (
        _circle(np.hypot(X, Y), radius_mm) + 0.05 * _noise(X.shape, 80, 11) + 0.003 * _noise(X.shape, 3, 12)
    )


def mushroom(cap_radius_mm: float = 22.0, cap_edge_mm: float = 13.0):
    """A button mushroom's cap from the side: a 22 mm-radius dome whose rim curls in at 13 mm, with
    a fine velvety texture."""
    X, Y = _grid()
    r = np.hypot(X, Y)
    h = _circle(r, cap_radius_mm) + 0.6 * np.maximum(r - cap_edge_mm + 4, 0) ** 2 / 4
    return np.where(r < cap_edge_mm, h + 0.006 * _noise(X.shape, 2, 13), FAR)


BUILDERS = {f.__name__: f for f in (flat_face, cylinder_wall, bottle_wall, cup_rim, tomato, mushroom)}


@functools.cache
def get_contact(name: str) -> sim.Shape:
    """A downstream contact by name (BUILDERS), or any simulator shape (e.g. "banana", "strawberry")."""
    if name in BUILDERS:
        return sim.Shape.from_heightmap(BUILDERS[name](), MM_PER_PX, name=name)
    return sim.get_shape(name)
