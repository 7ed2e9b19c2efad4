"""Interference's signature: arcs that come and go. It confirms a selected interference and finds one the gap
does not see.

The catalogue's interference is pulses from another source, out of sync with our pings: each ping's arcs land at
new ranges. Two questions follow.

- Is a selected interference arcs that move, or a fixed band it absorbed? A reflection inside the housing (or any
  fixed band) lights the same rows in every frame, and an interference fitted at its strongest (many wide arcs per
  ping) can stand in for it in the statistics. So a row that stands out of the rows around it in most real frames,
  more often than in the corrected sim's, is a band, not interference: what the interference closed stays residual
  (and the gain pattern's band may name its place). `check_arcs`.
- Are there lines the gap cannot see? A few thin arcs a ping, in a third of the pings, move the per-frame means the
  gap is made of by less than the scenes' own differences: on every validation set the gap with interference was
  at the no-effect floor and nothing was named. But a frame with such a line has one row far brighter than the
  rows beside it across the fan, which neither a scene nor any other catalogued effect makes (the closest,
  sidelobes, spread a bright echo only where the echo is). So the real frames with a line are counted against the
  corrected sim's; significantly more of them find interference, whatever the gap says. `find_lines`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter1d, median_filter
from scipy.stats import fisher_exact

from sonar_realism.sim.effects import Interference

# A row stands out when its mean is this far (a share of the level) above the running median of the rows around
# it; the window is wider than a housing band (a few per cent of the window) so the band cannot hide in it.
STANDOUT = 0.3
WINDOW_ROWS = 41
# The ring-down's rows (a fixed band the catalogue has) are not searched.
SKIP_SHARE = 0.1
# On the tuning sets, bands of 1-3 % of the window lit their rows in 78-100 % of the frames against 20-40 % for the
# scenes themselves and for every interference form (validation, tuning set, catalogue).
FIXED_EXCESS = 0.4


def at_same_range(values: np.ndarray, ranges_m: np.ndarray | None) -> np.ndarray:
    """For every frame's row of `values` [n, n_ranges], the mean over the frames of the value at that row's range
    in metres, not its index: a sensor whose range window changes from ping to ping (the calibrated Oculus) puts a
    reflection at a fixed range on other rows in every frame. `ranges_m` [n, n_ranges]: each frame's range axis
    (None: one axis for all). Where fewer than a quarter of the frames reach a range, 0 (no band can be told there).
    The mean is the largest within a range bin, so a band that falls between two rows in some frames is met at its
    peak."""
    if ranges_m is None or np.allclose(ranges_m, ranges_m[:1]):
        return np.broadcast_to(values.mean(axis=0), values.shape)
    n, n_ranges = values.shape
    grid = np.linspace(float(ranges_m[:, 0].min()), float(ranges_m[:, -1].max()), 2 * n_ranges)
    on_grid = np.stack([np.interp(grid, r, v, left=np.nan, right=np.nan) for r, v in zip(ranges_m, values,
                                                                                          strict=True)])
    covered = np.isfinite(on_grid).sum(axis=0)
    result = np.zeros(grid.size)
    enough = covered >= max(2, n / 4)
    result[enough] = np.nanmean(on_grid[:, enough], axis=0)
    bin_m = float(np.max(np.diff(ranges_m, axis=1)))
    reach = max(1, int(np.ceil(bin_m / (grid[1] - grid[0]))))
    widest = maximum_filter1d(result, size=2 * reach + 1, mode="nearest")
    return np.stack([np.interp(r, grid, widest) for r in ranges_m])


def fixed_share(lit: np.ndarray, ranges_m: np.ndarray | None) -> np.ndarray:
    """For every frame's row of `lit` [n, n_ranges] (bool), the share of frames lit at the same row or at the same
    range in metres, whichever is larger (a row a neighbour's reach wide): an artefact at a fixed sample (a gain
    step) stays on its row, a reflection at a fixed delay (the housing) at its range, whatever the window."""
    by_row = maximum_filter1d(lit.mean(axis=0), size=3, mode="nearest")
    return np.maximum(by_row[None, :], at_same_range(lit.astype(np.float64), ranges_m))


def fixed_row_share(images: np.ndarray, ranges_m: np.ndarray | None = None) -> float:
    """The largest share of frames [n, n_ranges, n_beams] in which a row at one place (beyond the first SKIP_SHARE
    of the window) stands out of its neighbourhood; `ranges_m` as in `at_same_range`."""
    rows = images.astype(np.float32).mean(axis=2)
    level = median_filter(rows, size=(1, WINDOW_ROWS), mode="nearest")
    lit = rows - level > STANDOUT * (level + 0.01)
    first = int(SKIP_SHARE * rows.shape[1])
    return float(fixed_share(lit, ranges_m)[:, first:].max()) if rows.shape[1] > first else 0.0


@dataclass(frozen=True)
class ArcCheck:
    """The share of real frames lighting one fixed row and the corrected sim's; arcs that move are confirmed
    unless the real share exceeds the sim's by `needed`."""

    real_share: float
    sim_share: float
    needed: float = FIXED_EXCESS

    @property
    def confirmed(self) -> bool:
        return self.real_share - self.sim_share < self.needed

    def describe(self) -> str:
        return (f"arcs that move from ping to ping; one row stands out in {100 * self.real_share:.0f}% of the real "
                f"frames against {100 * self.sim_share:.0f}% of the corrected sim's (a fixed band from "
                f"{100 * self.needed:.0f} points more)")


