"""The recording's own texture in the calibrated simulator: fitted from real frames, saved in CALIB.json,
drawn in place of the catalogue's speckle and output mapping."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from sonar_realism.errors import ConfigError
from sonar_realism.sim.calibrated import calibrated_chain, calibrated_view, finish
from sonar_realism.sim.calibration import load_calibration, save_calibration
from sonar_realism.sim.texture import fit_texture, local_mean
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
