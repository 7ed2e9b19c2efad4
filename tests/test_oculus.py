import struct
import tracemalloc
import zlib
from pathlib import Path

import numpy as np
import pytest

from sonar_realism.errors import FormatError, FrameError, UnsupportedFormatError
from sonar_realism.frames import SonarImage, uniform_ranges
from sonar_realism.io.oculus import (
    ITEM_MAGIC,
    LOG_HEADER,
    LOG_ITEM,
    LOG_MAGIC,
    decode_ping,
    encode_message,
    encode_ping,
    read_oculus,
    sniff,
    write_oculus_log,
)
from sonar_realism.io.report import ReadReport

REAL_RAW = Path(__file__).parent / "data" / "three_pings_8bit.raw"
REAL_MESSAGE_BYTES = 182_016
GIGABYTES_3 = 3 * 1024**3


def ping_frame(n_ranges=12, n_beams=16, dtype=np.uint8, seed=0, seq=7, stamp_ns=0, fov_deg=130.0):
    """A small frame with a non-uniform bearing table (1/100 degree steps like a real sonar)."""
    rng = np.random.default_rng(seed)
    info = np.iinfo(dtype)
    intensity = rng.integers(0, int(info.max) + 1, size=(n_ranges, n_beams), dtype=dtype)
    centideg = np.round(np.linspace(-fov_deg / 2, fov_deg / 2, n_beams) * 100) + rng.integers(-3, 4, n_beams)
    return SonarImage(intensity, uniform_ranges(n_ranges, 5.0), np.radians(centideg / 100.0), stamp_ns=stamp_ns,
                      seq=seq, meta={"frequency_hz": 750e3, "gain_percent": 40.0, "device_id": 19125})


def log_item(payload: bytes, item_type=10, time_s=0.0, compression=0, original_size=None) -> bytes:
    original = len(payload) if original_size is None else original_size
    return LOG_ITEM.pack(ITEM_MAGIC, LOG_ITEM.size, item_type, 0, time_s, compression, original, len(payload)) + payload


def log_bytes(*items: bytes, encryption=0, header_size=LOG_HEADER.size) -> bytes:
    return LOG_HEADER.pack(LOG_MAGIC, header_size, b"Oculus", 1, encryption, 0, 0.0) + b"".join(items)


def real_messages() -> list[bytes]:
    data = REAL_RAW.read_bytes()
    return [data[i:i + REAL_MESSAGE_BYTES] for i in range(0, len(data), REAL_MESSAGE_BYTES)]


def read_all(path, report=None):
    return list(read_oculus(path, report))


def with_field(message: bytes, offset: int, fmt: str, value) -> bytes:
    patched = bytearray(message)
    struct.pack_into(fmt, patched, offset, value)
    return bytes(patched)


def twenty_four_bit_ping(frame: SonarImage) -> bytes:
    """A well-formed v1 ping with 3-byte samples (encode_ping refuses to write them)."""
    base = bytearray(encode_ping(frame))
    image_size = frame.n_ranges * frame.n_beams * 3
    message = base + bytes(image_size - frame.intensity.size)
    struct.pack_into("<I", message, 10, len(message) - 16)  # payloadSize
    struct.pack_into("<B", message, 97, 2)  # dataSize 24-bit
    struct.pack_into("<II", message, 114, image_size, len(message))  # imageSize, messageSize
    return bytes(message)


# --- the real capture -------------------------------------------------------------------------------------------

def test_real_raw_capture_decodes_to_pinned_values():
    report = ReadReport()
    frames = read_all(REAL_RAW, report)
    assert [f.seq for f in frames] == [415323, 415324, 415325]
    assert report.frames == 3 and not report.skipped and not report.problems
    assert [int(f.intensity.sum(dtype=np.int64)) for f in frames] == [10052524, 10101513, 10008409]
    first = frames[0]
    assert first.intensity.shape == (703, 256) and first.intensity.dtype == np.uint8
    assert first.intensity[100, 100] == 5 and frames[1].intensity[100, 100] == 13
    assert first.stamp_ns == 0 and first.frame_id == "oculus"
    assert np.degrees(first.azimuths_rad[[0, -1]]) == pytest.approx([-30.0, 30.0])
    steps = np.round(np.diff(np.degrees(first.azimuths_rad)) * 100).astype(int)
    assert (steps.min(), steps.max(), int((steps == 23).sum())) == (22, 26, 110)  # the real table is not uniform
    meta = first.meta
    assert meta["frequency_hz"] == pytest.approx(2_098_880.597, abs=1e-3)
    assert meta["range_resolution_m"] == pytest.approx(0.0028421890)
    assert first.ranges_m[0] == pytest.approx(0.5 * meta["range_resolution_m"])
    assert first.ranges_m[-1] == pytest.approx(702.5 * meta["range_resolution_m"])
    assert (meta["msg_version"], meta["device_id"], meta["sample_bits"], meta["flags"]) == (0, 7892, 8, 0x19)
    assert meta["sound_speed_mps"] == pytest.approx(1490.6586) and meta["range_demand"] == 2.0
    assert "row_gains" not in meta


