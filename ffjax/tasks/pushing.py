"""Weighing by pushing (the paper's Table IV): push an object across a table at constant velocity with
the tactile sensor, read the push force, and weigh the object as m = f_p / (mu * g).

Geometry (which sensor axis is which): the sensor is mounted on the arm with its gel facing the object's
side and pushes horizontally, so the gel normal (sensor z, the axis the model's Fz reads) IS the push
direction and f_p = Fz. Image columns (sensor x) are horizontal across the push, image rows (sensor y)
point down along gravity. The reference force sensor (the paper's ATI Axia80 behind the gel) reads the
push along the same axis.

Physics of one push (f_p = m dv/dt + mu m g, the paper's equation, plus the non-idealities a real table
and arm add; each is a named knob of PushConfig and off when set to 0):
  load     the arm advances, the gel loads against the still object: f_p ramps to static breakaway
           mu_s m g over `t_load_s`.
  accel    the object speeds up to v along a smooth (cosine) velocity ramp over `t_accel_s`:
           f_p = m dv/dt + mu_k m g.
  constant v = const: f_p = mu_k(x) m g. mu_k varies along the path by `roughness` (wood grain, a
           smooth random function of position), with `vibration` (stick-slip chatter) per frame.
  The contact can carry a small vertical shear Fy = eps f_p (the gel contact above/below the centre of
  mass); pressing the object down by Fy raises the table's normal load, so f_p = (m a + mu m g) /
  (1 - mu eps). Lateral shear Fx follows the object's small yaw corrections (`lateral`).
Reference sensor: the true f_p + a drift toward higher values growing since its tare at the start of
each push (the paper: "drifts slightly towards higher values over time"; `drift_n_per_s`, a rate drawn
per push), white noise and quantization. Sensor (camera) noise is the simulator's per-frame noise.

Weighing as the paper does it: average the z force over the constant-velocity frames of all pushes,
for the tactile estimate and the reference; fit the dynamic friction from the reference with the
known mass, mu_fit = f_ref / (m g); the tactile weight is m_hat = f_est / (mu_fit g). (Check on the
paper's numbers: Weight(1): mu_fit = 2.24 / 9.81 = 0.228, weight error 0.2 / (0.228 g) = 0.09 kg.)
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from ffjax import sim
from ffjax.tasks.contacts import get_contact

G = 9.81
PHASES = ("load", "accel", "constant")


@dataclasses.dataclass(frozen=True)
class PushObject:
    name: str
    label: str  # the paper's column title
    mass_kg: float
    mu: float  # dynamic friction object-table (a wooden table)
    mu_static: float
    contact: str  # contacts.get_contact name
    paper: dict  # the paper's Table IV column


# Friction: mid-range handbook values for dry contacts on varnished wood (steel 0.2-0.6, PP 0.2-0.4,
# glass 0.2-0.3); static ~20% above dynamic. Masses are the paper's.
OBJECTS = (
    PushObject(
        "weight",
        "Weight(1)",
        1.0,
        0.30,
        0.36,
        "flat_face",
        {"force_est": 2.05, "force_ref": 2.24, "force_error": 0.2, "weight_error": 0.1},
    ),
    PushObject(
        "cylinder_0503",
        "Cyl.(0.503)",
        0.503,
        0.26,
        0.31,
        "cylinder_wall",
        {"force_est": 0.87, "force_ref": 0.96, "force_error": 0.09, "weight_error": 0.04},
    ),
    PushObject(
        "cylinder_0559",
        "Cyl.(0.559)",
        0.559,
        0.26,
        0.31,
        "cylinder_wall",
        {"force_est": 0.98, "force_ref": 1.06, "force_error": 0.09, "weight_error": 0.05},
    ),
    PushObject(
        "bottle",
        "Bottle(0.630)",
        0.630,
        0.22,
        0.26,
        "bottle_wall",
        {"force_est": 1.02, "force_ref": 1.08, "force_error": 0.06, "weight_error": 0.04},
    ),
)


@dataclasses.dataclass(frozen=True)
class PushConfig:
    duration_s: float = 15.0
    fps: float = 25.0  # GelSight Mini frame rate; presets subsample it
    pushes: int = 5
    velocity_mm_s: float = 10.0  # "a controlled low velocity"
    t_load_s: float = 0.5
    t_accel_s: float = 0.8
    roughness: float = 0.04  # relative std of mu along the path
    roughness_len_mm: float = 15.0
    vibration: float = 0.01  # relative per-frame chatter
    lateral: float = 0.03  # |Fx| / f_p scale
    vertical: float = 0.05  # eps drawn in +-vertical per push
    drift_n_per_s: tuple = (0.002, 0.008)  # reference drift rate range (N/s since tare)
    ref_noise_n: float = 0.02
    ref_resolution_n: float = 0.04
    pose_jitter_mm: float = 0.4  # slow wander of the contact on the pad
    yaw_jitter_deg: float = 1.5

    def ideal(self) -> PushConfig:
        """The paper's model alone: no roughness, chatter, shear coupling, drift or reference noise."""
        return dataclasses.replace(
            self,
            roughness=0.0,
            vibration=0.0,
            lateral=0.0,
            vertical=0.0,
            drift_n_per_s=(0.0, 0.0),
            ref_noise_n=0.0,
            ref_resolution_n=0.0,
        )


