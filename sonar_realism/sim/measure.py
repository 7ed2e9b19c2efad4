"""Measurements on sonar frames that a calibration fits the simulator to: the same code measures the real
recording and the simulated frames, so every fitted number is matched like for like.

All images are float [n_ranges, n_beams] scaled so the frame maximum is 1 (the real export's rescale).

- seabed onset per beam group: the first range after the water column where the smoothed brightness reaches
  half the seabed level; its curvature across the fan gives the tilt, its range the height;
- seabed patchiness: the local mean (a box a few cells wide) below the onset, as log level about each row's
  median: its spread (interquartile, as an rms), its correlation lengths along range and across beams, the share
  below half;
- a target: a long run of beams darker than the seabed around it behind a bright return (its shadow).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from sonar_realism.sim.fingerprint import NEAR_ZERO

ONSET_GROUPS = 16
TILT_GRID_DEG = np.arange(-5.0, 60.0, 0.5)
# Weak pull of the tilt towards this value: where the fan is too narrow for the onset to curve, it decides.
TILT_PRIOR_DEG = 10.0
LOCAL_BOX = 9
# A target's shadow: local means (over a box of SHADOW_BOX_ROWS rows) under SHADOW_LEVEL of the seabed at the same
# ranges, behind a return (its brightest row across the shadow's beams) brighter than ECHO_LEVEL times it. Chosen
# on the Oculus fit recording's labelled targets and on calibrated-sim frames with and without targets
# (docs/RESULTS.md): 0.99 of its detections there are a labelled target, it finds one in half of the frames, and it
# fires on 3 of 40 target-free simulated frames.
SHADOW_BOX_ROWS = 25
SHADOW_LEVEL = 0.65
ECHO_LEVEL = 1.3


@dataclass(frozen=True)
class FrameGeometry:
    """What one frame says about the mounting: onset (m) at the central beams, fitted height and tilt."""

    onset_m: float
    height_m: float
    tilt_deg: float


def onset_rows(image: np.ndarray, groups: int = ONSET_GROUPS) -> np.ndarray:
    """Row of the seabed onset per beam group (NaN where the group shows no water column above the seabed)."""
    n_r, n_b = image.shape
    groups = max(1, min(groups, n_b // 2))
    width = n_b // groups
    cols = image[:, :width * groups].reshape(n_r, groups, width).mean(axis=2)
    smooth = cv2.blur(cols.astype(np.float32), (1, max(3, n_r // 40)))
    level = np.percentile(smooth, 75, axis=0)
    top = int(0.5 * n_r)
    out = np.full(groups, np.nan)
    for g in range(groups):
        dark = np.nonzero(smooth[:top, g] < 0.3 * level[g])[0]
        if dark.size == 0:
            continue
        above = np.nonzero(smooth[dark[0]:, g] > 0.5 * level[g])[0]
        if above.size:
            out[g] = dark[0] + above[0]
    return out


def group_bearings(azimuths_rad: np.ndarray, groups: int = ONSET_GROUPS) -> np.ndarray:
    groups = max(1, min(groups, azimuths_rad.size // 2))
    width = azimuths_rad.size // groups
    return azimuths_rad[:width * groups].reshape(groups, width).mean(axis=1)


def frame_geometry(image: np.ndarray, ranges_m: np.ndarray, azimuths_rad: np.ndarray,
                   vertical_fov_deg: float) -> FrameGeometry | None:
    """Height and tilt that put a flat seabed's first return (the lower edge of the vertical aperture) where
    this frame's onset is, across the fan; None when fewer than 6 beam groups show an onset."""
    rows = onset_rows(image)
    theta = group_bearings(azimuths_rad)
    ok = np.isfinite(rows)
    if ok.sum() < 6:
        return None
    onset = np.interp(rows[ok], np.arange(ranges_m.size), ranges_m)
    theta = theta[ok]
    median = float(np.median(onset))
    keep = np.abs(onset - median) < 0.3 * median
    if keep.sum() < 6:
        return None
    onset, theta = onset[keep], theta[keep]
    half_v = math.radians(vertical_fov_deg) / 2
    best: tuple[float, float, float] | None = None
    for tilt_deg in TILT_GRID_DEG:
        t = math.radians(tilt_deg)
        # downward component of the aperture's lower edge: the seabed at height h is first met at h / d
        d = math.cos(half_v) * np.cos(theta) * math.sin(t) + math.sin(half_v) * math.cos(t)
        if (d <= 0.01).any():
            continue
        height = float((onset / d).sum() / (1.0 / d ** 2).sum())
        error = float(((onset - height / d) ** 2).mean()) + 1e-4 * median ** 2 * ((tilt_deg - TILT_PRIOR_DEG) / 10) ** 2
        if best is None or error < best[0]:
            best = (error, height, float(tilt_deg))
    if best is None:
        return None
    central = np.abs(theta) <= np.quantile(np.abs(theta), 0.5)
    return FrameGeometry(float(np.median(onset[central])), best[1], best[2])


