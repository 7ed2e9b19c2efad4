"""Where the gap lies: over range x bearing cells, over intensity levels and over spatial-frequency bands.

Every map uses the same unbiased standardised mean difference as the headline gap (diagnose.gap), on features
measured locally: per cell (brightness, speckle contrast, grain along beam and range), per intensity level
(fraction of pixels at that level, speckle contrast of patches at that level) and per octave band of the power
spectrum along range and along beam.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from sonar_realism.diagnose.gap import FeatureScale, Stats, feature_gaps
from sonar_realism.diagnose.result import GapMaps, HotBin, HotCell, Share
from sonar_realism.errors import ConfigError
from sonar_realism.evaluate.statistics import StatisticsConfig, level_histograms, octave_band_edges, patch_moments

CELL_FEATURES = ("mean", "contrast", "grain_beam", "grain_range")
# Octave intensity levels: sonar frames are mostly dark, so equal-width levels would lump the background together.
LEVEL_EDGES = (0.0, 1 / 128, 1 / 64, 1 / 32, 1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0 + 1e-6)


@dataclass(frozen=True)
class WhereConfig:
    """range_cells x bearing_cells cells in the range-bearing map; patch: side of speckle patches per level."""

    range_cells: int = 8
    bearing_cells: int = 8
    patch: int = 8

    def validate(self) -> None:
        if self.range_cells < 1 or self.bearing_cells < 1 or self.patch < 2:
            raise ConfigError("WhereConfig: range_cells, bearing_cells >= 1 and patch >= 2")


def where_features(images: np.ndarray, config: WhereConfig = WhereConfig()) -> dict[str, np.ndarray]:
    """Local feature rows per frame: {"cells": [n, cells * 4], "levels": [n, levels * 2]}."""
    return {"cells": cell_features(images, config.range_cells, config.bearing_cells).reshape(len(images), -1),
            "levels": level_features(images, config.patch)}


def cell_features(images: np.ndarray, range_cells: int, bearing_cells: int) -> np.ndarray:
    """[n, range_cells, bearing_cells, 4]: mean, CV, lag-1 correlation along beam and along range per cell."""
    n, r, b = images.shape
    detrended = np.stack([x - cv2.blur(x, (5, 5), borderType=cv2.BORDER_REFLECT) for x in images])
    beam_products = np.zeros_like(images)
    beam_products[:, :, :-1] = detrended[:, :, :-1] * detrended[:, :, 1:]
    range_products = np.zeros_like(images)
    range_products[:, :-1, :] = detrended[:, :-1, :] * detrended[:, 1:, :]
    r_edges = np.linspace(0, r, range_cells + 1).round().astype(int)
    b_edges = np.linspace(0, b, bearing_cells + 1).round().astype(int)
    out = np.zeros((n, range_cells, bearing_cells, len(CELL_FEATURES)))
    for i, (r0, r1) in enumerate(zip(r_edges[:-1], r_edges[1:], strict=True)):
        for j, (b0, b1) in enumerate(zip(b_edges[:-1], b_edges[1:], strict=True)):
            cell = images[:, r0:r1, b0:b1]
            mean = cell.mean(axis=(1, 2))
            # below half an 8-bit count rms there is no texture to correlate (empty water, outside the fan)
            energy = np.maximum((detrended[:, r0:r1, b0:b1] ** 2).sum(axis=(1, 2)), cell[0].size * (0.5 / 255) ** 2)
            out[:, i, j, 0] = mean
            # contrast of an (almost) empty cell is noise over nothing: measure it against a 1 % floor instead
            out[:, i, j, 1] = cell.std(axis=(1, 2)) / np.maximum(mean, 0.01)
            out[:, i, j, 2] = beam_products[:, r0:r1, b0:b1].sum(axis=(1, 2)) / energy
            out[:, i, j, 3] = range_products[:, r0:r1, b0:b1].sum(axis=(1, 2)) / energy
    return out


def level_features(images: np.ndarray, patch: int) -> np.ndarray:
    """[n, 2 * levels]: fraction of pixels in each octave level, then the median speckle contrast of the patches
    whose mean falls in that level (the frame's median contrast where no patch does)."""
    levels = len(LEVEL_EDGES) - 1
    hist = level_histograms(images)
    grid = np.linspace(0.0, 1.0, hist.shape[1])
    which = np.clip(np.searchsorted(LEVEL_EDGES, grid, side="right") - 1, 0, levels - 1)
    mass = np.stack([hist[:, which == k].sum(axis=1) for k in range(levels)], axis=1)
    mean, std, _ = patch_moments(images, patch)
    cv = std / np.maximum(mean, 1.0 / 255)  # darker than one 8-bit count: contrast against one count
    contrast = np.zeros((len(images), levels))
    for i in range(len(images)):
        fallback = float(np.median(cv[i]))
        for k in range(levels):
            sel = (mean[i] >= LEVEL_EDGES[k]) & (mean[i] < LEVEL_EDGES[k + 1])
            contrast[i, k] = float(np.median(cv[i][sel])) if sel.any() else fallback
    return np.column_stack([mass, contrast])


def gap_maps(where_a: Stats, where_b: Stats, where_scale: FeatureScale, stats_a: Stats, stats_b: Stats,
             stats_scale: FeatureScale, config: WhereConfig = WhereConfig(),
             profile_bins: int = StatisticsConfig.profile_bins) -> GapMaps:
    local = feature_gaps(where_a, where_b, where_scale)
    cells = local["cells"].reshape(config.range_cells, config.bearing_cells, len(CELL_FEATURES)).mean(axis=2)
    n_levels = len(LEVEL_EDGES) - 1
    levels = local["levels"].reshape(2, n_levels).mean(axis=0)
    spectrum = feature_gaps({"spectrum": stats_a["spectrum"]}, {"spectrum": stats_b["spectrum"]},
                            FeatureScale({"spectrum": stats_scale.spread["spectrum"]}))["spectrum"]
    half = spectrum.shape[0] // 2
    families = ("range_profile", "bearing_profile")
    profiles = feature_gaps({f: stats_a[f] for f in families}, {f: stats_b[f] for f in families},
                            FeatureScale({f: stats_scale.spread[f] for f in families}))
    return GapMaps(cells=cells, levels=levels, bands_range=spectrum[:half], bands_beam=spectrum[half:],
                   range_bins=profiles["range_profile"][:profile_bins],
                   bearing_bins=profiles["bearing_profile"][:profile_bins])


def level_names() -> list[str]:
    return [f"{lo * 255:.0f}-{min(hi, 1.0) * 255:.0f}" for lo, hi in zip(LEVEL_EDGES[:-1], LEVEL_EDGES[1:],
                                                                         strict=True)]


def band_names(length: int, n_bands: int) -> list[str]:
    """Octave bands as periods in pixels (the highest frequencies first)."""
    edges = octave_band_edges(length, n_bands)
    names = []
    for hi, lo in zip(edges[:-1], edges[1:], strict=True):
        longest = 2 * length / max(2 * lo, 1)
        shortest = 2 * length / max(2 * (hi - 1), 1)
        names.append(f"{shortest:.3g}-{longest:.3g} px")
    return names


def hot_cells(cells: np.ndarray, ranges_m: np.ndarray, azimuths_rad: np.ndarray, top: int = 3,
              share: float = 0.5) -> tuple[HotCell, ...]:
    """The cells holding the largest gap (up to `top`, or fewer if they already hold `share` of the positive total),
    as range and bearing intervals a person can read."""
    positive = np.clip(cells, 0.0, None)
    total = float(positive.sum())
    if total <= 0.0:
        return ()
    r_edges = np.linspace(0, len(ranges_m), cells.shape[0] + 1).round().astype(int)
    b_edges = np.linspace(0, len(azimuths_rad), cells.shape[1] + 1).round().astype(int)
    out: list[HotCell] = []
    covered = 0.0
    for flat in np.argsort(positive, axis=None)[::-1][:top]:
        i, j = (int(k) for k in np.unravel_index(flat, cells.shape))
        covered += float(positive[i, j])
        out.append(HotCell(i, j, (round(float(ranges_m[r_edges[i]]), 3),
                                  round(float(ranges_m[r_edges[i + 1] - 1]), 3)),
                           (round(float(np.degrees(azimuths_rad[b_edges[j]])), 2),
                            round(float(np.degrees(azimuths_rad[b_edges[j + 1] - 1])), 2)),
                           float(cells[i, j]), float(positive[i, j] / total)))
        if covered / total >= share:
            break
    return tuple(out)


def hot_bins(values: np.ndarray, axis: np.ndarray, top: int = 3) -> tuple[HotBin, ...]:
    """The profile bins holding the largest gap (up to `top`), as intervals of `axis` (ranges in m or bearings in
    degrees) with their share of the positive total."""
    positive = np.clip(values, 0.0, None)
    total = float(positive.sum())
    if total <= 0.0:
        return ()
    edges = np.linspace(0, len(axis), len(values) + 1).round().astype(int)
    return tuple(HotBin(int(k), (round(float(axis[edges[k]]), 3),
                                 round(float(axis[max(edges[k + 1] - 1, edges[k])]), 3)),
                        float(values[k]), float(positive[k] / total))
                 for k in np.argsort(positive)[::-1][:top])


def concentration(values: np.ndarray, names: list[str], top: int = 2) -> tuple[Share, ...]:
    """The entries of a 1-D gap profile (levels or bands) holding the most gap, with their share."""
    positive = np.clip(values, 0.0, None)
    total = float(positive.sum())
    order = np.argsort(positive)[::-1][:top]
    return tuple(Share(names[k], float(values[k]), float(positive[k] / total) if total > 0 else 0.0) for k in order)
