"""Texture statistics of image sets on the model grid, and their distance from a real reference set.

* Power spectra: mean log10 power, radially averaged and along each axis (range, beam) separately,
  because sonar grain is anisotropic (range resolution and beam width differ).
* Checkerboard score: the strongest spectral peak at the periods a stride-2 upsampler leaves (2 and 4
  cells), in decades above the spectrum next to it — the artefact the cDFCVAE authors saw in Fourier space.
* Speckle shape per range band: contrast (std/mean; 0.52 for Rayleigh amplitude), Weibull shape k and
  K-distribution shape nu (moments), on amplitudes divided by their local mean so that objects and
  shadows do not count as speckle. Intensity statistics change with range (TVG, grazing angle), hence bands.
* Intensity histogram and its earth mover's distance to the real one.
* Grain: lag-1 correlation of the texture (image minus its local mean) along range and across beams, on frames
  at their own resolution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from sonar_realism.errors import ConfigError

CHECKERBOARD_FREQUENCIES = (0.25, 0.5)  # cycles per cell: periods 4 and 2
N_RANGE_BANDS = 4
HISTOGRAM_BINS = 64
LOCAL_MEAN_SIGMA = 4.0  # grid cells: larger than the speckle grain, smaller than objects
K_SHAPE_CAP = 100.0  # nu above this is indistinguishable from Rayleigh with tens of thousands of cells
# Cells whose local mean is below this fraction of the frame's 99th percentile hold no speckle to measure (a clean
# simulator's empty water column, a shadow): their ratios are leakage from bright neighbours, not texture.
SPECKLE_FLOOR_FRACTION = 0.02
# A band where fewer cells than this fraction hold speckle has no statistics (NaN), rather than a few edge cells'.
SPECKLE_MIN_COVERAGE = 0.05


def _check(images: np.ndarray) -> np.ndarray:
    images = np.asarray(images, np.float64)
    if images.ndim != 3 or len(images) == 0:
        raise ConfigError(f"texture statistics: expected images [N, rows, cols], got shape {images.shape}")
    return images


def _power(images: np.ndarray) -> np.ndarray:
    """|FFT|^2 of each mean-removed, Hann-windowed image, [N, rows, cols], zero frequency at [0, 0]."""
    rows, cols = images.shape[1:]
    window = np.outer(np.hanning(rows), np.hanning(cols))
    centred = (images - images.mean(axis=(1, 2), keepdims=True)) * window
    return np.abs(np.fft.fft2(centred)) ** 2


@dataclass(frozen=True)
class Spectra:
    """Mean log10 power; frequencies in cycles per grid cell (0 .. 0.5)."""

    radial_freq: np.ndarray
    radial: np.ndarray
    range_freq: np.ndarray
    along_range: np.ndarray
    beam_freq: np.ndarray
    along_beam: np.ndarray


def power_spectra(images: np.ndarray) -> Spectra:
    images = _check(images)
    rows, cols = images.shape[1:]
    power = _power(images).mean(axis=0) + 1e-12
    fy, fx = np.fft.fftfreq(rows), np.fft.fftfreq(cols)
    radius = np.hypot(fy[:, None], fx[None, :])
    n_bins = min(rows, cols) // 2
    edges = np.linspace(0.0, 0.5, n_bins + 1)
    which = np.digitize(radius.ravel(), edges) - 1
    keep = (which >= 0) & (which < n_bins)
    sums = np.bincount(which[keep], weights=power.ravel()[keep], minlength=n_bins)
    counts = np.maximum(np.bincount(which[keep], minlength=n_bins), 1)
    # Along one axis: 1-D spectra of every column (or row), averaged; keeps the half up to Nyquist.
    windowed = images - images.mean(axis=(1, 2), keepdims=True)
    range_power = (np.abs(np.fft.rfft(windowed * np.hanning(rows)[None, :, None], axis=1)) ** 2).mean(axis=(0, 2))
    beam_power = (np.abs(np.fft.rfft(windowed * np.hanning(cols)[None, None, :], axis=2)) ** 2).mean(axis=(0, 1))
    return Spectra(radial_freq=0.5 * (edges[:-1] + edges[1:]), radial=np.log10(sums / counts + 1e-12),
                   range_freq=np.fft.rfftfreq(rows), along_range=np.log10(range_power + 1e-12),
                   beam_freq=np.fft.rfftfreq(cols), along_beam=np.log10(beam_power + 1e-12))


def spectral_distance(a: Spectra, b: Spectra) -> float:
    """Mean |difference| of the radial log10 spectra (decades), skipping the zero-frequency bin."""
    return float(np.abs(a.radial[1:] - b.radial[1:]).mean())


def checkerboard_score(spectra: Spectra) -> float:
    """Largest peak (decades) at periods 2 and 4 along either axis, over the median of its neighbours."""
    peaks = []
    for freq, log_power in ((spectra.range_freq, spectra.along_range), (spectra.beam_freq, spectra.along_beam)):
        for target in CHECKERBOARD_FREQUENCIES:
            at = int(np.argmin(np.abs(freq - target)))
            near = (np.abs(freq - target) <= 0.08) & (np.arange(freq.size) != at)
            if near.any():
                peaks.append(float(log_power[at] - np.median(log_power[near])))
    return max(peaks)


def _weibull_shape(contrast: float) -> float:
    """Weibull k whose std/mean equals `contrast` (bisection; the ratio falls monotonically with k)."""
    def ratio(k: float) -> float:
        g1, g2 = math.lgamma(1 + 1 / k), math.lgamma(1 + 2 / k)
        return math.sqrt(max(math.exp(g2 - 2 * g1) - 1.0, 0.0))

    low, high = 0.1, 50.0
    if contrast >= ratio(low):
        return low
    if contrast <= ratio(high):
        return high
    for _ in range(60):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if ratio(mid) > contrast else (low, mid)
    return 0.5 * (low + high)


@dataclass(frozen=True)
class SpeckleBand:
    contrast: float
    weibull_k: float
    k_shape: float  # K-distribution nu, capped at K_SHAPE_CAP (Rayleigh limit)


def speckle_statistics(images: np.ndarray, n_bands: int = N_RANGE_BANDS) -> list[SpeckleBand]:
    """Speckle shape per range band (rows split into `n_bands` equal bands, nearest first)."""
    images = _check(images)
    normalised = []
    for image in images.astype(np.float32):
        local = cv2.GaussianBlur(image, (0, 0), LOCAL_MEAN_SIGMA)
        floor = max(1e-3, SPECKLE_FLOOR_FRACTION * float(np.percentile(image, 99)))
        normalised.append(np.where(local > floor, image / np.maximum(local, floor), np.nan))
    stack = np.stack(normalised)
    bands = []
    for rows in np.array_split(np.arange(images.shape[1]), n_bands):
        amplitude = stack[:, rows].ravel()
        amplitude = amplitude[np.isfinite(amplitude)]
        if amplitude.size < max(2, SPECKLE_MIN_COVERAGE * stack[:, rows].size) or amplitude.mean() <= 0:
            bands.append(SpeckleBand(float("nan"), float("nan"), float("nan")))
            continue
        contrast = float(amplitude.std() / amplitude.mean())
        intensity = amplitude ** 2
        moment_ratio = float((intensity ** 2).mean() / intensity.mean() ** 2)
        k_shape = K_SHAPE_CAP if moment_ratio <= 2.0 else min(2.0 / (moment_ratio - 2.0), K_SHAPE_CAP)
        bands.append(SpeckleBand(contrast, _weibull_shape(contrast), k_shape))
    return bands


def speckle_distance(a: list[SpeckleBand], b: list[SpeckleBand]) -> float:
    """Mean |difference| of the speckle contrast over range bands."""
    return float(np.nanmean([abs(x.contrast - y.contrast) for x, y in zip(a, b, strict=True)]))


def intensity_histogram(images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(bin centres, density) of all cell values in [0, 1]."""
    images = _check(images)
    density, edges = np.histogram(np.clip(images, 0, 1), bins=HISTOGRAM_BINS, range=(0.0, 1.0), density=True)
    return 0.5 * (edges[:-1] + edges[1:]), density


