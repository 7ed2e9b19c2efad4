"""The diagnosis' configuration: one frozen dataclass, validated, built from JSON by `config.from_dict`."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

from sonar_realism.diagnose.where import WhereConfig
from sonar_realism.errors import ConfigError
from sonar_realism.evaluate.statistics import StatisticsConfig
from sonar_realism.sim.effects import EFFECTS, PIPELINE_ORDER

MIN_FRAMES_PER_SPLIT = 2


@dataclass(frozen=True)
class SearchConfig:
    """points: coarse grid values per parameter; rounds: 1 coarse round + (rounds - 1) finer rounds that try half a
    grid step either side of the best value, halving the step each round; first_round: the rounds before it are
    skipped (a fit already made, searched on from where it is at the finer steps);
    seed: the random draws shared by every candidate."""

    points: int = 5
    rounds: int = 2
    seed: int = 0
    first_round: int = 0

    def validate(self) -> None:
        if self.points < 2 or self.rounds < 1 or not 0 <= self.first_round < self.rounds:
            raise ConfigError("SearchConfig: points >= 2, rounds >= 1 and 0 <= first_round < rounds")
        if self.seed < 0:
            raise ConfigError(f"diagnose.search.seed: must be 0 or more, got {self.seed}")


@dataclass(frozen=True)
class DiagnoseConfig:
    """holdout_fraction: share of each set kept for measuring; fit_frames: sim frames the parameter search uses
    (those of the fit split whose mean statistics are closest to the split's, among up to eval_frames of it);
    eval_frames / real_frames: cap on held-out sim / real frames per measurement (cost grows with them);
    max_effects, min_gain, candidates_per_step: greedy selection (an effect must close at least min_gain of the
    gap before to be selected; effects found by their signature alone come on top of max_effects);
    significance: one-sided level of the paired bootstrap test an effect's gain must pass to be selected
    (0 = no test); backfit: refit the chosen effects around each new candidate; polish_rounds: finer search
    rounds (each halving the step) every effect the gap selected gets last, each around the others, on the fit
    split (0 = none);
    prune: after forward selection, drop effects the others make redundant; gain_check: drop selected effects
    that do no better than a fixed per-range and per-beam gain pattern; effects: the candidates (empty = the
    whole catalogue); normalize: "max" divides every frame by its maximum before measuring (for real sets
    exported that way); bootstrap: resamples of the held-out frames for every interval, test and selection
    frequency; ambiguity: a step whose pick wins fewer than 1 - this share of the resamples (its rivals together
    win more) is ambiguous (pick and rivals are reported, with their shares); workers: processes that fit a
    step's candidates side by side (the results do not depend on it)."""

    holdout_fraction: float = 0.5
    fit_frames: int = 8
    eval_frames: int = 96
    real_frames: int = 256
    max_effects: int = 4
    min_gain: float = 0.05
    candidates_per_step: int = 3
    significance: float = 0.95
    backfit: bool = True
    polish_rounds: int = 2
    prune: bool = True
    gain_check: bool = True
    effects: tuple[str, ...] = ()
    normalize: Literal["none", "max"] = "none"
    bootstrap: int = 200
    ambiguity: float = 0.2
    workers: int = 2
    seed: int = 0
    search: SearchConfig = field(default_factory=SearchConfig)
    statistics: StatisticsConfig = field(default_factory=StatisticsConfig)
    where: WhereConfig = field(default_factory=WhereConfig)

    def validate(self) -> None:
        if not 0.0 < self.holdout_fraction < 1.0:
            raise ConfigError(f"diagnose.holdout_fraction: must be in (0, 1), got {self.holdout_fraction}")
        if min(self.fit_frames, self.eval_frames, self.real_frames) < MIN_FRAMES_PER_SPLIT:
            raise ConfigError(f"diagnose: fit_frames, eval_frames and real_frames must be >= {MIN_FRAMES_PER_SPLIT}")
        if self.max_effects < 0 or self.candidates_per_step < 1 or not 0.0 <= self.min_gain < 1.0:
            raise ConfigError("diagnose: max_effects >= 0, candidates_per_step >= 1, 0 <= min_gain < 1")
        if not 0.0 <= self.significance < 1.0:
            raise ConfigError(f"diagnose.significance: must be in [0, 1), got {self.significance}")
        if self.polish_rounds < 0:
            raise ConfigError(f"diagnose.polish_rounds: at least 0, got {self.polish_rounds}")
        if self.bootstrap < 1:
            raise ConfigError(f"diagnose.bootstrap: at least 1 resample, got {self.bootstrap}")
        if self.workers < 1:
            raise ConfigError(f"diagnose.workers: at least 1, got {self.workers}")
        if self.seed < 0:
            raise ConfigError(f"diagnose.seed: must be 0 or more, got {self.seed}")
        if not 0.0 < self.ambiguity <= 0.5:
            raise ConfigError(f"diagnose.ambiguity: must be in (0, 0.5], got {self.ambiguity}")
        if self.normalize not in ("none", "max"):
            raise ConfigError(f"diagnose.normalize: 'none' or 'max', got {self.normalize!r}")
        check_effect_names(self.effects)
        self.search.validate()
        self.statistics.validate()
        self.where.validate()


def check_effect_names(names: Sequence[str]) -> list[str]:
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ConfigError(f"unknown effect(s) {', '.join(unknown)}; catalogue: {', '.join(PIPELINE_ORDER)}")
    return list(names) if names else list(PIPELINE_ORDER)