def check_arcs(real_images: np.ndarray, sim_images: np.ndarray, real_ranges_m: np.ndarray | None = None,
               sim_ranges_m: np.ndarray | None = None) -> ArcCheck:
    return ArcCheck(fixed_row_share(real_images, real_ranges_m), fixed_row_share(sim_images, sim_ranges_m))


# A line: a row whose log power, averaged over every beam, stands this far above the brighter of its flanks (rows
# LINE_GAP to LINE_REACH away on each side, per 256 rows of the grid). On the tuning sets (20 frames a side; the
# tuning forms, the catalogue, the validation's alternatives and bands fixed at a row or at a range, on the three
# scenes) this found 19 of 21 interference draws (not 0.3 events a ping) and nothing among 114 other cases.
LINE_DB = 4.0
LINE_GAP, LINE_REACH = 3, 8
# Found when the real frames with a line outnumber the sim's by this share, at this one-sided level (Fisher's exact
# test of the two counts).
LINE_EXCESS = 0.1
LINE_LEVEL = 0.05
# A place (row or range) lit in this share of the frames holds a band, not lines that move: even three thick lines a
# ping light one row in under a tenth of the pings.
FIXED_LINE_SHARE = 0.3
_FLOOR_POWER = (2 / 255) ** 2  # the 8-bit export's darkest counts: log power below this is noise


def _line_rows(n_ranges: int) -> tuple[int, int]:
    gap = max(2, round(LINE_GAP * n_ranges / 256))
    return gap, max(gap + 3, round(LINE_REACH * n_ranges / 256))


