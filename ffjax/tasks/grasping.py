"""Grasping to a target force: a parallel gripper closes in discrete steps on a deformable object held
between two tactile sensors (one per jaw) until the estimated Fz of either sensor reaches a target.

Mechanics of one grasp: the jaws close by `step_mm` (total) per step. Past first contact the closure c
is taken up by the object (linear spring, c_obj = F / k) and by both gels (their penetration at force F,
read from the simulator for the trial's contact pose), in series: c = F / k + p_A(F) + p_B(F), solved
for F. The same F loads both gels (equilibrium); each sensor's frame is a press with Fz = F and a small
shear from jaw misalignment. The object's deformation is its own share, c_obj.

Plastic cup (the paper's quantitative task): deformation % = c_obj / rim diameter x 100 (the paper
fits an ellipse to the rim: the squeezed axis shortens by c_obj). Stiffness from physics, not from the
paper: a thin ring under diametral load deflects delta = (pi/4 - 2/pi) F R^3 / (E I) (Roark). A hard
polystyrene cup (E = 3.0 GPa), rim diameter 75 mm, rolled bead = a tube of 2.5 mm outer / 2.0 mm inner
diameter (I = 1.13 mm^4): k = 0.44 N/mm. A free ring ignores the conical wall and base, which stiffen a
real cup, so this cup is if anything softer than a real one.

Fruits (the paper's qualitative task): gentle threshold = the least force that holds the fruit while
lifting it at 3 m/s^2 with two frictional contacts, m (g + a) / (2 mu); firm threshold = the force
at which bruising starts (order-of-magnitude values for fingertip-sized contacts). A gentle grasp
closes until the estimate reaches the gentle threshold; a firm grasp closes up to the firm threshold
without passing it (the gripper steps back when a step's estimate passes it). Success: the final TRUE
force lies between the two thresholds (held, not damaged).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ffjax import sim
from ffjax.tasks.contacts import get_contact

G = 9.81
LIFT_ACCEL = 3.0  # m/s^2, lifting after the grasp


def ring_stiffness(young_mpa: float, inertia_mm4: float, radius_mm: float) -> float:
    """N/mm of a thin ring squeezed across a diameter (Roark: delta = 0.1488 F R^3 / (E I))."""
    return young_mpa * inertia_mm4 / ((math.pi / 4 - 2 / math.pi) * radius_mm**3)


def tube_inertia(d_out_mm: float, d_in_mm: float) -> float:
    return math.pi / 64 * (d_out_mm**4 - d_in_mm**4)


@dataclasses.dataclass(frozen=True)
class Deformable:
    name: str
    contact: str  # contacts.get_contact name
    stiffness_n_per_mm: float
    diameter_mm: float
    mass_kg: float
    mu_gel: float  # friction object-gel
    firm_n: float | None = None  # damage onset (fruits)

    @property
    def gentle_n(self) -> float:
        return self.mass_kg * (G + LIFT_ACCEL) / (2 * self.mu_gel)


CUP = Deformable(
    "plastic_cup", "cup_rim", ring_stiffness(3000.0, tube_inertia(2.5, 2.0), 37.5), 75.0, 0.010, 0.6
)
# Fruit stiffness: whole-fruit compression between flat plates (N/mm, ripe fruit), masses of a typical
# piece, skin-silicone friction, bruising onset for ~1 cm^2 contacts.
FRUITS = (
    Deformable("banana", "banana", 2.0, 35.0, 0.120, 0.7, firm_n=6.0),
    Deformable("tomato", "tomato", 3.0, 64.0, 0.090, 0.5, firm_n=8.0),
    Deformable("mushroom", "mushroom", 1.5, 40.0, 0.020, 0.8, firm_n=3.0),
    Deformable("strawberry", "strawberry", 0.8, 30.0, 0.025, 0.9, firm_n=2.5),
)


@dataclasses.dataclass(frozen=True)
class GripperConfig:
    step_mm: float = 0.196  # Robotiq Hand-E: 50 mm stroke over 255 positions (total closure per step)
    sensors: tuple = (("mini-1", 1), ("mini-2", 1))  # two GelSight Mini units, one per jaw
    max_force_n: float = 14.0  # stop: the training range ends at 15 N
    max_steps: int = 400
    pose_jitter_mm: float = 1.0  # "small pose changes" between trials
    yaw_jitter_deg: float = 5.0
    tilt_jitter_deg: float = 1.0
    misalign: float = 0.03  # shear / normal from jaw misalignment


class GraspTrial:
    """One object, one trial pose: force, deformation and camera frames at every gripper step."""

    _F_GRID = np.concatenate([[0.0], np.geomspace(0.02, 20.0, 32)])

    def __init__(self, obj: Deformable, cfg: GripperConfig, seed: int, size, sensors=None):
        rng = np.random.default_rng(seed)
        self.obj, self.cfg, self.seed, self.size = obj, cfg, seed, tuple(size)
        self.shape = get_contact(obj.contact)
        self.sensors = sensors or [sim.get_sensor(n, g) for n, g in cfg.sensors]
        self.poses = [
            dict(
                x_mm=rng.uniform(-1, 1) * cfg.pose_jitter_mm,
                y_mm=rng.uniform(-1, 1) * cfg.pose_jitter_mm,
                yaw_deg=rng.uniform(-1, 1) * cfg.yaw_jitter_deg,
                tilt_deg=tuple(rng.uniform(-1, 1, 2) * cfg.tilt_jitter_deg),
            )
            for _ in self.sensors
        ]
        self.shear = [rng.uniform(-1, 1, 2) * cfg.misalign for _ in self.sensors]
        self.offset_mm = rng.uniform(0, cfg.step_mm)  # where first contact falls between two steps
        self._closure = self._F_GRID / obj.stiffness_n_per_mm
        for sensor, pose in zip(self.sensors, self.poses):
            self._closure = self._closure + self._penetration(sensor, pose)
        self._frames: dict = {}

    def _penetration(self, sensor, pose) -> np.ndarray:
        """The gel's penetration (mm) at each force of _F_GRID (0 at no force), one batch of presses."""
        f = self._F_GRID[1:]
        n = len(f)
        done = sim.press_many([self.shape] * n, sensor, np.column_stack([np.zeros((n, 2)), f]),
                              [pose["x_mm"]] * n, [pose["y_mm"]] * n, [pose["yaw_deg"]] * n,
                              [pose["tilt_deg"]] * n, [0] * n, (24, 32), noise=False)
        for s in done:
            if isinstance(s, ValueError):
                raise s
        return np.concatenate([[0.0], [s.meta["penetration_mm"] for s in done]])

    def closure(self, step: int) -> float:
        """mm the jaws have closed past first contact at `step` (step 1 is the first in contact)."""
        return max(step * self.cfg.step_mm - self.offset_mm, 0.0)

    def force(self, step: int) -> float:
        """True normal force (N) on each gel at `step`."""
        return float(np.interp(self.closure(step), self._closure, self._F_GRID))

    def deformation_pct(self, step: int) -> float:
        return 100.0 * self.force(step) / self.obj.stiffness_n_per_mm / self.obj.diameter_mm

    def forces(self, step: int) -> list[np.ndarray]:
        """(Fx, Fy, Fz) on each sensor at `step`."""
        f = self.force(step)
        return [np.array([s[0] * f, s[1] * f, f], np.float32) for s in self.shear]

    def frames(self, step: int) -> list[np.ndarray]:
        """Both sensors' camera frames at `step` (cached)."""
        if step not in self._frames:
            self._frames[step] = [
                sim.press(
                    self.shape, sensor, f, seed=self.seed * 7919 + step * 2 + k, size=self.size, **pose
                ).image
                for k, (sensor, pose, f) in enumerate(zip(self.sensors, self.poses, self.forces(step)))
            ]
        return self._frames[step]

    def backgrounds(self) -> list[np.ndarray]:
        return [s.background(self.size) for s in self.sensors]


