"""Held-out transmit ring-down: leakage that falls off as a power law while the receiver's gain recovers from
saturation, and a two-time-constant ring added in phase with a fixed bearing profile. Neither is the catalogue's
single exponential in power with per-ping beam ripple nor the tuning half's damped oscillation with random phase."""

from __future__ import annotations

import numpy as np

from sonar_realism.diagnose.heldout.base import Param, held_out
from sonar_realism.frames import SonarImage


@held_out("ring_down", "power_law_recovery", strength="amplitude",
          amplitude=Param((0.1, 0.8), (0.03, 1.5), "amplitude"),
          knee_m=Param((0.02, 0.2), (0.005, 1.0), "decay_m"),
          power=Param((1.5, 3.0), (1.0, 4.0)),
          suppression=Param((0.0, 0.8), (0.0, 0.95)))
def power_law_recovery(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                       instrument: np.random.Generator) -> np.ndarray:
    """The transducer still rings: leaked amplitude `amplitude` / (1 + d / knee)^power at distance d past the
    first bin; meanwhile the saturated receiver recovers, so echoes near the start are suppressed by up to
    `suppression`, recovering over the same knee. Leak and echo add in power; the leak jitters 10 % per bin."""
    d = (frame.ranges_m - frame.ranges_m[0])[:, None]
    leak = p["amplitude"] / (1.0 + d / p["knee_m"]) ** p["power"]
    leak = leak * (1.0 + 0.1 * ping.standard_normal((x.shape[0], 1)))
    recovery = 1.0 - p["suppression"] / (1.0 + d / p["knee_m"]) ** 2
    return np.sqrt((x * recovery) ** 2 + leak ** 2).astype(np.float32)


@held_out("ring_down", "two_exponential_inphase",
          amplitude=Param((0.1, 0.8), (0.03, 1.5), "amplitude"),
          fast_decay_m=Param((0.01, 0.1), (0.003, 0.3), "decay_m"),
          slow_fraction=Param((0.05, 0.3), (0.0, 0.6)),
          slow_decay_m=Param((0.2, 0.8), (0.1, 2.0)),
          centre_power=Param((0.0, 4.0), (0.0, 10.0)))
def two_exponential_inphase(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                            instrument: np.random.Generator) -> np.ndarray:
    """Two ringing modes (a fast one and a `slow_fraction` slow one) added to the echo amplitude in phase, with a
    fixed bearing profile cos(bearing)^`centre_power` (the leak is strongest at boresight), no per-ping change."""
    d = (frame.ranges_m - frame.ranges_m[0])[:, None]
    ring = p["amplitude"] * (np.exp(-d / p["fast_decay_m"]) + p["slow_fraction"] * np.exp(-d / p["slow_decay_m"]))
    profile = np.cos(frame.azimuths_rad)[None, :] ** p["centre_power"]
    return (x + ring * profile).astype(np.float32)
