"""Geometry and scene terms as diagnosis candidates (issue 13, item 4): the terms themselves, where a calibration
puts them, and the diagnosis naming the sim's geometry for a mounting difference but not for a sensor effect."""

import dataclasses
import math

import numpy as np
import pytest

from sonar_realism.diagnose import DiagnoseConfig, diagnose, load_diagnosis
from sonar_realism.diagnose.config import SearchConfig
from sonar_realism.diagnose.result import write_diagnosis
from sonar_realism.diagnose.scene_terms import SCENE_TERMS, SceneStart, scene_term_starts
from sonar_realism.diagnose.scene_terms.mounting import Mounting, measured_onset_fraction, onset_of
from sonar_realism.diagnose.scene_terms.seabed import SeabedPatches
from sonar_realism.diagnose.which import corrected_images
from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.sim import SensorConfig, simulate
from sonar_realism.sim.calibration import load_calibration
from sonar_realism.sim.effects import apply_effects, make_effect
from sonar_realism.sim.scene import build_scene

SENSOR = SensorConfig(n_ranges=128, n_beams=128, max_range_m=10.0, elevation_rays=16)
CONFIG = DiagnoseConfig(fit_frames=8, eval_frames=12, bootstrap=50, search=SearchConfig(points=4, rounds=1),
                        effects=("elevation_spread", "tvg_noise", "ring_down"))


def frames(n: int, seed: int, tilt_deg: float | None = None) -> list[SonarImage]:
    """The default scene's clean frames; with `tilt_deg`, the same world and path seen at another tilt."""
    scene = build_scene("default", seed, SENSOR.max_range_m)
    if tilt_deg is not None:
        poses = [dataclasses.replace(p, tilt=math.radians(tilt_deg)) for p in scene.trajectory(n)]
        scene = dataclasses.replace(scene, trajectory=lambda k: poses[:k])
    return [f for f, _ in simulate(scene=scene, n=n, seed=seed, sensor=SENSOR)]


def calibrated_as(frame: SonarImage, tilt_deg: float) -> SceneStart:
    """What a calibration of the "real" frames would say, a little off (height 15 % high, tilt 2 deg more)."""
    return SceneStart(height_fraction=1.15 * frame.meta["sonar_altitude_m"] / SENSOR.max_range_m,
                      tilt_deg=tilt_deg + 2.0, vertical_fov_deg=SENSOR.vertical_fov_deg, patch_contrast=0.5,
                      patch_scale_fraction=0.05)


def test_mounting_moves_the_onset_by_whole_rows():
    sim = frames(4, seed=1)
    images = corrected_images(sim, [], 0, "max")
    sim_onset = measured_onset_fraction(images)
    term = Mounting(onset_adjust=0.0, calibrated_onset_fraction=sim_onset + 0.15, sim_onset_fraction=sim_onset)
    moved = corrected_images(sim, [term], 0, "max")
    assert measured_onset_fraction(moved) == pytest.approx(sim_onset + 0.15, abs=0.03)
    # rows are moved, never interpolated: every output row is one of the frame's rows (the grain stays the sim's)
    rows = {r.tobytes() for r in images[0]}
    assert all(r.tobytes() in rows for r in moved[0])
    identity = dataclasses.replace(term, calibrated_onset_fraction=sim_onset)  # and no skirt (at its bound)
    np.testing.assert_array_equal(corrected_images(sim, [identity], 0), corrected_images(sim, [], 0))
    # the vertical pattern's skirt lights the black rows between the nadir and the onset, rising towards it
    skirted = dataclasses.replace(identity, skirt_db=-12.0, height_fraction=0.1)
    lit = corrected_images(sim, [skirted], 0, "max")
    rows = lit.mean(axis=(0, 2))
    n = len(rows)
    nadir, onset = int(0.1 * (n - 1)) + 1, int(sim_onset * (n - 1))
    assert np.array_equal(lit[:, :nadir], images[:, :nadir])
    assert np.all(rows[nadir:onset] > images.mean(axis=(0, 2))[nadir:onset])
    assert rows[onset - 3] > 2 * rows[nadir + 1]


