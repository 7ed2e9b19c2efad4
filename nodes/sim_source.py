"""sim_source: the built-in simulator as a live source (frames and object masks), finite or endless."""

from __future__ import annotations

from dataclasses import dataclass

from sonar_realism.errors import ConfigError
from sonar_realism.runtime.node import TimedSourceNode
from sonar_realism.runtime.sources import SimSource, Trajectory


@dataclass(frozen=True)
class SimSourceParams:
    scene: str = "default"   # a name in sonar_realism.sim.SCENES
    effects: str = "none"    # "none", "all" or "speckle,range_blur,..."
    count: int = 16          # frames to publish, then end of stream; 0 = endless
    seed: int = 0
    rate_hz: float = 0.0     # 0 = as fast as the consumers take them
    sensor: str = "m1200d_1200khz"   # a name in sonar_realism.sim.SENSORS
    trajectory: Trajectory = Trajectory()  # [nodes.X.params.trajectory] kind = "circle", radius_m = 5, ...
    calibration: str = ""    # a CALIB.json (`sonar-realism calibrate`) or "oculus" (shipped): that sensor's views

    def validate(self) -> None:
        if self.count < 0 or self.rate_hz < 0:
            raise ConfigError(f"sim_source: count ({self.count}) and rate_hz ({self.rate_hz}) must be >= 0")
        self.trajectory.validate()


class SimSourceNode(TimedSourceNode):
    PARAMS = SimSourceParams
    OUTPUTS = {"frames": "polar", "masks": "mask"}

    def configure(self) -> None:
        p: SimSourceParams = self.params
        self.source = SimSource(p.scene, p.effects, p.count, p.seed, p.rate_hz, p.sensor, p.trajectory,
                                calibration=p.calibration)


NODE = SimSourceNode
