"""CALIB.json: what `sonar-realism calibrate` learned about one sensor in one setting, read by `simulate`.

Frozen dataclasses, versioned, validated on load, unknown keys rejected (errors name the file and the field).
Every fitted number is an `Estimate` with a bootstrap-over-frames 90 % interval; `notes` says what was
assumed rather than measured (e.g. the bearing span of a PNG export that has no bearing table).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sonar_realism.config import from_dict, to_dict
from sonar_realism.errors import ConfigError
from sonar_realism.sim.effects import EFFECTS, Effect, make_effect
from sonar_realism.sim.texture import LearnedSensorTexture, SensorTexture

# Targets a calibrated frame may show at most (a Poisson draw is capped here).
MAX_TARGETS = 12
# 2: the grain kernel per level group; 3: the patches' width across the fan; 4: crosstalk_db re each return
CALIBRATION_VERSION = 4


@dataclass(frozen=True)
class Estimate:
    """A fitted number and its bootstrap interval over frames (5th and 95th percentiles)."""

    value: float
    low: float
    high: float

    def validate(self) -> None:
        if not all(math.isfinite(v) for v in (self.value, self.low, self.high)):
            raise ConfigError(f"estimate {self}: values must be finite")
        if not self.low <= self.high:
            raise ConfigError(f"estimate {self}: low > high")


@dataclass(frozen=True)
class GridMode:
    """One range/bearing grid the sensor used, with the fraction of frames that had it."""

    n_beams: int
    n_ranges: int
    min_range_m: float
    max_range_m: float
    fov_deg: float
    weight: float

    def validate(self) -> None:
        if not (2 <= self.n_beams <= 4096 and 2 <= self.n_ranges <= 16384):
            raise ConfigError(f"grid mode: {self.n_beams} beams x {self.n_ranges} ranges out of range")
        if not 0.0 <= self.min_range_m < self.max_range_m <= 500.0:
            raise ConfigError(f"grid mode: range window {self.min_range_m}..{self.max_range_m} m invalid")
        if not (1.0 <= self.fov_deg <= 179.0 and 0.0 < self.weight <= 1.0):
            raise ConfigError(f"grid mode: fov_deg {self.fov_deg} or weight {self.weight} invalid")


@dataclass(frozen=True)
class Grid:
    """The grids seen (most frequent first; simulate draws one per frame by weight) and where they came from."""

    modes: tuple[GridMode, ...]
    bearing_source: str  # "recording" or why a default span was used
    range_source: str

    def validate(self) -> None:
        if not self.modes:
            raise ConfigError("grid.modes: at least one grid is needed")
        if abs(sum(m.weight for m in self.modes) - 1.0) > 1e-3:
            raise ConfigError("grid.modes: weights must sum to 1")


@dataclass(frozen=True)
class Mounting:
    """How the sonar sits over the seabed: height, downward tilt, their spread across frames, vertical aperture."""

    height_m: Estimate
    tilt_deg: Estimate
    heave_sd_m: Estimate
    pitch_sd_deg: Estimate
    vertical_fov_deg: float  # assumed from the sensor class (a recording does not tell it)

    def validate(self) -> None:
        if not 0.01 <= self.height_m.value <= 200.0:
            raise ConfigError(f"mounting.height_m: {self.height_m.value} outside 0.01..200 m")
        if not -10.0 <= self.tilt_deg.value <= 89.0:
            raise ConfigError(f"mounting.tilt_deg: {self.tilt_deg.value} outside -10..89 deg")
        if not 0.5 <= self.vertical_fov_deg <= 90.0:
            raise ConfigError(f"mounting.vertical_fov_deg: {self.vertical_fov_deg} outside 0.5..90")


@dataclass(frozen=True)
class SeabedTerms:
    """Seabed backscatter: patchiness of the mean level (log-amplitude contrast, correlation lengths along range
    and across the fan, the share of dark patches) and small-scale roughness."""

    patch_contrast: Estimate  # rms of log local mean amplitude
    patch_scale_m: Estimate  # correlation length of the mean level along range
    # ... and across the fan, as an angle (the Oculus recording's patches are as many beams wide at every range)
    patch_width_deg: Estimate
    dark_fraction: Estimate  # share of the seabed in dark patches
    roughness_m: Estimate

    def validate(self) -> None:
        if not 0.0 <= self.patch_contrast.value <= 3.0:
            raise ConfigError(f"seabed.patch_contrast: {self.patch_contrast.value} outside 0..3")
        if not 0.02 <= self.patch_scale_m.value <= 50.0:
            raise ConfigError(f"seabed.patch_scale_m: {self.patch_scale_m.value} outside 0.02..50 m")
        if not 0.1 <= self.patch_width_deg.value <= 90.0:
            raise ConfigError(f"seabed.patch_width_deg: {self.patch_width_deg.value} outside 0.1..90 deg")
        if not 0.0 <= self.dark_fraction.value <= 0.9:
            raise ConfigError(f"seabed.dark_fraction: {self.dark_fraction.value} outside 0..0.9")


@dataclass(frozen=True)
class TargetTerms:
    """Targets like the recording's: how many frames show one, how many such a frame shows, their size and where
    in range they sit, and what they were measured from ("shadows": a long shadow marks a target; or the
    recording's own annotations, `calibrate --targets-from`)."""

    present_fraction: Estimate
    size_m: Estimate  # diameter / edge length
    range_fraction: Estimate  # target range over the frame's maximum range
    highlight: Estimate  # target return (95th percentile) over the seabed median, in output units
    highlight_gain: float  # amplitude gain on target returns that reproduces `highlight` in simulation
    count: Estimate = Estimate(1.0, 1.0, 1.0)  # targets in a frame that shows any (mean)
    source: str = "shadows"
    # the seabed's level in a target's shadow over its level beside the shadow, in output units (0: not measured,
    # black shadows), and the share of the seabed's power the renderer leaves there to reproduce it
    shadow_level: Estimate = Estimate(0.0, 0.0, 0.0)
    shadow_floor: float = 0.0

    def validate(self) -> None:
        if not 0.0 <= self.present_fraction.value <= 1.0:
            raise ConfigError(f"targets.present_fraction: {self.present_fraction.value} outside 0..1")
        if not 0.02 <= self.size_m.value <= 20.0:
            raise ConfigError(f"targets.size_m: {self.size_m.value} outside 0.02..20 m")
        if not 1.0 <= self.count.value <= MAX_TARGETS:
            raise ConfigError(f"targets.count: {self.count.value} outside 1..{MAX_TARGETS}")
        if not 0.0 <= self.shadow_level.value <= 2.0:
            raise ConfigError(f"targets.shadow_level: {self.shadow_level.value} outside 0..2")
        if not 0.0 <= self.shadow_floor <= 1.0:
            raise ConfigError(f"targets.shadow_floor: {self.shadow_floor} outside 0..1")


@dataclass(frozen=True)
class FittedParameter:
    effect: str
    name: str
    estimate: Estimate


@dataclass(frozen=True)
class Calibration:
    version: int
    source: str
    frames: int
    grid: Grid
    mounting: Mounting
    seabed: SeabedTerms
    targets: TargetTerms
    effects: dict[str, dict[str, float]]  # every catalogue effect's parameters (defaults where not fitted)
    fitted: tuple[FittedParameter, ...]
    # Residual gain (dB) at evenly spaced knots over normalised range and over the fan, fitted last so the mean
    # brightness profiles match: what the physical terms leave unexplained, kept small and reported.
    range_gain_db: tuple[float, ...]
    bearing_gain_db: tuple[float, ...]
    distances: dict[str, float]  # fingerprint distance to the recording: uncalibrated sim, geometry only, calibrated
    export_rescaled: bool  # the recording was exported per frame as raw * 255 / raw.max(); simulate does the same
    notes: tuple[str, ...] = field(default=())
    # the recording's own speckle (sim/texture.py), drawn in place of the catalogue's speckle; None: not fitted
    texture: SensorTexture | None = None
    # `calibrate --texture learned`: a generator drawn in place of the fitted speckle (which keeps its row gain)
    learned_texture: LearnedSensorTexture | None = None

    def validate(self) -> None:
        if self.version != CALIBRATION_VERSION:
            raise ConfigError(f"version: calibration file version {self.version}, this library reads version "
                              f"{CALIBRATION_VERSION}; re-run `sonar-realism calibrate` to regenerate it")
        if self.frames < 1:
            raise ConfigError(f"frames: {self.frames}")
        self.effect_chain()  # every effect named, known and in range
        for p in self.fitted:
            if p.effect not in self.effects or p.name not in self.effects[p.effect]:
                raise ConfigError(f"fitted: {p.effect}.{p.name} is not among the effect parameters")
        if self.learned_texture is not None and self.texture is None:
            raise ConfigError("learned_texture: needs the fitted texture beside it (its row gain); got texture: null")
        for name, values in (("range_gain_db", self.range_gain_db), ("bearing_gain_db", self.bearing_gain_db)):
            if len(values) < 2 or not all(math.isfinite(v) and abs(v) <= 40.0 for v in values):
                raise ConfigError(f"{name}: need >= 2 finite knots within +-40 dB")

    def effect_chain(self) -> list[Effect]:
        missing = sorted(set(EFFECTS) - set(self.effects))
        unknown = sorted(set(self.effects) - set(EFFECTS))
        if missing or unknown:
            raise ConfigError(f"effects: missing {missing}, unknown {unknown} (catalogue: {', '.join(EFFECTS)})")
        return [make_effect(name, **dict(params)) for name, params in self.effects.items()]


def save_calibration(calibration: Calibration, path: str | Path) -> None:
    calibration.validate()
    Path(path).write_text(json.dumps(to_dict(calibration), indent=1) + "\n", encoding="utf-8")


# Calibrations shipped with the package, by name (assets/NAME_calibration.json, as scripts/train_sensor.sh writes
# them): `oculus` is the real Oculus M1200d set's fit recording (Oculus_20250805_173650), `aris` the ARIS water
# tank's 30-degree setting (scripts/train_aris.sh).
SHIPPED_CALIBRATIONS = {path.name.removesuffix("_calibration.json"): path
                        for path in (Path(__file__).resolve().parents[1] / "assets").glob("*_calibration.json")}


def load_calibration(path: str | Path) -> Calibration:
    """Read and validate CALIB.json (or a name in SHIPPED_CALIBRATIONS); ConfigError naming the file and the
    field on anything wrong."""
    path = SHIPPED_CALIBRATIONS.get(str(path), Path(path))
    try:
        data: Any = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the calibration file ({exc.strerror})") from exc
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{path}: not a JSON calibration file ({exc})") from exc
    if not isinstance(data, dict) or "version" not in data:
        raise ConfigError(f"{path}: version: missing; expected a CALIB.json written by `sonar-realism calibrate`")
    if data["version"] != CALIBRATION_VERSION:
        raise ConfigError(f"{path}: version: file has version {data['version']!r}, this library reads "
                          f"{CALIBRATION_VERSION}; re-run `sonar-realism calibrate` to regenerate it")
    try:
        return from_dict(Calibration, data, where="calibration")
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from exc