def test_seabed_patches_keep_the_mean_power_and_add_contrast():
    flat = np.full((20, 64, 64), 0.3, dtype=np.float32)
    frame = frames(1, seed=1)[0]
    patched = SeabedPatches(patch_contrast=0.8, patch_scale_fraction=0.05).apply(flat, frame,
                                                                                   np.random.default_rng(0))
    assert np.mean(patched ** 2) == pytest.approx(0.09, rel=0.25)
    assert np.std(np.log(patched)) == pytest.approx(0.8, rel=0.3)
    untouched = SeabedPatches(patch_contrast=0.0).apply(flat, frame, np.random.default_rng(0))
    np.testing.assert_allclose(untouched, flat)


def test_the_shipped_calibration_gives_a_start_for_every_term():
    start = SceneStart.from_calibration(load_calibration("oculus"))
    assert 0.02 < start.height_fraction < 0.5 and 0.1 < onset_of(start) < 0.9
    terms = scene_term_starts(corrected_images(frames(4, seed=1), [], 0, "max"), start)
    assert set(terms) == set(SCENE_TERMS) == {"mounting", "seabed"}
    assert {t.KIND for t in terms.values()} == {"geometry", "scene"}
    with pytest.raises(ConfigError, match="height_fraction"):
        dataclasses.replace(start, height_fraction=0.0).validate()


def test_a_different_mounting_is_blamed_on_the_geometry_not_on_a_sensor_effect(tmp_path):
    # "Real": the sim's own world and path with the sonar tilted 20 deg instead of 15 (the seabed starts nearer).
    # (A shallower tilt, 5-8 deg, is taken by elevation_spread first: it reshapes the profile over elevation,
    # which the rigid shift of the mounting term does not; docs/diagnosis.md, Limits.)
    # The evidence is thin at this size: the mounting closes 34 % with a one-sided lower bound of the gain of 1.5-2 %
    # of the gap before (50 resamples; 1.5 % on the 2026-11-23 machine at every commit, 2 % before), so any gain
    # whose lower bound is above zero is worth naming here, not 5 %.
    sim = frames(24, seed=1)
    real = frames(24, seed=1, tilt_deg=20.0)
    result = diagnose(sim, real, dataclasses.replace(CONFIG, min_gain=0.0), scene=calibrated_as(real[0], 20.0))
    assert result.selected == ("mounting",)
    assert result.selected_effects[0].kind == "geometry"
    assert result.blamed_on_setup() == result.selected_effects
    assert result.gap_closed > 0.2
    assert {r.kind for r in result.ranked_effects} == {"effect", "geometry", "scene"}
    assert result.scene_start is not None
    back = load_diagnosis(write_diagnosis(result, tmp_path / "diagnosis.json"))
    assert back.selected_effects == result.selected_effects and back.scene_start == result.scene_start
    assert [r.kind for r in back.ranked_effects] == [r.kind for r in result.ranked_effects]


def test_a_pure_sensor_effect_is_not_blamed_on_the_geometry():
    sim = frames(24, seed=1)
    noise = make_effect("tvg_noise", noise_amplitude=0.12)
    real = [apply_effects(f, [noise], np.random.default_rng(i)) for i, f in enumerate(frames(24, seed=2))]
    result = diagnose(sim, real, CONFIG, scene=calibrated_as(real[0], 15.0))
    # tvg_noise first, by far (0.90 of the gap); elevation_spread may take a second share of this small set's
    # residual (0.24 on the 2026-11-23 machine at every commit, none before): neither is the geometry
    assert result.selected[0] == "tvg_noise" and "mounting" not in result.selected
    assert result.blamed_on_setup() == ()
