"""Geometry candidate `mounting`: the sim's sonar sits otherwise over the seabed than the real one.

Height and tilt decide where the seabed starts (the lower edge of the vertical aperture meets it) and how its
brightness falls with range. The sim frames are remapped along range so their seabed onset lands where the
real sensor's is (the seabed shifted, the water column stretched or squeezed), and a gain ramp in dB from the onset to the
far end changes the fall-off. Both in shares of the range window; the sim's own onset is measured on its frames.
"""

from __future__ import annotations

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


@dataclass(frozen=True)
class Mounting(SceneTerm, kind="geometry"):
    """The seabed onset moved from `sim_onset_fraction` (measured on the sim) to `calibrated_onset_fraction`
    (where the calibration's mounting puts it) + `onset_adjust`, and `falloff_db` more (or, negative, less)
    brightness at the far end than at the onset, linear in dB between. The onset is searched near the
    calibration's: a few rows decide the statistics, so a coarse grid over the whole window would skip past it."""

    name: ClassVar[str] = "mounting"
    onset_adjust: float = 0.0
    falloff_db: float = 0.0
    calibrated_onset_fraction: float = 0.0
    sim_onset_fraction: float = 0.0
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"onset_adjust": (-0.15, 0.15),
                                                               "falloff_db": (-12.0, 12.0)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {
        "onset_adjust": (-0.95, 0.95), "falloff_db": (-60.0, 60.0), "calibrated_onset_fraction": (0.0, 0.95),
        "sim_onset_fraction": (0.0, 0.95)}

    @classmethod
    def start(cls, sim_images: np.ndarray, scene: SceneStart) -> Mounting:
        return cls(calibrated_onset_fraction=min(scene.onset_fraction, 0.95),
                   sim_onset_fraction=min(measured_onset_fraction(sim_images), 0.95))

    @property
    def onset_fraction(self) -> float:
        """Where the seabed starts in the real sensor's frames, as fitted."""
        return float(np.clip(self.calibrated_onset_fraction + self.onset_adjust, 0.0, 0.95))

    def source_rows(self, n_ranges: int) -> np.ndarray:
        """For every output row, the sim row it shows: the seabed shifted as a whole (its rows kept as they are,
        so the texture's grain along range is the sim's; rows beyond the sim's last are its last rows mirrored),
        the water column above it stretched or squeezed."""
        out = np.linspace(0.0, 1.0, n_ranges)
        onset, sim_onset = self.onset_fraction, self.sim_onset_fraction
        near = out * (sim_onset / onset) if onset > 0 else np.full(n_ranges, sim_onset)
        far = sim_onset + (out - onset)
        return np.where(out < onset, near, far) * (n_ranges - 1)

    def gain(self, n_ranges: int) -> np.ndarray:
        out = np.linspace(0.0, 1.0, n_ranges)
        along = np.clip((out - self.onset_fraction) / max(1.0 - self.onset_fraction, 1e-6), 0.0, 1.0)
        return (10 ** (self.falloff_db * along / 20)).astype(np.float32)

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        planes = _planes(intensity)
        n_ranges, n_beams = planes.shape[-2:]
        map_y = np.repeat(self.source_rows(n_ranges).astype(np.float32)[:, None], n_beams, axis=1)
        map_x = np.repeat(np.arange(n_beams, dtype=np.float32)[None, :], n_ranges, axis=0)
        gain = self.gain(n_ranges)[:, None]
        out = np.stack([cv2.remap(np.ascontiguousarray(p), map_x, map_y, cv2.INTER_NEAREST,
                                  borderMode=cv2.BORDER_REFLECT_101) * gain for p in planes])
        return out.reshape(intensity.shape)
