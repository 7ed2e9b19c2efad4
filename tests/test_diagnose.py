"""Gap measures, where-maps, the diagnosis on a planted effect, the CLI end to end, and bad input."""

import dataclasses
import json
import math
from collections.abc import Callable, Sequence

import numpy as np
import pytest

from sonar_realism.cli import main
from sonar_realism.diagnose import DiagnoseConfig, diagnose, load_diagnosis
from sonar_realism.diagnose.arcs import LINE_DB, check_arcs, find_lines, interference_from_lines, line_strength
from sonar_realism.diagnose.config import SearchConfig
from sonar_realism.diagnose.diagnosis import _ambiguous_groups, split_indices
from sonar_realism.diagnose.gap import (
    FeatureScale,
    best_frequency,
    bootstrap_gain,
    bootstrap_interval,
    classifier_auc,
    family_gaps,
    gap,
)
from sonar_realism.diagnose.ghost import check_ghost, range_lag_correlation
from sonar_realism.diagnose.leakage import check_leakage
from sonar_realism.diagnose.near_field import find_ring_down, ring_down_from_excess
from sonar_realism.diagnose.peaks import check_peaks, peak_sharpness
from sonar_realism.diagnose.report import sections, write_figures
from sonar_realism.diagnose.result import Alternative, RankedEffect, Step, Unconfirmed, write_diagnosis
from sonar_realism.diagnose.smear import check_smear
from sonar_realism.diagnose.where import WhereConfig, gap_maps, hot_bins, hot_cells, where_features
from sonar_realism.diagnose.which import (
    CountedFrames,
    Selection,
    SelectionProblem,
    Solo,
    carries_counts,
    coordinate_search,
    corrected_images,
    fit_effect,
    greedy_select,
    physics_off,
    rank_effects,
    signature_starts,
)
from sonar_realism.errors import ConfigError
from sonar_realism.evaluate.statistics import StatisticsConfig, frame_statistics
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.io import write_frames
from sonar_realism.report_html import Text
from sonar_realism.sim import SensorConfig, simulate
from sonar_realism.sim.effects import BeamSidelobes, Effect, RingDown, apply_effects, make_effect

SENSOR = SensorConfig(n_ranges=128, n_beams=128, max_range_m=10.0, elevation_rays=16)
PEDESTAL_OFF = BeamSidelobes.PARAM_BOUNDS["crosstalk_db"][0]
FAST = DiagnoseConfig(fit_frames=4, eval_frames=8, bootstrap=30, search=SearchConfig(points=4, rounds=1))
# Selection tests whose held-out judge is a table of gaps: the last finer search (a fit on the fit split) is left
# out, as the table would not follow it.
TABLE_JUDGED = DiagnoseConfig(max_effects=1, prune=False, gain_check=False, polish_rounds=0)


def sim_frames(n: int, seed: int) -> list[SonarImage]:
    return [frame for frame, _ in simulate(n=n, seed=seed, sensor=SENSOR)]


