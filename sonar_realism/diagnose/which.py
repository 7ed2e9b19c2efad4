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

from sonar_realism.diagnose.gap import FeatureScale, Stats, gap
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
               statistics: StatisticsConfig | None = None, normalize: str = "none") -> Fit:
    """Parameters of effect `name` that, applied to `frames` after/with the `base` effects, bring their
    statistics closest to `target`."""
    statistics = statistics or StatisticsConfig()
    cls = EFFECTS[name]
    bounds = dict(cls.PARAM_BOUNDS)
    current = start if start is not None else make_effect(name)
    current = dataclasses.replace(current, **{k: float(np.clip(getattr(current, k), *bounds[k])) for k in bounds})

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
                  fit_target: Stats, holdout_gap: Callable[[Sequence[Effect]], float], scale: FeatureScale,
                  search: SearchConfig, statistics: StatisticsConfig, max_effects: int, min_gain: float,
                  candidates_per_step: int, normalize: str = "none",
                  progress: Callable[[str], None] | None = None) -> Selection:
    """Forward selection: at each step refit the best few remaining effects on top of the chosen set, keep the one
    that lowers the held-out gap most, and stop when none lowers it by at least `min_gain` x gap_before."""
    chosen: list[Effect] = []
    path_gaps = [gap_before]
    current = gap_before
    remaining = list(ranked)
    stopped = f"reached max_effects={max_effects}"
    while remaining and len(chosen) < max_effects:
        if current <= min_gain * gap_before:
            stopped = f"the gap left is below {min_gain:.0%} of the gap before (nothing left to explain)"
            break
        trials = []
        for info, solo in remaining[:candidates_per_step]:
            if chosen:
                refit = fit_effect(info.name, fit_frames, fit_target, scale, base=chosen, start=solo,
                                   search=dataclasses.replace(search, rounds=1), statistics=statistics,
                                   normalize=normalize).effect
            else:
                refit = solo
            trials.append((holdout_gap([*chosen, refit]), refit, info))
        best_gap, best_effect, best_info = min(trials, key=lambda t: t[0])
        if current - best_gap < min_gain * max(gap_before, 1e-12):
            stopped = f"no remaining effect lowers the held-out gap by {min_gain:.0%} of the gap before"
            break
        chosen.append(best_effect)
        path_gaps.append(best_gap)
        current = best_gap
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

