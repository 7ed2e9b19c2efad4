"""The held-out validation effects (sonar_realism/diagnose/heldout): each changes a frame the way its physics
says, keeps shape and dtype, and is fixed by its seed; the registry covers every catalogued effect twice."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sonar_realism.diagnose.heldout import IMPLEMENTATIONS, UNCATALOGUED, apply_held_out
from sonar_realism.frames import SonarImage
from sonar_realism.sim.effects import EFFECTS
from tests.repo_script import load_repo_script

TEN = ("speckle", "beam_sidelobes", "range_blur", "tvg_noise", "elevation_spread", "multipath", "motion_blur",
       "ring_down", "interference", "gamma_quantization")
N_RANGES, N_BEAMS = 200, 96
TARGET_ROW, TARGET_BEAM = 100, 48


def frame_of(image: np.ndarray, seq: int = 3) -> SonarImage:
    ranges = np.linspace(0.5, 10.5, N_RANGES)
    azimuths = np.arcsin(np.linspace(math.sin(math.radians(-60)), math.sin(math.radians(60)), N_BEAMS))
    return SonarImage(image.astype(np.float32), ranges, azimuths, seq=seq, frame_id="sonar", stamp_ns=0,
                      intensity_scale=1.0, meta={"sonar_altitude_m": 1.5, "sonar_tilt_rad": math.radians(10.0)})


def point_frame(background: float = 0.02) -> SonarImage:
    image = np.full((N_RANGES, N_BEAMS), background, np.float32)
    image[TARGET_ROW, TARGET_BEAM] = 1.0
    return frame_of(image)


def middle_params(name: str) -> dict[str, float]:
    """Every parameter at the middle of its inside range."""
    return {k: (round(sum(p.inside) / 2) if p.integer else sum(p.inside) / 2)
            for k, p in IMPLEMENTATIONS[name].params.items()}


def run(name: str, frame: SonarImage, seed: int = 0, **changes: float) -> np.ndarray:
    params = {**middle_params(name), **changes}
    out = apply_held_out([frame], name, params, seed)[0]
    return out.intensity.astype(np.float64) / out.intensity_scale


def test_every_catalogued_effect_has_two_forms_and_three_uncatalogued_exist():
    families = [entry.family for entry in IMPLEMENTATIONS.values()]
    assert set(TEN) <= set(EFFECTS)
    for name in TEN:
        assert families.count(name) >= 2, name
    assert families.count(UNCATALOGUED) >= 3


@pytest.mark.parametrize("name", sorted(IMPLEMENTATIONS))
def test_draw_ranges_inside_the_fit_bounds_and_wider(name):
    entry = IMPLEMENTATIONS[name]
    widened = False
    for key, param in entry.params.items():
        assert param.wide[0] <= param.inside[0] <= param.inside[1] <= param.wide[1], key
        widened |= param.wide != param.inside
        if param.catalogue:
            lo, hi = EFFECTS[entry.family].PARAM_BOUNDS[param.catalogue]
            assert lo <= param.inside[0] and param.inside[1] <= hi, key
    assert widened
    rng = np.random.default_rng(1)
    assert entry.outside_bounds(entry.draw("inside", rng)) == []


@pytest.mark.parametrize("name", sorted(IMPLEMENTATIONS))
def test_shape_dtype_and_seed(name):
    rng = np.random.default_rng(5)
    frame = frame_of(0.3 + 0.2 * rng.random((N_RANGES, N_BEAMS)))
    params = IMPLEMENTATIONS[name].draw("wide", np.random.default_rng(2))
    first = apply_held_out([frame, frame], name, params, seed=4)
    again = apply_held_out([frame, frame], name, params, seed=4)
    for a, b in zip(first, again, strict=True):
        assert a.intensity.shape == frame.intensity.shape
        assert a.intensity.dtype in (np.float32, np.uint8)
        assert np.isfinite(a.intensity.astype(np.float64)).all() and (a.intensity >= 0).all()
        np.testing.assert_array_equal(a.intensity, b.intensity)
    sure = {**params, **({"probability": 1.0} if "probability" in params else {})}  # an event in this ping
    changed = apply_held_out([frame], name, sure, seed=4)[0]
    assert not np.array_equal(changed.intensity.astype(np.float64) / changed.intensity_scale, frame.intensity)


def beside_target(image: np.ndarray) -> float:
    """Mean power in the target's row 6 to 30 beams away from it."""
    row = image[TARGET_ROW] ** 2
    return float(np.r_[row[TARGET_BEAM - 30:TARGET_BEAM - 6], row[TARGET_BEAM + 7:TARGET_BEAM + 31]].mean())


