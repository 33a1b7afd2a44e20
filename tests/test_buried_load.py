"""The body's hold on the gel at the depth of its pit: the layer's buried-load response against its closed forms
and limits, the batched solve against the numpy reference, and both against a finite-element model of the
pressed layer (experiments.diagnostics.buried_load_check, one coarse case)."""

import numpy as np
import pytest

from ffjax import sim
from ffjax.sim import batched, mechanics
from ffjax.sim import elastic_layer as el

T, G = 4.5, 0.15


def test_a_load_on_the_surface_is_the_closed_forms():
    k = np.geomspace(1e-2, 40.0, 60) / T
    at_depth, at_surface = el.buried_response(k, T, G, 0.0)
    cl, ct, cn = el.tangential_compliance(k, T, G)
    np.testing.assert_allclose(at_depth, at_surface)
    np.testing.assert_allclose(at_depth[:, 0, 0].real, cl, rtol=1e-9)
    np.testing.assert_allclose(at_depth[:, 1, 1].real, ct, rtol=1e-9)
    np.testing.assert_allclose(at_depth[:, 2, 2].real, el.compliance(k, T, G), rtol=1e-7)
    np.testing.assert_allclose(at_depth[:, 2, 0], 1j * cn, atol=1e-9 * cn.max())  # the surface rises ahead
    np.testing.assert_allclose(at_depth[:, 0, 2], -1j * cn, atol=1e-9 * cn.max())


@pytest.mark.parametrize("depth", [0.3, 1.5, 4.0])
def test_buried_load_limits_and_reciprocity(depth):
    k = np.concatenate([[0.0], np.geomspace(1e-3, 60.0, 80) / T, [30.0 / depth]])
    at_depth, at_surface = el.buried_response(k, T, G, depth)
    # Betti: the response on the loaded plane is Hermitian (and the stick solve's CG stays valid)
    np.testing.assert_allclose(at_depth, np.conj(np.swapaxes(at_depth, -1, -2)), atol=1e-12 * np.abs(at_depth).max())
    # a uniform tangential load shears the part below the plane and carries the part above with it
    assert at_depth[0, 0, 0].real == pytest.approx((T - depth) / G) == at_surface[0, 1, 1].real
    # a load under short waves (kd = 30) leaves the surface still (it decays as e^-kd); the plane itself moves
    assert np.abs(at_surface[-1]).max() < 1e-6 * np.abs(at_depth[-1]).max()
    with pytest.raises(ValueError, match="depth must be in"):
        el.buried_response(k, T, G, T)


def test_batched_held_stick_matches_the_reference():
    n, dx = 96, 0.25
    x = (np.arange(n) - n / 2) * dx
    X, Y = np.meshgrid(x, x)
    on = np.hypot(X, Y) < 2.0
    layer = el.Layer((n, n), dx, T, G)
    ref = el.solve_stick(on, layer, depth=0.6)
    r = batched.stick(np.stack([on, on]), [[1.0, 0.0], [1.0, 0.0]], layer, [0.6, 0.0])  # held at 0.6 mm, at 0
    s_x = r["s"][0]  # the body's displacement under 1 N along x: K^-1 e_x
    np.testing.assert_allclose(s_x, np.linalg.solve(ref["K"], [1.0, 0.0]), rtol=2e-3, atol=1e-4 * abs(s_x[0]))
    field = s_x[0] * ref["fields"][0] + s_x[1] * ref["fields"][1]
    assert np.abs(r["fields"][0] - field).max() < 2e-3 * np.abs(field).max()
    surface = el.solve_stick(on, layer)  # the hold at depth is stiffer than on the surface
    assert ref["K"][0, 0] > 1.05 * surface["K"][0, 0]
    assert r["s"][1, 0] > 1.05 * s_x[0]


def test_a_press_holds_at_its_pits_mean_depth():
    s = sim.press("sphere_small", "mini-1", (1.0, 0.0, 8.0), size=(24, 32), noise=False)
    depth = s.meta["hold_depth_mm"]
    assert 0 < depth < s.meta["penetration_mm"]
    assert depth / mechanics.HOLD_STEP_MM == pytest.approx(round(depth / mechanics.HOLD_STEP_MM))
    assert sim.press("sphere_small", "mini-1", (0.0, 0.0, 8.0), size=(24, 32)).meta["hold_depth_mm"] == 0.0


def test_the_layers_stick_against_finite_elements():
    from experiments.diagnostics import buried_load_check

    res = buried_load_check.run(smoke=True)
    (c,) = res["cases"]
    assert c["within_band"] and res["all_within_band"]
    # the FE's own check: on the flat mesh it is the surface-held layer solve (the closed forms' model)
    assert c["stiffness"]["model surface"] == pytest.approx(c["stiffness"]["FE flat"], rel=0.05)
    assert c["ratios"]["FE flat"]["rms"] == pytest.approx(c["ratios"]["model surface"]["rms"], rel=0.05)
    assert c["fe_contact_half_mm"] == pytest.approx(c["contact_half_mm"], abs=0.15)
    # holding the pit's walls stiffens the stick; the hold on the mean-depth plane gets part of it
    s = c["stiffness"]
    assert s["FE pressed"] > s["model held"] > s["model surface"]
