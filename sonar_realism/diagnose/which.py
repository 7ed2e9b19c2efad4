"""Which catalogued effect explains the gap: fit each effect's parameters on one split, measure on another.

Fitting is a coordinate search over the effect's `PARAM_BOUNDS` (a coarse grid per parameter, then a finer grid
around the best value), minimising the headline gap between the corrected fit-split sim frames and the fit-split
real frames. The same random draws are used for every candidate parameter value (common random numbers), so the
objective is smooth in the parameters and a handful of frames suffice. Ranking and selection are judged on the
held-out split only, and every choice is repeated over bootstrap resamples of the held-out frames: how often each
candidate wins is its stability, and a step whose runner-up wins often is reported as ambiguous.

After forward selection, each selected effect is tried out again (backward pruning): one that the effects chosen
after it make redundant (motion blur standing in for beam sidelobes until they are selected) is dropped. A
selected multipath must then show its ghost in the real frames (diagnose/ghost.py), and a selected interference
arcs that move (diagnose/arcs.py: not a fixed band), or it is dropped as unconfirmed. Effects are also held to
their signature while they are picked: a pick whose signature the real frames lack gives way to the runner-up of
its step when that passes the step's tests by itself. Fitted at their strongest, sidelobes stand in for a noise
floor or a yaw smear (their signatures: the dark beams of bright rows lifted, diagnose/leakage.py, where sidelobes
whose cross-talk pedestal the real frames lack are first refitted without it; bright echoes that stand clear of the
beams a few away, diagnose/peaks.py, where a rival that flattens them as the real frames show is named), and a multipath
whose ghosts interfere with the direct return stands in for speckle (its signature: the ghost). Between a range blur
and a motion blur, the axis of the real frames' smoothing decides (diagnose/smear.py). Last,
each selected effect must beat a fixed gain pattern (`GainPattern`: a gain per range and per beam): an effect
whose fitted form does no more than such a pattern (a TVG ramp standing in for a beam-gain ripple the catalogue
lacks) is not blamed, and its part of the gap stays residual, with the pattern's place. After all that, an
interference the gap cannot see is looked for by its signature alone: lines that move, in significantly more real
frames than corrected sim frames (diagnose/arcs.py `find_lines`); one found is named with the parameters the lines
measure. So is a ring-down: a band from the first range bin (diagnose/near_field.py).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar, TypeVar

import cv2
import numpy as np

from sonar_realism.diagnose.arcs import ArcCheck, check_arcs, find_lines, interference_from_lines
from sonar_realism.diagnose.config import DiagnoseConfig, SearchConfig
from sonar_realism.diagnose.gap import FeatureScale, Stats, best_frequency, bootstrap_gain, gap, gap_closed
from sonar_realism.diagnose.ghost import (
    GhostCheck,
    check_ghost,
    ghost_lag_bins,
    ghost_lag_peak,
    range_lag_correlation,
)
from sonar_realism.diagnose.leakage import LeakageCheck, check_leakage
from sonar_realism.diagnose.near_field import find_ring_down, ring_down_from_excess
from sonar_realism.diagnose.peaks import PeakCheck, check_peaks
from sonar_realism.diagnose.result import (
    Alternative,
    Found,
    GainPatternFit,
    GainSpot,
    RankedEffect,
    StandIn,
    Step,
    Unconfirmed,
)
from sonar_realism.diagnose.scene_terms import SceneTerm, apply_scene_terms, kind_of
from sonar_realism.diagnose.smear import BLURS, SmearCheck, check_smear
from sonar_realism.errors import FrameError
from sonar_realism.evaluate.statistics import StatisticsConfig, feature_names, frame_statistics
from sonar_realism.frames import SonarImage
from sonar_realism.parallel import parallel_map
from sonar_realism.sim.effects import (
    BeamSidelobes,
    Effect,
    Interference,
    MotionBlur,
    Multipath,
    RingDown,
    apply_effects,
    make_effect,
)

# A gain pattern's smooth part has this many degrees of freedom per axis; channels that stand out from it by more
# than SPIKE_SIGMA robust deviations (and SPIKE_MIN_DB) keep their own gain: a stripe is one beam wide.
GAIN_KNOTS = 16
SPIKE_SIGMA = 4.0
SPIKE_MIN_DB = 1.0
GAIN_LIMIT_DB = 20.0
SPOT_MIN_DB = 1.0
MEASURED_WEIGHT = 0.3  # of the strongest row's or beam's weight (sqrt of mean signal): about 10% of its signal
MAX_SPOTS = 8
# A ghost nearer than this many range bins is the grain's own correlation, not a copy of the scene.
GHOST_MIN_LAG = 4
# Nearer than this many beams, the excess correlation across the beams is the sidelobes' and the grain's.
COPY_MIN_LAG_BEAMS = 3
# An added-power band (a reflection inside the housing: the same delay every ping) is looked for beyond this share
# of the range span: nearer in, a fixed band is the transducer's ring-down, which the catalogue has.
BAND_MIN_START = 0.1
# The band stands out from a running median of the rows' excess over this share of the rows (wider than any band).
BAND_CONTEXT = 0.125


@dataclass(frozen=True)
class GainPattern:
    """A fixed gain (dB) per range row and per beam, applied to the sim frames before any effect: not a sensor
    effect but the yardstick every selected effect must beat, and the form un-catalogued gain errors are reported
    in. An overall level and a linear ramp over range (searched on the statistics, as an effect's parameters are),
    plus a shape per range and per beam (estimated from mean images: see fit_gain_pattern), and a band of added
    power at fixed ranges (rows `band_rows`, amplitude `band_amplitude` in every beam): what is fixed in the frame
    whatever the scene, where every catalogued effect but the ring-down moves with the scene or the ping."""

    level_db: float = 0.0
    ramp_db: float = 0.0
    range_shape_db: np.ndarray | None = None
    beam_shape_db: np.ndarray | None = None
    band_rows: tuple[int, int] | None = None
    band_amplitude: float = 0.0
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"level_db": (-12.0, 12.0), "ramp_db": (-12.0, 12.0)}
    # A gain is one smooth dimension each: a finer search than the effects get is cheap and keeps the yardstick
    # from losing to an effect only because its grid missed a fraction of a dB.
    SEARCH_ROUNDS: ClassVar[int] = 6

    def params(self) -> dict[str, float]:
        return {"level_db": self.level_db, "ramp_db": self.ramp_db}

    def profiles(self, n_ranges: int, n_beams: int) -> tuple[np.ndarray, np.ndarray]:
        """Gain in dB per range row and per beam."""
        range_db = self.level_db + self.ramp_db * np.linspace(0.0, 1.0, n_ranges)
        if self.range_shape_db is not None:
            range_db = range_db + self.range_shape_db
        beam_db = self.beam_shape_db if self.beam_shape_db is not None else np.zeros(n_beams)
        return range_db, beam_db

    def factor(self, n_ranges: int, n_beams: int) -> np.ndarray:
        range_db, beam_db = self.profiles(n_ranges, n_beams)
        return (10 ** ((range_db[:, None] + beam_db[None, :]) / 20)).astype(np.float32)

    @property
    def shaped(self) -> bool:
        """Whether it has a range or beam shape (dozens of numbers). A band alone is not: like an effect, it is a
        hypothesis of a few numbers (a place, a width, an amplitude) about one thing in the frame."""
        return self.range_shape_db is not None

    def apply(self, image: np.ndarray, factor: np.ndarray) -> np.ndarray:
        """`image` (amplitude) times the gain `factor` (self.factor, computed once per frame set), plus the band."""
        out = image * factor
        if self.band_rows is not None and self.band_amplitude > 0:
            start, stop = self.band_rows
            out[start:stop] = np.sqrt(out[start:stop] ** 2 + np.float32(self.band_amplitude) ** 2)
        return out


@dataclass(frozen=True)
class Fit:
    effect: Effect
    fit_gap: float
    evaluations: int


def corrected_images(frames: Sequence[SonarImage], effects: Sequence[Effect], seed: int,
                     normalize: str = "none", gain: GainPattern | None = None) -> np.ndarray:
    """Apply `gain`, the geometry and scene terms among `effects`, then its sensor effects to every frame (one
    generator seeded with `seed`) and stack as float32 [n, R, B] in [0, 1]."""
    rng = np.random.default_rng(seed)
    factor = gain.factor(frames[0].n_ranges, frames[0].n_beams) if gain is not None and frames else None
    terms = [e for e in effects if isinstance(e, SceneTerm)]
    sensor = [e for e in effects if not isinstance(e, SceneTerm)]
    out = []
    for frame in frames:
        if factor is not None:
            frame = frame.replace(intensity=gain.apply(frame.normalized(), factor), intensity_scale=1.0)
        if terms:
            frame = apply_scene_terms(frame, terms, rng)
        corrected = apply_effects(frame, sensor, rng) if sensor else frame
        out.append(normalize_image(corrected.normalized(), normalize))
    return np.stack(out)


def normalize_image(image: np.ndarray, how: str) -> np.ndarray:
    """"max" divides a frame by its maximum (as the real Oculus set was exported), "none" leaves it."""
    if how == "max":
        peak = float(image.max())
        return image / peak if peak > 0 else image
    return image


def fit_effect(name: str, frames: Sequence[SonarImage], target: Stats, scale: FeatureScale,
               base: Sequence[Effect] = (), start: Effect | None = None, search: SearchConfig | None = None,
               statistics: StatisticsConfig | None = None, normalize: str = "none",
               alternatives: Sequence[Effect] = (), fixed: Sequence[str] = ()) -> Fit:
    """Parameters of effect `name` that, applied to `frames` after/with the `base` effects, bring their
    statistics closest to `target`. The search starts from `start` (default: the catalogue's values; a geometry
    or scene term always comes with its start) or from whichever of `alternatives` fits better there; the
    `fixed` parameters keep their values in `start`."""
    statistics = statistics or StatisticsConfig()
    search = search or SearchConfig()

    def objective(effect: Effect) -> float:
        return gap(frame_statistics(corrected_images(frames, [*base, effect], search.seed, normalize), statistics),
                   target, scale)

    start = start if start is not None else make_effect(name)
    bounds = {k: v for k, v in type(start).PARAM_BOUNDS.items() if k not in fixed}
    best, score, evaluations = coordinate_search(start, bounds, objective, search, alternatives)
    return Fit(best, score, evaluations)


T = TypeVar("T")


def coordinate_search(start: T, bounds: dict[str, tuple[float, float]], objective: Callable[[T], float],
                      search: SearchConfig, alternatives: Sequence[T] = ()) -> tuple[T, float, int]:
    """Minimise `objective` over the `bounds` fields of the frozen dataclass `start`: a coarse grid per parameter
    (`search.points`, log-spaced for parameters spanning decades), then finer rounds of half a step either side
    of the best; from `start` or whichever of `alternatives` scores better. Returns the best, its score and the
    number of evaluations. Values for which the objective raises FrameError (invalid frames) are no candidates.
    Only the searched fields key the cache: the others must be the same in `start` and `alternatives`."""

    def clipped(value: T) -> T:
        return dataclasses.replace(value, **{k: float(np.clip(getattr(value, k), *bounds[k])) for k in bounds})

    evaluations = 0
    cache: dict[tuple, float] = {}

    def score(value: T) -> float:
        nonlocal evaluations
        key = tuple(float(f"{getattr(value, k):.9g}") for k in bounds)
        if key not in cache:
            try:
                cache[key] = objective(value)
            except FrameError:
                cache[key] = math.inf
            evaluations += 1
        return cache[key]

    current = clipped(start)
    best = score(current)
    for other in alternatives:
        other = clipped(other)
        other_score = score(other)
        if other_score < best:
            best, current = other_score, other
    for round_index in range(search.first_round, search.rounds):
        for param, (low, high) in bounds.items():
            log_scale = low > 0 and high / low >= 20  # parameters spanning decades are searched on a log grid
            to_grid, from_grid = (np.log, np.exp) if log_scale else (float, float)
            lo, hi = to_grid(low), to_grid(high)
            if round_index == 0:
                grid = np.linspace(lo, hi, search.points)
            else:  # half a coarse step either side of the best, halving each further round (centre is cached)
                step = (hi - lo) / (search.points - 1) / 2 ** round_index
                centre = to_grid(getattr(current, param))
                grid = np.array([max(lo, centre - step), centre, min(hi, centre + step)])
            for candidate in grid:
                trial = dataclasses.replace(current, **{param: float(np.clip(from_grid(candidate), low, high))})
                trial_score = score(trial)
                if trial_score < best:
                    best, current = trial_score, trial
    return current, best, evaluations


def fit_gain_pattern(problem: SelectionProblem, base: Sequence[Effect], config: DiagnoseConfig) -> GainPattern:
    """The fixed gain pattern that, applied before `base`, brings the fit frames closest to the real ones.

    The level and the ramp over range are searched on the statistics, as an effect's parameters are. The shape
    per range and per beam is then estimated directly from mean images: ratios of row sums (real over corrected
    sim) give the range shape, then ratios of column sums the beam shape, each a smooth curve (GAIN_KNOTS degrees
    of freedom) plus isolated channels that stand out from it. Sim and real frames show different scenes, whose
    brightness also differs by range and bearing; only a *fixed* pattern is wanted, so the shape is estimated on
    two halves of the frames (sim and real) separately and only what both agree on (same sign, the smaller size)
    is kept: a scene's bright rock is in one half, a channel's gain error in both. Last, a parsimony test: the
    shape is kept only if it lowers the fit-split gap below that of the level and ramp alone."""
    search = dataclasses.replace(config.search, rounds=max(config.search.rounds, GainPattern.SEARCH_ROUNDS))
    frames = problem.fit_frames

    def fit_gap(pattern: GainPattern) -> float:
        images = corrected_images(frames, base, search.seed, config.normalize, gain=pattern)
        return gap(frame_statistics(images, config.statistics), problem.fit_target, problem.scale)

    line, line_gap, _ = coordinate_search(GainPattern(), GainPattern.PARAM_BOUNDS, fit_gap, search)
    line, line_gap = _with_band(line, line_gap, fit_gap, problem, base, config, search)
    images = corrected_images(frames, base, search.seed, config.normalize, gain=line)
    sim_halves = (images[0::2].mean(axis=0), images[1::2].mean(axis=0) if len(images) > 1 else images[0])
    rows = [(r.sum(axis=1), s.sum(axis=1)) for r, s in zip(problem.fit_real_halves, sim_halves, strict=True)]
    range_shape = _fixed_shape([_ratio_db(*pair) for pair in rows], _weight(rows), detrend=True)
    shift = (10 ** (range_shape / 20))[:, None]
    columns = [(r.sum(axis=0), (s * shift).sum(axis=0))
               for r, s in zip(problem.fit_real_halves, sim_halves, strict=True)]
    beam_shape = _fixed_shape([_ratio_db(*pair) for pair in columns], _weight(columns), detrend=False)
    shaped = dataclasses.replace(line, range_shape_db=range_shape, beam_shape_db=beam_shape)
    try:
        return shaped if fit_gap(shaped) < line_gap else line
    except FrameError:
        return line


def _with_band(line: GainPattern, line_gap: float, fit_gap: Callable[[GainPattern], float],
               problem: SelectionProblem, base: Sequence[Effect], config: DiagnoseConfig,
               search: SearchConfig) -> tuple[GainPattern, float]:
    """`line` with an added-power band where both halves of the real fit frames are brighter than the corrected
    sim by more than their neighbourhood (a narrow excess at fixed rows; a scene's bright patch is in one half
    only), beyond the ring-down's reach; its amplitude searched on the statistics from 0. Kept only if it lowers
    the fit-split gap (parsimony), with its gap; else `line` and `line_gap`."""
    images = corrected_images(problem.fit_frames, base, search.seed, config.normalize, gain=line)
    sim_halves = (images[0::2].mean(axis=0), images[1::2].mean(axis=0) if len(images) > 1 else images[0])
    excess = [real.mean(axis=1) - sim.mean(axis=1) for real, sim in zip(problem.fit_real_halves, sim_halves,
                                                                         strict=True)]
    agreed = np.maximum(_agree(*excess), 0.0)
    n = len(agreed)
    context = max(3, int(BAND_CONTEXT * n) | 1)
    padded = np.pad(agreed, context // 2, mode="edge")
    standout = agreed - np.array([np.median(padded[i:i + context]) for i in range(n)])
    first = int(math.ceil(BAND_MIN_START * n))
    peak = first + int(np.argmax(standout[first:]))
    if standout[peak] <= 0.0:
        return line, line_gap
    above = standout >= 0.5 * standout[peak]
    start, stop = peak, peak + 1
    while start > first and above[start - 1]:
        start -= 1
    while stop < n and above[stop]:
        stop += 1
    # the band adds power a^2 to rows whose mean amplitude it raises by at most a: a is above the excess
    ceiling = float(min(1.0, 3.0 * standout[peak] + 1e-3))
    banded, band_gap, _ = coordinate_search(dataclasses.replace(line, band_rows=(start, stop)),
                                            {"band_amplitude": (0.0, ceiling)}, fit_gap, search)
    return (banded, band_gap) if banded.band_amplitude > 0 and band_gap < line_gap else (line, line_gap)


def _ratio_db(real: np.ndarray, sim: np.ndarray) -> np.ndarray:
    floor = 1e-6 * max(float(real.max()), float(sim.max()), 1e-12)
    ratio = np.where((real > floor) & (sim > floor), np.maximum(real, floor) / np.maximum(sim, floor), 1.0)
    return np.clip(20 * np.log10(ratio), -GAIN_LIMIT_DB, GAIN_LIMIT_DB)


def _weight(sums: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Weights of a profile's samples: rows or columns with more signal say more about the gain (the empty water
    column says nothing)."""
    total = np.sum([real + sim for real, sim in sums], axis=0)
    return np.sqrt(np.maximum(total, 0.0) / max(float(total.max()), 1e-12))


def _fixed_shape(halves: Sequence[np.ndarray], weight: np.ndarray, detrend: bool) -> np.ndarray:
    """A gain shape (dB) from its estimates on two halves of the frames: the smooth shape and isolated channels on
    which both halves agree, about the weighted median (and, with `detrend`, without the weighted linear trend,
    which the searched level and ramp already carry)."""
    x = np.linspace(-1.0, 1.0, len(halves[0]))
    centred = []
    for half in halves:
        trend = (np.polyval(np.polyfit(x, half, 1, w=weight + 1e-6), x) if detrend
                 else np.full_like(half, np.median(half[weight > 0.1 * weight.max()])))
        centred.append(half - trend)
    smooth = [_running_smooth(c) for c in centred]
    channels = [_isolated(c - sm) for c, sm in zip(centred, smooth, strict=True)]
    # a row or beam with almost no signal in either set (the empty water column) measures no gain of its own
    measured = weight >= MEASURED_WEIGHT * weight.max()
    return _agree(*smooth) + _agree(*channels) * measured


def _agree(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.where(a * b > 0, np.sign(a) * np.minimum(np.abs(a), np.abs(b)), 0.0)


def _width(n: int) -> int:
    return max(3, (n // GAIN_KNOTS) | 1)


def _running_smooth(profile: np.ndarray) -> np.ndarray:
    """A running median then a box over len / GAIN_KNOTS samples: the shape without isolated channels."""
    width = _width(len(profile))
    padded = np.pad(profile, width // 2, mode="edge")
    median = np.array([np.median(padded[i:i + width]) for i in range(len(profile))], dtype=np.float32)
    return cv2.blur(median.reshape(-1, 1), (1, width), borderType=cv2.BORDER_REPLICATE).ravel().astype(np.float64)


def _isolated(deviation: np.ndarray) -> np.ndarray:
    """The samples that stand out by more than SPIKE_SIGMA robust deviations (and SPIKE_MIN_DB); 0 elsewhere."""
    spread = 1.4826 * float(np.median(np.abs(deviation - np.median(deviation))))
    return np.where(np.abs(deviation) > max(SPIKE_SIGMA * spread, SPIKE_MIN_DB), deviation, 0.0)


def describe_pattern(pattern: GainPattern, ranges_m: np.ndarray, bearings_deg: np.ndarray, gap_with: float,
                     share: float) -> GainPatternFit:
    range_db, beam_db = pattern.profiles(len(ranges_m), len(bearings_deg))
    band_m = None
    if pattern.band_rows is not None:
        start, stop = pattern.band_rows
        band_m = (float(ranges_m[start]), float(ranges_m[stop - 1]))
    return GainPatternFit(level_db=pattern.level_db, ramp_db=pattern.ramp_db,
                          range_db=tuple(float(v) for v in range_db), beam_db=tuple(float(v) for v in beam_db),
                          beams=_spots(beam_db, bearings_deg), ranges=_spots(range_db - np.median(range_db), ranges_m),
                          gap=gap_with, share_of_gap=share, band_m=band_m, band_amplitude=pattern.band_amplitude)


def _spots(profile_db: np.ndarray, axis: np.ndarray) -> tuple[GainSpot, ...]:
    """Where a profile stands out: isolated channels first (strongest first), then the smooth part's extremes."""
    centred = profile_db - np.median(profile_db)
    channels = centred - _running_smooth(centred)
    isolated = [int(i) for i in np.argsort(-np.abs(channels)) if abs(channels[i]) > SPIKE_MIN_DB][:MAX_SPOTS]
    width = _width(len(centred))
    extremes = [int(i) for i in (np.argmax(centred), np.argmin(centred))
                if abs(centred[i]) >= SPOT_MIN_DB and all(abs(int(i) - j) > width for j in isolated)]
    return tuple(GainSpot(i, float(axis[i]), float(centred[i])) for i in [*isolated, *dict.fromkeys(extremes)])


QUANTIZED = feature_names()["intensity"].index("quantized_fraction")


def carries_counts(stats: Stats | None) -> bool:
    """Whether the frames behind `stats` lie on 8-bit steps (nearly every pixel): the mark of an 8-bit export,
    which an output mapping that quantizes gives and a gain pattern does not."""
    return stats is not None and float(np.mean(stats["intensity"][:, QUANTIZED])) >= 0.99


def physics_off(effect: Effect) -> tuple[str, ...]:
    """The effect's own-physics parameters (`Effect.OWN_PHYSICS`) if all of them sit at their lower bound (within
    1 % of the bound's width: the search's grid includes the bound), else (): with them off it is only a gain."""
    names = effect.OWN_PHYSICS
    bounds = effect.PARAM_BOUNDS
    off = all(getattr(effect, k) <= bounds[k][0] + 0.01 * (bounds[k][1] - bounds[k][0]) for k in names)
    return tuple(names) if names and off else ()


@dataclass(frozen=True)
class CountedFrames:
    """The frames the signature finds count on (`find_by_signature`): the real frames of both splits (`real`, their
    range axes `real_ranges_m`) and `sim` (effects -> as many sim frames of both splits, corrected by them). Nothing
    is fitted to a count, so the fit split's frames are as good as the held-out ones, and a line in one ping of eight
    is significant in 40 frames where it is not in the held-out 20."""

    real: np.ndarray
    sim: Callable[[Sequence[Effect]], np.ndarray]
    real_ranges_m: np.ndarray | None = None
    sim_ranges_m: np.ndarray | None = None


@dataclass(frozen=True)
class SelectionProblem:
    """The data a selection works on: the sim frames and real statistics of the fit split (`fit_real_halves`:
    the mean images of two halves of the real fit frames, for the gain pattern), the held-out judge
    `holdout(effects, gain)` -> (gap, statistics or None), the held-out real statistics `target` and the raw sim's
    `stats_before` (None: no significance test, no bootstrap frequencies), and the gap before. `ranges_m` /
    `bearings_deg` place a gain pattern. `scene_terms`: the geometry and scene candidates' starting points (empty:
    sensor effects only). `real_images` (the real held-out frames) and `sim_images` (effects -> the held-out sim
    frames corrected by them) test a selected effect for its signature (`signature_check`; None: no test);
    `real_ranges_m` / `sim_ranges_m` [n, n_ranges]: those frames' own range axes, where a sensor's range window
    changes from ping to ping (None: all on `ranges_m`). `counted`: the frames of both splits the signature finds
    count on (None: the held-out ones)."""

    fit_frames: Sequence[SonarImage]
    fit_target: Stats
    fit_real_halves: tuple[np.ndarray, np.ndarray]
    scale: FeatureScale
    holdout: Callable[[Sequence[Effect], GainPattern | None], tuple[float, Stats | None]]
    target: Stats | None
    stats_before: Stats | None
    gap_before: float
    ranges_m: np.ndarray
    bearings_deg: np.ndarray
    scene_terms: Mapping[str, SceneTerm] = dataclasses.field(default_factory=dict)
    real_images: np.ndarray | None = None
    sim_images: Callable[[Sequence[Effect]], np.ndarray] | None = None
    real_ranges_m: np.ndarray | None = None
    sim_ranges_m: np.ndarray | None = None
    signature_starts: Mapping[str, Effect] = dataclasses.field(default_factory=dict)
    counted: CountedFrames | None = None

    def start(self, name: str) -> Effect:
        """Where a candidate's search starts: a geometry or scene term's start, else the catalogue's default."""
        return self.scene_terms[name] if name in self.scene_terms else make_effect(name)

    def other_starts(self, name: str) -> list[Effect]:
        """Starts the search also tries (the solo fit searches from each in full, a refit scores them at the start):
        one the fit split's own signature of the effect locates (`signature_starts`: a multipath at the ghost's
        lag, a motion blur of two looks at a copy across the beams)."""
        return [self.signature_starts[name]] if name in self.signature_starts else []


def signature_starts(real_fit: np.ndarray, sim_fit: np.ndarray, ranges_m: np.ndarray, bearings_deg: np.ndarray
                     ) -> dict[str, Effect]:
    """Starts located by an effect's signature on the fit split (real fit frames against the raw sim fit
    frames): a multipath whose ghost offset is the lag where the real frames' per-frame content correlates most
    beyond the sim's, within the effect's offset bounds; a motion blur of two looks as far apart as the lag across
    the beams where it does so (a double image: two pings averaged while the sonar turned)."""
    low, high = (ghost_lag_bins(m, ranges_m) for m in Multipath.PARAM_BOUNDS["ghost_offset_m"])
    lag = ghost_lag_peak(range_lag_correlation(real_fit), range_lag_correlation(sim_fit),
                         max(GHOST_MIN_LAG, math.ceil(low)), int(high))
    offset_m = lag / ghost_lag_bins(1.0, ranges_m)
    starts: dict[str, Effect] = {
        Multipath.name: dataclasses.replace(make_effect(Multipath.name), ghost_offset_m=offset_m)}
    double = _two_looks_at_copy(real_fit, sim_fit, bearings_deg)
    if double is not None:
        starts[MotionBlur.name] = double
    return starts


def _two_looks_at_copy(real_fit: np.ndarray, sim_fit: np.ndarray, bearings_deg: np.ndarray) -> MotionBlur | None:
    """The catalogue's motion blur as two looks whose turn between them is the across-beam lag where the real
    frames' per-frame content correlates most beyond the sim's: the coarse grid over yaw rate x window meets a
    copy 8 beams out (of 128) only by chance, and a continuous smear of that width fits a double image worse than
    sidelobes do (the third tuning group's `two_look_average`). None unless the excess peaks there as a ghost's
    does along range (`check_ghost`): a smear's excess is broad, and a start of two looks led its search to a worse
    optimum than the default's (tuning set 2, a Gaussian smear on the calibrated scene)."""
    start = make_effect(MotionBlur.name)
    beam_step = abs(float(bearings_deg[-1] - bearings_deg[0])) / max(1, bearings_deg.size - 1)
    yaw_high = MotionBlur.PARAM_BOUNDS["yaw_rate_deg_s"][1]
    window_high = MotionBlur.PARAM_BOUNDS["integration_s"][1]
    across = (np.swapaxes(real_fit, 1, 2), np.swapaxes(sim_fit, 1, 2))
    real_curve, sim_curve = (range_lag_correlation(images) for images in across)
    lag = ghost_lag_peak(real_curve, sim_curve, COPY_MIN_LAG_BEAMS, int(yaw_high * window_high / beam_step))
    if not check_ghost(real_curve, sim_curve, lag).confirmed:
        return None
    turn_deg = lag * beam_step
    window = min(window_high, turn_deg / abs(start.yaw_rate_deg_s))
    return dataclasses.replace(start, yaw_rate_deg_s=math.copysign(turn_deg / window, start.yaw_rate_deg_s),
                               integration_s=window, looks=2.0)


@dataclass(frozen=True)
class Selection:
    """`effects`: the selected effects as finally fitted; `path`: every step taken; `stopped`: why the forward
    selection ended; `stand_ins`: effects dropped because a gain pattern explained as much; `gap`: the held-out
    gap after `effects`; `stats`: their held-out statistics; `unconfirmed`: effects dropped because the real
    frames lack their signature; `found`: effects named by their signature alone."""

    effects: list[Effect]
    path: list[Step]
    stopped: str
    stand_ins: list[StandIn]
    gap: float
    stats: Stats | None
    unconfirmed: list[Unconfirmed] = dataclasses.field(default_factory=list)
    found: list[Found] = dataclasses.field(default_factory=list)


@dataclass(frozen=True)
class Solo:
    """An effect fitted alone and its held-out statistics (None: its frames were invalid)."""

    ranked: RankedEffect
    effect: Effect
    stats: Stats | None


# a step's judged candidate: (held-out gap, the chosen effects refitted around it, it as fitted, its solo, stats)
Trial = tuple[float, list[Effect], Effect, Solo, Stats | None]
# what an effect leaves in the real frames that nothing else does, as tested (see `signature_yield`)
SignatureCheck = LeakageCheck | PeakCheck | GhostCheck | ArcCheck | SmearCheck


def signature_check(effect: Effect, problem: SelectionProblem, sim_images: Callable[[], np.ndarray]
                    ) -> GhostCheck | ArcCheck | None:
    """The test of what `effect` leaves in every frame that nothing else does, on the real held-out frames
    against the sim's corrected by the other selected effects (`sim_images`, made only for an effect that has a
    test); None for an effect without one."""
    real = problem.real_images
    if real is not None and isinstance(effect, Multipath):
        return check_ghost(range_lag_correlation(real), range_lag_correlation(sim_images()),
                           ghost_lag_bins(effect.ghost_offset_m, problem.ranges_m))
    if real is not None and isinstance(effect, Interference):
        return check_arcs(real, sim_images(), problem.real_ranges_m, problem.sim_ranges_m)
    return None


# the sidelobes' parameter whose lift of a bright row's dark beams the leakage check tests
PEDESTAL = "crosstalk_db"

# effects looked for by their signature alone after the gain check, when the gap did not name them
SIGNATURE_FINDS = (Interference.name, RingDown.name)


def counted_frames(problem: SelectionProblem) -> CountedFrames | None:
    """What the signature finds count on: `problem.counted`, else the held-out frames (None: no real frames)."""
    if problem.counted is not None:
        return problem.counted
    if problem.real_images is None or problem.sim_images is None:
        return None
    return CountedFrames(problem.real_images, problem.sim_images, problem.real_ranges_m, problem.sim_ranges_m)


def find_by_signature(name: str, counted: CountedFrames, sim_images: np.ndarray, ranges_m: np.ndarray
                      ) -> tuple[Effect, str] | None:
    """Effect `name` (one of SIGNATURE_FINDS) as the real frames' signature of it (`counted.real`) measures it
    against the corrected sim frames `sim_images` (`counted.sim` of the selected effects), with what was found;
    None when the real frames do not show it. Interference: lines that move, in significantly more real frames
    (`arcs.find_lines`). Ring-down: a band from the first range bin (`near_field.find_ring_down`)."""
    real = counted.real
    if name == Interference.name:
        lines = find_lines(real, sim_images, counted.real_ranges_m, counted.sim_ranges_m)
        return (interference_from_lines(real, lines), lines.describe()) if lines.found else None
    near = find_ring_down(real, sim_images)
    return (ring_down_from_excess(real, sim_images, ranges_m), near.describe()) if near.found else None


def rank_effects(names: Sequence[str], problem: SelectionProblem, config: DiagnoseConfig,
                 progress: Callable[[str], None] | None = None) -> list[Solo]:
    """Every effect fitted alone, then judged on the held-out split; best (smallest gap) first, each with how
    often it ranks first over bootstrap resamples of the held-out frames."""
    def solo(name: str) -> tuple[str, Fit, float, Stats | None]:
        # a start the signature locates is searched in full beside the default's: compared at the start only, a
        # double image's start lost to the default and the search never left it (organic two_look_average), while
        # a smear that took it ended worse than from the default (calibrated gaussian_smear)
        fits = [fit_effect(name, problem.fit_frames, problem.fit_target, problem.scale, start=start,
                           search=config.search, statistics=config.statistics, normalize=config.normalize)
                for start in (problem.start(name), *problem.other_starts(name))]
        best = min(fits, key=lambda each: each.fit_gap)
        fit = Fit(best.effect, best.fit_gap, sum(each.evaluations for each in fits))
        return (name, fit, *problem.holdout([fit.effect], None))

    fitted = parallel_map(solo, names, config.workers)
    for name, fit, after, _ in fitted:
        if progress:
            progress(f"{name}: held-out gap {after:.4g} ({fit.evaluations} fits)")
    frequency = _frequencies([stats for *_, stats in fitted], problem, config, seed=config.seed + 500)
    solos = [Solo(RankedEffect(name, fit.effect.params(), after, fit.fit_gap,
                               gap_closed(problem.gap_before, after), float(freq), kind_of(fit.effect)),
                  fit.effect, stats)
             for (name, fit, after, stats), freq in zip(fitted, frequency, strict=True)]
    return sorted(solos, key=lambda solo: solo.ranked.gap_after)


def _frequencies(stats: Sequence[Stats | None], problem: SelectionProblem, config: DiagnoseConfig,
                 seed: int) -> np.ndarray:
    if problem.target is None or not stats:
        return np.full(len(stats), math.nan)
    return best_frequency(stats, problem.target, problem.scale, config.bootstrap, seed=seed)


def greedy_select(ranked: Sequence[Solo], problem: SelectionProblem, config: DiagnoseConfig,
                  progress: Callable[[str], None] | None = None) -> Selection:
    """Forward selection on the held-out split, then backward pruning, then the gain check.

    Step 1 takes the best effect of the solo ranking. Every later step tries *every* remaining effect: with
    `backfit`, the chosen effects are first refitted around its solo fit (their earlier fit
    may have compensated for the effect that was still missing), then it is refitted on top of them (one search
    round each, on the fit split, from the previous fit or the catalogue's default, whichever fits better); the
    `candidates_per_step` sets that fit best are judged on held-out frames. An effect that only helps together
    with another (speckle under a gamma curve) is useless alone and ranks low in the solo ranking, so a shortlist
    taken from that ranking would never reconsider it. The shortlisted set lowering the held-out gap most is kept
    if the gain is at least `min_gain` x gap_before and significantly so: the one-sided `significance` lower bound
    of a paired bootstrap of the gain is above `min_gain` x gap_before, so an effect that merely nudges the
    statistics within their sampling noise is left out and the gap stays residual. Each "add" step records its
    candidates with how often each won over bootstrap resamples of the held-out frames (the first step: the whole
    solo ranking).

    Pruning then takes the effect whose removal costs least and compares the set without it against the whole
    set, both refitted one round: it is dropped unless the cost passes the same two tests, and so on.

    The signature checks then drop a selected multipath whose ghost (each frame's own scene again at the fitted
    offset) the real held-out frames do not show (`ghost.check_ghost`) and a selected interference whose bright
    rows sit at the same ranges in most real frames (`arcs.check_arcs`); both are listed in `unconfirmed`, as are
    picks that gave way to their step's runner-up (`signature_yield`).

    The gain check (`gain_check`) replaces each selected effect in turn by a `GainPattern` fitted on top of the
    others: if a level and ramp alone do at least as well on held-out frames, or a pattern with a shape does
    significantly better (the paired bootstrap's lower bound above 0), the effect is dropped (a "stand-in"), unless
    the real frames are 8-bit counts that the effect gives and the pattern does not (`carries_counts`). The
    burden is on the gain pattern, so a true effect that the statistics tell from a gain only weakly (a multipath
    ghost on a seabed-filled scene) is kept.

    Then (`polish_rounds`) every effect the gap selected is searched that many rounds more, at the finer steps only,
    around the others as they stand (on the fit split), and the set's held-out gap is measured again: a "refit"
    step of "all". The forward steps searched one round each around a set still changing.

    Last, when interference is a candidate and not selected, the real held-out frames with a line that moves are
    counted against the corrected sim's (`arcs.find_lines`): significantly more find it, with the parameters the
    lines measure (`arcs.interference_from_lines`), listed in `found`. It comes after the gain check because a
    gain pattern cannot make lines that move, and the gap, which a few lines barely move, cannot judge it. A
    ring-down not selected is looked for the same way: a band from the first range bin, far above the corrected
    sim's (`near_field.find_ring_down`), which whole-frame statistics can count against it where the worlds differ.
    """
    c = config
    chosen: list[Effect] = []
    gap_before = problem.gap_before
    path = [Step("start", "none", gap_before)]
    current, current_stats = gap_before, problem.stats_before
    remaining = list(ranked)
    one_round = dataclasses.replace(c.search, rounds=1)
    # an effect is added (and kept by pruning) only if its gain is significantly at least this: a world difference
    # that an effect's fitted form mimics a little (interference arcs closing 10% of a no-effect gap) passes a test
    # against 0 but not one against the least gain worth naming
    least_gain = c.min_gain * max(gap_before, 1e-12)
    stopped = f"reached max_effects={c.max_effects}"
    unconfirmed: list[Unconfirmed] = []

    def refit(name: str, base: Sequence[Effect], start: Effect, search: SearchConfig = one_round,
              restart: bool = True) -> Fit:
        # the catalogue's default (a term's calibrated start) is the other start (`restart`): a fit made while
        # another effect was missing may sit in a compromise (a gamma curve bent to mimic speckle) from which one
        # coordinate round does not come back
        return fit_effect(name, problem.fit_frames, problem.fit_target, problem.scale, base=base, start=start,
                          search=search, statistics=c.statistics, normalize=c.normalize,
                          alternatives=[problem.start(name), *problem.other_starts(name)] if restart else ())

    def refit_in_turn(effects: Sequence[Effect], around: Sequence[Effect] = (), search: SearchConfig = one_round,
                      restart: bool = True) -> list[Effect]:
        """Each effect refitted in turn around the others as they now stand (and `around`)."""
        effects = list(effects)
        for i, previous in enumerate(effects):
            effects[i] = refit(previous.name, [*effects[:i], *effects[i + 1:], *around], previous, search,
                               restart).effect
        return effects

    def refit_each(effects: Sequence[Effect], around: Sequence[Effect] = ()) -> list[Effect]:
        return refit_in_turn(effects, around) if c.backfit else list(effects)

    def holdout(effects: Sequence[Effect], gain: GainPattern | None = None) -> tuple[float, Stats | None]:
        return problem.holdout(effects, gain)

    def lower_bound(worse: Stats | None, better: Stats | None, draw: int) -> tuple[float, float]:
        """The paired-bootstrap gain of `better` over `worse` and its one-sided lower bound (+inf: no test)."""
        if problem.target is None or worse is None or better is None or c.significance <= 0:
            return math.nan, math.inf
        return bootstrap_gain(worse, better, problem.target, problem.scale, c.bootstrap, c.significance,
                              seed=c.seed + draw)

    def held_to_leakage(trial: Trial) -> Trial:
        """A step's pick of sidelobes whose cross-talk pedestal lifts the dark beams of bright rows where the real
        frames' are not lifted (diagnose/leakage.py), refitted with the pedestal off: a pedestal fitted to some
        other difference (a texture, a floor) must not cost the sidelobes the real frames do show their place.
        The refit competes in the step as the sidelobes' trial and, picked, is held to the same check
        (`signature_yield`)."""
        gap_with, base, effect, solo, _ = trial
        off = BeamSidelobes.PARAM_BOUNDS[PEDESTAL][0]
        if (not isinstance(effect, BeamSidelobes) or getattr(effect, PEDESTAL) <= off
                or problem.real_images is None or problem.sim_images is None):
            return trial
        check = check_leakage(problem.real_images, problem.sim_images(base), problem.sim_images([*base, effect]))
        if check.confirmed:
            return trial
        refitted = fit_effect(effect.name, problem.fit_frames, problem.fit_target, problem.scale, base=base,
                              start=dataclasses.replace(effect, **{PEDESTAL: off}), search=c.search,
                              statistics=c.statistics, normalize=c.normalize, fixed=(PEDESTAL,)).effect
        gap_without, stats = holdout([*base, refitted])
        unconfirmed.append(Unconfirmed(effect.name, effect.params(), check.describe(), gap_with, gap_without,
                                       named_instead=effect.name))
        path.append(Step("unconfirmed", effect.name, current))
        if progress:
            progress(f"{effect.name}: the real frames lack the leakage its cross-talk pedestal predicts "
                     f"({check.describe()}): refitted without it, held-out gap {gap_with:.4g} -> {gap_without:.4g}")
        return gap_without, base, refitted, solo, stats

    def flattening_rival(check: PeakCheck, rivals: list[Trial]) -> Trial | None:
        """The best of `rivals` whose fitted form spreads the echoes across the beams more as the real frames do."""
        assert problem.sim_images is not None
        return next((t for t in rivals if check.rival_fits_better(problem.sim_images([*t[1], t[2]]))), None)

    def signature_yield(pick: Effect, pick_stats: Stats | None, pick_test: tuple[float, float], base: list[Effect],
                        rivals: list[Trial]) -> tuple[Trial, SignatureCheck, tuple[float, float]] | None:
        """A pick whose signature the real frames lack gives way to a rival of its step (`rivals`, best first) if that
        passes the step's tests by itself, or, between the two blurs, stands within the pick's naming resolution (the
        pick, which passed them, is not told apart from it: `pick_test` is then the step's test). The checks: sidelobes
        whose fitted form lifts the dark beams of bright rows where the real frames' are not lifted
        (diagnose/leakage.py), or leaves the bright echoes standing clear of the beams beside them where the real
        frames' are flattened (diagnose/peaks.py: the rival is then the best one whose fitted form flattens them clearly
        more, smoothing the frames across the beams as they are), a multipath without its ghost, an interference without
        arcs that move (`signature_check`), and, between the two blurs only, a motion blur whose real smoothing runs
        along range alone or a range blur whose real smoothing runs across the beams as much (diagnose/smear.py).
        Failing the check is evidence only against a rival that explains the gap too: on a scene whose rows are full of
        seabed a true sidelobe's lift can be too small to show, and with no rival it is still named (a multipath or an
        interference is then dropped after pruning)."""
        if not rivals or problem.real_images is None or problem.sim_images is None:
            return None
        check: SignatureCheck | None
        rival = rivals[0]
        if isinstance(pick, BeamSidelobes):
            with_pick = problem.sim_images([*base, pick])
            check = check_leakage(problem.real_images, problem.sim_images(base), with_pick)
            if check.confirmed:
                check = check_peaks(problem.real_images, with_pick)
                rival = rival if check.confirmed else flattening_rival(check, rivals)
                if rival is None:
                    return None
        elif pick.name in BLURS:
            name = rival[3].ranked.name
            check = check_smear(pick.name, problem.real_images, problem.sim_images(base)) if name in BLURS else None
        else:
            check = signature_check(pick, problem, lambda: problem.sim_images(base))
        if check is None or check.confirmed or current - rival[0] < least_gain:
            return None
        rival_stats = rival[4]
        gain, lower = lower_bound(current_stats, rival_stats, 700 + len(chosen))
        if lower > least_gain:
            return rival, check, (gain, lower)
        # The peak check, like the smear check, has evidence *for* the rival (its fitted form flattens the peaks as
        # the real frames show): one that closes the gap significantly, not by the least gain worth naming, is named
        # on the pick's test, and the pick stays in its ambiguity group.
        if isinstance(check, PeakCheck) and pick_test[1] > least_gain and lower > 0:
            return rival, check, pick_test
        # Only the smear check tells which of two rivals it is; the others only say what the pick is not (a rival
        # that is not significant by itself took an uncatalogued gap's place on the tuning sets). The seed is the
        # step's ambiguity test's (`alternatives` below), so a rival reported in the pick's group is one here.
        if (isinstance(check, SmearCheck) and pick_test[1] > least_gain
                and lower_bound(rival_stats, pick_stats, 300 + len(chosen))[1] <= least_gain):
            return rival, check, pick_test
        return None

    while remaining and len(chosen) < c.max_effects:
        if current <= c.min_gain * gap_before:
            stopped = f"the gap left is below {c.min_gain:.0%} of the gap before (nothing left to explain)"
            break
        if chosen:
            def screen(solo: Solo, chosen: list[Effect] = chosen) -> tuple[float, list[Effect], Effect, Solo]:
                base = refit_each(chosen, around=[solo.effect])
                fit = refit(solo.ranked.name, base, solo.effect)
                return fit.fit_gap, base, fit.effect, solo

            screened = parallel_map(screen, remaining, c.workers)
            shortlist = sorted(screened, key=lambda t: t[0])[:c.candidates_per_step]
            judged = parallel_map(lambda t: holdout([*t[1], t[2]]), shortlist, c.workers)
            trials = [(gap_value, base, effect, solo, stats)
                      for (_, base, effect, solo), (gap_value, stats) in zip(shortlist, judged, strict=True)]
            frequency = _frequencies([t[4] for t in trials], problem, c, seed=c.seed + 600 + len(chosen))
            candidates = [(t[3].ranked.name, t[0], float(f), t[4]) for t, f in zip(trials, frequency, strict=True)]
        else:  # the solo ranking is already judged on held-out frames: its best is the first step's choice
            trials = [(solo.ranked.gap_after, [], solo.effect, solo, solo.stats)
                      for solo in remaining[:max(2, c.candidates_per_step)]]
            candidates = [(s.ranked.name, s.ranked.gap_after, s.ranked.top_frequency, s.stats) for s in remaining]
        pick = min(trials, key=lambda t: t[0])
        held = held_to_leakage(pick)
        if held is not pick:  # the sidelobes compete refitted, in the step's trials and its reported candidates
            trials = [held if t is pick else t for t in trials]
            candidates = [(name, *((held[0], held[4]) if name == pick[3].ranked.name else (gap_value, stats)))
                          for name, gap_value, _, stats in candidates]
            frequency = _frequencies([stats for *_, stats in candidates], problem, c, seed=c.seed + 650 + len(chosen))
            candidates = [(name, gap_value, float(f), stats)
                          for (name, gap_value, stats), f in zip(candidates, frequency, strict=True)]
        best_gap, best_base, best_effect, best_solo, best_stats = min(trials, key=lambda t: t[0])
        best_name = best_solo.ranked.name
        if current - best_gap < least_gain:
            stopped = f"no remaining effect lowers the held-out gap by {c.min_gain:.0%} of the gap before"
            break
        gain, lower = lower_bound(current_stats, best_stats, len(chosen))
        yielded = signature_yield(best_effect, best_stats, (gain, lower), best_base,
                                  sorted(trials, key=lambda t: t[0])[1:])
        if yielded is not None:
            rival, signature, (gain, lower) = yielded
            unconfirmed.append(Unconfirmed(best_name, best_effect.params(), signature.describe(), best_gap,
                                           rival[0], named_instead=rival[3].ranked.name))
            path.append(Step("unconfirmed", best_name, current))
            remaining = [solo for solo in remaining if solo.ranked.name != best_name]
            if progress:
                progress(f"{best_name}: the real frames lack its signature ({signature.describe()}): "
                         f"{rival[3].ranked.name} named instead")
            best_gap, best_base, best_effect, best_solo, best_stats = rival
            best_name = best_solo.ranked.name
        if lower <= least_gain:
            stopped = (f"the best remaining effect ({best_name}) lowers the held-out gap by {gain:.3g}, not "
                       f"significantly by {c.min_gain:.0%} of the gap before (one-sided {c.significance:.0%} lower "
                       f"bound {lower:.3g} <= {least_gain:.3g})")
            break
        # a rival is told apart from the pick only at the resolution an effect is named at: the pick's gap lower
        # than the rival's by the least gain worth naming, significantly (a surge smear and a range blur that
        # both smooth along range differ by less, however steadily one of them wins the resamples)
        alternatives = tuple(
            Alternative(name, gap_value, frequency,
                        name == best_name or lower_bound(stats, best_stats, 300 + len(chosen))[1] > least_gain)
            for name, gap_value, frequency, stats in candidates)
        chosen = [*best_base, best_effect]
        path.append(Step("add", best_name, best_gap, alternatives))
        current, current_stats = best_gap, best_stats
        remaining = [solo for solo in remaining if solo.ranked.name != best_name]
        if progress:
            progress(f"selected {best_name}: held-out gap {best_gap:.4g} (gain {gain:.3g}, one-sided "
                     f"{c.significance:.0%} lower bound {lower:.3g})")
    else:
        if not remaining:
            stopped = "every catalogued effect selected or passed over"

    while c.prune and len(chosen) >= 2:
        # the candidate for removal: the effect whose absence hurts least as the others stand
        without = parallel_map(lambda e, chosen=chosen: holdout([o for o in chosen if o is not e])[0], chosen,
                               c.workers)
        dropped = chosen[int(np.argmin(without))]
        # judged with both sides refitted alike: the others were fitted while `dropped` was present, and a refit
        # of the rest alone would credit the removal with what is only a better fit
        def refit_side(effects: list[Effect]) -> tuple[list[Effect], float, Stats | None]:
            effects = refit_each(effects)
            return (effects, *holdout(effects))

        sides = [chosen, [e for e in chosen if e.name != dropped.name]]
        (full, gap_full, stats_full), (rest, gap_without, stats_without) = parallel_map(refit_side, sides, c.workers)
        if gap_full < current:
            chosen, current, current_stats = full, gap_full, stats_full
            path.append(Step("refit", "all", gap_full))
        cost = gap_without - current
        if cost >= least_gain and lower_bound(stats_without, current_stats, 100 + len(chosen))[1] > least_gain:
            break
        chosen, current, current_stats = rest, gap_without, stats_without
        path.append(Step("remove", dropped.name, gap_without))
        if progress:
            progress(f"pruned {dropped.name} (the others explain it): held-out gap {gap_without:.4g}")

    # an effect with a signature must show it in the real frames: a multipath its ghost (each frame's own scene
    # again at the fitted offset), an interference arcs that move; what it closed without is another world's
    # difference (another seabed) or a fixed band that its added power mimics
    for effect in list(chosen) if problem.real_images is not None and problem.sim_images is not None else []:
        rest = [e for e in chosen if e is not effect]
        check = signature_check(effect, problem, lambda rest=rest: problem.sim_images(rest))
        if check is None or check.confirmed:
            continue
        rest = refit_each(rest)
        gap_rest, stats_rest = holdout(rest)
        unconfirmed.append(Unconfirmed(effect.name, effect.params(), check.describe(), current, gap_rest))
        chosen, current, current_stats = rest, gap_rest, stats_rest
        path.append(Step("unconfirmed", effect.name, gap_rest))
        if progress:
            progress(f"{effect.name}: the real frames lack its signature ({check.describe()}): not blamed; "
                     f"held-out gap {gap_rest:.4g}")

    def pattern_in_place_of(effect: Effect) -> tuple[GainPattern, float, Stats | None]:
        rest = [e for e in chosen if e is not effect]
        pattern = fit_gain_pattern(problem, rest, c)
        judged = [(pattern, *holdout(rest, pattern))]
        if pattern.band_rows is not None and (pattern.shaped or pattern.params() != GainPattern().params()):
            # the band alone too: a level, ramp and shape fitted on a few frames of a varied scene can be worse
            # than nothing on held-out frames, where a fixed band at its rows (a housing reflection) still holds
            band = GainPattern(band_rows=pattern.band_rows, band_amplitude=pattern.band_amplitude)
            judged.append((band, *holdout(rest, band)))
        return min(judged, key=lambda t: t[1])

    stand_ins = []
    # every selected effect's stand-in pattern at once; one is refitted only if an earlier one was dropped
    patterns = dict(zip([e.name for e in chosen], parallel_map(pattern_in_place_of, chosen, c.workers),
                        strict=True)) if c.gain_check else {}
    changed = False
    real_counts = carries_counts(problem.target)
    for index, name in enumerate(list(patterns)):
        effect = next(e for e in chosen if e.name == name)  # as last refitted
        pattern, gap_gain, stats_gain = pattern_in_place_of(effect) if changed else patterns[name]
        if real_counts and carries_counts(current_stats) and not carries_counts(stats_gain):
            continue  # the real frames are 8-bit counts, as with the effect: no gain pattern in its place makes them
        # an effect fitted with its own physics off is a gain (a TVG curve without noise, per-ping beam gains
        # without haze) standing in for a gain error the catalogue lacks, however well it does that
        off = physics_off(effect)
        if not off and current < gap_gain:
            continue
        # parsimony: a level and a ramp (two numbers, as an effect has) need only do as well; a pattern with a
        # shape (dozens of numbers) must do better beyond the noise, or a ghost that brightens the far range
        # (multipath) is lost to a range shape that mimics its mean
        if (not off and pattern.shaped
                and lower_bound(current_stats, stats_gain, 200 + index)[1] <= 0):
            continue
        rest = refit_each([e for e in chosen if e is not effect])
        gap_rest, stats_rest = holdout(rest)
        fit = describe_pattern(pattern, problem.ranges_m, problem.bearings_deg, gap_gain,
                               gap_closed(gap_before, gap_gain) - gap_closed(gap_before, gap_rest))
        stand_ins.append(StandIn(effect.name, effect.params(), fit, current, gap_gain, off))
        chosen, current, current_stats, changed = rest, gap_rest, stats_rest, True
        path.append(Step("gain_stand_in", effect.name, gap_rest))
        if progress:
            why = f"fitted with {', '.join(off)} off" if off else "does no more than a gain pattern"
            progress(f"{effect.name} {why} ({fit.describe()}): not blamed; held-out gap {gap_rest:.4g}")

    if c.polish_rounds and chosen:
        # the forward steps searched one round each around a set still changing; the set now stands, and the
        # finer steps cost a few evaluations per parameter (the fit split decides, as for every fit)
        polish = dataclasses.replace(c.search, first_round=c.search.rounds, rounds=c.search.rounds + c.polish_rounds)
        polished = refit_in_turn(chosen, search=polish, restart=False)  # on from where each is
        gap_polished, stats_polished = holdout(polished)
        if math.isfinite(gap_polished):  # inf: the finer values make invalid held-out frames; keep the set as it was
            chosen, current, current_stats = polished, gap_polished, stats_polished
            path.append(Step("refit", "all", current))
            if progress:
                progress(f"the selected effects searched {c.polish_rounds} finer rounds: held-out gap {current:.4g}")

    found: list[Found] = []
    names = {solo.ranked.name for solo in ranked}
    counted = counted_frames(problem)
    corrected: np.ndarray | None = None  # the counted sim frames corrected by `chosen`, made once per set
    # max_effects caps what the gap selects, not what the real frames show: a last place taken by a stand-in at
    # its bounds must not hide a signature the real frames carry
    for name in SIGNATURE_FINDS if counted is not None else ():
        if name not in names or any(e.name == name for e in chosen):
            continue
        if corrected is None:
            corrected = counted.sim(chosen)
        hit = find_by_signature(name, counted, corrected, problem.ranges_m)
        if hit is None:
            continue
        effect, signature = hit
        gap_with, stats_with = holdout([*chosen, effect])
        found.append(Found(effect.name, effect.params(), signature, current, gap_with))
        chosen, current, current_stats, corrected = [*chosen, effect], gap_with, stats_with, None
        path.append(Step("found", effect.name, gap_with))
        if progress:
            progress(f"{effect.name} found by its signature ({signature}); held-out gap {gap_with:.4g}")
    return Selection(chosen, path, stopped, stand_ins, current, current_stats, unconfirmed, found)