def filled_window_geometry(ranges_m: np.ndarray, vertical_fov_deg: float) -> FrameGeometry:
    """Mounting for a frame whose seabed fills the window from its first bin (no water column to measure: a
    tank, a steep tilt): the aperture's lower edge meets the seabed at the window's start and the beam axis at
    its middle, i.e. the sensor is aimed at what it records. An assumption, not a measurement."""
    start, middle = float(ranges_m[0]), float(ranges_m[0] + ranges_m[-1]) / 2
    half_v = math.radians(vertical_fov_deg) / 2
    # sin(t + half_v) / sin(t) = middle / start, solved for the axis' depression t
    ratio = max(middle / max(start, 1e-3), 1.0 + 1e-3)
    tilt = math.atan2(math.sin(half_v), ratio - math.cos(half_v))
    return FrameGeometry(start, middle * math.sin(tilt), math.degrees(tilt))


def seabed_rows(image: np.ndarray) -> int:
    """First row below the seabed onset (median over beam groups; the top third when none is found)."""
    rows = onset_rows(image)
    return int(np.nanmedian(rows)) + 2 if np.isfinite(rows).any() else image.shape[0] // 3


@dataclass(frozen=True)
class SeabedStats:
    contrast: float  # rms of log local mean below the onset
    scale_rows: float  # correlation length of the log local mean along range, in rows
    width_beams: float  # its correlation length across beams, in beams
    dark_fraction: float  # share of local means below half their median


def seabed_stats(image: np.ndarray, targets: np.ndarray | None = None) -> SeabedStats | None:
    """The seabed's patchiness below the onset; `targets` (bool per beam) marks the beams of targets and their
    shadows, left out: a seabed statistic, not a target's (a target spanning half the fan doubled the contrast)."""
    start = seabed_rows(image)
    region = image[start:]
    if region.shape[0] < 4 * LOCAL_BOX:
        return None
    local = cv2.blur(region.astype(np.float32), (LOCAL_BOX, LOCAL_BOX))[LOCAL_BOX:-LOCAL_BOX, 2:-2]
    if targets is not None and targets.any():
        keep = ~np.asarray(targets, bool)[2:-2]
        if keep.sum() < 4 * LOCAL_BOX:
            return None
        local = np.where(keep[None, :], local, np.float32(np.nan))
    median = float(np.nanmedian(local))
    if median <= 1e-4:
        return None
    # log level about each row's median: the range trend (TVG, beam pattern) is not patchiness
    log_mean = np.log(np.maximum(local, 0.02 * median))
    centred = log_mean - np.nanmedian(log_mean, axis=1, keepdims=True)
    low, high = np.nanpercentile(centred, [25, 75])
    contrast = float(high - low) / 1.349  # rms of a normal with that spread: shadows and holes do not inflate it
    seen = np.isfinite(centred)
    return SeabedStats(contrast, _correlation_length(centred, axis=0), _correlation_length(centred, axis=1),
                       float((centred[seen] < math.log(0.5)).mean()))


def target_beams(n_beams: int, spans: Sequence[tuple[int, int]]) -> np.ndarray:
    """Bool per beam: the beams of each (first, last) span of a target, grown on each side by the half local box
    its return leaks into and a sixteenth of its width (its shadow's edge)."""
    out = np.zeros(n_beams, bool)
    for first, last in spans:
        pad = LOCAL_BOX // 2 + 1 + (last - first) // 16
        out[max(0, first - pad):min(n_beams, last + 1 + pad)] = True
    return out


