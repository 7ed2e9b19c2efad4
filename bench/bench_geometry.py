"""Polar → fan remap speed: 512 beams × 1024 ranges into a 1024 × 1024 image (goal ≤ 5 ms per frame).

Baselines measured in the same run: the first, uncached call (builds the remap table), a plain numpy
copy of the output's bytes (the floor for producing 1 MiB), and nearest-neighbour numpy gathering with
the same table, and OpenCV's fixed-point table form. Run: `python bench/bench_geometry.py` (prints a markdown table).
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable

import cv2
import numpy as np

from sonar_realism import geometry
from sonar_realism.frames import SonarImage, uniform_ranges
from sonar_realism.geometry import FanLayout, polar_to_fan

N_BEAMS, N_RANGES, OUT_PX = 512, 1024, 1024
REPEATS = 30


def _frame(dtype: type) -> SonarImage:
    rng = np.random.default_rng(0)
    bearings = np.arcsin(np.linspace(-math.sin(math.radians(65)), math.sin(math.radians(65)), N_BEAMS))
    intensity = rng.integers(0, 256, (N_RANGES, N_BEAMS)).astype(dtype)
    if np.dtype(dtype).kind == "f":
        intensity /= 255.0
    return SonarImage(intensity, uniform_ranges(N_RANGES, 40.0), bearings)


def _square_layout(frame: SonarImage) -> FanLayout:
    """1024 × 1024 output, apex at the bottom centre, the full 130° fan fitting the width."""
    px_per_m = (OUT_PX - 1) / (2 * frame.max_range_m * math.sin(-frame.azimuths_rad[0]))
    return FanLayout(width_px=OUT_PX, height_px=OUT_PX, apex_x_px=(OUT_PX - 1) / 2, apex_y_px=OUT_PX - 1,
                     px_per_m=px_per_m)


def _median_ms(call: Callable[[], object], repeats: int = REPEATS) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)


def run() -> list[dict]:
    rows: list[dict] = []
    for threads in (cv2.getNumThreads(), 1):
        cv2.setNumThreads(threads)
        for dtype in (np.uint8, np.float32):
            frame = _frame(dtype)
            layout = _square_layout(frame)

            def remap(frame: SonarImage = frame, layout: FanLayout = layout) -> np.ndarray:
                return polar_to_fan(frame, OUT_PX, layout)

            geometry.clear_cache()
            start = time.perf_counter()
            fan = remap()
            first_ms = (time.perf_counter() - start) * 1e3
            cached_ms = _median_ms(remap)
            copy_ms = _median_ms(lambda fan=fan: fan.copy())
            column, row = geometry._fan_maps(frame, layout)  # the cached tables themselves
            fixed_x, fixed_y = cv2.convertMaps(column, row, cv2.CV_16SC2)

            def fixed_point(image: np.ndarray = frame.intensity, fixed_x: np.ndarray = fixed_x,
                            fixed_y: np.ndarray = fixed_y) -> np.ndarray:
                return cv2.remap(image, fixed_x, fixed_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

            fixed_ms = _median_ms(fixed_point)
            inside = (column >= 0) & (row >= 0)
            rows_nearest = np.clip(np.rint(row), 0, N_RANGES - 1).astype(np.intp)
            columns_nearest = np.clip(np.rint(column), 0, N_BEAMS - 1).astype(np.intp)

            def gather(frame: SonarImage = frame, r: np.ndarray = rows_nearest, c: np.ndarray = columns_nearest,
                       inside: np.ndarray = inside) -> np.ndarray:
                return np.where(inside, frame.intensity[r, c], 0)

            gather_ms = _median_ms(gather, 10)
            for variant, ms in (("polar_to_fan, cached table", cached_ms),
                                ("polar_to_fan, first call (builds table)", first_ms),
                                ("numpy copy of the output bytes", copy_ms),
                                ("cv2.remap, fixed-point (CV_16SC2) tables", fixed_ms),
                                ("numpy nearest-neighbour gather", gather_ms)):
                rows.append({"threads": threads, "dtype": np.dtype(dtype).name, "variant": variant, "ms": ms,
                             "vs_cached": ms / cached_ms})
    return rows


def main() -> None:
    rows = run()
    print(f"polar {N_BEAMS} beams × {N_RANGES} ranges → fan {OUT_PX}×{OUT_PX}, median of {REPEATS} "
          "(first call: one sample)\n")
    print("| cv2 threads | dtype | variant | ms | × cached remap |")
    print("|---|---|---|---|---|")
    for row in rows:
        print(f"| {row['threads']} | {row['dtype']} | {row['variant']} | {row['ms']:.2f} | {row['vs_cached']:.2f} |")


if __name__ == "__main__":
    main()