def test_real_ping_is_a_read_only_zero_copy_view():
    message = bytearray(real_messages()[0])
    frame = decode_ping(message)
    assert not frame.intensity.flags.writeable
    message[2048] = 200  # first image byte: the frame sees it, so no copy was made
    assert frame.intensity[0, 0] == 200


def test_real_ping_survives_reencoding_with_real_image_offset():
    original = decode_ping(real_messages()[0])
    again = decode_ping(encode_ping(original, version=1, image_offset=2048))
    np.testing.assert_array_equal(again.intensity, original.intensity)
    np.testing.assert_array_equal(again.azimuths_rad, original.azimuths_rad)
    np.testing.assert_allclose(again.ranges_m, original.ranges_m, rtol=1e-12)
    for key in ("frequency_hz", "sound_speed_mps", "gain_percent", "device_id", "ping_start_time", "flags"):
        assert again.meta[key] == original.meta[key], key


def test_real_pings_inside_a_v1_log_get_item_times(tmp_path):
    times = [1754406000.125, 1754406000.225, 1754406000.325]
    path_bytes = log_bytes(*(log_item(m, time_s=t) for m, t in zip(real_messages(), times, strict=True)))
    raw = read_all(REAL_RAW)
    frames = list(read_oculus(_write(path_bytes, "real.oculus", tmp_path)))
    assert [f.stamp_ns for f in frames] == [1754406000125000000, 1754406000225000000, 1754406000325000000]
    for got, want in zip(frames, raw, strict=True):
        np.testing.assert_array_equal(got.intensity, want.intensity)
        assert got.seq == want.seq


# --- sniffing --------------------------------------------------------------------------------------------------

def test_sniff_tells_log_raw_and_other_files_apart():
    assert sniff(REAL_RAW.read_bytes()[:64]) == "oculus_raw"
    assert sniff(log_bytes()[:64]) == "oculus_log"
    assert sniff(b"\x89PNG\r\n\x1a\n" + bytes(56)) is None
    assert sniff(b"SQLite format 3\x00" + bytes(48)) is None
    assert sniff(encode_message(0x77, b"")) is None  # b"SO" but no message id the sonar sends
    assert sniff(b"SO") is None


# --- encode / decode round trips --------------------------------------------------------------------------------

@pytest.mark.parametrize("version", [1, 2])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.uint32])
@pytest.mark.parametrize("with_gains", [False, True])
@pytest.mark.parametrize("n_beams", [256, 512])
def test_encode_decode_round_trip(version, dtype, with_gains, n_beams):
    frame = ping_frame(n_ranges=9, n_beams=n_beams, dtype=dtype, seq=4242)
    gains = list(range(1000, 1009)) if with_gains else None
    decoded = decode_ping(encode_ping(frame, version=version, with_gains=with_gains, row_gains=gains))
    np.testing.assert_array_equal(decoded.intensity, frame.intensity)
    assert decoded.intensity.dtype == np.dtype(dtype)
    assert decoded.seq == 4242
    np.testing.assert_allclose(decoded.ranges_m, frame.ranges_m, rtol=1e-12)
    np.testing.assert_allclose(np.degrees(decoded.azimuths_rad), np.degrees(frame.azimuths_rad), atol=0.005)
    assert decoded.meta["sample_bits"] == 8 * np.dtype(dtype).itemsize
    assert decoded.meta["msg_version"] == version
    assert bool(decoded.meta["flags"] & 0x40) == (n_beams == 512)
    assert decoded.meta.get("row_gains") == gains
    assert decoded.meta["frequency_hz"] == 750e3 and decoded.meta["device_id"] == 19125
    assert ("heading_deg" in decoded.meta) == (version == 2)


