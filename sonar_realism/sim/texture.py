"""The real sensor's own texture for the calibrated simulator: speckle fitted on the recording, not modelled.

The catalogue's `speckle` effect is a physical model (a complex Gaussian field times a gamma texture) with a
few parameters; a real sensor's grain also carries its beamformer's correlation across beams, per-beam
stripes, the noise floor and the export's quantisation, and a two-sample test on level-free texture patches
tells the two apart at once. So `calibrate` also fits the recording's texture with the translator's speckle
model (models/speckle.py): the ratio of each real frame to its local mean level (a Gaussian blur of one cell
of the 128 x 128 model grid, the level the cDFCVAE learns), as a level-binned quantile table plus a grain
kernel. `simulate --calibration` then draws the simulated frame's texture from that fit in place of the
`speckle` effect, on the output level (after the output mapping): the simulated mean level, the sensor's
speckle on top, exported as the recording was.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.models.speckle_fit import GRAIN_GROUPS, KERNEL_SIZE, LEVEL_BINS, QUANTILES, TILE, fit_speckle

if TYPE_CHECKING:
    from sonar_realism.models.speckle import SpeckleField

MODEL_GRID = 128  # the local mean is the level on a 128 x 128 grid, the cDFCVAE's
MIN_BLUR = 2.0  # samples
FIT_FRAMES = 96  # frames the fit uses, evenly spaced over the recording
REPLACES = ("speckle",)  # the catalogue effects the fitted texture stands in for


@dataclass(frozen=True)
class SensorTexture:
    """A fitted speckle model (see models/speckle.py for what each table means); `kernel` holds one grain
    kernel per group of level bins."""

    level_edges: tuple[float, ...]
    ratio_quantiles: tuple[tuple[float, ...], ...]
    kernel: tuple[tuple[tuple[float, ...], ...], ...]

    def validate(self) -> None:
        shapes = {"level_edges": ((LEVEL_BINS - 1,), np.asarray(self.level_edges, dtype=np.float64)),
                  "ratio_quantiles": ((LEVEL_BINS, QUANTILES), np.asarray(self.ratio_quantiles, dtype=np.float64)),
                  "kernel": ((GRAIN_GROUPS, KERNEL_SIZE, KERNEL_SIZE), np.asarray(self.kernel, dtype=np.float64))}
        for name, (shape, values) in shapes.items():
            if values.shape != shape or not np.isfinite(values).all():
                raise ConfigError(f"texture.{name}: expected {shape} finite numbers, got shape {values.shape}")
        if (np.diff(shapes["ratio_quantiles"][1], axis=1) < 0).any():
            raise ConfigError("texture.ratio_quantiles: each row must be non-decreasing")


@functools.lru_cache(maxsize=4)
def _speckle_field(texture: SensorTexture) -> SpeckleField:
    from sonar_realism.models.speckle import SpeckleField

    speckle = SpeckleField()
    speckle.set_fit(np.asarray(texture.level_edges), np.asarray(texture.ratio_quantiles), np.asarray(texture.kernel))
    return speckle


def local_mean(image: np.ndarray) -> np.ndarray:
    """The frame's level: a Gaussian blur of one model-grid cell along range and across beams, and at least
    MIN_BLUR samples (a smaller frame's cell is finer than the speckle grain the ratio must keep)."""
    rows, cols = image.shape
    return cv2.GaussianBlur(image.astype(np.float32), (0, 0), sigmaX=max(cols / MODEL_GRID, MIN_BLUR),
                            sigmaY=max(rows / MODEL_GRID, MIN_BLUR), borderType=cv2.BORDER_REFLECT_101)


def _rounded(values: np.ndarray) -> tuple:
    if values.ndim == 1:
        return tuple(float(f"{v:.6g}") for v in values)
    return tuple(_rounded(row) for row in values)


def fit_texture(images: list[np.ndarray], seed: int = 0) -> SensorTexture:
    """Fit on real frames scaled to their maximum, [ranges, beams] at the sensor's resolution."""
    usable = [image for image in images if min(image.shape) >= TILE]
    if not usable:
        raise ConfigError(f"texture: no frame is at least {TILE} x {TILE} samples; cannot fit the sensor's texture")
    chosen = [usable[i] for i in np.linspace(0, len(usable) - 1, min(FIT_FRAMES, len(usable))).astype(int)]
    edges, table, kernel = fit_speckle([image.astype(np.float32) for image in chosen],
                                       [local_mean(image) for image in chosen], seed=seed)
    texture = SensorTexture(_rounded(edges), _rounded(np.maximum.accumulate(table, axis=1)), _rounded(kernel))
    texture.validate()
    return texture


def apply_texture(texture: SensorTexture, frame: SonarImage, rng: np.random.Generator) -> SonarImage:
    """The frame's local mean level times a fresh draw of the sensor's speckle, exported as the recording was
    (scaled to its maximum, 8-bit)."""
    import torch

    level = frame.intensity.astype(np.float32)
    level = local_mean(level / max(float(level.max()), 1e-12))
    generator = torch.Generator().manual_seed(int(rng.integers(0, 2 ** 62)))
    sample = _speckle_field(texture).sample(level[None], generator)[0]
    return frame.replace(intensity=np.rint(sample * 255.0).astype(np.uint8), intensity_scale=255.0)
