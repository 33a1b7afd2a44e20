"""ffjax.sim: physics invariants, determinism, every shape and sensor, refusals. Small renders only."""

import dataclasses

import numpy as np
import pytest

from ffjax import sim
from ffjax.sim import mechanics, optics
from ffjax.sim.sensors import with_markers, with_pattern_moving

SIZE = (24, 32)


def test_zero_force_is_background_and_flat():
    s = sim.press("sphere_big", "mini-1", force=(0.0, 0.0, 0.0), size=SIZE, noise=False)
    assert s.depth.shape == SIZE and s.depth.dtype == np.float32 and not s.depth.any()
    assert np.array_equal(s.image, sim.get_sensor("mini-1").background(SIZE, noise=False))
    noisy = sim.press("sphere_big", "mini-1", force=(0.0, 0.0, 0.0), size=SIZE, seed=3)
    diff = np.abs(noisy.image.astype(float) - noisy.background)
    # independent noise per frame: the difference is noise only (std ~ sqrt(2) * noise_std)
    assert diff.mean() < 3 * sim.get_sensor("mini-1").noise_std
    assert np.array_equal(noisy.background, sim.get_sensor("mini-1").background(SIZE))


def test_stiffening_is_the_inverse_pair_and_linear_at_small_strain():
    u = np.linspace(-0.5, 4.0, 50)
    assert np.allclose(mechanics.soften(mechanics.stiffen(u, 4.5), 4.5), u, atol=1e-4)
    assert mechanics.stiffen(0.045, 4.5) == pytest.approx(0.045, rel=0.02)  # 1% strain: linear
    assert mechanics.stiffen(2.25, 4.5) > 2 * 2.25  # half the thickness: the column has stiffened


def test_more_force_presses_deeper():
    pens = [sim.press("sphere_small", "mini-1", force=(0, 0, fz), size=SIZE).meta["penetration_mm"]
            for fz in (0.5, 2, 5, 10, 15)]
    assert np.all(np.diff(pens) > 0)


def test_solved_pressure_carries_the_requested_force_and_touches_only_the_body():
    sensor = sim.get_sensor("mini-2", gel=2)
    size = (60, 80)
    dy, dx = sensor.mm_per_px(size)
    h = sim.body_heights(sim.get_shape("cross"), sensor, size, 0, 0, 0, (0, 0)).astype(np.float64)
    n = mechanics.solve_normal(h, (dx + dy) / 2, sensor.gel.shear_mpa, sensor.gel.thickness_mm, 7.0)
    assert n.pressure.sum() * dx * dy == pytest.approx(7.0, rel=1e-3)
    assert n.pressure.min() >= 0 and not n.pressure[~n.contact].any()
    gap = h - h.min() - (n.delta - n.surface)  # body above the gel surface: >= 0, ~0 in the contact
    assert gap.min() > -1e-3 and np.abs(gap[n.contact]).max() < 0.02
    assert n.surface.min() < -0.01  # the displaced volume rises beside the contact


@pytest.mark.parametrize("fz, pose", [(3.28, (-0.257, 0.628, -128.5, (5.92, -12.39))),
                                      (10.42, (1.196, -0.408, 96.77, (12.10, 11.01)))])
def test_a_tilted_edge_is_not_pressed_to_the_glass_on_one_cell(fz, pose):
    """The knife edge at a large tilt: the batched solve once restiffened its target at an approach read off its
    first, unsettled pressure (4.2 mm on a 4 mm gel) and settled on a second fixed point, the whole force on the
    body's lowest cell pressed 3.2 mm in (batched.STIFFEN_AFTER). It finds the reference's contact."""
    sensor = sim.get_sensor("mini-1", gel=2)
    size = (60, 80)  # the force solve's own grid (quarter native)
    dy, dx = sensor.mm_per_px(size)
    h = sim.body_heights(sim.get_shape("prism_edge"), sensor, size, *pose).astype(np.float64)
    gel = sensor.gel
    new, ref = (mechanics.solve_normal_batch(h[None], (dx + dy) / 2, gel.shear_mpa, gel.thickness_mm, [fz],
                                             reference)[0] for reference in (False, True))
    assert ref.contact.sum() > 100  # a line contact along the edge, not a cell
    assert new.contact.sum() == pytest.approx(ref.contact.sum(), rel=0.02)
    assert abs(new.delta - ref.delta) < 1e-3  # mm: within 1 um, the agreement target
    assert np.abs(new.surface - ref.surface).max() < 1e-3