def test_v2_fields_round_trip():
    frame = ping_frame().replace(meta={"heading_deg": 12.5, "pitch_deg": -1.0, "roll_deg": 0.25,
                                       "ping_start_time": 1234.066667, "ext_flags": 0x200})
    meta = decode_ping(encode_ping(frame, version=2)).meta
    assert (meta["heading_deg"], meta["pitch_deg"], meta["roll_deg"]) == (12.5, -1.0, 0.25)
    assert meta["ping_start_time"] == 1234.066667 and meta["ext_flags"] == 0x200


def test_encode_ping_refuses_frames_it_cannot_represent():
    frame = ping_frame()
    with pytest.raises(FrameError, match="uint8/16/32"):
        encode_ping(frame.replace(intensity=frame.intensity.astype(np.float32)))
    with pytest.raises(FrameError, match="row_gains"):
        encode_ping(frame, with_gains=True, row_gains=[1, 2])
    with pytest.raises(FrameError, match="1/100 degree"):
        encode_ping(frame.replace(azimuths_rad=np.linspace(0, 1e-5, frame.n_beams)))


@pytest.mark.parametrize("compress", [False, True])
@pytest.mark.parametrize("version", [1, 2])
def test_v1_log_writer_round_trips(tmp_path, compress, version):
    frames = [ping_frame(dtype=np.uint16, seed=i, seq=100 + i, stamp_ns=1_754_406_000_000_000_000 + i * 66_667_000)
              for i in range(4)]
    path = tmp_path / "log.oculus"
    assert write_oculus_log(frames, path, version=version, compress=compress) == 4
    data = path.read_bytes()
    magic, header_size, name, file_version, encryption, _key, file_time = LOG_HEADER.unpack_from(data)
    assert (magic, header_size, name.rstrip(b"\0"), file_version, encryption) == (LOG_MAGIC, 48, b"Oculus", 1, 0)
    assert file_time == pytest.approx(1_754_406_000.0)
    item = LOG_ITEM.unpack_from(data, 48)
    assert item[:3] == (ITEM_MAGIC, 40, 10) and item[5] == int(compress)
    report = ReadReport()
    back = read_all(path, report)
    assert report.frames == 4 and not report.skipped
    for got, want in zip(back, frames, strict=True):
        np.testing.assert_array_equal(got.intensity, want.intensity)
        assert (got.seq, got.stamp_ns) == (want.seq, want.stamp_ns)
        assert got.meta["msg_version"] == version


# --- skipping and resynchronising -----------------------------------------------------------------------------

def test_raw_stream_skips_garbage_and_other_messages_and_keeps_every_ping(tmp_path):
    pings = [encode_ping(ping_frame(seq=i, seed=i)) for i in range(4)]
    garbage = b"\x00garbage SO but not a message\xff"
    stream = (pings[0] + garbage * 3 + encode_message(0xFF, b"")
              + pings[1] + encode_message(0x80, b"log text line") + encode_message(0x99, bytes(10))
              + pings[2] + b"S" + pings[3])
    report = ReadReport()
    frames = read_all(_write(stream, "stream.raw", tmp_path), report)
    assert [f.seq for f in frames] == [0, 1, 2, 3]
    assert report.skipped["msg_id 0xff (dummy)"] == 1 and report.skipped["msg_id 0x80 (log text)"] == 1
    assert report.skipped["msg_id 0x99 (unknown)"] == 1
    assert report.skipped["garbage bytes"] == 3 * len(garbage) + 1
    assert not report.problems


def test_raw_capture_that_starts_mid_message_is_read_from_the_first_ping_header(tmp_path):
    data = REAL_RAW.read_bytes()
    report = ReadReport()
    frames = read_all(_write(data[100_000:], "joined_late.raw", tmp_path), report)
    assert [f.seq for f in frames] == [415324, 415325]
    assert report.skipped["garbage bytes"] == REAL_MESSAGE_BYTES - 100_000


def test_log_skips_and_counts_other_items_and_messages(tmp_path):
    pings = [encode_ping(ping_frame(seq=i, seed=i)) for i in range(3)]
    data = log_bytes(log_item(b"settings", item_type=1), log_item(pings[0], time_s=10.0),
                     log_item(struct.pack("<QQ", 10, 5), item_type=1010), log_item(encode_message(0xFF, b"")),
                     log_item(pings[1], time_s=11.0), b"junk between items", log_item(pings[2], time_s=12.0))
    report = ReadReport()
    frames = read_all(_write(data, "mixed.oculus", tmp_path), report)
    assert [(f.seq, f.stamp_ns) for f in frames] == [(0, 10 * 10**9), (1, 11 * 10**9), (2, 12 * 10**9)]
    assert report.skipped["item type 1"] == 1 and report.skipped["item type 1010"] == 1
    assert report.skipped["msg_id 0xff (dummy)"] == 1 and report.skipped["garbage bytes"] == len(b"junk between items")