def _correlation_length(centred: np.ndarray, axis: int) -> float:
    """The first lag along `axis` where the autocorrelation falls below 1/e (half the extent when it never does);
    NaN cells (left-out beams) do not count."""
    variance = max(float(np.nanmean(centred ** 2)), 1e-12)
    moved = np.moveaxis(centred, axis, 0)
    for lag in range(1, moved.shape[0] // 2):
        if float(np.nanmean(moved[lag:] * moved[:-lag])) / variance < math.exp(-1):
            return float(lag)
    return float(moved.shape[0] // 2)


@dataclass(frozen=True)
class TargetStats:
    width_beams: int  # of the shadow
    start_row: int  # first row of the shadow
    first_beam: int


def onset_per_beam(image: np.ndarray, fallback: int) -> np.ndarray:
    """The seabed onset row of every beam (its group's, `onset_rows`; `fallback` where a group shows none)."""
    rows = onset_rows(image)
    rows = np.where(np.isfinite(rows), rows, fallback)
    width = image.shape[1] // rows.size
    return np.concatenate([np.repeat(rows, width), np.full(image.shape[1] - width * rows.size, rows[-1])])


def target_shadow(image: np.ndarray) -> TargetStats | None:
    """A target: the widest run of beams whose local mean stays under SHADOW_LEVEL of the seabed at the same
    ranges over most of a quarter of the rows below the onset (its shadow), with a return brighter than
    ECHO_LEVEL times that seabed just ahead of the shadow (its echo), or None.

    Both against the seabed at the same ranges (each row's median local mean over the beams), so that the range
    trend and the seabed's own dark patches (no echo ahead of them) are not taken for shadows; and only past each
    beam's own seabed onset, so that the water above a late onset is not either."""
    start = seabed_rows(image)
    region = image[start:]
    if region.shape[0] < 16:
        return None
    local = cv2.blur(region.astype(np.float32), (9, SHADOW_BOX_ROWS))
    seabed = np.maximum(np.median(local, axis=1, keepdims=True), 1e-6)
    relative = local / seabed
    # An echo is a thin arc, judged on a lightly smoothed level, over the whole frame: a target standing on the
    # seabed's first rows returns from above them (against the seabed's level where it begins).
    fine = cv2.blur(image.astype(np.float32), (3, 3)) / np.concatenate([np.repeat(seabed[:1], start, axis=0), seabed])
    past_onset = np.arange(region.shape[0])[:, None] >= (onset_per_beam(image, start) - start
                                                         + SHADOW_BOX_ROWS // 2)[None, :]
    dark = (relative < SHADOW_LEVEL) & past_onset
    run_rows = max(3, region.shape[0] // 4)
    long_run = cv2.blur(dark.astype(np.float32), (1, run_rows)) > 0.8
    ahead_rows = max(SHADOW_BOX_ROWS, region.shape[0] // 8)
    best: TargetStats | None = None
    for first_beam, stop in _runs(long_run.any(axis=0)):
        width = stop - first_beam
        if width < max(3, image.shape[1] // 32) or (best is not None and width <= best.width_beams):
            continue
        flagged = int(np.nonzero(long_run[:, first_beam:stop].any(axis=1))[0][0])
        # the centred box flags a run from 0.3 of its length past the run's start: the shadow begins at the first
        # row from half a box before that where most of its beams are dark
        half_dark = np.nonzero(dark[max(0, flagged - run_rows // 2):, first_beam:stop].mean(axis=1) > 0.5)[0]
        shadow_row = max(0, flagged - run_rows // 2) + (int(half_dark[0]) if half_dark.size else run_rows // 2)
        # the return: the brightest row ahead, averaged across the shadow's beams (speckle averages out there)
        ahead = fine[max(0, start + shadow_row - ahead_rows):start + shadow_row, first_beam:stop]
        if ahead.size and float(ahead.mean(axis=1).max()) > ECHO_LEVEL:
            best = TargetStats(width, start + shadow_row, first_beam)
    return best


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of every run of True in a 1-D array."""
    edges = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    return list(zip(np.nonzero(edges == 1)[0].tolist(), np.nonzero(edges == -1)[0].tolist(), strict=True))


def highlight_ratio(image: np.ndarray, columns: slice, shadow_row: int) -> float:
    """Brightness of a target's return (95th percentile just ahead of its shadow) over the seabed median."""
    top = max(0, shadow_row - max(8, image.shape[0] // 8))
    ahead = image[top:shadow_row + 2, columns]
    seabed = float(np.median(image[seabed_rows(image):]))
    return float(np.percentile(ahead, 95)) / max(seabed, 1e-6) if ahead.size else math.nan


def shadow_level(image: np.ndarray, rows: slice, columns: slice) -> float:
    """How dark a target's shadow is: the darkest band of rows behind the target's middle row, over the middle
    half of its columns, against the seabed beside it at the same rows (medians of the frame scaled to its
    maximum); NaN where the target leaves too few rows behind it or too few columns beside it.

    The darkest band, not a fixed place behind the target, so that a box framing the echo alone and a box framing
    the echo and its shadow measure the same shadow, and a hollow return's dark inside counts as it looks."""
    first, last = rows.start or 0, rows.stop or image.shape[0]
    start, stop = columns.start or 0, columns.stop or image.shape[1]
    width = stop - start
    begin = (first + last) // 2
    band = max(8, (image.shape[0] - begin) // 8)
    if width < 4 or image.shape[0] - begin < 2 * band:
        return math.nan
    pad = max(4, width // 8)
    beside = np.ones(image.shape[1], bool)
    beside[max(0, start - pad):stop + pad] = False
    if beside.sum() < 16:
        return math.nan
    inner = image[:, start + width // 4:stop - width // 4]
    levels = []
    for top in range(begin, image.shape[0] - band + 1, band // 2):
        seabed = float(np.median(image[top:top + band, beside]))
        if seabed > 1e-4:
            levels.append(float(np.median(inner[top:top + band])) / seabed)
    return min(levels) if levels else math.nan


def near_zero_fraction(image: np.ndarray, threshold: float = NEAR_ZERO) -> float:
    """Share of pixels at or below 2 counts of the frame max (black water)."""
    return float((image <= threshold).mean())
