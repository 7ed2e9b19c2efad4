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

The seabed is there from the nadir (slant range = height) on, but the simulator's vertical aperture has hard
edges, so its frames are black until the onset; a real transducer's vertical pattern has skirts that light the
seabed before the main lobe reaches it (the Oculus set's water column rises gradually from near range instead
of jumping at the onset). `skirt_db` fills the rows between the nadir and the onset with the seabed's texture
(its rows mirrored about the onset) at a level rising linearly in dB from `skirt_db` at the nadir to the
seabed's own at the onset; at its lower bound (-40 dB, where it starts) there is no skirt: the sim's hard edge.

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
    `calibrated_onset_fraction` (where the calibration's mounting puts it) + `onset_adjust`; the rows from the
    nadir (`height_fraction`) to the onset lit by the vertical pattern's skirt, `skirt_db` at the nadir."""

    name: ClassVar[str] = "mounting"
    onset_adjust: float = 0.0
    skirt_db: float = -40.0
    calibrated_onset_fraction: float = 0.0
    sim_onset_fraction: float = 0.0
    height_fraction: float = 0.0
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"onset_adjust": (-0.15, 0.15),
                                                               "skirt_db": (-40.0, -3.0)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {
        "onset_adjust": (-0.95, 0.95), "skirt_db": (-120.0, 0.0), "calibrated_onset_fraction": (0.0, 0.95),
        "sim_onset_fraction": (0.0, 0.95), "height_fraction": (0.0, 1.0)}

    @classmethod
    def start(cls, sim_images: np.ndarray, scene: SceneStart) -> Mounting:
        return cls(calibrated_onset_fraction=onset_of(scene),
                   sim_onset_fraction=min(measured_onset_fraction(sim_images), 0.95),
                   height_fraction=scene.height_fraction)

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
        rows, mirrored, level = self.skirt(n_ranges)
        if rows.size:
            out[:, rows, :] += out[:, mirrored, :] * level[None, :, None]
        return out.reshape(intensity.shape)

    def skirt(self, n_ranges: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rows the skirt lights (nadir to onset), the seabed rows whose texture each gets, and its gain."""
        onset = self.onset_fraction * (n_ranges - 1)
        nadir = min(self.height_fraction * (n_ranges - 1), onset)
        rows = np.arange(int(math.ceil(nadir)), int(math.ceil(onset)))
        if rows.size == 0 or self.skirt_db <= self.PARAM_BOUNDS["skirt_db"][0]:
            rows = rows[:0]
            return rows, rows, np.zeros(0, dtype=np.float32)
        mirrored = np.clip(np.round(2 * onset - rows).astype(int), 0, n_ranges - 1)
        level_db = self.skirt_db * (onset - rows) / max(onset - nadir, 1e-6)
        return rows, mirrored, (10 ** (level_db / 20)).astype(np.float32)
