import dataclasses

import numpy as np
import pytest

from sonar_realism import FrameError, SonarImage
from sonar_realism.frames import all_finite, checked_axis, uniform_azimuths, uniform_ranges


def make(shape=(64, 32), dtype=np.uint8, **kw):
    intensity = np.zeros(shape, dtype=dtype)
    return SonarImage(intensity, uniform_ranges(shape[-2], 10.0), uniform_azimuths(shape[-1], np.radians(130)), **kw)


def test_valid_frame_and_derived_properties():
    frame = make(stamp_ns=5, seq=3)
    assert (frame.n_ranges, frame.n_beams, frame.n_samples) == (64, 32, 1)
    assert frame.intensity_scale == 255.0
    assert frame.max_range_m == pytest.approx(10 - 10 / 128)
    assert frame.fov_rad == pytest.approx(np.radians(130) * 31 / 32)


def test_construction_keeps_checked_values_and_a_fresh_meta_per_frame():
    first, second = make(), make()
    assert first.meta == {} and first.meta is not second.meta  # the default is a new dict, never shared
    frame = make(stamp_ns=np.uint64(5), seq=np.int32(3), intensity_scale=np.float32(2))
    assert (type(frame.stamp_ns), type(frame.seq), type(frame.intensity_scale)) == (int, int, float)
    assert frame.ranges_m.dtype == np.float64 and frame.azimuths_rad.dtype == np.float64
    with pytest.raises(dataclasses.FrozenInstanceError):
        frame.seq = 4  # type: ignore[misc]
    relabelled = frame.replace(seq=9, frame_id="other")
    assert (relabelled.seq, relabelled.frame_id, relabelled.stamp_ns) == (9, "other", 5)
    assert relabelled.intensity is frame.intensity and relabelled.meta is frame.meta
    assert [f.name for f in dataclasses.fields(SonarImage)] == ["intensity", "ranges_m", "azimuths_rad", "stamp_ns",
                                                                "seq", "frame_id", "intensity_scale", "meta"]
    with pytest.raises(FrameError, match="seq"):
        make(seq=True + 0.5)
    with pytest.raises(FrameError, match="meta"):
        make(meta={1: "x"})


def test_sample_axis():
    frame = make((4, 64, 32), dtype=np.float32)
    assert frame.n_samples == 4
    assert frame.sample(2).intensity.shape == (64, 32)
    assert frame.intensity_scale == 1.0


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"dtype": np.int8}, "unsupported dtype"),
        ({"stamp_ns": -1}, "stamp_ns"),
        ({"seq": -2}, "seq"),
        ({"intensity_scale": -1.0}, "intensity_scale"),
    ],
)
def test_invalid_fields_raise_typed_errors(kwargs, message):
    with pytest.raises(FrameError, match=message):
        make(**kwargs)


def test_bad_shapes():
    with pytest.raises(FrameError, match="expected"):
        SonarImage(np.zeros(64, np.uint8), uniform_ranges(64, 5), uniform_azimuths(1, 1.0))
    with pytest.raises(FrameError, match="empty"):
        SonarImage(np.zeros((0, 4), np.uint8), np.zeros(0), uniform_azimuths(4, 1.0))


def test_non_finite_float_rejected():
    intensity = np.zeros((8, 4), np.float32)
    for bad in (np.nan, np.inf, -np.inf):
        intensity[3, 2] = bad
        with pytest.raises(FrameError, match="NaN"):
            SonarImage(intensity, uniform_ranges(8, 5), uniform_azimuths(4, 1.0))


SPECIAL_VALUES = (np.nan, -np.nan, np.inf, -np.inf, -0.0, 0.0, -1.0, 1e-45, 5e-324, 3.4e38, -3.4e38, 1.7e308)


