"""Sensor and gel presets: GelSight Mini units 1..3 x gels 1..3, and DIGIT.

Units differ the way real ones do: LED placement, colour mix, brightness, colour balance, pixel pattern and dust
(the camera side), and gel stiffness, thickness and pigment (the gel side). Lengths in mm, moduli in MPa
(= N/mm^2). What a real GelSight Mini shows at rest is measured, not chosen: see REST below.
Image axes: x to the right (columns), y down (rows); the pad centre is (0, 0).

`PRESETS` (key -> Sensor) is the one list of sensors: SENSOR_NAMES, sim.get_sensor, the dataset's per-sensor
splits and the config's data.train_sensor check all read it. A new sensor is one entry there (a new
GelSight Mini unit: one entry in _MINIS, which gives it every gel).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ffjax.sim import optics


@dataclasses.dataclass(frozen=True)
class LED:
    azimuth_deg: float  # where the LED sits around the pad, seen from the camera (0 = +x, 90 = +y)
    height_mm: float  # above the gel surface; low = grazing light = strong slope contrast
    color: tuple[float, float, float]  # linear RGB of the emitted light
    intensity: float = 1.0
    radius_mm: float = 24.0  # distance of the LED from the pad centre (light guides: far, even)


@dataclasses.dataclass(frozen=True)
class Gel:
    young_mpa: float  # E; Winkler k = E / thickness at small strain
    shear_mpa: float  # G, sets the tangential stick stiffness
    thickness_mm: float
    friction: float = 1.0
    markers: bool = False
    texture_seed: int = 0
    pigment: float = 0.006  # rms of the pigment's fine pattern, fraction of the level (moves with the gel)


@dataclasses.dataclass(frozen=True)
class Sensor:
    name: str
    gel_id: int
    gel: Gel
    leds: tuple[LED, ...]
    native_size: tuple[int, int]  # (H, W)
    native_mm_per_px: float
    ambient: tuple[float, float, float] = (0.08, 0.08, 0.08)
    albedo: tuple[float, float, float] = (0.85, 0.85, 0.85)
    brightness: float = 150.0  # mean 8-bit level of the no-contact frame
    vignette: float = 0.25
    blur_px: float = 0.8  # camera/defocus blur, in native pixels
    noise_std: float = 1.5  # 8-bit camera noise per frame (independent per frame)
    shading_gamma: float = 1.0
    dome_radius_mm: float | None = None  # DIGIT's curved gel; None = flat pad
    unevenness: float = 0.06  # low-frequency unevenness of the lighting (non-uniform background)
    falloff: float = 1.0  # LED irradiance ~ distance^-falloff (1: light guides spread it; 2: bare LED)
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)  # relative R, G, B level of the untouched frame
    pixel_pattern: float = 0.006  # rms of the pixels' fixed gain pattern, fraction of the level (stays put)
    dust: int = 0  # dust specks on the optics (stay put)

    @property
    def key(self) -> str:
        """Its name in SENSOR_NAMES: "mini-2-gel3"; a sensor whose name alone is a PRESETS key ("digit", its gel
        part of it) goes by its name. Derived sensors (the pretraining corpus's "rand-3") get "-gel<id>"."""
        return self.name if self.name in PRESETS else f"{self.name}-gel{self.gel_id}"

    @property
    def fov_mm(self) -> tuple[float, float]:
        """(height, width) of the field of view in mm; kept fixed at every render size."""
        h, w = self.native_size
        return h * self.native_mm_per_px, w * self.native_mm_per_px

    def mm_per_px(self, size: tuple[int, int] | None = None) -> tuple[float, float]:
        """(dy, dx) pixel pitch in mm at a render size (the field of view stays fixed)."""
        h, w = size or self.native_size
        fh, fw = self.fov_mm
        return fh / h, fw / w

    @property
    def k_gel(self) -> float:
        """Winkler foundation modulus at small strain, N/mm^3 (pressure per mm of indentation)."""
        return self.gel.young_mpa / self.gel.thickness_mm

    def background(self, size: tuple[int, int] | None = None, noise: bool = True) -> np.ndarray:
        """The no-contact frame, uint8 (H, W, 3). With noise it is one fixed recorded frame (seeded by the
        sensor's name), the same every call; a press frame gets its own independent noise."""
        return optics.background(self, tuple(size or self.native_size), noise)


# REST: a real GelSight Mini at rest (the FeelAnyForce release's records/calibration_sphere, 123 frames over 180 s
# at 240x320, measured by experiments.diagnostics.rest_recording; docs/results/real/rest_recording):
# - the untouched frame's mean is R 77, G 122, B 110 (level 103): darker and greener than a neutral balance;
# - its fine fixed pattern (finer than optics.FINE_PX) is 0.80-0.92% of the level per channel (0.87% on average),
#   per-frame noise 2.0 / 1.4 / 2.5 counts, and ~5 dust specks of 5-30% show;
# - the LEDs drift after start-up: -1.1, -0.3, -0.4 counts/min (R, G, B) over the 3 minutes.
# Which share of the fine pattern is pigment (moves with the gel) and which the camera's (stays) is not measurable
# at rest: PATTERN_MOVING splits its variance; `with_pattern_moving` makes a sensor with another split.
REST_FINE_PATTERN = 0.0087
REST_LEVEL = 103.0
REST_BALANCE = (77.0 / REST_LEVEL, 122.0 / REST_LEVEL, 110.0 / REST_LEVEL)
PATTERN_MOVING = 0.5
_PIGMENT = REST_FINE_PATTERN * PATTERN_MOVING**0.5
_PIXELS = REST_FINE_PATTERN * (1 - PATTERN_MOVING) ** 0.5

# Gels 1..3: different cast batches / recipes. Gel 2 is softer and thinner, gel 3 stiffer and thicker; their
# pigments scatter around the measured one. None carries markers (the paper's gels do not; a marker gel is a
# stability factor, `with_markers`). E ~ 3 G (incompressible silicone).
GELS = {
    1: Gel(young_mpa=0.44, shear_mpa=0.15, thickness_mm=4.5, friction=1.0, texture_seed=11, pigment=_PIGMENT),
    2: Gel(young_mpa=0.33, shear_mpa=0.11, thickness_mm=4.0, friction=1.1, texture_seed=22,
           pigment=1.2 * _PIGMENT),
    3: Gel(young_mpa=0.55, shear_mpa=0.18, thickness_mm=5.0, friction=0.9, texture_seed=33,
           pigment=0.8 * _PIGMENT),
}
# DIGIT is not measured: its fine pattern stays at its former level (1.7% of the level), split as a Mini's
DIGIT_GEL = Gel(young_mpa=0.30, shear_mpa=0.10, thickness_mm=4.0, friction=1.0, texture_seed=44, pigment=0.012)

_MINI_MM_PER_PX = 0.0634
_R, _G, _B = (1.0, 0.25, 0.2), (0.25, 1.0, 0.3), (0.2, 0.35, 1.0)

# GelSight Mini units: the same design, but LED positions, colour mixes, brightness, colour balance, pixel pattern
# and dust scatter from unit to unit (assembly, LED binning, camera) around the measured unit (REST).
_MINIS = {
    "mini-1": dict(
        leds=(LED(180, 6.0, _R, 1.0), LED(270, 6.0, _G, 0.9), LED(0, 6.0, _B, 1.1),
              LED(90, 7.5, (0.8, 0.8, 0.7), 0.5)),
        brightness=REST_LEVEL, ambient=(0.10, 0.10, 0.12), vignette=0.25, noise_std=1.5, unevenness=0.05,
        white_balance=REST_BALANCE, pixel_pattern=_PIXELS, dust=5,
    ),
    "mini-2": dict(
        leds=(LED(188, 5.4, (1.0, 0.3, 0.25), 1.1), LED(262, 6.5, (0.3, 1.0, 0.35), 0.85),
              LED(8, 5.7, (0.25, 0.4, 1.0), 1.0), LED(95, 8.2, (0.85, 0.8, 0.65), 0.45)),
        brightness=1.06 * REST_LEVEL, ambient=(0.12, 0.10, 0.10), vignette=0.30, noise_std=1.8, unevenness=0.07,
        white_balance=(0.76, 1.17, 1.07), pixel_pattern=1.15 * _PIXELS, dust=3,
    ),
    "mini-3": dict(
        leds=(LED(172, 6.6, (1.0, 0.2, 0.15), 0.9), LED(278, 5.5, (0.2, 1.0, 0.25), 1.05),
              LED(-6, 6.8, (0.15, 0.3, 1.0), 1.2), LED(84, 6.8, (0.75, 0.8, 0.8), 0.55)),
        brightness=0.92 * REST_LEVEL, ambient=(0.09, 0.11, 0.11), vignette=0.20, noise_std=1.3, unevenness=0.06,
        albedo=(0.82, 0.86, 0.84), white_balance=(0.72, 1.22, 1.06), pixel_pattern=0.9 * _PIXELS, dust=7,
    ),
}


def _mini(unit: str, gel: int) -> Sensor:
    return Sensor(name=unit, gel_id=gel, gel=GELS[gel], native_size=(240, 320), native_mm_per_px=_MINI_MM_PER_PX,
                  **_MINIS[unit])


# Every sensor by key: each GelSight Mini unit with each gel, and DIGIT with its own domed gel.
PRESETS: dict[str, Sensor] = {f"{unit}-gel{gel}": _mini(unit, gel) for unit in _MINIS for gel in GELS} | {
    "digit": Sensor(
        name="digit", gel_id=1, gel=DIGIT_GEL, native_size=(320, 240), native_mm_per_px=0.0625,
        # three RGB LEDs 120 degrees apart, closer to the gel and brighter at short range
        leds=(LED(90, 4.0, (1.0, 0.15, 0.1), 1.2, 14.0), LED(210, 4.0, (0.1, 1.0, 0.15), 1.2, 14.0),
              LED(330, 4.0, (0.1, 0.2, 1.0), 1.3, 14.0)),
        ambient=(0.06, 0.06, 0.07), albedo=(0.8, 0.8, 0.8), brightness=120.0, vignette=0.4, blur_px=1.2,
        noise_std=4.0, dome_radius_mm=60.0, unevenness=0.08, falloff=1.6, pixel_pattern=0.012, dust=4,
    ),
}
MINI_NAMES = tuple(_MINIS)
SENSOR_NAMES: tuple[str, ...] = tuple(PRESETS)
SENSORS: tuple[tuple[str, int], ...] = tuple((s.name, s.gel_id) for s in PRESETS.values())


def with_pattern_moving(sensor: Sensor, share: float) -> Sensor:
    """The sensor with another split of its fine fixed pattern (the same total variance): `share` of it the gel's
    pigment (moves with the gel), the rest the camera's pixel pattern (stays). 0: all camera, 1: all pigment."""
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"the moving share of the fixed pattern must be in [0, 1], got {share!r}")
    total = (sensor.gel.pigment**2 + sensor.pixel_pattern**2) ** 0.5
    gel = dataclasses.replace(sensor.gel, pigment=total * share**0.5)
    return dataclasses.replace(sensor, gel=gel, pixel_pattern=total * (1 - share) ** 0.5)


