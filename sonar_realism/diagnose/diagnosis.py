"""The whole diagnosis: gap (how big), where (which cells, levels, bands), which (effects ranked and selected),
how far (the gap after each effect and after the selected set), and the residual nothing in the catalogue explains.

Both sets are split once: fit frames (parameter estimation) and held-out frames (every gap that is reported).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from sonar_realism.diagnose.gap import FeatureScale, Stats, bootstrap_interval, classifier_auc, family_gaps, headline
from sonar_realism.diagnose.where import (
    GapMaps,
    WhereConfig,
    band_names,
    concentration,
    gap_maps,
    hot_bins,
    hot_cells,
    level_names,
    where_features,
)
from sonar_realism.diagnose.which import (
    RankedEffect,
    SearchConfig,
    Step,
    check_effect_names,
    corrected_images,
    greedy_select,
    rank_effects,
)
from sonar_realism.errors import ConfigError, FrameError
from sonar_realism.evaluate.statistics import StatisticsConfig, frame_statistics
from sonar_realism.frames import SonarImage
from sonar_realism.sim.effects import Effect

MIN_FRAMES_PER_SPLIT = 2


@dataclass(frozen=True)
class DiagnoseConfig:
    """holdout_fraction: share of each set kept for measuring; fit_frames: sim frames the parameter search uses;
    eval_frames / real_frames: cap on held-out sim / real frames per measurement (cost grows with them);
    max_effects, min_gain, candidates_per_step: greedy selection (an effect must close at least min_gain of the
    gap before to be selected); significance: one-sided level of the paired bootstrap test an effect's gain must
    pass to be selected (0 = no test); backfit: refit the chosen effects around each new candidate;
    prune: after forward selection, drop effects the others make redundant; gain_check: drop selected effects
    that do no better than a plain gain difference (level and range ramp); effects: the candidates (empty = the
    whole catalogue); normalize: "max" divides every frame by its maximum before measuring (for real sets
    exported that way)."""

    holdout_fraction: float = 0.5
    fit_frames: int = 12
    eval_frames: int = 96
    real_frames: int = 256
    max_effects: int = 4
    min_gain: float = 0.05
    candidates_per_step: int = 3
    significance: float = 0.95
    backfit: bool = True
    prune: bool = True
    gain_check: bool = True
    effects: tuple[str, ...] = ()
    normalize: Literal["none", "max"] = "none"
    bootstrap: int = 200
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
        if self.normalize not in ("none", "max"):
            raise ConfigError(f"diagnose.normalize: 'none' or 'max', got {self.normalize!r}")
        check_effect_names(self.effects)
        self.search.validate()
        self.statistics.validate()
        self.where.validate()


@dataclass
class Diagnosis:
    """Everything the report needs. `to_json()` is the diagnosis.json content."""

    summary: dict[str, Any]
    maps_before: GapMaps
    maps_after: GapMaps
    family_before: dict[str, float]
    family_after: dict[str, float]
    ranked: list[RankedEffect]
    path: list[Step]
    examples: dict[str, np.ndarray]

    def to_json(self) -> dict[str, Any]:
        return self.summary


def split_indices(n: int, holdout_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Fit and held-out indices of a set of n frames: a seeded shuffle, at least 2 frames on each side."""
    if n < 2 * MIN_FRAMES_PER_SPLIT:
        raise ConfigError(f"need at least {2 * MIN_FRAMES_PER_SPLIT} frames in each set ({MIN_FRAMES_PER_SPLIT} to "
                          f"fit the effects, {MIN_FRAMES_PER_SPLIT} held out), got {n}")
    order = np.random.default_rng(seed).permutation(n)
    n_hold = int(np.clip(round(n * holdout_fraction), MIN_FRAMES_PER_SPLIT, n - MIN_FRAMES_PER_SPLIT))
    return np.sort(order[n_hold:]), np.sort(order[:n_hold])


def check_sets(sim: Sequence[SonarImage], real: Sequence[SonarImage]) -> None:
    """Both sets non-empty and on one grid; otherwise a ConfigError that says what to do."""
    for label, frames in (("sim", sim), ("real", real)):
        if not frames:
            raise ConfigError(f"the {label} set is empty: give a folder or recording with frames")
        shapes = sorted({f.intensity.shape[-2:] for f in frames})
        if len(shapes) > 1:
            raise ConfigError(f"the {label} set mixes grids {shapes} (ranges x beams); resample it to one grid "
                              "(sonar-realism diagnose --resample)")
    a, b = sim[0], real[0]
    if a.intensity.shape[-2:] != b.intensity.shape[-2:]:
        raise ConfigError(f"sim frames are {a.n_ranges} ranges x {a.n_beams} beams but real frames are "
                          f"{b.n_ranges} x {b.n_beams}; simulate on the real grid or pass --resample to put the sim "
                          "frames on the real grid")
    need = StatisticsConfig().min_shape()
    if a.n_ranges < need[0] or a.n_beams < need[1]:
        raise ConfigError(f"frames of {a.n_ranges} x {a.n_beams} are too small to diagnose; need at least "
                          f"{need[0]} ranges x {need[1]} beams")


