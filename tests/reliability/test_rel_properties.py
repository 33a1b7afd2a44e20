"""Property-based tests (hypothesis) over the simulator's and the data pipeline's inputs.

Few, small examples (tiny frames) so the file stays fast on 2 cores; `--hypothesis-seed` reproduces a run.
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from ffjax import data, sim
from ffjax.data import validate
from ffjax.sim import optics

FAST = settings(max_examples=20, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
SIZE = (24, 32)  # the smoke preset's frame; at 12x16 a 2 mm bar (cross, ring) can fall between pixels
SENSORS = ("mini-1", "mini-3", "digit")

forces = st.tuples(st.floats(-3, 3), st.floats(-3, 3), st.floats(0, 8))
unit = st.floats(-0.3, 0.3)  # fraction of the pad, where every indenter still reaches it
tilts = st.tuples(st.floats(-5, 5), st.floats(-5, 5))


def _pose(sensor, fx, fy):
    fh, fw = sim.get_sensor(sensor).fov_mm
    return fx * fw, fy * fh


@FAST
@given(shape=st.sampled_from(sorted(sim.INDENTERS)), sensor=st.sampled_from(SENSORS), force=forces, px=unit,
       py=unit, yaw=st.floats(0, 360), tilt=tilts, seed=st.integers(0, 2**31 - 1))
def test_press_outputs_are_well_formed(shape, sensor, force, px, py, yaw, tilt, seed):
    x, y = _pose(sensor, px, py)
    try:
        s = sim.press(shape, sensor, force, x, y, yaw, tilt, seed, SIZE)
    except ValueError as e:  # a body that cannot reach the pad at this pose, or a force the gel cannot take
        assert "reach the pad" in str(e) or "beyond what this gel takes" in str(e)
        return
    assert s.image.shape == (*SIZE, 3) and s.image.dtype == np.uint8
    assert s.background.shape == (*SIZE, 3) and s.background.dtype == np.uint8
    assert s.depth.shape == SIZE and s.depth.dtype == np.float32 and np.isfinite(s.depth).all()
    assert s.force.shape == (3,) and s.force.dtype == np.float32 and np.isfinite(s.force).all()
    assert s.force[2] == np.float32(force[2])  # Fz is honoured exactly
    mu = sim.get_sensor(sensor).gel.friction
    assert math.hypot(s.force[0], s.force[1]) <= mu * force[2] * (1 + 1e-5) + 1e-6  # Coulomb cap
    assert s.meta["penetration_mm"] >= 0 and s.meta["contact_area_mm2"] >= 0
    if force[2] > 0.05:
        assert s.depth.max() > 0  # pressing moves the gel in somewhere


@pytest.mark.parametrize("fz", [5e-324, 1e-300, 1e-10])
def test_a_vanishing_normal_force_is_no_contact(fz):
    """Found by the property test above: a subnormal Fz (5e-324 N) spread over a cone underflowed the pressure
    to 0 and the depth came out NaN. Below a nanonewton a press is no contact."""
    x, y = _pose("mini-1", 0.0662, 7e-110)
    s = sim.press("cone", "mini-1", (-0.0607, 0.006, fz), x, y, 165.98, (0.0, 0.0), 0, SIZE)
    assert np.isfinite(s.depth).all() and np.abs(s.depth).max() == 0


@FAST
@given(shape=st.sampled_from(sorted(sim.INDENTERS)), sensor=st.sampled_from(SENSORS),
       shear=st.tuples(st.floats(-5, 5), st.floats(-5, 5)))
def test_zero_normal_force_leaves_the_gel_untouched(shape, sensor, shear):
    """Fz = 0: no penetration, so no shear can be carried either; the frame is the background."""
    s = sim.press(shape, sensor, (*shear, 0.0), size=SIZE, noise=False)
    assert s.force[2] == 0 and np.abs(s.force).max() <= 1e-9  # the slip test's tolerance: |F_t| <= cap + 1e-9
    assert np.abs(s.depth).max() == 0
    np.testing.assert_array_equal(s.image, sim.get_sensor(sensor).background(SIZE, noise=False))


@FAST
@given(shape=st.sampled_from(sorted(sim.INDENTERS)), f1=st.floats(0.1, 6), f2=st.floats(0.1, 6))
def test_more_normal_force_presses_deeper(shape, f1, f2):
    lo, hi = sorted((f1, f2))
    p = [sim.press(shape, "mini-1", (0, 0, f), size=SIZE, noise=False).meta["penetration_mm"] for f in (lo, hi)]
    assert p[0] <= p[1] + 1e-9


@settings(max_examples=8, deadline=None, database=None)
@given(shape=st.sampled_from(sorted(sim.INDENTERS)),
       fs=st.lists(forces, min_size=1, max_size=2), seed=st.integers(0, 1000))
def test_press_batch_matches_press(shape, fs, seed):
    seeds = [seed + i for i in range(len(fs))]
    b = sim.press_batch(shape, "mini-2", fs, seeds=seeds, size=SIZE)
    for i, f in enumerate(fs):
        s = sim.press(shape, "mini-2", f, seed=seeds[i], size=SIZE)
        assert np.abs(b["image"][i].astype(int) - s.image).max() <= 1  # batch of 1 vs 2: last float digits
        np.testing.assert_array_equal(b["force"][i], s.force)


bad_number = st.sampled_from([math.nan, math.inf, -math.inf])


@st.composite
def bad_press_args(draw):
    """One invalid argument among otherwise valid ones, and what the error must mention."""
    args = {"force": (0.0, 0.0, 2.0), "x_mm": 0.0, "y_mm": 0.0, "yaw_deg": 0.0, "tilt_deg": (0.0, 0.0),
            "seed": 0, "size": SIZE}
    kind = draw(st.sampled_from(["nonfinite", "negative_fz", "outside", "tilt", "size", "seed", "force_len"]))
    if kind == "nonfinite":
        key = draw(st.sampled_from(["force", "x_mm", "y_mm", "yaw_deg", "tilt_deg"]))
        if key in ("force", "tilt_deg"):
            v = list(args[key])
            v[draw(st.integers(0, len(v) - 1))] = draw(bad_number)
            args[key] = tuple(v)
        else:
            args[key] = draw(bad_number)
    elif kind == "negative_fz":
        args["force"] = (0.0, 0.0, -draw(st.floats(1e-6, 100)))
    elif kind == "outside":
        args[draw(st.sampled_from(["x_mm", "y_mm"]))] = draw(st.sampled_from([-1, 1])) * draw(st.floats(30, 1e6))
    elif kind == "tilt":
        args["tilt_deg"] = (draw(st.floats(15.01, 89)), 0.0)
    elif kind == "size":
        args["size"] = draw(st.sampled_from([(0, 5), (-3, 4), (1, 1), (12.5, 16), (12,), "big"]))
    elif kind == "seed":
        args["seed"] = draw(st.sampled_from([-1, 2.5, None, "a"]))
    else:
        args["force"] = tuple(draw(st.lists(st.floats(0, 1), min_size=0, max_size=5).filter(lambda v: len(v) != 3)))
    return args


@FAST
@given(args=bad_press_args(), shape=st.sampled_from(["sphere_big", "cube"]), sensor=st.sampled_from(SENSORS))
def test_invalid_press_inputs_raise_value_error(args, shape, sensor):
    with pytest.raises(ValueError):
        sim.press(shape, sensor, **args)


@FAST
@given(n=st.integers(1, 3), m=st.integers(1, 3))
def test_press_batch_rejects_mismatched_lengths(n, m):
    fs = np.tile([0.0, 0.0, 1.0], (n, 1))
    if n == m:
        assert len(sim.press_batch("sphere_big", "mini-1", fs, x_mm=np.zeros(m), size=SIZE)["image"]) == n
    else:
        with pytest.raises(ValueError, match="one value per force"):
            sim.press_batch("sphere_big", "mini-1", fs, x_mm=np.zeros(m), size=SIZE)


@FAST
@given(h=st.integers(2, 20), w=st.integers(2, 20), bad=st.sampled_from(["nan", "shape"]))
def test_render_rejects_bad_depth(h, w, bad):
    depth = np.zeros((h, w), np.float32)
    if bad == "nan":
        depth[h // 2, w // 2] = np.nan
    else:
        depth = np.zeros((h + 1, w), np.float32)
    with pytest.raises(ValueError, match="depth must be finite"):
        optics.render(sim.get_sensor("mini-1"), (h, w), depth)


# --- the data pipeline

STATS = data.Stats(mean=(0.5, 0.5, 0.5), std=(0.25, 0.25, 0.25), depth_min=-0.1, depth_max=2.0,
                   force_min=(0, 0, 0), force_max=(1, 1, 1), input_size=8)


@st.composite
def frames(draw, batch=False):
    h, w = draw(st.integers(1, 24)), draw(st.integers(1, 24))
    shape = (draw(st.integers(0, 3)), h, w, 3) if batch else (h, w, 3)
    img = draw(hnp.arrays(np.uint8, shape, elements=st.integers(0, 255)))
    bg = draw(hnp.arrays(np.uint8, (h, w, 3), elements=st.integers(0, 255)))
    return img, bg


@FAST
@given(fb=frames(), size=st.integers(1, 20))
def test_preprocess_image_shape_dtype_range(fb, size):
    img, bg = fb
    u = data.to_unit(img, bg, size)
    assert u.shape == (size, size, 3) and u.dtype == np.float32
    assert u.min() >= 0 and u.max() <= 1 + 1e-6
    x = data.preprocess_image(img, bg, STATS, size)
    np.testing.assert_allclose(x, (u - 0.5) / 0.25, rtol=1e-6, atol=1e-6)


@FAST
@given(fb=frames(batch=True), size=st.integers(1, 12))
def test_preprocess_batched_equals_per_frame(fb, size):
    imgs, bg = fb
    x = data.preprocess_image(imgs, bg, STATS, size)
    assert x.shape == (len(imgs), size, size, 3) and x.dtype == np.float32
    for i in range(len(imgs)):
        np.testing.assert_array_equal(x[i], data.preprocess_image(imgs[i], bg, STATS, size))


@FAST
@given(h=st.integers(1, 10), w=st.integers(1, 10), dtype=st.sampled_from([np.int8, np.uint16, np.float32, np.float64,
                                                                           np.bool_]))
def test_preprocess_image_rejects_non_uint8_and_size_mismatch(h, w, dtype):
    bg = np.zeros((h, w, 3), np.uint8)
    with pytest.raises(TypeError, match="uint8"):
        data.preprocess_image(np.zeros((h, w, 3), dtype), bg, STATS, 8)
    with pytest.raises(ValueError, match="differ in size"):
        data.preprocess_image(np.zeros((h + 1, w, 3), np.uint8), bg, STATS, 8)


@FAST
@given(depth=hnp.arrays(st.sampled_from([np.float16, np.float32, np.float64, np.int16]),
                        st.tuples(st.integers(1, 20), st.integers(1, 20)),
                        elements=st.integers(-5, 5)),
       size=st.integers(1, 16), lo=st.floats(-2, 2), span=st.floats(0, 5))
def test_preprocess_depth_is_in_unit_range(depth, size, lo, span):
    stats = data.Stats.from_dict({**STATS.to_dict(), "depth_min": lo, "depth_max": lo + span})
    d = data.preprocess_depth(depth, stats, size)
    assert d.shape == (size, size) and d.dtype == np.float32
    assert np.isfinite(d).all() and d.min() >= 0 and d.max() <= 1


class ArraySource:
    """The smallest source Stats.compute reads: len, read_range, background, forces."""

    def __init__(self, images, background, depth, forces):
        self.images, self.background, self.depth, self.forces = images, background, depth, forces

    def __len__(self):
        return len(self.images)

    def read_range(self, a, b):
        return {"image": self.images[a:b], "depth": self.depth[a:b], "force": self.forces[a:b]}


@st.composite
def sources(draw):
    n, h, w = draw(st.integers(1, 6)), draw(st.integers(2, 10)), draw(st.integers(2, 10))
    img = draw(hnp.arrays(np.uint8, (n, h, w, 3), elements=st.integers(0, 255)))
    bg = draw(hnp.arrays(np.uint8, (h, w, 3), elements=st.integers(0, 255)))
    depth = draw(hnp.arrays(np.float32, (n, h, w), elements=st.floats(-1, 3, width=32)))
    force = draw(hnp.arrays(np.float32, (n, 3), elements=st.floats(-20, 20, width=32)))
    return ArraySource(img, bg, depth, force)


@FAST
@given(src=sources(), size=st.integers(1, 12), eps=st.sampled_from([0.0, 0.05]), chunk=st.integers(1, 4))
def test_stats_are_finite_ordered_and_round_trip(src, size, eps, chunk):
    s = data.Stats.compute(src, {"input_size": size, "depth_eps": eps}, chunk=chunk)
    assert all(np.isfinite(v) and v > 0 for v in s.std) and all(0 <= v <= 1 for v in s.mean)
    assert s.depth_min <= s.depth_max and all(a <= b for a, b in zip(s.force_min, s.force_max))
    assert s.count == len(src) and s.input_size == size
    assert data.Stats.from_dict(s.to_dict()) == s
    d = data.preprocess_depth(src.depth[0], s, size)
    assert np.isfinite(d).all()


@FAST
@given(key=st.text(min_size=1, max_size=8).filter(lambda k: k not in STATS.to_dict()))
def test_stats_from_dict_rejects_unknown_keys(key):
    with pytest.raises(ValueError, match="unknown Stats keys"):
        data.Stats.from_dict({**STATS.to_dict(), key: 1})


# --- FT cells of the release CSV

finite32 = st.floats(-1e6, 1e6, allow_nan=False, width=32)


plausible32 = st.floats(-validate.FORCE_LIMIT_N, validate.FORCE_LIMIT_N, width=32)  # a force a sensor can take


@FAST
@given(values=st.one_of(st.lists(plausible32, min_size=3, max_size=3),
                        st.tuples(st.lists(plausible32, min_size=3, max_size=3),
                                  st.lists(finite32, min_size=3, max_size=3)).map(lambda t: t[0] + t[1])),
       sep=st.sampled_from([" ", "  ", ", ", ",", "\t"]), fmt=st.sampled_from(["{:.9g}", "{!r}", "{:.3e}"]),
       pad=st.sampled_from(["", " ", "  "]))
def test_ft_cells_parse(values, sep, fmt, pad):
    cell = pad + sep.join(fmt.format(v) for v in values) + pad
    force = data.csv_source.parse_ft(cell, "x.csv row 0 (line 2)")
    assert force.shape == (3,) and force.dtype == np.float32
    np.testing.assert_allclose(force, np.float32([float(fmt.format(v)) for v in values[:3]]), rtol=1e-6)


@FAST
@given(values=st.lists(plausible32, min_size=6, max_size=6), i=st.integers(0, 2),
       big=st.floats(validate.FORCE_LIMIT_N, 1e30, exclude_min=True), sign=st.sampled_from([1, -1]))
def test_ft_cells_beyond_the_plausible_force_are_refused_by_axis(values, i, big, sign):
    """Issue 33 (2): a force no tactile sensor takes is refused, naming its axis (torques are not bounded)."""
    parts = [f"{v:.9g}" for v in values]
    parts[i] = f"{sign * big:.9g}"
    if abs(float(parts[i])) <= validate.FORCE_LIMIT_N:  # rounded onto the bound
        return
    with pytest.raises(data.DataError, match=rf"^x\.csv line 9: FT cell .*{validate.FT_NAMES[i]} = .* N is beyond"):
        data.csv_source.parse_ft(" ".join(parts), "x.csv line 9")


@FAST
@given(values=st.lists(finite32, min_size=6, max_size=6), i=st.integers(0, 5),
       bad=st.sampled_from(["nan", "NaN", "inf", "-inf", "Infinity", "abc", "1..2", "--3"]))
def test_ft_cells_with_a_bad_value_are_refused_by_name(values, i, bad):
    parts = [f"{v:.9g}" for v in values]
    parts[i] = bad
    with pytest.raises(data.DataError, match=rf"^x\.csv line 9: FT cell .*{validate.FT_NAMES[i]}"):
        data.csv_source.parse_ft(" ".join(parts), "x.csv line 9")


@FAST
@given(cell=st.text(max_size=40))
def test_ft_cells_from_any_text_parse_or_raise_data_error(cell):
    try:
        force = data.csv_source.parse_ft(cell, "x.csv line 2")
    except data.DataError as e:
        assert str(e).startswith("x.csv line 2: FT cell")
    else:
        assert force.shape == (3,) and np.isfinite(force).all()
