"""The blind validation set (diagnose/blind_forms.py): its registry, its draws, the output contract, and each
form's own physics, on small synthetic frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonar_realism.diagnose.blind_forms import BLIND, _ring_extent_m, _stepped_gain_db
from sonar_realism.diagnose.heldout import UNCATALOGUED
from sonar_realism.frames import SonarImage
from tests.validation_forms import (
    apply_form,
    check_draw_ranges,
    check_output_contract,
    check_registry,
    make_frame,
    place_covers,
    point_frame,
)

NAMES = sorted(BLIND)


def run(name: str, frame: SonarImage, p: dict[str, float], ping: int = 1, instrument: int = 2) -> np.ndarray:
    return apply_form(BLIND[name], frame, p, ping, instrument)


def inside(name: str, seed: int = 0) -> dict[str, float]:
    return BLIND[name].draw("inside", np.random.default_rng(seed))


# --- registry and draws ----------------------------------------------------------------------------------------------

def test_registry_holds_every_family_once_and_two_uncatalogued_forms() -> None:
    check_registry(BLIND)


@pytest.mark.parametrize("name", NAMES)
def test_draw_ranges_nest_and_stay_inside_the_catalogue_bounds(name: str) -> None:
    entry = BLIND[name]
    check_draw_ranges(entry)
    rng = np.random.default_rng(3)
    for _ in range(20):
        assert entry.outside_bounds(entry.draw("inside", rng)) == []


# --- output contract -------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", NAMES)
def test_output_contract_determinism_and_change(name: str) -> None:
    check_output_contract(BLIND[name])


@pytest.mark.parametrize("name", [n for n in NAMES if BLIND[n].family == UNCATALOGUED])
@pytest.mark.parametrize("mode", ["inside", "wide"])
def test_uncatalogued_place_covers_every_changed_pixel(name: str, mode: str) -> None:
    frame = make_frame(np.full((400, 128), 0.3, np.float32))
    rng = np.random.default_rng(11)
    for _ in range(6):
        p = BLIND[name].draw(mode, rng)
        changed = np.abs(run(name, frame, p) - frame.normalized()) > 1e-6
        assert changed.any()
        place = BLIND[name].place(frame, p)
        assert place_covers(frame, changed, place.range_m, place.bearing_deg)


# --- each form's physics ---------------------------------------------------------------------------------------------

def test_elevation_is_a_multiplicative_weight_peaking_where_the_seabed_is_on_axis_per_bearing() -> None:
    name = "elevation_spread/gaussian_two_way_beam"
    frame = make_frame(np.full((600, 128), 0.5, np.float32))  # 0.3 .. 12.3 m
    p = {"beamwidth_deg": 12.0, "floor_db": -30.0}
    y = run(name, frame, p)
    assert np.all(y <= 0.5 + 1e-6)
    np.testing.assert_allclose(run(name, make_frame(np.full((600, 128), 0.25, np.float32)), p), y / 2, rtol=1e-5)
    on_axis = 1.5 / math.sin(math.radians(10.0))
    boresight = int(np.argmin(np.abs(frame.azimuths_rad)))
    assert frame.ranges_m[np.argmax(y[:, boresight])] == pytest.approx(on_axis, abs=0.05)
    off = int(np.argmin(np.abs(frame.azimuths_rad - math.radians(30.0))))
    assert frame.ranges_m[np.argmax(y[:, off])] > on_axis + 0.8  # the seabed meets the axis later off boresight


def test_multipath_ghost_only_beyond_the_direct_return_with_an_offset_that_shrinks_with_range() -> None:
    name = "multipath/surface_bounce_pair"
    p = {"reflection_coeff": 0.5, "surface_height_m": 2.0, "tail_m": 0.05}
    offsets = []
    for r_target in (2.0, 7.0):
        row = int(round((r_target - 0.3) / 0.02))
        frame = point_frame(row, 50)
        y = run(name, frame, p)
        added = y.astype(np.float64) ** 2 - frame.normalized().astype(np.float64) ** 2
        np.testing.assert_allclose(added[: row + 1], 0.0, atol=1e-9)
        np.testing.assert_allclose(np.delete(added, 50, axis=1), 0.0, atol=1e-9)
        assert added[row + 1:, 50].sum() > 0.01
        r = frame.ranges_m[row]
        expected = (math.sqrt(r * r + 4.0 * 4.0) - r) / 2.0
        offset = frame.ranges_m[row + 1 + int(np.argmax(added[row + 1:, 50]))] - r
        assert offset == pytest.approx(expected, abs=0.05)
        offsets.append(offset)
    assert offsets[0] > offsets[1] + 0.3


def test_speckle_is_multiplicative_power_preserving_with_the_rician_lognormal_index_and_new_each_ping() -> None:
    name = "speckle/rician_lognormal_ar"
    p = {"shape_nu": 5.0, "grain_beams": 1.5, "grain_ranges": 1.0, "diffuse_fraction": 0.9}
    frame = make_frame(np.full((400, 128), 0.5, np.float32))
    y = run(name, frame, p).astype(np.float64)
    intensity = y ** 2
    assert intensity.mean() == pytest.approx(0.25, rel=0.1)
    d, c = 0.9, 0.1
    expected_si = (1 + 2 * c * d + d * d) * (1 + 1 / 5.0) - 1
    assert intensity.var() / intensity.mean() ** 2 == pytest.approx(expected_si, rel=0.2)
    assert not np.array_equal(y, run(name, frame, p, ping=7))
    dark = make_frame()
    assert np.all(run(name, dark, p)[dark.normalized() == 0] == 0)

    def lag1_across(grain: float) -> float:
        z = run(name, frame, {**p, "grain_beams": grain}).astype(np.float64) ** 2
        z -= z.mean()
        return float((z[:, 1:] * z[:, :-1]).mean() / z.var())
    assert lag1_across(3.0) > lag1_across(0.4) + 0.2


def test_motion_blur_yaw_leaves_discrete_copies_along_the_row_and_surge_moves_along_the_beam() -> None:
    name = "motion_blur/discrete_look_average"
    row, col = 250, 64
    frame = point_frame(row, col)
    y = run(name, frame, {"yaw_rate_deg_s": 40.0, "surge_m_s": 0.0, "window_s": 0.2, "n_looks": 3.0})
    np.testing.assert_array_equal(np.delete(y, row, axis=0), 0.0)  # a rotation never changes range
    line = y[row].astype(np.float64)
    peaks = [i for i in range(1, line.size - 1) if line[i] > 0.05 and line[i] >= line[i - 1] and line[i] > line[i + 1]]
    assert len(peaks) == 3
    y = run(name, frame, {"yaw_rate_deg_s": 0.0, "surge_m_s": 1.0, "window_s": 0.2, "n_looks": 3.0})
    power = y.astype(np.float64) ** 2
    assert power[:, col].sum() > 0.95 * power.sum()  # near boresight a surge moves echoes along their beam
    lit = np.nonzero(power[:, col] > 0.02)[0]
    assert lit.tolist() == [row - 5, row, row + 5]  # +-0.1 m of surge at 2 cm bins


def test_beam_sidelobes_stay_on_the_row_with_the_mainlobe_width_and_a_fixed_instrument_floor() -> None:
    name = "beam_sidelobes/hann_array_element_errors"
    row, col = 200, 64
    frame = point_frame(row, col)
    p = {"mainlobe_deg": 2.0, "error_floor_db": -20.0}
    y = run(name, frame, p).astype(np.float64)
    np.testing.assert_array_equal(np.delete(y, row, axis=0), 0.0)
    line = y[row] ** 2
    step_deg = math.degrees(float(np.diff(np.sin(frame.azimuths_rad)).mean()))
    assert np.count_nonzero(line >= 0.5 * line.max()) * step_deg == pytest.approx(2.0, rel=0.35)
    far = np.r_[line[: col - 20], line[col + 21:]]
    assert 10 * math.log10(far.mean() / line.max()) == pytest.approx(-20.0, abs=4.0)
    np.testing.assert_array_equal(run(name, frame, p, ping=1), run(name, frame, p, ping=8))
    assert not np.allclose(run(name, frame, p, instrument=2), run(name, frame, p, instrument=3))


def test_range_blur_stays_in_its_beam_conserves_power_and_trails_towards_longer_range() -> None:
    name = "range_blur/triangle_rc_tail"
    row, col = 200, 40
    frame = point_frame(row, col)
    p = {"resolution_m": 0.1, "tail_m": 0.06}
    y = run(name, frame, p).astype(np.float64)
    np.testing.assert_array_equal(np.delete(y, col, axis=1), 0.0)
    power = y[:, col] ** 2
    assert power.sum() == pytest.approx(0.64, rel=1e-3)
    assert np.all(power[: row - 5] < 1e-12)  # nothing before the triangle's half base (0.1 m = 5 bins)
    assert power[row + 1:].sum() > 2.0 * power[:row].sum()


def test_tvg_steps_leave_a_bounded_sawtooth_and_the_noise_is_new_each_ping_at_its_amplitude() -> None:
    name = "tvg_noise/stepped_gain_multilook"
    p = {"noise_amplitude": 0.0, "tvg_log_coeff_db": 30.0, "absorption_db_per_m": 0.5, "step_db": 6.0,
         "looks": 2.0}
    frame = make_frame(np.full((400, 128), 0.4, np.float32))
    ratio_db = 20 * np.log10(run(name, frame, p)[:, 0].astype(np.float64) / 0.4)
    assert np.all(np.abs(ratio_db) <= 3.0 + 1e-4)
    assert ratio_db.max() - ratio_db.min() > 4.0
    p = {**p, "noise_amplitude": 0.2}
    dark = make_frame(np.zeros((400, 128), np.float32))
    y = run(name, dark, p).astype(np.float64)
    assert not np.allclose(y, run(name, dark, p, ping=5))
    _, actual = _stepped_gain_db(dark, p)
    last_step = actual == actual[-1]
    assert math.sqrt((y[last_step] ** 2).mean()) == pytest.approx(0.2, rel=0.1)
    assert math.sqrt((y[:20] ** 2).mean()) < 0.05  # the floor follows the TVG: low near the sonar


def test_interference_comb_moves_each_ping_from_one_fixed_bearing_at_a_regular_spacing() -> None:
    name = "interference/periodic_pulse_comb"
    p = {"amplitude": 0.6, "thickness_m": 0.06, "repeat_m": 2.5, "spread_deg": 5.0}
    frame = make_frame()
    x = frame.normalized().astype(np.float64)
    first, second = (run(name, frame, p, ping=k).astype(np.float64) for k in (1, 2))
    assert np.all(first >= x - 1e-6)
    assert not np.allclose(first, second)
    sources = [int(np.argmax((y ** 2 - x ** 2).sum(axis=0))) for y in (first, second)]
    assert sources[0] == sources[1]
    rows = np.nonzero((first ** 2 - x ** 2)[:, sources[0]] > 0.05)[0]
    starts = frame.ranges_m[rows[np.r_[True, np.diff(rows) > 1]]]
    assert len(starts) >= 3
    np.testing.assert_allclose(np.diff(starts), 2.5, atol=0.05)


def test_ring_down_leaves_far_rows_untouched_beats_along_range_and_is_fixed_for_the_recording() -> None:
    name = "ring_down/beating_fixed_pattern"
    p = {"amplitude": 0.7, "decay_m": 0.1, "beam_ripple": 0.4, "beat_m": 0.06, "beat_depth": 0.8}
    frame = make_frame()
    x = frame.normalized()
    y = run(name, frame, p)
    beyond = frame.ranges_m - frame.ranges_m[0] > _ring_extent_m(p)
    np.testing.assert_array_equal(y[beyond], x[beyond])
    assert y[0].min() > 0.1
    envelope = y[:20, 10].astype(np.float64)
    assert np.any((envelope[1:-1] < envelope[:-2]) & (envelope[1:-1] < envelope[2:]))  # beat fringes
    np.testing.assert_array_equal(y, run(name, frame, p, ping=9))
    assert not np.allclose(y[0], run(name, frame, p, instrument=4)[0])


def test_mu_law_is_monotone_lifts_weak_returns_truncates_and_saturates() -> None:
    name = "gamma_quantization/mu_law_truncate"
    values = np.linspace(0.0, 1.0, 400 * 128).reshape(400, 128).astype(np.float32)
    frame = make_frame(values)
    counts = run(name, frame, {"gain": 1.0, "mu": 255.0})
    assert counts.dtype == np.uint8 and np.all(np.diff(counts.ravel().astype(int)) >= 0)
    exact = 255 * np.log1p(255 * values.astype(np.float64)) / math.log1p(255)
    assert np.all(counts <= exact + 1e-9) and np.all(counts > exact - 1)  # floor, not round
    assert counts[values > 0.0099].min() >= 50  # 1 % amplitude lifted to ~58 counts (linear: 2)
    assert run(name, frame, {"gain": 3.0, "mu": 255.0})[values > 0.34].min() == 255
    nearly_linear = run(name, frame, {"gain": 1.0, "mu": 0.5}).astype(int)
    assert np.abs(nearly_linear - np.floor(255 * values)).max() <= 16


def test_bracket_arc_is_bright_at_its_range_and_shadows_the_sector_behind_it() -> None:
    name = "uncatalogued/bracket_arc_shadow"
    p = {"arc_range_m": 2.0, "arc_thickness_m": 0.03, "sector_center_deg": 10.0, "sector_width_deg": 14.0,
         "brightness": 0.7, "shadow_db": -10.0}
    frame = make_frame(np.full((400, 128), 0.3, np.float32))
    y = run(name, frame, p).astype(np.float64)
    bearings = np.degrees(frame.azimuths_rad)
    centre, outside = int(np.argmin(np.abs(bearings - 10.0))), int(np.argmin(np.abs(bearings + 30.0)))
    arc_row = int(np.argmax(y[:, centre]))
    assert frame.ranges_m[arc_row] == pytest.approx(2.0, abs=0.02)
    assert y[arc_row, centre] == pytest.approx(math.hypot(0.3, 0.7), rel=0.02)
    assert y[-1, centre] == pytest.approx(0.3 * 10 ** (-0.5), rel=1e-4)
    np.testing.assert_allclose(y[:, outside], 0.3, rtol=1e-6)


def test_board_gain_changes_one_contiguous_group_of_beams_and_flickers_per_ping() -> None:
    name = "uncatalogued/beam_board_gain"
    p = {"centre_deg": -20.0, "board_beams": 24.0, "gain_db": -6.0, "flicker_db": 1.0}
    frame = make_frame(np.full((400, 128), 0.3, np.float32))
    y = run(name, frame, p)
    cols = np.nonzero(np.any(np.abs(y - 0.3) > 1e-6, axis=0))[0]
    assert cols.size == 24 and np.all(np.diff(cols) == 1)
    assert np.ptp(y[:, cols]) < 1e-6  # one gain for the whole board, at every range
    gains = {float(run(name, frame, p, ping=k)[0, cols[0]]) for k in range(4)}
    assert len(gains) == 4
