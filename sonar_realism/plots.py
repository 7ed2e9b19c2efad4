"""Small PNG plots drawn with OpenCV, so reports need no plotting dependency.

Each function writes one PNG and returns its path. They are for a person to glance at (loss curves,
histograms, maps, sample grids), not for publication.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

_PALETTE = [(180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214), (189, 103, 148),
            (75, 86, 140), (194, 119, 227), (127, 127, 127), (34, 189, 188), (207, 190, 23)]  # BGR, tab10
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_MARGIN = (70, 20, 40, 55)  # left, right, top, bottom


def _write(path: str | Path, canvas: np.ndarray) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), canvas):
        raise OSError(f"could not write {path}")
    return path


def _fmt(value: float) -> str:
    if value == 0:
        return "0"
    if abs(value) >= 1e4 or abs(value) < 1e-2:
        return f"{value:.1e}"
    return f"{value:.3g}"


def _axes(canvas: np.ndarray, x_range: tuple[float, float], y_range: tuple[float, float], title: str,
          xlabel: str, ylabel: str, logy: bool = False) -> tuple[int, int, int, int]:
    h, w = canvas.shape[:2]
    left, right, top, bottom = _MARGIN
    x0, x1, y0, y1 = left, w - right, top, h - bottom
    cv2.rectangle(canvas, (x0, y0), (x1, y1), (0, 0, 0), 1)
    for i in range(5):
        fx = i / 4
        xv = x_range[0] + fx * (x_range[1] - x_range[0])
        yv = y_range[0] + fx * (y_range[1] - y_range[0])
        px = int(x0 + fx * (x1 - x0))
        py = int(y1 - fx * (y1 - y0))
        cv2.line(canvas, (px, y1), (px, y1 + 4), (0, 0, 0), 1)
        cv2.putText(canvas, _fmt(xv), (px - 18, y1 + 18), _FONT, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.line(canvas, (x0 - 4, py), (x0, py), (0, 0, 0), 1)
        label = _fmt(10 ** yv) if logy else _fmt(yv)
        cv2.putText(canvas, label, (4, py + 4), _FONT, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(canvas, title, (x0, 25), _FONT, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(canvas, xlabel, ((x0 + x1) // 2 - 4 * len(xlabel), h - 12), _FONT, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(canvas, ylabel, (4, y0 - 8), _FONT, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    return x0, x1, y0, y1


def _span(values: np.ndarray) -> tuple[float, float]:
    lo, hi = float(np.min(values)), float(np.max(values))
    if hi <= lo:
        hi = lo + 1.0
    pad = 0.05 * (hi - lo)
    return lo - pad, hi + pad


def line_plot(series: dict[str, tuple[Sequence[float], Sequence[float]]], path: str | Path, title: str = "",
              xlabel: str = "", ylabel: str = "", size: tuple[int, int] = (720, 420), logy: bool = False) -> Path:
    """One line per named (x, y) series, with a legend. logy plots log10(y) (y must be > 0)."""
    canvas = np.full((size[1], size[0], 3), 255, np.uint8)
    data = {}
    for name, (x, y) in series.items():
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        keep = np.isfinite(x) & np.isfinite(y) & ((y > 0) if logy else True)
        if keep.any():
            data[name] = (x[keep], np.log10(y[keep]) if logy else y[keep])
    if not data:
        cv2.putText(canvas, f"{title}: no data", (20, 40), _FONT, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
        return _write(path, canvas)
    x_range = _span(np.concatenate([x for x, _ in data.values()]))
    y_range = _span(np.concatenate([y for _, y in data.values()]))
    x0, x1, y0, y1 = _axes(canvas, x_range, y_range, title, xlabel, ylabel, logy)
    for i, (name, (x, y)) in enumerate(data.items()):
        color = _PALETTE[i % len(_PALETTE)]
        px = x0 + (x - x_range[0]) / (x_range[1] - x_range[0]) * (x1 - x0)
        py = y1 - (y - y_range[0]) / (y_range[1] - y_range[0]) * (y1 - y0)
        points = np.stack([px, py], axis=1).round().astype(np.int32)
        if len(points) == 1:
            cv2.circle(canvas, tuple(points[0]), 3, color, -1)
        cv2.polylines(canvas, [points], False, color, 2, cv2.LINE_AA)
        cv2.putText(canvas, name, (x1 - 200, y0 + 18 + 16 * i), _FONT, 0.45, color, 1, cv2.LINE_AA)
    return _write(path, canvas)


def bar_plot(labels: Sequence[str], values: Sequence[float], path: str | Path, title: str = "",
             ylabel: str = "", errors: Sequence[float] | None = None, size: tuple[int, int] = (720, 420)) -> Path:
    """Vertical bars with optional error bars; labels are drawn rotated-free under each bar (kept short)."""
    canvas = np.full((size[1], size[0], 3), 255, np.uint8)
    values_arr = np.asarray(values, np.float64)
    err = np.zeros_like(values_arr) if errors is None else np.asarray(errors, np.float64)
    y_range = _span(np.concatenate([[0.0], values_arr + err, values_arr - err]))
    x0, x1, y0, y1 = _axes(canvas, (0, len(values_arr)), y_range, title, "", ylabel)
    slot = (x1 - x0) / max(len(values_arr), 1)

    def to_py(v: float) -> int:
        return int(y1 - (v - y_range[0]) / (y_range[1] - y_range[0]) * (y1 - y0))

    for i, (label, value, e) in enumerate(zip(labels, values_arr, err, strict=True)):
        color = _PALETTE[i % len(_PALETTE)]
        left = int(x0 + i * slot + 0.15 * slot)
        right = int(x0 + (i + 1) * slot - 0.15 * slot)
        cv2.rectangle(canvas, (left, to_py(value)), (right, to_py(0.0)), color, -1)
        if e > 0:
            mid = (left + right) // 2
            cv2.line(canvas, (mid, to_py(value - e)), (mid, to_py(value + e)), (0, 0, 0), 1)
        cv2.putText(canvas, str(label)[:14], (left, y1 + 32 + 12 * (i % 2)), _FONT, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
    return _write(path, canvas)


def _to_uint8(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype == np.uint8:
        return image
    image = image.astype(np.float32)
    hi = float(image.max()) if image.size else 1.0
    scale = 255.0 if hi <= 1.0 else 255.0 / hi
    return np.clip(image * scale, 0, 255).astype(np.uint8)


def image_grid(images: Sequence[np.ndarray], path: str | Path, ncols: int = 4,
               labels: Sequence[str] | None = None, cell: tuple[int, int] | None = None) -> Path:
    """Tile 2-D (grey) or HxWx3 (BGR) images into one PNG. Float images in [0, 1] are scaled to 0-255."""
    if not images:
        raise ValueError("image_grid: no images")
    cell_w, cell_h = cell or (max(im.shape[1] for im in images), max(im.shape[0] for im in images))
    label_h = 18 if labels else 0
    nrows = (len(images) + ncols - 1) // ncols
    canvas = np.full((nrows * (cell_h + label_h + 4), ncols * (cell_w + 4), 3), 255, np.uint8)
    for i, image in enumerate(images):
        tile = _to_uint8(image)
        if tile.ndim == 2:
            tile = cv2.cvtColor(tile, cv2.COLOR_GRAY2BGR)
        scale = min(cell_w / tile.shape[1], cell_h / tile.shape[0])
        tile = cv2.resize(tile, (max(1, int(tile.shape[1] * scale)), max(1, int(tile.shape[0] * scale))),
                          interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_NEAREST)
        r, c = divmod(i, ncols)
        y = r * (cell_h + label_h + 4) + label_h
        x = c * (cell_w + 4)
        canvas[y:y + tile.shape[0], x:x + tile.shape[1]] = tile
        if labels:
            cv2.putText(canvas, str(labels[i])[:40], (x + 2, y - 5), _FONT, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    return _write(path, canvas)


def heatmap(array: np.ndarray, path: str | Path, title: str = "", colormap: int = cv2.COLORMAP_VIRIDIS,
            vmin: float | None = None, vmax: float | None = None, size: tuple[int, int] | None = None) -> Path:
    """A 2-D array as a colour map with a title and its value range; rows top to bottom as in the array."""
    array = np.asarray(array, np.float64)
    lo = float(np.nanmin(array)) if vmin is None else vmin
    hi = float(np.nanmax(array)) if vmax is None else vmax
    norm = np.clip((np.nan_to_num(array, nan=lo) - lo) / (hi - lo if hi > lo else 1.0), 0, 1)
    colored = cv2.applyColorMap((norm * 255).astype(np.uint8), colormap)
    width, height = size or (max(320, array.shape[1] * max(1, 320 // max(array.shape[1], 1))),
                             max(200, array.shape[0] * max(1, 200 // max(array.shape[0], 1))))
    colored = cv2.resize(colored, (width, height), interpolation=cv2.INTER_NEAREST)
    canvas = np.full((height + 50, width + 20, 3), 255, np.uint8)
    canvas[30:30 + height, 10:10 + width] = colored
    cv2.putText(canvas, title, (10, 20), _FONT, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(canvas, f"min {_fmt(lo)}  max {_fmt(hi)}", (10, height + 45), _FONT, 0.42, (0, 0, 0), 1,
                cv2.LINE_AA)
    return _write(path, canvas)
