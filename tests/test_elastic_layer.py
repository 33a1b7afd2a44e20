"""The elastic layer against closed forms, on both solvers: the numpy reference (ffjax.sim.elastic_layer) and the
batched JAX one the simulator runs (ffjax.sim.batched); and the layer check experiment."""

import numpy as np
import pytest

from ffjax.sim import batched
from ffjax.sim import elastic_layer as el

G = 0.15


def _batched_contact(h, layer, force):
    """batched.normal on the linear layer, in solve_contact's form."""
    r = batched.normal(h[None], np.array([force]), layer, layer.thickness, None, None)
    p, u = r["p"][0].astype(np.float64), r["u"][0].astype(np.float64)
    return {"p": p, "u": u, "delta": float(r["delta"][0]), "contact": p > 0, "iterations": int(r["iterations"][0])}


def _batched_stick(on, layer):
    """batched.stick under unit forces along x and y, in solve_stick's form: K (F = K s) and the fields of unit
    displacements (a displacement e_j is the force K[:, j], and the fields are linear in the force)."""
    r = batched.stick(np.stack([on, on]), np.eye(2), layer)
    K = np.linalg.inv(r["s"].T.astype(np.float64))
    return {"K": K, "fields": [K[0, j] * r["fields"][0] + K[1, j] * r["fields"][1] for j in range(2)]}


CONTACT = {"reference": el.solve_contact, "batched": _batched_contact}
STICK = {"reference": el.solve_stick, "batched": _batched_stick}


def _disc(a, t, dx, margin):
    n = int(np.ceil((2 * a + 2 * margin) / dx))
    n += n % 2
    x = (np.arange(n) - (n - 1) / 2) * dx
    X, Y = np.meshgrid(x, x)
    return np.where(np.hypot(X, Y) < a, 0.0, el.FAR), el.Layer((n, n), dx, t, G), X, Y


def test_compliance_limits_and_branches():
    t = 2.0
    k = np.array([1e-5, 50.0])
    c = el.compliance(k, t, G)
    assert c[0] == pytest.approx(k[0] ** 2 * t**3 / (3 * G), rel=1e-6)  # thin layer: lubrication
    assert c[1] == pytest.approx(1 / (2 * G * k[1]), rel=1e-9)  # thick: Boussinesq half-space
    assert el.compliance(np.array([0.0]), t, G)[0] == 0.0
    for x in (1e-3, 20.0):  # the series and the half-space branches meet the exact formula
        below, above = el.compliance(np.array([x * (1 - 1e-9), x * (1 + 1e-9)]) / t, t, G)
        assert below == pytest.approx(above, rel=1e-5)
    kk = np.linspace(1e-3, 30, 500)
    assert np.all(el.compliance(kk, t, G) <= 1 / (2 * G * kk) + 1e-12)  # the glass only stiffens the layer


@pytest.mark.parametrize("solver", CONTACT)
def test_flat_punch_between_half_space_and_thin_layer(solver):
    # a disc punch with a << t reads the half-space stiffness F = 8 G a delta, raised a little by the glass
    # (Hayes et al. 1972 give ~1.1 at a/t = 0.1 and ~1.2 at 0.2 for nu = 0.5)
    ratios = []
    for t in (10.0, 5.0):
        h, layer, _, _ = _disc(1.0, t, 0.1, 2 * t)
        r = CONTACT[solver](h, layer, 1.0)
        ratios.append(1.0 / (8 * G * 1.0 * r["delta"]))
    assert 1.0 < ratios[0] < 1.2 and ratios[0] < ratios[1] < 1.4
    # a >> t: the squeezed film, F = 3 pi G delta a^4 / (8 t^3), approached from above as a/t grows
    thin = []
    for a in (5.0, 10.0):
        h, layer, _, _ = _disc(a, 0.5, 0.25, 3.0)
        r = CONTACT[solver](h, layer, 1.0)
        thin.append(1.0 / (3 * np.pi * G * r["delta"] * a**4 / (8 * 0.5**3)))
    assert 1.0 < thin[1] < thin[0] < 2.0


@pytest.mark.parametrize("solver", CONTACT)
def test_sphere_contact_conditions(solver):
    dx, t, force = 0.1, 2.0, 2.0
    n = 160
    x = (np.arange(n) - (n - 1) / 2) * dx
    X, Y = np.meshgrid(x, x)
    h = (X**2 + Y**2) / (2 * 5.0)
    layer = el.Layer(h.shape, dx, t, G)
    r = CONTACT[solver](h, layer, force)
    p, u, d = r["p"], r["u"], r["delta"]
    gap = h + u - d
    assert r["iterations"] < 2000
    assert p.min() >= 0 and p.sum() * dx * dx == pytest.approx(force, rel=1e-9 if solver == "reference" else 1e-5)
    assert gap.min() > -2e-3 * d  # the sphere does not pass through the surface
    assert np.abs(gap[r["contact"]]).max() < 2e-3 * d  # and touches it wherever it pushes
    assert np.hypot(X, Y)[r["contact"]].max() < 0.3 * x.max()  # a compact contact, not the whole grid
    if solver == "batched":
        return
    with pytest.raises(ValueError, match="does not match"):
        el.solve_contact(h[:-1], layer, force)
    with pytest.raises(ValueError, match="force_n"):
        el.solve_contact(h, layer, 0.0)


