"""Per-family image statistics of polar sonar frames: cheap, physically meaningful summaries.

Each family answers one question a sonar engineer asks when a simulated frame "looks wrong":

- intensity:       how are the grey levels distributed (quantiles, dark/saturated fractions, 8-bit steps)?
- speckle:         what is the shape of the speckle (local contrast CV and 4th-moment ratio, per level)?
- grain:           how large is the grain along range and along beam (autocorrelation; leakage beside
                   bright echoes, which shows beam sidelobes and range smear)?
- spectrum:        how is the texture power spread over octave bands of spatial frequency, along range and
                   along beam?
- range_profile:   how does the mean brightness change with range (TVG, ring-down, bright arcs)?
- bearing_profile: how does it change across the fan (beam pattern, gain ripple)?

`frame_statistics` turns a batch `[n_frames, n_ranges, n_beams]` of floats in [0, 1] into one feature row per
frame and family; distances between sets of rows are the business of the caller (diagnose, evaluate). All
features are finite for any input (flat or black frames included).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage

FAMILIES = ("intensity", "speckle", "grain", "spectrum", "range_profile", "bearing_profile")

INTENSITY_QUANTILES = (0.01, 0.05, 0.1, 0.25, 0.5, 0.75, 0.9, 0.95, 0.99, 0.999)
# Patch-mean levels separating dark (noise floor), mid (background) and bright (targets, seabed band) patches.
SPECKLE_LEVELS = (0.0, 0.1, 0.3, 1.01)
_HIST_LEVELS = 1024  # quantisation used for fast per-frame quantiles (error < 0.001 of full scale)
_EPS = 1e-6


@dataclass(frozen=True)
class StatisticsConfig:
    """patch: side (pixels) of the square patches for local speckle contrast; profile_bins: bins of the range and
    bearing profiles; n_bands: octave bands of the spectra (the lowest band takes everything below);
    acf_lags: autocorrelation lags reported along each axis; detrend: box size removing scene structure before
    texture statistics; bright_pixels: brightest pixels per frame used for the leakage features."""

    patch: int = 8
    profile_bins: int = 32
    n_bands: int = 6
    acf_lags: int = 4
    detrend: int = 9
    bright_pixels: int = 32
    min_patch_mean: float = 0.01

    def validate(self) -> None:
        if self.patch < 2:
            raise ConfigError(f"StatisticsConfig.patch: need >= 2 pixels, got {self.patch}")
        if self.profile_bins < 1 or self.n_bands < 2 or self.acf_lags < 1 or self.bright_pixels < 1:
            raise ConfigError("StatisticsConfig: profile_bins >= 1, n_bands >= 2, acf_lags >= 1, bright_pixels >= 1")
        if self.detrend < 3 or self.detrend % 2 == 0:
            raise ConfigError(f"StatisticsConfig.detrend: need an odd box size >= 3, got {self.detrend}")
        if not 0.0 <= self.min_patch_mean < 1.0:
            raise ConfigError(f"StatisticsConfig.min_patch_mean: must be in [0, 1), got {self.min_patch_mean}")

    def min_shape(self) -> tuple[int, int]:
        """Smallest (n_ranges, n_beams) these statistics are defined on."""
        side = max(2 * self.patch, self.detrend + 2 * self.acf_lags, 2 ** (self.n_bands + 1), self.profile_bins)
        return side, side


def as_float_batch(frames: Iterable[SonarImage]) -> np.ndarray:
    """Stack frames (all of one shape) as float32 [n, n_ranges, n_beams] in [0, 1]; samples become frames."""
    arrays = []
    for frame in frames:
        x = frame.normalized()
        arrays.extend(x if x.ndim == 3 else [x])
    if not arrays:
        raise ConfigError("no frames to compute statistics on")
    shapes = {a.shape for a in arrays}
    if len(shapes) > 1:
        raise ConfigError(f"frames have different shapes {sorted(shapes)}; resample them to one grid first")
    return np.stack(arrays).astype(np.float32, copy=False)


def feature_names(config: StatisticsConfig = StatisticsConfig()) -> dict[str, list[str]]:
    """Names of the columns `frame_statistics` returns, per family."""
    lags = range(1, config.acf_lags + 1)
    bands = [f"band{b}" for b in range(config.n_bands)]
    return {
        "intensity": [f"q{q:g}" for q in INTENSITY_QUANTILES] + ["mean", "std", "dark_fraction",
                                                                   "saturated_fraction", "quantized_fraction"],
        "speckle": ["cv_q25", "cv_q50", "cv_q75"]
                   + [f"cv_level{i}" for i in range(len(SPECKLE_LEVELS) - 1)] + ["moment_ratio"],
        "grain": [f"acf_range_lag{k}" for k in lags] + [f"acf_beam_near_lag{k}" for k in lags]
                 + [f"acf_beam_far_lag{k}" for k in lags]
                 + ["acf_range_long_max", "acf_beam_long_max", "leak_beam", "leak_range"],
        "spectrum": [f"range_{b}" for b in bands] + [f"beam_{b}" for b in bands],
        "range_profile": [f"mean_bin{i}" for i in range(config.profile_bins)]
                         + ["row0", "row1", "row2", "row3", "row_roughness", "row_outlier"],
        "bearing_profile": [f"mean_bin{i}" for i in range(config.profile_bins)]
                           + ["column_roughness", "column_outlier"],
    }


def frame_statistics(images: np.ndarray, config: StatisticsConfig = StatisticsConfig(),
                     families: Sequence[str] = FAMILIES) -> dict[str, np.ndarray]:
    """Feature rows `{family: float64 [n_frames, n_features]}` of a batch `[n, n_ranges, n_beams]` in [0, 1]."""
    images = np.asarray(images, dtype=np.float32)
    if images.ndim == 2:
        images = images[None]
    if images.ndim != 3 or images.shape[0] == 0:
        raise ConfigError(f"statistics need a batch [n_frames, n_ranges, n_beams], got shape {images.shape}")
    need = config.min_shape()
    if images.shape[1] < need[0] or images.shape[2] < need[1]:
        raise ConfigError(f"frames of {images.shape[1]} ranges x {images.shape[2]} beams are too small for the "
                          f"statistics; need at least {need[0]} x {need[1]}")
    unknown = sorted(set(families) - set(FAMILIES))
    if unknown:
        raise ConfigError(f"unknown statistics families {unknown}; known: {', '.join(FAMILIES)}")
    out: dict[str, list[np.ndarray]] = {f: [] for f in families}
    for start in range(0, images.shape[0], 32):  # chunks bound the temporary memory
        chunk = images[start:start + 32]
        detrended = _detrend(chunk, config.detrend) if {"grain", "spectrum"} & set(families) else None
        for family in families:
            if family == "intensity":
                out[family].append(intensity_features(chunk))
            elif family == "speckle":
                out[family].append(speckle_features(chunk, config.patch, config.min_patch_mean))
            elif family == "grain":
                out[family].append(grain_features(chunk, detrended, config))
            elif family == "spectrum":
                out[family].append(spectrum_features(chunk, config.n_bands))
            elif family == "range_profile":
                out[family].append(range_profile_features(chunk, config.profile_bins))
            else:
                out[family].append(bearing_profile_features(chunk, config.profile_bins))
    return {f: np.nan_to_num(np.concatenate(rows).astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
            for f, rows in out.items()}


# --- intensity -------------------------------------------------------------------------------------------------

def level_histograms(images: np.ndarray, levels: int = _HIST_LEVELS) -> np.ndarray:
    """Per-frame histograms [n, levels] of values in [0, 1], as fractions of the pixels."""
    half_bin = 0.5 / (levels - 1)  # bin k holds values that round to k / (levels - 1)
    counts = np.stack([cv2.calcHist([np.ascontiguousarray(x, dtype=np.float32)], [0], None, [levels],
                                    [-half_bin, 1.0 + half_bin]).ravel() for x in images])
    # values outside [0, 1] (none after SonarImage.normalized) would fall outside the bins; clip-count them in
    counts[:, 0] += (images < -half_bin).sum(axis=(1, 2))
    counts[:, -1] += (images >= 1.0 + half_bin).sum(axis=(1, 2))
    return counts / float(images[0].size)


def intensity_features(images: np.ndarray) -> np.ndarray:
    hist = level_histograms(images)
    cdf = np.cumsum(hist, axis=1)
    quantiles = np.stack([np.argmax(cdf >= q, axis=1) for q in INTENSITY_QUANTILES], axis=1) / (_HIST_LEVELS - 1)
    flat = images.reshape(images.shape[0], -1)
    # 8-bit sensors put every pixel on a multiple of 1/255; a float simulator almost never does (a subsample of
    # the pixels measures that fraction well enough).
    steps = flat[:, ::7] * 255.0
    quantized = (np.abs(steps - np.round(steps)) < 1e-3).mean(axis=1)
    return np.column_stack([quantiles, flat.mean(axis=1), flat.std(axis=1), (flat <= 1.5 / 255).mean(axis=1),
                            (flat >= 253.5 / 255).mean(axis=1), quantized])


# --- speckle shape -----------------------------------------------------------------------------------------------

def patch_moments(images: np.ndarray, patch: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, std and 4th-moment ratio <x^4>/<x^2>^2 of non-overlapping patch x patch tiles: each [n, rows, cols]."""
    n, r, b = images.shape
    rows, cols = r // patch, b // patch
    mean, second, fourth = (np.empty((n, rows, cols), dtype=np.float32) for _ in range(3))
    # an area resize by a whole factor is the tiles' mean, about 7x faster than a mean over two axes of a 5-D view
    # (the diagnosis computes these for every candidate fit)
    for i, image in enumerate(images[:, :rows * patch, :cols * patch] if rows and cols else ()):
        image = np.ascontiguousarray(image, dtype=np.float32)
        square = image * image
        for moment, values in ((mean, image), (second, square), (fourth, square * square)):
            moment[i] = cv2.resize(values, (cols, rows), interpolation=cv2.INTER_AREA)
    std = np.sqrt(np.maximum(second - mean * mean, 0.0))
    return mean, std, fourth / np.maximum(second * second, _EPS * _EPS)


