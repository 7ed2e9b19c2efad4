"""Kernel Inception Distance (Bińkowski et al. 2018) on features of a network trained on sonar.

ImageNet features say little about sonar (the paper's reason to drop FID), so the features are the
realism CNN's penultimate layer. KID is the unbiased squared MMD with the cubic polynomial kernel
k(x, y) = (x·y / d + 1)^3, averaged over random subsets; unlike FID it is unbiased for the few dozen
images per set we have, and 0 means the feature distributions match (small negative values are noise).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sonar_realism.errors import ConfigError


@dataclass(frozen=True)
class KIDResult:
    mean: float
    std: float  # over subsets
    n_subsets: int
    subset_size: int


def _polynomial_mmd2(x: np.ndarray, y: np.ndarray) -> float:
    d = x.shape[1]
    k_xx = (x @ x.T / d + 1.0) ** 3
    k_yy = (y @ y.T / d + 1.0) ** 3
    k_xy = (x @ y.T / d + 1.0) ** 3
    m, n = len(x), len(y)
    same_x = (k_xx.sum() - np.trace(k_xx)) / (m * (m - 1))
    same_y = (k_yy.sum() - np.trace(k_yy)) / (n * (n - 1))
    return float(same_x + same_y - 2.0 * k_xy.mean())


def kernel_inception_distance(features_x: np.ndarray, features_y: np.ndarray, n_subsets: int = 100,
                              subset_size: int = 1000, seed: int = 0) -> KIDResult:
    """KID between two feature sets [N, d] and [M, d]; subsets are capped at the smaller set size."""
    x = np.asarray(features_x, np.float64)
    y = np.asarray(features_y, np.float64)
    if x.ndim != 2 or y.ndim != 2 or x.shape[1] != y.shape[1]:
        raise ConfigError(f"KID: feature shapes {x.shape} and {y.shape} do not match")
    size = min(subset_size, len(x), len(y))
    if size < 2:
        raise ConfigError("KID: need at least 2 feature vectors per set")
    rng = np.random.default_rng(seed)
    values = [_polynomial_mmd2(x[rng.choice(len(x), size, replace=False)], y[rng.choice(len(y), size, replace=False)])
              for _ in range(n_subsets)]
    return KIDResult(mean=float(np.mean(values)), std=float(np.std(values)), n_subsets=n_subsets, subset_size=size)