def test_wide_flat_face_is_stiffer_than_a_narrow_one():
    """A bonded incompressible layer stiffens as the contact widens against its thickness: at equal force
    an 18 mm flat face sinks less than a third as far as a 5 mm one (columns alone give the area ratio
    only through their pressure law)."""
    narrow = sim.press(sim.shapes.flat_punch(5.0), "mini-1", force=(0, 0, 4.0), size=SIZE, noise=False)
    wide = sim.press(sim.shapes.flat_punch(18.0), "mini-1", force=(0, 0, 4.0), size=SIZE, noise=False)
    assert wide.meta["penetration_mm"] < narrow.meta["penetration_mm"] / 3


def _symmetric_sensor():
    """mini-1 with LEDs mirror-symmetric about x = 0 and a uniform pigment."""
    base = sim.get_sensor("mini-1")
    leds = (sim.LED(90, 6.0, (1.0, 0.3, 0.3)), sim.LED(270, 6.0, (0.3, 0.3, 1.0)))
    gel = dataclasses.replace(base.gel, pigment=0.0, markers=False)
    return dataclasses.replace(base, leds=leds, gel=gel, unevenness=0.0, pixel_pattern=0.0, dust=0,
                               white_balance=(1.0, 1.0, 1.0), name="mini-sym")


def test_mirrored_shear_mirrors_depth_and_image():
    sensor = _symmetric_sensor()
    size = (48, 64)
    a = sim.press("sphere_big", sensor, force=(1.0, 0.0, 3.0), size=size, noise=False)
    b = sim.press("sphere_big", sensor, force=(-1.0, 0.0, 3.0), size=size, noise=False)
    assert np.abs(a.depth - b.depth[:, ::-1]).max() < 1e-3
    assert np.abs(a.depth - b.depth).max() > 0.02  # the bulge moved: shear is visible in the surface
    diff = np.abs(a.image.astype(int) - b.image[:, ::-1]).mean()
    assert diff < 0.5 and np.abs(a.image.astype(int) - b.image).mean() > 2 * diff
    assert a.meta["shear_disp_mm"][0] == pytest.approx(-b.meta["shear_disp_mm"][0])


def test_shear_capped_by_friction():
    sensor = sim.get_sensor("mini-1")
    mu = sensor.gel.friction
    stick = sim.press("sphere_big", sensor, force=(0.5, 0.5, 2.0), size=SIZE)
    assert not stick.meta["slip"] and np.allclose(stick.force, [0.5, 0.5, 2.0])
    slip = sim.press("sphere_big", sensor, force=(3.0, 4.0, 2.0), size=SIZE)
    assert slip.meta["slip"]
    assert np.hypot(*slip.force[:2]) == pytest.approx(mu * 2.0, rel=1e-5)
    assert slip.force[0] / slip.force[1] == pytest.approx(0.75, rel=1e-5)  # direction kept
    assert slip.meta["requested_force"] == (3.0, 4.0, 2.0)


def test_shear_moves_the_pigment():
    sensor = with_markers(sim.get_sensor("mini-1", gel=3))
    a = sim.press("sphere_big", sensor, force=(0, 0, 3.0), size=(48, 64), noise=False)
    b = sim.press("sphere_big", sensor, force=(1.5, 0, 3.0), size=(48, 64), noise=False)
    assert np.abs(a.image.astype(int) - b.image).mean() > 0.5


def test_only_the_gels_pattern_moves():
    """A gel moved sideways carries its pigment; the camera's vignette, gains, pixel pattern and dust stay."""
    size = (60, 80)
    flat = np.zeros(size, np.float32)
    shift = np.full(size + (2,), 2.0, np.float32)
    camera_only = with_pattern_moving(sim.get_sensor("mini-1"), 0.0)
    assert camera_only.gel.pigment == 0 and camera_only.dust > 0
    still = optics.render(camera_only, size, flat, None, None)
    assert np.array_equal(optics.render(camera_only, size, flat, shift, None), still)
    pigment_only = with_pattern_moving(sim.get_sensor("mini-1"), 1.0)
    moved = optics.render(pigment_only, size, flat, shift, None).astype(int)
    assert np.abs(moved - optics.render(pigment_only, size, flat, None, None)).mean() > 0.2
    assert not sim.get_sensor("mini-1", gel=3).gel.markers  # Table II's gels carry none


