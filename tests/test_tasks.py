"""Downstream tasks: the push force model, exact weighing with a perfect sensor, the gripper's stopping
rule, and the experiment CLI end to end at the smoke preset."""

from __future__ import annotations

import numpy as np
import pytest

from ffjax.tasks import grasping, pushing

OBJ = pushing.OBJECTS[0]


def test_push_force_model_recovered_from_true_force():
    cfg = pushing.PushConfig(duration_s=6.0, fps=50.0).ideal()
    p = pushing.simulate_push(OBJ, cfg, seed=3)
    moving = p.phase > 0
    expected = OBJ.mass_kg * p.accel + OBJ.mu * OBJ.mass_kg * pushing.G
    np.testing.assert_allclose(p.force[moving, 2], expected[moving], rtol=1e-5)
    assert p.accel[p.phase == 1].max() > 0 and np.all(p.accel[p.constant] == 0)
    np.testing.assert_allclose(p.velocity[p.constant], cfg.velocity_mm_s / 1000)
    # f_p = m dv/dt + mu m g: a line in dv/dt whose slope is m and whose intercept is mu m g
    slope, intercept = np.polyfit(p.accel[moving], p.force[moving, 2].astype(np.float64), 1)
    assert slope == pytest.approx(OBJ.mass_kg, rel=1e-3)
    assert intercept / (OBJ.mass_kg * pushing.G) == pytest.approx(OBJ.mu, rel=1e-4)
    # the static load phase peaks at breakaway, above the sliding force
    assert p.force[p.phase == 0, 2].max() > expected[p.constant].mean()


def test_vertical_shear_raises_the_push_force():
    assert pushing.push_force(1.0, 0.3, 0.0, eps=0.1) == pytest.approx(0.3 * pushing.G / 0.97)


def test_mass_exact_with_perfect_force_sensors():
    """Perfect tactile estimate and an ideal reference: weighing recovers the mass exactly, even on a rough
    table with shear coupling (mu is fitted from the same force)."""
    cfg = pushing.PushConfig(
        duration_s=8.0, fps=10.0, drift_n_per_s=(0.0, 0.0), ref_noise_n=0.0, ref_resolution_n=0.0
    )
    for obj in pushing.OBJECTS:
        pushes = [pushing.simulate_push(obj, cfg, seed=k) for k in range(3)]
        row = pushing.weigh(pushes, [p.force[:, 2] for p in pushes])
        assert row["mass_est"] == pytest.approx(obj.mass_kg, rel=1e-6)  # float32 frames
        assert row["force_error"] == pytest.approx(0.0, abs=1e-6)


def test_reference_drift_grows_with_push_duration():
    cfg = pushing.PushConfig(duration_s=30.0, fps=5.0, ref_noise_n=0.0)
    pushes = [pushing.simulate_push(OBJ, cfg, seed=k) for k in range(3)]
    est = [p.force[:, 2] for p in pushes]
    short, long = (pushing.weigh(pushes, est, duration_s=T) for T in (5.0, 30.0))
    assert 0 < short["reference_bias"] < long["reference_bias"]
    assert short["weight_error"] < long["weight_error"]


def test_weigh_refuses_pushes_without_constant_phase():
    p = pushing.simulate_push(OBJ, pushing.PushConfig(duration_s=1.0, fps=10.0), seed=0)
    with pytest.raises(ValueError, match="constant-velocity"):
        pushing.weigh([p], [p.force[:, 2]])


def test_close_until_rules():
    read = lambda k: 0.3 * k  # noqa: E731
    assert grasping.close_until(read, 1.0, "reach").stop_step == 4
    assert grasping.close_until(read, 1.0, "below").stop_step == 3
    assert grasping.close_until(read, 1.0, "closest").stop_step == 3  # 0.9 is closer than 1.2
    res = grasping.close_until(read, 100.0, "reach", max_steps=5)
    assert not res.reached and res.stop_step == 5
    with pytest.raises(ValueError):
        grasping.close_until(read, 1.0, "never")


@pytest.mark.parametrize("obj", [grasping.CUP, grasping.FRUITS[3]], ids=lambda o: o.name)
def test_gripper_stops_at_or_just_past_target_with_true_force(obj):
    cfg = grasping.GripperConfig()
    for seed in range(2):
        trial = grasping.GraspTrial(obj, cfg, seed=seed, size=(24, 32))
        forces = [trial.force(k) for k in range(1, 60)]
        assert np.all(np.diff(forces) > 0), "closing further must squeeze harder"
        for target in (0.5, 1.74, 2.1):
            out = grasping.run_grasp(trial, target, "reach", grasping.truth_reader(trial))
            assert out["reached"]
            assert 0 <= out["overshoot_n"] <= out["step_increment_n"] + 1e-9
            below = grasping.run_grasp(trial, target, "below", grasping.truth_reader(trial))
            assert below["force"] < target and below["stop_step"] == out["stop_step"] - 1
        # deformation is the object's own share of the closure
        k = 20
        assert trial.deformation_pct(k) == pytest.approx(
            100 * trial.force(k) / obj.stiffness_n_per_mm / obj.diameter_mm
        )
        assert trial.force(k) / obj.stiffness_n_per_mm < trial.closure(k)  # the gels take up the rest


def test_cup_stiffness_from_ring_theory():
    # Roark: diametral deflection of a thin ring 0.1488 F R^3 / (E I)
    k = grasping.ring_stiffness(3000.0, 1.0, 40.0)
    assert k == pytest.approx(3000.0 / (0.14878 * 40.0**3), rel=1e-3)
    for f in grasping.FRUITS:
        assert 0 < f.gentle_n < f.firm_n


def test_model_sensor_says_a_background_warning_once_per_message():
    """The gripper's two jaws are two sensor units; the one unlike the training sensor used to warn at every
    call (719 warnings in one quick downstream run)."""
    import warnings

    from _smoke_run import smoke_run

    from ffjax.inference import BackgroundWarning
    from ffjax.tasks.sensing import ModelSensor

    sensor = ModelSensor(smoke_run())
    h, w = sensor.frame_size
    odd = np.full((h, w, 3), 250, np.uint8)  # a saturated background: not the training sensor's
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        for _ in range(3):
            assert sensor(odd[None], odd).shape == (1, 3)
    assert len([x for x in said if issubclass(x.category, BackgroundWarning)]) == 1
