"""The second blind validation set (diagnose/second_blind_forms.py): its registry, its draws, the output contract,
and each form's own physics, on small synthetic frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonar_realism.diagnose.heldout import UNCATALOGUED
from sonar_realism.diagnose.heldout.base import REGISTRIES, find_implementation
from sonar_realism.diagnose.second_blind_forms import (
    SECOND_BLIND,
    chirp_events,
    fouling_sector_deg,
    grain_kernels,
    pulse_width_m,
    ring_extent_m,
    ripple_span_m,
    seabed_elevation,
    streak_centre,
    tvg_gains_db,
)
from sonar_realism.frames import SonarImage
from tests.validation_forms import (
    META,
    apply_form,
    check_draw_ranges,
    check_output_contract,
    check_registry,
    flat_frame,
    make_frame,
    place_covers,
    point_frame,
)

NAMES = sorted(SECOND_BLIND)


def run(name: str, frame: SonarImage, p: dict[str, float], ping: int = 1, instrument: int = 2) -> np.ndarray:
    return apply_form(SECOND_BLIND[name], frame, p, ping, instrument)


def inside(name: str, seed: int = 0) -> dict[str, float]:
    return SECOND_BLIND[name].draw("inside", np.random.default_rng(seed))


def row_of(frame: SonarImage, r: float) -> int:
    return int(np.argmin(np.abs(frame.ranges_m - r)))


# --- registry and draws ----------------------------------------------------------------------------------------------

def test_registry_holds_every_family_once_and_two_uncatalogued_forms() -> None:
    check_registry(SECOND_BLIND)
    assert SECOND_BLIND in REGISTRIES
    assert all(find_implementation(name) is SECOND_BLIND[name] for name in NAMES)
    others = {name for registry in REGISTRIES if registry is not SECOND_BLIND for name in registry}
    assert not others & set(SECOND_BLIND)


@pytest.mark.parametrize("name", NAMES)
def test_draw_ranges_nest_and_stay_inside_the_catalogue_bounds(name: str) -> None:
    entry = SECOND_BLIND[name]
    check_draw_ranges(entry)
    rng = np.random.default_rng(3)
    for _ in range(20):
        drawn = entry.draw("inside", rng)
        assert entry.outside_bounds(drawn) == []
        assert all(entry.params[k].inside[0] <= v <= entry.params[k].inside[1] for k, v in drawn.items())
        drawn = entry.draw("wide", rng)
        assert all(entry.params[k].wide[0] <= v <= entry.params[k].wide[1] for k, v in drawn.items())


# --- output contract -------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", NAMES)
def test_output_contract_determinism_and_change(name: str) -> None:
    check_output_contract(SECOND_BLIND[name])


@pytest.mark.parametrize("name", NAMES)
def test_any_grid_works(name: str) -> None:
    p = inside(name, 2)
    for n_ranges, n_beams, step in ((256, 128, 0.058), (512, 256, 0.029), (100, 40, 0.06)):
        frame = make_frame(n_ranges=n_ranges, n_beams=n_beams, step=step)
        y = run(name, frame, p)
        assert y.shape == (n_ranges, n_beams) and np.all(np.isfinite(y)) and np.all(y >= 0)


@pytest.mark.parametrize("name", [n for n in NAMES if SECOND_BLIND[n].family == UNCATALOGUED])
@pytest.mark.parametrize("mode", ["inside", "wide"])
def test_uncatalogued_place_lies_in_the_frame_and_covers_every_changed_pixel(name: str, mode: str) -> None:
    frame = make_frame(np.random.default_rng(4).uniform(0.1, 0.6, (400, 128)).astype(np.float32))
    bearings, ranges = np.degrees(frame.azimuths_rad), frame.ranges_m
    rng = np.random.default_rng(11)
    for _ in range(6):
        p = SECOND_BLIND[name].draw(mode, rng)
        changed = np.abs(run(name, frame, p) - frame.normalized()) > 1e-6
        assert changed.any()
        place = SECOND_BLIND[name].place(frame, p)
        assert place.range_m and place.bearing_deg
        for lo, hi in place.range_m:
            assert ranges[0] - 1e-9 <= lo < hi <= ranges[-1] + 1e-9
        for lo, hi in place.bearing_deg:
            assert bearings[0] - 1e-9 <= lo < hi <= bearings[-1] + 1e-9
        assert place_covers(frame, changed, place.range_m, place.bearing_deg)


# --- each form's physics ---------------------------------------------------------------------------------------------

def test_elevation_piston_is_a_multiplicative_weight_with_nulls_and_a_roll_that_tilts_it_across_the_fan() -> None:
    name = "elevation_spread/piston_two_way_roll"
    frame = flat_frame(0.5, n_ranges=600)  # 0.3 .. 12.3 m
    p = {"beamwidth_deg": 12.0, "floor_db": -50.0, "roll_deg": 0.0}
    y = run(name, frame, p).astype(np.float64)
    assert np.all(y <= 0.5 + 1e-6)
    np.testing.assert_allclose(run(name, flat_frame(0.25, n_ranges=600), p), y / 2, rtol=1e-5)
    boresight = 63  # of 128 sine-spaced beams, the one nearest 0
    peak = int(np.argmax(y[:, boresight]))
    assert frame.ranges_m[peak] == pytest.approx(1.5 / math.sin(math.radians(10.0)), abs=0.08)
    assert abs(seabed_elevation(frame, 0.0)[peak, boresight]) < math.radians(0.5)
    near = y[:peak, boresight]  # towards the sonar the seabed falls through the pattern's first null
    minima = [i for i in range(1, near.size - 1) if near[i] < near[i - 1] and near[i] <= near[i + 1]]
    assert minima and near[minima[-1]] < 0.02 * 0.5
    assert near[: minima[-1]].max() > 3.0 * near[minima[-1]]  # a sidelobe beyond the null
    bearings = np.degrees(frame.azimuths_rad)
    left, right = int(np.argmin(np.abs(bearings + 30.0))), int(np.argmin(np.abs(bearings - 30.0)))

    def peak_range(weights: np.ndarray, col: int) -> float:
        return float(frame.ranges_m[int(np.argmax(weights[:, col]))])

    assert peak_range(y, left) == pytest.approx(peak_range(y, right), abs=0.03)
    rolled = run(name, frame, {**p, "roll_deg": 5.0})
    assert peak_range(rolled, right) > peak_range(rolled, left) + 1.0
    np.testing.assert_array_equal(rolled, run(name, frame, {**p, "roll_deg": 5.0}, ping=5, instrument=6))


def test_multipath_face_ghosts_at_two_and_three_times_the_range_scaled_by_the_target_squared() -> None:
    name = "multipath/face_double_bounce"
    p = {"reflection_coeff": 0.6, "flutter": 0.0}
    frame = point_frame(100, 50)  # 2.3 m
    r = frame.ranges_m[100]
    y = run(name, frame, p).astype(np.float64)
    added = y ** 2 - frame.normalized().astype(np.float64) ** 2
    np.testing.assert_allclose(np.delete(added, 50, axis=1), 0.0, atol=1e-9)
    first = row_of(frame, 2 * r)
    np.testing.assert_allclose(added[: first - 1], 0.0, atol=1e-9)  # nothing before twice the range
    for order, level in ((2, 0.6 * 0.8 ** 2), (3, 0.6 ** 2 * 0.8 ** 3)):
        ghost = row_of(frame, order * r)
        assert added[ghost - 1: ghost + 2, 50].sum() == pytest.approx(level ** 2, rel=1e-4)
    assert added.sum() == pytest.approx((0.6 * 0.64) ** 2 + (0.36 * 0.512) ** 2, rel=1e-4)
    dim = run(name, point_frame(100, 50, value=0.2), p).astype(np.float64)  # a seabed-level echo: faint ghost
    assert math.sqrt((dim[first - 1: first + 2, 50] ** 2).sum()) == pytest.approx(0.6 * 0.2 ** 2, rel=1e-3)
    fluttering = {**p, "flutter": 0.5}
    levels = {round(float(run(name, frame, fluttering, ping=k)[first - 1: first + 2, 50].max()), 6) for k in range(4)}
    assert len(levels) == 4 and max(levels) <= 0.6 * 0.64 + 1e-6 and min(levels) >= 0.3 * 0.64 * 0.5 - 1e-6


def test_speckle_poisson_scatterers_preserve_power_with_the_compound_index_and_scene_fixed_counts() -> None:
    name = "speckle/poisson_scatterers"
    frame = flat_frame(0.5, meta={**META, "speckle_seed": 1234})
    for n_mean in (1.0, 30.0):
        p = {"scatterers_per_cell": n_mean, "grain_beams": 1.5, "grain_ranges": 1.0}
        intensity = run(name, frame, p).astype(np.float64) ** 2
        across, along = grain_kernels(1.5, 1.0)
        expected_si = 1.0 + 2.0 * float((np.outer(along ** 2, across ** 2) ** 2).sum()) / n_mean
        assert intensity.mean() == pytest.approx(0.25, rel=0.06)
        assert intensity.var() / intensity.mean() ** 2 == pytest.approx(expected_si, rel=0.12)
    dark = make_frame()
    assert np.all(run(name, dark, p)[dark.normalized() == 0] == 0)

    p = {"scatterers_per_cell": 1.0, "grain_beams": 0.8, "grain_ranges": 0.5}

    def correlation(a: SonarImage, b: SonarImage) -> float:
        ia, ib = (run(name, f, p, ping=k).astype(np.float64).ravel() ** 2 for f, k in ((a, 1), (b, 2)))
        return float(np.corrcoef(ia, ib)[0, 1])

    other = flat_frame(0.5, meta={**META, "speckle_seed": 99})
    assert not np.array_equal(run(name, frame, p, ping=1), run(name, frame, p, ping=2))
    assert correlation(frame, frame) > 0.2  # same pose: the scatterers stay, only their phases change
    assert abs(correlation(frame, other)) < 0.05

    def lag1_across(grain: float) -> float:
        z = run(name, frame, {**p, "scatterers_per_cell": 30.0, "grain_beams": grain}).astype(np.float64) ** 2
        z -= z.mean()
        return float((z[:, 1:] * z[:, :-1]).mean() / z.var())
    assert lag1_across(3.0) > lag1_across(0.5) + 0.3


def test_motion_sway_smears_near_echoes_across_more_bearing_than_far_ones_and_surge_along_range() -> None:
    name = "motion_blur/sway_translation"
    col = 63
    sway = {"surge_m_s": 0.0, "sway_m_s": 1.0, "integration_s": 0.2}

    def spread_across(row: int) -> float:
        frame = point_frame(row, col)
        power = run(name, frame, sway).astype(np.float64) ** 2
        assert power[:, col - 40: col + 41].sum() == pytest.approx(power.sum())
        weights = power.sum(axis=0)
        s = np.sin(frame.azimuths_rad)
        mean = (weights * s).sum() / weights.sum()
        return math.sqrt((weights * (s - mean) ** 2).sum() / weights.sum())

    near, far = spread_across(60), spread_across(360)  # 1.5 m and 7.5 m
    assert near > 3.0 * far > 0.0
    frame = point_frame(200, col)
    surge = {"surge_m_s": 1.0, "sway_m_s": 0.0, "integration_s": 0.2}
    power = run(name, frame, surge).astype(np.float64) ** 2
    assert power[:, col].sum() > 0.95 * power.sum()  # at boresight a forward move stays in its beam
    lit = np.nonzero(power[:, col] > 1e-4)[0]
    extent = (lit.max() - lit.min()) * 0.02
    assert 0.5 * 0.2 - 0.04 <= extent <= 1.0 * 0.2 + 0.04  # surge x window, times the ping's 0.5..1
    assert not np.allclose(run(name, frame, {**sway, "surge_m_s": 0.5}, ping=1),
                           run(name, frame, {**sway, "surge_m_s": 0.5}, ping=3))


def test_beam_sidelobes_stay_on_their_row_and_widen_in_the_near_field() -> None:
    name = "beam_sidelobes/near_field_defocus"
    col = 127  # of 256 beams: near boresight
    p = {"mainlobe_deg": 2.0, "fresnel_frac": 0.4, "taper": 0.5}

    def line(row: int, params: dict[str, float]) -> tuple[np.ndarray, SonarImage]:
        frame = point_frame(row, col, n_beams=256)
        y = run(name, frame, params).astype(np.float64)
        np.testing.assert_array_equal(np.delete(y, row, axis=0), 0.0)
        power = y[row] ** 2
        assert power.sum() == pytest.approx(0.64, rel=0.02)
        return power, frame

    def half_power_deg(power: np.ndarray, frame: SonarImage) -> float:
        step_deg = math.degrees(float(np.diff(np.sin(frame.azimuths_rad)).mean()))
        return np.count_nonzero(power >= 0.5 * power.max()) * step_deg

    far, frame = line(390, {**p, "fresnel_frac": 0.03})  # 8.1 m, far field
    assert half_power_deg(far, frame) == pytest.approx(2.0, rel=0.3)
    near, _ = line(10, p)  # 0.5 m, well inside the near field
    assert half_power_deg(near, frame) > 2.0 * half_power_deg(far, frame)
    uniform, _ = line(390, {"mainlobe_deg": 2.0, "fresnel_frac": 0.03, "taper": 0.0})
    hann, _ = line(390, {"mainlobe_deg": 2.0, "fresnel_frac": 0.03, "taper": 1.0})
    wings = np.r_[0:col - 12, col + 13:256]
    assert uniform[wings].sum() > 5.0 * hann[wings].sum()  # the taper lowers the sidelobes
    frame = point_frame(200, col, n_beams=256)
    np.testing.assert_array_equal(run(name, frame, p, ping=1, instrument=2), run(name, frame, p, ping=4, instrument=5))


def test_range_blur_stays_in_its_beam_conserves_power_is_symmetric_and_widens_with_range() -> None:
    name = "range_blur/absorption_broadened_chirp"
    col = 40

    def profile(row: int, p: dict[str, float]) -> np.ndarray:
        frame = point_frame(row, col)
        y = run(name, frame, p).astype(np.float64)
        np.testing.assert_array_equal(np.delete(y, col, axis=1), 0.0)
        power = y[:, col] ** 2
        assert power.sum() == pytest.approx(0.64, rel=1e-3)
        assert power[:row].sum() == pytest.approx(power[row + 1:].sum(), rel=0.05)  # no causal tail
        return power

    def width_m(power: np.ndarray) -> float:
        return np.count_nonzero(power >= 0.5 * power.max()) * 0.02

    p = {"resolution_m": 0.12, "broadening_per_m": 0.3}
    near, far = profile(30, p), profile(370, p)  # 0.9 m and 7.7 m
    ranges = make_frame().ranges_m
    np.testing.assert_allclose(pulse_width_m(make_frame(), p), 0.12 * np.sqrt(1.0 + 0.3 * ranges))
    expected = math.sqrt((1.0 + 0.3 * ranges[370]) / (1.0 + 0.3 * ranges[30]))  # 1.6
    assert width_m(far) / width_m(near) == pytest.approx(expected, rel=0.25)
    fixed = profile(200, {"resolution_m": 0.2, "broadening_per_m": 0.0})
    assert width_m(fixed) == pytest.approx(0.2, abs=0.03)
    null = 200 + round(2.0 * 0.2 / 1.44 / 0.02)  # the Hann-weighted chirp's first null, two bandwidth-delays out
    window = fixed[null - 2: null + 3]
    assert window.min() < 1e-3 * fixed.max()
    assert fixed[null + 3: null + 12].max() > 10.0 * window.min()  # a -31 dB sidelobe beyond it


def test_tvg_gain_ceiling_flattens_the_noise_floor_and_drops_the_signal_beyond_it() -> None:
    name = "tvg_noise/gain_ceiling_coloured"
    p = {"noise_amplitude": 0.0, "tvg_log_coeff_db": 30.0, "absorption_db_per_m": 0.5, "ceiling_frac": 0.6,
         "noise_corr": 0.6}
    frame = flat_frame(0.4)
    needed, applied = tvg_gains_db(frame, p)
    ceiling = 0.3 + 0.6 * (frame.ranges_m[-1] - 0.3)
    gain_db = 20 * np.log10(run(name, frame, p)[:, 5].astype(np.float64) / 0.4)
    before = frame.ranges_m < ceiling
    np.testing.assert_allclose(gain_db[before], 0.0, atol=1e-4)
    np.testing.assert_allclose(gain_db, applied - needed, atol=1e-3)
    assert np.all(np.diff(gain_db[~before]) < 0) and gain_db[-1] < -6.0
    p = {**p, "noise_amplitude": 0.2}
    dark = flat_frame(0.0)
    y = run(name, dark, p).astype(np.float64)
    rms = np.sqrt((y ** 2).mean(axis=1))
    assert rms[-30:].mean() == pytest.approx(0.2, rel=0.08)
    assert rms[~before][:30].mean() == pytest.approx(0.2, rel=0.08)  # flat from the ceiling on
    assert rms[:20].mean() < 0.02 and rms[100] < rms[200] < rms[~before][0] * 1.1
    power = y[~before] ** 2
    power -= power.mean()
    along = float((power[1:] * power[:-1]).mean() / power.var())
    across = float((power[:, 1:] * power[:, :-1]).mean() / power.var())
    assert along == pytest.approx(0.6 ** 2, abs=0.06) and abs(across) < 0.05
    assert not np.allclose(y, run(name, dark, p, ping=5))


def test_interference_streaks_follow_the_squinted_bearing_and_only_add_power() -> None:
    name = "interference/squinted_chirp_streaks"
    p = {"rate_per_ping": 1.0, "amplitude": 0.7, "floor_db": -30.0, "streak_m": 2.0, "sweep_fraction": 0.4}
    frame = make_frame()
    x = frame.normalized().astype(np.float64)
    s = np.sin(frame.azimuths_rad)
    checked = 0
    for ping in range(40):
        direction, events = chirp_events(frame, p, np.random.default_rng(ping), np.random.default_rng(2))
        y = run(name, frame, p, ping=ping).astype(np.float64)
        assert np.all(y >= x - 1e-6)
        spans = [(start, start + p["streak_m"]) for start, _ in events]
        outside = np.ones(frame.n_ranges, bool)
        for lo, hi in spans:
            outside &= ~((frame.ranges_m >= lo) & (frame.ranges_m <= hi))
        np.testing.assert_array_equal(y[outside], x[outside])
        if len(events) != 1 or abs(events[0][1]) < 0.3:
            continue
        start, source = events[0]
        added = y ** 2 - x ** 2
        rows = np.nonzero((frame.ranges_m >= start + 0.3) & (frame.ranges_m <= start + 1.7))[0]
        t = (frame.ranges_m[rows] - start) / p["streak_m"]
        predicted = np.argmin(np.abs(s[None, :] - streak_centre(source, direction, 0.4, t)[:, None]), axis=1)
        found = np.argmax(added[rows], axis=1)
        assert np.all(np.abs(found - predicted) <= 1)
        assert abs(int(found[-1]) - int(found[0])) >= 5  # slanted across the fan
        checked += 1
    assert checked >= 2
    directions = {chirp_events(frame, p, np.random.default_rng(k), np.random.default_rng(2))[0] for k in range(5)}
    assert len(directions) == 1  # the foreign sonar's sweep belongs to the recording


def test_ring_down_saturates_its_plateau_peaks_at_broadside_and_leaves_far_rows_alone() -> None:
    name = "ring_down/saturated_plateau_broadside"
    p = {"amplitude": 0.5, "decay_m": 0.05, "plateau_m": 0.11, "broadside_width": 0.8, "jitter_db": 1.0}
    frame = flat_frame(0.3)
    x = frame.normalized()
    y = run(name, frame, p)
    beyond = frame.ranges_m - frame.ranges_m[0] > ring_extent_m(p)
    np.testing.assert_array_equal(y[beyond], x[beyond])
    plateau = frame.ranges_m - frame.ranges_m[0] <= p["plateau_m"]
    assert plateau.sum() == 6
    np.testing.assert_array_equal(y[plateau], run(name, flat_frame(0.6), p)[plateau])  # the echo is lost there
    row = y[0].astype(np.float64)
    assert abs(np.sin(frame.azimuths_rad[int(np.argmax(row))])) < 0.12
    assert row[0] < 0.4 * row.max() and row[-1] < 0.4 * row.max()
    after = y[~plateau & ~beyond]
    assert np.all(after >= 0.3 - 1e-6) and after[0].max() > 0.35
    ratio = run(name, frame, p, ping=7)[plateau].astype(np.float64) / y[plateau]
    assert np.ptp(ratio) < 1e-5 and abs(ratio[0, 0] - 1.0) > 1e-3  # the level jitters, the shape stays
    shifted = run(name, frame, p, instrument=9)[0]
    assert not np.allclose(shifted / shifted.max(), y[0] / y[0].max())


def test_auto_gain_ignores_the_overall_level_maps_the_percentile_and_lifts_weak_returns() -> None:
    name = "gamma_quantization/auto_gain_percentile"
    values = np.linspace(0.0, 0.8, 400 * 128).reshape(400, 128).astype(np.float32)
    p = {"gamma": 0.4, "target_level": 0.8, "percentile": 99.0}
    counts = run(name, make_frame(values), p)
    assert counts.dtype == np.uint8 and np.all(np.diff(counts.ravel().astype(int)) >= 0)
    halved = run(name, make_frame(values / 2), p)
    assert np.abs(counts.astype(int) - halved.astype(int)).max() <= 1
    reference = np.percentile(values, 99.0)
    at = int(np.argmin(np.abs(values.ravel() - reference)))
    assert abs(int(counts.ravel()[at]) - round(255 * 0.8)) <= 1
    assert counts.max() < 255
    targets = values / 2
    targets.ravel()[::500] = 1.0  # 0.2 % bright targets, twice the 99th percentile: these alone saturate
    saturated = run(name, make_frame(targets), p) == 255
    np.testing.assert_array_equal(saturated.ravel(), targets.ravel() == 1.0)
    weak = int(np.argmin(np.abs(values.ravel() - 0.01 * reference)))
    assert counts.ravel()[weak] >= 25  # 1 % of the reference level: ~32 counts (linear: 2)
    linear = run(name, make_frame(values), {**p, "gamma": 1.0})
    assert abs(int(linear.ravel()[weak]) - 2) <= 1


def test_tvg_table_ripple_is_periodic_on_every_beam_within_its_stretch_and_fixed_for_the_sensor() -> None:
    name = "uncatalogued/tvg_table_ripple"
    p = {"ripple_db": 3.0, "period_m": 0.5, "start_frac": 0.3, "length_frac": 0.4}
    frame = flat_frame(0.3)
    y = run(name, frame, p).astype(np.float64)
    start, end = ripple_span_m(frame, p)
    inside_span = (frame.ranges_m >= start) & (frame.ranges_m <= end)
    np.testing.assert_array_equal(y[~inside_span], 0.3 * np.ones_like(y[~inside_span], np.float32))
    assert np.ptp(y, axis=1).max() < 1e-6  # one gain per range bin, the same on every beam
    gain_db = 20 * np.log10(y[:, 0] / 0.3)
    assert np.abs(gain_db).max() <= 3.0 + 1e-4 and gain_db.max() > 2.5 and gain_db.min() < -2.5
    core = inside_span & (frame.ranges_m > start + 0.1 * (end - start)) & (frame.ranges_m < end - 0.1 * (end - start))
    signs = np.sign(gain_db[core])
    crossings = frame.ranges_m[core][1:][signs[1:] != signs[:-1]]
    np.testing.assert_allclose(np.diff(crossings), 0.25, atol=0.03)
    np.testing.assert_array_equal(run(name, frame, p, ping=5), run(name, frame, p, ping=6))
    assert not np.allclose(run(name, frame, p, instrument=3), run(name, frame, p, instrument=4))


def test_fouled_window_attenuates_and_blurs_one_sector_at_every_range() -> None:
    name = "uncatalogued/fouled_window_sector"
    p = {"centre_frac": -0.3, "width_frac": 0.25, "loss_db": 6.0, "blur_deg": 3.0}
    frame = flat_frame(0.3)
    y = run(name, frame, p).astype(np.float64)
    lo, hi = fouling_sector_deg(frame, p)
    bearings = np.degrees(frame.azimuths_rad)
    sector = (bearings > lo) & (bearings < hi)
    np.testing.assert_array_equal(y[:, ~sector], 0.3 * np.ones_like(y[:, ~sector], np.float32))
    assert np.ptp(y, axis=0).max() < 1e-6  # the same at every range
    loss_db = -20 * np.log10(y[0, sector] / 0.3)
    assert np.all(loss_db > 0) and 3.0 < loss_db.max() <= 6.0 * 1.5 + 1e-6
    centre = int(np.argmin(np.abs(bearings - 0.5 * (lo + hi))))
    far_out = int(np.argmin(np.abs(bearings - 40.0)))
    for col, blurred in ((centre, True), (far_out, False)):
        point = point_frame(200, col)
        power = run(name, point, p).astype(np.float64) ** 2
        lit = np.count_nonzero(power[200] > 1e-6)
        assert (lit > 4) if blurred else (lit == 1 and power[200, col] == pytest.approx(0.64, rel=1e-6))
    np.testing.assert_array_equal(run(name, frame, p, ping=5), run(name, frame, p, ping=6))
