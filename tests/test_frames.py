import numpy as np
import pytest

from sonar_realism import FrameError, SonarImage
from sonar_realism.frames import uniform_azimuths, uniform_ranges


def make(shape=(64, 32), dtype=np.uint8, **kw):
    intensity = np.zeros(shape, dtype=dtype)
    return SonarImage(intensity, uniform_ranges(shape[-2], 10.0), uniform_azimuths(shape[-1], np.radians(130)), **kw)


def test_valid_frame_and_derived_properties():
    frame = make(stamp_ns=5, seq=3)
    assert (frame.n_ranges, frame.n_beams, frame.n_samples) == (64, 32, 1)
    assert frame.intensity_scale == 255.0
    assert frame.max_range_m == pytest.approx(10 - 10 / 128)
    assert frame.fov_rad == pytest.approx(np.radians(130) * 31 / 32)


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
    intensity[3, 2] = np.nan
    with pytest.raises(FrameError, match="NaN"):
        SonarImage(intensity, uniform_ranges(8, 5), uniform_azimuths(4, 1.0))


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