def _flanks(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean of `values` [n, n_ranges, n_beams] over the rows before and after each row (see LINE_GAP)."""
    n_ranges = values.shape[1]
    gap, reach = _line_rows(n_ranges)
    rows = np.arange(n_ranges)
    sums = np.concatenate([np.zeros_like(values[:, :1]), np.cumsum(values, axis=1)], axis=1)

    def mean(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        lo, hi = np.clip(lo, 0, n_ranges), np.clip(hi, 0, n_ranges)
        return (sums[:, hi] - sums[:, lo]) / np.maximum(hi - lo, 1)[None, :, None]

    return mean(rows - reach, rows - gap + 1), mean(rows + gap, rows + reach + 1)


def _log_power(images: np.ndarray) -> np.ndarray:
    return 10 * np.log10(images.astype(np.float64) ** 2 + _FLOOR_POWER)


def _ridges(images: np.ndarray) -> np.ndarray:
    """Per frame and row, how far (dB) the row's log power over every beam stands above its brighter flank
    [n, n_ranges]; 0 over the ring-down's rows and the last rows, where a flank is missing."""
    n_ranges = images.shape[1]
    out = np.zeros(images.shape[:2])
    for start in range(0, len(images), 32):  # chunks bound the temporary memory
        level = _log_power(images[start:start + 32])
        before, after = _flanks(level)
        out[start:start + 32] = (level - np.maximum(before, after)).mean(axis=2)
    out[:, :int(SKIP_SHARE * n_ranges)] = 0.0
    out[:, n_ranges - _line_rows(n_ranges)[1]:] = 0.0
    return out


def _moving(ridge: np.ndarray, ranges_m: np.ndarray | None) -> np.ndarray:
    """The ridges of rows at a place that is lit in FIXED_LINE_SHARE of the frames or more set to 0: a band there
    (at one row or one range, see `fixed_share`) is not a line, however its contrast over the scene under it
    changes from frame to frame, and a line at a new range each ping counts in full."""
    return np.where(fixed_share(ridge >= LINE_DB, ranges_m) >= FIXED_LINE_SHARE, 0.0, ridge)


def _strongest_lines(images: np.ndarray, ranges_m: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Per frame the strongest line that moves (dB over its flanks) and its row."""
    moving = _moving(_ridges(images), ranges_m)
    return moving.max(axis=1), moving.argmax(axis=1)


def line_strength(images: np.ndarray, ranges_m: np.ndarray | None = None) -> np.ndarray:
    """Per frame [n_frames, n_ranges, n_beams] the strongest line that moves (dB over its flanks, see LINE_DB);
    `ranges_m` as in `at_same_range`."""
    return _strongest_lines(images, ranges_m)[0]


@dataclass(frozen=True)
class LineFind:
    """Frames with a line that moves (`line_strength` >= LINE_DB) among the real frames and the corrected sim's,
    the one-sided p-value of the real frames having more, and where the real frames' lines are (`real_lines`:
    frame index and row of each lit frame's strongest line)."""

    real_lit: int
    real_frames: int
    sim_lit: int
    sim_frames: int
    p_value: float
    real_lines: tuple[tuple[int, int], ...] = ()

    @property
    def excess(self) -> float:
        return self.real_lit / max(self.real_frames, 1) - self.sim_lit / max(self.sim_frames, 1)

    @property
    def found(self) -> bool:
        return self.excess >= LINE_EXCESS and self.p_value < LINE_LEVEL

    def describe(self) -> str:
        return (f"lines that move from ping to ping: {self.real_lit} of {self.real_frames} real frames show one "
                f"(a row {LINE_DB:g} dB above the rows beside it across the fan) against {self.sim_lit} of "
                f"{self.sim_frames} corrected sim frames (one-sided p = {self.p_value:.2g})")


def find_lines(real_images: np.ndarray, sim_images: np.ndarray, real_ranges_m: np.ndarray | None = None,
               sim_ranges_m: np.ndarray | None = None) -> LineFind:
    strength, rows = _strongest_lines(real_images, real_ranges_m)
    lit = np.nonzero(strength >= LINE_DB)[0]
    sim_lit = int((line_strength(sim_images, sim_ranges_m) >= LINE_DB).sum())
    n_real, n_sim = len(real_images), len(sim_images)
    p_value = float(fisher_exact([[lit.size, n_real - lit.size], [sim_lit, n_sim - sim_lit]],
                                 alternative="greater")[1])
    return LineFind(int(lit.size), n_real, sim_lit, n_sim, p_value, tuple((int(i), int(rows[i])) for i in lit))


def interference_from_lines(real_images: np.ndarray, find: LineFind) -> Interference:
    """The catalogue's interference as the real frames' lines (`find`, made on `real_images`) measure it: the rate
    of pings with a line beyond the sim's (Poisson: P(at least one) = 1 - e^-rate), the amplitude of a line's peak
    over its flanks and its floor across the fan (the median over beams against the peak), medians over the frames
    with a line. The pulse's thickness stays the catalogue's: the lines are too thin for the grid to measure."""
    peaks, floors = [], []
    for index, row in find.real_lines:
        frame = real_images[index:index + 1]
        before, after = _flanks(_log_power(frame))
        flanks = _flanks(frame.astype(np.float64) ** 2)
        background = np.where(before[0, row] > after[0, row], flanks[0][0, row], flanks[1][0, row])
        line = np.maximum(frame[0, row].astype(np.float64) ** 2 - background, 0.0)
        line = np.convolve(line, np.ones(3) / 3, mode="same")  # a peak of one bright speckle is not the line's
        peaks.append(float(line.max()))
        floors.append(float(np.median(line)) / max(float(line.max()), 1e-12))
    bounds = Interference.PARAM_BOUNDS
    rate = -math.log(1.0 - min(max(find.excess, 0.0), 0.95))
    amplitude = math.sqrt(float(np.median(peaks))) if peaks else Interference.amplitude
    floor_db = 10 * math.log10(max(float(np.median(floors)), 1e-12)) if floors else Interference.floor_db

    def clip(name: str, value: float) -> float:
        return float(min(max(value, bounds[name][0]), bounds[name][1]))

    return dataclasses.replace(Interference(), rate_per_ping=clip("rate_per_ping", rate),
                               amplitude=clip("amplitude", amplitude), floor_db=clip("floor_db", floor_db))
