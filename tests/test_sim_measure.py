"""measure.target_shadow: a target is a shadow behind a return, judged against the seabed at the same ranges; the
seabed's own dark patches and the water above a late onset are not targets."""

from __future__ import annotations

import numpy as np
import pytest

from sonar_realism.sim import measure


def seabed_frame(seed: int = 0) -> np.ndarray:
    """[400 ranges, 128 beams]: dark water, then a speckled seabed from row 100 whose level falls with range."""
    rng = np.random.default_rng(seed)
    rows = np.arange(400)[:, None]
    level = np.where(rows >= 100, 0.5 * (1.0 - 0.4 * (rows - 100) / 300), 0.01)
    return (level * rng.exponential(1.0, (400, 128))).astype(np.float32).clip(0, 1)


def test_a_shadow_behind_a_return_is_found_where_it_starts() -> None:
    image = seabed_frame()
    image[180:188, 50:80] = 1.0  # the target's return
    image[188:, 52:78] *= 0.35  # its shadow: grey, not black
    found = measure.target_shadow(image)
    assert found is not None
    assert 50 <= found.first_beam <= 56 and 18 <= found.width_beams <= 28
    assert found.start_row == pytest.approx(188, abs=12)


def test_a_dark_patch_without_a_return_and_a_late_onset_are_not_targets() -> None:
    patch = seabed_frame(1)
    patch[200:, 50:80] *= 0.35  # as dark as a shadow, but nothing lit ahead of it
    assert measure.target_shadow(patch) is None
    late = seabed_frame(2)
    late[100:160, 40:80] = 0.01  # the seabed begins 60 rows later in these beams
    assert measure.target_shadow(late) is None


def test_a_shadows_level_is_its_darkest_band_against_the_seabed_beside_it() -> None:
    """A grey shadow (0.35 of the seabed) reads about 0.35 whether the box frames the return alone or the return and
    its shadow; a frame without one reads about 1; a target with no seabed beside it cannot be measured."""
    image = seabed_frame()
    image[180:188, 50:80] = 1.0
    image[188:, 52:78] *= 0.35
    echo = measure.shadow_level(image, slice(180, 188), slice(50, 80))
    echo_and_shadow = measure.shadow_level(image, slice(180, 400), slice(50, 80))
    assert echo == pytest.approx(0.35, abs=0.08)
    assert echo_and_shadow == pytest.approx(0.35, abs=0.08)
    assert measure.shadow_level(seabed_frame(1), slice(180, 188), slice(50, 80)) == pytest.approx(1.0, abs=0.2)
    assert np.isnan(measure.shadow_level(image, slice(180, 188), slice(4, 124)))
    assert np.isnan(measure.shadow_level(image, slice(380, 400), slice(50, 80)))  # no rows behind it


def test_seabed_patchiness_leaves_out_the_beams_of_a_target_and_its_shadow() -> None:
    """A target across a third of the fan, its return bright and its shadow grey, makes the seabed read patchier
    and longer-grained; its beams left out, the seabed reads as it does without it."""
    plain = seabed_frame(2)
    with_target = plain.copy()
    with_target[180:200, 40:84] = 1.0
    with_target[200:, 40:84] *= 0.3
    alone = measure.seabed_stats(plain)
    spoiled = measure.seabed_stats(with_target)
    cleaned = measure.seabed_stats(with_target, measure.target_beams(128, [(40, 83)]))
    assert alone is not None and spoiled is not None and cleaned is not None
    assert spoiled.contrast > 1.5 * alone.contrast
    assert cleaned.contrast == pytest.approx(alone.contrast, rel=0.15)
    assert cleaned.scale_rows <= alone.scale_rows + 2
    assert measure.target_beams(128, [(40, 83)]).sum() == 44 + 2 * (measure.LOCAL_BOX // 2 + 1 + 43 // 16)
    assert measure.seabed_stats(with_target, np.ones(128, bool)) is None  # nothing left to measure
