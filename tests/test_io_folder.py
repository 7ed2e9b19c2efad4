"""Frames folders (write_frames/read_frames round trip) and plain PNG/TIFF image folders with sidecars."""

import json
import math
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sonar_realism import FormatError, FrameError, SonarImage
from sonar_realism.frames import uniform_azimuths, uniform_ranges
from sonar_realism.io import ReadReport, read_frames, write_frames

OCULUS_SAMPLE = Path(__file__).parent / "data" / "three_pings_8bit.raw"


def make(dtype, shape, seed=0, **kw):
    rng = np.random.default_rng(seed)
    if np.dtype(dtype).kind == "f":
        intensity = rng.random(shape).astype(dtype)
    else:
        intensity = rng.integers(0, np.iinfo(dtype).max, shape, dtype=dtype, endpoint=True)
    azimuths = np.sort(rng.uniform(-1.1, 1.1, shape[-1]))  # non-uniform, like an Oculus bearing table
    return SonarImage(intensity, uniform_ranges(shape[-2], 30.0, 0.3) + rng.uniform(0, 1e-3), azimuths, **kw)


def assert_same(a: SonarImage, b: SonarImage) -> None:
    assert b.intensity.dtype == a.intensity.dtype
    np.testing.assert_array_equal(b.intensity, a.intensity)
    np.testing.assert_array_equal(b.ranges_m, a.ranges_m)
    np.testing.assert_array_equal(b.azimuths_rad, a.azimuths_rad)
    assert (b.stamp_ns, b.seq, b.frame_id, b.intensity_scale, b.meta) == (
        a.stamp_ns, a.seq, a.frame_id, a.intensity_scale, a.meta)


FRAMES = [
    make(np.uint8, (40, 24), 1, stamp_ns=1_754_412_000_123_456_789, seq=7, meta={"gain_percent": 40.0}),
    make(np.uint16, (40, 24), 2, frame_id="oculus", intensity_scale=4000.0),
    make(np.uint32, (40, 24), 3),
    make(np.float32, (40, 24), 4, meta={"nested": {"list": [1, 2]}}),
    make(np.float64, (33, 17), 5),
    make(np.float32, (5, 40, 24), 6),
    make(np.uint8, (3, 40, 24), 7),
]


def test_round_trip_is_lossless_for_every_dtype_and_sample_axis(tmp_path):
    count = write_frames((f for f in FRAMES), tmp_path / "out")  # a generator: write_frames streams
    assert count == len(FRAMES)
    report = ReadReport()
    back = list(read_frames(tmp_path / "out", report))
    assert len(back) == len(FRAMES) and report.frames == len(FRAMES) and not report.skipped
    for a, b in zip(FRAMES, back, strict=True):
        assert_same(a, b)
    # 2-D 8/16-bit frames are person-viewable PNGs; the rest NPY.
    files = sorted(p.name for p in (tmp_path / "out" / "frames").iterdir())
    assert files[:2] == ["000000.png", "000001.png"] and files[2].endswith(".npy")
    assert cv2.imread(str(tmp_path / "out" / "frames" / "000000.png"), cv2.IMREAD_UNCHANGED).shape == (40, 24)
    # Frames sharing a geometry share its file.
    same = [FRAMES[0].replace(seq=i) for i in range(3)]
    write_frames(same, tmp_path / "shared")
    assert len(list((tmp_path / "shared" / "geometry").iterdir())) == 1


@settings(max_examples=25, deadline=None)
@given(dtype=st.sampled_from([np.uint8, np.uint16, np.uint32, np.float32, np.float64]),
       samples=st.sampled_from([None, 1, 2]), n_ranges=st.integers(1, 9), n_beams=st.integers(1, 9),
       stamp_ns=st.integers(0, 2**63 - 1), seq=st.integers(0, 2**32), seed=st.integers(0, 1000))
def test_any_frame_round_trips_through_a_folder(dtype, samples, n_ranges, n_beams, stamp_ns, seq, seed):
    shape = (n_ranges, n_beams) if samples is None else (samples, n_ranges, n_beams)
    frame = make(dtype, shape, seed, stamp_ns=stamp_ns, seq=seq, meta={"seed": seed})
    with tempfile.TemporaryDirectory() as folder:
        write_frames([frame, frame.replace(seq=seq + 1)], folder)
        first, second = read_frames(folder)
    assert_same(frame, first)
    assert second.seq == seq + 1


def test_numpy_meta_values_become_plain_json(tmp_path):
    frame = FRAMES[0].replace(meta={"f": np.float32(1.5), "a": np.arange(3), "i": np.int64(4)})
    write_frames([frame], tmp_path)
    assert next(read_frames(tmp_path)).meta == {"f": 1.5, "a": [0, 1, 2], "i": 4}
    with pytest.raises(FrameError, match="meta"):
        write_frames([FRAMES[0].replace(meta={"bad": object()})], tmp_path / "bad")
    assert not list((tmp_path / "bad" / "frames").iterdir())  # refused before anything was written
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(FormatError, match="a_file: path: exists and is not a folder"):
        write_frames(FRAMES[:1], tmp_path / "a_file")