def diagnose(sim: Sequence[SonarImage], real: Sequence[SonarImage], config: DiagnoseConfig = DiagnoseConfig(),
             progress: Callable[[str], None] | None = None) -> Diagnosis:
    started = time.perf_counter()
    say = progress or (lambda message: None)
    config.validate()
    sim = _flatten_samples(sim)
    real = _flatten_samples(real)
    check_sets(sim, real)
    names = check_effect_names(config.effects)
    sim_fit_idx, sim_hold_idx = split_indices(len(sim), config.holdout_fraction, config.seed)
    real_fit_idx, real_hold_idx = split_indices(len(real), config.holdout_fraction, config.seed + 1)
    fit_frames = [sim[i] for i in sim_fit_idx[:config.fit_frames]]
    eval_frames = [sim[i] for i in sim_hold_idx[:config.eval_frames]]
    real_fit = _images([real[i] for i in real_fit_idx[:config.real_frames]], config.normalize)
    real_hold = _images([real[i] for i in real_hold_idx[:config.real_frames]], config.normalize)

    stats_cfg = config.statistics
    real_fit_stats = frame_statistics(real_fit, stats_cfg)
    real_hold_stats = frame_statistics(real_hold, stats_cfg)
    raw_eval = corrected_images(eval_frames, [], config.search.seed, config.normalize)
    raw_stats = frame_statistics(raw_eval, stats_cfg)
    scale = FeatureScale.pooled(raw_stats, real_hold_stats)
    say(f"statistics of {len(eval_frames)} sim and {len(real_hold)} real held-out frames")

    def holdout_stats(effects: Sequence[Effect]) -> tuple[np.ndarray, Stats]:
        images = corrected_images(eval_frames, effects, config.search.seed + 1, config.normalize)
        return images, frame_statistics(images, stats_cfg)

    def holdout(effects: Sequence[Effect]) -> tuple[float, Stats | None]:
        try:
            stats = holdout_stats(effects)[1]
        except FrameError:  # an effect that produces invalid frames explains nothing
            return math.inf, None
        return headline(family_gaps(stats, real_hold_stats, scale)), stats

    def holdout_gap(effects: Sequence[Effect]) -> float:
        return holdout(effects)[0]

    families_before = family_gaps(raw_stats, real_hold_stats, scale)
    gap_before = headline(families_before)
    ci_before = bootstrap_interval(raw_stats, real_hold_stats, scale, config.bootstrap, seed=config.seed)
    auc_before = classifier_auc(raw_stats, real_hold_stats, seed=config.seed)
    say(f"gap before: {gap_before:.4g} (95% CI {ci_before[0]:.4g}..{ci_before[1]:.4g}), AUC {auc_before[0]:.3f}")

    where_real = where_features(real_hold, config.where)
    where_raw = where_features(raw_eval, config.where)
    where_scale = FeatureScale.pooled(where_raw, where_real)
    maps_before = gap_maps(where_raw, where_real, where_scale, raw_stats, real_hold_stats, scale, config.where,
                           stats_cfg.profile_bins)

    ranked_pairs = rank_effects(names, fit_frames, real_fit_stats, holdout_gap, scale, config.search, stats_cfg,
                                config.normalize, say)
    selection = greedy_select(ranked_pairs, gap_before, fit_frames, real_fit_stats, holdout, scale,
                              config.search, stats_cfg, config.max_effects, config.min_gain,
                              config.candidates_per_step, config.normalize, say, target=real_hold_stats,
                              stats_before=raw_stats,
                              significance=config.significance, bootstrap=config.bootstrap,
                              backfit=config.backfit, seed=config.seed, prune=config.prune,
                              gain_check=config.gain_check)

    after_images, after_stats = holdout_stats(selection.effects)
    families_after = family_gaps(after_stats, real_hold_stats, scale)
    gap_after = headline(families_after)
    ci_after = bootstrap_interval(after_stats, real_hold_stats, scale, config.bootstrap, seed=config.seed)
    auc_after = classifier_auc(after_stats, real_hold_stats, seed=config.seed)
    maps_after = gap_maps(where_features(after_images, config.where), where_real, where_scale, after_stats,
                          real_hold_stats, scale, config.where, stats_cfg.profile_bins)

    # What stays of the original gap: where it was and still is. Where the correction itself made things worse
    # is reported apart ("worsened_cells"), so a side effect of a fitted effect is not mistaken for the residual.
    unexplained = GapMaps(*(np.minimum(a, b) for a, b in zip(maps_before.arrays(), maps_after.arrays(),
                                                             strict=True)))
    # Real frames read without geometry (plain PNGs) carry placeholder axes; the sim frames are on the same grid.
    reference = real[real_hold_idx[0]]
    if reference.meta.get("geometry_assumed"):
        reference = eval_frames[0]
    ranked = [pair[0] for pair in ranked_pairs]
    summary = {
        "gap_measure": "mean over statistic families of the unbiased squared standardised mean difference of "
                       "per-frame features (0 = same statistics); held-out frames only",
        "gap_before": gap_before,
        "gap_before_ci95": list(ci_before),
        "classifier_auc_before": {"auc": auc_before[0], "stderr": auc_before[1]},
        "family_gaps_before": families_before,
        "where_before": _where_summary(maps_before, reference, config),
        "ranked_effects": [{"name": r.name, "params": r.params, "gap_after": r.gap_after,
                            "gap_closed": _closed(gap_before, r.gap_after), "fit_gap": r.fit_gap} for r in ranked],
        "selected": [e.name for e in selection.effects],
        "selected_params": {e.name: e.params() for e in selection.effects},
        "selection_path": [{"step": step.action, "effect": step.effect, "gap": step.gap,
                            "gap_closed": _closed(gap_before, step.gap)} for step in selection.path],
        "selection_stopped": selection.stopped,
        "gain_stand_ins": selection.stand_ins,
        "gap_after_selected": gap_after,
        "gap_after_selected_ci95": list(ci_after),
        "classifier_auc_after_selected": {"auc": auc_after[0], "stderr": auc_after[1]},
        "gap_closed": _closed(gap_before, gap_after),
        "family_gaps_after_selected": families_after,
        "residual": {
            "size": max(gap_after, 0.0),
            "fraction_of_gap_before": gap_after / gap_before if gap_before > 0 else 0.0,
            "significant": bool(ci_after[0] > 0.0),
            "families": _top_families({k: min(v, families_before[k]) for k, v in families_after.items()}),
            **_where_summary(unexplained, reference, config),
            "worsened_cells": hot_cells(maps_after.cells - maps_before.cells, reference.ranges_m,
                                        reference.azimuths_rad),
        },
        "frames": {"sim": len(sim), "real": len(real), "sim_fit_used": len(fit_frames),
                   "sim_heldout_used": len(eval_frames), "real_fit_used": len(real_fit),
                   "real_heldout_used": len(real_hold)},
        "grid": {"n_ranges": reference.n_ranges, "n_beams": reference.n_beams,
                 "range_m": [float(reference.ranges_m[0]), float(reference.ranges_m[-1])],
                 "bearing_deg": [float(np.degrees(reference.azimuths_rad[0])),
                                 float(np.degrees(reference.azimuths_rad[-1]))]},
        "normalize": config.normalize,
        "seconds": time.perf_counter() - started,
    }
    examples = {"sim": raw_eval[0], "corrected": after_images[0], "real": real_hold[0]}
    return Diagnosis(summary, maps_before, maps_after, families_before, families_after, ranked, selection.path,
                     examples)


