"""The second tuning set (sonar_realism/diagnose/tuning_forms.py): one more form per catalogued effect, each
doing what its physics says, fixed by its seed, drawn inside the fit bounds (and wider), and kept out of the
held-out half's registry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonar_realism.diagnose.heldout import IMPLEMENTATIONS, apply_held_out
from sonar_realism.diagnose.tuning_forms import TUNING
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
