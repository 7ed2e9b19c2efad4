"""Table I of the paper: the realism CNN's "real" score per image, summarised per method and category.

The paper gives bare ranges (e.g. 0.114-0.281) without saying what they span. Here a range is the
10th-90th percentile of the per-input scores (min-max is also kept, but depends on the set size), and
the mean comes with a 95 % percentile-bootstrap confidence interval over inputs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sonar_realism.errors import ConfigError


@dataclass(frozen=True)
class ScoreSummary:
    n: int
    mean: float
    ci_low: float
    ci_high: float
    p10: float
    p90: float
    min: float
    max: float

    def range_text(self) -> str:
        return f"{self.p10:.3f}–{self.p90:.3f}"

    def mean_text(self) -> str:
        return f"{self.mean:.3f} [{self.ci_low:.3f}, {self.ci_high:.3f}]"


def bootstrap_ci(values: np.ndarray, n_boot: int = 2000, level: float = 0.95, seed: int = 0) -> tuple[float, float]:
    """Percentile-bootstrap confidence interval of the mean of `values` (resampling inputs)."""
    values = np.asarray(values, np.float64)
    if values.size == 0:
        raise ConfigError("bootstrap_ci: no values")
    rng = np.random.default_rng(seed)
    means = values[rng.integers(0, values.size, size=(n_boot, values.size))].mean(axis=1)
    tail = (1.0 - level) / 2.0
    return float(np.quantile(means, tail)), float(np.quantile(means, 1.0 - tail))


def summarize_scores(scores: np.ndarray, seed: int = 0) -> ScoreSummary:
    """Summary of per-input scores (one value per input; average its n samples first)."""
    scores = np.asarray(scores, np.float64)
    low, high = bootstrap_ci(scores, seed=seed)
    return ScoreSummary(n=int(scores.size), mean=float(scores.mean()), ci_low=low, ci_high=high,
                        p10=float(np.quantile(scores, 0.1)), p90=float(np.quantile(scores, 0.9)),
                        min=float(scores.min()), max=float(scores.max()))


PAPER_TABLE_I = {  # Panisilvam et al. 2022, Table I: (low, high) of the CNN's "real" output
    "organic": {"raw sim": (0.114, 0.212), "cyclegan": (0.442, 0.843), "cdfcvae": (0.507, 0.803)},
    "constructed": {"raw sim": (0.188, 0.281), "cyclegan": (0.266, 0.652), "cdfcvae": (0.552, 0.867)},
}