@dataclasses.dataclass
class Push:
    obj: PushObject
    t: np.ndarray  # (N,) s
    phase: np.ndarray  # (N,) int index into PHASES
    velocity: np.ndarray  # (N,) m/s
    accel: np.ndarray  # (N,) m/s^2
    mu_k: np.ndarray  # (N,) local dynamic friction
    force: np.ndarray  # (N, 3) true force on the gel (Fx, Fy, Fz = f_p), N
    reference: np.ndarray  # (N,) reference sensor's push force, N
    pose: np.ndarray  # (N, 3) x_mm, y_mm, yaw_deg of the contact on the pad
    seed: int

    @property
    def constant(self) -> np.ndarray:
        return self.phase == PHASES.index("constant")


def _smooth_series(rng, n: int, corr: float) -> np.ndarray:
    """Unit-std smooth noise of length n with correlation length `corr` samples. Normalized over a
    series much longer than the correlation length, so a short push is not inflated to unit std."""
    if n == 0:
        return np.zeros(0)
    corr = max(corr, 0.5)
    pad = int(3 * corr) + 1
    m = max(n, int(20 * corr)) + 2 * pad
    x = rng.standard_normal(m).astype(np.float32)[None]
    y = cv2.GaussianBlur(x, (0, 0), sigmaX=corr, sigmaY=1e-3)[0, pad : m - pad]
    return (y / (y.std() + 1e-9))[:n].astype(np.float64)


def kinematics(cfg: PushConfig, t: np.ndarray):
    """(phase, velocity m/s, acceleration m/s^2, position m) of the object at times t."""
    v0 = cfg.velocity_mm_s / 1000
    tau = np.clip((t - cfg.t_load_s) / cfg.t_accel_s, 0, 1)
    moving = t >= cfg.t_load_s
    v = np.where(moving, v0 * (1 - np.cos(np.pi * tau)) / 2, 0.0)
    a = np.where(moving & (tau < 1), v0 * np.pi / (2 * cfg.t_accel_s) * np.sin(np.pi * tau), 0.0)
    ts = np.maximum(t - cfg.t_load_s, 0)
    # closed-form position: integral of the cosine ramp, then constant speed
    ta = np.minimum(ts, cfg.t_accel_s)
    x = v0 / 2 * (ta - cfg.t_accel_s / np.pi * np.sin(np.pi * ta / cfg.t_accel_s)) + v0 * np.maximum(
        ts - cfg.t_accel_s, 0
    )
    phase = np.where(~moving, 0, np.where(tau < 1, 1, 2))
    return phase, v, a, x


def push_force(mass: float, mu_k, accel, eps=0.0):
    """f_p = (m dv/dt + mu m g) / (1 - mu eps): the paper's equation, with the table's extra normal load
    when the contact also presses the object down by Fy = eps f_p (eps = 0: the paper's model)."""
    mu_k = np.asarray(mu_k, np.float64)
    return (mass * np.asarray(accel) + mu_k * mass * G) / (1 - mu_k * eps)


