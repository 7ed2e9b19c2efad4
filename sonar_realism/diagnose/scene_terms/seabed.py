"""Scene candidate `seabed`: the real seabed's backscatter is patchier than the sim's.

Patchiness of the mean level (sand, gravel, weed: a log-normal level over metres) is a property of the scene, not
of the sensor: speckle is fine-grained and fixed by the pulse and the beams, patches are as large as the seabed
makes them. The sim frames are multiplied by a smooth log-normal field of rms log-amplitude `patch_contrast`
(mean power kept) and correlation length `patch_scale_fraction` of each axis, drawn anew per frame.
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
from sonar_realism.sim.measure import seabed_stats


@dataclass(frozen=True)
class SeabedPatches(SceneTerm, kind="scene"):
    """More seabed patchiness: a log-normal level field on top of the sim's own."""

    name: ClassVar[str] = "seabed"
    patch_contrast: float = 0.0
    patch_scale_fraction: float = 0.03
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"patch_contrast": (0.0, 1.5),
                                                               "patch_scale_fraction": (0.01, 0.2)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {"patch_contrast": (0.0, 5.0),
                                                              "patch_scale_fraction": (1e-3, 1.0)}
    LOG_SCALE: ClassVar[frozenset[str]] = frozenset({"patch_scale_fraction"})

    @classmethod
    def start(cls, sim_images: np.ndarray, scene: SceneStart) -> SeabedPatches:
        """The contrast the real seabed has beyond the sim's (patch variances add in the log)."""
        measured = [s.contrast for image in sim_images if (s := seabed_stats(image)) is not None]
        sim_contrast = float(np.median(measured)) if measured else 0.0
        extra = math.sqrt(max(scene.patch_contrast ** 2 - sim_contrast ** 2, 0.0))
        low, high = cls.PARAM_BOUNDS["patch_scale_fraction"]
        return cls(patch_contrast=min(extra, cls.PARAM_BOUNDS["patch_contrast"][1]),
                   patch_scale_fraction=float(np.clip(scene.patch_scale_fraction, low, high)))

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        planes = _planes(intensity)
        n_ranges, n_beams = planes.shape[-2:]
        sigma = (max(self.patch_scale_fraction * n_beams, 0.5), max(self.patch_scale_fraction * n_ranges, 0.5))
        out = np.empty_like(planes)
        for i, plane in enumerate(planes):
            white = rng.standard_normal((n_ranges, n_beams)).astype(np.float32)
            field = cv2.GaussianBlur(white, (0, 0), sigmaX=sigma[0], sigmaY=sigma[1], borderType=cv2.BORDER_REFLECT)
            field /= max(float(field.std()), 1e-6)
            c = np.float32(self.patch_contrast)
            out[i] = plane * np.exp(c * field - c * c)
        return out.reshape(intensity.shape)
