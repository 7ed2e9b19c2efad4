"""Small blind runs: effects made by other implementations are identified; a withheld effect that is not in the
catalogue stays as residual, found in the right place."""

import numpy as np
import pytest

from sonar_realism.diagnose import diagnose
from sonar_realism.diagnose.config import DiagnoseConfig, SearchConfig
from sonar_realism.diagnose.validation import (
    ALTERNATIVES,
    HIDDEN_RANGES,
    WITHHELD,
    blind_run,
    check_catalogue_defaults,
    make_real,
)
from sonar_realism.errors import ConfigError
from sonar_realism.geometry import resample_to_grid
from sonar_realism.sim import SensorConfig, simulate
from sonar_realism.sim.calibrated import simulate_calibrated
from sonar_realism.sim.calibration import load_calibration
from sonar_realism.sim.effects import EFFECTS

SENSOR = SensorConfig(n_ranges=128, n_beams=128, max_range_m=10.0, elevation_rays=16)
CANDIDATES = ("speckle", "beam_sidelobes", "tvg_noise", "interference", "ring_down", "gamma_quantization")
CONFIG = DiagnoseConfig(fit_frames=4, eval_frames=8, real_frames=8, bootstrap=40, effects=CANDIDATES,
                        search=SearchConfig(points=4, rounds=1))


@pytest.fixture(scope="module")
def sets():
    sim = [frame for frame, _ in simulate(n=12, seed=7, sensor=SENSOR)]
    real_source = [frame for frame, _ in simulate(n=12, seed=8, sensor=SENSOR)]
    return sim, real_source


def test_every_catalogue_effect_has_an_alternative_and_hidden_ranges_inside_its_bounds():
    assert set(EFFECTS) | set(WITHHELD) == set(ALTERNATIVES)
    assert set(HIDDEN_RANGES) == set(EFFECTS)
    check_catalogue_defaults()


@pytest.mark.parametrize("name, params", [
    ("speckle", {"shape_nu": 3.0, "grain_beams": 1.2, "grain_ranges": 0.8}),
    ("gamma_quantization", {"gain": 1.5, "gamma": 0.5}),
])
def test_single_effect_by_another_implementation_is_identified(sets, name, params):
    blind = blind_run(*sets, {name: params}, CONFIG)
    assert blind.diagnosis.top1 == name
    assert blind.diagnosis.selected[:1] == (name,)
    assert blind.diagnosis.gap_closed > 0.6
    assert blind.param_error[name] < 0.35


def test_withheld_lens_reflection_is_left_as_residual_at_its_range():
    # Sim and "real" alternate along one trajectory, so the withheld band is the only systematic difference
    # (two different scenes differ in ways that 8 held-out frames cannot tell from the band).
    frames = [frame for frame, _ in simulate(n=32, seed=7, sensor=SENSOR)]
    hidden = {"lens_reflection": {"at_fraction": 0.62, "width_fraction": 0.02, "amplitude": 0.5}}
    diagnosis = blind_run(frames[0::2], frames[1::2], hidden, CONFIG).diagnosis
    residual = diagnosis.residual
    assert diagnosis.gap_closed < 0.5  # no catalogued effect explains a fixed bright band
    assert residual.significant
    band_m = SENSOR.min_range_m + 0.62 * (SENSOR.max_range_m - SENSOR.min_range_m)
    for cell in residual.where.cells[:3]:  # the residual lies along the band's range, whatever the bearing
        assert cell.range_m[0] - 0.7 <= band_m <= cell.range_m[1] + 0.7


def test_no_effect_is_selected_when_nothing_was_hidden():
    # Sim and "real" alternate along one trajectory and nothing is hidden: whatever the fits find is sampling
    # noise, which the significance test must refuse.
    frames = [frame for frame, _ in simulate(n=32, seed=9, sensor=SENSOR)]
    diagnosis = blind_run(frames[0::2], frames[1::2], {}, CONFIG).diagnosis
    assert diagnosis.selected == ()
    assert diagnosis.verdict == "residual_only" and diagnosis.selection_stopped


def test_make_real_rejects_effects_it_cannot_make(sets):
    with pytest.raises(ConfigError, match="no alternative implementation"):
        make_real(sets[0][:1], {"sparkle": {}}, seed=0)
    real = make_real(sets[0][:2], {"beam_gain_ripple": {}}, seed=0)
    assert real[0].same_geometry(sets[0][0])
    assert not np.array_equal(real[0].normalized(), sets[0][0].normalized())


def test_multipath_alternative_stays_finite_where_the_far_range_is_empty(sets):
    # The calibrated scene has rows with no echo at all beyond bright ones; the ghost's box smear must not turn
    # their zero power negative (it did: NaN frames on `calibrated`).
    frame = sets[0][0]
    rng = np.random.default_rng(0)
    x = np.zeros((frame.n_ranges, frame.n_beams), np.float32)
    x[:60] = (rng.random((60, frame.n_beams)) ** 4 * 0.3).astype(np.float32)
    out = ALTERNATIVES["multipath"](x, frame, {"reflection_coeff": 0.6, "ghost_offset_m": 2.0}, rng)
    assert np.isfinite(out).all()
    assert (out[60:] > 0).any()  # the ghost did land in the empty far range


def test_a_fixed_band_on_a_varied_scene_is_not_blamed_on_interference():
    # Views of the calibrated sensor vary in level, so a level, ramp and shape fitted on a few of them fail on
    # held-out frames; interference fitted as a wide band at random ranges then beat that pattern, and the band
    # was named "interference". Its rows are lit in every real frame: not arcs that move (and the band alone,
    # judged as an effect is, holds where the band is).
    calibration = load_calibration("sonar_realism/assets/oculus_calibration.json")

    def views(seed: int) -> list:
        return [resample_to_grid(f, 256, 128) for f, _ in simulate_calibrated(calibration, 40, seed, chain=[])]

    real = make_real(views(22), {"lens_reflection": {"at_fraction": 0.8, "width_fraction": 0.02, "amplitude": 0.6}}, 5)
    diagnosis = diagnose(views(11), real, DiagnoseConfig(effects=("interference", "multipath", "ring_down",
                                                                   "range_blur")))
    assert diagnosis.selected == ()
    assert [u.effect for u in diagnosis.unconfirmed] == ["interference"]
    assert "stands out in 100% of the real frames" in diagnosis.unconfirmed[0].signature