@pytest.mark.parametrize("name", ["beam_sidelobes/chebyshev_coherent", "beam_sidelobes/gaussian_skirt_grating"])
def test_sidelobes_raise_energy_beside_a_bright_point_in_bearing(name):
    frame = point_frame()
    out = run(name, frame, sidelobe_db=-15.0, skirt_db=-15.0, mainlobe_deg=2.0, skirt_decay_deg=8.0)
    assert beside_target(out) > 1.5 * beside_target(frame.intensity)
    # only constant-range rows mix: a uniform row stays as it was (away from the fan's edges)
    np.testing.assert_allclose(out[TARGET_ROW + 5, 10:-10], frame.intensity[TARGET_ROW + 5, 10:-10], rtol=0.02)


def test_chebyshev_sidelobes_sit_at_the_drawn_level():
    out = run("beam_sidelobes/chebyshev_coherent", point_frame(0.0), sidelobe_db=-20.0, mainlobe_deg=1.0)
    row = out[TARGET_ROW] ** 2
    far = np.r_[row[:TARGET_BEAM - 15], row[TARGET_BEAM + 16:]]
    assert -24.0 < 10 * math.log10(far.max() / row.max()) < -16.0


@pytest.mark.parametrize("name", ["range_blur/rect_rc_causal", "range_blur/triangle_coherent"])
def test_range_blur_spreads_a_point_along_range_only(name):
    out = run(name, point_frame(0.0), pulse_m=0.2, resolution_m=0.2)
    assert out[TARGET_ROW + 2, TARGET_BEAM] > 0.05
    assert out[TARGET_ROW, TARGET_BEAM] < 0.99
    assert out[:, TARGET_BEAM + 3].max() == 0.0
    if name.endswith("causal"):
        assert out[:TARGET_ROW, TARGET_BEAM].max() < 1e-6


@pytest.mark.parametrize("name", ["multipath/diffuse_phasor", "multipath/wall_comb_sector"])
def test_multipath_adds_a_delayed_copy(name):
    image = np.full((N_RANGES, N_BEAMS), 0.02, np.float32)
    image[60] = 1.0  # a bright arc across the fan
    frame = frame_of(image)
    offset_m = 2.0
    out = run(name, frame, ghost_offset_m=offset_m, spacing_m=offset_m, reflection_coeff=0.6, tail_m=0.05,
              sector_fraction=1.0)
    ghost_row = 60 + int(round(offset_m / (10.0 / (N_RANGES - 1))))
    near_ghost = (out[ghost_row - 2:ghost_row + 3] ** 2).mean(axis=1).max()
    assert near_ghost > 10 * 0.02 ** 2
    assert (out[:60] ** 2).mean() < 2 * 0.02 ** 2  # nothing arrives before the direct return


@pytest.mark.parametrize("name", ["gamma_quantization/log_8bit", "gamma_quantization/knee_coarse_adc"])
def test_output_mapping_reduces_distinct_levels(name):
    rng = np.random.default_rng(0)
    frame = frame_of(rng.random((N_RANGES, N_BEAMS)))
    out = apply_held_out([frame], name, middle_params(name), 0)[0]
    assert out.intensity.dtype == np.uint8
    assert np.unique(out.intensity).size < min(np.unique(frame.intensity).size, 256)
    if name.endswith("adc"):
        assert np.unique(out.intensity).size <= 2 ** int(middle_params(name)["bits"])


@pytest.mark.parametrize("name", ["speckle/weibull_copula", "speckle/rician_lognormal"])
def test_speckle_makes_a_flat_field_fluctuate_and_keeps_its_power(name):
    frame = frame_of(np.full((N_RANGES, N_BEAMS), 0.4))
    out = run(name, frame, diffuse_fraction=1.0)
    assert out.std() / out.mean() > 0.2
    assert abs((out ** 2).mean() / 0.16 - 1.0) < 0.1


