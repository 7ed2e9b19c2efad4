"""Geometry and scene terms as diagnosis candidates, beside the sensor effects (issue 13, item 4).

A sim can be unlike a real recording because of how the scene was set up, not because a sensor effect is missing:
the sonar mounted higher or tilted less (the seabed starts elsewhere and its brightness falls differently with
range), a seabed of other backscatter patchiness. No sensor effect supplies that, and without these candidates
the selection blames stand-ins at their bounds. A term is a transform of the sim frames that a calibration
parameter implies (the frames remapped to the real sensor's seabed onset, a patchier seabed), fitted and judged
exactly like an effect (same search, same held-out gap, same selection and gain check) and reported with its own
`kind` ("geometry" or "scene") instead of "effect".

A term is a frozen dataclass like an `Effect` (searched fields in `PARAM_BOUNDS`; other fields are measured on the
sim frames, fixed during the search) that registers itself with `class X(SceneTerm, kind=...)`. It acts on the
clean sim frame, before any sensor effect (`apply_scene_terms`). `SceneStart` is what the calibration says about
the real setting; each term's `start()` turns it into the term's starting point for these sim frames.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.sim.calibration import Calibration
from sonar_realism.sim.effects import Effect

Kind = Literal["effect", "geometry", "scene"]
SCENE_TERMS: dict[str, type[SceneTerm]] = {}


@dataclass(frozen=True)
class SceneStart:
    """The real setting as the calibration describes it, lengths in shares of the range window's far end (real
    frames exported without geometry are stretched over their own window, so metres would not line up): the
    mounting (`height_fraction`, `tilt_deg`, `vertical_fov_deg`), the seabed's patchiness (`patch_contrast`: rms
    of the log local mean level) and its correlation length (`patch_scale_fraction`)."""

    height_fraction: float
    tilt_deg: float
    vertical_fov_deg: float
    patch_contrast: float
    patch_scale_fraction: float

    def validate(self) -> None:
        if not 1e-3 <= self.height_fraction <= 1.0:
            raise ConfigError(f"scene start: height_fraction {self.height_fraction} outside [0.001, 1]")
        if not -10.0 <= self.tilt_deg <= 89.0 or not 0.5 <= self.vertical_fov_deg <= 90.0:
            raise ConfigError(f"scene start: tilt_deg {self.tilt_deg} or vertical_fov_deg {self.vertical_fov_deg} "
                              "out of range")
        if not 0.0 <= self.patch_contrast <= 3.0:
            raise ConfigError(f"scene start: patch_contrast {self.patch_contrast} outside [0, 3]")
        if not 0.0 < self.patch_scale_fraction <= 1.0:
            raise ConfigError(f"scene start: patch_scale_fraction {self.patch_scale_fraction} outside (0, 1]")

    @classmethod
    def from_calibration(cls, calibration: Calibration) -> SceneStart:
        """The calibration's mounting, seabed patchiness and most frequent range window."""
        window = calibration.grid.modes[0].max_range_m
        m = calibration.mounting
        start = cls(height_fraction=float(np.clip(m.height_m.value / window, 1e-3, 1.0)),
                    tilt_deg=float(m.tilt_deg.value), vertical_fov_deg=float(m.vertical_fov_deg),
                    patch_contrast=float(np.clip(calibration.seabed.patch_contrast.value, 0.0, 3.0)),
                    patch_scale_fraction=float(np.clip(calibration.seabed.patch_scale_m.value / window, 1e-3, 1.0)))
        start.validate()
        return start


class SceneTerm(Effect):
    """Base of geometry and scene candidates: an `Effect`-like stage that is not in the sensor catalogue."""

    KIND: ClassVar[Kind]

    def __init_subclass__(cls, kind: Kind | None = None, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if kind is None:
            return
        if cls.name in SCENE_TERMS:
            raise ConfigError(f"scene term {cls.name!r} registered twice")
        cls.KIND = kind
        SCENE_TERMS[cls.name] = cls

    @classmethod
    @abc.abstractmethod
    def start(cls, sim_images: np.ndarray, scene: SceneStart) -> SceneTerm:
        """The term's starting point: fields measured on the sim images ([n, R, B], max-normalised), searched
        fields where `scene` puts the real setting."""


def kind_of(effect: Effect) -> Kind:
    return effect.KIND if isinstance(effect, SceneTerm) else "effect"


def scene_term_starts(sim_images: np.ndarray, scene: SceneStart) -> dict[str, SceneTerm]:
    """Every registered term's starting point for these sim images."""
    scene.validate()
    return {name: cls.start(sim_images, scene) for name, cls in SCENE_TERMS.items()}


def apply_scene_terms(frame: SonarImage, terms: Sequence[SceneTerm], rng: np.random.Generator) -> SonarImage:
    """`frame` (any dtype) with the terms applied in registration order, as float32 amplitude."""
    intensity = frame.normalized().astype(np.float32)
    for name in SCENE_TERMS:
        for term in terms:
            if term.name == name:
                intensity = term.apply(intensity, frame, rng)
    return frame.replace(intensity=np.maximum(intensity, 0.0).astype(np.float32), intensity_scale=1.0)
