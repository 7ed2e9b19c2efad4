"""Polar ↔ Cartesian fan, and resampling polar frames onto other range/bearing grids.

A polar frame has one bearing per beam (Oculus bearing tables are not uniform) and one range per row.
Every mapping here is a cv2.remap whose index maps come from np.interp of the wanted range/bearing into
the frame's own tables, so non-uniform tables are exact. Maps are cached by geometry: the first call for a
geometry builds them, later calls (every ping of a recording) only remap.

Fan convention (FanLayout): pixel x = apex_x_px + r·sin θ·px_per_m, and y = apex_y_px − r·cos θ·px_per_m
when range grows upward (apex at the bottom, the usual display and the ARIS export), + when downward.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from sonar_realism.errors import FrameError
from sonar_realism.frames import SonarImage

_CACHE_ENTRIES = 32
_CACHE_BYTES = 128 << 20
_OUTSIDE = -16.0  # map value far enough outside the source image that remap's constant border gives 0


@dataclass(frozen=True)
class FanLayout:
    """Where a fan sits in a Cartesian image of width_px × height_px (see the module docstring)."""

    width_px: int
    height_px: int
    apex_x_px: float
    apex_y_px: float
    px_per_m: float
    range_up: bool = True

    def __post_init__(self) -> None:
        if self.width_px < 1 or self.height_px < 1:
            raise FrameError(f"FanLayout: image size must be positive, got {self.width_px}×{self.height_px}")
        if not (math.isfinite(self.px_per_m) and self.px_per_m > 0):
            raise FrameError(f"FanLayout: px_per_m must be positive, got {self.px_per_m}")
        if not (math.isfinite(self.apex_x_px) and math.isfinite(self.apex_y_px)):
            raise FrameError("FanLayout: apex must be finite")


class _MapCache:
    """A small LRU of remap tables keyed by geometry (the bytes of the tables, not their identity), bounded in
    count and in bytes (a 1024² fan table is 8 MiB). Locked: recorder threads draw fans beside the main loop."""

    def __init__(self, max_entries: int, max_bytes: int) -> None:
        self.max_entries = max_entries
        self.max_bytes = max_bytes
        self.entries: OrderedDict[Any, tuple[Any, int]] = OrderedDict()
        self.lock = threading.Lock()

    def get(self, key: Any, build: Callable[[], tuple[Any, ...]]) -> tuple[Any, ...]:
        with self.lock:
            if key in self.entries:
                self.entries.move_to_end(key)
                return self.entries[key][0]
            value = build()
            self.entries[key] = (value, sum(v.nbytes for v in value if isinstance(v, np.ndarray)))
            while len(self.entries) > 1 and (len(self.entries) > self.max_entries
                                             or self.total_bytes() > self.max_bytes):
                self.entries.popitem(last=False)
            return value

    def total_bytes(self) -> int:
        return sum(size for _, size in self.entries.values())

    def clear(self) -> None:
        with self.lock:
            self.entries.clear()


_MAPS = _MapCache(_CACHE_ENTRIES, _CACHE_BYTES)


def clear_cache() -> None:
    """Forget every cached remap table (benchmarks measure the uncached build with it)."""
    _MAPS.clear()


# ---------------------------------------------------------------------------------------------- index helpers


def _fractional_index(values: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Fractional index of each value in a strictly increasing table; _OUTSIDE beyond half a bin past either end."""
    n = table.shape[0]
    index = np.interp(values, table, np.arange(n, dtype=np.float64))
    if n == 1:
        half_low = half_high = 0.5 * max(abs(float(table[0])), 1e-9)
    else:
        half_low, half_high = 0.5 * (table[1] - table[0]), 0.5 * (table[-1] - table[-2])
    outside = (values < table[0] - half_low) | (values > table[-1] + half_high)
    return np.where(outside, _OUTSIDE, index)


def _remap(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, nearest: bool = False) -> np.ndarray:
    """cv2.remap over the last two axes of `image`, for every dtype SonarImage allows (`nearest`: labels, which
    must not blend)."""
    interpolation = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    if image.ndim == 3:
        return np.stack([_remap(plane, map_x, map_y, nearest) for plane in image])
    if image.dtype == np.uint32:
        # cv2 has no 32-bit unsigned remap; float64 holds every uint32 exactly.
        out = cv2.remap(image.astype(np.float64), map_x, map_y, interpolation, borderMode=cv2.BORDER_CONSTANT)
        return np.clip(np.rint(out), 0, np.iinfo(np.uint32).max).astype(np.uint32)
    return cv2.remap(image, map_x, map_y, interpolation, borderMode=cv2.BORDER_CONSTANT)