def test_implausible_item_times_leave_the_stamp_unknown(tmp_path):
    ping = encode_ping(ping_frame())
    data = log_bytes(log_item(ping, time_s=float("nan")), log_item(ping, time_s=-5.0), log_item(ping, time_s=1e300))
    report = ReadReport()
    assert [f.stamp_ns for f in read_all(_write(data, "times.oculus", tmp_path), report)] == [0, 0, 0]
    assert report.skipped["item time invalid (stamp_ns left 0)"] == 3


# --- bad input ------------------------------------------------------------------------------------------------

def test_wrong_magic_raises_naming_the_file(tmp_path):
    path = _write(b"\x89PNG\r\n\x1a\n" + bytes(100), "image.oculus", tmp_path)
    with pytest.raises(FormatError, match="image.oculus.*file magic"):
        read_all(path)
    with pytest.raises(FormatError, match="oculusId"):
        decode_ping(b"XX" + encode_ping(ping_frame())[2:])


def test_sqlite_v2_log_is_unsupported(tmp_path):
    with pytest.raises(UnsupportedFormatError, match="SQLite"):
        read_all(_write(b"SQLite format 3\x00" + bytes(100), "v2.oculus", tmp_path))


def test_truncated_raw_file_keeps_complete_pings_and_reports_the_rest(tmp_path):
    data = REAL_RAW.read_bytes()
    report = ReadReport()
    frames = read_all(_write(data[: 2 * REAL_MESSAGE_BYTES + 5000], "cut.raw", tmp_path), report)
    assert [f.seq for f in frames] == [415323, 415324]
    assert any("runs past the end of the file" in p for p in report.problems)
    report = ReadReport()
    assert len(read_all(_write(data[: REAL_MESSAGE_BYTES + 7], "cut_header.raw", tmp_path), report)) == 1
    assert any("truncated message header" in p for p in report.problems)


def test_truncated_log_keeps_complete_items(tmp_path):
    data = log_bytes(*(log_item(m) for m in real_messages()))
    report = ReadReport()
    frames = read_all(_write(data[:-1000], "cut.oculus", tmp_path), report)
    assert [f.seq for f in frames] == [415323, 415324]
    assert report.skipped["corrupt record"] == 1
    with pytest.raises(FormatError, match="file header"):
        read_all(_write(data[:20], "stub.oculus", tmp_path))


def test_log_header_lies_and_encryption_raise(tmp_path):
    with pytest.raises(FormatError, match="sizeHeader"):
        read_all(_write(log_bytes(header_size=10**9), "lying.oculus", tmp_path))
    with pytest.raises(UnsupportedFormatError, match="encrypt"):
        read_all(_write(log_bytes(encryption=1), "secret.oculus", tmp_path))


def test_image_beyond_its_message_is_refused_and_the_stream_goes_on(tmp_path):
    good = encode_ping(ping_frame(seq=1))
    lying = with_field(encode_ping(ping_frame(seq=2)), 114, "<I", 10**6)  # v1 imageSize
    with pytest.raises(FormatError, match="imageSize.*runs past the end"):
        decode_ping(lying)
    report = ReadReport()
    frames = read_all(_write(lying + good, "lie.raw", tmp_path), report)
    assert [f.seq for f in frames] == [1]
    assert "imageSize" in report.problems[0]


def test_gigabyte_payload_sizes_do_not_allocate(tmp_path):
    pings = [encode_ping(ping_frame(seq=i, seed=i)) for i in range(3)]
    raw_lie = with_field(pings[1], 10, "<I", GIGABYTES_3)  # message header payloadSize
    log_lie = LOG_ITEM.pack(ITEM_MAGIC, 40, 10, 0, 0.0, 0, GIGABYTES_3, GIGABYTES_3) + pings[1]
    raw_path = _write(pings[0] + raw_lie + pings[2], "huge.raw", tmp_path)
    log_path = _write(log_bytes(log_item(pings[0]), log_lie, log_item(pings[2])), "huge.oculus", tmp_path)
    with pytest.raises(FormatError, match="payloadSize"):
        decode_ping(raw_lie)
    tracemalloc.start()
    try:
        raw_report, log_report = ReadReport(), ReadReport()
        raw_frames, log_frames = read_all(raw_path, raw_report), read_all(log_path, log_report)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 * 1024**2
    assert [f.seq for f in raw_frames] == [0, 2] and [f.seq for f in log_frames] == [0, 2]
    assert raw_report.skipped["corrupt record"] == 1 and log_report.skipped["corrupt record"] == 1


