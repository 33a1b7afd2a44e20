"""ffjax.sim shapes: named shapes, user height maps and meshes, and the force range they reach."""

import numpy as np
import pytest

from ffjax import sim
from ffjax.sim import mechanics
from ffjax.sim.press import solve_size


def test_named_shapes():
    assert len(sim.INDENTERS) == 10 and len(sim.UNSEEN_OBJECTS) == 10
    assert not set(sim.INDENTERS) & set(sim.UNSEEN_OBJECTS)
    for name in ("sphere_big", "heart"):
        s = sim.get_shape(name)
        assert s.height.min() == 0 and s.name == name


@pytest.mark.parametrize("frame", [(24, 32), None])  # the smoke preset's coarse solve and the finest one
@pytest.mark.parametrize("key", ["mini-1-gel1", "mini-2-gel2", "mini-3-gel3", "digit"])
def test_every_shape_reaches_15_newtons(key, frame):
    """Fz up to 15 N fits in every gel for every body, also off-centre and tilted, on every solve grid."""
    sensor = sim.get_sensor(key)
    size = solve_size(sensor, frame)
    dy, dx = sensor.mm_per_px(size)
    for name in sim.INDENTERS + sim.UNSEEN_OBJECTS:
        h = sim.body_heights(sim.get_shape(name), sensor, size, 4.0, -3.0, 30.0, (3.0, -3.0))
        n = mechanics.solve_normal(h.astype(np.float64), (dx + dy) / 2, sensor.gel.shear_mpa,
                                   sensor.gel.thickness_mm, 15.0)
        assert 0 < n.delta < mechanics.MAX_STRAIN * sensor.gel.thickness_mm


def test_from_heightmap_matches_sphere():
    mpp = 0.05
    c = (np.arange(401) - 200) * mpp
    X, Y = np.meshgrid(c, c)
    r2 = X**2 + Y**2
    h = np.where(r2 < 100, 10 - np.sqrt(np.maximum(100 - r2, 0)), np.nan)
    mine = sim.Shape.from_heightmap(h + 3.0, mpp, name="mine")  # offset is removed
    a = sim.press(mine, "mini-1", force=(0, 0, 5), size=(24, 32))
    b = sim.press(sim.shapes.sphere(10.0), "mini-1", force=(0, 0, 5), size=(24, 32))
    assert a.meta["shape"] == "mine"
    assert a.meta["penetration_mm"] == pytest.approx(b.meta["penetration_mm"], rel=0.02)
    with pytest.raises(ValueError):
        sim.Shape.from_heightmap(np.full((4, 4), np.nan), 0.1)
    with pytest.raises(ValueError):
        sim.Shape.from_heightmap(np.zeros(5), 0.1)


def test_from_mesh(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    path = tmp_path / "ball.stl"
    trimesh.creation.icosphere(subdivisions=3, radius=5.0).export(path)
    shape = sim.Shape.from_mesh(path, mm_per_px=0.1)
    assert shape.name == "ball"
    H, W = shape.height.shape
    # lowest surface of a sphere: h ~ r^2 / (2R) near the bottom
    assert shape.height[H // 2, W // 2] < 0.1
    assert shape.height[H // 2, W // 2 + 20] == pytest.approx(5 - np.sqrt(25 - 4), abs=0.1)
    s = sim.press(shape, "mini-1", force=(0, 0, 3), size=(24, 32))
    assert s.depth.max() > 0.1


def test_sphere_builder_is_the_big_sphere_at_40mm():
    from ffjax.sim.shapes import sphere

    assert np.array_equal(sphere(40.0).height, sim.get_shape("sphere_big").height)
    assert sphere(30.0).height.min() == 0 and sphere(30.0).name == "sphere_30mm"
    with pytest.raises(ValueError, match="radius_mm"):
        sphere(0.0)


def test_flat_punch_knurl():
    from ffjax.sim.shapes import flat_punch

    smooth, cube, deep = (flat_punch(14.0, k).height for k in (0.0, 0.03, 0.06))
    face = smooth == 0  # inside the rounded rim
    assert 0.1 < np.ptp(cube[face]) < 0.13 and 0.2 < np.ptp(deep[face]) < 0.25  # crest to trough: 4x the amplitude
    with pytest.raises(ValueError, match="knurl_mm"):
        flat_punch(14.0, -0.1)
