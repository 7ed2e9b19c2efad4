"""The texture a decoder cannot express: spatially correlated, level-dependent speckle fitted to a real sensor.

A VAE decoder trained with a reconstruction loss outputs the conditional mean of its target; real pings
scatter around that mean with per-pixel speckle whose distribution and grain belong to the sensor. This
module fits that scatter and samples it, so every sample of a frame differs where real pings differ.

Fitting (`fit_speckle`), at the sensor's own resolution, from real frames I and the model's mean field M of
the same frames (its reconstructions, resampled back to the frames' grids):
- the ratio r = I / M in each of `LEVEL_BINS` bins of M: a quantile table (the marginal; dark bins keep the
  noise floor's and quantisation's shape, bright bins the speckle's heavy tail);
- the grain: r is mapped to a standard normal field through its own bin's distribution (a Gaussian copula),
  and the average power spectrum of that field over tiles gives a zero-phase kernel which, convolved with
  white noise, reproduces the correlation along range and across beams (per-beam stripes included).

Sampling (`SpeckleField.sample`): white noise -> kernel (circular convolution by FFT) -> unit normal field
-> r from the quantile table (spaced in normal scores) of each pixel's level bin -> I = M * r, then each
sample is scaled to its maximum and quantised as the real export was (8-bit, one pixel at full scale).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from sonar_realism.errors import ConfigError
from sonar_realism.models.speckle_fit import (
    EXPORT_LEVELS,
    KERNEL_SIZE,
    LEVEL_BINS,
    NORMAL_SPAN,
    QUANTILES,
)


class SpeckleField(nn.Module):
    """Fitted speckle statistics (buffers, so they travel in the checkpoint) and a sampler."""

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("level_edges", torch.linspace(0.0, 1.0, LEVEL_BINS + 1)[1:-1])
        self.register_buffer("ratio_quantiles", torch.ones(LEVEL_BINS, QUANTILES))
        kernel = torch.zeros(KERNEL_SIZE, KERNEL_SIZE)
        kernel[KERNEL_SIZE // 2, KERNEL_SIZE // 2] = 1.0
        self.register_buffer("kernel", kernel)
        self.register_buffer("fitted", torch.zeros(()))
        self._spectra: dict[tuple[int, int], torch.Tensor] = {}

    def _load_from_state_dict(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        self._spectra.clear()  # a new kernel arrives with the state
        super()._load_from_state_dict(*args, **kwargs)

    @property
    def is_fitted(self) -> bool:
        return bool(self.fitted.item())

    def set_fit(self, level_edges: np.ndarray, ratio_quantiles: np.ndarray, kernel: np.ndarray) -> None:
        self.level_edges.copy_(torch.from_numpy(level_edges.astype(np.float32)))
        self.ratio_quantiles.copy_(torch.from_numpy(ratio_quantiles.astype(np.float32)))
        self.kernel.copy_(torch.from_numpy(kernel.astype(np.float32)))
        self.fitted.fill_(1.0)
        self._spectra.clear()

    def correlated_normal(self, n: int, shape: tuple[int, int], generator: torch.Generator | None) -> torch.Tensor:
        """[n, H, W] unit-variance normal fields with the fitted grain."""
        rows, cols = shape
        noise = torch.randn((n, rows, cols), generator=generator, dtype=torch.float32)
        field = torch.fft.irfft2(torch.fft.rfft2(noise) * self._kernel_spectrum(rows, cols), s=(rows, cols))
        spread = field.flatten(1).std(dim=1).clamp_min(1e-6)
        return field / spread[:, None, None]

    def _kernel_spectrum(self, rows: int, cols: int) -> torch.Tensor:
        """rfft2 of the kernel laid circularly on a rows x cols grid, centre at (0, 0); cached per grid."""
        key = (rows, cols)
        if key not in self._spectra:
            taps = torch.arange(KERNEL_SIZE) - KERNEL_SIZE // 2
            index_r = (taps % rows)[:, None].expand(KERNEL_SIZE, KERNEL_SIZE)
            index_c = (taps % cols)[None, :].expand(KERNEL_SIZE, KERNEL_SIZE)
            laid = torch.zeros((rows, cols), dtype=torch.float32)
            laid.index_put_((index_r, index_c), self.kernel.float(), accumulate=True)
            self._spectra[key] = torch.fft.rfft2(laid)
        return self._spectra[key]

    def ratios(self, mean: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
        """r for each pixel: the quantile of its level bin at the normal field's probability."""
        position = ((normal + NORMAL_SPAN) / (2 * NORMAL_SPAN)).clamp(0.0, 1.0) * (QUANTILES - 1)
        low = position.floor().long().clamp(max=QUANTILES - 2)
        frac = position - low
        bins = torch.bucketize(mean.contiguous(), self.level_edges)
        table = self.ratio_quantiles[bins.flatten()]  # [P, Q]
        low_flat = low.flatten()[:, None]
        below = table.gather(1, low_flat).squeeze(1)
        above = table.gather(1, low_flat + 1).squeeze(1)
        return (below + frac.flatten() * (above - below)).view_as(mean)

    def sample(self, mean: np.ndarray, generator: torch.Generator | None) -> np.ndarray:
        """Speckled, max-scaled, 8-bit-quantised samples float32 [n, H, W] in [0, 1] of mean fields [n, H, W]."""
        if not self.is_fitted:
            raise ConfigError("texture: this checkpoint's speckle statistics were never fitted")
        mean_t = torch.from_numpy(np.ascontiguousarray(mean, np.float32))
        normal = self.correlated_normal(mean_t.shape[0], tuple(mean_t.shape[1:]), generator)
        image = mean_t * self.ratios(mean_t, normal)
        peak = image.flatten(1).amax(dim=1).clamp_min(1e-6)
        image = torch.round(image / peak[:, None, None] * EXPORT_LEVELS) / EXPORT_LEVELS
        return image.numpy()
