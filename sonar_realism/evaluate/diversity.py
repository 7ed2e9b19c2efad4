"""One-to-many diversity: how different are the n samples a translator draws for one input?

Mean pairwise L1 distance between the samples of one input (StarGAN v2 uses LPIPS; an ImageNet LPIPS
would need downloaded weights and says little about sonar). To be comparable between methods it is also
given relative to the distance between outputs of *different* inputs: 0 = collapsed to one output per
input (a deterministic CycleGAN), 1 = samples of one input differ as much as outputs of different scenes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sonar_realism.errors import ConfigError


@dataclass(frozen=True)
class DiversityResult:
    pairwise_l1: float  # mean |a - b| between samples of the same input
    between_inputs_l1: float  # mean |a - b| between first samples of different inputs
    relative: float  # pairwise_l1 / between_inputs_l1
    pixel_std: float  # mean per-pixel standard deviation over the samples of one input
    between_inputs_std: float  # mean per-pixel standard deviation over the first samples of different inputs
    std_ratio: float  # pixel_std / between_inputs_std: how much of a scene change one resampling is


def _mean_pairwise_l1(stack: np.ndarray) -> float:
    n = len(stack)
    total = sum(float(np.abs(stack[i] - stack[j]).mean()) for i in range(n) for j in range(i + 1, n))
    return total / (n * (n - 1) / 2)


def sample_diversity(samples: np.ndarray) -> DiversityResult:
    """Diversity of samples [n_inputs, n_samples, rows, cols] (needs n_samples >= 2 and n_inputs >= 2)."""
    samples = np.asarray(samples, np.float64)
    if samples.ndim != 4 or samples.shape[0] < 2 or samples.shape[1] < 2:
        raise ConfigError(f"diversity: need [inputs >= 2, samples >= 2, rows, cols], got {samples.shape}")
    within = float(np.mean([_mean_pairwise_l1(stack) for stack in samples]))
    between = _mean_pairwise_l1(samples[:, 0])
    pixel_std = float(samples.std(axis=1).mean())
    between_std = float(samples[:, 0].std(axis=0).mean())
    return DiversityResult(pairwise_l1=within, between_inputs_l1=between,
                           relative=within / between if between > 0 else 0.0, pixel_std=pixel_std,
                           between_inputs_std=between_std,
                           std_ratio=pixel_std / between_std if between_std > 0 else 0.0)
