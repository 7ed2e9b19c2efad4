"""Fitting the speckle model of models/speckle.py: numpy only, so the simulator's calibration (sim/texture.py)
fits and validates the same model without importing torch. See models/speckle.py for what the tables mean."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from sonar_realism.errors import ConfigError

LEVEL_BINS = 8
QUANTILES = 129
NORMAL_SPAN = 4.5  # the quantile table is spaced evenly in normal scores over [-span, span]: tails resolved
KERNEL_SIZE = 33  # odd; the grain of a forward-looking sonar spans a few bins, far less than this
# Level bins share a grain kernel in groups: on the real Oculus set the dark water column (per-beam stripes)
# is correlated along range at lag 1 about 0.6, the lit seabed about 0.25; one kernel for all levels gave
# everything about 0.43 (docs/RESULTS.md).
GRAIN_GROUPS = 4
TILE = 64
MEAN_FLOOR = 0.5 / 255.0  # below half an 8-bit step the ratio I / M says nothing about texture
EXPORT_LEVELS = 255  # the real set is 8-bit, scaled so that its brightest pixel is 255
EXPORT_TOP_QUANTILE = 0.999  # the export's knee is matched on a frame's 99.9th percentile over its maximum
EXPORT_KNEE_LOW = 0.05  # the lowest knee the matches search (full-scale units)


def highest_knee_at(top: Callable[[float], float], target: float, start: float = 1.0, step: float = 0.05,
                    refine: int = 6) -> float:
    """The highest knee in [EXPORT_KNEE_LOW, start] at which `top(knee)` (a sample's `top_ratio` under that
    knee) is down to `target`: a scan down in `step`s, then bisection between the last two knees. `start` when
    it is there already. The least compression that does it: below it, compressing further bends the whole top
    and the ratio rises again. Where no knee gets there, the one of the lowest ratio."""
    knee, best = start, (top(start), start)
    if best[0] <= target:
        return start
    while knee > EXPORT_KNEE_LOW:
        lower = max(knee - step, EXPORT_KNEE_LOW)
        ratio = top(lower)
        if ratio <= target:
            low, high = lower, knee  # top(low) <= target < top(high)
            for _ in range(refine):
                middle = 0.5 * (low + high)
                low, high = (middle, high) if top(middle) <= target else (low, middle)
            return low
        best = min(best, (ratio, lower))
        knee = lower
    return best[1]


def top_ratio(image: np.ndarray) -> float:
    """A frame's 99.9th percentile over its maximum: how light the top of its range is (0.96 on the Oculus set,
    whose brightest pixel is one of a handful, not a clipped plateau)."""
    values = np.asarray(image, np.float32).ravel()
    return float(np.quantile(values, EXPORT_TOP_QUANTILE) / max(float(values.max()), 1e-12))


def fit_speckle(images: list[np.ndarray], means: list[np.ndarray], seed: int = 0
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(level_edges [LEVEL_BINS-1], ratio_quantiles [LEVEL_BINS, QUANTILES],
    kernels [GRAIN_GROUPS, KERNEL_SIZE, KERNEL_SIZE]: one grain kernel per group of level bins).

    `images`: real frames, each scaled to its maximum, [R, B] at the sensor's resolution; `means`: the model's
    mean field of each frame on the same grid.
    """
    if not images or len(images) != len(means):
        raise ConfigError(f"speckle fit: need real frames and one mean field each, got {len(images)} and "
                          f"{len(means)}")
    for index, (image, mean) in enumerate(zip(images, means, strict=True)):
        if image.shape != mean.shape or image.ndim != 2 or min(image.shape) < TILE:
            raise ConfigError(f"speckle fit: frame {index} has shape {image.shape} and mean {mean.shape}; need "
                              f"equal 2-D shapes with sides >= {TILE}")
    rng = np.random.default_rng(seed)
    levels = np.concatenate([np.maximum(m, MEAN_FLOOR).ravel() for m in means])
    ratio = np.concatenate([(i / np.maximum(m, MEAN_FLOOR)).ravel() for i, m in zip(images, means, strict=True)])
    edges = level_edges(levels)
    bins = np.searchsorted(edges, levels, side="left")
    scores = np.linspace(-NORMAL_SPAN, NORMAL_SPAN, QUANTILES)
    probabilities = 0.5 * (1.0 + np.vectorize(math.erf)(scores / math.sqrt(2.0)))
    table = np.stack([np.quantile(ratio[bins == k], probabilities) if np.any(bins == k) else np.ones(QUANTILES)
                      for k in range(LEVEL_BINS)])
    # Gaussian copula of the ratios; ties (8-bit steps) spread at random over their stretch of the table.
    normal = np.empty_like(ratio)
    for k in range(LEVEL_BINS):
        in_bin = bins == k
        values = ratio[in_bin]
        low = np.searchsorted(table[k], values, side="left")
        high = np.searchsorted(table[k], values, side="right")
        position = low - 0.5 + rng.random(values.size) * np.maximum(high - low, 1)
        normal[in_bin] = np.interp(position, np.arange(QUANTILES), scores)
    kernels = grain_kernels(normal, bins // (LEVEL_BINS // GRAIN_GROUPS), [image.shape for image in images])
    return edges, table, kernels


def level_edges(levels: np.ndarray) -> np.ndarray:
    """[LEVEL_BINS - 1] edges splitting mean levels (floored at MEAN_FLOOR) into bins of equal pixel counts."""
    return np.quantile(levels, np.linspace(0, 1, LEVEL_BINS + 1)[1:-1])


def grain_kernels(normal: np.ndarray, groups: np.ndarray, shapes: list[tuple[int, ...]]) -> np.ndarray:
    """[GRAIN_GROUPS, KERNEL_SIZE, KERNEL_SIZE] zero-phase kernels, each reproducing the autocorrelation of the
    normal-score field around the pixels of its level group.

    `normal` and `groups` are the frames' fields flattened one after another (`shapes`). The autocorrelation
    around group g is Σ m_g(x) f(x) f(x + τ) / Σ m_g(x) over TILE x TILE tiles (zero-padded, so no wrap); its
    power spectrum's square root is the kernel. A group with too few pixels takes the pooled estimate."""
    padded = 2 * TILE
    window = np.zeros((padded, padded))
    window[:TILE, :TILE] = 1.0
    window_spectrum = np.fft.rfft2(window)
    products = np.zeros((GRAIN_GROUPS, padded, padded))
    counts = np.zeros((GRAIN_GROUPS, padded, padded))
    offset = 0
    for shape in shapes:
        size = int(np.prod(shape))
        field = normal[offset:offset + size].reshape(shape)
        group = groups[offset:offset + size].reshape(shape)
        offset += size
        tiles = [(field[r:r + TILE, c:c + TILE], group[r:r + TILE, c:c + TILE])
                 for r in range(0, shape[0] - TILE + 1, TILE) for c in range(0, shape[1] - TILE + 1, TILE)]
        values = np.stack([tile - tile.mean() for tile, _ in tiles])
        members = np.stack([tile_group for _, tile_group in tiles])
        spectrum = np.fft.rfft2(values, s=(padded, padded))
        for g in range(GRAIN_GROUPS):
            mask = (members == g).astype(np.float64)
            if not mask.any():
                continue
            masked = np.fft.rfft2(mask * values, s=(padded, padded))
            products[g] += np.fft.irfft2(np.conj(masked) * spectrum, s=(padded, padded)).sum(axis=0)
            counts[g] += np.fft.irfft2(np.conj(np.fft.rfft2(mask, s=(padded, padded))) * window_spectrum,
                                       s=(padded, padded)).sum(axis=0)
    pooled = products.sum(axis=0) / np.maximum(counts.sum(axis=0), 1.0)
    enough = counts[:, 0, 0] >= TILE * TILE  # a tile's worth of pixels: lag correlations to about 0.02
    return np.stack([_kernel_from_correlation(products[g] / np.maximum(counts[g], 1.0) if enough[g] else pooled)
                     for g in range(GRAIN_GROUPS)])


def _kernel_from_correlation(correlation: np.ndarray) -> np.ndarray:
    """A zero-phase KERNEL_SIZE^2 kernel, unit energy, whose autocorrelation approximates `correlation`
    (lags laid circularly on a 2 TILE grid, lag 0 at [0, 0])."""
    half = TILE // 2
    lags = np.r_[0:half, -half + 1:0]
    acf = correlation[np.ix_(lags % correlation.shape[0], lags % correlation.shape[1])]
    acf = 0.5 * (acf + np.roll(acf[::-1, ::-1], 1, axis=(0, 1)))  # C(τ) and C(-τ) differ by the masks; average
    acf /= max(acf[0, 0], 1e-12)
    circular = np.zeros((TILE, TILE))
    circular[np.ix_(lags % TILE, lags % TILE)] = acf
    spectrum = np.maximum(np.real(np.fft.fft2(circular)), 0.0)
    kernel_full = np.fft.fftshift(np.real(np.fft.ifft2(np.sqrt(spectrum))))
    centre, reach = TILE // 2, KERNEL_SIZE // 2
    kernel = kernel_full[centre - reach:centre + reach + 1, centre - reach:centre + reach + 1]
    return kernel / np.sqrt(np.sum(kernel ** 2))