def test_24_bit_samples_are_unsupported(tmp_path):
    message = twenty_four_bit_ping(ping_frame())
    with pytest.raises(UnsupportedFormatError, match="unsupported"):
        decode_ping(message)
    with pytest.raises(UnsupportedFormatError, match="24-bit"):
        read_all(_write(message + message, "only24.raw", tmp_path))
    report = ReadReport()
    frames = read_all(_write(message + encode_ping(ping_frame(seq=3)), "mixed24.raw", tmp_path), report)
    assert [f.seq for f in frames] == [3] and report.skipped["unsupported dataSize"] == 1


def test_inconsistent_ping_fields_are_refused():
    message = encode_ping(ping_frame(n_ranges=4, n_beams=8))
    with pytest.raises(FormatError, match="imageSize.*per-row gains"):
        decode_ping(with_field(message, 20, "<B", 0x19 | 0x04))  # gain flag without gain prefixes
    with pytest.raises(FormatError, match="messageSize"):
        decode_ping(with_field(message, 118, "<I", 5))
    with pytest.raises(FormatError, match="dataSize"):
        decode_ping(with_field(message, 97, "<B", 9))
    with pytest.raises(FormatError, match="bearings"):
        decode_ping(with_field(message, 122, "<h", 9000))  # first bearing above the second
    with pytest.raises(FormatError, match="rangeResolution"):
        decode_ping(with_field(message, 98, "<d", float("nan")))
    with pytest.raises(FormatError, match="msgId"):
        decode_ping(encode_message(0x22, bytes(600)))
    with pytest.raises(FormatError, match="payloadSize"):
        decode_ping(message + b"extra")


def test_corrupt_compressed_item_is_reported_and_the_next_item_read(tmp_path):
    message = encode_ping(ping_frame(seq=5))
    compressed = struct.pack(">I", len(message)) + zlib.compress(message, 1)
    broken = compressed[:30] + bytes(20) + compressed[50:]
    wrong_length = struct.pack(">I", len(message) + 1) + compressed[4:]
    data = log_bytes(log_item(broken, compression=1, original_size=len(message)),
                     log_item(wrong_length, compression=1, original_size=len(message)),
                     log_item(compressed, compression=0, original_size=len(message)),  # flag lies: still inflated
                     log_item(compressed, compression=1, original_size=len(message)),
                     log_item(compressed, compression=7, original_size=len(message)))
    report = ReadReport()
    frames = read_all(_write(data, "zlib.oculus", tmp_path), report)
    assert [f.seq for f in frames] == [5, 5]
    assert report.skipped["corrupt record"] == 2 and report.skipped["unsupported compression"] == 1


def _write(data: bytes, name: str, folder: Path) -> Path:
    path = folder / name
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("cut", [1, 77, 2000])
def test_read_frames_recognises_a_raw_capture_that_starts_mid_stream(tmp_path, cut):
    from sonar_realism.io import read_frames
    from sonar_realism.io import sniff as sniff_file

    pings = [encode_ping(ping_frame(n_ranges=64, n_beams=256, seq=10 + i, seed=i)) for i in range(3)]
    path = _write(b"".join(pings)[cut:], "joined_late.raw", tmp_path)  # the first message is cut short
    assert sniff(path.read_bytes()[:64]) is None  # not a message boundary at byte 0 ...
    assert sniff_file(path) == "oculus_raw"       # ... but the file sniffer finds the ping headers further in
    report = ReadReport()
    assert [f.seq for f in read_frames(path, report)] == [11, 12]
    assert report.skipped["garbage bytes"] == len(pings[0]) - cut


def test_the_mid_stream_search_is_bounded_and_refuses_other_content(tmp_path):
    from sonar_realism.io import read_frames

    ping = encode_ping(ping_frame(seq=3))
    far = _write(bytes(2 << 20) + ping, "far.raw", tmp_path)  # a ping header only after 2 MiB of zeros
    with pytest.raises(FormatError, match="unrecognised content"):
        list(read_frames(far))
    text = _write(b"SO what? " * 1000, "notes.txt", tmp_path)
    with pytest.raises(FormatError, match="unrecognised content"):
        list(read_frames(text))