def _closed(before: float, after: float) -> float:
    return float(1.0 - after / before) if before > 0 else 0.0


def _top_families(families: dict[str, float]) -> list[dict[str, float | str]]:
    positive = {k: max(v, 0.0) for k, v in families.items()}
    total = sum(positive.values())
    return [{"name": k, "gap": families[k], "share": positive[k] / total if total > 0 else 0.0}
            for k in sorted(positive, key=positive.get, reverse=True)]


def _where_summary(maps: GapMaps, reference: SonarImage, config: DiagnoseConfig) -> dict[str, Any]:
    n_bands = config.statistics.n_bands
    return {"cells": hot_cells(maps.cells, reference.ranges_m, reference.azimuths_rad),
            "range_bins": hot_bins(maps.range_bins, reference.ranges_m, "range_m"),
            "bearing_bins": hot_bins(maps.bearing_bins, np.degrees(reference.azimuths_rad), "bearing_deg"),
            "levels": concentration(maps.levels, level_names()),
            "bands_range": concentration(maps.bands_range, band_names(reference.n_ranges, n_bands)),
            "bands_beam": concentration(maps.bands_beam, band_names(reference.n_beams, n_bands))}


def _images(frames: Sequence[SonarImage], normalize: str) -> np.ndarray:
    return corrected_images(frames, [], 0, normalize)


def _flatten_samples(frames: Sequence[SonarImage]) -> list[SonarImage]:
    """Multi-sample frames (a translator's output) count as one frame per sample."""
    out: list[SonarImage] = []
    for frame in frames:
        if frame.intensity.ndim == 3:
            out.extend(frame.sample(i) for i in range(frame.n_samples))
        else:
            out.append(frame)
    return out
