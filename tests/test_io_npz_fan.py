"""NPZ recordings and Cartesian fan images (with and without sidecars, and the real ARIS set)."""

import json
import math

import cv2
import numpy as np
import pytest

from sonar_realism import FormatError, FrameError, SonarImage
from sonar_realism.frames import uniform_azimuths, uniform_ranges
from sonar_realism.geometry import fan_layout, polar_to_fan
from sonar_realism.io import ReadReport, read_frames, sniff, write_frames
from sonar_realism.io.fan import detect_fan

RANGES = uniform_ranges(48, 20.0, 1.0)
BEARINGS = np.arcsin(np.linspace(-0.8, 0.8, 32))


def stack(n, dtype=np.float32, samples=None, seed=0):
    rng = np.random.default_rng(seed)
    shape = (48, 32) if samples is None else (samples, 48, 32)
    frames = []
    for i in range(n):
        if np.dtype(dtype).kind == "f":
            intensity = rng.random(shape).astype(dtype)
        else:
            intensity = rng.integers(0, 255, shape, dtype=dtype)
        frames.append(SonarImage(intensity, RANGES, BEARINGS, stamp_ns=1_000 + i, seq=40 + i, frame_id="fls",
                                 meta={"i": i, "gain_percent": 30.0}))
    return frames


def test_npz_round_trip_with_samples_stamps_and_meta(tmp_path):
    frames = stack(4, np.float32, samples=3)
    assert write_frames(iter(frames), tmp_path / "new" / "rec.npz") == 4
    assert sniff(tmp_path / "new" / "rec.npz") == "npz"
    report = ReadReport()
    back = list(read_frames(tmp_path / "new" / "rec.npz", report))
    assert report.frames == 4 and not report.skipped
    for a, b in zip(frames, back, strict=True):
        np.testing.assert_array_equal(a.intensity, b.intensity)
        np.testing.assert_array_equal(a.azimuths_rad, b.azimuths_rad)
        assert (a.stamp_ns, a.seq, a.frame_id, a.meta) == (b.stamp_ns, b.seq, b.frame_id, b.meta)
    # np.load sees an ordinary NPZ.
    with np.load(tmp_path / "new" / "rec.npz") as data:
        assert data["intensity"].shape == (4, 3, 48, 32)


def test_npz_from_other_tools_reads_with_defaults_and_by_content(tmp_path):
    intensity = np.random.default_rng(1).integers(0, 60000, (5, 48, 32), dtype=np.uint16)
    np.savez_compressed(tmp_path / "other.dat", intensity=intensity, ranges_m=RANGES, azimuths_rad=BEARINGS,
                        notes=np.arange(3))
    report = ReadReport()
    back = list(read_frames(tmp_path / "other.dat.npz", report))
    assert [f.seq for f in back] == [0, 1, 2, 3, 4] and {f.stamp_ns for f in back} == {0}
    np.testing.assert_array_equal(back[3].intensity, intensity[3])
    assert report.skipped == {"npz array 'notes'": 1}
    (tmp_path / "other.dat.npz").rename(tmp_path / "renamed.bin")
    assert len(list(read_frames(tmp_path / "renamed.bin"))) == 5
    np.savez(tmp_path / "single.npz", intensity=intensity[0], ranges_m=RANGES, azimuths_rad=BEARINGS,
             meta_json=np.asarray(json.dumps({"frame_id": "x", "meta": {"k": 1}})))
    (single,) = read_frames(tmp_path / "single.npz")
    assert single.intensity.shape == (48, 32) and single.frame_id == "x" and single.meta == {"k": 1}


@pytest.mark.parametrize("arrays, field", [
    ({"intensity": np.zeros((2, 48, 32), np.uint8), "azimuths_rad": BEARINGS}, "ranges_m: array missing"),
    ({"intensity": np.zeros((2, 48, 32), np.uint8), "ranges_m": RANGES[:40], "azimuths_rad": BEARINGS},
     "ranges_m: expected 48 values"),
    ({"intensity": np.full((2, 48, 32), np.nan, np.float32), "ranges_m": RANGES, "azimuths_rad": BEARINGS},
     "intensity: NaN or inf in frame 0"),
    ({"intensity": np.zeros((2, 48, 32), np.uint8), "ranges_m": RANGES, "azimuths_rad": BEARINGS,
      "stamps_ns": np.arange(3)}, "stamps_ns: expected 2 integers"),
    ({"intensity": np.zeros((2, 48, 32), np.uint8), "ranges_m": RANGES, "azimuths_rad": BEARINGS,
      "meta_json": np.asarray('{"colour": 1}')}, "meta_json: expected an object"),
    ({"intensity": np.zeros((48,), np.uint8), "ranges_m": RANGES, "azimuths_rad": BEARINGS},
     "intensity: expected 2 to 4 dimensions"),
])
def test_bad_npz_raises_format_error_naming_the_array(tmp_path, arrays, field):
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(FormatError, match=rf"bad\.npz: {field}"):
        list(read_frames(tmp_path / "bad.npz"))


