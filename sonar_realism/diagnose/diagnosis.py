"""The whole diagnosis: gap (how big), where (which cells, levels, bands), which (effects ranked and selected, with
their stability and the ambiguous choices), how far (the gap after each effect and after the selected set), and
the residual nothing in the catalogue explains (with the fixed gain pattern that explains part of it).

Both sets are split once: fit frames (parameter estimation) and held-out frames (every gap that is reported).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence

import numpy as np

from sonar_realism.diagnose.config import MIN_FRAMES_PER_SPLIT, DiagnoseConfig, check_effect_names
from sonar_realism.diagnose.gap import (
    FeatureScale,
    Stats,
    bootstrap_interval,
    classifier_auc,
    family_gaps,
    gap_closed,
    headline,
    representative_subset,
)
from sonar_realism.diagnose.result import (
    AmbiguousGroup,
    Auc,
    Diagnosis,
    Examples,
    FrameCounts,
    GapMaps,
    Grid,
    Residual,
    SelectedEffect,
    Share,
    Step,
    Verdict,
    Where,
)
from sonar_realism.diagnose.scene_terms import SceneStart, kind_of, scene_term_starts
from sonar_realism.diagnose.where import (
    band_names,
    concentration,
    gap_maps,
    hot_bins,
    hot_cells,
    level_names,
    where_features,
)
from sonar_realism.diagnose.which import (
    CountedFrames,
    GainPattern,
    Selection,
    SelectionProblem,
    corrected_images,
    describe_pattern,
    fit_gain_pattern,
    greedy_select,
    rank_effects,
    signature_starts,
)
from sonar_realism.errors import ConfigError, FrameError
from sonar_realism.evaluate.statistics import StatisticsConfig, frame_statistics
from sonar_realism.frames import SonarImage
from sonar_realism.parallel import parallel_map
from sonar_realism.sim.effects import Effect
from sonar_realism.sim.repeated_draws import remembering_draws

# Fewer held-out frames a side than this and a bootstrap resample repeats most of them: no ranking is told apart.
MIN_FRAMES_TO_TELL = 4
GAP_MEASURE = ("mean over statistic families of the unbiased squared standardised mean difference of per-frame "
               "features (0 = same statistics); held-out frames only")


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


@remembering_draws()  # every candidate is evaluated under the same seeds: each draws the same fields again
def diagnose(sim: Sequence[SonarImage], real: Sequence[SonarImage], config: DiagnoseConfig | None = None,
             progress: Callable[[str], None] | None = None, scene: SceneStart | None = None) -> Diagnosis:
    """The diagnosis of `sim` against `real` (default config: `DiagnoseConfig()`). With `scene` (what a
    calibration says about the real setting: `SceneStart.from_calibration`), the geometry and scene terms are
    candidates beside the sensor effects, starting from there."""
    started = time.perf_counter()
    say = progress or (lambda message: None)
    config = config or DiagnoseConfig()
    config.validate()
    sim = _flatten_samples(sim)
    real = _flatten_samples(real)
    check_sets(sim, real)
    names = check_effect_names(config.effects)
    sim_fit_idx, sim_hold_idx = split_indices(len(sim), config.holdout_fraction, config.seed)
    real_fit_idx, real_hold_idx = split_indices(len(real), config.holdout_fraction, config.seed + 1)
    eval_frames = [sim[i] for i in sim_hold_idx[:config.eval_frames]]
    real_fit = _images([real[i] for i in real_fit_idx[:config.real_frames]], config.normalize)
    real_hold = _images([real[i] for i in real_hold_idx[:config.real_frames]], config.normalize)
    # each held-out frame's own range axis: a sensor's window may change from ping to ping
    real_hold_ranges = np.stack([real[i].ranges_m for i in real_hold_idx[:config.real_frames]])
    eval_ranges = np.stack([f.ranges_m for f in eval_frames])

    stats_cfg = config.statistics
    raw_eval = corrected_images(eval_frames, [], config.search.seed, config.normalize)
    # the real side's statistics are computed once, on every core: each later measurement reuses them
    real_fit_stats, real_hold_stats, raw_stats = (_statistics(images, stats_cfg, config.workers)
                                                  for images in (real_fit, real_hold, raw_eval))
    scale = FeatureScale.pooled(raw_stats, real_hold_stats)
    say(f"statistics of {len(eval_frames)} sim and {len(real_hold)} real held-out frames")
    # the parameter search sees only `fit_frames` sim frames: the ones of the fit split (among as many as are held
    # out) whose statistics' mean is the split's, not the first few, whose chance level a fit would absorb
    candidates = sim_fit_idx[:max(config.fit_frames, config.eval_frames)]
    candidate_images = _images([sim[i] for i in candidates], config.normalize)
    candidate_stats = _statistics(candidate_images, stats_cfg, config.workers)
    chosen = sorted(representative_subset(candidate_stats, config.fit_frames, scale))
    fit_frames = [sim[candidates[i]] for i in chosen]

    def holdout_images(effects: Sequence[Effect], gain: GainPattern | None = None) -> np.ndarray:
        return corrected_images(eval_frames, effects, config.search.seed + 1, config.normalize, gain)

    def holdout_stats(effects: Sequence[Effect], gain: GainPattern | None = None) -> tuple[np.ndarray, Stats]:
        images = holdout_images(effects, gain)
        return images, frame_statistics(images, stats_cfg)

    def holdout(effects: Sequence[Effect], gain: GainPattern | None = None) -> tuple[float, Stats | None]:
        try:
            stats = holdout_stats(effects, gain)[1]
        except FrameError:  # an effect that produces invalid frames explains nothing
            return math.inf, None
        return headline(family_gaps(stats, real_hold_stats, scale)), stats

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

    # Real frames read without geometry (plain PNGs) carry placeholder axes; the sim frames are on the same grid.
    reference = real[real_hold_idx[0]]
    if reference.meta.get("geometry_assumed"):
        reference = eval_frames[0]
    bearings_deg = np.degrees(reference.azimuths_rad)
    real_halves = (real_fit[0::2].mean(axis=0), real_fit[1::2].mean(axis=0))
    terms = scene_term_starts(_images(fit_frames, "max"), scene) if scene is not None else {}
    names = [*names, *terms]
    starts = signature_starts(real_fit, candidate_images[chosen], reference.ranges_m, bearings_deg)
    # the signature finds count on both splits: as many sim frames of the fit split as are held out
    counted_sim = [sim[i] for i in sim_fit_idx[:len(eval_frames)]] + eval_frames
    real_fit_ranges = np.stack([real[i].ranges_m for i in real_fit_idx[:config.real_frames]])
    counted = CountedFrames(
        np.concatenate([real_fit, real_hold]),
        lambda effects: corrected_images(counted_sim, effects, config.search.seed + 2, config.normalize),
        np.concatenate([real_fit_ranges, real_hold_ranges]), np.stack([f.ranges_m for f in counted_sim]))
    problem = SelectionProblem(fit_frames, real_fit_stats, real_halves, scale, holdout, real_hold_stats, raw_stats,
                               gap_before, reference.ranges_m, bearings_deg, terms,
                               real_images=real_hold, sim_images=holdout_images, real_ranges_m=real_hold_ranges,
                               sim_ranges_m=eval_ranges, signature_starts=starts, counted=counted)
    enough = min(len(eval_frames), len(real_hold)) >= MIN_FRAMES_TO_TELL
    if enough:
        ranked = rank_effects(names, problem, config, say)
        selection = greedy_select(ranked, problem, config, say)
    else:
        ranked = []
        selection = Selection([], [Step("start", "none", gap_before)],
                              f"not enough frames to tell: {len(eval_frames)} sim and {len(real_hold)} real "
                              f"held-out frames, fewer than {MIN_FRAMES_TO_TELL} a side", [], gap_before, raw_stats)

    after_images, after_stats = holdout_stats(selection.effects)
    families_after = family_gaps(after_stats, real_hold_stats, scale)
    gap_after = headline(families_after)
    ci_after = bootstrap_interval(after_stats, real_hold_stats, scale, config.bootstrap, seed=config.seed)
    auc_after = classifier_auc(after_stats, real_hold_stats, seed=config.seed)
    maps_after = gap_maps(where_features(after_images, config.where), where_real, where_scale, after_stats,
                          real_hold_stats, scale, config.where, stats_cfg.profile_bins)

    # A fixed gain pattern on top of the selected effects: what of the residual a gain explains, and where.
    gain_pattern = None
    if enough:
        pattern = fit_gain_pattern(problem, selection.effects, config)
        gap_with_pattern = holdout(selection.effects, pattern)[0]
        if gap_with_pattern < gap_after:
            share = gap_closed(gap_before, gap_with_pattern) - gap_closed(gap_before, gap_after)
            gain_pattern = describe_pattern(pattern, reference.ranges_m, bearings_deg, gap_with_pattern, share)
            say(f"a fixed gain pattern explains {100 * gain_pattern.share_of_gap:.0f}% of the gap before on top of "
                f"the selected effects: {gain_pattern.describe()}")

    # What stays of the original gap: where it was and still is. Where the correction itself made things worse
    # is reported apart ("worsened_cells"), so a side effect of a fitted effect is not mistaken for the residual.
    unexplained = GapMaps(*(np.minimum(a, b) for a, b in zip(maps_before.arrays(), maps_after.arrays(),
                                                             strict=True)))
    residual = Residual(
        size=max(gap_after, 0.0),
        fraction_of_gap_before=gap_after / gap_before if gap_before > 0 else 0.0,
        significant=bool(ci_after[0] > 0.0),
        families=_top_families({k: min(v, families_before[k]) for k, v in families_after.items()}),
        where=_where(unexplained, reference, config),
        worsened_cells=hot_cells(maps_after.cells - maps_before.cells, reference.ranges_m, reference.azimuths_rad),
        gain_pattern=gain_pattern)
    ambiguous = _ambiguous_groups(selection.path, gap_before, config.ambiguity,
                                  [e.name for e in selection.effects])
    verdict: Verdict = ("not_enough_frames" if not enough else "residual_only" if not selection.effects
                        else "ambiguous" if ambiguous else "selected")
    return Diagnosis(
        verdict=verdict,
        gap_measure=GAP_MEASURE,
        gap_before=gap_before,
        gap_before_ci95=ci_before,
        classifier_auc_before=Auc(*auc_before),
        family_gaps_before=families_before,
        where_before=_where(maps_before, reference, config),
        ranked_effects=tuple(solo.ranked for solo in ranked),
        selected=tuple(e.name for e in selection.effects),
        selected_effects=_selected_effects(selection, gap_before),
        ambiguous=ambiguous,
        selection_path=tuple(selection.path),
        selection_stopped=selection.stopped,
        gain_stand_ins=tuple(selection.stand_ins),
        gap_after_selected=gap_after,
        gap_after_selected_ci95=ci_after,
        classifier_auc_after_selected=Auc(*auc_after),
        gap_closed=gap_closed(gap_before, gap_after),
        family_gaps_after_selected=families_after,
        residual=residual,
        maps_before=maps_before,
        maps_after=maps_after,
        frames=FrameCounts(len(sim), len(real), len(fit_frames), len(eval_frames), len(real_fit), len(real_hold)),
        grid=Grid(reference.n_ranges, reference.n_beams,
                  (float(reference.ranges_m[0]), float(reference.ranges_m[-1])),
                  (float(bearings_deg[0]), float(bearings_deg[-1]))),
        normalize=config.normalize,
        bootstrap_resamples=config.bootstrap,
        seconds=time.perf_counter() - started,
        scene_start=scene,
        unconfirmed=tuple(selection.unconfirmed),
        found=tuple(selection.found),
        examples=Examples(raw_eval[0], after_images[0], real_hold[0]))


def _statistics(images: np.ndarray, config: StatisticsConfig, workers: int) -> dict[str, np.ndarray]:
    """frame_statistics of many frames, in `workers` chunks side by side (rows in frame order)."""
    chunks = np.array_split(np.arange(len(images)), max(1, min(workers, len(images) // 8)))
    parts = parallel_map(lambda index: frame_statistics(images[index], config), chunks, workers)
    return {family: np.concatenate([part[family] for part in parts]) for family in parts[0]}


def _selected_effects(selection: Selection, gap_before: float) -> tuple[SelectedEffect, ...]:
    """Each selected effect with the share of the gap before it closed when added and its step's stability (NaN
    for one found by its signature: no rival was weighed against it)."""
    added = {}
    previous = gap_before
    for step in selection.path:
        if step.action in ("add", "found"):
            chosen = next((a for a in step.alternatives if a.effect == step.effect), None)
            added[step.effect] = ((previous - step.gap) / gap_before if gap_before > 0 else 0.0,
                                  chosen.frequency if chosen else math.nan)
        previous = step.gap
    return tuple(SelectedEffect(e.name, e.params(), *added.get(e.name, (0.0, math.nan)), kind_of(e))
                 for e in selection.effects)


def _ambiguous_groups(path: Sequence[Step], gap_before: float, threshold: float,
                      selected: Sequence[str]) -> tuple[AmbiguousGroup, ...]:
    """Steps that named a selected effect but could not tell it from others: a rival the pick was not told apart
    from (`Alternative.separated`), or the pick winning fewer than 1 - `threshold` of the resamples (one rival or
    several together winning more than `threshold`). The group is the pick, every rival not told apart and, when
    the pick wins too rarely, every rival that won at least half of `threshold` (at least the strongest), each with
    the share of the gap before it would close at that step. A step whose pick was later pruned or replaced by a
    gain pattern names nothing."""
    groups = []
    previous = gap_before
    for index, step in enumerate(path):
        if step.action == "add" and step.effect in selected:
            pick = next(a for a in step.alternatives if a.effect == step.effect)
            rivals = sorted((a for a in step.alternatives if a.effect != step.effect), key=lambda a: a.gap)
            close = {a.effect for a in rivals if not a.separated}
            winning = sorted((a for a in rivals if a.frequency > 0), key=lambda a: -a.frequency)
            if winning and pick.frequency < 1.0 - threshold:
                close |= {a.effect for a in winning if a.frequency >= threshold / 2} or {winning[0].effect}
            if close:
                members = (pick, *(a for a in rivals if a.effect in close))
                shares = tuple((previous - a.gap) / gap_before if gap_before > 0 else 0.0 for a in members)
                groups.append(AmbiguousGroup(index, members, shares))
        previous = step.gap
    return tuple(groups)


def _top_families(families: dict[str, float]) -> tuple[Share, ...]:
    positive = {k: max(v, 0.0) for k, v in families.items()}
    total = sum(positive.values())
    return tuple(Share(k, families[k], positive[k] / total if total > 0 else 0.0)
                 for k in sorted(positive, key=positive.get, reverse=True))


def _where(maps: GapMaps, reference: SonarImage, config: DiagnoseConfig) -> Where:
    n_bands = config.statistics.n_bands
    return Where(cells=hot_cells(maps.cells, reference.ranges_m, reference.azimuths_rad),
                 range_bins=hot_bins(maps.range_bins, reference.ranges_m),
                 bearing_bins=hot_bins(maps.bearing_bins, np.degrees(reference.azimuths_rad)),
                 levels=concentration(maps.levels, level_names()),
                 bands_range=concentration(maps.bands_range, band_names(reference.n_ranges, n_bands)),
                 bands_beam=concentration(maps.bands_beam, band_names(reference.n_beams, n_bands)))


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