def simulate_push(obj: PushObject, cfg: PushConfig, seed: int, duration_s: float | None = None) -> Push:
    """One push's true forces, reference readings and contact poses, one row per camera frame."""
    rng = np.random.default_rng(seed)
    dur = cfg.duration_s if duration_s is None else duration_s
    n = max(2, int(round(dur * cfg.fps)))
    t = np.arange(n) / cfg.fps
    phase, v, a, x = kinematics(cfg, t)
    # mu along the path: smooth in position (sampled on a 1 mm grid, read at x)
    path_mm = np.arange(int(cfg.velocity_mm_s * dur) + 3)
    rough = (
        _smooth_series(rng, len(path_mm), cfg.roughness_len_mm) if cfg.roughness else np.zeros(len(path_mm))
    )
    mu_k = obj.mu * (1 + cfg.roughness * np.interp(x * 1000, path_mm, rough))
    eps = rng.uniform(-cfg.vertical, cfg.vertical) if cfg.vertical else 0.0
    f = push_force(obj.mass_kg, mu_k, a, eps)
    if cfg.vibration:
        f = f * (1 + cfg.vibration * rng.standard_normal(n) * (phase > 0))
    f_break = float(push_force(obj.mass_kg, obj.mu_static, 0.0, eps))
    f = np.where(phase == 0, f_break * np.clip((t + 1 / cfg.fps) / cfg.t_load_s, 0, 1), f)
    corr = cfg.fps * 1.5  # pose / lateral corrections over ~1.5 s
    fx = cfg.lateral * f * _smooth_series(rng, n, corr) if cfg.lateral else np.zeros(n)
    force = np.stack([fx, eps * f, f], 1)

    lo, hi = cfg.drift_n_per_s
    drift = rng.uniform(lo, hi) * t
    ref = f + drift + cfg.ref_noise_n * rng.standard_normal(n)
    if cfg.ref_resolution_n:
        ref = np.round(ref / cfg.ref_resolution_n) * cfg.ref_resolution_n
    pose = np.stack(
        [
            cfg.pose_jitter_mm * _smooth_series(rng, n, corr) + rng.uniform(-1, 1),
            cfg.pose_jitter_mm * _smooth_series(rng, n, corr) + rng.uniform(-1, 1),
            cfg.yaw_jitter_deg * _smooth_series(rng, n, corr),
        ],
        1,
    )
    return Push(obj, t, phase, v, a, mu_k, force.astype(np.float32), ref, pose, seed)


def render_push(push: Push, sensor, size) -> tuple[np.ndarray, np.ndarray]:
    """Camera frames of a push (N, H, W, 3) uint8 and the sensor's background frame."""
    sensor = sim.get_sensor(sensor) if isinstance(sensor, str) else sensor
    shape = get_contact(push.obj.contact)
    n = len(push.t)
    done = sim.press_many([shape] * n, sensor, push.force, push.pose[:, 0], push.pose[:, 1], push.pose[:, 2],
                          np.zeros((n, 2)), [push.seed * 100_003 + i for i in range(n)], tuple(size))
    for s in done:
        if isinstance(s, ValueError):
            raise s
    return np.stack([s.image for s in done]) if n else np.empty((0, *size, 3), np.uint8), sensor.background(size)


def weigh(pushes: list[Push], estimates: list[np.ndarray], duration_s: float | None = None) -> dict:
    """Table IV numbers for one object from its pushes and the tactile Fz estimate of each frame.

    Only frames in the constant-velocity phase (and before `duration_s`, for the duration sweep) count;
    the averages pool all pushes' frames, as the paper does."""
    obj = pushes[0].obj

    def pooled(values):
        keep = [p.constant & (p.t < (duration_s if duration_s is not None else math.inf)) for p in pushes]
        v = np.concatenate([np.asarray(x, np.float64)[k] for x, k in zip(values, keep)])
        if len(v) == 0:
            raise ValueError("no constant-velocity frames: the push is shorter than load + acceleration")
        return float(v.mean())

    f_est = pooled(estimates)
    f_ref = pooled([p.reference for p in pushes])
    f_true = pooled([p.force[:, 2] for p in pushes])
    mu_fit = f_ref / (obj.mass_kg * G)
    m_est = f_est / (mu_fit * G)
    m_true_mu = f_est / (obj.mu * G)
    return {
        "object": obj.name,
        "label": obj.label,
        "mass": obj.mass_kg,
        "force_est": f_est,
        "force_ref": f_ref,
        "force_true": f_true,
        "force_error": abs(f_est - f_ref),
        "force_error_signed": f_est - f_ref,
        "force_error_vs_true": f_est - f_true,
        "mu_true": obj.mu,
        "mu_fit": mu_fit,
        "mass_est": m_est,
        "weight_error": abs(m_est - obj.mass_kg),
        "weight_error_rel": abs(m_est - obj.mass_kg) / obj.mass_kg,
        "mass_est_true_mu": m_true_mu,
        "weight_error_true_mu": abs(m_true_mu - obj.mass_kg),
        "reference_bias": f_ref - f_true,
    }
