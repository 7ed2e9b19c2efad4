"""Timed frame sources for source nodes: a recording replayed on its own clock, and the live simulator.

Each source hands out `(due, frame)`: the `clock()` time at which the frame should be published, or
None when it has nothing more. The node only waits until `due` and publishes, so all timing decisions
are here and testable with a fake clock.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sonar_realism.errors import ConfigError, FormatError
from sonar_realism.frames import SonarImage
from sonar_realism.io import read_frames

Clock = Callable[[], float]


def replay_offsets(frames: Iterator[SonarImage], speed: float, start_s: float = 0.0,
                   stop_s: float = 0.0) -> Iterator[tuple[float, SonarImage]]:
    """(seconds after the replay started, frame) for the frames between start_s and stop_s of recording
    time (measured from the first frame's stamp; stop_s 0 = to the end). speed 0 = as fast as possible;
    2 = twice real time. Stamps that go backwards never make the schedule go backwards."""
    first_ns: int | None = None
    offset = 0.0
    for frame in frames:
        if first_ns is None:
            first_ns = frame.stamp_ns
        recorded_s = (frame.stamp_ns - first_ns) / 1e9
        if recorded_s < start_s:
            continue
        if stop_s > 0 and recorded_s > stop_s:
            return
        if speed > 0:
            offset = max(offset, (recorded_s - start_s) / speed)
        yield offset, frame


class ReplaySource:
    """Frames of any recording `read_frames` reads, paced by their stamps; optionally looped.

    When looping, seq is renumbered so it keeps increasing across passes (downstream gap counting stays
    meaningful); the recorded seq is kept in meta["recorded_seq"]. `restamp` replaces stamps with the
    publish time (keeping meta["recorded_stamp_ns"]) so staleness limits work on old recordings.
    """

    def __init__(self, path: str | Path, speed: float = 1.0, loop: bool = False, start_s: float = 0.0,
                 stop_s: float = 0.0, restamp: bool = False, clock: Clock = time.monotonic) -> None:
        if speed < 0:
            raise ConfigError(f"speed: must be >= 0 (0 = as fast as possible), got {speed}")
        if stop_s and stop_s <= start_s:
            raise ConfigError(f"stop_s ({stop_s}) must be after start_s ({start_s})")
        self.path = Path(path)
        if not self.path.exists():
            raise FormatError(str(self.path), "path", "no such file or folder")
        self.speed, self.loop, self.start_s, self.stop_s, self.restamp = speed, loop, start_s, stop_s, restamp
        self.clock = clock
        self.passes = 0
        self.published = 0
        self._pass: Iterator[tuple[float, SonarImage]] | None = None
        self._pass_start = 0.0

    def next(self) -> tuple[float, SonarImage] | None:
        while True:
            if self._pass is None:
                if self.passes > 0 and not self.loop:
                    return None
                self._pass = replay_offsets(read_frames(self.path), self.speed, self.start_s, self.stop_s)
                self._pass_start = self.clock()
                self.passes += 1
            item = next(self._pass, None)
            if item is not None:
                break
            self._pass = None
            if self.published == 0:
                return None  # an empty selection would loop forever without publishing anything
        offset, frame = item
        changes: dict = {}
        if self.loop:
            changes.update(seq=self.published, meta={**frame.meta, "recorded_seq": frame.seq})
        if self.restamp:
            changes["meta"] = {**changes.get("meta", frame.meta), "recorded_stamp_ns": frame.stamp_ns}
            changes["stamp_ns"] = time.time_ns()
        self.published += 1
        return self._pass_start + offset, frame.replace(**changes) if changes else frame


@dataclass(frozen=True)
class Trajectory:
    """The vehicle path: "scene" (the scene's own), "circle" around the origin looking at it, or "transect"
    (a straight line along x, centred on the origin, looking along it)."""

    kind: str = "scene"
    radius_m: float = 7.0
    length_m: float = 20.0
    altitude_m: float = 2.5
    tilt_deg: float = 15.0

    def validate(self) -> None:
        if self.kind not in ("scene", "circle", "transect"):
            raise ConfigError(f"trajectory: {self.kind!r} is not one of scene, circle, transect")
        if self.radius_m <= 0 or self.length_m <= 0 or self.altitude_m <= 0:
            raise ConfigError("trajectory: radius_m, length_m and altitude_m must be > 0")

    def apply(self, scene: Any) -> Any:
        from sonar_realism.sim.scene import circle_trajectory, transect_trajectory

        if self.kind == "circle":
            path = circle_trajectory((0.0, 0.0), self.radius_m, self.altitude_m, self.tilt_deg)
        elif self.kind == "transect":
            half = self.length_m / 2
            path = transect_trajectory((-half, 0.0), (half, 0.0), self.altitude_m, self.tilt_deg)
        else:
            return scene
        return dataclasses.replace(scene, trajectory=path, trajectory_kind=self.kind)


def _calibrated_passes(path: str, effects: str) -> Callable[[int, int], Iterator[tuple[SonarImage, Any]]]:
    from sonar_realism.sim.calibrated import calibrated_chain, simulate_calibrated
    from sonar_realism.sim.calibration import load_calibration

    calibration = load_calibration(path)
    chain = calibrated_chain(calibration, effects)
    return lambda n, pass_seed: simulate_calibrated(calibration, n, pass_seed, chain)


class SimSource:
    """The built-in simulator as a live source: `count` frames (0 = endless) at `rate_hz` (0 = as fast as
    consumers take them), each stamped with the wall clock when made and numbered from 0.

    An endless run simulates passes of `chunk` frames along the trajectory; pass k uses seed + k, so the
    per-ping noise differs between passes while the world (built from `seed`) stays the same. With a
    `calibration` (a CALIB.json from `sonar-realism calibrate`) the frames are that sensor's, each a new
    randomised view, and `effects` picks among its fitted effects.
    """

    def __init__(self, scene: str = "default", effects: str = "none", count: int = 16, seed: int = 0,
                 rate_hz: float = 0.0, sensor: str = "m1200d_1200khz", trajectory: Trajectory | None = None,
                 chunk: int = 64, clock: Clock = time.monotonic, calibration: str = "") -> None:
        from sonar_realism.sim import SENSORS, simulate  # the simulator is imported only by sim sources
        from sonar_realism.sim.scene import build_scene

        if count < 0 or rate_hz < 0:
            raise ConfigError(f"count ({count}) and rate_hz ({rate_hz}) must be >= 0")
        if sensor not in SENSORS:
            raise ConfigError(f"sensor: {sensor!r} is not one of {', '.join(SENSORS)}")
        trajectory = trajectory or Trajectory()
        trajectory.validate()
        self._passes: Callable[[int, int], Iterator[tuple[SonarImage, Any]]]
        if calibration:
            if scene != "default" or sensor != "m1200d_1200khz" or trajectory != Trajectory():
                raise ConfigError("calibration: the calibrated sensor makes its own views (grid, mounting, "
                                  "targets); leave scene, sensor and trajectory unset")
            self._passes = _calibrated_passes(calibration, effects)
        else:
            world = trajectory.apply(build_scene(scene, seed, SENSORS[sensor].max_range_m))
            self._passes = lambda n, pass_seed: simulate(world, effects=effects, n=n, seed=pass_seed,
                                                         sensor=SENSORS[sensor])
        self.count, self.seed, self.rate_hz = count, seed, rate_hz
        self.chunk = chunk
        self.clock = clock
        self.made = 0
        self._next_due: float | None = None
        self._batch: Iterator[tuple[SonarImage, Any]] | None = None
        self._pass = 0

    def next(self) -> tuple[float, SonarImage, SonarImage] | None:
        """(due, frame, object mask as a uint8 frame of the same geometry), or None after `count` frames."""
        if self.count and self.made >= self.count:
            return None
        item = next(self._batch, None) if self._batch is not None else None
        if item is None:
            n = self.count if self.count else self.chunk
            self._batch = self._passes(n, self.seed + self._pass)
            self._pass += 1
            item = next(self._batch, None)
            if item is None:
                return None
        frame, mask = item
        now = self.clock()
        due = now if self._next_due is None or self.rate_hz == 0 else max(now, self._next_due)
        self._next_due = due + (1.0 / self.rate_hz if self.rate_hz else 0.0)
        frame = frame.replace(seq=self.made, stamp_ns=time.time_ns())
        mask_frame = frame.replace(intensity=np.asarray(mask, np.uint8), intensity_scale=0.0,
                                   meta={"kind": "object_mask"})
        self.made += 1
        return due, frame, mask_frame
