"""The diagnosis as typed data: what `diagnose()` returns, what diagnosis.json holds (`Diagnosis.to_json()`), and
what `load_diagnosis()` reads back. Report, validation and bench read these fields, never string keys.

The DESIGN contract keys of diagnosis.json are fields here: `gap_before`, `ranked_effects` (`name`, `params`,
`gap_after`), `selected` (effect names), `gap_after_selected`, `residual`.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from sonar_realism.config import from_dict
from sonar_realism.diagnose.scene_terms import Kind, SceneStart
from sonar_realism.errors import ConfigError

Verdict = Literal["selected", "ambiguous", "residual_only", "not_enough_frames"]


@dataclass(frozen=True)
class Share:
    """One entry of a 1-D gap profile (a statistic family, an intensity level, a frequency band) and its share."""

    name: str
    gap: float
    share: float


@dataclass(frozen=True)
class HotCell:
    range_cell: int
    bearing_cell: int
    range_m: tuple[float, float]
    bearing_deg: tuple[float, float]
    gap: float
    share: float


@dataclass(frozen=True)
class HotBin:
    """A profile bin; `span` is in metres for range bins, in degrees for bearing bins."""

    bin: int
    span: tuple[float, float]
    gap: float
    share: float


@dataclass(frozen=True)
class Where:
    """Where a gap lies: the hottest cells, range and bearing bins, intensity levels and frequency bands."""

    cells: tuple[HotCell, ...]
    range_bins: tuple[HotBin, ...]
    bearing_bins: tuple[HotBin, ...]
    levels: tuple[Share, ...]
    bands_range: tuple[Share, ...]
    bands_beam: tuple[Share, ...]


@dataclass(frozen=True)
class GapMaps:
    """cells: [range_cells, bearing_cells] gap per cell; levels: [levels] gap per intensity level;
    bands_range / bands_beam: [n_bands] gap per octave band (highest frequencies first); range_bins /
    bearing_bins: gap of the mean brightness per bin of the range and bearing profiles (finer than the cells:
    a narrow band at one range shows up in one bin instead of being averaged into a cell)."""

    cells: np.ndarray
    levels: np.ndarray
    bands_range: np.ndarray
    bands_beam: np.ndarray
    range_bins: np.ndarray
    bearing_bins: np.ndarray

    def __post_init__(self) -> None:  # read back from JSON as nested lists
        for f in dataclasses.fields(self):
            object.__setattr__(self, f.name, np.asarray(getattr(self, f.name), dtype=np.float64))

    def arrays(self) -> tuple[np.ndarray, ...]:
        return tuple(getattr(self, f.name) for f in dataclasses.fields(self))


@dataclass(frozen=True)
class RankedEffect:
    """A candidate fitted alone: its parameters, its gap on the fit split and on held-out frames, and how often
    it ranked first over bootstrap resamples of the held-out frames (`top_frequency`). `kind`: "effect" (a sensor
    effect of the catalogue), "geometry" or "scene" (a term of the sim's set-up: diagnose/scene_terms)."""

    name: str
    params: dict[str, Any]
    gap_after: float
    fit_gap: float
    gap_closed: float
    top_frequency: float
    kind: Kind = "effect"


@dataclass(frozen=True)
class Alternative:
    """A candidate set judged at one selection step: `effect` added on top of the chosen ones, the held-out gap
    it gives, how often it was the best of the step's candidates over bootstrap resamples, and whether the step's
    pick was told apart from it (`separated`: the pick's gap lower by the least gain worth naming, `min_gain` of
    the gap before, at the selection's significance; always true of the pick itself)."""

    effect: str
    gap: float
    frequency: float
    separated: bool = True


@dataclass(frozen=True)
class Step:
    """One step of the selection: `action` is "start" (nothing applied), "add", "refit" (pruning refitted the
    whole set, which fitted better), "remove" (pruned), "unconfirmed" (removed, or passed over for its step's
    runner-up: the real frames lack its signature, see Unconfirmed), "gain_stand_in" (removed: a gain pattern
    does its job) or "found" (added last, by its signature alone, see Found); `gap` the held-out gap after it;
    `alternatives` the candidates an "add" step chose among."""

    action: Literal["start", "add", "refit", "remove", "unconfirmed", "gain_stand_in", "found"]
    effect: str
    gap: float
    alternatives: tuple[Alternative, ...] = ()


@dataclass(frozen=True)
class GainSpot:
    """One beam or range bin where a fitted gain pattern stands out: `at` in degrees (beams) or metres (ranges)."""

    index: int
    at: float
    gain_db: float


@dataclass(frozen=True)
class GainPatternFit:
    """A fixed gain pattern (per range and per beam, in dB, applied before any effect) fitted on top of a set of
    effects: its level and ramp over range; `range_db` / `beam_db` the whole profiles; `beams` / `ranges` the
    places where it stands out (isolated channels and the extremes of its smooth part); `gap` the held-out gap
    with it; `share_of_gap` how much of the gap before it closes on top of the effects; `band_m` (start and end,
    metres) and `band_amplitude` an added-power band at fixed ranges (None: none)."""

    level_db: float
    ramp_db: float
    range_db: tuple[float, ...]
    beam_db: tuple[float, ...]
    beams: tuple[GainSpot, ...]
    ranges: tuple[GainSpot, ...]
    gap: float
    share_of_gap: float
    band_m: tuple[float, float] | None = None
    band_amplitude: float = 0.0

    def describe(self) -> str:
        def spots(items: tuple[GainSpot, ...], unit: str) -> str:
            return ", ".join(f"{s.at:.3g} {unit} ({s.gain_db:+.1f} dB)" for s in items) or "none"

        band = (f"; added power at {self.band_m[0]:.3g}-{self.band_m[1]:.3g} m (amplitude {self.band_amplitude:.3g})"
                if self.band_m is not None else "")
        return (f"level {self.level_db:+.1f} dB, ramp {self.ramp_db:+.1f} dB over range; beams standing out: "
                f"{spots(self.beams, 'deg')}; ranges standing out: {spots(self.ranges, 'm')}{band}")


@dataclass(frozen=True)
class StandIn:
    """A selected effect dropped because a fixed gain pattern fitted in its place did at least as well, or because
    it was fitted with its own physics off (`physics_off`: those parameters at their lower bound), leaving only a
    gain (then `gain_pattern` is the pattern in its place, whatever its gap)."""

    effect: str
    params: dict[str, Any]
    gain_pattern: GainPatternFit
    gap_with_effect: float
    gap_with_gain_pattern: float
    physics_off: tuple[str, ...] = ()


@dataclass(frozen=True)
class SelectedEffect:
    """A selected effect as finally fitted: `share` of the gap before it closed when it was added, `stability`
    how often it was the best candidate of its step over bootstrap resamples of the held-out frames; `kind` as in
    RankedEffect."""

    name: str
    params: dict[str, Any]
    share: float
    stability: float
    kind: Kind = "effect"


@dataclass(frozen=True)
class AmbiguousGroup:
    """Effects that explain the same part of the gap within the noise at one selection step (`step`: index in
    the selection path): each with its share of the gap before and its selection frequency."""

    step: int
    effects: tuple[Alternative, ...]
    shares: tuple[float, ...]


@dataclass(frozen=True)
class Residual:
    """What the selected effects leave: its size, whether its 95% interval excludes 0, the families and places
    holding it (the part of the original gap still there), cells the correction made worse, and the fixed gain
    pattern that explains part of it (None when it explains nothing on held-out frames)."""

    size: float
    fraction_of_gap_before: float
    significant: bool
    families: tuple[Share, ...]
    where: Where
    worsened_cells: tuple[HotCell, ...]
    gain_pattern: GainPatternFit | None


@dataclass(frozen=True)
class Unconfirmed:
    """A selected effect dropped because the real frames lack its signature (`signature`: what was looked for and what
    was measured): a multipath whose ghost copy of each frame's scene is not there, an interference whose bright rows
    sit at the same ranges in every frame (a fixed band), sidelobes whose fitted form lifts the dark beams of bright
    rows where the real frames' are not lifted (a noise floor, a yaw smear) or leaves the bright echoes standing clear
    of the beams beside them where the real frames flatten them (a yaw smear). What it closed of the gap is a difference
    of the world, the set-up or an un-catalogued effect, not this effect. An effect that fails its check when picked
    gives way to its step's runner-up (`named_instead`; `gap_with_effect`: what it would have left; `gap_without`: what
    the runner-up leaves); between the two blurs the check is the axis of the real frames' smoothing (a motion blur
    whose smoothing runs along range alone is a range blur). Sidelobes whose fitted cross-talk pedestal fails the
    leakage check are refitted without it and compete so (`named_instead` is then the effect itself; `gap_without`: what
    the refit leaves)."""

    effect: str
    params: dict[str, Any]
    signature: str
    gap_with_effect: float
    gap_without: float
    named_instead: str = ""


@dataclass(frozen=True)
class Found:
    """An effect named by its signature alone, which the gap does not credit (`signature`: what was found): an
    interference whose lines, a few thin arcs in some pings, move the frames' mean statistics by less than the
    scenes' own differences, or a ring-down whose band at the first range bins the whole-frame statistics count
    against it where the worlds differ. Its parameters are read off the signature, not fitted to the gap;
    `gap_without` / `gap_with_effect`: the held-out gap before and after it was added (a found ring-down can
    raise it: the statistics count it against it)."""

    effect: str
    params: dict[str, Any]
    signature: str
    gap_without: float
    gap_with_effect: float


@dataclass(frozen=True)
class Auc:
    """Cross-validated classifier two-sample AUC and its standard error."""

    auc: float
    stderr: float


@dataclass(frozen=True)
class FrameCounts:
    sim: int
    real: int
    sim_fit_used: int
    sim_heldout_used: int
    real_fit_used: int
    real_heldout_used: int


@dataclass(frozen=True)
class Grid:
    n_ranges: int
    n_beams: int
    range_m: tuple[float, float]
    bearing_deg: tuple[float, float]


@dataclass(frozen=True)
class Examples:
    """One held-out frame three ways (for the report's figure; not written to diagnosis.json)."""

    sim: np.ndarray
    corrected: np.ndarray
    real: np.ndarray


@dataclass(frozen=True)
class Diagnosis:
    """The whole diagnosis. `verdict`: "selected" (confident names), "ambiguous" (at least one step could not
    tell its candidates apart: see `ambiguous`), "residual_only" (nothing selected) or "not_enough_frames" (too
    few held-out frames for the bootstrap to separate anything: no ranking). `scene_start`: where the calibration
    put the real setting, when geometry and scene terms were candidates (None: sensor effects only).
    `unconfirmed`: selected effects dropped because the real frames lack their signature (a multipath without its
    ghost); `found`: effects named by their signature alone (interference lines, a ring-down's first-bin band)."""

    verdict: Verdict
    gap_measure: str
    gap_before: float
    gap_before_ci95: tuple[float, float]
    classifier_auc_before: Auc
    family_gaps_before: dict[str, float]
    where_before: Where
    ranked_effects: tuple[RankedEffect, ...]
    selected: tuple[str, ...]
    selected_effects: tuple[SelectedEffect, ...]
    ambiguous: tuple[AmbiguousGroup, ...]
    selection_path: tuple[Step, ...]
    selection_stopped: str
    gain_stand_ins: tuple[StandIn, ...]
    gap_after_selected: float
    gap_after_selected_ci95: tuple[float, float]
    classifier_auc_after_selected: Auc
    gap_closed: float
    family_gaps_after_selected: dict[str, float]
    residual: Residual
    maps_before: GapMaps
    maps_after: GapMaps
    frames: FrameCounts
    grid: Grid
    normalize: str
    bootstrap_resamples: int
    seconds: float
    scene_start: SceneStart | None = None
    unconfirmed: tuple[Unconfirmed, ...] = ()
    found: tuple[Found, ...] = ()
    examples: Examples | None = dataclasses.field(default=None, compare=False)

    def blamed_on_setup(self) -> tuple[SelectedEffect, ...]:
        """The selected geometry and scene terms: the part of the gap that is the sim's set-up, not its sensor."""
        return tuple(s for s in self.selected_effects if s.kind != "effect")

    @property
    def top1(self) -> str:
        return self.ranked_effects[0].name if self.ranked_effects else ""

    def fitted_params(self) -> dict[str, dict[str, Any]]:
        """Each effect's fitted parameters: as selected where selected, else its solo fit."""
        out = {r.name: r.params for r in self.ranked_effects}
        out.update({s.name: s.params for s in self.selected_effects})
        return out

    def to_json(self) -> dict[str, Any]:
        """The diagnosis.json content (everything but the example frames)."""
        data = dataclasses.asdict(dataclasses.replace(self, examples=None))
        del data["examples"]
        return _jsonable(data)


def write_diagnosis(diagnosis: Diagnosis, path: str | Path) -> Path:
    path = Path(path)
    path.write_text(json.dumps(diagnosis.to_json(), indent=2) + "\n")
    return path


def load_diagnosis(path: str | Path) -> Diagnosis:
    """A diagnosis.json read back as the Diagnosis that wrote it (without the example frames)."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read a diagnosis: {exc}") from exc
    return from_dict(Diagnosis, data, where=str(path))


def _jsonable(value: Any) -> Any:
    """Plain JSON values. A non-finite gap (an effect whose frames were invalid) stays Infinity, which Python's
    json writes and reads back."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value