def speckle_features(images: np.ndarray, patch: int, min_mean: float) -> np.ndarray:
    mean, std, ratio = patch_moments(images, patch)
    cv = std / np.maximum(mean, _EPS)
    rows = []
    for i in range(images.shape[0]):
        valid = mean[i] > min_mean
        cvs = cv[i][valid]
        if cvs.size == 0:  # a black frame has no speckle: report zero contrast
            rows.append(np.zeros(3 + len(SPECKLE_LEVELS) - 1 + 1))
            continue
        q25, q50, q75 = np.quantile(cvs, (0.25, 0.5, 0.75))
        by_level = []
        for lo, hi in zip(SPECKLE_LEVELS[:-1], SPECKLE_LEVELS[1:], strict=True):
            in_level = valid & (mean[i] >= lo) & (mean[i] < hi)
            by_level.append(float(np.median(cv[i][in_level])) if in_level.any() else q50)
        rows.append(np.array([q25, q50, q75, *by_level, float(np.median(ratio[i][valid]))]))
    return np.stack(rows)


# --- grain size --------------------------------------------------------------------------------------------------

def _detrend(images: np.ndarray, box: int) -> np.ndarray:
    """Images minus their local mean: keeps speckle and fine texture, removes scene layout."""
    return np.stack([x - cv2.blur(x, (box, box), borderType=cv2.BORDER_REFLECT) for x in images])


