"""The second tuning set (sonar_realism/diagnose/tuning_forms.py): one more form per catalogued effect, each
doing what its physics says, fixed by its seed, drawn inside the fit bounds (and wider), and kept out of the
held-out half's registry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonar_realism.diagnose.heldout import IMPLEMENTATIONS, apply_held_out, find_implementation
from sonar_realism.diagnose.heldout.base import REGISTRIES
from sonar_realism.diagnose.tuning_forms import TUNING
from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.sim.effects import EFFECTS

N_RANGES, N_BEAMS = 200, 96
ROW, BEAM = 100, 48


def frame_of(image: np.ndarray) -> SonarImage:
    ranges = np.linspace(0.5, 10.5, N_RANGES)
    azimuths = np.arcsin(np.linspace(math.sin(math.radians(-60)), math.sin(math.radians(60)), N_BEAMS))
    return SonarImage(image.astype(np.float32), ranges, azimuths, seq=3, frame_id="sonar", stamp_ns=0,
                      intensity_scale=1.0, meta={"sonar_altitude_m": 1.5, "sonar_tilt_rad": math.radians(10.0)})


def point() -> SonarImage:
    image = np.full((N_RANGES, N_BEAMS), 0.02, np.float32)
    image[ROW, BEAM] = 1.0
    return frame_of(image)


def run(name: str, frame: SonarImage, seed: int = 0, **changes: float) -> np.ndarray:
    params = {k: (round(sum(p.inside) / 2) if p.integer else sum(p.inside) / 2) for k, p in TUNING[name].params.items()}
    out = apply_held_out([frame], name, {**params, **changes}, seed)[0]
    return out.intensity.astype(np.float64) / out.intensity_scale


def test_one_form_per_catalogued_effect_none_in_the_held_out_registry():
    assert {entry.family for entry in TUNING.values()} == {entry.family for entry in IMPLEMENTATIONS.values()} - {
        "uncatalogued"}
    assert not set(TUNING) & set(IMPLEMENTATIONS)


@pytest.mark.parametrize("name", sorted(TUNING))
def test_draws_inside_the_fit_bounds_and_a_seeded_change(name):
    entry = TUNING[name]
    for key, param in entry.params.items():
        assert param.wide[0] <= param.inside[0] <= param.inside[1] <= param.wide[1], key
        if param.catalogue:
            lo, hi = EFFECTS[entry.family].PARAM_BOUNDS[param.catalogue]
            assert lo <= param.inside[0] and param.inside[1] <= hi, key
    frame = frame_of(0.3 + 0.2 * np.random.default_rng(5).random((N_RANGES, N_BEAMS)))
    params = entry.draw("wide", np.random.default_rng(2))
    first, again = (apply_held_out([frame], name, params, seed=4)[0] for _ in range(2))
    assert first.intensity.shape == frame.intensity.shape and (first.intensity >= 0).all()
    np.testing.assert_array_equal(first.intensity, again.intensity)
    assert not np.allclose(first.intensity.astype(np.float64) / first.intensity_scale, frame.intensity)


def test_sidelobe_skirt_spreads_a_point_across_beams_not_along_range():
    out = run("beam_sidelobes/exponential_skirt", point(), skirt_db=-12.0)
    assert out[ROW, BEAM + 8] > 3 * 0.02 and out[ROW + 8, BEAM] == pytest.approx(0.02, rel=0.05)


def test_lorentzian_blur_spreads_a_point_along_range_with_heavy_tails():
    out = run("range_blur/lorentzian", point(), resolution_m=0.2)
    assert out[ROW + 6, BEAM] > 2 * 0.02 and out[ROW, BEAM + 6] == pytest.approx(0.02, rel=0.05)
    assert out[ROW, BEAM] < 0.8


def test_random_yaw_smears_each_ping_across_beams_by_its_own_rate_and_never_along_range():
    widths = []
    for seed in range(6):
        out = run("motion_blur/random_yaw_triangle", point(), seed=seed, yaw_rate_deg_s=60.0, rate_spread=0.6,
                  integration_s=0.3)
        lit = np.flatnonzero(out[ROW] > 2 * 0.02)
        assert lit.size >= 3 and lit.min() < BEAM < lit.max()  # a triangle about the echo (the shear is < a beam)
        assert out[ROW + 3, BEAM] == pytest.approx(0.02, rel=0.05)  # nothing along range
        widths.append(lit.size)
    assert len(set(widths)) > 1  # each ping turns at its own rate


def test_gaussian_smear_spreads_across_beams_with_yaw_and_along_range_with_surge():
    across = run("motion_blur/gaussian_smear", point(), yaw_rate_deg_s=60.0, surge_m_s=0.0, integration_s=0.25)
    along = run("motion_blur/gaussian_smear", point(), yaw_rate_deg_s=0.0, surge_m_s=2.0, integration_s=0.25)
    assert across[ROW, BEAM + 3] > across[ROW + 3, BEAM + 1]
    assert along[ROW + 3, BEAM] > along[ROW, BEAM + 3]


def test_shoulder_brightens_the_first_rows_only():
    flat = frame_of(np.full((N_RANGES, N_BEAMS), 0.1, np.float32))
    out = run("ring_down/logistic_shoulder", flat, amplitude=0.6, hold_m=0.2, fall_m=0.02)
    assert out[:3].mean() > 0.4 and out[60:].mean() == pytest.approx(0.1, rel=1e-3)


def test_blurred_echo_repeats_a_bright_row_further_out():
    image = np.full((N_RANGES, N_BEAMS), 0.02, np.float32)
    image[50] = 1.0
    out = run("multipath/blurred_echo", frame_of(image), offset_m=2.0, reflection=0.6, blur_bins=1.0)
    shift = round(2.0 / (10.0 / (N_RANGES - 1)))
    assert out[50 + shift].mean() > 5 * out[50 + shift + 20].mean()


def test_real_noise_grows_along_range_and_two_slope_gives_counts():
    dark = frame_of(np.zeros((N_RANGES, N_BEAMS), np.float32))
    noisy = run("tvg_noise/real_ramp_db", dark, slope_db=20.0)
    assert noisy[-20:].mean() > 5 * noisy[:20].mean()
    counts = apply_held_out([point()], "gamma_quantization/two_slope",
                            {"gain": 1.0, "knee_in": 0.1, "knee_out": 0.5}, 0)[0]
    assert counts.intensity.dtype == np.uint8 and counts.intensity[ROW, BEAM] == 255
    assert abs(int(counts.intensity[0, 0]) - 255 * 0.02 * 0.5 / 0.1) <= 1  # steep below the knee: 25.5 counts


def test_cos_power_weights_the_seabed_by_elevation_and_partial_arcs_cover_part_of_the_fan():
    flat = frame_of(np.full((N_RANGES, N_BEAMS), 0.5, np.float32))
    weighted = run("elevation_spread/cos_power", flat, beamwidth_deg=10.0, floor_db=-30.0)
    assert (weighted <= 0.5 + 1e-6).all() and weighted[:, BEAM].std() > 0.05
    speckled = run("speckle/multilook_box", flat)
    assert (speckled ** 2).mean() == pytest.approx(0.25, rel=0.05) and speckled.std() > 0.1
    arcs = run("interference/partial_arcs", frame_of(np.zeros((N_RANGES, N_BEAMS), np.float32)), seed=1,
               rate_per_ping=5.0, span=0.3)
    lit = arcs.max(axis=0) > 0.05
    assert lit.any() and not lit.all()


def test_grating_lobes_put_faint_copies_far_across_the_fan_with_dark_beams_between():
    out = run("beam_sidelobes/grating_lobes", point(), lobe_db=-15.0, offset_beams=20, mainlobe_deg=0.5)
    copy_db = 20 * math.log10(out[ROW, BEAM + 20] / out[ROW, BEAM])
    assert copy_db == pytest.approx(-15.0, abs=1.5) and out[ROW, BEAM - 20] == pytest.approx(out[ROW, BEAM + 20])
    assert out[ROW, BEAM + 10] < 1.5 * 0.02 and out[ROW + 5, BEAM] == pytest.approx(0.02, rel=0.05)


def test_the_chirp_spreads_a_point_along_range_with_sidelobes_13_db_down():
    out = run("range_blur/sinc_chirp", frame_of(np.where(point().intensity > 0.5, 1.0, 0.0)), resolution_m=0.25)
    width = 0.25 / (10.0 / (N_RANGES - 1))  # bins to the first null: 5
    power = out[:, BEAM] ** 2
    first_sidelobe = power[ROW + int(round(1.5 * width))] / power[ROW]
    assert 10 * math.log10(first_sidelobe) == pytest.approx(-13.3, abs=1.5)
    assert out[ROW, BEAM + 2] == 0.0


def test_noise_before_the_gain_grows_with_range_and_the_echoes_dim():
    dark = run("tvg_noise/noise_before_gain", frame_of(np.zeros((N_RANGES, N_BEAMS), np.float32)),
               noise_level=0.2, absorption_db_per_m=0.0)
    assert dark[-20:].mean() > 5 * dark[:20].mean()
    flat = run("tvg_noise/noise_before_gain", frame_of(np.full((N_RANGES, N_BEAMS), 0.5, np.float32)),
               noise_level=0.0, absorption_db_per_m=1.0)
    assert 20 * math.log10(flat[-1].mean() / flat[0].mean()) == pytest.approx(-10.0, abs=0.1)


def test_the_surface_path_repeats_a_bright_row_after_the_image_path_and_two_looks_double_a_point():
    image = np.full((N_RANGES, N_BEAMS), 0.02, np.float32)
    image[50] = 1.0
    frame = frame_of(image)
    out = run("multipath/surface_bounce", frame, reflection=0.5, depth_m=1.5)
    r = frame.ranges_m
    ghost = int(np.searchsorted(r, math.sqrt(r[50] ** 2 + 9.0)))
    assert ghost > 51 and out[ghost].mean() ** 2 == pytest.approx(0.02 ** 2 + 0.25, rel=0.1)
    doubled = run("motion_blur/two_look_average", point(), yaw_rate_deg_s=50.0, surge_m_s=0.0, interval_s=0.2)
    shift = round(math.radians(10.0) / (math.radians(120.0) / (N_BEAMS - 1)))  # 8 beams
    peaks = sorted(np.argsort(doubled[ROW])[-2:])
    assert abs(peaks[1] - peaks[0] - shift) <= 1 and doubled[ROW, peaks].min() ** 2 > 0.4


def test_the_s_curve_keeps_6_bits_and_the_mispointed_pattern_darkens_the_seabed():
    flat = frame_of(np.linspace(0, 1, N_RANGES * N_BEAMS, dtype=np.float32).reshape(N_RANGES, N_BEAMS))
    counts = apply_held_out([flat], "gamma_quantization/s_curve_6bit",
                            {"gain": 1.0, "midpoint": 0.3, "steepness": 8.0}, 0)[0].intensity
    assert counts.dtype == np.uint8 and len(np.unique(counts)) <= 64 and counts.min() == 0 and counts.max() == 255
    lit = frame_of(np.full((N_RANGES, N_BEAMS), 0.5, np.float32))
    on_axis = run("elevation_spread/mispointed_gaussian", lit, beamwidth_deg=10.0, mispoint_deg=0.0)
    off_axis = run("elevation_spread/mispointed_gaussian", lit, beamwidth_deg=10.0, mispoint_deg=6.0)
    assert (on_axis <= 0.5 + 1e-6).all() and np.argmax(on_axis[:, BEAM]) != np.argmax(off_axis[:, BEAM])


def test_steered_beams_gather_from_further_across_the_fan_than_the_beam_on_axis():
    image = np.full((N_RANGES, N_BEAMS), 0.02, np.float32)
    image[ROW, BEAM] = image[ROW, 8] = 1.0  # one echo on axis, one 50 deg off it
    out = run("beam_sidelobes/steered_broadening", frame_of(image), mainlobe_deg=2.0, plateau_db=-20.0)
    assert out[ROW, 8 + 2] > out[ROW, BEAM + 2] and out[ROW + 5, BEAM] == pytest.approx(0.02, rel=0.05)


def test_the_skewed_pulse_trails_after_its_peak_and_the_ringing_beats_near_the_sonar():
    out = run("range_blur/skewed_laplace", point(), resolution_m=0.3, skew=3.0)
    assert out[ROW + 3, BEAM] > out[ROW - 3, BEAM] > 0.02 and out[ROW, BEAM + 3] == pytest.approx(0.02, rel=0.05)
    flat = frame_of(np.full((N_RANGES, N_BEAMS), 0.05, np.float32))
    rung = run("ring_down/damped_ringing", flat, amplitude=0.8, decay_m=0.3, period_m=0.2, beam_spread=0.0)
    near = rung[:12, BEAM]
    assert near.max() > 0.5 and near.min() < 0.3 and rung[150:].mean() == pytest.approx(0.05, rel=1e-3)


def test_the_side_wall_ghost_lands_further_out_and_round_in_bearing_and_recursion_trails_copies():
    out = run("multipath/side_wall", point(), offset_m=1.0, lateral_deg=5.0, reflection=0.6)
    rows = round(1.0 / (10.0 / (N_RANGES - 1)))
    ghost = out[ROW + rows - 1:ROW + rows + 2].max(axis=0)
    assert ghost.max() ** 2 > 0.1 and abs(int(np.argmax(ghost)) - BEAM) >= 2
    trail = run("motion_blur/recursive_average", point(), yaw_rate_deg_s=60.0, surge_m_s=0.0,
                ping_interval_s=0.1, memory=0.6)
    shift = math.radians(6.0) / (math.radians(120.0) / (N_BEAMS - 1))  # 4.75 beams a ping
    assert trail[ROW, BEAM] > trail[ROW, BEAM + round(shift)] > trail[ROW, BEAM + round(2 * shift)] > 0.02


def test_the_pulse_train_lights_evenly_spaced_rows_and_the_black_level_keeps_32_counts():
    dark = frame_of(np.zeros((N_RANGES, N_BEAMS), np.float32))
    lit = [run("interference/pulse_train", dark, seed=s, count=3, spacing_m=1.0)[:, BEAM]
           for s in range(4)]
    rows = [np.flatnonzero((c > 0.2) & (c >= np.roll(c, 1)) & (c >= np.roll(c, -1))) for c in lit]
    assert any(len(r) >= 2 and np.allclose(np.diff(r), 1.0 / (10.0 / (N_RANGES - 1)), atol=1.5) for r in rows)
    ramp = frame_of(np.linspace(0, 1, N_RANGES * N_BEAMS, dtype=np.float32).reshape(N_RANGES, N_BEAMS))
    counts = apply_held_out([ramp], "gamma_quantization/black_level_5bit",
                            {"gain": 1.0, "black": 0.1, "gamma": 0.7}, 0)[0].intensity
    assert len(np.unique(counts)) == 32 and (counts.reshape(-1)[: N_RANGES * N_BEAMS // 12] == 0).all()


def test_nakagami_draws_share_beams_not_ranges_and_the_agc_floor_moves_from_ping_to_ping():
    flat = frame_of(np.full((N_RANGES, N_BEAMS), 0.5, np.float32))
    out = run("speckle/nakagami_beams", flat, shape_m=0.8, spread_beams=2.0) ** 2
    across = np.corrcoef(out[:, :-1].ravel(), out[:, 1:].ravel())[0, 1]
    along = np.corrcoef(out[:-1].ravel(), out[1:].ravel())[0, 1]
    assert across > 0.3 and abs(along) < 0.05 and out.mean() == pytest.approx(0.25, rel=0.05)
    dark = frame_of(np.zeros((N_RANGES, N_BEAMS), np.float32))
    floors = [run("tvg_noise/agc_floor", dark, seed=s, exponent=1.0, jitter=0.4)[-20:].mean() for s in range(4)]
    assert max(floors) > 1.2 * min(floors)
    rising = run("tvg_noise/agc_floor", dark, exponent=1.0)
    assert rising[-20:].mean() > 5 * rising[:20].mean()


def test_the_lopsided_pattern_darkens_the_seabed_more_on_its_narrow_side():
    lit = frame_of(np.full((N_RANGES, N_BEAMS), 0.5, np.float32))
    wider_above = run("elevation_spread/lopsided_vertical", lit, beamwidth_deg=10.0, lopsided=0.5)
    wider_below = run("elevation_spread/lopsided_vertical", lit, beamwidth_deg=10.0, lopsided=-0.5)
    assert (wider_above <= 0.5 + 1e-6).all() and not np.allclose(wider_above, wider_below)


def test_an_unknown_form_names_the_tuning_forms_and_none_of_the_held_out_ones():
    # a tuning script that misspells a form must not show whoever reads its error what the held-out sets hold
    with pytest.raises(ConfigError) as error:
        find_implementation("speckle/no_such_form")
    message = str(error.value)
    assert next(iter(TUNING)) in message
    unseen = [name for known in REGISTRIES if known is not TUNING for name in known]
    assert unseen and not any(name in message for name in unseen)