def test_truncated_npz_and_inconsistent_frames_are_refused(tmp_path):
    write_frames(stack(3), tmp_path / "ok.npz")
    payload = (tmp_path / "ok.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(payload[: len(payload) // 2])
    with pytest.raises(FormatError, match=r"cut\.npz: zip"):
        list(read_frames(tmp_path / "cut.npz"))
    mixed = stack(2) + [stack(1)[0].replace(ranges_m=RANGES * 2)]
    with pytest.raises(FrameError, match="frame 2 has a different geometry"):
        write_frames(mixed, tmp_path / "mixed.npz")
    with pytest.raises(FrameError, match="frame 1 is uint8"):
        write_frames([stack(1)[0], stack(1, np.uint8)[0]], tmp_path / "mixed.npz")
    with pytest.raises(FrameError, match="no frames"):
        write_frames([], tmp_path / "empty.npz")
    assert not (tmp_path / "mixed.npz").exists() and not (tmp_path / "empty.npz").exists()


# ---------------------------------------------------------------------------------------------- fan images


def fan_source(fov_deg=40.0, seed=0):
    rows, cols = np.mgrid[0:160, 0:60]
    intensity = (60 + 150 * (0.5 + 0.5 * np.sin(rows / 11.0) * np.cos(cols / 6.0))).astype(np.uint8)
    return SonarImage(intensity, uniform_ranges(160, 6.0, 1.5), uniform_azimuths(60, math.radians(fov_deg)))


def test_fan_image_with_full_sidecar_converts_back_to_the_polar_frame(tmp_path):
    polar = fan_source()
    layout = fan_layout(polar, 600)
    cv2.imwrite(str(tmp_path / "fan.png"), polar_to_fan(polar, 600))
    sidecar = {"kind": "fan", "apex_x_px": layout.apex_x_px, "apex_y_px": layout.apex_y_px,
               "px_per_m": layout.px_per_m, "fov_deg": 40.0, "min_range_m": 1.5, "max_range_m": 6.0,
               "n_ranges": 160, "n_beams": 60, "stamp_ns": 5}
    (tmp_path / "fan.json").write_text(json.dumps(sidecar))
    (frame,) = read_frames(tmp_path / "fan.png")
    assert frame.same_geometry(polar) and frame.stamp_ns == 5
    assert frame.meta["converted_from"] == "fan" and "geometry_assumed" not in frame.meta
    error = np.abs(frame.intensity[5:-5, 3:-3].astype(float) - polar.intensity[5:-5, 3:-3])
    assert error.mean() < 3.0


def test_fan_geometry_is_measured_from_the_image_when_the_sidecar_leaves_it_out(tmp_path):
    polar = fan_source(fov_deg=30.0)
    layout = fan_layout(polar, 400)
    image = polar_to_fan(polar, 400)
    detected = detect_fan(image)
    assert detected is not None and detected.range_up
    assert math.degrees(detected.fov_rad) == pytest.approx(30.0 * 59 / 60 + 30 / 60, abs=0.6)
    assert (detected.apex_x_px, detected.apex_y_px) == pytest.approx((layout.apex_x_px, layout.apex_y_px), abs=3)
    cv2.imwrite(str(tmp_path / "only_scale.png"), image)
    (tmp_path / "only_scale.json").write_text(json.dumps({"kind": "fan", "px_per_m": layout.px_per_m}))
    (frame,) = read_frames(tmp_path / "only_scale.png")
    assert frame.ranges_m[0] == pytest.approx(1.5, abs=0.1) and frame.max_range_m == pytest.approx(6.0, abs=0.1)
    assert set(frame.meta["measured_from_image"]) >= {"apex_x_px", "fov_deg", "max_range_m"}
    # No sidecar at all: still a fan (detected), with the scale assumed and said so.
    (tmp_path / "only_scale.json").unlink()
    (frame,) = read_frames(tmp_path / "only_scale.png")
    assert frame.meta["geometry_assumed"] is True and frame.meta["assumed_fields"] == ["px_per_m"]
    assert np.degrees(frame.fov_rad) == pytest.approx(30.0, abs=1.0)
    # A polar image is not mistaken for a fan.
    assert detect_fan(polar.intensity) is None


def test_a_fan_with_its_apex_at_the_top_reads_the_same_as_upright(tmp_path):
    image = polar_to_fan(fan_source(), 300)
    cv2.imwrite(str(tmp_path / "up.png"), image)
    cv2.imwrite(str(tmp_path / "down.png"), np.ascontiguousarray(image[::-1]))
    up, down = read_frames(tmp_path / "up.png"), read_frames(tmp_path / "down.png")
    up, down = next(up), next(down)
    assert detect_fan(image[::-1]).range_up is False
    assert down.same_geometry(up, atol=0.02)
    difference = np.abs(down.intensity.astype(float) - up.intensity)
    assert difference[2:-2, 2:-2].mean() < 2.0


def test_fan_sidecar_on_an_image_that_is_not_a_fan_names_the_missing_key(tmp_path):
    cv2.imwrite(str(tmp_path / "flat.png"), np.full((64, 64), 80, np.uint8))
    (tmp_path / "flat.json").write_text(json.dumps({"kind": "fan", "px_per_m": 10.0}))
    with pytest.raises(FormatError, match=r"flat\.json: apex_x_px: missing"):
        list(read_frames(tmp_path / "flat.png"))


def test_real_aris_fan_images_read_as_30_degree_polar_frames(real_aris):
    frames = read_frames(real_aris / "Images")
    fovs = []
    for _, frame in zip(range(12), frames, strict=False):
        assert frame.meta["converted_from"] == "fan" and frame.intensity.dtype == np.uint8
        assert frame.intensity.mean() > 20  # the polar grid lies inside the fan, not on the black surround
        fovs.append(math.degrees(frame.fov_rad + frame.fov_rad / (frame.n_beams - 1)))
    # Most images show the ARIS 3000's 30° fan; some were squeezed by the dataset's resize to 320×480 (≈24°).
    assert np.median(fovs) == pytest.approx(30.0, abs=0.5)
    assert all(23.5 < fov < 31.0 for fov in fovs)