@dataclasses.dataclass
class GraspResult:
    stop_step: int  # the step the gripper ends at
    reached: bool  # the target was reached before the force / step limit
    readings: list  # the controller's reading at each step taken (1..last)


def close_until(read, target: float, rule: str = "reach", max_steps: int = 400, limit=None) -> GraspResult:
    """Close step by step (1, 2, ...) until read(step) >= target.

    rule "reach": stop at that step (at or just past the target); "below": step back to the previous
    step (never past the target); "closest": whichever of the two read closer to the target (the paper's
    cup protocol). limit(step) -> True aborts (e.g. the true force left the safe range)."""
    if rule not in ("reach", "below", "closest"):
        raise ValueError(f"rule must be reach|below|closest, got {rule!r}")
    readings = []
    for step in range(1, max_steps + 1):
        r = float(read(step))
        readings.append(r)
        if r >= target:
            if rule == "reach" or step == 1:
                return GraspResult(step, True, readings)
            if rule == "below":
                return GraspResult(step - 1, True, readings)
            prev = readings[-2]
            return GraspResult(step if r - target <= target - prev else step - 1, True, readings)
        if limit is not None and limit(step):
            break
    return GraspResult(len(readings), False, readings)


def run_grasp(trial: GraspTrial, target: float, rule: str, read) -> dict:
    """One grasp on `trial` with the controller reading `read(step)`; the outcome in true quantities."""
    cfg = trial.cfg
    res = close_until(read, target, rule, cfg.max_steps, limit=lambda s: trial.force(s) > cfg.max_force_n)
    k = res.stop_step
    return {
        "stop_step": k,
        "reached": res.reached,
        "force": trial.force(k),
        "deformation_pct": trial.deformation_pct(k),
        "overshoot_n": trial.force(k) - target,
        "step_increment_n": trial.force(k) - trial.force(max(k - 1, 0)),
        "readings": res.readings,
    }


def truth_reader(trial: GraspTrial):
    """The reference: the true force (what the paper's force sensor gives)."""
    return trial.force


def model_reader(trial: GraspTrial, estimate, chunk: int = 8):
    """Reading = max over the two sensors of the model's Fz, estimated in chunks of steps (the closed
    loop is unchanged: steps before the stop do not depend on the readings)."""
    cache: dict = {}
    bgs = trial.backgrounds()

    def read(step: int) -> float:
        if step not in cache:
            steps = list(range(step, step + chunk))
            per_sensor = []
            for k, bg in enumerate(bgs):
                imgs = np.stack([trial.frames(s)[k] for s in steps])
                per_sensor.append(estimate(imgs, bg)[:, 2])
            for s, v in zip(steps, np.max(per_sensor, 0)):
                cache[s] = float(v)
        return cache[step]

    read.cache = cache
    return read
