"""What the readers share: building a frame with errors that name the file, JSON for meta, and the JSON
sidecar that gives an image (a PNG/TIFF, a ROS sensor_msgs/Image) its geometry.

Sidecar lookup (docs/formats.md): `<stem>.json` beside the file, merged over a folder-wide `sonar.json`
(per-file keys win). Without geometry, DEFAULT_FOV_DEG and 1 m per row are assumed and
`meta["geometry_assumed"] = True`.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from sonar_realism.config import from_dict
from sonar_realism.errors import ConfigError, FormatError, FrameError
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges

FOLDER_SIDECAR_NAME = "sonar.json"
DEFAULT_FOV_DEG = 130.0
DEFAULT_METRES_PER_ROW = 1.0
_FAN_ONLY_KEYS = ("apex_x_px", "apex_y_px", "px_per_m", "range_up", "n_ranges", "n_beams")


def build_frame(source: str | Path, **fields: Any) -> SonarImage:
    """SonarImage(**fields), turning its FrameError into a FormatError that names the file and field."""
    try:
        return SonarImage(**fields)
    except FrameError as exc:
        field, _, message = str(exc).partition(": ")
        raise FormatError(str(source), field, message or str(exc)) from exc


def json_default(value: Any) -> Any:
    """numpy scalars and arrays in meta become plain JSON numbers and lists."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-able")


@dataclass(frozen=True)
class ImageSidecar:
    """Keys of a PNG/TIFF JSON sidecar (unknown keys are rejected). All optional; see docs/formats.md."""

    kind: Literal["polar", "fan"] | None = None
    ranges_m: tuple[float, ...] | None = None
    azimuths_rad: tuple[float, ...] | None = None
    min_range_m: float | None = None
    max_range_m: float | None = None
    fov_deg: float | None = None
    stamp_ns: int = 0
    seq: int | None = None
    frame_id: str = "sonar"
    intensity_scale: float = 0.0
    meta: dict[str, Any] | None = None
    # Cartesian fan images only: where the apex is, the scale, and the polar grid to resample onto.
    apex_x_px: float | None = None
    apex_y_px: float | None = None
    px_per_m: float | None = None
    range_up: bool | None = None
    n_ranges: int | None = None
    n_beams: int | None = None

    def validate(self) -> None:
        if self.ranges_m is not None and (self.min_range_m is not None or self.max_range_m is not None):
            raise ConfigError("ranges_m: give either ranges_m or min_range_m/max_range_m, not both")
        if self.azimuths_rad is not None and self.fov_deg is not None:
            raise ConfigError("azimuths_rad: give either azimuths_rad or fov_deg, not both")
        if self.fov_deg is not None and not 0 < self.fov_deg <= 360:
            raise ConfigError(f"fov_deg: expected (0, 360], got {self.fov_deg}")
        if self.max_range_m is not None and not self.max_range_m > (self.min_range_m or 0.0):
            raise ConfigError("max_range_m: must be greater than min_range_m (and 0)")
        if self.min_range_m is not None and self.min_range_m < 0:
            raise ConfigError("min_range_m: must be >= 0")
        if self.px_per_m is not None and not self.px_per_m > 0:
            raise ConfigError("px_per_m: must be positive")
        for name in ("n_ranges", "n_beams"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ConfigError(f"{name}: must be >= 1")
        fan_keys = [key for key in _FAN_ONLY_KEYS if getattr(self, key) is not None]
        if self.kind != "fan" and fan_keys:
            raise ConfigError(f'{fan_keys[0]}: {", ".join(fan_keys)} only apply to "kind": "fan"')


def load_sidecar(image_path: Path, overrides: dict[str, Any] | None = None) -> tuple[ImageSidecar | None, str]:
    """The sidecar of one image (its own `<stem>.json` merged over the folder's sonar.json, `overrides` over
    both) and where it came from."""
    merged: dict[str, Any] = {}
    sources = []
    for candidate in (image_path.parent / FOLDER_SIDECAR_NAME, image_path.with_suffix(".json")):
        if candidate.is_file():
            try:
                data = json.loads(candidate.read_text(encoding="utf-8"))
            except json.JSONDecodeError as exc:
                raise FormatError(str(candidate), "sidecar", f"not JSON ({exc.msg})") from exc
            if not isinstance(data, dict):
                raise FormatError(str(candidate), "sidecar", "expected a JSON object")
            merged.update(data)
            sources.append(str(candidate))
    if overrides:
        merged.update(overrides)
        sources.append("options")
    if not sources:
        return None, ""
    source = " + ".join(sources)
    try:
        return from_dict(ImageSidecar, merged, where="sidecar"), source
    except ConfigError as exc:
        message = str(exc)
        unknown = re.search(r"unknown key\(s\) ([^,;]+)", message)
        field = unknown.group(1) if unknown else message.split(":")[0].removeprefix("sidecar.")
        raise FormatError(source, field, message.removeprefix(f"sidecar.{field}: ")) from exc


def polar_frame(intensity: np.ndarray, path: Path, sidecar: ImageSidecar | None, sidecar_source: str,
                 seq: int, meta: dict[str, Any]) -> SonarImage:
    if intensity.dtype.kind == "f":
        intensity = intensity.astype(np.float32, copy=False)
        if not np.isfinite(intensity).all():
            raise FormatError(str(path), "intensity", "NaN or inf in a float image (rejected; see docs/formats.md)")
    n_ranges, n_beams = intensity.shape
    sidecar = sidecar or ImageSidecar()
    source = sidecar_source or str(path)
    assumed = []
    if sidecar.ranges_m is not None:
        ranges = np.asarray(sidecar.ranges_m)
        if ranges.shape[0] != n_ranges:
            raise FormatError(source, "ranges_m", f"{ranges.shape[0]} values for an image of {n_ranges} rows")
    elif sidecar.max_range_m is not None:
        ranges = uniform_ranges(n_ranges, sidecar.max_range_m, sidecar.min_range_m or 0.0)
    else:
        ranges = uniform_ranges(n_ranges, n_ranges * DEFAULT_METRES_PER_ROW)
        assumed.append("ranges_m")
    if sidecar.azimuths_rad is not None:
        azimuths = np.asarray(sidecar.azimuths_rad)
        if azimuths.shape[0] != n_beams:
            raise FormatError(source, "azimuths_rad", f"{azimuths.shape[0]} values for an image of {n_beams} columns")
    else:
        azimuths = uniform_azimuths(n_beams, math.radians(sidecar.fov_deg or DEFAULT_FOV_DEG))
        if sidecar.fov_deg is None:
            assumed.append("azimuths_rad")
    if assumed:
        meta = {**meta, "geometry_assumed": True, "assumed_fields": assumed}
    return build_frame(source, intensity=intensity, ranges_m=ranges, azimuths_rad=azimuths,
                       stamp_ns=sidecar.stamp_ns, seq=seq, frame_id=sidecar.frame_id,
                       intensity_scale=sidecar.intensity_scale, meta=meta)
