"""Fitting the speckle model of models/speckle.py: numpy only, so the simulator's calibration (sim/texture.py)
fits and validates the same model without importing torch. See models/speckle.py for what the tables mean."""

from __future__ import annotations

import math

import numpy as np

from sonar_realism.errors import ConfigError

LEVEL_BINS = 8
QUANTILES = 129
NORMAL_SPAN = 4.5  # the quantile table is spaced evenly in normal scores over [-span, span]: tails resolved
KERNEL_SIZE = 33  # odd; the grain of a forward-looking sonar spans a few bins, far less than this
TILE = 64
MEAN_FLOOR = 0.5 / 255.0  # below half an 8-bit step the ratio I / M says nothing about texture
EXPORT_LEVELS = 255  # the real set is 8-bit, scaled so that its brightest pixel is 255


def fit_speckle(images: list[np.ndarray], means: list[np.ndarray], seed: int = 0
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(level_edges [LEVEL_BINS-1], ratio_quantiles [LEVEL_BINS, QUANTILES], kernel [KERNEL_SIZE]^2).

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
    edges = np.quantile(levels, np.linspace(0, 1, LEVEL_BINS + 1)[1:-1])
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
    power = np.zeros((TILE, TILE))
    tiles = 0
    offset = 0
    for image in images:
        field = normal[offset:offset + image.size].reshape(image.shape)
        offset += image.size
        for r in range(0, image.shape[0] - TILE + 1, TILE):
            for c in range(0, image.shape[1] - TILE + 1, TILE):
                tile = field[r:r + TILE, c:c + TILE]
                power += np.abs(np.fft.fft2(tile - tile.mean())) ** 2
                tiles += 1
    kernel_full = np.real(np.fft.ifft2(np.sqrt(power / tiles)))
    kernel_full = np.fft.fftshift(kernel_full)
    centre, half = TILE // 2, KERNEL_SIZE // 2
    kernel = kernel_full[centre - half:centre + half + 1, centre - half:centre + half + 1]
    kernel = kernel / np.sqrt(np.sum(kernel ** 2))
    return edges, table, kernel