def histogram_distance(images_a: np.ndarray, images_b: np.ndarray) -> float:
    """Earth mover's (Wasserstein-1) distance between the two sets' cell-value distributions, in [0, 1]."""
    _, pa = intensity_histogram(images_a)
    _, pb = intensity_histogram(images_b)
    width = 1.0 / HISTOGRAM_BINS
    return float(np.abs(np.cumsum(pa - pb) * width).sum() * width)


@dataclass(frozen=True)
class Grain:
    along_range: float  # lag-1 correlation of neighbouring range bins
    across_beams: float  # lag-1 correlation of neighbouring beams


def grain(frames: list[np.ndarray]) -> Grain:
    """Mean lag-1 correlations of each frame's texture (frame minus its Gaussian local mean, sigma 3 bins)."""
    if not frames:
        raise ConfigError("grain: no frames")
    along, across = [], []
    for frame in frames:
        image = np.asarray(frame, np.float32)
        texture = (image - cv2.GaussianBlur(image, (0, 0), 3.0)).astype(np.float64)
        texture -= texture.mean()
        power = float((texture ** 2).mean()) + 1e-18
        along.append(float((texture[1:] * texture[:-1]).mean()) / power)
        across.append(float((texture[:, 1:] * texture[:, :-1]).mean()) / power)
    return Grain(along_range=float(np.mean(along)), across_beams=float(np.mean(across)))


def range_asymmetry(frames: list[np.ndarray]) -> float:
    """Mean over frames of the skewness of the log-intensity steps along range on the lit seabed: > 0 where the
    texture rises sharply and falls slowly with range, 0 for any texture that looks the same read backwards.

    A texture's grain, marginal and whole power spectrum are all blind to the direction of range; real sonar
    texture is not (the Oculus recordings: +0.58 and +0.30), while texture drawn from a Gaussian field through a
    pointwise map, as the speckle layer's, reads 0 whatever its grain (-0.01 for the calibrated sim). Each frame is
    scaled to its maximum; lit pixels are those whose 15 x 15 local mean is above the frame's median local mean;
    one count (1/255) is added before the log so the black floor does not dominate."""
    if not frames:
        raise ConfigError("range asymmetry: no frames")
    skews = []
    for frame in frames:
        image = np.asarray(frame, np.float32)
        image = image / max(float(image.max()), 1e-12)
        local = cv2.blur(image, (15, 15))
        lit = local > np.median(local)
        steps = np.diff(np.log(image + 1 / 255), axis=0)[lit[1:] & lit[:-1]].astype(np.float64)
        if steps.size < 3 or steps.std() == 0:
            continue
        centred = steps - steps.mean()
        skews.append(float((centred ** 3).mean() / (centred ** 2).mean() ** 1.5))
    return float(np.mean(skews)) if skews else math.nan
