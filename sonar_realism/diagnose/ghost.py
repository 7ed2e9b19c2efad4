"""Is a selected multipath a ghost, or a world difference it absorbed?

A multipath ghost is a weaker copy of *each frame's own* scene at a fixed range offset, so the real frames'
per-frame content (each frame minus the mean frame: what changes from ping to ping) correlates between rows r and
r + offset more than the sim's does: a peak of the excess correlation at that lag. A difference between the sim's
world and the real one (another seabed, other objects) shifts the mean power over range, which the catalogue's
ghost can also mimic in the statistics, but it puts no peak there. The check compares the real held-out frames
with the held-out sim frames corrected by every other selected effect (so a range blur's wider correlation is on
both sides).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# The real frames' excess correlation at the ghost's lag must stand this far above its flanks. On the tuning half
# (40 frames a side) a planted ghost of reflection 0.4-0.7 showed 0.09-0.24 at its lag and one of 0.3 0.01-0.13;
# scenes that differ with no ghost (null, lens band, beam ripple, the other effects) 0.064 at most beyond 20 bins.
GHOST_MIN_EXCESS = 0.07


@dataclass(frozen=True)
class GhostCheck:
    """The fitted ghost's lag (`lag_bins`), the real frames' excess correlation peak there over the corrected
    sim's (`excess`: the peak within half to 1.5 times the lag, minus the median of its flanks) and the least that
    confirms a ghost (`needed`)."""

    lag_bins: float
    excess: float
    needed: float = GHOST_MIN_EXCESS

    @property
    def confirmed(self) -> bool:
        return self.excess >= self.needed

    def describe(self) -> str:
        return (f"a ghost: the real frames' excess correlation between rows {self.lag_bins:.0f} bins apart is "
                f"{self.excess:.3f} (a ghost from {self.needed:.3f})")


def range_lag_correlation(images: np.ndarray) -> np.ndarray:
    """Correlation of the per-frame amplitude fluctuation (each frame minus the mean frame) between rows r and
    r + lag, pooled over frames and beams; index = lag in range bins (index 0: the variance, 1). Amplitude, not
    power: power lets a few highlights decide, and on the tuning half a weak ghost (reflection 0.3) stood out
    about half as far above the scenes' own differences in power as in amplitude."""
    amplitude = images.astype(np.float64)
    fluctuation = amplitude - amplitude.mean(axis=0, keepdims=True)
    n_ranges = fluctuation.shape[1]
    spectrum = np.fft.rfft(fluctuation, n=2 * n_ranges, axis=1)
    covariance = np.fft.irfft((spectrum * spectrum.conj()).sum(axis=(0, 2)), n=2 * n_ranges)[:n_ranges]
    return covariance / covariance[0] if covariance[0] > 0 else np.zeros(n_ranges)


def check_ghost(real_curve: np.ndarray, sim_curve: np.ndarray, lag_bins: float) -> GhostCheck:
    """How far the real frames' excess lag correlation (`real_curve` - `sim_curve`, both range_lag_correlation)
    peaks at a ghost `lag_bins` away. The window is wide (half to 1.5 times the lag): a ghost's offset changes
    over range when its mirror is near (the sea surface), and the fit's grid places it only roughly."""
    excess = real_curve - sim_curve
    n = len(excess)
    lo, hi = max(2, int(0.5 * lag_bins)), min(n - 1, int(1.5 * lag_bins) + 2)
    if lo > hi:
        return GhostCheck(lag_bins, 0.0)
    flanks = np.r_[excess[max(1, int(0.25 * lag_bins)):lo], excess[hi + 1:min(n, int(2.5 * lag_bins) + 5)]]
    baseline = float(np.median(flanks)) if flanks.size else 0.0
    return GhostCheck(lag_bins, float(excess[lo:hi + 1].max()) - baseline)


def ghost_lag_bins(offset_m: float, ranges_m: np.ndarray) -> float:
    """A range offset in range bins (the mean bin, as the catalogue's multipath shifts by)."""
    return offset_m * (ranges_m.size - 1) / float(ranges_m[-1] - ranges_m[0])


def ghost_lag_peak(real_curve: np.ndarray, sim_curve: np.ndarray, lowest: int, highest: int) -> int:
    """The lag in [lowest, highest] (range bins) where the real frames' excess correlation over the sim's peaks:
    where a ghost would put each frame's scene again. A start for the multipath search, not a verdict: the
    statistics the search minimises barely change with the ghost's offset (a tuning multipath 3.7 m out was
    fitted at the catalogue's 1.5 m, and its ghost check then looked at the wrong lag and dropped it)."""
    excess = real_curve - sim_curve
    lowest, highest = max(1, lowest), min(len(excess) - 1, highest)
    if lowest > highest:
        return lowest
    return lowest + int(np.argmax(excess[lowest:highest + 1]))