def with_markers(sensor: Sensor) -> Sensor:
    """The sensor's gel printed with dark markers (1.6 mm pitch, 0.5 mm dots): a stress test, not a paper gel."""
    return dataclasses.replace(sensor, gel=dataclasses.replace(sensor.gel, markers=True))


def get_sensor(name: str, gel: int = 1) -> Sensor:
    """A sensor preset by unit and gel ("mini-1".."mini-3" with gel 1..3; "digit", gel 1) or by its key in
    SENSOR_NAMES ("mini-2-gel3", "digit")."""
    if name in PRESETS:
        if gel != 1 and PRESETS[name].name == name:  # a sensor with one gel of its own (DIGIT)
            raise ValueError(f"{name} has one gel of its own; got gel={gel}")
        return PRESETS[name]
    if f"{name}-gel{gel}" in PRESETS:
        return PRESETS[f"{name}-gel{gel}"]
    units = list(dict.fromkeys(s.name for s in PRESETS.values()))
    if name not in units:
        raise ValueError(f"unknown sensor {name!r}; choose from {units} or a key of {list(SENSOR_NAMES)}")
    gels = [s.gel_id for s in PRESETS.values() if s.name == name]
    raise ValueError(f"unknown gel {gel!r} for {name}; choose from {gels}")