def _axes_key(frame: SonarImage) -> tuple[bytes, bytes]:
    return frame.ranges_m.tobytes(), frame.azimuths_rad.tobytes()


# ---------------------------------------------------------------------------------------------- polar -> fan


def fan_layout(frame: SonarImage, width_px: int) -> FanLayout:
    """The layout that fits the whole fan of `frame` into an image `width_px` wide, apex at the bottom."""
    if width_px < 2:
        raise FrameError(f"width_px: expected >= 2, got {width_px}")
    r_min, r_max = float(frame.ranges_m[0]), float(frame.ranges_m[-1])
    bearings = [float(frame.azimuths_rad[0]), float(frame.azimuths_rad[-1])]
    if bearings[0] < 0 < bearings[1]:
        bearings.append(0.0)
    xs = [r * math.sin(b) for r in (r_min, r_max) for b in bearings]
    ys = [r * math.cos(b) for r in (r_min, r_max) for b in bearings]
    # Bearings beyond ±90° reach below the apex; a wide fan spans ±90° at most by construction of xs/ys.
    if bearings[0] < -math.pi / 2 < bearings[1]:
        xs.append(-r_max)
    if bearings[0] < math.pi / 2 < bearings[1]:
        xs.append(r_max)
    span_x = max(max(xs) - min(xs), 1e-9)
    px_per_m = (width_px - 1) / span_x
    height_px = max(2, int(math.ceil((max(ys) - min(ys)) * px_per_m)) + 1)
    return FanLayout(width_px=width_px, height_px=height_px, apex_x_px=-min(xs) * px_per_m,
                     apex_y_px=max(ys) * px_per_m, px_per_m=px_per_m, range_up=True)


def _fan_maps(frame: SonarImage, layout: FanLayout) -> tuple[np.ndarray, np.ndarray]:
    def build() -> tuple[np.ndarray, np.ndarray]:
        xs = (np.arange(layout.width_px, dtype=np.float64) - layout.apex_x_px) / layout.px_per_m
        ys = (np.arange(layout.height_px, dtype=np.float64) - layout.apex_y_px) / layout.px_per_m
        forward = -ys if layout.range_up else ys
        x, y = np.meshgrid(xs, forward)
        column = _fractional_index(np.arctan2(x, y), frame.azimuths_rad).astype(np.float32)
        row = _fractional_index(np.hypot(x, y), frame.ranges_m).astype(np.float32)
        return column, row

    return _MAPS.get(("fan", *_axes_key(frame), layout), build)


def polar_to_fan(frame: SonarImage, width_px: int, layout: FanLayout | None = None) -> np.ndarray:
    """Cartesian fan image of `frame` (apex at the bottom unless `layout` says otherwise), 0 outside the fan.

    Keeps the dtype (uint8 in, uint8 out for display) and a leading sample axis ([S, H, W]). The tables
    stay float32: with OpenCV 5 that remaps several times faster than the fixed-point (CV_16SC2) form
    (bench/bench_geometry.py measured both).
    """
    layout = layout or fan_layout(frame, width_px)
    map_x, map_y = _fan_maps(frame, layout)
    return _remap(_native(frame.intensity), map_x, map_y)


def _native(intensity: np.ndarray) -> np.ndarray:
    """OpenCV reads raw bytes: big-endian samples are swapped once, before any filter or remap sees them."""
    return intensity if intensity.dtype.isnative else intensity.astype(intensity.dtype.newbyteorder("="))


def fan_to_polar(image: np.ndarray, layout: FanLayout, ranges_m: np.ndarray,
                 azimuths_rad: np.ndarray, nearest: bool = False) -> np.ndarray:
    """Polar [n_ranges, n_beams] samples of a Cartesian fan image (0 where the cell falls outside the image);
    `nearest` for a label image (class ids), which interpolation would blend."""
    ranges = np.asarray(ranges_m, dtype=np.float64)
    azimuths = np.asarray(azimuths_rad, dtype=np.float64)
    if image.shape[-2:] != (layout.height_px, layout.width_px):
        raise FrameError(f"fan_to_polar: image is {image.shape[-1]}×{image.shape[-2]} px, layout says "
                         f"{layout.width_px}×{layout.height_px}")

    def build() -> tuple[np.ndarray, np.ndarray]:
        r, theta = np.meshgrid(ranges, azimuths, indexing="ij")
        x = layout.apex_x_px + r * np.sin(theta) * layout.px_per_m
        forward = r * np.cos(theta) * layout.px_per_m
        y = layout.apex_y_px - forward if layout.range_up else layout.apex_y_px + forward
        return x.astype(np.float32), y.astype(np.float32)

    map_x, map_y = _MAPS.get(("polar", ranges.tobytes(), azimuths.tobytes(), layout), build)
    return _remap(image, map_x, map_y, nearest)


