"""Cartesian (scan-converted) fan images → polar SonarImage.

Many datasets ship only the display image: a sector, zero outside, apex at the bottom (e.g. the ARIS
Explorer 3000 water-tank set, 320×480 px, ~30° fov). The geometry comes from the JSON sidecar
(`"kind": "fan"`, apex_x_px, apex_y_px, px_per_m, fov_deg, min_range_m, max_range_m, n_ranges, n_beams,
range_up); what it leaves out is measured from the image: the two straight sides of the sector give the
apex and the fov, the nearest and farthest non-zero pixels the range window. The metric scale cannot be
measured from pixels: without px_per_m, DEFAULT_PX_PER_M is assumed and `meta["geometry_assumed"]` set.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sonar_realism.errors import FormatError
from sonar_realism.frames import SonarImage, uniform_ranges
from sonar_realism.geometry import FanLayout, fan_to_polar
from sonar_realism.io.common import ImageSidecar, build_frame

# 1 px = 1 cm: puts the ARIS water-tank window (≈130–570 px from the apex) at ≈1.3–5.7 m, the ARIS 3000's
# usual short-range window. Only an assumption; a sidecar with px_per_m replaces it.
DEFAULT_PX_PER_M = 100.0
_MIN_CONTENT_ROWS = 16
_MIN_FOV_RAD = math.radians(3.0)
_MAX_EDGE_RESIDUAL_PX = 2.0
_ANGLE_STEP_DEG = 0.1


@dataclass(frozen=True)
class DetectedFan:
    """A sector measured from the non-zero pixels of an image, in pixels and radians."""

    apex_x_px: float
    apex_y_px: float
    range_up: bool
    left_rad: float
    right_rad: float
    min_range_px: float
    max_range_px: float

    @property
    def fov_rad(self) -> float:
        return self.right_rad - self.left_rad


def detect_fan(image: np.ndarray) -> DetectedFan | None:
    """The sector drawn in `image` ([H, W], zero outside), or None when the image is not a fan.

    A polar frame has data in its corners and vertical sides; a fan has zero corners and two straight
    sides converging on an apex outside or at the edge of the content.
    """
    if image.ndim != 2 or min(image.shape) < _MIN_CONTENT_ROWS:
        return None
    if image[0, 0] or image[0, -1] or image[-1, 0] or image[-1, -1]:
        return None
    content = image > 0
    rows = np.flatnonzero(content.any(axis=1))
    if rows.shape[0] < _MIN_CONTENT_ROWS:
        return None
    # The sides are straight only between the arcs: fit them on the middle of the content rows.
    middle = rows[(rows >= np.percentile(rows, 20)) & (rows <= np.percentile(rows, 80))]
    middle_rows = content[middle]
    left = np.argmax(middle_rows, axis=1).astype(np.float64)
    right = (image.shape[1] - np.argmax(middle_rows[:, ::-1], axis=1)).astype(np.float64)
    left_fit = np.polyfit(middle, left, 1)
    right_fit = np.polyfit(middle, right, 1)
    residual = max(np.median(np.abs(np.polyval(left_fit, middle) - left)),
                   np.median(np.abs(np.polyval(right_fit, middle) - right)))
    converging = left_fit[0] - right_fit[0]
    if residual > _MAX_EDGE_RESIDUAL_PX or abs(converging) < 1e-3:
        return None
    apex_y = (right_fit[1] - left_fit[1]) / converging
    apex_x = float(np.polyval(left_fit, apex_y))
    range_up = apex_y > middle.mean()
    # Bearing of a side: its x change per unit of forward distance from the apex.
    direction = -1.0 if range_up else 1.0
    left_rad = math.atan(left_fit[0] * direction)
    right_rad = math.atan(right_fit[0] * direction)
    if right_rad - left_rad < _MIN_FOV_RAD:
        return None
    ys, xs = np.nonzero(content)
    distances = np.hypot(xs + 0.5 - apex_x, ys + 0.5 - apex_y)
    # Nearest and farthest content, ignoring the outermost 0.05 % (stray bright pixels off the arcs).
    outliers = int(0.0005 * distances.shape[0])
    near, far = np.partition(distances, [outliers, distances.shape[0] - 1 - outliers])[
        [outliers, distances.shape[0] - 1 - outliers]]
    # Rounded to half a pixel and a tenth of a degree, below what the edge fit resolves: frames of one recording
    # then share one geometry (and one cached remap table) instead of jittering with their content.
    step_rad = math.radians(_ANGLE_STEP_DEG)
    return DetectedFan(apex_x_px=_round_to(apex_x, 0.5), apex_y_px=_round_to(float(apex_y), 0.5),
                       range_up=bool(range_up), left_rad=_round_to(left_rad, step_rad),
                       right_rad=_round_to(right_rad, step_rad), min_range_px=_round_to(float(near), 0.5),
                       max_range_px=_round_to(float(far), 0.5))


def _round_to(value: float, step: float) -> float:
    return round(value / step) * step


def fan_layout_of(frame: SonarImage) -> FanLayout | None:
    """The Cartesian layout a frame read from a fan image came from (the meta `fan_image_to_frame` writes), or None
    for polar frames: annotations drawn on that image map onto the frame through it."""
    meta = frame.meta
    if meta.get("converted_from") != "fan":
        return None
    width, height = meta["fan_image_px"]
    apex_x, apex_y = meta["fan_apex_px"]
    return FanLayout(int(width), int(height), float(apex_x), float(apex_y), float(meta["fan_px_per_m"]),
                     bool(meta["fan_range_up"]))


def fan_image_to_frame(image: np.ndarray, path: Path, sidecar: ImageSidecar | None, sidecar_source: str,
                       seq: int, meta: dict[str, Any], detected: DetectedFan | None) -> SonarImage:
    """Polar frame of a fan image, geometry from the sidecar where given and measured (`detected`,
    from detect_fan) otherwise."""
    source = sidecar_source or str(path)
    if image.dtype.kind == "f":
        image = image.astype(np.float32, copy=False)
        if not np.isfinite(image).all():
            raise FormatError(str(path), "intensity", "NaN or inf in a float image (rejected; see docs/formats.md)")
    sidecar = sidecar or ImageSidecar(kind="fan")
    for unsupported in ("ranges_m", "azimuths_rad"):
        if getattr(sidecar, unsupported) is not None:
            raise FormatError(source, unsupported, "a fan sidecar gives min/max_range_m and fov_deg, not tables")
    measured: list[str] = []

    def pick(name: str, from_image: float | bool | None) -> Any:
        value = getattr(sidecar, name)
        if value is not None:
            return value
        if from_image is None:
            raise FormatError(source, name, f"missing, and {path.name} does not look like a fan to measure it from")
        measured.append(name)
        return from_image

    px_per_m = sidecar.px_per_m if sidecar.px_per_m is not None else DEFAULT_PX_PER_M
    apex_x = pick("apex_x_px", detected and detected.apex_x_px)
    apex_y = pick("apex_y_px", detected and detected.apex_y_px)
    if sidecar.range_up is not None:
        range_up = sidecar.range_up
    else:
        range_up = detected.range_up if detected is not None else True
    if sidecar.fov_deg is not None:
        fov, centre = math.radians(sidecar.fov_deg), 0.0
    elif detected is not None:
        fov, centre = detected.fov_rad, 0.5 * (detected.left_rad + detected.right_rad)
        measured.append("fov_deg")
    else:
        raise FormatError(source, "fov_deg", f"missing, and {path.name} does not look like a fan to measure it from")
    min_range = pick("min_range_m", detected and detected.min_range_px / px_per_m)
    max_range = pick("max_range_m", detected and detected.max_range_px / px_per_m)
    if not max_range > min_range:
        raise FormatError(source, "max_range_m", f"{max_range} is not beyond min_range_m {min_range}")
    # Default grid: about one polar cell per pixel along range and along the far arc, so nothing is lost.
    n_ranges = sidecar.n_ranges or max(2, round((max_range - min_range) * px_per_m))
    n_beams = sidecar.n_beams or max(2, round(fov * max_range * px_per_m))
    ranges = uniform_ranges(n_ranges, max_range, min_range)
    step = fov / n_beams
    azimuths = centre + (np.arange(n_beams) - (n_beams - 1) / 2.0) * step
    if np.abs(azimuths).max() >= math.pi:
        raise FormatError(source, "fov_deg", f"fan of {math.degrees(fov):.1f}° does not fit in ±180°")
    height, width = image.shape
    layout = FanLayout(width_px=width, height_px=height, apex_x_px=float(apex_x), apex_y_px=float(apex_y),
                       px_per_m=px_per_m, range_up=bool(range_up))
    intensity = fan_to_polar(image, layout, ranges, azimuths)
    meta = {**meta, "converted_from": "fan", "fan_apex_px": [float(apex_x), float(apex_y)],
            "fan_px_per_m": px_per_m, "fan_image_px": [width, height], "fan_range_up": bool(range_up)}
    if measured:
        meta["measured_from_image"] = measured
    if sidecar.px_per_m is None:
        meta["geometry_assumed"] = True
        meta["assumed_fields"] = ["px_per_m"]
    return build_frame(source, intensity=intensity, ranges_m=ranges, azimuths_rad=azimuths,
                       stamp_ns=sidecar.stamp_ns, seq=seq, frame_id=sidecar.frame_id,
                       intensity_scale=sidecar.intensity_scale, meta=meta)
