"""The texture a decoder cannot express: spatially correlated, level-dependent speckle fitted to a real sensor.

A VAE decoder trained with a reconstruction loss outputs the conditional mean of its target; real pings
scatter around that mean with per-pixel speckle whose distribution and grain belong to the sensor. This
module fits that scatter and samples it, so every sample of a frame differs where real pings differ.

Fitting (`fit_speckle`), at the sensor's own resolution, from real frames I and the model's mean field M of
the same frames (its reconstructions, resampled back to the frames' grids):
- the ratio r = I / M in each of `LEVEL_BINS` bins of M: a quantile table (the marginal; dark bins keep the
  noise floor's and quantisation's shape, bright bins the speckle's heavy tail);
- the grain: r is mapped to a standard normal field through its own bin's distribution (a Gaussian copula),
  and the autocorrelation of that field around the pixels of each group of level bins (GRAIN_GROUPS) gives a
  zero-phase kernel which, convolved with white noise, reproduces the correlation along range and across
  beams at that level (the dark water column's per-beam stripes, the lit seabed's finer grain).

Sampling (`SpeckleField.sample`): one white noise per sample -> each group's kernel (circular convolution by
FFT) -> unit normal fields, each pixel taking its level group's -> r from the quantile table (spaced in
normal scores) of its level bin -> I = M * r, then each sample is scaled to its maximum and quantised as the
real export was (8-bit, one pixel at full scale). The groups share the noise, so their fields agree where
the level crosses from one group to the next.

The kernel from the copula's autocorrelation falls short of the grain it was fitted on where the frames are
dark: there the 8-bit ratios tie in long runs, the copula spreads each tie at random (white noise in the
normal field), and the kernel's spectrum is clipped and truncated. On the real Oculus set the sampled dark
levels came out with lag-1 correlations of 0.93 against the frames' 0.98 (neighbouring-beam differences in
dark texture patches 2-4x the real ones), which a texture two-sample test sees at once. So the fit ends with
`match_grain`: each group's kernel is widened by a Gaussian along range and across beams until frames sampled
around the fitted mean fields have the real frames' lag-1 correlations around that group's pixels.

The top of the range: the real export's brightest pixel is one of a handful (a frame's 99.9th percentile is
0.96 of its maximum on the Oculus set), while the speckle's tail drawn on a bright mean overshoots full scale,
and a hard clip there piled 0.6 % of a simulated frame's pixels at 255. So the export bends values above a knee
smoothly towards full scale (`compress_top`), the knee matched last (`match_export_knee`) on that percentile.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch
from torch import nn

from sonar_realism.errors import ConfigError
from sonar_realism.models.speckle_fit import (
    EXPORT_LEVELS,
    EXPORT_TOP_QUANTILE,
    GRAIN_GROUPS,
    KERNEL_SIZE,
    LEVEL_BINS,
    NORMAL_SPAN,
    QUANTILES,
    fit_speckle,
    highest_knee_at,
    top_ratio,
)

DENSE_STEPS = 1024  # normal scores at which the quantile table is looked up
LEVEL_STEPS = 4096  # mean levels at which the level bin is looked up
GRAIN_MATCH_STEPS = 7  # bisection steps of each widening: 4 / 2^7 = 0.03 bins
GRAIN_MATCH_MAX_SIGMA = 4.0  # bins; beyond it a kernel's 33 taps would cut the widened grain off
GRAIN_MATCH_FRAMES = 40  # frames sampled per step, evenly spaced over the fit's


class SpeckleField(nn.Module):
    """Fitted speckle statistics (buffers, so they travel in the checkpoint) and a sampler."""

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("level_edges", torch.linspace(0.0, 1.0, LEVEL_BINS + 1)[1:-1])
        self.register_buffer("ratio_quantiles", torch.ones(LEVEL_BINS, QUANTILES))
        kernel = torch.zeros(GRAIN_GROUPS, KERNEL_SIZE, KERNEL_SIZE)
        kernel[:, KERNEL_SIZE // 2, KERNEL_SIZE // 2] = 1.0
        self.register_buffer("kernel", kernel)
        self.register_buffer("export_knee", torch.ones(()))  # 1: a hard clip at full scale
        self.register_buffer("fitted", torch.zeros(()))
        self._spectra: dict[tuple[int, int], torch.Tensor] = {}  # kernel spectra per grid
        self._refresh()

    def _load_from_state_dict(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        super()._load_from_state_dict(*args, **kwargs)
        self._refresh()  # a new fit arrived with the state

    def _refresh(self) -> None:
        """Lookup tables derived from the fit, so sampling does one table read per pixel where it would search
        or interpolate: the level bin at LEVEL_STEPS levels, and the quantile table at DENSE_STEPS normal scores
        per bin (0.01 apart), flattened."""
        self._level_lookup = torch.bucketize(torch.linspace(0.0, 1.0, LEVEL_STEPS), self.level_edges.float().cpu())
        position = torch.linspace(0.0, QUANTILES - 1, DENSE_STEPS)
        low = position.floor().long().clamp(max=QUANTILES - 2)
        frac = position - low
        table = self.ratio_quantiles.float().cpu()
        self._dense_quantiles = (table[:, low] + frac * (table[:, low + 1] - table[:, low])).flatten()
        self._spectra.clear()

    @property
    def is_fitted(self) -> bool:
        return bool(self.fitted.item())

    def set_fit(self, level_edges: np.ndarray, ratio_quantiles: np.ndarray, kernel: np.ndarray,
                export_knee: float = 1.0) -> None:
        self.level_edges.copy_(torch.from_numpy(level_edges.astype(np.float32)))
        self.ratio_quantiles.copy_(torch.from_numpy(ratio_quantiles.astype(np.float32)))
        self.kernel.copy_(torch.from_numpy(kernel.astype(np.float32)))
        self.export_knee.fill_(export_knee)
        self.fitted.fill_(1.0)
        self._refresh()

    def fit(self, images: list[np.ndarray], means: list[np.ndarray], seed: int = 0) -> None:
        """Fit on real frames scaled to their maximum and the mean field of each (`fit_speckle`; see the module
        docstring), then match the grain (`match_grain`) and the top of the export (`match_export_knee`): what
        both the translator's and the calibrated simulator's texture fits do."""
        edges, table, kernel = fit_speckle(images, means, seed=seed)
        self.set_fit(edges, np.maximum.accumulate(table, axis=1), kernel)  # a quantile table never decreases
        self.match_grain(images, means, seed)
        self.match_export_knee(images, means, seed)

    def match_export_knee(self, images: list[np.ndarray], means: list[np.ndarray], seed: int = 0) -> float:
        """Set the export's knee to the highest at which samples around `means` have the median ratio of the
        99.9th percentile to the maximum of `images` (frames scaled to their maximum; `highest_knee_at`); returns
        it. 1.0 (a hard clip) where the samples' top is already as light. The compression is monotonic, so a
        frame's quantile and maximum after it are those before it, compressed: one draw of each frame serves
        every knee tried."""
        if not self.is_fitted:
            raise ConfigError("texture: fit the speckle statistics before matching the export")
        picked = _matched_frames(len(images))
        target = float(np.median([top_ratio(images[i]) for i in picked]))
        generator = torch.Generator().manual_seed(seed)
        raw = [self._speckled(np.ascontiguousarray(means[i], np.float32)[None], generator)[0] for i in picked]
        tops = torch.stack([torch.stack([torch.quantile(frame.flatten(), EXPORT_TOP_QUANTILE), frame.max()])
                            for frame in raw])

        def ratio(knee: float) -> float:
            top, peak = compress_top(tops, knee).clamp(max=1.0).unbind(1)
            return float(torch.median(top / peak.clamp_min(1e-6)))

        knee = highest_knee_at(ratio, target)
        self.export_knee.fill_(knee)
        return knee

    def match_grain(self, images: list[np.ndarray], means: list[np.ndarray], seed: int = 0) -> np.ndarray:
        """Widen each group's kernel so that samples around `means` have the lag-1 correlations (along range,
        across beams) of `images` around the pixels of that group; returns the Gaussian widths (bins)
        [GRAIN_GROUPS, 2]. A kernel already as correlated as the frames is left as it is."""
        if not self.is_fitted:
            raise ConfigError("texture: fit the speckle statistics before matching their grain")
        picked = _matched_frames(len(images))
        images = [images[i] for i in picked]
        means = [np.ascontiguousarray(means[i], np.float32) for i in picked]
        groups = [(self.level_bins(torch.from_numpy(mean)) // (LEVEL_BINS // GRAIN_GROUPS)).numpy() for mean in means]
        target = group_lag1(images, groups)
        fitted = self.kernel.numpy().astype(np.float64)

        def lag1_with(widths: np.ndarray) -> np.ndarray:
            self._use_kernel(_widened(fitted, widths))
            generator = torch.Generator().manual_seed(seed)
            return group_lag1([self.sample(mean[None], generator)[0] for mean in means], groups)

        short_as_fitted = lag1_with(np.zeros((GRAIN_GROUPS, 2))) < target
        low = np.zeros((GRAIN_GROUPS, 2))
        high = np.full((GRAIN_GROUPS, 2), GRAIN_MATCH_MAX_SIGMA)
        for _ in range(GRAIN_MATCH_STEPS):
            middle = 0.5 * (low + high)
            short = lag1_with(middle) < target
            low, high = np.where(short, middle, low), np.where(short, high, middle)
        widths = np.where(short_as_fitted, 0.5 * (low + high), 0.0)
        self._use_kernel(_widened(fitted, widths))
        return widths

    def _use_kernel(self, kernel: np.ndarray) -> None:
        """Swap the grain kernels only (the level and quantile lookups stay as fitted)."""
        self.kernel.copy_(torch.from_numpy(kernel.astype(np.float32)))
        self._spectra.clear()

    def level_bins(self, mean: torch.Tensor) -> torch.Tensor:
        """Each pixel's level bin (int64), read from the table at the nearest of LEVEL_STEPS levels."""
        step = (mean * (LEVEL_STEPS - 1)).round_().clamp_(0, LEVEL_STEPS - 1).long()
        return torch.take(self._level_lookup, step)

    def correlated_normal(self, bins: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
        """[n, H, W] unit-variance normal fields with the fitted grain of each pixel's level bin [n, H, W]."""
        n, rows, cols = bins.shape
        noise = torch.fft.rfft2(torch.randn((n, rows, cols), generator=generator, dtype=torch.float32))
        groups = bins // (LEVEL_BINS // GRAIN_GROUPS)
        out: torch.Tensor | None = None
        for group, spectrum in enumerate(self._kernel_spectra(rows, cols)):
            members = groups == group
            if not members.any():
                continue
            field = torch.fft.irfft2(noise * spectrum, s=(rows, cols))
            out = field if out is None else torch.where(members, field, out)
        assert out is not None
        return out

    def _kernel_spectra(self, rows: int, cols: int) -> torch.Tensor:
        """rfft2 of each group's kernel laid circularly on a rows x cols grid, centre at (0, 0), at unit energy
        (so white noise through it has unit variance on any grid); cached per grid."""
        key = (rows, cols)
        if key not in self._spectra:
            taps = torch.arange(KERNEL_SIZE) - KERNEL_SIZE // 2
            index_r = (taps % rows)[:, None].expand(KERNEL_SIZE, KERNEL_SIZE)
            index_c = (taps % cols)[None, :].expand(KERNEL_SIZE, KERNEL_SIZE)
            laid = torch.zeros((GRAIN_GROUPS, rows, cols), dtype=torch.float32)
            for group in range(GRAIN_GROUPS):
                laid[group].index_put_((index_r, index_c), self.kernel[group].float(), accumulate=True)
            laid /= laid.square().sum(dim=(1, 2), keepdim=True).sqrt().clamp_min(1e-12)
            self._spectra[key] = torch.fft.rfft2(laid)
        return self._spectra[key]

    def ratios(self, bins: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
        """r for each pixel: the quantile of its level bin at the normal field's probability."""
        step = ((normal + NORMAL_SPAN) * ((DENSE_STEPS - 1) / (2 * NORMAL_SPAN))).round_().clamp_(0, DENSE_STEPS - 1)
        return torch.take(self._dense_quantiles, bins * DENSE_STEPS + step.long())

    def sample(self, mean: np.ndarray, generator: torch.Generator | None,
               row_gain: np.ndarray | None = None, knee: float | None = None) -> np.ndarray:
        """Speckled, max-scaled, 8-bit-quantised samples float32 [n, H, W] in [0, 1] of mean fields [n, H, W];
        `row_gain` [H] multiplies each range row before the export's scaling (a sensor's gain per range sample);
        `knee` is the export's (`compress_top`; None: the one fitted with these statistics).
        The mean is in full-scale units (1.0 is the export's 255, which no frame the statistics were fitted on
        exceeds): the speckled value clips there, as a sensor's 8-bit output does, before the export scales the
        frame to its maximum. Scaling by an unclipped speckle peak instead would darken the whole frame by it
        (the translator's output median fell 30-45 % below its decoded level that way until 2026-11-23)."""
        if not self.is_fitted:
            raise ConfigError("texture: this checkpoint's speckle statistics were never fitted")
        knee = float(self.export_knee) if knee is None else knee
        return export_like_sensor(self._speckled(mean, generator), row_gain, knee)

    def _speckled(self, mean: np.ndarray, generator: torch.Generator | None) -> torch.Tensor:
        """Mean fields [n, H, W] times a draw of the speckle ratio, in full-scale units, before the export."""
        mean_t = torch.from_numpy(np.ascontiguousarray(mean, np.float32))
        bins = self.level_bins(mean_t)
        return mean_t * self.ratios(bins, self.correlated_normal(bins, generator))


def compress_top(image: torch.Tensor, knee: float) -> torch.Tensor:
    """Values above `knee` (full-scale units) bent smoothly towards full scale (tanh, slope 1 at the knee);
    those below unchanged. `knee` 1.0: unchanged."""
    if knee >= 1.0:
        return image
    span = 1.0 - knee
    return torch.where(image > knee, knee + span * torch.tanh((image - knee) / span), image)


def as_sensor_bytes(exported: np.ndarray) -> np.ndarray:
    """An export (`export_like_sensor`: EXPORT_LEVELS steps of [0, 1]) as the sensor's 8-bit samples, exactly;
    full scale is EXPORT_LEVELS (the frame's `intensity_scale`)."""
    return np.rint(exported * EXPORT_LEVELS).astype(np.uint8)


def export_like_sensor(image: torch.Tensor, row_gain: np.ndarray | None = None, knee: float = 1.0) -> np.ndarray:
    """Textured frames [n, H, W] in full-scale units -> float32 as the real export: `row_gain` [H] multiplies
    each range row, values above `knee` are compressed towards full scale (`compress_top`) and clip there (a
    sensor's 8-bit output), each frame is scaled to its maximum and quantised to EXPORT_LEVELS steps. With the
    hard clip alone (knee 1.0) the speckle's tail piled up at full scale: 0.6 % of a calibrated-sim frame's
    pixels at 255 and 0.4 % of a translated one's, where the recording has one or two per frame."""
    if row_gain is not None:
        image = image * torch.from_numpy(np.asarray(row_gain, np.float32))[None, :, None]
    image = compress_top(image, knee).clamp(max=1.0)
    peak = image.flatten(1).amax(dim=1).clamp_min(1e-6)
    return (torch.round(image * (EXPORT_LEVELS / peak)[:, None, None]) / EXPORT_LEVELS).numpy()


def _matched_frames(n: int) -> np.ndarray:
    """Indices of the frames the grain and export matches sample: GRAIN_MATCH_FRAMES evenly spaced of n."""
    return np.linspace(0, n - 1, min(GRAIN_MATCH_FRAMES, n)).astype(int)


def _widened(kernels: np.ndarray, widths: np.ndarray) -> np.ndarray:
    """Each kernel convolved with a Gaussian of its (range, beam) widths in bins (0: unchanged), unit energy."""
    out = []
    for kernel, (along_range, across_beams) in zip(kernels, widths, strict=True):
        if along_range > 0 or across_beams > 0:
            kernel = cv2.GaussianBlur(kernel, (0, 0), sigmaX=max(across_beams, 1e-3), sigmaY=max(along_range, 1e-3),
                                      borderType=cv2.BORDER_CONSTANT)
        out.append(kernel / max(float(np.sqrt(np.sum(kernel ** 2))), 1e-12))
    return np.stack(out)


def group_lag1(fields: list[np.ndarray], groups: list[np.ndarray]) -> np.ndarray:
    """[GRAIN_GROUPS, 2] correlation of neighbouring values (along range, across beams) over the pairs whose
    two pixels are both in the group; NaN for a group with fewer than two such pairs."""
    out = np.full((GRAIN_GROUPS, 2), np.nan)
    for group in range(GRAIN_GROUPS):
        for axis in (0, 1):
            first, second = [], []
            for field, members in zip(fields, groups, strict=True):
                inside = members == group
                both = np.logical_and(*_neighbours(inside, axis))
                ahead, behind = _neighbours(field, axis)
                first.append(ahead[both])
                second.append(behind[both])
            a, b = np.concatenate(first), np.concatenate(second)
            if a.size >= 2 and a.std() > 0 and b.std() > 0:
                out[group, axis] = np.corrcoef(a, b)[0, 1]
    return out


def _neighbours(field: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    return (field[1:], field[:-1]) if axis == 0 else (field[:, 1:], field[:, :-1])