def test_foreign_files_are_ignored_and_rewrites_replace_old_frames(tmp_path):
    write_frames(FRAMES[:4], tmp_path)
    (tmp_path / "masks").mkdir()
    cv2.imwrite(str(tmp_path / "masks" / "000000.png"), np.ones((40, 24), np.uint8))
    cv2.imwrite(str(tmp_path / "contact_sheet.png"), np.ones((10, 10), np.uint8))
    (tmp_path / "manifest.json").write_text('{"by": "simulator"}')
    assert len(list(read_frames(tmp_path))) == 4
    write_frames(FRAMES[4:5], tmp_path)
    back = list(read_frames(tmp_path))
    assert len(back) == 1
    assert_same(FRAMES[4], back[0])
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == ["000000.npy"]
    assert (tmp_path / "masks" / "000000.png").exists() and (tmp_path / "manifest.json").exists()
    # The index file itself is also a valid path.
    assert len(list(read_frames(tmp_path / "frames.jsonl"))) == 1


def test_partially_written_folder_reads_complete_frames(tmp_path):
    def frames_then_crash():
        yield FRAMES[0]
        yield FRAMES[1]
        raise RuntimeError("writer died")

    with pytest.raises(RuntimeError):
        write_frames(frames_then_crash(), tmp_path)
    back = list(read_frames(tmp_path))
    assert len(back) == 2
    assert_same(FRAMES[1], back[1])
    # A line cut mid-write (no newline) is reported, not fatal.
    with open(tmp_path / "frames.jsonl", "a") as index:
        index.write('{"file": "frames/0000')
    report = ReadReport()
    assert len(list(read_frames(tmp_path, report))) == 2
    assert report.problems and "incomplete" in report.problems[0]


def test_reading_is_lazy(tmp_path):
    write_frames(FRAMES[:3], tmp_path)
    frames = read_frames(tmp_path)
    assert_same(FRAMES[0], next(frames))
    (tmp_path / "frames" / "000002.npy").unlink()  # not yet read: the first frames must not need it
    assert_same(FRAMES[1], next(frames))
    with pytest.raises(FormatError, match="000002.npy.*file: missing"):
        next(frames)


def _rewrite_line(folder: Path, number: int, **changes) -> None:
    lines = (folder / "frames.jsonl").read_text().splitlines()
    entry = json.loads(lines[number + 1])
    entry.update(changes)
    lines[number + 1] = json.dumps(entry)
    (folder / "frames.jsonl").write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("change, message", [
    ({"colour": "red"}, "colour: unknown key"),
    ({"shape": [41, 24]}, "000000.png: shape"),
    ({"dtype": "uint16"}, "000000.png: dtype"),
    ({"file": "../escape.png"}, "file: expected a relative path"),
])
def test_inconsistent_index_lines_raise_format_errors(tmp_path, change, message):
    write_frames(FRAMES[:1], tmp_path)
    _rewrite_line(tmp_path, 0, **change)
    with pytest.raises(FormatError, match=message):
        list(read_frames(tmp_path))


def test_corrupt_files_raise_format_errors_naming_the_file(tmp_path):
    write_frames(FRAMES[:4], tmp_path)
    png = tmp_path / "frames" / "000000.png"
    png.write_bytes(png.read_bytes()[:60])
    with pytest.raises(FormatError, match=r"000000\.png: png: cannot decode"):
        list(read_frames(tmp_path))
    write_frames(FRAMES[:4], tmp_path)
    nan_frame = FRAMES[3].intensity.copy()
    nan_frame[3, 4] = np.nan
    np.save(tmp_path / "frames" / "000003.npy", nan_frame)
    with pytest.raises(FormatError, match=r"000003\.npy: intensity: NaN"):
        list(read_frames(tmp_path))
    write_frames(FRAMES[:1], tmp_path)
    geometry = next((tmp_path / "geometry").iterdir())
    geometry.write_text(json.dumps({"ranges_m": [1.0, 2.0], "azimuths_rad": [0.0]}))
    with pytest.raises(FormatError, match="ranges_m"):
        list(read_frames(tmp_path))
    (tmp_path / "frames.jsonl").write_text('{"format": "something-else", "version": 1}\n')
    with pytest.raises(FormatError, match="header.format"):
        list(read_frames(tmp_path))


# ---------------------------------------------------------------------------------------------- image folders


def test_png_folder_without_sidecar_assumes_documented_geometry(tmp_path):
    for i in (10, 2, 1):
        cv2.imwrite(str(tmp_path / f"ping-{i}.png"), np.full((30, 20), i, np.uint8))
    (tmp_path / "notes.txt").write_text("not a frame")
    report = ReadReport()
    frames = list(read_frames(tmp_path, report))
    assert [int(f.intensity[0, 0]) for f in frames] == [1, 2, 10]  # natural order
    assert [f.seq for f in frames] == [0, 1, 2]
    frame = frames[0]
    assert frame.meta["geometry_assumed"] is True and frame.meta["source"] == "ping-1.png"
    np.testing.assert_allclose(frame.ranges_m, np.arange(30) + 0.5)
    assert frame.fov_rad + frame.fov_rad / 19 == pytest.approx(math.radians(130))
    assert report.skipped == {"not a frame file (.txt)": 1}


