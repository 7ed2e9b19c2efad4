"""simulate(): scene -> poses -> clean polar images -> chosen real-sensor effects, as SonarImage frames."""

from __future__ import annotations

import hashlib
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.parallel import parallel_imap
from sonar_realism.sim.effects import Effect, apply_effects, resolve_effects
from sonar_realism.sim.render import render
from sonar_realism.sim.scene import Pose, Scene, build_scene
from sonar_realism.sim.sensor import M1200D_1200KHZ, SensorConfig

# Stamps start at the real recordings' day (2025-08-05) and advance at 10 Hz.
FIRST_STAMP_NS = 1_754_400_000_000_000_000
PING_PERIOD_NS = 100_000_000


def speckle_seed(scene: Scene, pose: Pose) -> int:
    """A seed fixed by the world and the viewpoint: same scene + pose -> same speckle (it is frozen)."""
    key = f"{scene.name}|{scene.seed}|" + "|".join(f"{v:.4f}" for v in pose.as_dict().values())
    return int.from_bytes(hashlib.blake2b(key.encode(), digest_size=8).digest(), "little")


def frame_for(scene: Scene, pose: Pose, sensor: SensorConfig, index: int, clip: bool = True,
              ) -> tuple[SonarImage, np.ndarray]:
    """The clean frame (float32 amplitude; in [0, 1] with `clip`) and object mask at one pose."""
    amplitude, mask = render(scene, pose, sensor, clip)
    meta: dict[str, Any] = {
        **sensor.meta(), "source": "sim", "scene": scene.name, "scene_seed": scene.seed,
        "trajectory": scene.trajectory_kind, "pose": pose.as_dict(), "sonar_altitude_m": pose.z,
        "sonar_tilt_rad": pose.tilt, "speckle_seed": speckle_seed(scene, pose)}
    frame = SonarImage(amplitude, sensor.ranges_m, sensor.azimuths_rad, seq=index, frame_id="sonar",
                       stamp_ns=FIRST_STAMP_NS + index * PING_PERIOD_NS, intensity_scale=1.0, meta=meta)
    return frame, mask


def simulate(scene: str | Scene = "default", effects: str | Sequence[str | Effect] | None = "none", n: int = 24,
             seed: int = 0, sensor: SensorConfig | None = None,
             params: dict[str, dict[str, Any]] | None = None, workers: int = 1,
             ) -> Iterator[tuple[SonarImage, np.ndarray]]:
    """Yield n (frame, object mask) pairs along the scene's trajectory.

    scene: a name in SCENES (built with `seed` and the sensor's range) or an already built Scene.
    effects: "none" (the raw sim), "all", "a,b", or a list of names/effect instances; `params` overrides effect
    parameters by name ({"speckle": {"shape_nu": 3}}). Frames are float32 amplitude, or uint8 when
    gamma_quantization is on; masks are uint8 object ids on the same [range, beam] grid. Everything is fixed by
    `seed`: the world (scene), and, per frame, the electronic noise and other per-ping draws, so `workers`
    processes (sonar_realism/parallel.py) give the same frames in the same order as one.
    """
    if not isinstance(n, int) or n < 0:
        raise ConfigError(f"n: expected a non-negative number of frames, got {n!r}")
    sensor = sensor or M1200D_1200KHZ
    sensor.validate()
    chosen = resolve_effects(effects, params)
    world = scene if isinstance(scene, Scene) else build_scene(scene, seed, sensor.max_range_m)
    poses = world.trajectory(n)

    def one(index: int) -> tuple[SonarImage, np.ndarray]:
        frame, mask = frame_for(world, poses[index], sensor, index)
        if chosen:
            frame = apply_effects(frame, chosen, np.random.default_rng([seed, index]))
        return frame, mask

    yield from parallel_imap(one, range(len(poses)), workers, chunksize=2)