@pytest.mark.parametrize("dtype", ["<f4", ">f4", "<f8", ">f8"])
def test_all_finite_agrees_with_isfinite_on_every_special_value(dtype):
    # The fast path reads the samples' bits as unsigned ints: NaNs of either sign, ±inf, -0.0, negatives,
    # subnormals and the largest finite values, alone and mixed, in contiguous and strided arrays.
    rng = np.random.default_rng(0)
    for value in SPECIAL_VALUES:
        for others in (0.5, -0.5, 0.0):
            with np.errstate(over="ignore"):
                values = np.full((6, 10), others, dtype=dtype)
                values[rng.integers(6), rng.integers(10)] = value
            for view in (values, values[:, ::3], values.T, values[2:3]):
                assert all_finite(view) == bool(np.isfinite(view).all()), (dtype, value, others)
    assert all_finite(np.zeros((0, 3), dtype))


def test_replace_scans_a_new_intensity_but_not_the_unchanged_one():
    frame = make(dtype=np.float32)
    frame.intensity[1, 1] = np.nan  # written after the frame was checked: replace() trusts that check
    assert frame.replace(seq=7).seq == 7
    with pytest.raises(FrameError, match="NaN"):
        frame.replace(intensity=frame.intensity.copy())
    with pytest.raises(FrameError, match="seq"):
        frame.replace(seq=-1)  # everything else is still checked
    with pytest.raises(FrameError, match="NaN"):  # and only within replace(): a new frame is checked in full
        SonarImage(frame.intensity, frame.ranges_m, frame.azimuths_rad)


def test_geometry_must_match_and_increase():
    with pytest.raises(FrameError, match="ranges_m"):
        SonarImage(np.zeros((8, 4), np.uint8), np.arange(7.0), uniform_azimuths(4, 1.0))
    with pytest.raises(FrameError, match="strictly increasing"):
        SonarImage(np.zeros((8, 4), np.uint8), uniform_ranges(8, 5), np.array([0.1, 0.0, 0.2, 0.3]))
    with pytest.raises(FrameError, match="degrees"):
        SonarImage(np.zeros((8, 4), np.uint8), uniform_ranges(8, 5), np.array([-65.0, -10, 10, 65]))


def test_normalized_and_replace():
    frame = make(shape=(4, 4))
    bright = frame.replace(intensity=np.full((4, 4), 255, np.uint8))
    assert bright.normalized().max() == 1.0
    with pytest.raises(FrameError):
        frame.replace(seq=-1)


def test_a_checked_axis_is_a_read_only_copy_taken_as_is():
    bearings = uniform_azimuths(32, np.radians(130))
    axis = checked_axis(bearings, "azimuths_rad", 32)
    bearings[0] = -10.0  # the caller's array is not the checked one
    frame = SonarImage(np.zeros((64, 32), np.uint8), uniform_ranges(64, 10.0), axis)
    assert frame.azimuths_rad is axis and axis[0] > -np.pi
    with pytest.raises(ValueError, match="read-only"):
        axis[1] = 0.0


def test_checked_axis_checks_what_sonar_image_checks():
    with pytest.raises(FrameError, match="degrees"):
        checked_axis(np.array([-65.0, -10, 10, 65]), "azimuths_rad", 4)
    with pytest.raises(FrameError, match="negative range"):
        checked_axis(np.array([-0.5, 1.0]), "ranges_m", 2)
    with pytest.raises(FrameError, match="strictly increasing"):
        checked_axis(np.array([0.0, 0.0]), "ranges_m", 2)
    ranges = checked_axis(uniform_ranges(8, 5), "ranges_m", 8)
    with pytest.raises(FrameError, match="degrees"):  # checked as ranges (up to 4.7 m), not as bearings
        SonarImage(np.zeros((4, 8), np.uint8), uniform_ranges(4, 5), ranges)
    with pytest.raises(FrameError, match="expected 4 values"):  # a checked axis of the wrong length
        SonarImage(np.zeros((4, 8), np.uint8), ranges, uniform_azimuths(8, 1.0))


def test_checked_axes_are_remembered_in_bounded_memory():
    from sonar_realism import frames

    axes = [checked_axis(uniform_ranges(8, 5.0 + i), "ranges_m", 8) for i in range(200)]
    assert len(frames._CHECKED_AXES) <= 64
    # The oldest is no longer remembered: checked in full again, and still taken as it is.
    frame = SonarImage(np.zeros((8, 4), np.uint8), axes[0], uniform_azimuths(4, 1.0))
    assert frame.ranges_m is axes[0]