def test_tangential_compliance_limits():
    t = 2.0
    k = np.array([0.0, 1e-5, 50.0])
    cl, ct, cn = el.tangential_compliance(k, t, G)
    assert cl[:2] == pytest.approx([t / G, t / G], rel=1e-6) and ct[:2] == pytest.approx([t / G, t / G], rel=1e-6)
    assert cl[2] == pytest.approx(1 / (2 * G * k[2]), rel=1e-9)  # Cerruti's half-space at nu = 0.5
    assert ct[2] == pytest.approx(1 / (G * k[2]), rel=1e-9)
    assert cn[0] == 0 and cn[2] < 1e-12  # the coupling needs the glass at a finite depth
    for x in (1e-3, 20.0):  # branches meet the exact formula
        below, above = el.tangential_compliance(np.array([x * (1 - 1e-9), x * (1 + 1e-9)]) / t, t, G)[0]
        assert below == pytest.approx(above, rel=1e-5)


@pytest.mark.parametrize("solver", STICK)
def test_stuck_disc_between_half_space_and_thin_film(solver):
    # a << t: Mindlin's rigid disc in stick on a half-space, F = 8 G a s / (2 - nu) = 16 G a s / 3, raised a
    # little by the glass; a >> t: the film in simple shear, F = G pi a^2 s / t, plus an edge term ~ t / a
    c, layer, _, _ = _disc(1.0, 10.0, 0.1, 20.0)
    ratio = STICK[solver](c < el.FAR / 2, layer)["K"][0, 0] / (16 * G * 1.0 / 3)
    assert 1.0 < ratio < 1.1
    thin = []
    for a in (4.0, 8.0):
        c, layer, _, _ = _disc(a, 1.0, 0.25, 4.0)
        thin.append(STICK[solver](c < el.FAR / 2, layer)["K"][0, 0] / (G * np.pi * a * a / 1.0))
    assert 1.0 < thin[1] < thin[0] < 1.5
    assert (thin[0] - 1) / (thin[1] - 1) == pytest.approx(2.0, rel=0.1)  # the edge term halves as a doubles


@pytest.mark.parametrize("solver", STICK)
def test_stick_holds_the_gel_on_the_body_and_raises_it_ahead(solver):
    h, layer, X, Y = _disc(2.0, 4.0, 0.2, 8.0)
    on = h < el.FAR / 2
    r = STICK[solver](on, layer)
    K = r["K"]
    assert K[0, 0] == pytest.approx(K[1, 1], rel=1e-3) and abs(K[0, 1]) < 1e-3 * K[0, 0]  # round: isotropic
    ux, uy, depth = r["fields"][0]
    assert np.abs(ux[on] - 1).max() < 1e-3 and np.abs(uy[on]).max() < 1e-3  # moves with the body
    assert np.ptp(depth[on]) < 1e-3  # the body holds the surface: it only shifts as a whole
    ahead, behind = (np.abs(Y) < 0.3) & (X > 2.5) & (X < 5), (np.abs(Y) < 0.3) & (X < -2.5) & (X > -5)
    assert depth[ahead].mean() < 0 < depth[behind].mean()  # the gel rises ahead of the motion, sinks behind
    far = np.hypot(X, Y) > 8
    assert np.abs(ux[far]).max() < 0.2  # the drag decays away from the contact
    if solver == "batched":
        return
    with pytest.raises(ValueError, match="no contact"):
        el.solve_stick(np.zeros_like(on), layer)


def test_a_textured_face_holds_the_gel_like_a_smooth_one():
    """Asperities at a pitch well under the gel's thickness pin the gel across the whole face: the knurled
    14 mm cube and a smooth face of the same size resist shear alike, though the knurl touches less of it. On the
    finest solve grid (a native frame's): a coarser one blurs the knurl's tips into a face (docs/simulator.md's
    discretization table)."""
    from ffjax import sim
    from ffjax.sim.shapes import MAP_MM_PER_PX, Shape, _grid, _rounded

    X, Y = _grid()
    smooth = Shape(_rounded(np.minimum(7 - np.abs(X), 7 - np.abs(Y)), 0.5), MAP_MM_PER_PX, name="smooth_14mm")
    knurl, flat = (sim.press(s, "mini-1", (0.5, 0.0, 3.0), size=(240, 320), noise=False).meta
                   for s in (sim.shapes.flat_punch(14.0), smooth))
    assert knurl["contact_area_mm2"] < 0.6 * flat["contact_area_mm2"]
    assert knurl["shear_stiffness_n_per_mm"] == pytest.approx(flat["shear_stiffness_n_per_mm"], rel=0.1)


def test_layer_check_smoke(tmp_path):
    from experiments.diagnostics import layer_check

    r = layer_check.main(["--preset", "smoke", "--out", str(tmp_path), "--quiet"])
    for f in ("results.json", "layer_check.md", "layer_check.png"):
        assert (tmp_path / f).stat().st_size > 0
    rows = [w for v in r["shapes"].values() for w in v["rows"]]
    assert rows and all(w["delta_sim"] > 0 and w["delta_ref"] > 0 and w["area_ref"] > 0 for w in rows)
    assert all(w["sens_train_sim"] > 0 and w["sens_train_ref"] > 0 for w in rows)
    # the incompressible layer pushes gel up around a flat face; independent columns cannot
    flat = r["shapes"]["flat_14mm"]["rows"][0]
    assert flat["bulge_ref"] > 0.05 and flat["sink_band_ref"] > 0
