"""The calibration targets of a set of frames: what the effect refit matches between simulation and recording.

Frames are compared as the real export made them: rescaled per frame so the maximum is 1.

- intensity histogram (Wasserstein-1 distance between the grey-level distributions);
- speckle grain: autocorrelation of the detrended image at lags 1-3 across beams and along range;
- range profile: row mean against normalised range and the row 10th percentile (noise floor); bearing profile;
- near-field band: mean of the first 2 % of rows (ring-down) and of the next 2-8 % (the dark zone behind it);
- beam stripes: rms across beams of the column means, detrended across beams, over their mean, on the far half (the
  lit seabed: a gain error per beam) and on the top quarter (the water column: per-beam noise and grain);
- near-zero share (black water) and speckle contrast (the frame over its local mean, as evaluate.texture has it).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from sonar_realism.errors import ConfigError

PROFILE_BINS = 48
HIST_BINS = 64
MAX_LAG = 3
DETREND_BOX = 9
STRIPE_BOX = 15
NEAR_ZERO = 2.5 / 255
SPECKLE_SIGMA = 4.0


@dataclass(frozen=True)
class Fingerprint:
    """The calibration targets of a set of frames (all in units of the frame maximum)."""

    histogram: np.ndarray  # [HIST_BINS] density over [0, 1]
    acf_beams: np.ndarray  # [MAX_LAG]
    acf_ranges: np.ndarray  # [MAX_LAG]
    row_mean: np.ndarray  # [PROFILE_BINS]
    row_floor: np.ndarray  # [PROFILE_BINS]
    column_mean: np.ndarray  # [PROFILE_BINS]
    near_band: float
    dark_zone: float
    stripes: float  # of the lit seabed (far half)
    water_stripes: float  # of the water column (top quarter)
    near_zero: float  # share of pixels at or below 2 counts of 255
    speckle_contrast: float  # std / mean of the frame over its local mean (Gaussian, sigma 4 cells)

    def as_dict(self) -> dict[str, Any]:
        return {k: (v.round(4).tolist() if isinstance(v, np.ndarray) else round(v, 4))
                for k, v in dataclasses.asdict(self).items()}


def per_frame_rescaled(image: np.ndarray) -> np.ndarray:
    """What the real set's export did: raw * 255 / raw.max(), as float in [0, 1]."""
    image = image.astype(np.float32)
    peak = float(image.max())
    return image / peak if peak > 0 else image


def resample_profile(profile: np.ndarray, bins: int) -> np.ndarray:
    x = (np.arange(profile.size) + 0.5) / profile.size
    return np.interp((np.arange(bins) + 0.5) / bins, x, profile)


def _acf(detrended: np.ndarray, weight: np.ndarray, axis: int) -> np.ndarray:
    out = np.empty(MAX_LAG)
    var = float((detrended * detrended * weight).sum()) + 1e-12
    n = detrended.shape[axis]
    for lag in range(1, MAX_LAG + 1):
        a = detrended.take(np.arange(n - lag), axis=axis)
        b = detrended.take(np.arange(lag, n), axis=axis)
        w = weight.take(np.arange(n - lag), axis=axis) * weight.take(np.arange(lag, n), axis=axis)
        out[lag - 1] = float((a * b * w).sum()) / var
    return out


def stripe_level(rows: np.ndarray) -> float:
    """Per-beam stripes of a band of rows: rms of its column means about their running mean, over the mean."""
    columns = rows.mean(axis=0).astype(np.float32)
    trend = cv2.blur(columns.reshape(1, -1), (STRIPE_BOX, 1), borderType=cv2.BORDER_REFLECT_101).ravel()
    return float(np.sqrt(((columns - trend) ** 2).mean()) / max(float(columns.mean()), 1e-6))