def lag_correlation(detrended: np.ndarray, axis: int, max_lag: int) -> np.ndarray:
    """Normalised autocorrelation [n, max_lag] at lags 1..max_lag along `axis` (1 = range, 2 = beam)."""
    # Every 2nd line across the axis halves the cost; the correlation is a mean over lines anyway.
    detrended = detrended[:, :, ::2] if axis == 1 else detrended[:, ::2, :]
    energy = np.maximum((detrended * detrended).sum(axis=(1, 2)), _EPS)
    out = np.empty((detrended.shape[0], max_lag))
    for k in range(1, max_lag + 1):
        if axis == 1:
            products = detrended[:, :-k, :] * detrended[:, k:, :]
        else:
            products = detrended[:, :, :-k] * detrended[:, :, k:]
        out[:, k - 1] = products.sum(axis=(1, 2)) / energy
    return out


def long_lag_correlation(detrended: np.ndarray, axis: int, min_lag: int) -> np.ndarray:
    """Largest autocorrelation [n] at lags >= min_lag along `axis` (ghost copies, periodic artefacts), via FFT."""
    # Every 8th line across the axis is enough for a mean correlation and cuts the FFT cost eightfold.
    detrended = detrended[:, :, ::8] if axis == 1 else detrended[:, ::8, :]
    length = detrended.shape[axis]
    spectrum = np.fft.rfft(detrended, n=2 * length, axis=axis)
    acf = np.fft.irfft(spectrum.real ** 2 + spectrum.imag ** 2, axis=axis)
    acf = acf.sum(axis=3 - axis)  # sum over the other image axis: [n, 2 * length]
    lags = acf[:, min_lag: length // 2]
    return lags.max(axis=1) / np.maximum(acf[:, 0], _EPS)


def brightest(flat: np.ndarray, count: int, block: int = 64) -> np.ndarray:
    """Indices [n, count] of the `count` largest values of each row of `flat` [n, m], in no order: the pixels
    `np.argpartition` picks. The `count`-th largest of the rows' block maxima cannot exceed the `count`-th largest
    value, so only the values at or above it are partitioned, about 6x faster than whole frames; where the last
    place is tied (8-bit frames) the whole row is partitioned, because which of the tied pixels are taken changes
    the leakage beside them and a rule of our own moved a no-effect diagnosis over its significance bound."""
    n, m = flat.shape
    if m < count * block:
        return np.argpartition(flat, -count, axis=1)[:, -count:]
    maxima = flat[:, : m // block * block].reshape(n, -1, block).max(axis=2)
    floors = np.partition(maxima, -count, axis=1)[:, -count]
    top = np.empty((n, count), dtype=np.intp)
    for i, (values, floor) in enumerate(zip(flat, floors, strict=True)):
        candidates = np.flatnonzero(values >= floor)
        above = values[candidates]
        in_top = above >= np.partition(above, -count)[-count]
        if np.count_nonzero(in_top) > count:
            top[i] = np.argpartition(values, -count)[-count:]
        else:
            top[i] = candidates[in_top]
    return top


def bright_leakage(images: np.ndarray, count: int, near: int = 2, far: int = 6) -> np.ndarray:
    """Mean of the pixels `near`..`far` beams (column 0) and range bins (column 1) away from each of the `count`
    brightest pixels, relative to that pixel: beam sidelobes raise the first, range smear the second."""
    n, r, b = images.shape
    flat = images.reshape(n, -1)
    top = brightest(flat, count)
    rows, cols = np.divmod(top, b)
    offsets = np.concatenate([np.arange(-far, -near + 1), np.arange(near, far + 1)])
    peak = np.maximum(np.take_along_axis(flat, top, axis=1), _EPS)
    frame = np.arange(n)[:, None, None]
    beam_side = images[frame, rows[..., None], np.clip(cols[..., None] + offsets, 0, b - 1)].mean(axis=2)
    range_side = images[frame, np.clip(rows[..., None] + offsets, 0, r - 1), cols[..., None]].mean(axis=2)
    return np.column_stack([(beam_side / peak).mean(axis=1), (range_side / peak).mean(axis=1)])


def grain_features(images: np.ndarray, detrended: np.ndarray | None, config: StatisticsConfig) -> np.ndarray:
    d = _detrend(images, config.detrend) if detrended is None else detrended
    half = images.shape[1] // 2
    along_range = lag_correlation(d, 1, config.acf_lags)
    beam_near = lag_correlation(d[:, :half], 2, config.acf_lags)
    beam_far = lag_correlation(d[:, half:], 2, config.acf_lags)
    long_min = 2 * config.acf_lags + 1
    return np.column_stack([along_range, beam_near, beam_far, long_lag_correlation(d, 1, long_min),
                            long_lag_correlation(d, 2, long_min),
                            bright_leakage(images, min(config.bright_pixels, images[0].size))])


# --- spatial spectrum --------------------------------------------------------------------------------------------

def octave_band_edges(length: int, n_bands: int) -> np.ndarray:
    """Bin indices of rfft frequencies bounding octave bands, highest band [N/4, N/2] first, lowest band last."""
    edges = [length // 2 + 1]
    for _ in range(n_bands - 1):
        edges.append(max(edges[-1] // 2, 2))
    edges.append(1)  # the DC bin (index 0) is excluded
    return np.array(edges)


def band_powers(images: np.ndarray, axis: int, n_bands: int) -> np.ndarray:
    """log10 fraction of the (mean-removed) power in each octave band along `axis`: [n, n_bands], high first."""
    lines = images[:, :, ::2] if axis == 1 else images[:, ::2, :]  # every 2nd line: half the cost, same mean
    centred = lines - lines.mean(axis=axis, keepdims=True)
    spectrum = np.fft.rfft(centred, axis=axis)
    power = spectrum.real ** 2 + spectrum.imag ** 2
    power = power.mean(axis=3 - axis)  # [n, n_freq]
    edges = octave_band_edges(images.shape[axis], n_bands)
    bands = np.stack([power[:, lo:hi].sum(axis=1) for hi, lo in zip(edges[:-1], edges[1:], strict=True)], axis=1)
    total = np.maximum(bands.sum(axis=1, keepdims=True), _EPS)
    return np.log10(np.maximum(bands / total, 1e-8))


def spectrum_features(images: np.ndarray, n_bands: int) -> np.ndarray:
    return np.column_stack([band_powers(images, 1, n_bands), band_powers(images, 2, n_bands)])


# --- range and bearing profiles ----------------------------------------------------------------------------------

def binned_profile(profile: np.ndarray, bins: int) -> np.ndarray:
    """Average [n, length] into `bins` equal bins: [n, bins]."""
    edges = np.linspace(0, profile.shape[1], bins + 1).round().astype(int)
    return np.stack([profile[:, lo:max(hi, lo + 1)].mean(axis=1) for lo, hi in zip(edges[:-1], edges[1:],
                                                                                  strict=True)], axis=1)


def profile_roughness(profile: np.ndarray, window: int = 15) -> np.ndarray:
    """Std and largest deviation [n, 2] of a profile from its moving average: narrow arcs, stripes, ripple."""
    kernel = np.ones(window) / window
    padded = np.pad(profile, ((0, 0), (window // 2, window // 2)), mode="reflect")
    smooth = np.stack([np.convolve(p, kernel, mode="valid") for p in padded])
    residual = profile - smooth
    return np.column_stack([residual.std(axis=1), np.abs(residual).max(axis=1)])


def range_profile(images: np.ndarray) -> np.ndarray:
    """Mean over beams of every range row: [n, n_ranges]."""
    return images.mean(axis=2)


def bearing_profile(images: np.ndarray) -> np.ndarray:
    """Mean over ranges of every beam: [n, n_beams]."""
    return images.mean(axis=1)


def range_profile_features(images: np.ndarray, bins: int) -> np.ndarray:
    rows = range_profile(images)
    return np.column_stack([binned_profile(rows, bins), rows[:, :4], profile_roughness(rows)])


def bearing_profile_features(images: np.ndarray, bins: int) -> np.ndarray:
    cols = bearing_profile(images)
    return np.column_stack([binned_profile(cols, bins), profile_roughness(cols)])