def test_pattern_split_keeps_the_total():
    s = sim.get_sensor("mini-2", gel=2)
    for share in (0.0, 0.5, 1.0):
        t = with_pattern_moving(s, share)
        assert np.hypot(t.gel.pigment, t.pixel_pattern) == pytest.approx(np.hypot(s.gel.pigment, s.pixel_pattern))
        assert t.gel.pigment**2 / (t.gel.pigment**2 + t.pixel_pattern**2) == pytest.approx(share)
    with pytest.raises(ValueError, match="moving share"):
        with_pattern_moving(s, 1.5)


def test_same_seed_same_bytes():
    kw = dict(force=(0.3, -0.2, 4.0), x_mm=1.0, y_mm=-0.5, yaw_deg=30, tilt_deg=(2, -1), size=SIZE)
    a, b = sim.press("cube", "mini-3", seed=7, **kw), sim.press("cube", "mini-3", seed=7, **kw)
    c = sim.press("cube", "mini-3", seed=8, **kw)
    assert a.image.tobytes() == b.image.tobytes() and a.depth.tobytes() == b.depth.tobytes()
    assert a.image.tobytes() != c.image.tobytes() and np.array_equal(a.depth, c.depth)


@pytest.mark.parametrize("name", sim.INDENTERS + sim.UNSEEN_OBJECTS)
def test_every_shape_renders(name):
    s = sim.press(name, "mini-1", force=(0.2, 0.1, 5.0), size=SIZE, seed=1)
    assert s.image.shape == SIZE + (3,) and s.image.dtype == np.uint8
    assert s.force.dtype == np.float32 and s.force.shape == (3,)
    assert s.depth.max() > 0.05 and s.meta["shape"] == name and s.meta["contact_area_mm2"] > 0


