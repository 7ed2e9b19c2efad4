"""Polar ↔ fan remaps and polar resampling, on non-uniform bearing tables."""

import math

import numpy as np
import pytest

from sonar_realism import FrameError, SonarImage
from sonar_realism import geometry as geo
from sonar_realism.frames import uniform_ranges

# An Oculus-like bearing table: beams denser in the centre than at the edges (uniform in sin θ).
BEARINGS = np.arcsin(np.linspace(-0.9, 0.9, 64))
RANGES = uniform_ranges(120, 12.0, 0.5)


def frame_of(intensity, ranges=RANGES, bearings=BEARINGS):
    return SonarImage(intensity, ranges, bearings)


def smooth(dtype=np.float32, shape=(120, 64)):
    rows, cols = np.mgrid[0:shape[-2], 0:shape[-1]]
    values = 0.5 + 0.4 * np.sin(rows / 9.0) * np.cos(cols / 7.0)
    if np.dtype(dtype).kind == "f":
        return np.broadcast_to(values, shape).astype(dtype)
    return np.broadcast_to(np.rint(values * np.iinfo(dtype).max * 0.9), shape).astype(dtype)


def pixel_of(layout, range_m, bearing):
    x = layout.apex_x_px + range_m * math.sin(bearing) * layout.px_per_m
    y = layout.apex_y_px - range_m * math.cos(bearing) * layout.px_per_m
    return int(round(y)), int(round(x))


def test_a_single_beam_lands_at_its_true_bearing_in_the_fan():
    intensity = np.zeros((120, 64), np.uint8)
    intensity[:, 50] = 255  # beam 50: bearing arcsin(0.529) ≈ 31.9°, not 50/64 of a uniform fan
    frame = frame_of(intensity)
    fan = geo.polar_to_fan(frame, 400)
    layout = geo.fan_layout(frame, 400)
    assert fan.dtype == np.uint8 and fan.shape == (layout.height_px, 400)
    assert fan[pixel_of(layout, 8.0, BEARINGS[50])] > 200
    assert fan[pixel_of(layout, 8.0, BEARINGS[45])] == 0
    uniform_guess = BEARINGS[0] + 50 / 63 * (BEARINGS[-1] - BEARINGS[0])
    assert fan[pixel_of(layout, 8.0, uniform_guess)] == 0


def test_fan_is_zero_outside_the_sector_and_near_the_apex():
    frame = frame_of(np.full((120, 64), 200, np.uint8))
    fan = geo.polar_to_fan(frame, 300)
    layout = geo.fan_layout(frame, 300)
    assert fan[0, 0] == 0 and fan[0, -1] == 0
    assert fan[pixel_of(layout, 0.2, 0.0)] == 0  # closer than the first range bin
    assert fan[pixel_of(layout, 6.0, 0.0)] == 200
    assert fan[pixel_of(layout, 6.0, 1.3)] == 0  # beyond the last beam (±64°)
    # The fan fills the requested width: the outermost beams touch both sides.
    assert fan[:, :3].any() and fan[:, -3:].any()


def test_fan_round_trip_keeps_dtype_samples_and_values():
    for dtype in (np.uint8, np.uint16, np.uint32, np.float32, np.float64):
        frame = frame_of(smooth(dtype, (2, 120, 64)))
        fan = geo.polar_to_fan(frame, 700)
        assert fan.dtype == np.dtype(dtype) and fan.shape[0] == 2
        back = geo.fan_to_polar(fan, geo.fan_layout(frame, 700), frame.ranges_m, frame.azimuths_rad)
        assert back.dtype == np.dtype(dtype) and back.shape == frame.intensity.shape
        inner = (slice(None), slice(10, -10), slice(4, -4))
        error = np.abs(back[inner].astype(np.float64) - frame.intensity[inner]) / frame.intensity_scale
        assert error.mean() < 0.01, dtype


def test_remap_tables_are_cached_by_geometry_not_identity():
    geo.clear_cache()
    first = geo.polar_to_fan(frame_of(smooth()), 256)
    cached = len(geo._MAPS.entries)
    again = geo.polar_to_fan(frame_of(smooth(), RANGES.copy(), BEARINGS.copy()), 256)  # equal tables, new arrays
    assert len(geo._MAPS.entries) == cached == 1
    np.testing.assert_array_equal(first, again)
    geo.polar_to_fan(frame_of(smooth(), RANGES * 2), 256)
    assert len(geo._MAPS.entries) == 2
    geo.clear_cache()
    assert not geo._MAPS.entries


