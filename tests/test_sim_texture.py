"""The recording's own texture in the calibrated simulator: fitted from real frames, saved in CALIB.json,
drawn in place of the catalogue's speckle and output mapping."""

from __future__ import annotations

import base64
import dataclasses
import json

import numpy as np
import pytest
import torch
from safetensors.torch import save

from sonar_realism.errors import ConfigError
from sonar_realism.models.speckle_fit import top_ratio
from sonar_realism.sim.calibrate import effect_in, match_export_knee, match_noise_floor, sim_images
from sonar_realism.sim.calibrated import calibrated_chain, calibrated_view, finish, texture_levels
from sonar_realism.sim.calibration import load_calibration, save_calibration
from sonar_realism.sim.effects import TvgNoise
from sonar_realism.sim.fingerprint import distance, fingerprint
from sonar_realism.sim.measure import near_zero_fraction
from sonar_realism.sim.texture import LearnedSensorTexture, fit_learned_texture, fit_row_gain, fit_texture, local_mean
from tests.test_sim_calibrate import truth


def grainy_frames(n: int = 4, seed: int = 0) -> list[np.ndarray]:
    """Frames with a smooth level and strongly beam-correlated speckle (stripes along range)."""
    rng = np.random.default_rng(seed)
    rows, cols = 160, 128
    level = np.linspace(0.2, 1.0, rows)[:, None] * np.ones((1, cols))
    frames = []
    for _ in range(n):
        grain = rng.gamma(1.0, 1.0, (rows, cols // 4)).repeat(4, axis=1)  # 4 beams share each draw
        image = level * grain
        frames.append((image / image.max()).astype(np.float32))
    return frames


def correlation_across_beams(frame: np.ndarray) -> float:
    """Lag-1 correlation across beams of the frame's ratio to its local mean, where the level is not dark."""
    image = frame.astype(np.float64)
    level = local_mean(image)
    ratio = image / np.maximum(level, 1.0)
    bright = (level > 20)[:, :-1]
    return float(np.corrcoef(ratio[:, :-1][bright], ratio[:, 1:][bright])[0, 1])


@pytest.fixture(scope="module")
def texture():
    return fit_texture(grainy_frames())


def test_fitted_texture_reproduces_the_grain_across_beams(texture) -> None:
    calibration = dataclasses.replace(truth(), texture=texture)
    clean, _ = calibrated_view(calibration, 0, 0)
    chain = calibrated_chain(calibration, "all")
    frame = finish(calibration, clean, chain, np.random.default_rng(1))
    assert frame.intensity.dtype == np.uint8 and frame.intensity.max() == 255
    across = correlation_across_beams(frame.intensity)
    assert across > 0.4  # the fitted kernel carries the 4-beam correlation
    assert correlation_across_beams(finish(truth(), clean, chain, np.random.default_rng(1)).intensity) < across
    again = finish(calibration, clean, chain, np.random.default_rng(2)).intensity
    assert not np.array_equal(again, frame.intensity)  # a fresh draw per frame


def test_texture_is_drawn_only_when_the_chain_asks_for_speckle(texture) -> None:
    calibration = dataclasses.replace(truth(), texture=texture)
    clean, _ = calibrated_view(calibration, 0, 0)
    none = finish(calibration, clean, calibrated_chain(calibration, "none"), np.random.default_rng(0))
    np.testing.assert_array_equal(
        none.intensity, finish(truth(), clean, calibrated_chain(truth(), "none"), np.random.default_rng(0)).intensity)


def test_texture_round_trips_through_calib_json_and_bad_tables_are_refused(texture, tmp_path) -> None:
    path = tmp_path / "calib.json"
    save_calibration(dataclasses.replace(truth(), texture=texture), path)
    assert load_calibration(path).texture == texture
    data = json.loads(path.read_text())
    data["texture"]["kernel"] = data["texture"]["kernel"][:-1]  # a grain group short
    path.write_text(json.dumps(data))
    with pytest.raises(ConfigError, match="texture.kernel"):
        load_calibration(path)
    with pytest.raises(ConfigError, match="64 x 64"):
        fit_texture([np.ones((32, 32), np.float32)])


def row_gain_frames(gain_sd: float, n: int = 12, seed: int = 0) -> list[np.ndarray]:
    """Frames whose every range row carries one gain across all beams (log-normal, `gain_sd`), over speckle."""
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(n):
        image = rng.gamma(1.0, 1.0, (200, 128)) * np.exp(gain_sd * rng.standard_normal(200))[:, None]
        frames.append((image / image.max()).astype(np.float32))
    return frames


def test_row_gain_fit_keeps_only_the_gain_the_whole_fan_shares() -> None:
    """Speckle averaged over a row moves its mean too (~9 % here); the fit keeps the shared gain alone."""
    for true_sd in (0.0, 0.05, 0.15):
        table = np.asarray(fit_row_gain(row_gain_frames(true_sd)))
        spread = (np.interp(0.84, np.linspace(0.005, 0.995, table.size), table)
                  - np.interp(0.16, np.linspace(0.005, 0.995, table.size), table)) / 2
        assert spread == pytest.approx(true_sd, abs=0.02), (true_sd, spread)


def test_row_gain_draws_lines_across_the_fan_and_old_files_without_it_still_load(texture, tmp_path) -> None:
    with_rows = dataclasses.replace(texture, row_gain_log_quantiles=fit_row_gain(row_gain_frames(0.15)))
    # output gain low enough that nothing saturates: saturation (after the row gain, as in a receiver) clips lines
    effects = {**truth().effects, "gamma_quantization": {**truth().effects["gamma_quantization"], "gain": 0.3}}
    calibration = dataclasses.replace(truth(), texture=with_rows, effects=effects)
    clean, _ = calibrated_view(calibration, 0, 0)
    chain = calibrated_chain(calibration, "all")

    def row_means(texture_used) -> np.ndarray:
        frame = finish(dataclasses.replace(calibration, texture=texture_used), clean, chain, np.random.default_rng(1))
        return frame.intensity.astype(np.float64).mean(axis=1)

    # same seed, so the same speckle: the rows differ by their drawn gain alone, one gain per row
    plain, lined = row_means(texture), row_means(with_rows)
    lit = plain > 20
    assert np.std(np.log(lined[lit] / plain[lit])) == pytest.approx(0.15, abs=0.05)
    path = tmp_path / "calib.json"
    save_calibration(dataclasses.replace(truth(), texture=texture), path)
    data = json.loads(path.read_text())
    del data["texture"]["row_gain_log_quantiles"]  # a file fitted before the row gain existed
    path.write_text(json.dumps(data))
    assert load_calibration(path).texture.row_gain_log_quantiles == ()
    data["texture"]["row_gain_log_quantiles"] = [0.1, 0.0]
    path.write_text(json.dumps(data))
    with pytest.raises(ConfigError, match="row_gain_log_quantiles"):
        load_calibration(path)


@pytest.fixture(scope="module")
def learned(texture) -> LearnedSensorTexture:
    calibration = dataclasses.replace(truth(), texture=texture)
    levels = texture_levels(calibration, calibrated_chain(calibration, "all"), 2, seed=0)
    return fit_learned_texture(grainy_frames(), levels, seed=0, steps=3)


def test_the_learned_texture_is_the_same_on_any_thread_count(texture, learned) -> None:
    calibration = dataclasses.replace(truth(), texture=texture)
    levels = texture_levels(calibration, calibrated_chain(calibration, "all"), 2, seed=0)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2 if threads == 1 else 1)
        again = fit_learned_texture(grainy_frames(), levels, seed=0, steps=3)
    finally:
        torch.set_num_threads(threads)
    assert again.safetensors_base64 == learned.safetensors_base64 and torch.get_num_threads() == threads


def test_texture_levels_are_the_smooth_level_each_simulated_frame_is_textured_on(texture) -> None:
    calibration = dataclasses.replace(truth(), texture=texture)
    chain = calibrated_chain(calibration, "all")
    levels = texture_levels(calibration, chain, 3, seed=4)
    for index, level in enumerate(levels):
        clean, _ = calibrated_view(calibration, 4, index)
        frame = finish(calibration, clean, chain, np.random.default_rng([4, index])).intensity.astype(np.float32)
        assert level.shape == frame.shape and level.dtype == np.float32 and level.min() >= 0
        # the textured frame follows its level, and the level itself carries no speckle
        assert np.corrcoef(local_mean(frame).ravel(), level.ravel())[0, 1] > 0.9
        step_along_range = level[1:] - level[:-1]
        assert np.abs(step_along_range).mean() < 0.05 * level.mean()
    assert not np.array_equal(levels[0], levels[1])  # each view its own scene


def test_learned_texture_is_drawn_in_place_of_the_speckle_and_round_trips(texture, learned, tmp_path) -> None:
    calibration = dataclasses.replace(truth(), texture=texture, learned_texture=learned)
    clean, _ = calibrated_view(calibration, 0, 0)
    chain = calibrated_chain(calibration, "all")
    drawn = finish(calibration, clean, chain, np.random.default_rng(1)).intensity
    speckled = finish(dataclasses.replace(calibration, learned_texture=None), clean, chain,
                      np.random.default_rng(1)).intensity
    assert drawn.dtype == np.uint8 and drawn.max() == 255 and not np.array_equal(drawn, speckled)
    # drawn on the same level: the two textures agree on where the frame is bright
    assert np.corrcoef(local_mean(drawn).ravel(), local_mean(speckled).ravel())[0, 1] > 0.8
    assert not np.array_equal(drawn, finish(calibration, clean, chain, np.random.default_rng(2)).intensity)
    path = tmp_path / "calib.json"
    save_calibration(calibration, path)
    loaded = load_calibration(path)
    assert loaded.learned_texture == learned
    np.testing.assert_array_equal(finish(loaded, clean, chain, np.random.default_rng(1)).intensity, drawn)
    # the learned texture's export bends at the texture's knee too: the same draw, another top of the range
    bent = finish(dataclasses.replace(calibration, texture=dataclasses.replace(texture, export_knee=0.2)), clean, chain,
                  np.random.default_rng(1)).intensity
    assert bent.shape == drawn.shape and not np.array_equal(bent, drawn)


def test_a_broken_learned_texture_is_refused_naming_the_field(texture, learned, tmp_path) -> None:
    path = tmp_path / "calib.json"
    save_calibration(dataclasses.replace(truth(), texture=texture, learned_texture=learned), path)
    data = json.loads(path.read_text())
    for broken, says in (("not base64!", "not base64"), (base64.b64encode(save({"weight": torch.zeros(2)})).decode(),
                                                         "generator")):
        data["learned_texture"]["safetensors_base64"] = broken
        path.write_text(json.dumps(data))
        with pytest.raises(ConfigError, match=f"learned_texture.safetensors_base64.*{says}"):
            load_calibration(path)
    with pytest.raises(ConfigError, match="needs the fitted texture"):
        save_calibration(dataclasses.replace(truth(), learned_texture=learned), path)


def test_noise_floor_under_the_texture_draws_the_recordings_share_of_black_pixels(texture) -> None:
    calibration = dataclasses.replace(truth(), texture=texture)
    chain = calibrated_chain(calibration, "all")

    def black_share(effects) -> float:
        images = sim_images(calibration, effects, 6, 0)
        return float(np.mean([near_zero_fraction(image) for image in images]))

    amplitudes = []
    assert black_share(chain) < 0.042  # the default floor (0.12) draws ~4 % here; none at all ~5 %
    for wanted in (0.03, 0.047):
        matched = match_noise_floor(calibration, chain, wanted, 6, 0)
        amplitudes.append(effect_in(matched, TvgNoise).noise_amplitude)
        assert black_share(matched) == pytest.approx(wanted, abs=0.003)
    assert amplitudes[0] > amplitudes[1]  # more black pixels wanted: a lower floor
    # a recording without black water does not show its floor: the fitted amplitude stays
    assert match_noise_floor(calibration, chain, 0.0, 6, 0) == list(chain)


def clipping_calibration(texture):
    """A calibration whose export clips: its brightest speckle piles up at 255 under a hard knee."""
    effects = {**truth().effects, "gamma_quantization": {**truth().effects["gamma_quantization"], "gain": 0.3}}
    return dataclasses.replace(truth(), texture=texture, effects=effects)


def with_knee(calibration, knee: float):
    return dataclasses.replace(calibration, texture=dataclasses.replace(calibration.texture, export_knee=knee))


def test_export_knee_gives_the_recordings_top_of_the_range_and_old_files_clip(texture, tmp_path) -> None:
    """Under a hard clip the calibrated sim piles its brightest speckle at 255 (0.35 % of the pixels here); a
    "recording" made by the same sim under knee 0.5 has its knee found again: its ratio of 99.9th percentile to
    maximum is reached, and its fingerprint allows it."""
    calibration = clipping_calibration(texture)
    chain = calibrated_chain(calibration, "all")

    def top_and_full_share(candidate) -> tuple[float, float]:
        images = sim_images(candidate, chain, 6, 0)
        return (float(np.median([top_ratio(image) for image in images])),
                float(np.mean([np.mean(image >= image.max()) for image in images])))

    assert texture.export_knee == 1.0  # nothing to bend around the grainy frames' own means
    recording = sim_images(with_knee(calibration, 0.5), chain, 6, 0)
    recording_top = float(np.median([top_ratio(image) for image in recording]))
    clipped_top, clipped_full = top_and_full_share(calibration)
    matched = match_export_knee(calibration, chain, fingerprint(recording), recording_top, 6, 0)
    bent_top, bent_full = top_and_full_share(matched)
    assert clipped_top == 1.0 and clipped_full > 0.002 and recording_top < 0.99
    assert matched.texture.export_knee == pytest.approx(0.5, abs=0.1)
    assert bent_top == pytest.approx(recording_top, abs=0.01)
    assert bent_full < clipped_full / 10


def test_export_knee_does_not_bend_the_range_further_than_the_fingerprint_allows(texture) -> None:
    """A recording whose top ratio is lower than its level allows (a few bright pixels over a clipped body, say):
    reaching the ratio would bend the whole upper range away from the recording's histogram and profiles, so the
    knee stops where the fingerprint distance starts to grow."""
    calibration = clipping_calibration(texture)
    chain = calibrated_chain(calibration, "all")
    recording = sim_images(calibration, chain, 6, 0)  # the hard clip itself is the recording's look
    matched = match_export_knee(calibration, chain, fingerprint(recording), 0.5, 6, 0)
    assert matched.texture.export_knee >= 0.8
    lowest = with_knee(calibration, 0.05)
    assert distance(fingerprint(sim_images(lowest, chain, 6, 0)), fingerprint(recording))["total"] > 1.05 * \
        distance(fingerprint(sim_images(matched, chain, 6, 0)), fingerprint(recording))["total"]


def test_calibration_files_carry_the_export_knee(texture, tmp_path) -> None:
    matched = with_knee(clipping_calibration(texture), 0.5)
    path = tmp_path / "calib.json"
    save_calibration(matched, path)
    assert load_calibration(path).texture.export_knee == matched.texture.export_knee
    data = json.loads(path.read_text())
    del data["texture"]["export_knee"]  # a file fitted before the knee: the hard clip it was made with
    path.write_text(json.dumps(data))
    assert load_calibration(path).texture.export_knee == 1.0
    data["texture"]["export_knee"] = 1.5
    path.write_text(json.dumps(data))
    with pytest.raises(ConfigError, match="texture.export_knee"):
        load_calibration(path)
