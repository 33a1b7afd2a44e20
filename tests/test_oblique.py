"""The paper's press: the tool moves along its tilted axis, the shear grows with the press over nested contacts
in stick (mechanics.oblique_batch, sim.press(..., path="oblique")). Checks fixed before it was built: a small
sphere on a thick layer gives Ft / Fz = (2/3) tan a (Mindlin over Hertz at nu = 0.5); a flat face is pressed, then
sheared, by the same displacement; no slip while that ratio is below mu; convergence in the path's steps, faster
with the power-law quadrature."""

import numpy as np
import pytest

from ffjax import sim
from ffjax.sim import elastic_layer as el
from ffjax.sim import mechanics

G, MU = 0.15, 1.0
TILT = np.tan(np.radians(10.0))


def _grid(n=64, dx=0.1):
    x = (np.arange(n) - n / 2 + 0.5) * dx
    return np.meshgrid(x, x)


def test_a_small_sphere_on_a_thick_layer_shears_by_two_thirds_of_the_tilt():
    X, Y = _grid()
    h = (X**2 + Y**2) / (2 * 20.0)  # R 20 mm at 0.05 N on 10 mm of gel: a ~ 1.1 mm, a/t ~ 0.1, a/R ~ 0.05
    normals, shears = mechanics.oblique_batch(h[None], 0.1, G, 10.0, MU, [0.05], [[TILT, 0.0]])
    a = np.sqrt(normals[0].contact.sum() * 0.01 / np.pi)
    assert a / 10.0 < 0.15
    ft = shears[0].force
    assert ft[0] / 0.05 == pytest.approx(2 / 3 * TILT, rel=0.05) and abs(ft[1]) < 1e-3 * ft[0]
    assert not shears[0].slip


def test_a_flat_face_is_pressed_then_sheared_by_the_tools_sideways_move():
    """The contact is the whole face from the first touch, so the path is press-then-shear by the tool's sideways
    travel, each step held at the pit's depth then: between the hold on the surface and at the final depth."""
    X, Y = _grid()
    h = np.where(np.hypot(X, Y) < 2.0, 0.0, el.FAR)
    normals, shears = mechanics.oblique_batch(h[None], 0.1, G, 4.5, MU, [2.0], [[TILT, 0.0]], steps=3)
    move = TILT * normals[0].delta  # the tool's sideways travel over the press
    assert shears[0].disp_mm[0] == pytest.approx(move, rel=1e-3)  # the held gel goes with the tool
    bounds = [move / mechanics.shear_batch([[1.0, 0.0]], [2.0], normals[0].contact[None], 0.1, G, 4.5, MU,
                                           depths=[d])[0].disp_mm[0]
              for d in (0.0, mechanics.hold_depth(normals[0], 4.5))]
    assert bounds[0] < shears[0].force[0] < bounds[1]


def test_no_slip_below_friction_and_the_cap_above():
    X, Y = _grid()
    h = (X**2 + Y**2) / (2 * 10.0)
    _, (stick,) = mechanics.oblique_batch(h[None], 0.1, G, 4.5, MU, [3.0], [[TILT, 0.0]])
    assert not stick.slip
    _, (slide,) = mechanics.oblique_batch(h[None], 0.1, G, 4.5, 0.02, [3.0], [[TILT, 0.0]])
    assert slide.slip and np.hypot(*slide.force) == pytest.approx(0.02 * 3.0, rel=1e-6)


def _oblique_on_a_mini(shape: str, **how):
    """The shear of `shape` pressed to 8 N on a Mini along a path tilted (7, 3) deg, by oblique_batch(**how)."""
    import importlib

    press = importlib.import_module("ffjax.sim.press")
    sensor = sim.get_sensor("mini-1")
    ssize = press.solve_size(sensor, None)  # native frames: the finest solve
    dy, dx = sensor.mm_per_px(ssize)
    req = press._request(sim.get_shape(shape), sensor, ssize, (0.0, 0.0, 8.0), 0.0, 0.0, 20.0, (7.0, 3.0), 0)
    gel = sensor.gel
    return mechanics.oblique_batch([req.h_s], (dx + dy) / 2, gel.shear_mpa, gel.thickness_mm, gel.friction, [8.0],
                                   [np.tan(np.radians([7.0, 3.0]))], **how)[1][0]


