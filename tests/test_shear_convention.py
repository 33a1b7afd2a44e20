"""Shear label convention end to end: the force written as the label and the shear seen in the model's input
agree in axis and sign (+Fx moves the gel towards +x = columns, +Fy towards +y = rows, down), for a
landscape sensor (padded along y) and a portrait one (padded along x); the preprocessing keeps both axes at
the same scale. Noiseless renders, well under a second."""

import numpy as np
import pytest

from ffjax import sim
from ffjax.data import preprocess
from ffjax.sim import optics
from ffjax.sim.dataset import render_size
from ffjax.sim.sensors import with_markers

FZ = 5.0


def _shift(a0, a1):
    """Global translation (sx, sy) in px with a1(p) ~ a0(p - s), least squares on the gradients of all channels."""
    gy, gx = np.gradient(a0, axis=(0, 1))
    return np.linalg.lstsq(np.stack([gx.ravel(), gy.ravel()], 1), -(a1 - a0).ravel(), rcond=None)[0]


def _unpadded(x, size):
    h, w = size
    pad = abs(w - h) * x.shape[0] // max(h, w) // 2
    return x[pad: x.shape[0] - pad] if h < w else x[:, pad: x.shape[1] - pad]


def test_pigment_moves_with_the_displacement():
    """optics.render: a uniform +1 px displacement along x (then y) moves the pigment +1 px along x (y)."""
    sensor = with_markers(sim.get_sensor("mini-1", gel=3))  # a strong texture to track
    size = (48, 64)
    flat = np.zeros(size, np.float32)
    base = optics.render(sensor, size, flat, None, None).astype(np.float32).mean(-1)
    for axis in (0, 1):
        disp = np.zeros(size + (2,), np.float32)
        disp[..., axis] = 1.0
        moved = optics.render(sensor, size, flat, disp, None).astype(np.float32).mean(-1)
        # moved(p) = base(p - e_axis): compare away from the borders
        ref = np.roll(base, 1, axis=1 - axis)
        inner = (slice(4, -4), slice(4, -4))
        assert np.abs(moved[inner] - ref[inner]).mean() < 0.25 * np.abs(moved[inner] - base[inner]).mean()


@pytest.mark.parametrize("key", ["mini-1-gel1", "mini-1-gel3", "digit"])
def test_label_axis_and_sign_match_the_image(key):
    sensor = sim.get_sensor(key)
    size = render_size(sensor, (48, 64))
    dy, dx = sensor.mm_per_px(size)
    assert dy == pytest.approx(dx, rel=1e-6)  # square pixels: padding then resizing squashes neither axis
    ball = sim.shapes.sphere(10.0)  # a compact round contact (the big sphere, 40 mm, presses a wide flat patch)
    s0 = sim.press(ball, sensor, (0, 0, FZ), size=size, noise=False)
    x0 = _unpadded(preprocess.to_unit(s0.image, s0.background, 64), size)
    for f, axis in (((1.0, 0.0), 0), ((-1.0, 0.0), 0), ((0.0, 1.0), 1), ((0.0, -1.0), 1)):
        s = sim.press(ball, sensor, (*f, FZ), size=size, noise=False)
        sign = np.sign(f[axis])
        np.testing.assert_allclose(s.force, [*f, FZ], atol=1e-6)  # the label is the applied force, (Fx, Fy, Fz)
        disp = s.meta["shear_disp_mm"]
        # across the push only what the stick solve leaves (it stops at an rms error of 1e-4 of the displacement)
        assert np.sign(disp[axis]) == sign and abs(disp[1 - axis]) < 1e-3 * abs(disp[axis])
        # the bulge rises in front of the motion: depth < 0 (out of the gel) on the +axis side for +F
        bulge = np.clip(-(s.depth - s0.depth), 0, None)
        coord = np.indices(bulge.shape)[1 - axis] - (bulge.shape[1 - axis] - 1) / 2
        assert np.sign((bulge * coord).sum()) == sign
        # and the model's input moves the same way along the same axis
        shift = _shift(x0, _unpadded(preprocess.to_unit(s.image, s.background, 64), size))
        assert np.sign(shift[axis]) == sign and abs(shift[axis]) > 3 * abs(shift[1 - axis])


def test_shear_probe_physics_report(tmp_path):
    """experiments.diagnostics.shear_probe (physics part) runs, finds the convention intact, writes its report."""
    from experiments.diagnostics import shear_probe

    res = shear_probe.main(["--out", str(tmp_path)])
    assert res["physics"]["sign_ok"]
    assert (tmp_path / "results.json").exists() and (tmp_path / "report.md").exists()
    rows = {(r["sensor"], r["leds"], r["source"], r["shape"]): r for r in res["physics"]["rows"]}
    # the pigment (marker) warp is isotropic: the x/y difference comes from the LED layout, not the pipeline
    assert 0.8 < rows[("mini-1-gel1", "as built", "pigment", "sphere_10mm")]["ratio_y_over_x"] < 1.25
    assert 0.8 < rows[("mini-1-gel1", "equal4", "all", "sphere_10mm")]["ratio_y_over_x"] < 1.25
    # the pigment's grain is finer than a 48x64 pixel: its share of a shear's image change grows with the render size
    for key in ("mini-1-gel1", "mini-1-gel2"):
        share = {tuple(r["size"]): r["pigment_share"] for r in res["physics"]["resolution"] if r["sensor"] == key}
        assert 0 < share[(48, 64)] < share[(240, 320)] < 1
    assert "pigment share" in (tmp_path / "report.md").read_text()


def test_low_force_physics(tmp_path):
    """experiments.diagnostics.low_force (physics part) at the smoke size: every load leaves a trace on the frame that
    grows with Fz, and the bound on Fz from one frame is finite; the report and figure are written."""
    from experiments.diagnostics import low_force

    res = low_force.main(["--preset", "smoke", "--out", str(tmp_path)])
    for body in low_force.BODIES:
        rows = [r for r in res["physics"] if r["body"] == body]
        assert [r["fz"] for r in rows] == list(low_force.LOADS_N)
        approach = [r["approach_mm"] for r in rows]
        assert all(a < b for a, b in zip(approach, approach[1:])) and rows[0]["change_max"] > 0
        assert all(0 < r["crb_n"] < np.inf for r in rows)
    assert (tmp_path / "low_force.png").stat().st_size > 0 and "Cramer-Rao" in (tmp_path / "low_force.md").read_text()
