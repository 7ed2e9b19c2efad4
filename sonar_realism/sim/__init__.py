"""Physics-based forward-looking sonar simulator with a switchable catalogue of real-sensor effects.

`simulate(scene, effects, n, seed, sensor)` yields (SonarImage, object mask) pairs; `SCENES` names the scene
builders; the effects live in `sonar_realism.sim.effects` (EFFECTS, make_effect, apply_effects).
"""

from sonar_realism.sim.scene import SCENES
from sonar_realism.sim.sensor import SENSORS, SensorConfig
from sonar_realism.sim.simulate import simulate

__all__ = ["SCENES", "SENSORS", "SensorConfig", "simulate"]
