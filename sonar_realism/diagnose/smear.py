"""Is a smoothing along range a range blur or a platform-motion smear?

A pulse-length blur (range_blur) mixes each beam along range only. A platform that turns or sways while the
receiver averages smears across bearing as well, and as much or more (motion_blur). The two can close a gap
equally well in the frames' statistics: a motion blur fitted with its surge alone is a box along range, and a
range blur with wide sidelobes stands in for a random sub-ping smear. What decides between them is the axis of the
smoothing in the real frames: how much sharper the sim's frames are than the real ones along range and across the
beams, each measured as the log of the ratio of their mean squared log-power differences. This test is put only to
a pick whose runner-up is the other blur (diagnose/which.py `signature_yield`); a smoothing along range alone is
named a range blur.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sonar_realism.diagnose.leakage import POWER_FLOOR
from sonar_realism.sim.effects import MotionBlur, RangeBlur

BLURS = (RangeBlur.name, MotionBlur.name)
# Across-beam smoothing over along-range smoothing (see `SmearCheck`). On the tuning forms and the catalogue
# (default, organic and calibrated scenes, 40 frames a side; docs/RESULTS.md) range blurs gave 0.29-0.63 and motion
# blurs that turn or sway 1.35-4.5; a motion blur with its surge alone 0.25-0.6, as a range blur.
AXIS_RATIO = 0.9
# Below this much smoothing on both axes the scenes' own differences decide the ratio (the null cases reach 0.22).
LEAST_SMOOTHING = 0.3


def log_gradient_energy(images: np.ndarray) -> tuple[float, float]:
    """Mean squared difference of log power between neighbouring cells along range and across beams: images
    [n, n_ranges, n_beams] (amplitude)."""
    log_power = np.log(images.astype(np.float64) ** 2 + POWER_FLOOR)
    return (float(np.mean(np.square(np.diff(log_power, axis=1)))),
            float(np.mean(np.square(np.diff(log_power, axis=2)))))


@dataclass(frozen=True)
class SmearCheck:
    """How much smoother the real frames are than the corrected sim's along range (`along_range`) and across the
    beams (`across_beams`), each ln(sim's log-gradient energy / real's). A motion blur is confirmed when the beams
    are smoothed at least AXIS_RATIO times as much as the range, a range blur when they are not; either is
    confirmed when neither axis is smoothed by LEAST_SMOOTHING (nothing to read)."""

    effect: str
    along_range: float
    across_beams: float

    @property
    def confirmed(self) -> bool:
        if max(self.along_range, self.across_beams) < LEAST_SMOOTHING:
            return True
        across = self.across_beams >= AXIS_RATIO * self.along_range
        return across if self.effect == MotionBlur.name else not across

    def describe(self) -> str:
        want = "as much across the beams as along range" if self.effect == MotionBlur.name else "along range"
        return (f"a smear {want}: the real frames are smoother than the sim's by {self.along_range:.2f} along range "
                f"and {self.across_beams:.2f} across the beams (log gradient energy; a motion smear from "
                f"{AXIS_RATIO:.1f} times as much across)")


def check_smear(effect: str, real_images: np.ndarray, sim_images: np.ndarray) -> SmearCheck:
    real_range, real_beams = log_gradient_energy(real_images)
    sim_range, sim_beams = log_gradient_energy(sim_images)
    return SmearCheck(effect, _log_ratio(sim_range, real_range), _log_ratio(sim_beams, real_beams))


def _log_ratio(sim: float, real: float) -> float:
    return math.log(max(sim, 1e-12) / max(real, 1e-12))
