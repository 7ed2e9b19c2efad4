"""Per-family image statistics: shapes, finiteness, and that each family moves with the physics it describes."""

import numpy as np
import pytest

from sonar_realism.errors import ConfigError
from sonar_realism.evaluate.statistics import (
    FAMILIES,
    StatisticsConfig,
    as_float_batch,
    brightest,
    feature_names,
    frame_statistics,
    level_histograms,
    octave_band_edges,
    patch_moments,
)
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges

SHAPE = (4, 128, 128)


def rayleigh(seed: int = 0, scale: float = 0.2, shape: tuple[int, ...] = SHAPE) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(rng.rayleigh(scale, shape), 0, 1).astype(np.float32)


def column(stats: dict[str, np.ndarray], family: str, name: str) -> np.ndarray:
    return stats[family][:, feature_names()[family].index(name)]


def test_every_family_has_named_finite_columns_even_for_black_and_flat_frames():
    names = feature_names()
    for images in (rayleigh(), np.zeros(SHAPE, np.float32), np.full(SHAPE, 0.5, np.float32)):
        stats = frame_statistics(images)
        assert list(stats) == list(FAMILIES)
        for family, rows in stats.items():
            assert rows.shape == (SHAPE[0], len(names[family]))
            assert np.isfinite(rows).all()


def test_speckle_contrast_matches_rayleigh_and_gamma_compression():
    amplitude = rayleigh(1)
    cv_linear = np.median(column(frame_statistics(amplitude), "speckle", "cv_q50"))
    cv_gamma = np.median(column(frame_statistics(np.sqrt(amplitude)), "speckle", "cv_q50"))
    assert cv_linear == pytest.approx(0.52, abs=0.04)  # Rayleigh amplitude: CV = 0.523
    assert cv_gamma == pytest.approx(0.26, abs=0.04)  # amplitude^0.5 is Weibull k = 4: CV = 0.28 (patch bias)


def test_grain_sees_blur_along_the_axis_it_happens_on():
    images = rayleigh(2)
    across_beams = (images + np.roll(images, 1, axis=2) + np.roll(images, 2, axis=2)) / 3
    before, after = frame_statistics(images), frame_statistics(across_beams)
    beam_lag1 = [column(s, "grain", "acf_beam_near_lag1").mean() for s in (before, after)]
    range_lag1 = [column(s, "grain", "acf_range_lag1").mean() for s in (before, after)]
    assert beam_lag1[1] > beam_lag1[0] + 0.3
    assert abs(range_lag1[1] - range_lag1[0]) < 0.05


def test_spectrum_moves_power_to_coarse_bands_when_smoothed():
    images = rayleigh(3)
    smooth = (images + np.roll(images, 1, axis=1)) / 2  # along range
    finest_range = column(frame_statistics(smooth), "spectrum", "range_band0").mean()
    assert finest_range < column(frame_statistics(images), "spectrum", "range_band0").mean() - 0.2
    assert octave_band_edges(128, 6).tolist() == [65, 32, 16, 8, 4, 2, 1]


def test_quantized_fraction_tells_8_bit_from_float_frames():
    images = rayleigh(4)
    counts = np.round(images * 255) / 255
    assert column(frame_statistics(counts), "intensity", "quantized_fraction").min() == 1.0
    assert column(frame_statistics(images), "intensity", "quantized_fraction").max() < 0.05


def test_range_and_bearing_profiles_follow_a_ramp_and_a_ring_down():
    images = rayleigh(5) * np.linspace(0.2, 1.0, SHAPE[1])[None, :, None]
    images[:, 0, :] = 0.9
    stats = frame_statistics(images.astype(np.float32))
    bins = stats["range_profile"][:, :StatisticsConfig().profile_bins]
    assert (np.diff(bins, axis=1) > 0).mean() > 0.8
    assert column(stats, "range_profile", "row0").min() == pytest.approx(0.9, abs=1e-6)
    assert np.ptp(stats["bearing_profile"][:, :StatisticsConfig().profile_bins], axis=1).max() < 0.05


def test_level_histograms_are_fractions_and_quantiles_are_right():
    images = np.tile(np.linspace(0, 1, 128, dtype=np.float32), (2, 128, 1))
    hist = level_histograms(images)
    assert hist.sum(axis=1) == pytest.approx([1.0, 1.0])
    median = column(frame_statistics(images), "intensity", "q0.5")
    assert median == pytest.approx([0.5, 0.5], abs=0.01)


def test_bad_input_is_refused_with_what_is_needed():
    with pytest.raises(ConfigError, match="too small"):
        frame_statistics(np.zeros((2, 16, 16), np.float32))
    with pytest.raises(ConfigError, match="unknown statistics families"):
        frame_statistics(rayleigh(), families=["colour"])
    with pytest.raises(ConfigError, match="odd box"):
        StatisticsConfig(detrend=4).validate()
    ranges, azimuths = uniform_ranges(128, 10.0), uniform_azimuths(128, 2.0)
    with pytest.raises(ConfigError, match="different shapes"):
        as_float_batch([SonarImage(np.zeros((128, 128), np.uint8), ranges, azimuths),
                        SonarImage(np.zeros((64, 128), np.uint8), ranges[:64], azimuths)])


def test_brightest_finds_the_largest_values_and_takes_the_pixels_argpartition_takes_on_a_tie():
    rng = np.random.default_rng(3)
    frames = rng.random((4, 300 * 64), dtype=np.float32)
    frames[1] = np.round(frames[1] * 40) / 255  # 8-bit: a tie for the last place
    frames[2, 5000:5100] = 2.0  # a saturated run: 100 pixels tied for the top, 32 wanted
    top = brightest(frames, 32)
    partitioned = np.argpartition(frames, -32, axis=1)[:, -32:]
    for row, picked, reference in zip(frames, top, partitioned, strict=True):
        assert len(set(picked.tolist())) == 32
        np.testing.assert_array_equal(np.sort(row[picked]), np.sort(row)[-32:])
        np.testing.assert_array_equal(np.sort(picked), np.sort(reference))
    small = frames[:, :100]  # fewer pixels than the blocks need
    np.testing.assert_array_equal(np.sort(small[1][brightest(small, 5)[1]]), np.sort(small[1])[-5:])


def test_patch_moments_are_the_tiles_own_mean_std_and_fourth_moment_ratio():
    rng = np.random.default_rng(4)
    images = rng.random((2, 19, 27), dtype=np.float32)  # not whole tiles: the edge is left out
    mean, std, ratio = patch_moments(images, 8)
    tile = images[1, 8:16, 16:24].astype(np.float64)
    assert mean.shape == (2, 2, 3)
    assert mean[1, 1, 2] == pytest.approx(tile.mean(), rel=1e-5)
    assert std[1, 1, 2] == pytest.approx(tile.std(), rel=1e-4)
    assert ratio[1, 1, 2] == pytest.approx((tile ** 4).mean() / (tile ** 2).mean() ** 2, rel=1e-4)
