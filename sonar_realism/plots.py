"""Report figures drawn with matplotlib (Agg, no display): labelled axes with units, colour bars, grouped bars
with full labels, sonar frames drawn as fans in metres.

Each function writes one PNG and returns its path. Figures are built on their own `Figure` (never pyplot's
global state), so the recorder's writer thread and a report can draw at the same time.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

DPI = 100
FAN_COLORMAP = "inferno"


def _figure(size: tuple[int, int], layout: str | None = None) -> Figure:
    figure = Figure(figsize=(size[0] / DPI, size[1] / DPI), dpi=DPI, layout=layout)
    FigureCanvasAgg(figure)
    return figure


def _save(figure: Figure, path: str | Path, tight: bool = True) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if tight:
        figure.tight_layout()
    figure.savefig(path, dpi=DPI, facecolor="white")
    return path


def line_plot(series: Mapping[str, tuple[Sequence[float], Sequence[float]]], path: str | Path, title: str = "",
              xlabel: str = "", ylabel: str = "", size: tuple[int, int] = (720, 420), logy: bool = False) -> Path:
    """One line per named (x, y) series, with a legend; logy draws y on a log axis (values <= 0 are left out)."""
    figure = _figure(size)
    axes = figure.add_subplot()
    drawn = 0
    for name, (x, y) in series.items():
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        keep = np.isfinite(x) & np.isfinite(y) & ((y > 0) if logy else True)
        if keep.any():
            axes.plot(x[keep], y[keep], marker="o" if keep.sum() == 1 else None, label=name)
            drawn += 1
    if not drawn:
        axes.text(0.5, 0.5, "no data", ha="center", va="center", transform=axes.transAxes)
    if logy:
        axes.set_yscale("log")
    axes.set(title=title, xlabel=xlabel, ylabel=ylabel)
    axes.grid(alpha=0.3)
    if drawn > 1:
        axes.legend(fontsize="small")
    return _save(figure, path)


def bar_plot(labels: Sequence[str], values: Sequence[float], path: str | Path, title: str = "",
             ylabel: str = "", errors: Sequence[float] | None = None, size: tuple[int, int] = (720, 420),
             reference: tuple[str, float] | None = None) -> Path:
    """One bar per label (labels in full, turned when long), optional ± error bars, value on each bar."""
    return grouped_bar_plot(labels, {"": values}, path, title, ylabel,
                            errors={"": errors} if errors is not None else None, size=size, reference=reference)


def grouped_bar_plot(labels: Sequence[str], groups: Mapping[str, Sequence[float]], path: str | Path, title: str = "",
                     ylabel: str = "", errors: Mapping[str, Sequence[float] | None] | None = None,
                     size: tuple[int, int] = (720, 420), reference: tuple[str, float] | None = None) -> Path:
    """Bars side by side per label, one colour per group (e.g. {"before": [...], "after": [...]}), with a legend;
    `reference` = (name, value) draws a dashed line across (e.g. the gap before any correction)."""
    figure = _figure(size)
    axes = figure.add_subplot()
    positions = np.arange(len(labels), dtype=np.float64)
    width = 0.8 / max(len(groups), 1)
    for index, (name, values) in enumerate(groups.items()):
        offset = (index - (len(groups) - 1) / 2) * width
        spread = (errors or {}).get(name)
        bars = axes.bar(positions + offset, np.asarray(values, np.float64), width, label=name or None,
                        yerr=None if spread is None else np.asarray(spread, np.float64), capsize=3)
        axes.bar_label(bars, fmt="%.3g", fontsize="x-small", padding=2)
    turned = max((len(str(label)) for label in labels), default=0) > 8
    axes.set_xticks(positions, [str(label) for label in labels], rotation=30 if turned else 0,
                    ha="right" if turned else "center")
    axes.set(title=title, ylabel=ylabel)
    axes.axhline(0.0, color="black", linewidth=0.8)
    if reference is not None:
        axes.axhline(reference[1], color="grey", linestyle="--", linewidth=1.0, label=reference[0])
    axes.grid(axis="y", alpha=0.3)
    if len(groups) > 1 or reference is not None:
        axes.legend(fontsize="small")
    return _save(figure, path)


def heatmap(array: np.ndarray, path: str | Path, title: str = "", vmin: float | None = None,
            vmax: float | None = None, size: tuple[int, int] = (640, 480),
            extent: tuple[float, float, float, float] | None = None, xlabel: str = "column", ylabel: str = "row",
            colorbar_label: str = "", colormap: str = "viridis") -> Path:
    """A 2-D array as a colour map with axes and a colour bar; row 0 at the bottom. `extent` = (x_left,
    x_right, y_bottom, y_top) in the axis units (e.g. degrees and metres)."""
    figure = _figure(size)
    axes = figure.add_subplot()
    image = axes.imshow(np.asarray(array, np.float64), origin="lower", aspect="auto", cmap=colormap, vmin=vmin,
                        vmax=vmax, extent=extent, interpolation="nearest")
    figure.colorbar(image, ax=axes, label=colorbar_label)
    axes.set(title=title, xlabel=xlabel, ylabel=ylabel)
    return _save(figure, path)


def image_grid(images: Sequence[np.ndarray], path: str | Path, ncols: int = 4,
               labels: Sequence[str] | None = None, cell: tuple[int, int] | None = None) -> Path:
    """Tile 2-D (grey) or HxWx3 (RGB) images into one PNG, each pixel for pixel at `cell` size (default: the
    largest image), a label above each. Float images in [0, 1] are shown on 0-1, integers on 0-255."""
    if not images:
        raise ValueError("image_grid: no images")
    cell_w, cell_h = cell or (max(im.shape[1] for im in images), max(im.shape[0] for im in images))
    label_h, gap = (18 if labels else 0), 4
    nrows = (len(images) + ncols - 1) // ncols
    width, height = ncols * (cell_w + gap), nrows * (cell_h + label_h + gap)
    figure = _figure((width, height))
    for index, image in enumerate(images):
        row, col = divmod(index, ncols)
        left = col * (cell_w + gap) / width
        bottom = 1.0 - ((row + 1) * (cell_h + label_h + gap) - gap) / height
        axes = figure.add_axes((left, bottom, cell_w / width, cell_h / height))
        image = np.asarray(image)
        scale = 1.0 if image.dtype.kind == "f" and (image.size == 0 or float(image.max()) <= 1.0) else \
            (255.0 if image.dtype == np.uint8 else float(image.max()) or 1.0)
        axes.imshow(image, cmap="gray", vmin=0.0, vmax=scale, interpolation="antialiased")
        axes.set_axis_off()
        if labels:
            axes.set_title(str(labels[index]), fontsize=8, loc="left", pad=2)
    return _save(figure, path, tight=False)


def fan_axes(axes: object, intensity: np.ndarray, ranges_m: np.ndarray, azimuths_rad: np.ndarray,
             title: str = "", vmax: float | None = None) -> object:
    """Draw one polar frame as a fan on `axes` (x across, y forward, metres); returns the mesh for a colour bar."""
    ranges_m, azimuths_rad = np.asarray(ranges_m, np.float64), np.asarray(azimuths_rad, np.float64)
    r_edges, a_edges = _edges(ranges_m), _edges(azimuths_rad)
    radius, angle = np.meshgrid(r_edges, a_edges, indexing="ij")
    mesh = axes.pcolormesh(radius * np.sin(angle), radius * np.cos(angle), np.asarray(intensity, np.float64),
                           cmap=FAN_COLORMAP, vmin=0.0, vmax=vmax, shading="flat", rasterized=True)
    axes.set_aspect("equal")
    axes.set_title(title, fontsize=9)
    axes.set_xlabel("across (m)", fontsize=8)
    axes.set_ylabel("forward (m)", fontsize=8)
    axes.tick_params(labelsize=7)
    return mesh


def fan_grid(fans: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], path: str | Path, ncols: int = 4,
             labels: Sequence[str] | None = None, tile_px: int = 260, colorbar_label: str = "intensity") -> Path:
    """Frames as fans, `ncols` per row: each item is (intensity [ranges, beams], ranges_m, azimuths_rad). One
    colour scale for all (0 to the largest value) and one colour bar."""
    if not fans:
        raise ValueError("fan_grid: no frames")
    nrows = (len(fans) + ncols - 1) // ncols
    _, ranges_m, azimuths_rad = fans[0]
    half_width = float(np.max(ranges_m) * np.max(np.abs(np.sin(azimuths_rad))))
    aspect = float(np.max(ranges_m) - np.min(ranges_m) * np.cos(np.max(np.abs(azimuths_rad)))) / max(2 * half_width,
                                                                                                   1e-9)
    figure = _figure((ncols * tile_px + 100, int(nrows * (tile_px * min(max(aspect, 0.3), 2.0) + 60))),
                     layout="constrained")
    vmax = max(float(np.max(intensity)) for intensity, _, _ in fans) or 1.0
    mesh = None
    for index, (intensity, ranges_m, azimuths_rad) in enumerate(fans):
        axes = figure.add_subplot(nrows, ncols, index + 1)
        mesh = fan_axes(axes, intensity, ranges_m, azimuths_rad, labels[index] if labels else "", vmax)
    figure.colorbar(mesh, ax=figure.axes, label=colorbar_label, shrink=0.9)
    return _save(figure, path, tight=False)


def _edges(centres: np.ndarray) -> np.ndarray:
    """Cell edges around centres (half a step beyond the first and last); a single centre gets ±0.5."""
    if centres.size == 1:
        return np.array([centres[0] - 0.5, centres[0] + 0.5])
    middle = 0.5 * (centres[1:] + centres[:-1])
    return np.concatenate([[2 * centres[0] - middle[0]], middle, [2 * centres[-1] - middle[-1]]])