def test_the_path_converges_in_its_steps():
    slope = np.tan(np.radians([7.0, 3.0]))
    ft = {n: _oblique_on_a_mini("sphere_small", steps=n).force for n in (4, 8)}
    # the default's 4 steps within 5% of 8 (measured against 16 on six indenters: 2.2-7.1% at 4, 0-3.8% at 8)
    assert np.hypot(*(ft[4] - ft[8])) < 0.05 * np.hypot(*ft[8])
    assert np.degrees(np.arctan2(ft[8][1], ft[8][0])) == pytest.approx(np.degrees(np.arctan2(*slope[::-1])), abs=5)


@pytest.mark.parametrize("q", [0.0, 0.5, 1.0, 1.7])
@pytest.mark.parametrize("n", [2, 3])
def test_the_power_quadrature_is_exact_for_a_power_law(q, n):
    ends = np.linspace(0.0, 2.0, n + 1) ** 1.2  # uneven steps, as the path's are
    mids = 0.5 * (ends[:-1] + ends[1:])
    stiff = 3.0 * mids**q
    w = mechanics._power_weights(mids, stiff, ends)
    assert np.sum(w * stiff * np.diff(ends)) == pytest.approx(3.0 * ends[-1] ** (q + 1) / (q + 1), rel=1e-12)
    assert mechanics._power_weights(mids[:1], stiff[:1], ends[:2]).tolist() == [1.0]  # one step: the midpoint rule


def test_the_power_quadrature_converges_faster_and_moves_the_gel_as_far():
    got = {(n, q): _oblique_on_a_mini("ring", steps=n, quadrature=q) for n in (2, 8) for q in mechanics.QUADRATURES}
    off = {k: np.hypot(*(v.force - got[8, "power"].force)) / np.hypot(*got[8, "power"].force) for k, v in got.items()}
    # measured against 16 power steps: 10.5% (midpoint) and 1.5% (power) at 2 steps, 0.5% at 4 with the power law
    assert off[2, "power"] < 0.03 < off[2, "midpoint"]
    np.testing.assert_array_equal(got[2, "power"].disp_mm, got[2, "midpoint"].disp_mm)  # the held gel: the move's
    with pytest.raises(ValueError, match="quadrature must be one of"):
        _oblique_on_a_mini("ring", quadrature="simpson")


def test_press_takes_the_oblique_path():
    s = sim.press("sphere_small", "mini-1", (0.0, 0.0, 6.0), tilt_deg=(6.0, 0.0), size=(24, 32), noise=False,
                  path="oblique")
    assert s.meta["path"] == "oblique" and s.force[2] == pytest.approx(6.0)
    assert 0.2 * 6.0 * np.tan(np.radians(6.0)) < s.force[0] < 6.0 * np.tan(np.radians(6.0))
    assert abs(s.force[1]) < 0.05 * s.force[0]
    flat = sim.press("sphere_small", "mini-1", (0.0, 0.0, 6.0), size=(24, 32), noise=False, path="oblique")
    assert not flat.force[:2].any()  # untilted: pressed straight down
    with pytest.raises(ValueError, match="request \\(0, 0, Fz\\)"):
        sim.press("sphere_small", "mini-1", (1.0, 0.0, 6.0), tilt_deg=(6.0, 0.0), size=(24, 32), path="oblique")
    with pytest.raises(ValueError, match="path must be one of"):
        sim.press("sphere_small", "mini-1", (0.0, 0.0, 6.0), size=(24, 32), path="tilted")