def test_resample_to_grid_spans_the_same_range_and_bearings_and_keeps_dtypes():
    for dtype in (np.uint8, np.uint16, np.uint32, np.float32):
        frame = frame_of(smooth(dtype, (3, 120, 64)))
        grid = geo.resample_to_grid(frame, 256, 128)
        assert grid.intensity.shape == (3, 256, 128) and grid.intensity.dtype == np.dtype(dtype)
        assert grid.ranges_m[[0, -1]] == pytest.approx(frame.ranges_m[[0, -1]])
        assert grid.azimuths_rad[[0, -1]] == pytest.approx(frame.azimuths_rad[[0, -1]])
        assert np.allclose(np.diff(grid.azimuths_rad), np.diff(grid.azimuths_rad)[0])
        back = geo.resample_like(grid, frame)
        assert back.same_geometry(frame)
        error = np.abs(back.intensity.astype(np.float64) - frame.intensity) / frame.intensity_scale
        assert error[:, :, 2:-2].mean() < 0.01, dtype


def test_a_linear_ramp_along_range_stays_exact_when_resampled():
    ramp = np.repeat(RANGES[:, None], 64, axis=1).astype(np.float32) / 12.0
    grid = geo.resample_to_grid(frame_of(ramp), 300, 64)
    np.testing.assert_allclose(grid.intensity[:, 10], grid.ranges_m / 12.0, atol=1e-5)


def test_shrinking_filters_speckle_instead_of_aliasing_it():
    speckle = np.random.default_rng(0).exponential(0.2, (120, 64)).astype(np.float32)
    frame = frame_of(speckle)
    small = geo.resample_to_grid(frame, 30, 16)
    assert small.intensity.mean() == pytest.approx(speckle.mean(), rel=0.1)
    # Point-sampling would keep the full speckle variance; a 4× shrink should average most of it away.
    assert small.intensity.std() < 0.5 * speckle.std()


def test_resample_like_is_zero_where_the_reference_reaches_beyond_the_frame():
    frame = frame_of(np.full((120, 64), 1.0, np.float32))
    wider = SonarImage(np.zeros((50, 20), np.float32), uniform_ranges(50, 20.0), np.linspace(-1.3, 1.3, 20))
    out = geo.resample_like(frame, wider)
    inside_ranges = (wider.ranges_m > RANGES[0]) & (wider.ranges_m < RANGES[-1])
    inside_beams = (wider.azimuths_rad > BEARINGS[0]) & (wider.azimuths_rad < BEARINGS[-1])
    assert (out.intensity[np.ix_(inside_ranges, inside_beams)] > 0.99).all()
    assert (out.intensity[~inside_ranges] == 0).all() and (out.intensity[:, ~inside_beams] == 0).all()


def test_invalid_requests_raise_frame_errors():
    frame = frame_of(smooth())
    with pytest.raises(FrameError, match="grid"):
        geo.resample_to_grid(frame, 0, 10)
    with pytest.raises(FrameError, match="width_px"):
        geo.polar_to_fan(frame, 1)
    with pytest.raises(FrameError, match="layout"):
        geo.fan_to_polar(np.zeros((10, 10), np.uint8), geo.fan_layout(frame, 50), RANGES, BEARINGS)


@pytest.mark.parametrize("dtype", [">u2", ">f4", ">f8"])
def test_big_endian_frames_resample_and_fan_like_native_ones(dtype):
    rng = np.random.default_rng(3)
    native = np.dtype(dtype).newbyteorder("=")
    values = (rng.random((120, 64)) * (1000 if native.kind == "u" else 1)).astype(native)
    little, big = frame_of(values), frame_of(values.astype(dtype))
    # Shrinking takes the anti-aliasing path (a blur over the samples), which must see values, not raw bytes.
    np.testing.assert_array_equal(geo.resample_to_grid(big, 30, 16).intensity,
                                  geo.resample_to_grid(little, 30, 16).intensity)
    np.testing.assert_array_equal(geo.polar_to_fan(big, 64), geo.polar_to_fan(little, 64))


def test_a_single_beam_cannot_be_spread_and_the_error_names_the_frame():
    frame = SonarImage(np.ones((1, 1), np.uint8), np.array([2.0]), np.array([0.0]), seq=4,
                       meta={"source": "tiny.png"})
    with pytest.raises(FrameError, match=r"tiny\.png is 1 range\(s\) x 1 beam\(s\)"):
        geo.resample_to_grid(frame, 8, 8)
    assert geo.resample_to_grid(frame, 1, 1).intensity.shape == (1, 1)