@pytest.mark.parametrize("name", ["tvg_noise/incoherent_power_law", "tvg_noise/stepped_real_noise"])
def test_tvg_noise_grows_with_range(name):
    out = run(name, frame_of(np.zeros((N_RANGES, N_BEAMS))), noise_amplitude=0.2)
    near, far = (out[:40] ** 2).mean(), (out[-40:] ** 2).mean()
    assert far > 3 * near and far > 0.005


@pytest.mark.parametrize("name", ["elevation_spread/hann_pointing", "elevation_spread/trapezoid_db"])
def test_vertical_pattern_weights_the_seabed_by_range(name):
    out = run(name, frame_of(np.full((N_RANGES, N_BEAMS), 0.5)), flat_deg=6.0)
    profile = out[:, N_BEAMS // 2]
    assert profile.max() <= 0.5 + 1e-6 and profile.min() < 0.25  # attenuates, more at some ranges than others
    assert np.allclose(out[:, N_BEAMS // 2], out[:, N_BEAMS // 2 + 1], rtol=0.05)  # nearly bearing-independent


@pytest.mark.parametrize("name", ["motion_blur/accelerating_yaw", "motion_blur/jitter_subpings"])
def test_motion_blur_moves_a_point_across_bearing(name):
    frame = point_frame(0.0)
    out = run(name, frame, yaw_rate_deg_s=60.0, smear_deg=1.0, jitter_deg=1.5, copies=5)
    row = out[TARGET_ROW - 3:TARGET_ROW + 4].max(axis=0)
    lit = np.flatnonzero(row > 0.05)
    assert lit.size >= 2 or lit[0] != TARGET_BEAM


@pytest.mark.parametrize("name", ["ring_down/power_law_recovery", "ring_down/two_exponential_inphase"])
def test_ring_down_brightens_the_first_bins(name):
    out = run(name, frame_of(np.full((N_RANGES, N_BEAMS), 0.05)), amplitude=0.5)
    assert out[:3].mean() > 3 * 0.05
    assert out[-50:].mean() < 0.07


@pytest.mark.parametrize("name", ["interference/long_pulse_fading", "interference/clock_lines"])
def test_interference_raises_rows_across_the_fan(name):
    frames = [frame_of(np.full((N_RANGES, N_BEAMS), 0.05), seq=i) for i in range(6)]
    params = {**middle_params(name), "probability": 1.0, "amplitude": 0.8}
    hits = 0
    for out in apply_held_out(frames, name, params, 0):  # a fading pulse can be faint or fall off the end
        image = out.intensity.astype(np.float64)
        raised = (image ** 2).mean(axis=1) > 4 * 0.05 ** 2
        assert raised.mean() < 0.5
        hits += bool(raised.any()) and (image[raised] > 0.1).mean() > 0.3  # raised across much of the fan
    assert hits >= 3


def test_column_stripes_hit_the_same_beams_in_every_frame_and_their_place_names_them():
    name = "uncatalogued/column_stripes"
    params = middle_params(name)
    frames = [frame_of(np.full((N_RANGES, N_BEAMS), 0.3), seq=i) for i in range(2)]
    outs = [f.intensity for f in apply_held_out(frames, name, params, 0)]
    changed = [set(np.flatnonzero(np.abs(o.mean(axis=0) - 0.3) > 0.05)) for o in outs]
    assert changed[0] == changed[1] and len(changed[0]) == params["bad_beams"]
    place = IMPLEMENTATIONS[name].place(frames[0], params)
    bearings = np.degrees(frames[0].azimuths_rad[sorted(changed[0])])
    np.testing.assert_allclose(sorted(lo for lo, _ in place.bearing_deg), bearings)


@pytest.mark.parametrize("name,raised", [("uncatalogued/housing_band", True), ("uncatalogued/range_gain_notch", False)])
def test_range_fixed_patterns_sit_at_their_place(name, raised):
    frame = frame_of(np.full((N_RANGES, N_BEAMS), 0.3))
    params = middle_params(name)
    out = run(name, frame)
    (lo, hi), = IMPLEMENTATIONS[name].place(frame, params).range_m
    inside = (frame.ranges_m >= lo) & (frame.ranges_m <= hi)
    row_means = out.mean(axis=1)
    assert ((row_means[inside].max() > 0.35) if raised else (row_means[inside].min() < 0.25))
    np.testing.assert_allclose(row_means[~inside & (np.abs(frame.ranges_m - (lo + hi) / 2) > 1.0)], 0.3, rtol=1e-4)


def test_fan_gain_drift_tilts_the_fan():
    out = run("uncatalogued/fan_gain_drift", frame_of(np.full((N_RANGES, N_BEAMS), 0.3)), tilt_db=6.0, bow_db=0.0)
    assert 20 * math.log10(out[:, -1].mean() / out[:, 0].mean()) == pytest.approx(6.0, abs=0.1)


def test_the_bench_reads_a_diagnosis_from_the_design_contract_keys_alone():
    bench = load_repo_script("bench/bench_diagnose_heldout.py", "bench_diagnose_heldout")
    payload = {"gap_before": 2.0, "gap_after_selected": 0.5, "selected": ["range_blur", "motion_blur"],
               "ranked_effects": [{"name": "motion_blur", "params": {}, "gap_after": 1.2},
                                  {"name": "range_blur", "params": {}, "gap_after": 0.9}],
               "residual": {"range_bins": [{"bin": 3, "range_m": [4.0, 4.5]}, {"bin": 1, "range_m": [1.0, 1.5]}],
                            "size": 0.5}}
    read = bench.read_diagnosis(payload)
    assert bench.top1(read) == "range_blur" and read.ambiguous is None
    assert bench.in_place(read, bench.Place(range_m=((4.2, 4.3),)))
    assert not bench.in_place(read, bench.Place(range_m=((1.1, 1.2),)))  # only the top entry counts
    assert bench.top1(bench.read_diagnosis({**payload, "selected": []})) == ""
    # the reworked diagnosis nests the places under residual.where and names a profile bin's interval `span`
    nested = {**payload, "residual": {"size": 0.5, "where": {"cells": [], "bearing_bins": [
        {"bin": 7, "span": [10.0, 12.0], "gap": 0.1, "share": 0.4}]}}}
    assert bench.in_place(bench.read_diagnosis(nested), bench.Place(bearing_deg=((11.0, 11.5),)))


def test_the_bench_counts_a_name_with_its_ambiguous_group_and_runs_either_half():
    bench = load_repo_script("bench/bench_diagnose_heldout.py", "bench_diagnose_heldout")
    payload = {"gap_before": 1.0, "gap_after_selected": 0.5, "selected": ["motion_blur"],
               "ranked_effects": [{"name": "motion_blur", "params": {}, "gap_after": 0.5}], "residual": {},
               "ambiguous": [{"step": 1, "effects": [{"effect": "motion_blur"}, {"effect": "range_blur"}]}]}
    read = bench.read_diagnosis(payload)
    assert bench.top1(read) == "motion_blur"
    assert set(bench.ambiguous_with(read, "motion_blur")) == {"motion_blur", "range_blur"}
    assert bench.ambiguous_with(bench.read_diagnosis({**payload, "ambiguous": []}), "motion_blur") == []
    tuning = bench.implementations(False, registry=bench.TUNING)
    assert tuning and not set(tuning) & set(bench.implementations(False))


def test_the_validation_runs_small_end_to_end_on_both_halves():
    # the tuning set's assertions may fail with the diagnosis; the held-out half is only run, never pinned
    bench = load_repo_script("bench/bench_diagnose_heldout.py", "bench_diagnose_heldout")
    config = dataclasses.replace(bench.QUICK_CONFIG, effects=("gamma_quantization", "speckle", "tvg_noise",
                                                              "range_blur"))
    rows = bench.accuracy("default:16", config, lambda message: None,
                          only=("gamma_quantization/two_slope", "range_blur/lorentzian"), registry=bench.TUNING)
    assert [r["implementation"] for r in rows] == ["none (null)", "range_blur/lorentzian",
                                                   "gamma_quantization/two_slope"]
    assert rows[0]["selected"] == [] and all(r["top1_correct"] for r in rows[1:])
    held_out = bench.accuracy("default:16", config, lambda message: None, only=("column_stripes",))
    summary = bench.summarise(held_out)
    assert summary["uncatalogued_cases"] == 1 and {"blamed", "in_place"} <= set(held_out[-1])
