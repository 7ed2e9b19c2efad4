"""The calibration's fingerprint: what each statistic reads, on frames built to show it."""

from __future__ import annotations

import numpy as np
import pytest

from sonar_realism.sim.fingerprint import distance, fingerprint, seabed_stripes, water_stripes


def striped_frame(rng: np.random.Generator, seabed_gain_rms: float, water_stripe_rms: float) -> np.ndarray:
    """[200, 128]: a dark water column (near half) whose per-beam noise levels differ by `water_stripe_rms`, over
    a lit seabed (far half) whose beams carry a per-beam gain error of rms `seabed_gain_rms`."""
    n_ranges, n_beams = 200, 128
    image = np.empty((n_ranges, n_beams), np.float32)
    water_levels = 0.03 * np.exp(water_stripe_rms * rng.standard_normal(n_beams))
    image[:100] = water_levels * rng.rayleigh(1.0, (100, n_beams)) / np.sqrt(np.pi / 2)
    gains = np.exp(seabed_gain_rms * rng.standard_normal(n_beams))
    image[100:] = 0.4 * gains * rng.gamma(50.0, 1 / 50.0, (100, n_beams))
    return image / image.max()


def test_seabed_stripes_read_the_lit_seabeds_beam_gains_not_the_water_columns_stripes() -> None:
    rng = np.random.default_rng(0)
    quiet_water = np.mean([seabed_stripes(striped_frame(rng, 0.05, 0.0)) for _ in range(8)])
    striped_water = np.mean([seabed_stripes(striped_frame(rng, 0.05, 0.4)) for _ in range(8)])
    unstriped = np.mean([seabed_stripes(striped_frame(rng, 0.0, 0.4)) for _ in range(8)])
    assert quiet_water == pytest.approx(0.05, rel=0.25)
    assert striped_water == pytest.approx(quiet_water, rel=0.1)
    assert unstriped < 0.4 * quiet_water  # what is left is the seabed's own grain averaged down a column
    doubled = np.mean([seabed_stripes(striped_frame(rng, 0.1, 0.0)) for _ in range(8)])
    assert doubled == pytest.approx(2 * quiet_water, rel=0.25)


def test_distance_counts_a_seabed_stripe_mismatch_and_is_zero_against_itself() -> None:
    rng = np.random.default_rng(1)
    plain = fingerprint([striped_frame(rng, 0.02, 0.0) for _ in range(4)])
    striped = fingerprint([striped_frame(rng, 0.15, 0.0) for _ in range(4)])
    assert distance(plain, plain)["total"] == 0.0
    assert distance(striped, plain)["stripes"] > 0.01
    striped_water = fingerprint([striped_frame(rng, 0.02, 0.4) for _ in range(4)])
    assert distance(striped_water, plain)["stripes"] > 0.01


def test_water_stripes_read_the_water_columns_per_beam_levels() -> None:
    rng = np.random.default_rng(2)
    plain = np.mean([water_stripes(striped_frame(rng, 0.05, 0.0)) for _ in range(8)])
    striped = np.mean([water_stripes(striped_frame(rng, 0.05, 0.3)) for _ in range(8)])
    assert striped > 2 * plain
    assert striped == pytest.approx(0.3, rel=0.35)