def seabed_stripes(image: np.ndarray) -> float:
    """Stripes of the far half, where the seabed is lit and a per-beam gain error is what lines a column up.

    Kept apart from the water column's: there the noise and the sensor's own grain (smeared along range) stripe
    the columns too, and matching one gain error to those stripes doubled it on the seabed (Oculus recording:
    0.035 there, 0.049 in the water column)."""
    return stripe_level(image[image.shape[0] // 2:])


def water_stripes(image: np.ndarray) -> float:
    """Stripes of the top quarter (the water column before the seabed)."""
    return stripe_level(image[: max(4, image.shape[0] // 4)])


def speckle_contrast(image: np.ndarray) -> float:
    """Speckle contrast: std / mean of the frame divided by its local mean, where that mean is above the floor."""
    local = cv2.GaussianBlur(image, (0, 0), SPECKLE_SIGMA)
    floor = max(1e-3, 0.05 * float(np.percentile(image, 99)))
    ratio = image[local > floor] / local[local > floor]
    return float(ratio.std() / ratio.mean()) if ratio.size > 16 else math.nan


def fingerprint(images: Sequence[np.ndarray]) -> Fingerprint:
    """Targets of images already rescaled to [0, 1] (each [n_ranges, n_beams], any n_ranges)."""
    if not images:
        raise ConfigError("calibrate: no frames to measure")
    hist = np.zeros(HIST_BINS)
    acf_b, acf_r = np.zeros(MAX_LAG), np.zeros(MAX_LAG)
    means, floors, columns, near, dark, stripes, water, zeros, contrasts = [], [], [], [], [], [], [], [], []
    for image in images:
        hist += np.histogram(image, bins=HIST_BINS, range=(0.0, 1.0))[0]
        local = cv2.blur(image, (DETREND_BOX, DETREND_BOX), borderType=cv2.BORDER_REFLECT_101)
        detrended = image - local
        weight = np.ones_like(image)  # every pixel, as the evaluation's grain statistic counts them
        acf_b += _acf(detrended, weight, axis=1)
        acf_r += _acf(detrended, weight, axis=0)
        means.append(resample_profile(image.mean(axis=1), PROFILE_BINS))
        floors.append(resample_profile(np.percentile(image, 10, axis=1), PROFILE_BINS))
        columns.append(resample_profile(image.mean(axis=0), PROFILE_BINS))
        rows = image.shape[0]
        near.append(float(image[: max(1, rows // 50)].mean()))
        dark.append(float(image[max(1, rows // 50): max(2, rows * 8 // 100)].mean()))
        stripes.append(seabed_stripes(image))
        water.append(water_stripes(image))
        zeros.append(float((image <= NEAR_ZERO).mean()))
        contrasts.append(speckle_contrast(image))
    n = len(images)
    return Fingerprint(hist / hist.sum() * HIST_BINS, acf_b / n, acf_r / n, np.mean(means, axis=0),
                       np.mean(floors, axis=0), np.mean(columns, axis=0), float(np.mean(near)),
                       float(np.mean(dark)), float(np.mean(stripes)), float(np.mean(water)), float(np.mean(zeros)),
                       float(np.nanmean(contrasts)))


def distance(sim: Fingerprint, real: Fingerprint) -> dict[str, float]:
    """Per-target mismatch (all O(0.01-0.1) when close) and their sum `total`."""
    cdf_sim = np.cumsum(sim.histogram) / HIST_BINS
    cdf_real = np.cumsum(real.histogram) / HIST_BINS
    parts = {
        "histogram_w1": float(np.abs(cdf_sim - cdf_real).mean()),
        "grain_beams": float(np.abs(sim.acf_beams - real.acf_beams).mean()),
        "grain_ranges": float(np.abs(sim.acf_ranges - real.acf_ranges).mean()),
        "range_profile": float(np.abs(sim.row_mean - real.row_mean).mean()),
        "bearing_profile": float(np.abs(sim.column_mean - real.column_mean).mean()),
        "noise_floor": float(np.abs(sim.row_floor - real.row_floor).mean()),
        "near_band": abs(sim.near_band - real.near_band) + abs(sim.dark_zone - real.dark_zone),
        "stripes": 0.2 * (abs(sim.stripes - real.stripes) + abs(sim.water_stripes - real.water_stripes)),
        "near_zero": abs(sim.near_zero - real.near_zero),
        "speckle_contrast": abs(sim.speckle_contrast - real.speckle_contrast),
    }
    parts["total"] = float(sum(parts.values()))
    return parts