@pytest.mark.parametrize("key", sim.SENSOR_NAMES)
def test_every_sensor_renders(key):
    sensor = sim.get_sensor(key)
    h, w = sensor.native_size
    size = (h // 10, w // 10)
    s = sim.press("sphere_small", sensor, force=(0.5, 0.0, 5.0), size=size)
    assert s.image.shape == size + (3,) and s.background.shape == size + (3,)
    assert 40 < s.background.mean() < 220
    assert np.abs(s.image.astype(int) - s.background).mean() > 1.0


def test_sensors_differ():
    bgs = [sim.get_sensor(k).background(SIZE, noise=False).astype(int) for k in ("mini-1", "mini-2", "mini-3")]
    assert all(np.abs(a - b).mean() > 2 for i, a in enumerate(bgs) for b in bgs[i + 1:])
    g1, g3 = sim.get_sensor("mini-1", 1), sim.get_sensor("mini-1", 3)
    p1 = sim.press("sphere_small", g1, force=(0, 0, 5), size=SIZE).meta["penetration_mm"]
    p3 = sim.press("sphere_small", g3, force=(0, 0, 5), size=SIZE).meta["penetration_mm"]
    assert p1 != pytest.approx(p3, rel=0.02)
    assert sim.get_sensor("digit").native_size == (320, 240)
    assert len(sim.SENSORS) == len(sim.SENSOR_NAMES) == 10


@pytest.mark.parametrize("kw", [
    dict(force=(0, 0, 1e4)),  # beyond what the gel takes
    dict(force=(0, 0, -1.0)),
    dict(force=(0, float("nan"), 1.0)),
    dict(force=(0, 0, float("inf"))),
    dict(x_mm=50.0),
    dict(y_mm=-9.0),
    dict(tilt_deg=(40.0, 0.0)),
    dict(yaw_deg=float("nan")),
    dict(force=(1.0, 2.0)),
])
def test_invalid_requests_raise(kw):
    args = dict(force=(0, 0, 1.0), size=SIZE) | kw
    with pytest.raises(ValueError):
        sim.press("sphere_big", "mini-1", **args)


def test_unknown_names_raise():
    with pytest.raises(ValueError):
        sim.get_shape("teapot")
    with pytest.raises(ValueError):
        sim.get_sensor("mini-4")
    with pytest.raises(ValueError):
        sim.get_sensor("mini-1", gel=4)


def test_press_batch_matches_press():
    forces = np.array([[0.1, 0.0, 2.0], [0.0, -0.3, 9.0]])
    out = sim.press_batch("ring", "mini-1", forces, x_mm=[0.5, -1], y_mm=[0, 1], yaw_deg=[0, 45],
                          tilt_deg=[[0, 0], [1, 2]], seeds=[5, 6], size=SIZE)
    one = sim.press("ring", "mini-1", force=forces[1], x_mm=-1, y_mm=1, yaw_deg=45, tilt_deg=(1, 2), seed=6,
                    size=SIZE)
    assert out["image"].shape == (2,) + SIZE + (3,)
    # the layer solves run as a batch of 2 and of 1: XLA may round the last float digit otherwise (tolerance in
    # docs/simulator.md); a batch's order never matters (test_a_batch_does_not_depend_on_its_order)
    assert np.abs(out["image"][1].astype(int) - one.image).max() <= 1
    np.testing.assert_allclose(out["depth"][1], one.depth, atol=1e-6)
    assert np.array_equal(out["force"][1], one.force)
    assert np.array_equal(out["background"], one.background) and len(out["meta"]) == 2


def test_a_batch_does_not_depend_on_its_order():
    """Same presses, other order, same bytes: each press's solve is frozen once it converges, whatever the
    others in its batch still do."""
    shapes = ["ring", "cone", "sphere_big"]
    forces = np.array([[0.1, 0.0, 2.0], [0.0, -0.3, 9.0], [0.4, 0.2, 5.0]])
    a = sim.press_batch(shapes, "mini-2", forces, seeds=[1, 2, 3], size=SIZE)
    b = sim.press_batch(shapes[::-1], "mini-2", forces[::-1], seeds=[3, 2, 1], size=SIZE)
    assert np.array_equal(a["image"], b["image"][::-1]) and np.array_equal(a["depth"], b["depth"][::-1])


def test_a_batch_above_the_compiled_sizes_takes_a_program_of_its_own(monkeypatch):
    """MAX_BATCH above batched.BATCHES (a GPU's large batches): the calls are that size, the last one padded to
    the smallest size that holds it, and the presses come out as in the default pieces (to XLA's last digit)."""
    from ffjax.sim import batched

    monkeypatch.setattr(batched, "MAX_BATCH", 40)
    assert list(batched._pieces(100)) == [(0, 40, 40), (40, 80, 40), (80, 100, 32)]
    n = 34
    rng = np.random.default_rng(0)
    forces = np.column_stack([np.zeros((n, 2)), rng.uniform(0.5, 9.0, n)])
    args = (["ring", "cone"] * (n // 2), "mini-1", forces)
    big = sim.press_batch(*args, seeds=list(range(n)), size=(24, 32))
    monkeypatch.setattr(batched, "MAX_BATCH", None)
    default = sim.press_batch(*args, seeds=list(range(n)), size=(24, 32))
    np.testing.assert_allclose(big["depth"], default["depth"], atol=1e-6)
    assert np.abs(big["image"].astype(int) - default["image"]).max() <= 1


def test_the_pigment_pattern_belongs_to_the_gel():
    """A gel moved to another unit (Table II's S2 G1) brings its own speckle; another gel has another one."""
    import cv2

    from ffjax.sim import optics

    def speckle(key):  # the fine part of the pigment (how uneven the pad looks is the unit's own)
        s = sim.get_sensor(key)
        a = (optics.tables(s, (96, 128)).albedo / np.asarray(s.albedo, np.float32))[..., 0]
        return (a - cv2.GaussianBlur(a, (0, 0), 3.0)).ravel()

    assert np.corrcoef(speckle("mini-1-gel1"), speckle("mini-2-gel1"))[0, 1] > 0.95
    assert abs(np.corrcoef(speckle("mini-1-gel1"), speckle("mini-1-gel2"))[0, 1]) < 0.2


def test_the_free_surface_is_carried_with_the_gel():
    """Sheared, the gel around a sharp body trails it: behind the motion the unsheared profile is found further
    out, so the rim region changes, while the surface the body holds does not."""
    sensor = sim.get_sensor("mini-1")
    a = sim.press("cone", sensor, (0.0, 0.0, 5.0), size=(48, 64), noise=False)
    b = sim.press("cone", sensor, (1.0, 0.0, 5.0), size=(48, 64), noise=False)
    assert abs(float(a.depth.max()) - float(b.depth.max())) < 0.02 * float(a.depth.max())
    assert np.abs(b.depth - a.depth).max() > 0.01  # mm: the rim moved