def speckled(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(rng.rayleigh(0.2, (n, 128, 128)), 0, 1).astype(np.float32)


def test_gap_is_near_zero_for_one_distribution_and_large_for_two():
    a, b = frame_statistics(speckled(12, 0)), frame_statistics(speckled(12, 1))
    c = frame_statistics(np.sqrt(speckled(12, 2)))
    scale = FeatureScale.pooled(a, c)
    same, different = gap(a, b, scale), gap(a, c, scale)
    assert abs(same) < 0.1
    assert different > 1.0
    lo, hi = bootstrap_interval(a, c, scale, n_boot=50)
    assert lo < different < hi
    assert set(family_gaps(a, c, scale)) == set(a)
    assert classifier_auc(a, c)[0] > 0.95
    assert classifier_auc(a, b)[0] < 0.85


def test_where_map_points_at_the_cell_that_differs():
    real = speckled(8, 3)
    sim = speckled(8, 4)
    real[:, 32:48, 96:112] *= 2.5  # something only the real frames have, in range cell 2, bearing cell 6 (of 8)
    real = np.clip(real, 0, 1)
    config = WhereConfig()
    wa, wb = where_features(sim, config), where_features(real, config)
    sa, sb = frame_statistics(sim), frame_statistics(real)
    maps = gap_maps(wa, wb, FeatureScale.pooled(wa, wb), sa, sb, FeatureScale.pooled(sa, sb), config)
    hottest = hot_cells(maps.cells, uniform_ranges(128, 10.0), uniform_azimuths(128, 2.0), top=1)[0]
    assert (hottest.range_cell, hottest.bearing_cell) == (2, 6)
    assert 2.5 <= hottest.range_m[0] <= hottest.range_m[1] <= 3.8


def test_paired_gain_is_significant_only_for_a_real_improvement():
    target = frame_statistics(np.sqrt(speckled(12, 5)))
    raw = speckled(12, 6)
    before, better = frame_statistics(raw), frame_statistics(np.sqrt(raw))
    scale = FeatureScale.pooled(before, target)
    gain, lower = bootstrap_gain(before, better, target, scale, n_boot=50)
    assert gain > 0.5 and lower > 0.0
    gain, lower = bootstrap_gain(before, before, target, scale, n_boot=50)
    assert gain == 0.0 and lower <= 0.0


def test_a_gain_in_one_family_is_significant_through_the_noise_a_correction_adds_to_another():
    # family "a" moves onto the target in every frame; the correction also jitters family "b" (a ring-down's bright
    # rows in the speckle statistics), which widens the headline's interval below 0
    rng = np.random.default_rng(0)
    target = {f: rng.normal(0, 1, (20, 3)) for f in "abcdef"}
    before = {f: rng.normal(0, 1, (20, 3)) for f in "abcdef"}
    before["a"] = target["a"] + 1.0
    after = {**before, "a": target["a"], "b": before["b"] + rng.normal(0.6, 3.0, (20, 3))}
    scale = FeatureScale.pooled(before, target)
    gain, lower = bootstrap_gain(before, after, target, scale, n_boot=200)
    headline = np.array([gap({f: v[i] for f, v in before.items()}, {f: v[j] for f, v in target.items()}, scale)
                         - gap({f: v[i] for f, v in after.items()}, {f: v[j] for f, v in target.items()}, scale)
                         for i, j in (np.random.default_rng(k).integers(0, 20, (2, 20)) for k in range(200))])
    assert np.quantile(headline, 0.05) - headline.mean() + gain < 0.0  # the headline alone: not significant
    assert 0.0 < lower < gain


def test_where_maps_point_at_a_narrow_band_by_range_bin():
    real = speckled(8, 7)
    real[:, 80:84, :] = np.clip(real[:, 80:84, :] + 0.5, 0, 1)  # a bright band 4 bins wide, rows 80-83 of 128
    sim = speckled(8, 8)
    config = WhereConfig()
    wa, wb = where_features(sim, config), where_features(real, config)
    sa, sb = frame_statistics(sim), frame_statistics(real)
    maps = gap_maps(wa, wb, FeatureScale.pooled(wa, wb), sa, sb, FeatureScale.pooled(sa, sb), config)
    ranges = uniform_ranges(128, 10.0)
    top = hot_bins(maps.range_bins, ranges, top=1)[0]
    assert top.bin == 20  # 32 bins of 4 rows: rows 80-83
    assert top.span[0] <= ranges[81] <= top.span[1]


def test_diagnosis_finds_a_planted_catalogue_effect_and_closes_the_gap():
    sim = sim_frames(10, seed=1)
    noise = make_effect("tvg_noise", noise_amplitude=0.2)
    rng = np.random.default_rng(0)
    real = [apply_effects(f, [noise], rng) for f in sim_frames(10, seed=2)]
    config = dataclasses.replace(FAST, effects=("tvg_noise", "ring_down"))
    result = diagnose(sim, real, config)
    assert result.ranked_effects[0].name == "tvg_noise"
    assert result.selected[0] == "tvg_noise"
    assert result.gap_after_selected < 0.3 * result.gap_before
    assert result.ranked_effects[0].params["noise_amplitude"] == pytest.approx(0.2, abs=0.12)
    assert result.verdict == "selected" and result.ambiguous == ()
    chosen = result.selected_effects[0]
    assert chosen.stability > 0.8 and chosen.share > 0.5  # told apart from ring_down in every resample


def test_the_draw_memo_leaves_a_diagnosis_bit_identical_on_every_core():
    sim = sim_frames(10, seed=1)
    real = [apply_effects(f, [make_effect("speckle", shape_nu=3.0, looks=2.5)], np.random.default_rng(0))
            for f in sim_frames(10, seed=2)]
    config = dataclasses.replace(FAST, effects=("speckle", "tvg_noise"), workers=2)
    remembered, plain = ({**run(sim, real, config).to_json(), "seconds": 0.0}
                         for run in (diagnose, diagnose.__wrapped__))
    assert remembered["selected"] and remembered == plain


def test_a_plain_gain_difference_is_not_blamed_on_an_effect():
    # "Real" = the sim's world 3 dB darker, falling a further 4 dB towards the far range. The TVG ramp or the
    # quantiser's gain can mimic that, but a plain gain profile does as well, so no effect is blamed for it.
    real = []
    for frame in sim_frames(10, seed=2):
        t = (frame.ranges_m - frame.ranges_m[0]) / (frame.ranges_m[-1] - frame.ranges_m[0])
        gain = (10 ** ((-3.0 - 4.0 * t) / 20)).astype(np.float32)[:, None]
        real.append(frame.replace(intensity=frame.normalized() * gain, intensity_scale=1.0))
    config = dataclasses.replace(FAST, effects=("tvg_noise", "gamma_quantization", "ring_down"))
    unchecked = diagnose(sim_frames(10, seed=1), real, dataclasses.replace(config, gain_check=False))
    assert unchecked.selected != ()  # without the check, an effect's gain parameter takes the blame
    result = diagnose(sim_frames(10, seed=1), real, config)
    assert result.selected == ()
    assert {s.effect for s in result.gain_stand_ins} == set(unchecked.selected)
    assert result.selection_path[-1].action == "gain_stand_in"
    assert result.residual.significant
    assert result.verdict == "residual_only"
    pattern = result.residual.gain_pattern  # reported as the residual's gain pattern: darker overall
    assert pattern is not None and pattern.share_of_gap > 0.2 and pattern.level_db < -1.0


def striped(frames: list[SonarImage], beams: np.ndarray, gains_db: np.ndarray) -> list[SonarImage]:
    """Fixed channel gain errors: the given beams `gains_db` off, every frame (a fault outside the catalogue)."""
    gain = np.ones(frames[0].n_beams, dtype=np.float32)
    gain[beams] = 10 ** (gains_db / 20)
    return [f.replace(intensity=np.clip(f.normalized() * gain[None, :], 0, 1), intensity_scale=1.0) for f in frames]


def test_column_stripes_are_left_unexplained_at_their_beams():
    # Sim and "real" alternate along one trajectory; "real" has six channels with fixed gain errors. No catalogued
    # effect may take the blame (elevation_spread did before the gain pattern had a per-beam shape), and the
    # residual's gain pattern must point at those beams.
    frames = sim_frames(24, seed=3)
    beams = np.array([14, 37, 61, 80, 99, 117])
    gains_db = np.array([6.0, -6.0, 5.0, -5.0, 6.0, -6.0])
    # 8 fit frames, not FAST's 4: the shape is kept only where two halves of the fit frames agree, and with two
    # frames a half a scene's near-range rock decided it (on the 2026-11-23 machine the 4-frame fit chose other
    # frames and kept no shape at all, at every commit; with 6 or 8 all six channels are found)
    config = dataclasses.replace(FAST, fit_frames=8, effects=("elevation_spread", "tvg_noise", "beam_sidelobes"))
    result = diagnose(frames[0::2], striped(frames[1::2], beams, gains_db), config)
    assert result.selected == ()
    pattern = result.residual.gain_pattern
    assert pattern is not None
    found = {spot.index for spot in pattern.beams}
    assert sum(any(abs(b - f) <= 1 for f in found) for b in beams) >= 5
    for spot in pattern.beams:
        if spot.index in beams:
            assert np.sign(spot.gain_db) == np.sign(gains_db[list(beams).index(spot.index)])


def test_a_fixed_band_of_added_power_is_left_unexplained_at_its_ranges():
    # Sim and "real" alternate along one trajectory; "real" has a band of added power at fixed rows in every frame
    # (a reflection inside the housing, outside the catalogue). No effect may take the blame, and the residual's
    # pattern must name the band's ranges and about its amplitude.
    frames = sim_frames(24, seed=5)
    rows, amplitude = (80, 85), 0.4
    real = []
    for frame in frames[1::2]:
        x = frame.normalized().copy()
        x[rows[0]:rows[1]] = np.sqrt(x[rows[0]:rows[1]] ** 2 + amplitude ** 2)
        real.append(frame.replace(intensity=x, intensity_scale=1.0))
    config = dataclasses.replace(FAST, effects=("beam_sidelobes", "interference", "multipath", "ring_down"))
    result = diagnose(frames[0::2], real, config)
    assert result.selected == ()
    pattern = result.residual.gain_pattern
    assert pattern is not None and pattern.band_m is not None
    ranges = frames[0].ranges_m
    assert pattern.band_m[0] <= ranges[rows[1] - 1] and pattern.band_m[1] >= ranges[rows[0]]
    assert pattern.band_amplitude == pytest.approx(amplitude, rel=0.3)
    assert "added power at" in pattern.describe()


def test_an_effect_with_its_own_physics_off_is_only_a_gain():
    assert physics_off(make_effect("tvg_noise", noise_amplitude=0.0)) == ("noise_amplitude",)
    assert physics_off(make_effect("tvg_noise", noise_amplitude=0.1)) == ()
    assert physics_off(make_effect("water_column", haze_level=0.001)) == ("haze_level",)
    assert physics_off(make_effect("water_column", haze_level=0.04)) == ()
    assert physics_off(make_effect("speckle")) == ()  # no reduction to a gain declared


def test_8_bit_counts_in_the_real_frames_keep_an_output_mapping_a_gain_pattern_would_stand_in_for():
    # A held-out judge given as a table: the output mapping closes most of the gap, and a gain pattern in its
    # place closes more. Where the real frames are 8-bit counts, as the frames with the mapping are and the
    # frames with the pattern are not, the pattern cannot be what the real frames show: the mapping is kept.
    frames = sim_frames(4, seed=3)
    images = np.stack([f.normalized() for f in frames])
    floats, counts = frame_statistics(images), frame_statistics(np.round(images * 255) / 255)
    mapping = make_effect("gamma_quantization", gamma=1.0)

    def select(target):
        def holdout(effects, gain=None):
            if gain is not None:
                return 0.1, floats
            return (0.2, counts) if effects else (1.0, floats)

        problem = SelectionProblem(frames[:2], target, (np.zeros((128, 128)),) * 2, FeatureScale.pooled(floats, counts),
                                   holdout, target, floats, 1.0, frames[0].ranges_m, np.degrees(frames[0].azimuths_rad))
        ranked = [Solo(RankedEffect("gamma_quantization", mapping.params(), 0.2, 0.0, 0.8, 1.0), mapping, counts)]
        config = DiagnoseConfig(search=SearchConfig(points=2, rounds=1), max_effects=1, significance=0.0,
                                backfit=False, prune=False, polish_rounds=0)
        return greedy_select(ranked, problem, config)

    assert [e.name for e in select(counts).effects] == ["gamma_quantization"]
    assert [(s.action, s.effect) for s in select(floats).path][-1] == ("gain_stand_in", "gamma_quantization")
    assert carries_counts(counts) and not carries_counts(floats)


def test_bootstrap_frequency_splits_between_equals_and_goes_to_the_clearly_better():
    target = frame_statistics(np.sqrt(speckled(12, 5)))
    raw = speckled(12, 6)
    before, better = frame_statistics(raw), frame_statistics(np.sqrt(raw))
    scale = FeatureScale.pooled(before, target)
    assert best_frequency([before, better], target, scale, 50).tolist() == [0.0, 1.0]
    twin = frame_statistics(np.sqrt(raw) * 1.0001)
    tied = best_frequency([better, twin, None], target, scale, 50)
    assert 0.0 < tied[0] < 1.0 and tied[2] == 0.0 and tied.sum() == pytest.approx(1.0)


def test_a_step_whose_runner_up_wins_often_is_reported_as_ambiguous():
    step_one = (Alternative("motion_blur", 0.40, 0.55), Alternative("range_blur", 0.42, 0.40),
                Alternative("speckle", 0.9, 0.05))
    path = [Step("start", "none", 1.0), Step("add", "motion_blur", 0.40, step_one),
            Step("add", "tvg_noise", 0.20, (Alternative("tvg_noise", 0.20, 0.95), Alternative("speckle", 0.35, 0.05)))]
    groups = _ambiguous_groups(path, 1.0, threshold=0.2, selected=["motion_blur", "tvg_noise"])
    assert len(groups) == 1 and groups[0].step == 1
    assert [a.effect for a in groups[0].effects] == ["motion_blur", "range_blur"]
    assert groups[0].shares == pytest.approx((0.60, 0.58))


def test_a_pick_that_several_rivals_share_is_ambiguous_and_a_removed_pick_names_nothing():
    # no single rival wins 20 % of the resamples, but together they win 30 %: the pick is not a confident name
    spread = (Alternative("motion_blur", 0.40, 0.70), Alternative("range_blur", 0.42, 0.15),
              Alternative("beam_sidelobes", 0.43, 0.12), Alternative("speckle", 0.9, 0.03))
    close_call = (Alternative("multipath", 0.30, 0.6), Alternative("interference", 0.31, 0.4))
    path = [Step("start", "none", 1.0), Step("add", "motion_blur", 0.40, spread),
            Step("add", "multipath", 0.30, close_call), Step("gain_stand_in", "multipath", 0.40)]
    groups = _ambiguous_groups(path, 1.0, threshold=0.2, selected=["motion_blur"])
    assert [[a.effect for a in g.effects] for g in groups] == [["motion_blur", "range_blur", "beam_sidelobes"]]
    assert _ambiguous_groups(path, 1.0, threshold=0.2, selected=["motion_blur", "multipath"])[1].step == 2


def test_too_few_frames_give_no_ranking_but_say_so():
    sim, real = sim_frames(5, seed=1), sim_frames(5, seed=2)
    result = diagnose(sim, real, dataclasses.replace(FAST, effects=("tvg_noise",)))
    assert result.verdict == "not_enough_frames"
    assert result.ranked_effects == () and result.selected == ()
    assert "not enough frames" in result.selection_stopped


def test_pruning_drops_an_effect_the_later_ones_make_redundant():
    # A held-out objective given as a table: A helps alone, B helps more, and with B chosen A adds nothing.
    frames = sim_frames(4, seed=3)
    stats = frame_statistics(np.stack([f.normalized() for f in frames]))
    scale = FeatureScale.pooled(stats, stats)
    a, b = make_effect("motion_blur"), make_effect("beam_sidelobes")
    table = {(): 1.0, ("motion_blur",): 0.6, ("beam_sidelobes",): 0.31, ("beam_sidelobes", "motion_blur"): 0.3}

    def holdout(effects, gain=None):
        return table[tuple(sorted(e.name for e in effects))], None

    ranked = [Solo(RankedEffect("motion_blur", a.params(), 0.6, 0.0, 0.4, 1.0), a, None),
              Solo(RankedEffect("beam_sidelobes", b.params(), 0.7, 0.0, 0.3, 0.0), b, None)]
    problem = SelectionProblem(frames[:2], stats, (np.zeros((128, 128)),) * 2, scale, holdout, None, None, 1.0,
                               frames[0].ranges_m, np.degrees(frames[0].azimuths_rad))
    config = DiagnoseConfig(search=SearchConfig(points=2, rounds=1), statistics=StatisticsConfig(), max_effects=3,
                            min_gain=0.05, candidates_per_step=2, backfit=False, gain_check=False,
                            polish_rounds=0)
    pruned = greedy_select(ranked, problem, config)
    assert [(s.action, s.effect) for s in pruned.path] == [
        ("start", "none"), ("add", "motion_blur"), ("add", "beam_sidelobes"), ("remove", "motion_blur")]
    assert [e.name for e in pruned.effects] == ["beam_sidelobes"]
    assert pruned.path[-1].gap == 0.31
    kept = greedy_select(ranked, problem, dataclasses.replace(config, prune=False))
    assert [e.name for e in kept.effects] == ["motion_blur", "beam_sidelobes"]


def first_step_with_a_rival(pick: Effect, rival: Effect, rival_gap: float, real_effect: Effect,
                            without_pedestal_gap: float = 0.6, others: tuple[tuple[Effect, float], ...] = (),
                            frames: list[SonarImage] | None = None) -> Selection:
    """One selection step on 8 sim frames (or `frames`) whose held-out objective is a table: `pick` closes 70 % of
    the gap, `rival` leaves `rival_gap` (and each of `others` its gap), sidelobes with their cross-talk pedestal off
    leave `without_pedestal_gap`; the real frames are the sim's with `real_effect`, for the signature checks."""
    frames = frames or sim_frames(8, seed=3)
    stats = frame_statistics(np.stack([f.normalized() for f in frames]))
    scale = FeatureScale.pooled(stats, stats)

    def images(effects) -> np.ndarray:
        return np.stack([apply_effects(f, list(effects), np.random.default_rng(i)).normalized()
                         for i, f in enumerate(frames)])

    table = {(): 1.0, (pick.name,): 0.3, (rival.name,): rival_gap, **{(e.name,): g for e, g in others}}

    def holdout(effects, gain=None):
        if any(isinstance(e, BeamSidelobes) and e.crosstalk_db <= PEDESTAL_OFF for e in effects):
            return without_pedestal_gap, None
        return table.get(tuple(sorted(e.name for e in effects)), 0.29), None

    ranked = [Solo(RankedEffect(pick.name, pick.params(), 0.3, 0.0, 0.7, 1.0), pick, None),
              *(Solo(RankedEffect(e.name, e.params(), g, 0.0, 1 - g, 0.0), e, None)
                for e, g in [(rival, rival_gap), *others])]
    problem = SelectionProblem(frames[:2], stats, (np.zeros(frames[0].intensity.shape),) * 2, scale, holdout, None,
                               None, 1.0, frames[0].ranges_m, np.degrees(frames[0].azimuths_rad),
                               real_images=images([real_effect]), sim_images=images)
    config = DiagnoseConfig(search=SearchConfig(points=2, rounds=1), statistics=StatisticsConfig(),
                            max_effects=1, min_gain=0.05, backfit=False, prune=False, gain_check=False,
                            polish_rounds=0)
    return greedy_select(ranked, problem, config)


def test_sidelobes_whose_leakage_the_real_frames_lack_give_way_to_a_rival_that_explains_the_gap():
    # Strong sidelobes close most, a noise floor a little less. Real frames with a noise floor lack the lift the
    # fitted sidelobes put on bright rows' dark beams, so the floor is named; real frames with those sidelobes show
    # it, and sidelobes are named; with no rival that passes the step's tests the sidelobes are named whatever the
    # check says.
    sidelobes = make_effect("beam_sidelobes", sidelobe_db=-10.0, crosstalk_db=-15.0)
    floor = make_effect("tvg_noise", noise_amplitude=0.15)
    yielded = first_step_with_a_rival(sidelobes, floor, 0.4, floor)
    assert [e.name for e in yielded.effects] == ["tvg_noise"]
    assert [(s.action, s.effect) for s in yielded.path] == [
        ("start", "none"), ("unconfirmed", "beam_sidelobes"), ("add", "tvg_noise")]
    assert yielded.unconfirmed[0].signature.startswith("leakage along the row")
    assert [e.name for e in first_step_with_a_rival(sidelobes, floor, 0.4, sidelobes).effects] == ["beam_sidelobes"]
    # the rival closes too little
    assert [e.name for e in first_step_with_a_rival(sidelobes, floor, 0.98, floor).effects] == ["beam_sidelobes"]


def test_sidelobes_whose_pedestal_the_real_frames_lack_are_refitted_without_it_and_named():
    # The fit took a strong cross-talk pedestal; the real frames have near sidelobes but no pedestal, so the
    # pedestal fails the leakage check. Refitted without it the sidelobes still beat the rival and are named, the
    # pedestal recorded as unconfirmed; where the refit closes less than the rival, the rival is named.
    fitted = make_effect("beam_sidelobes", sidelobe_db=-12.0, crosstalk_db=-20.0)
    real = make_effect("beam_sidelobes", sidelobe_db=-12.0, crosstalk_db=PEDESTAL_OFF)
    floor = make_effect("tvg_noise", noise_amplitude=0.15)
    held = first_step_with_a_rival(fitted, floor, 0.5, real, without_pedestal_gap=0.35)
    assert [e.name for e in held.effects] == ["beam_sidelobes"]
    assert held.effects[0].crosstalk_db == PEDESTAL_OFF
    assert held.path[-1].gap == 0.35
    assert [(u.effect, u.named_instead, u.params["crosstalk_db"]) for u in held.unconfirmed] == [
        ("beam_sidelobes", "beam_sidelobes", -20.0)]
    assert held.unconfirmed[0].signature.startswith("leakage along the row")
    assert [e.name for e in first_step_with_a_rival(fitted, floor, 0.5, real, 0.55).effects] == ["tvg_noise"]
    # real frames that show the pedestal keep it
    kept = first_step_with_a_rival(fitted, floor, 0.5, fitted, without_pedestal_gap=0.35)
    assert kept.effects[0].crosstalk_db == -20.0 and not kept.unconfirmed


def point_echoes(n: int, seed: int) -> list[SonarImage]:
    """Frames of 100 single-cell echoes (amplitude 0.3-0.9) each on a faint Rayleigh floor, a beam a degree."""
    rng = np.random.default_rng(seed)
    template = sim_frames(1, 0)[0]
    frames = []
    for _ in range(n):
        image = rng.rayleigh(0.005, (128, 128))
        image[rng.integers(8, 120, 100), rng.integers(4, 124, 100)] = rng.uniform(0.3, 0.9, 100)
        frames.append(template.replace(intensity=image.astype(np.float32), ranges_m=uniform_ranges(128, 10.0, 0.5),
                                       azimuths_rad=uniform_azimuths(128, math.radians(128.0)), intensity_scale=1.0))
    return frames


def test_peak_sharpness_falls_under_a_yaw_smear_and_stays_under_a_narrow_skirt():
    frames = point_echoes(8, seed=1)

    def images(*effects: Effect) -> np.ndarray:
        return np.stack([apply_effects(f, list(effects), np.random.default_rng(i)).normalized()
                         for i, f in enumerate(frames)])

    clean = images()
    skirt = images(make_effect("beam_sidelobes", mainlobe_deg=0.6, sidelobe_db=-10.0, crosstalk_db=PEDESTAL_OFF))
    smeared = images(make_effect("motion_blur", yaw_rate_deg_s=60.0, integration_s=0.3))  # an 18-beam box
    assert peak_sharpness(clean) > 25.0
    assert peak_sharpness(skirt) > 15.0 > 6.0 > peak_sharpness(smeared)
    assert math.isnan(peak_sharpness(np.zeros((2, 8, 6))))  # too narrow to have beams 3 away on both sides
    check = check_peaks(smeared, skirt)
    assert not check.confirmed and check.spread.excess > 10.0
    assert "peaks across the beams" in check.describe()
    assert check_peaks(skirt, skirt).confirmed and check_peaks(smeared, smeared).confirmed
    # the smear itself fits the smeared frames better than the skirt does; a range blur does not
    assert check.rival_fits_better(smeared)
    pulse = images(make_effect("range_blur", resolution_m=0.3, sidelobe_db=-20.0))
    assert not check.rival_fits_better(pulse)


def test_sidelobes_that_leave_the_peaks_a_yaw_smear_flattens_give_way_to_the_rival_that_flattens_them():
    # The tuning pair motion_blur + tvg_noise: sidelobes fitted at a -10 dB skirt closed a yaw smear's gap best, its
    # leakage check passed (no pedestal), and a range blur was the runner-up. The real frames' peaks stand barely
    # above the beams 3 away; the skirt leaves them sharp, so do the range blur's; the motion blur, third, flattens
    # them as the real frames show and is named. Real frames with those sidelobes keep them.
    frames = point_echoes(8, seed=1)
    skirt = make_effect("beam_sidelobes", mainlobe_deg=0.6, sidelobe_db=-10.0, crosstalk_db=PEDESTAL_OFF)
    pulse = make_effect("range_blur", resolution_m=0.3, sidelobe_db=-20.0)
    turning = make_effect("motion_blur", yaw_rate_deg_s=60.0, integration_s=0.3)
    yielded = first_step_with_a_rival(skirt, pulse, 0.4, turning, others=((turning, 0.45),), frames=frames)
    assert [(s.action, s.effect) for s in yielded.path] == [
        ("start", "none"), ("unconfirmed", "beam_sidelobes"), ("add", "motion_blur")]
    assert yielded.unconfirmed[0].signature.startswith("peaks across the beams")
    assert yielded.unconfirmed[0].named_instead == "motion_blur"
    kept = first_step_with_a_rival(skirt, pulse, 0.4, skirt, others=((turning, 0.45),), frames=frames)
    assert [e.name for e in kept.effects] == ["beam_sidelobes"] and not kept.unconfirmed
    # no rival flattens the peaks: the sidelobes are named whatever the check says
    alone = first_step_with_a_rival(skirt, pulse, 0.4, turning, frames=frames)
    assert [e.name for e in alone.effects] == ["beam_sidelobes"]


def test_a_multipath_whose_ghost_the_real_frames_lack_gives_way_to_a_rival_that_explains_the_gap():
    # A multipath whose ghosts interfere with the direct return adds speckle-like texture, so on real frames with
    # more speckle it can close the most (tuning half 1, speckle + gamma: picked over speckle, then dropped for
    # want of its ghost, and the speckle was lost). Picked without its ghost it yields to its step's runner-up;
    # real frames with the ghost keep it.
    ghost = make_effect("multipath", reflection_coeff=0.7, ghost_offset_m=2.0, coherence=1.0)
    grain = make_effect("speckle", shape_nu=1.5)
    yielded = first_step_with_a_rival(ghost, grain, 0.4, grain)
    assert [(s.action, s.effect) for s in yielded.path] == [
        ("start", "none"), ("unconfirmed", "multipath"), ("add", "speckle")]
    assert yielded.unconfirmed[0].signature.startswith("a ghost")
    assert [e.name for e in first_step_with_a_rival(ghost, grain, 0.4, ghost).effects] == ["multipath"]


def test_between_the_two_blurs_the_axis_of_the_real_smoothing_decides():
    # A motion blur fitted with its surge is a box along range and can close a range blur's gap best; a range blur
    # can close a turning platform's. Picked over the other blur, each yields when the real frames are smoothed
    # along the other's axis, and is kept when they are smoothed along its own. Against any other rival the axis
    # is not asked.
    pulse = make_effect("range_blur", resolution_m=0.3, sidelobe_db=-20.0)
    turning = make_effect("motion_blur", yaw_rate_deg_s=40.0, surge_m_s=0.5, integration_s=0.2)
    yielded = first_step_with_a_rival(turning, pulse, 0.4, pulse)
    assert [(s.action, s.effect) for s in yielded.path] == [
        ("start", "none"), ("unconfirmed", "motion_blur"), ("add", "range_blur")]
    assert yielded.unconfirmed[0].signature.startswith("a smear as much across the beams")
    assert yielded.unconfirmed[0].named_instead == "range_blur"
    assert [e.name for e in first_step_with_a_rival(turning, pulse, 0.4, turning).effects] == ["motion_blur"]
    assert [e.name for e in first_step_with_a_rival(pulse, turning, 0.4, turning).effects] == ["motion_blur"]
    assert [e.name for e in first_step_with_a_rival(pulse, turning, 0.4, pulse).effects] == ["range_blur"]
    grain = make_effect("speckle", shape_nu=1.5)
    assert [e.name for e in first_step_with_a_rival(turning, grain, 0.4, pulse).effects] == ["motion_blur"]


def test_smear_check_reads_a_surge_alone_as_range_smoothing_and_nothing_as_no_evidence():
    frames = sim_frames(6, seed=4)
    clean = np.stack([f.normalized() for f in frames])

    def blurred(effect: Effect) -> np.ndarray:
        return np.stack([apply_effects(f, [effect], np.random.default_rng(0)).normalized() for f in frames])

    surge = blurred(make_effect("motion_blur", yaw_rate_deg_s=0.0, surge_m_s=2.0, integration_s=0.2))
    turn = blurred(make_effect("motion_blur", yaw_rate_deg_s=40.0, surge_m_s=0.0, integration_s=0.2))
    assert check_smear("motion_blur", surge, clean).along_range > 0.3
    assert not check_smear("motion_blur", surge, clean).confirmed and check_smear("range_blur", surge, clean).confirmed
    assert check_smear("motion_blur", turn, clean).confirmed and not check_smear("range_blur", turn, clean).confirmed
    # no smoothing on either axis: nothing to read, no verdict against either blur
    assert check_smear("motion_blur", clean, clean).confirmed and check_smear("range_blur", clean, clean).confirmed


def scattered_corrections():
    """Held-out statistics of a target, of the frames before correction, their scale, and `corrected(power,
    spread)`: the statistics of a correction that lowers the gap more with a lower `power`, scattered from frame to
    frame by `spread`."""
    target = frame_statistics(np.sqrt(speckled(12, 5)))
    raw = speckled(12, 6)
    before = frame_statistics(raw)
    scatter = np.exp(np.random.default_rng(7).standard_normal(12))[:, None, None]

    def corrected(power: float, spread: float):
        return frame_statistics(np.clip(raw ** power * scatter ** spread, 0, 1).astype(np.float32))

    return target, before, FeatureScale.pooled(before, target), corrected


def test_a_gain_is_named_only_if_significantly_at_least_min_gain():
    # Two corrections of the same frames, given by their held-out statistics. The scattered one lowers the gap by
    # 7.5 % of it, but with a per-frame scatter its one-sided lower bound is 1.6 %: above 0 (the old test passed it:
    # a world difference that an effect mimics a little) but below the 5 % worth naming. The steadier one (11.6 %,
    # lower bound 8.9 %) is named.
    target, before, scale, corrected = scattered_corrections()
    frames = sim_frames(2, seed=3)
    effect = make_effect("tvg_noise")

    def select(power: float, spread: float):
        after = corrected(power, spread)
        ranked = [Solo(RankedEffect("tvg_noise", effect.params(), gap(after, target, scale), 0.0, 0.0, 1.0), effect,
                       after)]
        problem = SelectionProblem(frames, target, (np.zeros((128, 128)),) * 2, scale, None, target, before,
                                   gap(before, target, scale), frames[0].ranges_m, np.degrees(frames[0].azimuths_rad))
        return greedy_select(ranked, problem, TABLE_JUDGED)

    scattered = select(0.97, 0.1)
    assert scattered.effects == [] and "not significantly by 5%" in scattered.stopped
    assert [e.name for e in select(0.96, 0.05).effects] == ["tvg_noise"]


def test_a_pick_without_its_signature_yields_to_a_rival_it_cannot_be_told_apart_from():
    # Statistics as in the test above: the pick (a motion blur) lowers the gap significantly; the rival (a range
    # blur) lowers it nearly as far but, scattered from frame to frame, not significantly by itself. The real
    # frames are smoothed along range only, so the motion blur lacks its signature, and since it is not told apart
    # from the range blur (it does better by less than the gain worth naming) the range blur takes its place
    # with the step's test passed by the pick.
    target, before, scale, corrected = scattered_corrections()
    frames = sim_frames(4, seed=3)
    pulse = make_effect("range_blur", resolution_m=0.3, sidelobe_db=-20.0)
    turning = make_effect("motion_blur", yaw_rate_deg_s=40.0, surge_m_s=0.5, integration_s=0.2)

    def images(effects) -> np.ndarray:
        return np.stack([apply_effects(f, list(effects), np.random.default_rng(i)).normalized()
                         for i, f in enumerate(frames)])

    steady, scattered = corrected(0.96, 0.05), corrected(0.97, 0.1)
    ranked = [Solo(RankedEffect(e.name, e.params(), gap(stats, target, scale), 0.0, 0.0, 0.5), e, stats)
              for e, stats in ((turning, steady), (pulse, scattered))]
    problem = SelectionProblem(frames, target, (np.zeros((128, 128)),) * 2, scale, None, target, before,
                               gap(before, target, scale), frames[0].ranges_m, np.degrees(frames[0].azimuths_rad),
                               real_images=images([pulse]), sim_images=images)
    chosen = greedy_select(ranked, problem, TABLE_JUDGED)
    assert [(s.action, s.effect) for s in chosen.path] == [
        ("start", "none"), ("unconfirmed", "motion_blur"), ("add", "range_blur")]
    # the rival alone would not have been named
    alone = greedy_select(ranked[1:], problem, TABLE_JUDGED)
    assert alone.effects == [] and "not significantly by 5%" in alone.stopped


def test_a_ring_down_fit_tries_long_decays_before_switching_it_off():
    # The shape of a tuning case (organic scene, a long damped-oscillation ring-down): at the calibrated short decay
    # any ring-down is worse than none, a long one much better. Swept amplitude first, the search switches it off
    # (amplitude 0), after which no decay changes anything; the catalogue lists the decay first.
    def objective(effect: RingDown) -> float:
        if effect.amplitude == 0.0:
            return 1.0
        return 1.5 if effect.decay_m < 0.1 else abs(effect.amplitude - 0.7) + abs(math.log(effect.decay_m / 0.3))

    start = make_effect("ring_down")
    best, score, _ = coordinate_search(start, RingDown.PARAM_BOUNDS, objective, SearchConfig())
    assert best.decay_m > 0.1 and best.amplitude > 0.3 and score < 1.0
    amplitude_first = {k: RingDown.PARAM_BOUNDS[k] for k in ("amplitude", "decay_m", "beam_ripple")}
    assert coordinate_search(start, amplitude_first, objective, SearchConfig())[0].amplitude == 0.0


def test_a_search_from_a_later_round_only_takes_the_finer_steps_and_gets_closer():
    # A minimum between the coarse grid's points: two rounds land half a step off; a polish (rounds 2 and 3 from
    # there) moves by at most a quarter and an eighth of a step and ends nearer, never further.
    bounds = {"amplitude": (0.0, 1.0)}
    calls = []

    def objective(effect: RingDown) -> float:
        calls.append(effect.amplitude)
        return abs(effect.amplitude - 0.41)

    coarse, coarse_score, _ = coordinate_search(make_effect("ring_down"), bounds, objective, SearchConfig())
    calls.clear()
    polish = SearchConfig(rounds=4, first_round=2)
    fine, fine_score, _ = coordinate_search(coarse, bounds, objective, polish)
    step = 1.0 / (SearchConfig().points - 1)
    assert max(abs(a - coarse.amplitude) for a in calls) <= step / 4 + step / 8 + 1e-9
    assert fine_score < coarse_score and abs(fine.amplitude - 0.41) <= step / 8
    with pytest.raises(ConfigError, match="first_round"):
        SearchConfig(rounds=2, first_round=2).validate()


def test_the_selected_effects_are_searched_at_finer_steps_last():
    # "Real" = the sim's world through a gamma curve between the coarse grid's points (0.25, 0.725, 1.2). One
    # coarse round stops on a grid point; three finer rounds from there end nearer the truth, as a "refit" step.
    real = [apply_effects(f, [make_effect("gamma_quantization", gamma=0.45)], np.random.default_rng(0))
            for f in sim_frames(12, seed=2)]
    config = dataclasses.replace(FAST, effects=("gamma_quantization",), search=SearchConfig(points=3, rounds=1),
                                 max_effects=1, prune=False, gain_check=False)
    coarse = diagnose(sim_frames(12, seed=1), real, dataclasses.replace(config, polish_rounds=0))
    fine = diagnose(sim_frames(12, seed=1), real, dataclasses.replace(config, polish_rounds=3))
    assert coarse.selected == fine.selected == ("gamma_quantization",)
    assert [(s.action, s.effect) for s in fine.selection_path][-1] == ("refit", "all")
    assert coarse.selection_path[-1].action == "add"
    coarse_gamma, fine_gamma = (r.selected_effects[0].params["gamma"] for r in (coarse, fine))
    assert coarse_gamma in (0.25, 0.725, 1.2)
    assert abs(fine_gamma - 0.45) < abs(coarse_gamma - 0.45) - 0.05


def test_cli_writes_diagnosis_json_and_report(tmp_path):
    write_frames(sim_frames(8, seed=3), tmp_path / "sim")
    rng = np.random.default_rng(1)
    gamma = make_effect("gamma_quantization", gamma=0.5)
    write_frames([apply_effects(f, [gamma], rng) for f in sim_frames(8, seed=4)], tmp_path / "real")
    config = tmp_path / "config.json"
    config.write_text(json.dumps({"fit_frames": 3, "eval_frames": 4, "bootstrap": 20,
                                  "search": {"points": 3, "rounds": 1}}))
    code = main(["diagnose", "--sim", str(tmp_path / "sim"), "--real", str(tmp_path / "real"), "--out",
                 str(tmp_path / "out"), "--effects", "gamma_quantization,ring_down", "--config", str(config)])
    assert code == 0
    result = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    for key in ("gap_before", "ranked_effects", "selected", "gap_after_selected", "residual"):
        assert key in result
    assert {"name", "params", "gap_after"} <= set(result["ranked_effects"][0])
    assert result["ranked_effects"][0]["name"] == "gamma_quantization"
    assert isinstance(result["gap_before"], float) and result["gap_before"] > 0
    assert all(isinstance(name, str) for name in result["selected"])
    loaded = load_diagnosis(tmp_path / "out" / "diagnosis.json")  # read back as the typed result it was
    assert loaded.top1 == "gamma_quantization" and loaded.gap_before == result["gap_before"]
    assert loaded.maps_before.cells.shape == (8, 8) and loaded.examples is None
    assert loaded.to_json() == result
    assert (tmp_path / "out" / "report.md").read_text().startswith("# Sim-to-real gap diagnosis")
    assert (tmp_path / "out" / "diag_cells_after.png").stat().st_size > 0
    page = (tmp_path / "out" / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 8 and "gamma_quantization" in page
    assert 'src="diag_' not in page  # self-contained: nothing linked beside it
    # a pick passed over for its step's runner-up reads as such; one dropped after selection leaves its part residual
    passed = Unconfirmed("motion_blur", {}, "a smear as much across the beams as along range", 0.2, 0.21,
                         named_instead="range_blur")
    dropped = Unconfirmed("multipath", {}, "a ghost", 0.2, 0.3)
    both = dataclasses.replace(loaded, unconfirmed=(passed, dropped))
    texts = [item.text for section in sections(both, write_figures(both, tmp_path)) for item in section.items
             if isinstance(item, Text)]
    assert any(t.startswith("Passed over: **motion_blur**") and "range_blur is named in its place" in t
               for t in texts)
    assert any(t.startswith("Not blamed: **multipath**") and "residual" in t for t in texts)
    # what was named instead travels in diagnosis.json; a file written before the key existed still reads
    written = write_diagnosis(both, tmp_path / "both.json")
    assert load_diagnosis(written).unconfirmed == (passed, dropped)
    older = json.loads(written.read_text())
    del older["unconfirmed"][0]["named_instead"]
    (tmp_path / "older.json").write_text(json.dumps(older))
    assert load_diagnosis(tmp_path / "older.json").unconfirmed[0].named_instead == ""


def test_bad_input_says_what_is_needed(tmp_path, capsys):
    sim = sim_frames(4, seed=5)
    with pytest.raises(ConfigError, match="real set is empty"):
        diagnose(sim, [], FAST)
    with pytest.raises(ConfigError, match="at least 4 frames"):
        diagnose(sim[:3], sim, FAST)
    other = [f.replace(intensity=f.intensity[:, :96], azimuths_rad=f.azimuths_rad[:96]) for f in sim]
    with pytest.raises(ConfigError, match="--resample"):
        diagnose(sim, other, FAST)
    with pytest.raises(ConfigError, match="unknown effect"):
        DiagnoseConfig(effects=("sparkle",)).validate()
    with pytest.raises(ConfigError, match="at least 4"):
        split_indices(3, 0.5, 0)
    (tmp_path / "empty").mkdir()
    write_frames(sim, tmp_path / "sim")
    code = main(["diagnose", "--sim", str(tmp_path / "sim"), "--real", str(tmp_path / "empty"), "--out",
                 str(tmp_path / "out")])
    assert code == 2
    assert "error" in capsys.readouterr().err


def ghost_shaped(frame: SonarImage, donor: SonarImage, offset_m: float, coeff: float) -> SonarImage:
    """`frame` plus far-range power shaped as a ghost at `offset_m`, but a copy of *another* scene (`donor`): the
    statistics of a multipath, without the copy of the frame's own scene that a ghost is."""
    bins = int(round(offset_m / (frame.ranges_m[1] - frame.ranges_m[0])))
    x, y = frame.normalized(), donor.normalized()
    far = np.zeros_like(y)
    far[bins:] = y[:-bins] ** 2
    return frame.replace(intensity=np.sqrt(x * x + coeff ** 2 * far).astype(np.float32), intensity_scale=1.0)


def test_multipath_without_its_ghost_is_not_blamed_and_a_true_ghost_is():
    # The organic scene's world difference was blamed on multipath (RESULTS, #13 round 3, kind b): more power at
    # far range, which a ghost also adds. A ghost copies each frame's own scene at its offset; another world does
    # not, so the real frames' per-frame content shows no excess correlation at that lag.
    frames, donors = sim_frames(24, seed=3), sim_frames(12, seed=8)
    config = dataclasses.replace(FAST, effects=("multipath", "range_blur"))
    shaped = [ghost_shaped(f, d, 2.0, 0.6) for f, d in zip(frames[1::2], donors, strict=True)]
    world = diagnose(frames[0::2], shaped, config)
    assert world.selected == ()
    assert [u.effect for u in world.unconfirmed] == ["multipath"]
    assert world.unconfirmed[0].signature.startswith("a ghost")
    assert world.selection_path[-1].action == "unconfirmed"
    assert world.unconfirmed[0].gap_with_effect < world.unconfirmed[0].gap_without  # it did close part of the gap
    ghost = make_effect("multipath", reflection_coeff=0.6, ghost_offset_m=2.0)
    rng = np.random.default_rng(0)
    true = diagnose(frames[0::2], [apply_effects(f, [ghost], rng) for f in frames[1::2]], config)
    assert true.selected == ("multipath",) and true.unconfirmed == ()


def test_the_multipath_search_also_starts_where_the_fit_split_shows_its_ghost():
    # The statistics barely change with a ghost's offset, so a search from the catalogue's 1.5 m left a ghost 3.7 m
    # out at 1.5 m, and the ghost check then looked at the wrong lag (#13, 2026-11-24). The fit split's own
    # frames say where the copy is: the lag where real content correlates most beyond the sim's.
    frames = sim_frames(24, seed=3)
    ghost = make_effect("multipath", reflection_coeff=0.5, ghost_offset_m=6.0)
    rng = np.random.default_rng(0)
    real = np.stack([apply_effects(f, [ghost], rng).normalized() for f in frames[1::2]])
    sim = np.stack([f.normalized() for f in frames[0::2]])
    ranges = frames[0].ranges_m
    start = signature_starts(real, sim, ranges, np.degrees(frames[0].azimuths_rad))["multipath"]
    assert start.ghost_offset_m == pytest.approx(6.0, abs=1.5 * (ranges[1] - ranges[0]))
    assert start.reflection_coeff == make_effect("multipath").reflection_coeff  # only the offset is located


def test_the_motion_blur_search_also_starts_as_two_looks_as_far_apart_as_the_fit_splits_copy_across_beams():
    # A double image (two pings averaged while the sonar turned) was named beam_sidelobes on every scene of the
    # third tuning group: the coarse grid over yaw x window missed a copy 8 beams out, and a continuous smear of
    # that width fits it worse than sidelobes (#13, 2026-11-29). The fit split says where the copy is.
    frames = sim_frames(24, seed=3)
    bearings = np.degrees(frames[0].azimuths_rad)
    step = float(bearings[-1] - bearings[0]) / (bearings.size - 1)  # the mean beam step, as the effect turns by
    sim = np.stack([f.normalized() for f in frames[0::2]])
    plain = np.stack([f.normalized() for f in frames[1::2]])
    assert "motion_blur" not in signature_starts(plain, sim, frames[0].ranges_m, bearings)  # no copy, no start
    for apart in (5, 12):
        double = make_effect("motion_blur", yaw_rate_deg_s=40.0, surge_m_s=0.0, integration_s=apart * step / 40.0,
                             looks=2)
        rng = np.random.default_rng(0)
        real = np.stack([apply_effects(f, [double], rng).normalized() for f in frames[1::2]])
        start = signature_starts(real, sim, frames[0].ranges_m, bearings)["motion_blur"]
        assert start.looks == 2
        assert abs(start.yaw_rate_deg_s) * start.integration_s == pytest.approx(apart * step, abs=step)


def test_the_solo_fit_searches_from_a_signature_start_in_full_and_keeps_the_better_fit():
    # Compared at the start only, a two-look start that scores better there leads a continuous smear's search to a
    # worse optimum than the default's (calibrated gaussian_smear, tuning set 2), and a double image's start that
    # scores worse there is never searched from (organic two_look_average). Both searches run; the better fit on the
    # fit split is kept.
    frames = sim_frames(5, seed=3)
    ranges, bearings = frames[0].ranges_m, np.degrees(frames[0].azimuths_rad)
    turn = 12 * (bearings[-1] - bearings[0]) / (bearings.size - 1)
    raw = frame_statistics(corrected_images(frames, [], 0))
    start = make_effect("motion_blur", yaw_rate_deg_s=turn / 0.3, integration_s=0.3, looks=2.0)
    config = DiagnoseConfig()
    how = {"search": config.search, "statistics": config.statistics, "normalize": config.normalize}
    for looks in (0.0, 2.0):
        truth = make_effect("motion_blur", yaw_rate_deg_s=50.0, surge_m_s=1.2, integration_s=turn / 50.0,
                            looks=looks)
        target = frame_statistics(corrected_images(frames, [truth], 5))
        scale = FeatureScale.pooled(raw, target)
        problem = SelectionProblem(frames, target, (np.zeros(frames[0].intensity.shape),) * 2, scale,
                                   lambda effects, gain: (0.0, None), None, None, 1.0, ranges, bearings,
                                   signature_starts={"motion_blur": start})
        solo = rank_effects(["motion_blur"], problem, config)[0]
        searched = [fit_effect("motion_blur", frames, target, scale, start=s, **how).fit_gap
                    for s in (make_effect("motion_blur"), start)]
        assert solo.ranked.fit_gap == pytest.approx(min(searched))
        assert (solo.effect.looks >= 2) == (looks == 2.0)
        at_start_only = fit_effect("motion_blur", frames, target, scale, alternatives=[start], **how)
        assert at_start_only.fit_gap > solo.ranked.fit_gap + 0.1  # the path compared at the start ends worse


def test_lag_correlation_peaks_at_a_copy_of_each_frames_content():
    rng = np.random.default_rng(1)
    content = rng.rayleigh(0.2, (16, 96, 32)).astype(np.float32)
    copied = np.sqrt(content ** 2 + 0.5 * np.pad(content, ((0, 0), (12, 0), (0, 0)))[:, :96] ** 2)
    plain = range_lag_correlation(content)
    check = check_ghost(range_lag_correlation(copied), plain, 12.0)
    assert check.confirmed and int(np.argmax(range_lag_correlation(copied)[5:40])) + 5 == 12
    assert not check_ghost(range_lag_correlation(rng.rayleigh(0.2, (16, 96, 32))), plain, 12.0).confirmed



def test_leakage_check_confirms_sidelobes_and_rejects_them_standing_in_for_a_noise_floor():
    # Bright returns in a few rows of a Rayleigh seabed; sidelobes lift those rows' dark beams, a noise floor lifts
    # every row alike. Fitted at their strongest, the sidelobes predict a lift the noise-floor frames do not show.
    rng = np.random.default_rng(3)
    scene = rng.rayleigh(0.05, (24, 96, 48))
    for frame in scene:
        for row in rng.choice(np.arange(12, 84), 4, replace=False):
            beam = rng.integers(0, 44)
            frame[row, beam:beam + 4] = 1.0
    strong = make_effect("beam_sidelobes", sidelobe_db=-10.0, crosstalk_db=-15.0)
    template = sim_frames(1, 0)[0]

    def with_effect(images: np.ndarray, effect_name: str, **params: float) -> np.ndarray:
        effect = make_effect(effect_name, **params)
        frames = [template.replace(intensity=im.astype(np.float32), ranges_m=uniform_ranges(96, 10.0, 0.5),
                                   azimuths_rad=uniform_azimuths(48, math.radians(60.0)), intensity_scale=1.0)
                  for im in images]
        return np.stack([apply_effects(f, [effect], np.random.default_rng(i)).intensity
                         for i, f in enumerate(frames)])

    sidelobed = with_effect(scene, "beam_sidelobes", sidelobe_db=-12.0, crosstalk_db=-18.0)
    noisy = np.sqrt(scene ** 2 + rng.rayleigh(0.08, scene.shape) ** 2)
    predicted = with_effect(scene, "beam_sidelobes", **strong.params())
    true = check_leakage(sidelobed, scene, predicted)
    floor = check_leakage(noisy, scene, predicted)
    assert true.predicted > 0.3 and true.confirmed
    assert abs(floor.shown) < 0.1 and not floor.confirmed
    assert "leakage along the row" in floor.describe()
    # an effect that predicts no lift has nothing to show: no verdict against it
    assert check_leakage(noisy, scene, scene).confirmed


def dimmed(frames: list[SonarImage], factor: float, count: int) -> list[SonarImage]:
    """The first `count` frames `factor` times as bright in amplitude: a varied set, some views of darker ground."""
    return [f.replace(intensity=f.normalized() * (factor if i < count else 1.0), intensity_scale=1.0)
            for i, f in enumerate(frames)]


def test_the_fit_frames_are_a_fair_sample_of_a_varied_set():
    # A third of each set's frames are 10 dB darker. The sim's fit split (12 frames) holds 4 dark ones, and they
    # are its first 4: a fit on those alone sees a sim darker than the real frames and spends TVG's gain on it
    # (log coefficient and ramp at their bounds), which the held-out frames judge far worse than no effect, so
    # nothing was named. The fit frames are the split's frames whose statistics' mean is the split's.
    assert list(split_indices(24, 0.5, 0)[0][:4]) == [0, 1, 5, 7]
    sim = dimmed(sim_frames(24, seed=1), 0.3, 8)
    noise = make_effect("tvg_noise", noise_amplitude=0.1)
    rng = np.random.default_rng(0)
    real = [apply_effects(f, [noise], rng) for f in dimmed(sim_frames(24, seed=2), 0.3, 8)]
    config = dataclasses.replace(FAST, eval_frames=12, effects=("tvg_noise", "gamma_quantization"))
    result = diagnose(sim, real, config)
    assert result.selected == ("tvg_noise",)
    fitted = result.selected_effects[0].params
    assert fitted["noise_amplitude"] == pytest.approx(0.1, abs=0.05)
    assert abs(fitted["residual_ramp_db"]) < 6.0
    assert result.gap_closed > 0.6


def test_a_rival_the_pick_is_not_told_apart_from_makes_the_step_ambiguous_however_often_the_pick_wins():
    # the pick wins every resample, but by less than the least gain worth naming: "one of these", not one name
    steady = (Alternative("motion_blur", 0.40, 1.0), Alternative("range_blur", 0.41, 0.0, separated=False),
              Alternative("speckle", 0.9, 0.0))
    path = [Step("start", "none", 1.0), Step("add", "motion_blur", 0.40, steady)]
    groups = _ambiguous_groups(path, 1.0, threshold=0.2, selected=["motion_blur"])
    assert [[a.effect for a in g.effects] for g in groups] == [["motion_blur", "range_blur"]]
    told_apart = (steady[0], Alternative("range_blur", 0.41, 0.0), steady[2])
    assert _ambiguous_groups([path[0], Step("add", "motion_blur", 0.40, told_apart)], 1.0, threshold=0.2,
                             selected=["motion_blur"]) == ()


def test_a_range_blur_is_reported_as_a_range_blur_or_a_surge_smear_not_as_one_confident_name():
    # both smooth along range; the surge's box fits this Gaussian blur a little better in every resample, by
    # less than the least gain worth naming
    sim, real = sim_frames(24, seed=1), sim_frames(24, seed=2)
    blur = make_effect("range_blur", resolution_m=0.25, sidelobe_db=-30.0)
    real = [apply_effects(f, [blur], np.random.default_rng(i)) for i, f in enumerate(real)]
    result = diagnose(sim, real, dataclasses.replace(FAST, effects=("range_blur", "motion_blur", "speckle"),
                                                     search=SearchConfig()))
    assert result.verdict == "ambiguous"
    assert {a.effect for a in result.ambiguous[0].effects} == {"range_blur", "motion_blur"}
    assert result.selected[0] in {"range_blur", "motion_blur"}


def test_arcs_that_move_are_confirmed_and_a_band_at_fixed_rows_is_not():
    rng = np.random.default_rng(4)
    sim = np.clip(rng.rayleigh(0.2, (16, 128, 64)), 0, 1).astype(np.float32)
    real = np.clip(rng.rayleigh(0.2, (16, 128, 64)), 0, 1).astype(np.float32)
    moving, band = real.copy(), real.copy()
    for frame, row in zip(moving, rng.integers(20, 120, 16), strict=True):
        frame[row:row + 2] += 0.8  # one arc per ping, somewhere new
    band[:, 80:83] += 0.8  # the same rows in every frame
    assert check_arcs(moving, sim).confirmed
    fixed = check_arcs(band, sim)
    assert not fixed.confirmed and fixed.real_share == 1.0


def with_lines(frames: np.ndarray, every: int, level: float, seed: int, beams: slice = slice(None)) -> np.ndarray:
    """Every `every`-th frame gains a two-row line of amplitude `level` over `beams`, at a new range each time."""
    out = frames.copy()
    rng = np.random.default_rng(seed)
    for frame in out[::every]:
        row = int(rng.integers(20, 110))
        frame[row:row + 2, beams] = np.sqrt(frame[row:row + 2, beams] ** 2 + level ** 2)
    return out


def test_lines_that_move_are_found_and_neither_a_fixed_band_nor_speckle_nor_a_compact_echo_is():
    sim, real = speckled(30, seed=1) * 0.2, speckled(30, seed=2) * 0.2
    lined = with_lines(real, every=2, level=0.5, seed=3)
    assert (line_strength(lined)[::2] >= LINE_DB).all() and (line_strength(real) < LINE_DB).all()
    find = find_lines(lined, sim)
    assert find.found and find.real_lit == 15 and find.sim_lit == 0
    band = real.copy()
    band[:, 60:62] = np.sqrt(band[:, 60:62] ** 2 + 0.25)  # a housing reflection: the same rows in every frame
    echoes = with_lines(real, every=2, level=0.9, seed=3, beams=slice(40, 52))  # compact: a target, not a line
    assert not find_lines(band, sim).found and not find_lines(echoes, sim).found
    assert not find_lines(with_lines(real, every=15, level=0.5, seed=3), sim).found  # 2 of 30: not significant
    fitted = interference_from_lines(lined, find)
    assert fitted.rate_per_ping == pytest.approx(-np.log(0.5), rel=0.01)  # half the pings show one
    assert fitted.amplitude == pytest.approx(0.5, rel=0.25)
    assert fitted.floor_db > -3.5  # as bright across the fan as at its peak


def test_a_band_at_one_range_is_fixed_when_the_range_window_changes_from_ping_to_ping():
    sim, real = speckled(30, seed=1) * 0.2, speckled(30, seed=2) * 0.2
    ends = np.random.default_rng(5).uniform(8.0, 12.0, 30)
    ranges = np.stack([np.linspace(0.1, end, 128) for end in ends])
    band = real.copy()
    for frame, axis in zip(band, ranges, strict=True):
        row = int(np.argmin(np.abs(axis - 5.0)))  # a housing reflection 5 m out: another row in every frame
        frame[row:row + 2] = np.sqrt(frame[row:row + 2] ** 2 + 0.25)
    assert (line_strength(band) >= LINE_DB).mean() > 0.8  # counted by row, it would be a line in every frame
    assert (line_strength(band, ranges) < LINE_DB).all()
    assert not find_lines(band, sim, ranges, ranges).found
    assert check_arcs(band, real, ranges, ranges).real_share > 0.8
    assert not check_arcs(band, real, ranges, ranges).confirmed
    lined = with_lines(real, every=2, level=0.5, seed=3)  # lines that move are still found on these axes
    assert find_lines(lined, sim, ranges, ranges).found
    at_row = real.copy()
    at_row[::2, 60:] *= 5.0  # a bright seabed under the band's row in half the frames: its contrast comes and goes
    at_row[:, 70:72] = np.sqrt(at_row[:, 70:72] ** 2 + 0.25)  # an artefact at a fixed sample, whatever the window
    assert not find_lines(at_row, sim, ranges, ranges).found


def test_a_ring_down_is_found_from_the_first_bin_and_neither_a_band_further_out_nor_a_gain_ramp_is():
    frames = sim_frames(12, seed=2)
    sim = np.stack([f.normalized() for f in sim_frames(12, seed=1)])

    def real(change) -> np.ndarray:
        return np.stack([change(f.normalized(), f) for f in frames])

    ring = make_effect("ring_down", amplitude=0.3, decay_m=0.12, beam_ripple=0.0)
    rung = real(lambda x, f: ring.apply(x, f, np.random.default_rng(0)))
    find = find_ring_down(rung, sim)
    assert find.found and find.head_db - find.tail_db > 20
    measured = ring_down_from_excess(rung, sim, frames[0].ranges_m)
    assert measured.amplitude == pytest.approx(0.3, rel=0.15)
    assert 0.12 / 1.5 < measured.decay_m < 0.12 * 1.5

    def band(x: np.ndarray, f: SonarImage) -> np.ndarray:  # a housing reflection a few bins out
        out = x.copy()
        out[6:9] = np.sqrt(out[6:9] ** 2 + 0.3 ** 2)
        return out

    ramp = real(lambda x, f: x * (10 ** (np.linspace(0, 1.0, x.shape[0]) / 20))[:, None])  # a TVG error
    assert not find_ring_down(real(band), sim).found
    assert not find_ring_down(ramp, sim).found
    assert not find_ring_down(real(lambda x, f: x), sim).found
    # a weak noise floor over a dark near field stands out in dB there, but adds as much power everywhere
    draw = np.random.default_rng(5)
    seabed = draw.rayleigh(0.3, (12, 128, 128))
    seabed[:, :10] = 0.0  # the water column
    misread = find_ring_down(np.sqrt(seabed ** 2 + draw.rayleigh(0.02, seabed.shape) ** 2), seabed)
    assert misread.head_db - misread.tail_db > 6 and misread.first_db >= misread.peak_db - 3  # the dB test alone
    assert abs(misread.added_fall_db) < 3 and not misread.found


def test_a_ring_down_whose_receiver_recovers_is_found_though_dimmer_at_the_first_bin():
    # The Oculus recordings' near-field band: lit at the first bin, but brighter a few bins out, where the receiver
    # has recovered from the transmit blanking (the first-bin start test alone took it for a band further out).
    frames = sim_frames(12, seed=2)
    sim = np.stack([f.normalized() for f in sim_frames(12, seed=1)])
    distance = frames[0].ranges_m - frames[0].ranges_m[0]
    leak = 0.3 * np.exp(-distance / 0.5) * (1 - 0.8 * np.exp(-distance / 0.2))
    recovering = np.stack([np.sqrt(f.normalized() ** 2 + leak[:, None] ** 2) for f in frames])
    find = find_ring_down(recovering, sim)
    assert find.first_db < find.peak_db - 3 and find.peak_in_head
    assert find.found


def test_a_ring_down_the_gap_does_not_name_is_found_by_its_footprint():
    # The gap cannot credit it (the table: no candidate lowers it), the first rows show it: a found step.
    frames = sim_frames(8, seed=3)
    stats = frame_statistics(np.stack([f.normalized() for f in frames]))
    ring = make_effect("ring_down", amplitude=0.3, decay_m=0.1, beam_ripple=0.0)

    def images(effects) -> np.ndarray:
        return np.stack([apply_effects(f, list(effects), np.random.default_rng(i)).normalized()
                         for i, f in enumerate(frames)])

    def holdout(effects, gain=None):
        return 1.0, None

    def select(real_effects, max_effects: int = 2) -> Selection:
        ranked = [Solo(RankedEffect("ring_down", ring.params(), 1.0, 0.0, 0.0, 1.0), ring, None)]
        problem = SelectionProblem(frames[:2], stats, (np.zeros((128, 128)),) * 2, FeatureScale.pooled(stats, stats),
                                   holdout, None, None, 1.0, frames[0].ranges_m, np.degrees(frames[0].azimuths_rad),
                                   real_images=images(real_effects), sim_images=images)
        config = DiagnoseConfig(search=SearchConfig(points=2, rounds=1), statistics=StatisticsConfig(),
                                max_effects=max_effects, min_gain=0.05, backfit=False, prune=False, gain_check=False)
        return greedy_select(ranked, problem, config)

    found = select([ring])
    assert [(s.action, s.effect) for s in found.path] == [("start", "none"), ("found", "ring_down")]
    assert found.found[0].params["amplitude"] == pytest.approx(0.3, rel=0.15)
    assert found.found[0].signature.startswith("a band from the first range bin")
    assert select([]).path == [Step("start", "none", 1.0)] and select([]).found == []
    # max_effects caps what the gap selects, not what the real frames show
    assert [s.effect for s in select([ring], max_effects=0).found] == ["ring_down"]


def test_lines_in_a_few_pings_are_counted_on_both_splits_not_the_held_out_half_alone():
    # Lines in 7 of 32 real pings (and the world's own in one more): the few of the 16 held out are not significantly
    # more than none of 16 sim frames, all of them in 32 are (Fisher's exact test). Nothing is fitted to a count,
    # so the fit split counts too.
    sim, world = sim_frames(32, seed=4), sim_frames(32, seed=5)
    lines = make_effect("interference", rate_per_ping=3.0, amplitude=0.5, floor_db=-10.0, thickness_m=0.1)
    rng = np.random.default_rng(0)
    real = np.stack([(apply_effects(f, [lines], rng) if i % 5 == 0 else f).normalized() for i, f in enumerate(world)])
    stats = frame_statistics(np.stack([f.normalized() for f in sim[:4]]))
    interference = make_effect("interference")

    def images(frames: list[SonarImage]) -> Callable[[Sequence[Effect]], np.ndarray]:
        return lambda effects: np.stack([apply_effects(f, list(effects), np.random.default_rng(i)).normalized()
                                         for i, f in enumerate(frames)])

    def select(counted: CountedFrames | None) -> Selection:
        ranked = [Solo(RankedEffect("interference", interference.params(), 1.0, 0.0, 0.0, 1.0), interference, None)]
        problem = SelectionProblem(sim[:2], stats, (np.zeros((128, 128)),) * 2, FeatureScale.pooled(stats, stats),
                                   lambda effects, gain=None: (1.0, None), None, None, 1.0, sim[0].ranges_m,
                                   np.degrees(sim[0].azimuths_rad), real_images=real[1::2],
                                   sim_images=images(sim[1::2]), counted=counted)
        config = DiagnoseConfig(search=SearchConfig(points=2, rounds=1), statistics=StatisticsConfig(),
                                max_effects=1, min_gain=0.05, backfit=False, prune=False, gain_check=False)
        return greedy_select(ranked, problem, config)

    assert select(None).found == []
    found = select(CountedFrames(real, images(sim))).found
    assert [f.effect for f in found] == ["interference"]
    assert "of 32 real frames" in found[0].signature and "against 0 of 32 corrected sim frames" in found[0].signature


def test_interference_the_gap_does_not_see_is_found_by_its_lines(tmp_path):
    sim = sim_frames(16, seed=1)
    lines = make_effect("interference", rate_per_ping=1.0, amplitude=0.3, floor_db=-10.0, thickness_m=0.1)
    rng = np.random.default_rng(0)
    real = [apply_effects(f, [lines], rng) for f in sim_frames(16, seed=2)]
    config = dataclasses.replace(FAST, effects=("interference", "tvg_noise"))
    result = diagnose(sim, real, config)
    assert result.selected == ("interference",)
    assert [s.action for s in result.selection_path] == ["start", "found"]  # the gap alone named nothing
    assert result.found[0].params["amplitude"] == pytest.approx(0.3, rel=0.3)
    assert load_diagnosis(write_diagnosis(result, tmp_path / "diagnosis.json")).found == result.found
    clean = diagnose(sim, sim_frames(16, seed=2), config)
    assert "interference" not in clean.selected and clean.found == ()


def test_the_speckle_fit_reaches_speckle_lighter_than_rayleigh_through_its_looks():
    # Gamma draws of shape 1.5 shared across beams (tuning group 4) were named nothing on every scene: the
    # catalogue's speckle was never lighter than Rayleigh (SI >= 1). With looks it is, and the fit finds them.
    frames = sim_frames(5, seed=3)
    config = DiagnoseConfig()
    how = {"search": config.search, "statistics": config.statistics, "normalize": config.normalize}
    raw = frame_statistics(corrected_images(frames, [], 0))
    truth = make_effect("speckle", shape_nu=50.0, grain_beams=1.5, grain_ranges=0.6, looks=3.0)
    target = frame_statistics(corrected_images(frames, [truth], 5))
    scale = FeatureScale.pooled(raw, target)
    fit = fit_effect("speckle", frames, target, scale, **how)
    one_look = fit_effect("speckle", frames, target, scale, fixed=("looks",), **how)
    assert fit.effect.looks >= 2.0 and fit.fit_gap < one_look.fit_gap - 0.1