def test_sidecars_give_geometry_and_are_merged_per_image(tmp_path):
    image = (np.arange(30 * 20, dtype=np.uint16).reshape(30, 20) * 50)
    bgr = np.repeat(image[:, :, None], 3, axis=2)  # R=G=B export, as the Oculus seabed set
    cv2.imwrite(str(tmp_path / "a.png"), bgr)
    cv2.imwrite(str(tmp_path / "b.png"), image)
    (tmp_path / "sonar.json").write_text(json.dumps({"max_range_m": 15.0, "fov_deg": 70.0, "frame_id": "fls"}))
    azimuths = np.sort(np.random.default_rng(0).uniform(-0.6, 0.6, 20)).tolist()
    (tmp_path / "b.json").write_text(json.dumps({"fov_deg": None, "azimuths_rad": azimuths, "stamp_ns": 99,
                                                 "seq": 5, "meta": {"gain_percent": 20}}))
    a, b = read_frames(tmp_path)
    np.testing.assert_array_equal(a.intensity, image)
    assert a.intensity.dtype == np.uint16 and a.frame_id == "fls" and "geometry_assumed" not in a.meta
    np.testing.assert_allclose(a.ranges_m, uniform_ranges(30, 15.0))
    np.testing.assert_allclose(a.azimuths_rad, uniform_azimuths(20, math.radians(70)))
    np.testing.assert_allclose(b.azimuths_rad, azimuths)
    assert (b.stamp_ns, b.seq, b.meta["gain_percent"], b.frame_id) == (99, 5, 20, "fls")


@pytest.mark.parametrize("sidecar, field", [
    ({"colour_map": "hot"}, "colour_map"),
    ({"ranges_m": [1.0, 2.0, 3.0]}, "ranges_m"),
    ({"azimuths_rad": [0.1, 0.2]}, "azimuths_rad"),
    ({"fov_deg": 400}, "fov_deg"),
    ({"apex_x_px": 3.0}, "apex_x_px"),
])
def test_bad_sidecars_are_rejected_naming_the_key(tmp_path, sidecar, field):
    cv2.imwrite(str(tmp_path / "x.png"), np.ones((30, 20), np.uint8))
    (tmp_path / "x.json").write_text(json.dumps(sidecar))
    with pytest.raises(FormatError, match=rf"x\.json: {field}: "):
        list(read_frames(tmp_path / "x.png"))


def test_tiff_pages_float_images_and_content_sniffing(tmp_path):
    pages = [np.full((16, 12), v, np.uint16) for v in (100, 200, 300)]
    cv2.imwritemulti(str(tmp_path / "stack.tif"), pages)
    (tmp_path / "stack.tif").rename(tmp_path / "stack.dat")  # the extension does not matter
    assert [int(f.intensity[0, 0]) for f in read_frames(tmp_path / "stack.dat")] == [100, 200, 300]
    floats = np.random.default_rng(0).random((16, 12)).astype(np.float32)
    cv2.imwrite(str(tmp_path / "f.tiff"), floats)
    np.testing.assert_array_equal(next(read_frames(tmp_path / "f.tiff")).intensity, floats)
    floats[2, 2] = np.inf
    cv2.imwrite(str(tmp_path / "f.tiff"), floats)
    with pytest.raises(FormatError, match=r"f\.tiff: intensity: NaN or inf"):
        list(read_frames(tmp_path / "f.tiff"))
    (tmp_path / "junk.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)
    with pytest.raises(FormatError, match=r"junk\.png: png"):
        list(read_frames(tmp_path / "junk.png"))
    (tmp_path / "unknown.bin").write_bytes(b"hello world")
    with pytest.raises(FormatError, match="magic"):
        list(read_frames(tmp_path / "unknown.bin"))


def test_real_oculus_png_export_reads_as_polar_frames(real_oculus):
    images = real_oculus / "val" / "images"
    report = ReadReport()
    frames = list(read_frames(images, report))
    assert len(frames) == len(list(images.glob("*.png"))) > 50
    assert all(f.n_beams == 256 and f.intensity.dtype == np.uint8 and "converted_from" not in f.meta for f in frames)
    assert all(f.intensity.max() == 255 for f in frames)  # the export scaled each frame to its maximum


def test_oculus_streams_are_found_by_content_inside_mixed_folders(tmp_path):
    shutil.copy(OCULUS_SAMPLE, tmp_path / "a_pings.png")  # a misleading extension: the magic bytes decide
    cv2.imwrite(str(tmp_path / "b.png"), np.full((30, 20), 7, np.uint8))
    frames = list(read_frames(tmp_path))
    assert [f.n_beams for f in frames] == [256, 256, 256, 20]
    assert "geometry_assumed" not in frames[0].meta and frames[3].meta["geometry_assumed"] is True
