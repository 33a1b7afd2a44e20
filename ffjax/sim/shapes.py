"""Indenters and objects as height fields: h(x, y) in mm = height of the body's lowest surface above the
gel plane when the body's lowest point touches it (h >= 0; FAR where there is no body).

The 10 training indenters and 10 unseen objects (names as in the paper's Table I) are built
procedurally on a 0.05 mm grid; users bring their own with Shape.from_heightmap or Shape.from_mesh.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import cv2
import numpy as np

FAR = 1000.0  # mm: "no body here", never touched
MAP_MM_PER_PX = 0.05
_EXTENT_MM = 20.0  # half-width of procedural maps: the pad diagonal plus offsets


class Shape:
    """A rigid body's lowest surface as a height map (mm), centred on the map centre."""

    def __init__(self, height_mm: np.ndarray, mm_per_px: float, name: str = "user", kind: str = "user"):
        h = np.asarray(height_mm, dtype=np.float64)
        if h.ndim != 2 or min(h.shape) < 2:
            raise ValueError(f"height map must be 2-D with at least 2x2 pixels, got shape {h.shape}")
        if not np.isfinite(mm_per_px) or mm_per_px <= 0:
            raise ValueError(f"mm_per_px must be a positive number, got {mm_per_px}")
        body = np.isfinite(h) & (h < FAR)
        if not body.any():
            raise ValueError(f"height map of {name!r} has no finite values")
        h = np.where(body, h - h[body].min(), FAR)
        self.height = h.astype(np.float32)
        self.mm_per_px = float(mm_per_px)
        self.name = name
        self.kind = kind
        self._levels: dict[int, np.ndarray] = {1: self.height}

    def __repr__(self) -> str:
        H, W = self.height.shape
        return f"Shape({self.name!r}, {H}x{W} px @ {self.mm_per_px:g} mm/px)"

    @classmethod
    def from_heightmap(cls, h_mm: np.ndarray, mm_per_px: float, name: str = "user") -> Shape:
        """Any height map in mm (lower = touches first; NaN/inf = no body). The minimum is set to 0."""
        return cls(h_mm, mm_per_px, name=name, kind="user")

    @classmethod
    def from_mesh(cls, path, mm_per_px: float = 0.05, scale: float = 1.0, name: str | None = None) -> Shape:
        """Height field of the lowest surface (min z, pressing along -z) of an STL/OBJ mesh in mm.

        Rasterizes every triangle (z-buffer, keep the minimum) on a grid centred on the mesh's x-y
        bounding box. Needs trimesh (`pip install ffjax[mesh]`).
        """
        try:
            import trimesh
        except ImportError as e:  # optional extra
            raise ImportError("Shape.from_mesh needs trimesh: pip install 'ffjax[mesh]' (or trimesh)") from e
        mesh = trimesh.load(str(path), force="mesh")
        tri = np.asarray(mesh.triangles, dtype=np.float64) * scale  # (F, 3, 3)
        if tri.size == 0:
            raise ValueError(f"mesh {path} has no triangles")
        lo, hi = tri.reshape(-1, 3).min(0), tri.reshape(-1, 3).max(0)
        centre = (lo[:2] + hi[:2]) / 2
        half = (hi[:2] - lo[:2]) / 2 + 2 * mm_per_px
        nx, ny = (np.ceil(half / mm_per_px).astype(int) * 2 + 1)
        zbuf = np.full((ny, nx), np.inf)
        # pixel (i, j) centre at centre + ((j - (nx-1)/2), (i - (ny-1)/2)) * mm_per_px
        px = (tri[..., 0] - centre[0]) / mm_per_px + (nx - 1) / 2
        py = (tri[..., 1] - centre[1]) / mm_per_px + (ny - 1) / 2
        for (ax, bx, cx), (ay, by, cy), (az, bz, cz) in zip(px, py, tri[..., 2]):
            j0, j1 = int(np.ceil(min(ax, bx, cx))), int(np.floor(max(ax, bx, cx)))
            i0, i1 = int(np.ceil(min(ay, by, cy))), int(np.floor(max(ay, by, cy)))
            det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
            if j1 < j0 or i1 < i0 or abs(det) < 1e-12:
                continue  # no pixel centre inside, or seen edge-on from below
            jj, ii = np.meshgrid(np.arange(j0, j1 + 1), np.arange(i0, i1 + 1))
            w0 = ((by - cy) * (jj - cx) + (cx - bx) * (ii - cy)) / det
            w1 = ((cy - ay) * (jj - cx) + (ax - cx) * (ii - cy)) / det
            w2 = 1 - w0 - w1
            inside = (w0 >= -1e-9) & (w1 >= -1e-9) & (w2 >= -1e-9)
            z = w0 * az + w1 * bz + w2 * cz
            sub = zbuf[i0:i1 + 1, j0:j1 + 1]
            np.minimum(sub, np.where(inside, z, np.inf), out=sub)
        return cls(zbuf, mm_per_px, name=name or str(path).rsplit("/", 1)[-1].rsplit(".", 1)[0], kind="user")

    def level(self, factor: int) -> tuple[np.ndarray, float]:
        """The map area-averaged by an integer factor (anti-aliasing for coarse renders), and its pitch."""
        factor = max(1, int(factor))
        if factor not in self._levels:
            H, W = self.height.shape
            h = self.height[: H // factor * factor, : W // factor * factor]
            self._levels[factor] = h.reshape(H // factor, factor, W // factor, factor).mean((1, 3))
        return self._levels[factor], self.mm_per_px * factor

    def sample(self, x_mm: np.ndarray, y_mm: np.ndarray, target_mm_per_px: float | None = None) -> np.ndarray:
        """Heights (mm, float32) at body-frame coordinates (mm); FAR off the map. Bilinear."""
        f = max(1, int(target_mm_per_px / self.mm_per_px / 1.5)) if target_mm_per_px else 1
        h, _ = self.level(f)
        H0, W0 = self.height.shape
        # original pixel p lies at level coordinate (p - (f - 1) / 2) / f (block centres)
        mx = ((x_mm / self.mm_per_px + (W0 - 1) / 2 - (f - 1) / 2) / f).astype(np.float32)
        my = ((y_mm / self.mm_per_px + (H0 - 1) / 2 - (f - 1) / 2) / f).astype(np.float32)
        return cv2.remap(h, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=FAR)


# ----------------------------------------------------------------------------------------- builders
def _grid(extent: float = _EXTENT_MM) -> tuple[np.ndarray, np.ndarray]:
    n = int(round(extent / MAP_MM_PER_PX))
    c = np.arange(-n, n + 1) * MAP_MM_PER_PX
    return np.meshgrid(c, c)


def _cap(r2: np.ndarray, R: float) -> np.ndarray:
    """Lower surface of a sphere of radius R touching at r=0 (FAR outside its silhouette)."""
    return np.where(r2 < R * R, R - np.sqrt(np.maximum(R * R - r2, 0)), FAR)


def _rounded(dist_in: np.ndarray, edge_r: float) -> np.ndarray:
    """Flat face with a rounded rim of radius edge_r, from the distance (mm) to the outline inside."""
    t = np.clip(edge_r - dist_in, 0, edge_r)
    return np.where(dist_in > 0, edge_r - np.sqrt(edge_r**2 - t**2), FAR)


def _extrude(mask: np.ndarray, edge_r: float) -> np.ndarray:
    dist = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5) * MAP_MM_PER_PX
    return _rounded(dist, edge_r)


def _bumps(X, Y, pitch, radius, amp, jitter=0.0, seed=0):
    """Small hemispherical bumps (amp > 0 raises the surface away = dimples; < 0 = studs)."""
    rng = np.random.default_rng(seed)
    gx = (X / pitch) - np.round(X / pitch)
    gy = (Y / pitch) - np.round(Y / pitch)
    if jitter:
        gx = gx + jitter * np.sin(np.round(X / pitch) * 12.9898 + np.round(Y / pitch) * 78.233 + rng.random())
    r2 = (gx * pitch) ** 2 + (gy * pitch) ** 2
    return amp * np.clip(1 - r2 / radius**2, 0, 1)


def _fbm(shape, sigma_px, seed):
    """Smooth unit-variance noise; sigma_px = (sx, sy) or one value."""
    sx, sy = sigma_px if isinstance(sigma_px, tuple) else (sigma_px, sigma_px)
    noise = np.random.default_rng(seed).standard_normal(shape).astype(np.float32)
    n = cv2.GaussianBlur(noise, (0, 0), sigmaX=sx, sigmaY=sy)
    return n / (n.std() + 1e-9)


def sphere_big():  # radius 40 mm: its 15 N contact reaches a/t ~ 1.6 on the 4.5 mm gel, like the cube's face
    X, Y = _grid()
    return _cap(X**2 + Y**2, 40.0)


def sphere_small():
    X, Y = _grid()
    return _cap(X**2 + Y**2, 4.0)


def cylinder():  # flat punch, fine concentric machining grooves
    X, Y = _grid()
    r = np.hypot(X, Y)
    return _rounded(3.0 - r, 0.4) + 0.02 * (1 + np.cos(2 * np.pi * r / 0.6))


def triple_cylinder():
    X, Y = _grid()
    h = np.full_like(X, FAR)
    for k in range(3):
        a = np.pi / 2 + 2 * np.pi * k / 3
        h = np.minimum(h, _rounded(1.5 - np.hypot(X - 3.5 * np.cos(a), Y - 3.5 * np.sin(a)), 0.3))
    return h


def ring():  # torus: major radius 3.5 mm, tube radius 0.8 mm
    X, Y = _grid()
    return _cap((np.hypot(X, Y) - 3.5) ** 2, 0.8)


def cross():  # two rounded bars 12 x 2.4 mm
    X, Y = _grid()
    bar = lambda u, v: np.where(np.abs(v) < 6, _cap(u**2, 1.2), _cap(u**2 + (np.abs(v) - 6) ** 2, 1.2))  # noqa: E731
    return np.minimum(bar(X, Y), bar(Y, X))


def cube():  # 14 mm square face, knurled: a flat contact across most of the pad's short side (15.2 mm)
    return flat_punch(14.0).height


@functools.lru_cache(maxsize=32)  # one Shape per size: press's per-shape caches then hit
def flat_punch(side_mm: float, knurl_mm: float = 0.03) -> Shape:
    """A knurled square flat punch like the cube indenter (0.5 mm rounded rim, 0.7 mm diamond knurl of
    amplitude knurl_mm; 0 = smooth) with any face size: the contact-size and face-texture factors of
    experiments.stability (the cube, 14 mm, knurl 0.03 mm, is the largest flat face in training)."""
    if not 0 < side_mm < 2 * _EXTENT_MM:
        raise ValueError(f"side_mm must be in (0, {2 * _EXTENT_MM}) mm, got {side_mm}")
    if not 0 <= knurl_mm <= 0.5:
        raise ValueError(f"knurl_mm must be in [0, 0.5] mm, got {knurl_mm}")
    X, Y = _grid()
    d = np.minimum(side_mm / 2 - np.abs(X), side_mm / 2 - np.abs(Y))
    knurl = knurl_mm * (2 + np.sin(2 * np.pi * (X + Y) / 0.7) + np.sin(2 * np.pi * (X - Y) / 0.7))
    name = f"flat_punch_{side_mm:g}mm" + ("" if knurl_mm == 0.03 else f"_knurl{knurl_mm:g}")
    return Shape(_rounded(d, 0.5) + knurl, MAP_MM_PER_PX, name=name, kind="user")


@functools.lru_cache(maxsize=32)  # one Shape per size: press's per-shape caches then hit
def sphere(radius_mm: float) -> Shape:
    """A smooth sphere like the sphere indenters with any radius: the curvature factor of
    experiments.stability (the big sphere, 40 mm, is the flattest curved indenter in training)."""
    if not 0 < radius_mm <= 100:
        raise ValueError(f"radius_mm must be in (0, 100] mm, got {radius_mm}")
    X, Y = _grid()
    return Shape(_cap(X**2 + Y**2, radius_mm), MAP_MM_PER_PX, name=f"sphere_{radius_mm:g}mm", kind="user")


@functools.lru_cache(maxsize=32)  # one Shape per size: press's per-shape caches then hit
def bar(length_mm: float, radius_mm: float = 4.0) -> Shape:
    """A smooth rounded bar (a cylinder of radius_mm lying along x, hemispherical ends; length_mm between the
    end centres): the elongation factor of experiments.stability. At length 0 it is a sphere; at the
    default radius, the small sphere indenter."""
    if not 0 <= length_mm < 2 * _EXTENT_MM or not 0 < radius_mm <= 100:
        raise ValueError(f"need 0 <= length_mm < {2 * _EXTENT_MM} and 0 < radius_mm <= 100, "
                         f"got {length_mm}, {radius_mm}")
    X, Y = _grid()
    along = np.maximum(np.abs(X) - length_mm / 2, 0)
    return Shape(_cap(along**2 + Y**2, radius_mm), MAP_MM_PER_PX, name=f"bar_{length_mm:g}x{radius_mm:g}mm",
                 kind="user")


def prism_edge():  # 110-degree wedge, edge rounded 0.3 mm, 30 mm long: longer than the pad's diagonal (25.4 mm),
    # so its line contact crosses the field of view at any yaw, as the edge of a box or a ruler does
    X, Y = _grid()
    cot = 1 / np.tan(np.radians(55))
    rho = 0.3
    h = cot * (np.sqrt(X**2 + rho**2) - rho) + np.maximum(np.abs(Y) - 15, 0) ** 2 / 0.6
    return np.where(np.abs(X) < 6, h, FAR)


def cone():  # 120-degree cone, tip rounded 0.4 mm
    X, Y = _grid()
    r = np.hypot(X, Y)
    cot = 1 / np.tan(np.radians(60))
    return np.where(r < 9, cot * (np.sqrt(r**2 + 0.16) - 0.4), FAR)


def ellipsoid():  # semi-axes 7 x 4 x 4 mm, dimpled
    X, Y = _grid()
    q = 1 - (X / 7) ** 2 - (Y / 4) ** 2
    h = np.where(q > 0, 4 * (1 - np.sqrt(np.maximum(q, 0))), FAR)
    return h + _bumps(X, Y, 1.0, 0.3, 0.06)


def banana():  # curved fruit, 36 mm arc radius, faceted cross-section, fibre streaks
    X, Y = _grid()
    Rc = 36.0
    dist = np.hypot(X, Y + Rc) - Rc  # signed distance from the arc through the origin
    ang = np.arctan2(X, Y + Rc)
    facet = 1 + 0.04 * np.cos(5 * np.arcsin(np.clip(dist / 9, -1, 1)))
    h = _cap((dist * facet) ** 2, 9.0) + 0.5 * (ang * Rc / 20) ** 2  # the ends curl up
    return h + 0.015 * _fbm(X.shape, (30, 2), 1) * (np.abs(dist) < 9)


def brown_egg():  # 56 x 42 mm egg, pointed end to +x; speckled shell roughness
    X, Y = _grid()
    a = np.where(X > 0, 32.0, 24.0)
    q = 1 - (X / a) ** 2 - (Y / 21) ** 2
    return 21 * (1 - np.sqrt(np.clip(q, 1e-6, 1))) + 0.01 * _fbm(X.shape, 3, 2)


def strawberry():  # blunt cone with seeds (achenes) in pits
    X, Y = _grid()
    r = np.hypot(X, Y)
    h = np.where(r < 6, r**2 / 12, 3 + 0.9 * (r - 6))
    pits = _bumps(X, Y, 2.2, 0.6, 0.12, jitter=0.15, seed=3)
    seeds = -_bumps(X, Y, 2.2, 0.25, 0.1, jitter=0.15, seed=3)
    return h + pits + seeds


def marker():  # 14 mm barrel lying along x; the cap (x > 5 mm) is 0.3 mm wider
    X, Y = _grid()
    body = _cap(Y**2, 7.0) + 0.3
    capr = _cap(Y**2, 7.3)
    return np.where(X > 5, capr, body)


def wooden_spatula():  # flat blade ending at y = 4 mm, slightly bowed, wood grain
    X, Y = _grid()
    grain = 0.04 * _fbm(X.shape, (1.5, 60.0), 4)  # streaks along the handle (y)
    return _rounded(4.0 - Y, 1.0) + X**2 / 800 + grain


def ellipsoid_ycb():  # a larger smooth ellipsoid (30 x 20 x 20 mm)
    X, Y = _grid()
    q = 1 - (X / 15) ** 2 - (Y / 10) ** 2
    return np.where(q > 0, 10 * (1 - np.sqrt(np.maximum(q, 0))), FAR)


def nectarine():  # 30 mm radius, suture groove, smooth skin
    X, Y = _grid()
    groove = 0.25 * np.exp(-((X - 4) ** 2) / 1.5)
    return _cap(X**2 + Y**2, 30.0) + groove + 0.008 * _fbm(X.shape, 4, 5)


def green_apple():  # 37 mm radius, lumpy with lenticels
    X, Y = _grid()
    lumps = 0.08 * _fbm(X.shape, 60, 6)
    return _cap(X**2 + Y**2, 37.0) + lumps - _bumps(X, Y, 1.7, 0.2, 0.03, jitter=0.2, seed=6)


def wrench():  # open-end head (jaw slot to +x) on a 12 mm handle, flat face, machined
    X, Y = _grid()
    head = np.hypot(X, Y) < 11
    slot = (X > -2) & (np.abs(Y) < 4.5)
    handle = (X < 0) & (np.abs(Y) < 6)
    mask = (head & ~slot) | handle
    return _extrude(mask, 0.6) + 0.01 * np.sin(2 * np.pi * X / 0.4)


def heart():  # 18 mm heart-shaped flat-top pillow with 2 mm rounded rim
    X, Y = _grid()
    x, y = X / 9.0, -Y / 9.0 + 0.25
    mask = (x**2 + y**2 - 1) ** 3 - x**2 * y**3 < 0
    return _extrude(mask, 2.0)


_INDENTER_BUILDERS: dict[str, Callable[[], np.ndarray]] = {
    f.__name__: f
    for f in (sphere_big, sphere_small, cylinder, triple_cylinder, ring, cross, cube, prism_edge, cone, ellipsoid)
}
_OBJECT_BUILDERS: dict[str, Callable[[], np.ndarray]] = {
    f.__name__: f
    for f in (banana, brown_egg, strawberry, marker, wooden_spatula, ellipsoid_ycb, nectarine, green_apple,
              wrench, heart)
}
INDENTERS: tuple[str, ...] = tuple(_INDENTER_BUILDERS)
UNSEEN_OBJECTS: tuple[str, ...] = tuple(_OBJECT_BUILDERS)


@functools.cache
def get_shape(name: str) -> Shape:
    """A named indenter (INDENTERS) or unseen object (UNSEEN_OBJECTS); built once, then cached."""
    if name in _INDENTER_BUILDERS:
        return Shape(_INDENTER_BUILDERS[name](), MAP_MM_PER_PX, name=name, kind="indenter")
    if name in _OBJECT_BUILDERS:
        return Shape(_OBJECT_BUILDERS[name](), MAP_MM_PER_PX, name=name, kind="object")
    raise ValueError(f"unknown shape {name!r}; indenters: {list(INDENTERS)}; objects: {list(UNSEEN_OBJECTS)}")
