"""Which catalogued effect explains the gap: fit each effect's parameters on one split, measure on another.

Fitting is a coordinate search over the effect's `PARAM_BOUNDS` (a coarse grid per parameter, then a finer grid
around the best value), minimising the headline gap between the corrected fit-split sim frames and the fit-split
real frames. The same random draws are used for every candidate parameter value (common random numbers), so the
objective is smooth in the parameters and a handful of frames suffice. Ranking and selection are judged on the
held-out split only.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

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
class Fit:
    effect: Effect
    fit_gap: float
    evaluations: int


def corrected_images(frames: Sequence[SonarImage], effects: Sequence[Effect], seed: int,
                     normalize: str = "none") -> np.ndarray:
    """Apply `effects` to every frame (one generator seeded with `seed`) and stack as float32 [n, R, B] in [0, 1]."""
    rng = np.random.default_rng(seed)
    out = []
    for frame in frames:
        corrected = apply_effects(frame, effects, rng) if effects else frame
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
    cls = EFFECTS[name]
    bounds = dict(cls.PARAM_BOUNDS)

    def clipped(effect: Effect) -> Effect:
        return dataclasses.replace(effect, **{k: float(np.clip(getattr(effect, k), *bounds[k])) for k in bounds})

    current = clipped(start if start is not None else make_effect(name))

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
class Selection:
    """The greedy path: `effects` in the order chosen; `gaps[0]` the gap before, `gaps[i]` after the first i effects;
    `stopped` says why the selection ended."""

    effects: list[Effect]
    gaps: list[float]
    stopped: str


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
                  backfit: bool = True, seed: int = 0) -> Selection:
    """Forward selection on the held-out split.

    Step 1 takes the best effect of the solo ranking. Every later step tries *every* remaining effect: with
    `backfit`, the chosen effects are first refitted around its solo fit (their earlier fit may have compensated
    for the effect that was still missing), then it is refitted on top of them (one search round each, on the fit
    split, from the previous fit or the catalogue's default, whichever fits better); the `candidates_per_step`
    sets that fit best are judged on held-out frames. An effect that only helps together with another (speckle
    under a gamma curve) is useless alone and ranks low in the solo ranking, so a shortlist taken from that
    ranking would never reconsider it. The shortlisted set lowering the held-out gap most is kept if the gain is
    at least `min_gain` x gap_before and, with `target` (the held-out real statistics) and `stats_before` (the
    held-out sim statistics that gave gap_before) given, significant: the
    one-sided `significance` lower bound of a paired bootstrap of the gain is above 0, so an effect that merely
    nudges the statistics within their sampling noise is left out and the gap stays residual.
    """
    chosen: list[Effect] = []
    path_gaps = [gap_before]
    current, current_stats = gap_before, stats_before
    remaining = list(ranked)
    one_round = dataclasses.replace(search, rounds=1)
    stopped = f"reached max_effects={max_effects}"

    def refit(name: str, base: Sequence[Effect], start: Effect) -> Fit:
        # the catalogue's default is the other start: a fit made while another effect was missing may sit in a
        # compromise (a gamma curve bent to mimic speckle) from which one coordinate round does not come back
        return fit_effect(name, fit_frames, fit_target, scale, base=base, start=start, search=one_round,
                          statistics=statistics, normalize=normalize, alternatives=[make_effect(name)])

    while remaining and len(chosen) < max_effects:
        if current <= min_gain * gap_before:
            stopped = f"the gap left is below {min_gain:.0%} of the gap before (nothing left to explain)"
            break
        if chosen:
            screened = []
            for info, solo in remaining:
                base = list(chosen)
                if backfit:  # the chosen effects around the candidate first, then the candidate on top of them
                    for i, previous in enumerate(base):
                        base[i] = refit(previous.name, [*base[:i], *base[i + 1:], solo], previous).effect
                fit = refit(info.name, base, solo)
                screened.append((fit.fit_gap, base, fit.effect, info))
            shortlist = sorted(screened, key=lambda t: t[0])[:candidates_per_step]
        else:  # the solo ranking is already judged on held-out frames: its best is the first step's choice
            shortlist = [(remaining[0][0].fit_gap, [], remaining[0][1], remaining[0][0])]
        trials = []
        for _, base, effect, info in shortlist:
            gap_value, stats = holdout([*base, effect])
            trials.append((gap_value, base, effect, info, stats))
        best_gap, best_base, best_effect, best_info, best_stats = min(trials, key=lambda t: t[0])
        if current - best_gap < min_gain * max(gap_before, 1e-12):
            stopped = f"no remaining effect lowers the held-out gap by {min_gain:.0%} of the gap before"
            break
        if target is not None and current_stats is not None and best_stats is not None and significance > 0:
            gain, lower = bootstrap_gain(current_stats, best_stats, target, scale, bootstrap, significance,
                                         seed=seed + len(chosen))
            if lower <= 0.0:
                stopped = (f"the best remaining effect ({best_info.name}) lowers the held-out gap by {gain:.3g}, "
                           f"not significantly (one-sided {significance:.0%} lower bound {lower:.3g} <= 0)")
                break
        chosen = [*best_base, best_effect]
        path_gaps.append(best_gap)
        current, current_stats = best_gap, best_stats
        remaining = [pair for pair in remaining if pair[0].name != best_info.name]
        if progress:
            progress(f"selected {best_info.name}: held-out gap {best_gap:.4g}")
    else:
        if not remaining:
            stopped = "every catalogued effect selected"
    return Selection(chosen, path_gaps, stopped)


def check_effect_names(names: Sequence[str]) -> list[str]:
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ConfigError(f"unknown effect(s) {', '.join(unknown)}; catalogue: {', '.join(PIPELINE_ORDER)}")
    return list(names) if names else list(PIPELINE_ORDER)

