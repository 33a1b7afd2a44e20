"""The windowed layer solves (ffjax.sim.batched.windows): a solve kept to a region of the grid, run on a small window
with the grid's own kernels at every offset inside the region, is the whole grid's solve to round-off."""

import numpy as np
import pytest

from ffjax import sim
from ffjax.sim import batched, mechanics
from ffjax.sim import elastic_layer as el


def _layer():
    return el.Layer((90, 100), 0.25, 4.5, 0.15)  # the Mini's gel: t = 18 cells, wider than most contacts


def _blob(shape, cy, cx, ry, rx):
    y, x = np.mgrid[: shape[0], : shape[1]]
    return ((y - cy) / ry) ** 2 + ((x - cx) / rx) ** 2 <= 1.0


def test_windows_hold_the_region_and_fold_nothing_onto_it():
    masks = np.stack([_blob((90, 100), 45, 50, 4, 9), _blob((90, 100), 3, 97, 2, 2), np.ones((90, 100), bool)])
    w = batched.windows(masks, margin=2)
    y0, x0, h, wd, side = w[0]
    assert (y0, x0, h, wd) == (39, 39, 13, 23)  # the bounding box grown by 2 cells
    assert side == 48 and side >= 2 * max(h, wd) - 1  # the smallest side that holds twice the extent
    assert tuple(w[1][:4]) == (0, 93, 8, 7)  # clipped to the grid at its edges
    assert w[2][4] == 0  # a region as wide as the grid: the whole grid


def test_aperiodic_kernel_is_the_grid_kernel_on_the_region():
    layer = _layer()
    mask = _blob(layer.shape, 40, 30, 6, 10)
    w = batched.windows(mask[None])[0]
    rng = np.random.default_rng(0)
    p = np.where(mask, rng.random(layer.shape), 0.0)
    whole = layer.apply(p)[batched._region(w)]
    small = np.zeros((w[4], w[4]))
    small[: w[2], : w[3]] = p[batched._region(w)]
    win = np.fft.irfft2(batched._aperiodic(layer.kernel, layer.shape, int(w[4]), False) * np.fft.rfft2(small),
                        s=small.shape)[: w[2], : w[3]]
    assert np.abs(win - whole).max() < 1e-6 * np.abs(whole).max()


@pytest.mark.parametrize("depth", [0.0, 1.0])
def test_windowed_stick_is_the_whole_grid_stick(depth):
    layer = _layer()
    held = np.stack([_blob(layer.shape, 45, 50, 5, 8), _blob(layer.shape, 30, 60, 3, 3)])
    force = np.array([[0.3, -0.1], [0.0, 0.2]])
    depths = [depth, 0.5]
    whole = batched.stick(held, force, layer, depths)
    win = batched.stick(held, force, layer, depths, windows=batched.windows(held))
    assert (batched.windows(held)[:, 4] > 0).all()  # both solved on windows
    assert np.allclose(win["s"], whole["s"], rtol=1e-3)
    scale = np.abs(whole["fields"]).max()
    assert np.abs(win["fields"] - whole["fields"]).max() < 1e-3 * scale


def test_record_solves_lists_each_press_of_each_solve_with_its_window_and_iterations():
    layer = _layer()
    held = np.stack([_blob(layer.shape, 45, 50, 5, 8), _blob(layer.shape, 30, 60, 3, 3)])
    wins = batched.windows(held)
    with batched.record_solves() as seen:
        r = batched.stick(held, np.array([[0.3, -0.1], [0.0, 0.2]]), layer, windows=wins)
        with batched.record_solves() as inner:  # a nested block records apart and gives the outer one back
            batched.stick(held[:1], np.array([[0.1, 0.0]]), layer)
        batched.stick(held[1:], np.array([[0.0, 0.1]]), layer)
    assert seen == [("stick", int(wins[0, 4]), layer.shape, int(r["iterations"][0])),
                    ("stick", int(wins[1, 4]), layer.shape, int(r["iterations"][1])),
                    ("stick", 0, layer.shape, seen[2][3])]
    assert [k[:3] for k in inner] == [("stick", 0, layer.shape)] and inner[0][3] >= 1
    assert batched._RECORD is None


def test_windowed_normal_is_the_whole_grid_normal():
    layer = _layer()
    y, x = np.mgrid[:90, :100]
    hb = np.stack([((y - 45.0) ** 2 + (x - 50.0) ** 2) * layer.dx**2 / 8.0,  # a 4 mm sphere
                   np.abs(x - 40.0) * layer.dx * 0.3 + ((y - 50.0) * layer.dx) ** 2 / 20])  # a tilted cylinder
    pad = (abs(y - 45) < 25) & (abs(x - 50) < 30)  # the pad, free gel around it (as mechanics pads its grid)
    hb = np.where(pad, hb, el.FAR)
    fz = np.array([2.0, 1.0])
    args = (hb, fz, layer, layer.thickness, mechanics._EPS, mechanics._PSI)
    whole = batched.normal(*args)
    win = batched.normal(*args, windows=batched.windows(whole["p"] > 0, margin=2))
    assert np.allclose(win["delta"], whole["delta"], rtol=0, atol=1e-6)  # mm: the tolerance of the solve
    assert ((win["p"] > 0) == (whole["p"] > 0)).mean() > 0.999
    assert np.abs(win["u"] - whole["u"]).max() < 1e-5


def test_oblique_press_solves_lighter_presses_inside_the_final_contact():
    # the path's lighter presses each lie inside the final contact (nested contacts): their windowed solves give
    # the same press as solving them on the whole grid
    sensor = sim.get_sensor("mini-1-gel1")
    a = sim.press("sphere_small", sensor, (0, 0, 6.0), tilt_deg=(8.0, -3.0), size=(24, 32), path="oblique")
    before = mechanics.NESTED_MARGIN_PX
    try:
        mechanics.NESTED_MARGIN_PX = 10**6  # every region the whole pad: the whole grid
        b = sim.press("sphere_small", sensor, (0, 0, 6.0), tilt_deg=(8.0, -3.0), size=(24, 32), path="oblique")
    finally:
        mechanics.NESTED_MARGIN_PX = before
    assert np.allclose(a.force, b.force, rtol=1e-3, atol=1e-4)
    assert np.abs(a.depth - b.depth).max() < 1e-3  # mm
    assert np.abs(a.image.astype(int) - b.image).max() <= 1


def test_a_press_touching_beyond_its_reach_is_solved_again_on_the_whole_grid(monkeypatch):
    sensor = sim.get_sensor("mini-1-gel1")
    press = dict(shape="sphere_small", sensor=sensor, force=(0, 0, 6.0), size=(24, 32))
    whole = sim.press(**press)
    monkeypatch.setattr(mechanics, "REACH", 1e-9)  # the window holds the lowest cell only: the check must catch it
    again = sim.press(**press)
    assert np.abs(again.depth - whole.depth).max() < 1e-6
    assert abs(again.meta["penetration_mm"] - whole.meta["penetration_mm"]) < 1e-5  # mm: within the solve's tolerance
