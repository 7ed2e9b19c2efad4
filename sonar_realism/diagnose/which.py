"""Which catalogued effect explains the gap: fit each effect's parameters on one split, measure on another.

Fitting is a coordinate search over the effect's `PARAM_BOUNDS` (a coarse grid per parameter, then a finer grid
around the best value), minimising the headline gap between the corrected fit-split sim frames and the fit-split
real frames. The same random draws are used for every candidate parameter value (common random numbers), so the
objective is smooth in the parameters and a handful of frames suffice. Ranking and selection are judged on the
held-out split only.

After forward selection, each selected effect is tried out again (backward pruning): one that the effects chosen
after it make redundant (motion blur standing in for beam sidelobes until they are selected) is dropped. Last,
each selected effect must beat a plain gain difference (`GainProfile`): an effect whose fitted form does no more
than a level and a range ramp would (a TVG ramp standing in for a beam-gain pattern the catalogue lacks) is not
blamed, and its part of the gap stays residual.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from sonar_realism.diagnose.gap import FeatureScale, Stats, bootstrap_gain, gap
from sonar_realism.errors import ConfigError, FrameError
from sonar_realism.evaluate.statistics import StatisticsConfig, frame_statistics
from sonar_realism.frames import SonarImage
from sonar_realism.sim.effects import EFFECTS, PIPELINE_ORDER, Effect, apply_effects, make_effect


@dataclass(frozen=True)
class SearchConfig:
    """points: coarse grid values per parameter; rounds: 1 coarse round + (rounds - 1) finer rounds that try half a
    grid step either side of the best value;
    seed: the random draws shared by every candidate."""

    points: int = 5
    rounds: int = 2
    seed: int = 0

    def validate(self) -> None:
        if self.points < 2 or self.rounds < 1:
            raise ConfigError("SearchConfig: points >= 2 and rounds >= 1")


@dataclass(frozen=True)
class GainProfile(Effect):
    """A plain gain difference: an overall level and a linear ramp in dB over range. Not a sensor effect: the
    yardstick every selected effect must beat, applied to the sim frames before any effect."""

    name: ClassVar[str] = "gain_profile"
    level_db: float = 0.0
    ramp_db: float = 0.0
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"level_db": (-12.0, 12.0), "ramp_db": (-12.0, 12.0)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {"level_db": (-60.0, 60.0), "ramp_db": (-60.0, 60.0)}
    # A gain is one smooth dimension each: a finer search than the effects get is cheap and keeps the yardstick
    # from losing to an effect only because its grid missed a fraction of a dB.
    SEARCH_ROUNDS: ClassVar[int] = 6

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        r = frame.ranges_m
        gain_db = self.level_db + self.ramp_db * (r - r[0]) / max(r[-1] - r[0], 1e-9)
        return intensity * (10 ** (gain_db / 20)).astype(np.float32)[:, None]


def candidate_class(name: str) -> type[Effect]:
    return GainProfile if name == GainProfile.name else EFFECTS[name]


def default_candidate(name: str) -> Effect:
    return GainProfile() if name == GainProfile.name else make_effect(name)


@dataclass(frozen=True)
class Fit:
    effect: Effect
    fit_gap: float
    evaluations: int


def corrected_images(frames: Sequence[SonarImage], effects: Sequence[Effect], seed: int,
                     normalize: str = "none") -> np.ndarray:
    """Apply `effects` to every frame (one generator seeded with `seed`) and stack as float32 [n, R, B] in [0, 1]."""
    rng = np.random.default_rng(seed)
    gains = [e for e in effects if isinstance(e, GainProfile)]
    sensor_effects = [e for e in effects if not isinstance(e, GainProfile)]
    out = []
    for frame in frames:
        for gain in gains:
            frame = frame.replace(intensity=gain.apply(frame.normalized(), frame, rng), intensity_scale=1.0)
        corrected = apply_effects(frame, sensor_effects, rng) if sensor_effects else frame
        out.append(normalize_image(corrected.normalized(), normalize))
    return np.stack(out)


def normalize_image(image: np.ndarray, how: str) -> np.ndarray:
    """"max" divides a frame by its maximum (as the real Oculus set was exported), "none" leaves it."""
    if how == "max":
        peak = float(image.max())
        return image / peak if peak > 0 else image
    return image


def fit_effect(name: str, frames: Sequence[SonarImage], target: Stats, scale: FeatureScale,
               base: Sequence[Effect] = (), start: Effect | None = None, search: SearchConfig = SearchConfig(),
               statistics: StatisticsConfig | None = None, normalize: str = "none",
               alternatives: Sequence[Effect] = ()) -> Fit:
    """Parameters of effect `name` that, applied to `frames` after/with the `base` effects, bring their
    statistics closest to `target`. The search starts from `start` (default: the catalogue's values) or from
    whichever of `alternatives` fits better there."""
    statistics = statistics or StatisticsConfig()
    bounds = dict(candidate_class(name).PARAM_BOUNDS)

    def clipped(effect: Effect) -> Effect:
        return dataclasses.replace(effect, **{k: float(np.clip(getattr(effect, k), *bounds[k])) for k in bounds})

    current = clipped(start if start is not None else default_candidate(name))

    evaluations = 0
    cache: dict[tuple, float] = {}

    def objective(effect: Effect) -> float:
        nonlocal evaluations
        key = tuple((k, float(f"{v:.9g}")) for k, v in sorted(effect.params().items()))
        if key not in cache:
            try:
                images = corrected_images(frames, [*base, effect], search.seed, normalize)
                cache[key] = gap(frame_statistics(images, statistics), target, scale)
            except FrameError:  # parameter values for which the effect yields an invalid frame are no candidates
                cache[key] = math.inf
            evaluations += 1
        return cache[key]

    best = objective(current)
    for other in alternatives:
        other = clipped(other)
        score = objective(other)
        if score < best:
            best, current = score, other
    for round_index in range(search.rounds):
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
                score = objective(trial)
                if score < best:
                    best, current = score, trial
    return Fit(current, best, evaluations)


@dataclass(frozen=True)
class RankedEffect:
    name: str
    params: dict
    gap_after: float
    fit_gap: float


@dataclass(frozen=True)
class Step:
    """One step of the selection: `action` is "start" (nothing applied), "add", "refit" (pruning refitted the
    whole set, which fitted better), "remove" (pruned) or "gain_stand_in" (removed: a plain gain difference does
    its job); `gap` the held-out gap after it."""

    action: str
    effect: str
    gap: float


@dataclass(frozen=True)
class Selection:
    """`effects`: the selected effects as finally fitted; `path`: every step taken; `stopped`: why the forward
    selection ended; `stand_ins`: effects dropped because a plain gain difference explained as much."""

    effects: list[Effect]
    path: list[Step]
    stopped: str
    stand_ins: list[dict] = dataclasses.field(default_factory=list)


def rank_effects(names: Sequence[str], fit_frames: Sequence[SonarImage], fit_target: Stats,
                 holdout_gap: Callable[[Sequence[Effect]], float], scale: FeatureScale, search: SearchConfig,
                 statistics: StatisticsConfig, normalize: str = "none",
                 progress: Callable[[str], None] | None = None) -> list[tuple[RankedEffect, Effect]]:
    """Every effect fitted alone, then judged on the held-out split; best (smallest gap) first."""
    out = []
    for name in names:
        fit = fit_effect(name, fit_frames, fit_target, scale, search=search, statistics=statistics,
                         normalize=normalize)
        after = holdout_gap([fit.effect])
        if progress:
            progress(f"{name}: held-out gap {after:.4g} ({fit.evaluations} fits)")
        out.append((RankedEffect(name, fit.effect.params(), after, fit.fit_gap), fit.effect))
    return sorted(out, key=lambda pair: pair[0].gap_after)


def greedy_select(ranked: Sequence[tuple[RankedEffect, Effect]], gap_before: float, fit_frames: Sequence[SonarImage],
                  fit_target: Stats, holdout: Callable[[Sequence[Effect]], tuple[float, Stats | None]],
                  scale: FeatureScale, search: SearchConfig, statistics: StatisticsConfig, max_effects: int,
                  min_gain: float, candidates_per_step: int, normalize: str = "none",
                  progress: Callable[[str], None] | None = None, target: Stats | None = None,
                  stats_before: Stats | None = None, significance: float = 0.95, bootstrap: int = 200,
                  backfit: bool = True, seed: int = 0, prune: bool = True,
                  gain_check: bool = True) -> Selection:
    """Forward selection on the held-out split, then backward pruning, then the gain check.

    Step 1 takes the best effect of the solo ranking. Every later step tries *every* remaining effect: with
    `backfit`, the chosen effects are first refitted around its solo fit (their earlier fit
    may have compensated for the effect that was still missing), then it is refitted on top of them (one search
    round each, on the fit split, from the previous fit or the catalogue's default, whichever fits better); the
    `candidates_per_step` sets that fit best are judged on held-out frames. An effect that only helps together
    with another (speckle under a gamma curve) is useless alone and ranks low in the solo ranking, so a shortlist
    taken from that ranking would never reconsider it. The shortlisted set lowering the held-out gap most is kept
    if the gain is at least `min_gain` x gap_before and, with `target` (the held-out real statistics) and
    `stats_before` (the held-out sim statistics that gave gap_before) given, significant: the one-sided
    `significance` lower bound of a paired bootstrap of the gain is above 0, so an effect that merely nudges the
    statistics within their sampling noise is left out and the gap stays residual.

    Pruning then takes the effect whose removal costs least and compares the set without it against the whole
    set, both refitted one round: it is dropped unless the cost passes the same two tests, and so on.

    The gain check (`gain_check`) replaces each selected effect in turn by a `GainProfile` fitted on top of the
    others: if that does at least as well on held-out frames, the effect is dropped (a "stand-in"). Not a
    significance test: the burden is on the plain gain, so a true effect that the statistics tell from a gain
    only weakly (a multipath ghost on a seabed-filled scene) is kept.
    """
    chosen: list[Effect] = []
    path = [Step("start", "none", gap_before)]
    current, current_stats = gap_before, stats_before
    remaining = list(ranked)
    one_round = dataclasses.replace(search, rounds=1)
    stopped = f"reached max_effects={max_effects}"

    def refit(name: str, base: Sequence[Effect], start: Effect) -> Fit:
        # the catalogue's default is the other start: a fit made while another effect was missing may sit in a
        # compromise (a gamma curve bent to mimic speckle) from which one coordinate round does not come back
        return fit_effect(name, fit_frames, fit_target, scale, base=base, start=start, search=one_round,
                          statistics=statistics, normalize=normalize, alternatives=[default_candidate(name)])

    def refit_each(effects: Sequence[Effect], around: Sequence[Effect] = ()) -> list[Effect]:
        effects = list(effects)
        if backfit:
            for i, previous in enumerate(effects):
                effects[i] = refit(previous.name, [*effects[:i], *effects[i + 1:], *around], previous).effect
        return effects

    def lower_bound(worse: Stats | None, better: Stats | None, draw: int) -> tuple[float, float]:
        """The paired-bootstrap gain of `better` over `worse` and its one-sided lower bound (+inf: no test)."""
        if target is None or worse is None or better is None or significance <= 0:
            return math.nan, math.inf
        return bootstrap_gain(worse, better, target, scale, bootstrap, significance, seed=seed + draw)

    while remaining and len(chosen) < max_effects:
        if current <= min_gain * gap_before:
            stopped = f"the gap left is below {min_gain:.0%} of the gap before (nothing left to explain)"
            break
        if chosen:
            screened = []
            for info, solo in remaining:
                base = refit_each(chosen, around=[solo])
                fit = refit(info.name, base, solo)
                screened.append((fit.fit_gap, base, fit.effect, info))
            shortlist = sorted(screened, key=lambda t: t[0])[:candidates_per_step]
        else:  # the solo ranking is already judged on held-out frames: its best is the first step's choice
            shortlist = [(remaining[0][0].fit_gap, list(chosen), remaining[0][1], remaining[0][0])]
        trials = []
        for _, base, effect, info in shortlist:
            gap_value, stats = holdout([*base, effect])
            trials.append((gap_value, base, effect, info, stats))
        best_gap, best_base, best_effect, best_info, best_stats = min(trials, key=lambda t: t[0])
        if current - best_gap < min_gain * max(gap_before, 1e-12):
            stopped = f"no remaining effect lowers the held-out gap by {min_gain:.0%} of the gap before"
            break
        gain, lower = lower_bound(current_stats, best_stats, len(chosen))
        if lower <= 0.0:
            stopped = (f"the best remaining effect ({best_info.name}) lowers the held-out gap by {gain:.3g}, "
                       f"not significantly (one-sided {significance:.0%} lower bound {lower:.3g} <= 0)")
            break
        chosen = [*best_base, best_effect]
        path.append(Step("add", best_info.name, best_gap))
        current, current_stats = best_gap, best_stats
        remaining = [pair for pair in remaining if pair[0].name != best_info.name]
        if progress:
            progress(f"selected {best_info.name}: held-out gap {best_gap:.4g} (gain {gain:.3g}, one-sided "
                     f"{significance:.0%} lower bound {lower:.3g})")
    else:
        if not remaining:
            stopped = "every catalogued effect selected"

    while prune and len(chosen) >= 2:
        # the candidate for removal: the effect whose absence hurts least as the others stand
        dropped = min(chosen, key=lambda e: holdout([other for other in chosen if other is not e])[0])
        # judged with both sides refitted alike: the others were fitted while `dropped` was present, and a refit
        # of the rest alone would credit the removal with what is only a better fit
        full = refit_each(chosen)
        gap_full, stats_full = holdout(full)
        if gap_full < current:
            chosen, current, current_stats = full, gap_full, stats_full
            path.append(Step("refit", "all", gap_full))
        rest = refit_each([e for e in chosen if e.name != dropped.name])
        gap_without, stats_without = holdout(rest)
        cost = gap_without - current
        significant = lower_bound(stats_without, current_stats, 100 + len(chosen))[1] > 0
        if cost >= min_gain * max(gap_before, 1e-12) and significant:
            break
        chosen, current, current_stats = rest, gap_without, stats_without
        path.append(Step("remove", dropped.name, gap_without))
        if progress:
            progress(f"pruned {dropped.name} (the others explain it): held-out gap {gap_without:.4g}")

    stand_ins = []
    gain_search = dataclasses.replace(search, rounds=max(search.rounds, GainProfile.SEARCH_ROUNDS))
    for name in [e.name for e in chosen] if gain_check else []:
        effect = next(e for e in chosen if e.name == name)  # as last refitted
        rest = [e for e in chosen if e.name != name]
        gain = fit_effect(GainProfile.name, fit_frames, fit_target, scale, base=rest, search=gain_search,
                          statistics=statistics, normalize=normalize).effect
        gap_gain, _ = holdout([*rest, gain])
        if current < gap_gain:
            continue
        rest = refit_each(rest)
        gap_rest, stats_rest = holdout(rest)
        stand_ins.append({"effect": effect.name, "params": effect.params(), "gain_profile": gain.params(),
                          "gap_with_effect": current, "gap_with_gain_profile": gap_gain})
        chosen, current, current_stats = rest, gap_rest, stats_rest
        path.append(Step("gain_stand_in", effect.name, gap_rest))
        if progress:
            progress(f"{effect.name} does no more than a gain profile ({gain.params()}): not blamed; held-out gap "
                     f"{gap_rest:.4g}")
    return Selection(chosen, path, stopped, stand_ins)


def check_effect_names(names: Sequence[str]) -> list[str]:
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ConfigError(f"unknown effect(s) {', '.join(unknown)}; catalogue: {', '.join(PIPELINE_ORDER)}")
    return list(names) if names else list(PIPELINE_ORDER)