# ---------------------------------------------------------------------------------------------- polar -> polar


def resample_to_grid(frame: SonarImage, n_ranges: int, n_beams: int) -> SonarImage:
    """`frame` on a uniform grid of n_ranges × n_beams spanning the same first..last range and bearing.

    Keeps a leading sample axis and the dtype (integers are rounded). Shrinking an axis low-pass filters
    it first so that speckle does not alias into false texture.
    """
    if n_ranges < 1 or n_beams < 1:
        raise FrameError(f"resample_to_grid: grid must be at least 1×1, got {n_ranges}×{n_beams}")
    if (frame.n_ranges == 1 < n_ranges) or (frame.n_beams == 1 < n_beams):
        raise FrameError(f"resample_to_grid: {frame.meta.get('source', f'frame seq {frame.seq}')} is "
                         f"{frame.n_ranges} range(s) x {frame.n_beams} beam(s); a single range bin or beam cannot be "
                         f"spread over the {n_ranges} x {n_beams} grid")
    ranges = _uniform_span(frame.ranges_m, n_ranges)
    azimuths = _uniform_span(frame.azimuths_rad, n_beams)
    return _resample(frame, ranges, azimuths)


def resample_like(frame: SonarImage, reference: SonarImage) -> SonarImage:
    """`frame` resampled onto `reference`'s ranges and bearings (0 where reference reaches beyond frame)."""
    return _resample(frame, reference.ranges_m, reference.azimuths_rad)


def _uniform_span(table: np.ndarray, n: int) -> np.ndarray:
    if n == 1:
        return np.array([0.5 * (table[0] + table[-1])])
    return np.linspace(table[0], table[-1], n)


def _resample(frame: SonarImage, ranges: np.ndarray, azimuths: np.ndarray) -> SonarImage:
    if np.array_equal(frame.ranges_m, ranges) and np.array_equal(frame.azimuths_rad, azimuths):
        return frame

    def build() -> tuple[np.ndarray, np.ndarray, float, float]:
        rows = _fractional_index(ranges, frame.ranges_m)
        columns = _fractional_index(azimuths, frame.azimuths_rad)
        map_x = np.broadcast_to(columns[None, :], (ranges.shape[0], azimuths.shape[0])).astype(np.float32)
        map_y = np.broadcast_to(rows[:, None], (ranges.shape[0], azimuths.shape[0])).astype(np.float32)
        return map_x, map_y, _shrink_factor(rows), _shrink_factor(columns)

    key = ("grid", *_axes_key(frame), ranges.tobytes(), azimuths.tobytes())
    map_x, map_y, row_shrink, column_shrink = _MAPS.get(key, build)
    intensity = _antialias(_native(frame.intensity), row_shrink, column_shrink)
    return frame.replace(intensity=_remap(intensity, map_x, map_y), ranges_m=ranges, azimuths_rad=azimuths)


def _shrink_factor(indices: np.ndarray) -> float:
    """Source bins per output bin (1 when enlarging)."""
    inside = indices[indices != _OUTSIDE]
    if inside.shape[0] < 2:
        return 1.0
    return max(1.0, float(np.median(np.abs(np.diff(inside)))))


def _antialias(intensity: np.ndarray, row_shrink: float, column_shrink: float) -> np.ndarray:
    if row_shrink <= 1.0 and column_shrink <= 1.0:
        return intensity
    if intensity.ndim == 3:
        return np.stack([_antialias(plane, row_shrink, column_shrink) for plane in intensity])
    # Gaussian whose width matches the output bin (sigma = sqrt(f² − 1) / 2), zero when not shrinking.
    sigma_y = math.sqrt(row_shrink ** 2 - 1) / 2
    sigma_x = math.sqrt(column_shrink ** 2 - 1) / 2
    working = intensity.astype(np.float64) if intensity.dtype == np.uint32 else intensity
    blurred = cv2.GaussianBlur(working, (0, 0), sigmaX=max(sigma_x, 1e-3), sigmaY=max(sigma_y, 1e-3),
                               borderType=cv2.BORDER_REFLECT)
    if intensity.dtype == np.uint32:
        return np.clip(np.rint(blurred), 0, np.iinfo(np.uint32).max).astype(np.uint32)
    return blurred
