"""Held-out motion during a ping: a turn that speeds up while the echoes come in, with a Gaussian angular smear,
and a few randomly displaced sub-pings (heave and sway jitter). Neither is the catalogue's constant-rate shear
with box smears nor the tuning half's evenly time-stepped sub-pings."""

from __future__ import annotations

import math

import cv2
import numpy as np

from sonar_realism.diagnose.heldout.base import Param, bin_m, held_out
from sonar_realism.frames import SonarImage

SOUND_SPEED_MPS = 1480.0


def _beam_step_rad(frame: SonarImage) -> float:
    theta = frame.azimuths_rad
    return float(theta[-1] - theta[0]) / max(theta.size - 1, 1)


@held_out("motion_blur", "accelerating_yaw",
          yaw_rate_deg_s=Param((15.0, 60.0), (5.0, 150.0), "yaw_rate_deg_s"),
          yaw_accel_deg_s2=Param((-500.0, 500.0), (-3000.0, 3000.0)),
          smear_deg=Param((0.3, 2.0), (0.1, 5.0)))
def accelerating_yaw(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                     instrument: np.random.Generator) -> np.ndarray:
    """The echo from range r left the scene at t = 2r/c, by when the sonar has turned w t + a t^2 / 2; the
    rotation during the receiver's averaging smears across bearing with a Gaussian of `smear_deg` (sigma)."""
    t = 2.0 * frame.ranges_m / SOUND_SPEED_MPS
    turned = math.radians(p["yaw_rate_deg_s"]) * t + 0.5 * math.radians(p["yaw_accel_deg_s2"]) * t * t
    step = _beam_step_rad(frame)
    rows, cols = np.indices(x.shape, dtype=np.float32)
    map_x = (cols + (turned / step)[:, None]).astype(np.float32)
    power = cv2.remap((x * x).astype(np.float32), map_x, rows, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    sigma_beams = math.radians(p["smear_deg"]) / step
    if sigma_beams > 0.2:
        power = cv2.GaussianBlur(power, (0, 0), sigmaX=sigma_beams, sigmaY=1e-3)
    return np.sqrt(np.maximum(power, 0.0)).astype(np.float32)


@held_out("motion_blur", "jitter_subpings",
          copies=Param((3.0, 5.0), (2.0, 8.0), integer=True),
          jitter_range_m=Param((0.02, 0.15), (0.005, 0.4)),
          jitter_deg=Param((0.2, 1.5), (0.05, 4.0)))
def jitter_subpings(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                    instrument: np.random.Generator) -> np.ndarray:
    """The receiver averages `copies` sub-pings, each taken from a randomly displaced pose (Gaussian jitter of
    `jitter_range_m` along range and `jitter_deg` in bearing, new every ping): a random, not a straight, smear."""
    step = _beam_step_rad(frame)
    rows, cols = np.indices(x.shape, dtype=np.float32)
    power = (x * x).astype(np.float32)
    total = np.zeros_like(power)
    copies = max(int(p["copies"]), 1)
    for _ in range(copies):
        dr = ping.normal(0.0, p["jitter_range_m"]) / bin_m(frame)
        db = ping.normal(0.0, math.radians(p["jitter_deg"])) / step
        total += cv2.remap(power, cols + np.float32(db), rows + np.float32(dr), cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REFLECT_101)
    return np.sqrt(np.maximum(total / copies, 0.0)).astype(np.float32)
