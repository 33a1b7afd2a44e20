"""ffjax.sim: a small tactile simulator for GelSight Mini and DIGIT frames with exact force labels.

    from ffjax import sim
    sensor = sim.get_sensor("mini-1", gel=1)      # sim.SENSOR_NAMES / sim.SENSORS: 9 minis x gels + "digit"
    shape = sim.get_shape("sphere_big")           # sim.INDENTERS (10), sim.UNSEEN_OBJECTS (10)
    s = sim.press(shape, sensor, force=(fx, fy, fz), x_mm=0, y_mm=0, yaw_deg=0, tilt_deg=(0, 0), seed=0,
                  size=(48, 64))                  # -> Sample(image, background, depth, force, meta)
    batch = sim.press_batch(shape, sensor, forces, x_mm, y_mm, yaw_deg, tilt_deg, seeds, size)  # dataset path
    sim.benchmark(size=(48, 64), n=400)           # samples/minute on this machine

Pipeline: shape height field (shapes.py) posed on the pad -> contact pressure, approach and gel surface
solved for the requested Fz on an incompressible elastic layer bonded to the glass (elastic_layer.py),
with local large-strain stiffening (mechanics.py) -> shear stick displacement with a Coulomb cap, bulge in
front -> Lambertian LED shading, pigment and markers warped by shear, vignetting, blur, noise (optics.py).
Sensors and gels: sensors.py.

Conventions: x right (image columns), y down (rows), origin at the pad centre, mm; depth in mm, + = into
the gel, - = bulge; force in N, +Fx drags the gel towards +x. `size` changes the pixel count, never the
field of view. The force solve always runs on a fixed quarter-native grid (~0.25 mm), so the force-depth
relation does not depend on the render size. Noise: `sensor.background(size)` is one fixed recorded
frame (its noise seeded by the sensor's name); every pressed frame gets independent camera noise from its
own `seed`; noise=False renders noiseless frames (then a zero-force frame equals
`sensor.background(size, noise=False)` exactly).
Fast path: `press_batch` shares per-(sensor, size) lighting/albedo tables and per-shape map pyramids
(all cached), and shades only the window where the gel moved; parallelize across processes by shard.

Left out, on purpose:
- FEM: the layer is linear-elastic with a pointwise (uniaxial) large-strain correction, frictionless in the
  normal solve, and unbounded (a real pad ends at its frame); exact at small strain, approximate beyond.
- Dynamics: every press is quasi-static; no rate dependence, vibration, or motion blur.
- Hysteresis: loading and unloading give the same frame (no viscoelasticity, creep or gel ageing).
- Shadows: LEDs light every surface point they face; self-occlusion by deep indentations is ignored.
- Ray tracing: no refraction in the gel or acrylic, no inter-reflection; shading is Lambertian per LED.
- Torque: no moment is applied or reported; twisting (yaw-rate) shear fields are not modelled.
- Object compliance: bodies are rigid; soft objects (fruit) press like hard ones of the same shape.
- Partial slip: the contact either sticks or fully slides (Coulomb cap); no stick-slip annulus.
"""

from ffjax.sim.press import (
    Sample,
    benchmark,
    body_heights,
    mechanics_key,
    press,
    press_batch,
    press_many,
    press_many_seen,
    solve_size,
)
from ffjax.sim.sensors import GELS, LED, SENSOR_NAMES, SENSORS, Gel, Sensor, get_sensor
from ffjax.sim.shapes import INDENTERS, UNSEEN_OBJECTS, Shape, get_shape

__all__ = [
    "GELS", "INDENTERS", "LED", "SENSORS", "SENSOR_NAMES", "UNSEEN_OBJECTS", "Gel", "Sample", "Sensor", "Shape",
    "benchmark", "body_heights", "get_sensor", "get_shape", "mechanics_key", "press", "press_batch", "press_many",
    "press_many_seen", "solve_size",
]
