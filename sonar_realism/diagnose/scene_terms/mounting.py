"""Geometry candidate `mounting`: the sim's sonar sits otherwise over the seabed than the real one.

Height and tilt decide where the seabed starts: the lower edge of the vertical aperture meets a flat seabed at
height / sin(tilt + half the aperture), and the water column above it is dark. The term shifts the sim frames
along range as a whole so that their seabed onset (measured on the sim frames with the calibration's detector,
sim/measure.py) lands where the candidate mounting puts it; rows from before the first or past the last are
mirrored back in (more water column, more seabed). Rows are moved, never interpolated, so the speckle's grain
stays the sim's (interpolating between rows smooths it, which no mounting does). The onset is a share of the
range window (real frames exported without geometry are stretched over their own window, so only shares line up
between the sets), searched as a change of where the calibration's mounting puts it: a few rows decide the
statistics, so a coarse grid over the whole window would skip past it.

A rigid shift, not a re-rendering: a large change of height also changes the profile's shape behind the onset
(a low sonar sees a sharp onset and a fast fall-off), which this term does not make. Tried and dropped: a gain
ramp over range beside the shift (a plain range gain, which the gain check's yardstick already is); moving the
mean profile and keeping the texture in place (dividing by the sim's rising edge blew up its noise); re-lighting
with a flat-seabed model (the simulator's profile is not that model's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import cv2
import numpy as np

from sonar_realism.diagnose.scene_terms.base import SceneStart, SceneTerm
from sonar_realism.frames import SonarImage
from sonar_realism.sim.effects import _planes
from sonar_realism.sim.measure import onset_rows


def measured_onset_fraction(images: np.ndarray) -> float:
    """Median seabed onset of max-normalised images [n, R, B], as a share of the window (0: no water column)."""
    rows = [np.nanmedian(r) for image in images if np.isfinite(r := onset_rows(image)).any()]
    return float(np.median(rows) / max(images.shape[1] - 1, 1)) if rows else 0.0


def onset_of(scene: SceneStart) -> float:
    """Where the calibration's mounting puts the seabed's onset, as a share of the window."""
    lower_edge = math.radians(scene.tilt_deg + scene.vertical_fov_deg / 2)
    return float(np.clip(scene.height_fraction / max(math.sin(lower_edge), 1e-3), 0.0, 0.95))


@dataclass(frozen=True)
class Mounting(SceneTerm, kind="geometry"):
    """The sim frames shifted so the seabed onset moves from `sim_onset_fraction` (measured on the sim) to
    `calibrated_onset_fraction` (where the calibration's mounting puts it) + `onset_adjust`."""

    name: ClassVar[str] = "mounting"
    onset_adjust: float = 0.0
    calibrated_onset_fraction: float = 0.0
    sim_onset_fraction: float = 0.0
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"onset_adjust": (-0.15, 0.15)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {
        "onset_adjust": (-0.95, 0.95), "calibrated_onset_fraction": (0.0, 0.95), "sim_onset_fraction": (0.0, 0.95)}

    @classmethod
    def start(cls, sim_images: np.ndarray, scene: SceneStart) -> Mounting:
        return cls(calibrated_onset_fraction=onset_of(scene),
                   sim_onset_fraction=min(measured_onset_fraction(sim_images), 0.95))

    @property
    def onset_fraction(self) -> float:
        """Where the seabed starts in the real sensor's frames, as fitted."""
        return float(np.clip(self.calibrated_onset_fraction + self.onset_adjust, 0.0, 0.95))

    def source_rows(self, n_ranges: int) -> np.ndarray:
        """For every output row, the sim row it shows (before mirroring at the ends)."""
        shift = (self.onset_fraction - self.sim_onset_fraction) * (n_ranges - 1)
        return np.arange(n_ranges) - np.round(shift)

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        planes = _planes(intensity)
        n_ranges, n_beams = planes.shape[-2:]
        map_y = np.repeat(self.source_rows(n_ranges).astype(np.float32)[:, None], n_beams, axis=1)
        map_x = np.repeat(np.arange(n_beams, dtype=np.float32)[None, :], n_ranges, axis=0)
        out = np.stack([cv2.remap(np.ascontiguousarray(p), map_x, map_y, cv2.INTER_NEAREST,
                                  borderMode=cv2.BORDER_REFLECT_101) for p in planes])
        return out.reshape(intensity.shape)
