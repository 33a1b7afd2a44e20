"""Sensor and gel presets: GelSight Mini units 1..3 x gels 1..3, and DIGIT.

Units differ the way real ones do: LED placement, colour mix and brightness (the camera side), and
gel stiffness, thickness and markers (the gel side). Lengths in mm, moduli in MPa (= N/mm^2).
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
    texture_contrast: float = 0.02


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
    unevenness: float = 0.06  # low-frequency albedo variation of the pad (non-uniform background)
    falloff: float = 1.0  # LED irradiance ~ distance^-falloff (1: light guides spread it; 2: bare LED)

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


# Gels 1..3: different cast batches / recipes. Gel 2 is softer and thinner, gel 3 stiffer, thicker
# and printed with markers. E ~ 3 G (incompressible silicone).
GELS = {
    1: Gel(young_mpa=0.44, shear_mpa=0.15, thickness_mm=4.5, friction=1.0, texture_seed=11),
    2: Gel(young_mpa=0.33, shear_mpa=0.11, thickness_mm=4.0, friction=1.1, texture_seed=22,
           texture_contrast=0.025),
    3: Gel(young_mpa=0.55, shear_mpa=0.18, thickness_mm=5.0, friction=0.9, markers=True, texture_seed=33,
           texture_contrast=0.015),
}
DIGIT_GEL = Gel(young_mpa=0.30, shear_mpa=0.10, thickness_mm=4.0, friction=1.0, texture_seed=44,
                texture_contrast=0.03)

_MINI_MM_PER_PX = 0.0634
_R, _G, _B = (1.0, 0.25, 0.2), (0.25, 1.0, 0.3), (0.2, 0.35, 1.0)

# GelSight Mini units: the same design, but LED positions, colour mixes and brightness scatter
# from unit to unit (assembly and LED binning).
_MINIS = {
    "mini-1": dict(
        leds=(LED(180, 6.0, _R, 1.0), LED(270, 6.0, _G, 0.9), LED(0, 6.0, _B, 1.1),
              LED(90, 7.5, (0.8, 0.8, 0.7), 0.5)),
        brightness=150.0, ambient=(0.10, 0.10, 0.12), vignette=0.25, noise_std=1.5, unevenness=0.05,
    ),
    "mini-2": dict(
        leds=(LED(188, 5.4, (1.0, 0.3, 0.25), 1.1), LED(262, 6.5, (0.3, 1.0, 0.35), 0.85),
              LED(8, 5.7, (0.25, 0.4, 1.0), 1.0), LED(95, 8.2, (0.85, 0.8, 0.65), 0.45)),
        brightness=162.0, ambient=(0.12, 0.10, 0.10), vignette=0.30, noise_std=1.8, unevenness=0.07,
    ),
    "mini-3": dict(
        leds=(LED(172, 6.6, (1.0, 0.2, 0.15), 0.9), LED(278, 5.5, (0.2, 1.0, 0.25), 1.05),
              LED(-6, 6.8, (0.15, 0.3, 1.0), 1.2), LED(84, 6.8, (0.75, 0.8, 0.8), 0.55)),
        brightness=138.0, ambient=(0.09, 0.11, 0.11), vignette=0.20, noise_std=1.3, unevenness=0.06,
        albedo=(0.82, 0.86, 0.84),
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
        noise_std=4.0, dome_radius_mm=60.0, unevenness=0.08, falloff=1.6,
    ),
}
MINI_NAMES = tuple(_MINIS)
SENSOR_NAMES: tuple[str, ...] = tuple(PRESETS)
SENSORS: tuple[tuple[str, int], ...] = tuple((s.name, s.gel_id) for s in PRESETS.values())


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
