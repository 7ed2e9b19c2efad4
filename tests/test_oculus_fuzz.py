"""Random and mutated bytes: the Oculus readers must end cleanly or raise FormatError, nothing else, never hang."""

import os
import tempfile

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from sonar_realism.errors import FormatError
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.io.oculus import (
    SQLITE_MAGIC,
    decode_ping,
    encode_message,
    encode_ping,
    read_oculus,
    write_oculus_log,
)
from sonar_realism.io.report import ReadReport

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def tiny_frame(seq: int, dtype=np.uint8) -> SonarImage:
    intensity = (np.arange(6 * 8, dtype=np.uint32).reshape(6, 8) * (seq + 3)).astype(dtype)
    return SonarImage(intensity, uniform_ranges(6, 3.0), uniform_azimuths(8, np.radians(60)), seq=seq,
                      stamp_ns=1_700_000_000_000_000_000 + seq * 1000)


def valid_raw_stream() -> bytes:
    return (encode_ping(tiny_frame(1)) + encode_message(0xFF, b"")
            + encode_ping(tiny_frame(2, np.uint16), version=2, with_gains=True, row_gains=range(6))
            + encode_ping(tiny_frame(3, np.uint32)))


def valid_log(compress: bool) -> bytes:
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "fixture.oculus")
        write_oculus_log([tiny_frame(i) for i in range(3)], path, version=1 + (compress is True), compress=compress)
        with open(path, "rb") as handle:
            return handle.read()


RECORDINGS = [valid_raw_stream(), valid_log(False), valid_log(True)]
PINGS = [encode_ping(tiny_frame(1)), encode_ping(tiny_frame(2, np.uint16), version=2, with_gains=True)]


@st.composite
def mutated(draw, seeds: list[bytes]) -> bytes:
    data = bytearray(draw(st.sampled_from(seeds)))
    for _ in range(draw(st.integers(1, 6))):
        kind = draw(st.sampled_from(["flip", "truncate", "insert", "delete", "word"]))
        at = draw(st.integers(0, max(len(data) - 1, 0)))
        if kind == "flip" and data:
            data[at] ^= draw(st.integers(1, 255))
        elif kind == "truncate":
            del data[at:]
        elif kind == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=40))
        elif kind == "delete":
            del data[at:at + draw(st.integers(1, 40))]
        elif kind == "word" and len(data) >= at + 4:  # size fields are 32-bit: write extreme values
            data[at:at + 4] = draw(st.sampled_from([0, 1, 0x7FFFFFFF, 0xFFFFFFFF, 3 << 30])).to_bytes(4, "little")
    return bytes(data)


def read_file_bytes(data: bytes) -> ReadReport:
    report = ReadReport()
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "fuzz.bin")
        with open(path, "wb") as handle:
            handle.write(data)
        try:
            for frame in read_oculus(path, report):
                assert frame.intensity.ndim == 2
        except FormatError:
            pass
    return report


@FUZZ
@given(st.binary(max_size=600))
def test_decode_ping_on_random_bytes_raises_only_format_errors(data):
    try:
        decode_ping(data)
    except FormatError:
        pass


@FUZZ
@given(mutated(PINGS))
def test_decode_ping_on_mutated_messages_raises_only_format_errors(data):
    try:
        decode_ping(data)
    except FormatError:
        pass


@FUZZ
@given(st.one_of(st.binary(max_size=400), st.binary(max_size=300).map(lambda b: b"SO\x00\x00\x00\x00\x23\x00" + b),
                 st.binary(max_size=300).map(lambda b: b"\x44\x33\x22\x11\x30\x00\x00\x00" + b)))
def test_read_oculus_on_random_bytes_raises_only_format_errors(data):
    read_file_bytes(data)


@settings(FUZZ, max_examples=150)
@given(mutated(RECORDINGS))
def test_read_oculus_on_mutated_recordings_ends_cleanly(data):
    report = read_file_bytes(data)
    assert report.frames <= 3


def recording_records(kind: str) -> tuple[bytes, list[tuple[int, int]], list[SonarImage]]:
    """A three-ping recording, the (start, end) byte span of each ping's record, and the frames it holds."""
    frames = [tiny_frame(1), tiny_frame(2, np.uint16), tiny_frame(3, np.uint32)]
    if kind == "raw":
        records = [encode_ping(frame, version=1 + (frame.seq == 2)) for frame in frames]
        start = 0
    else:
        data = valid_log(kind == "log_compressed")
        start, records = 48, []
        while start < len(data):
            size = 40 + int.from_bytes(data[start + 32:start + 36], "little")
            records.append(data[start:start + size])
            start += size
        start = 48
        frames = [tiny_frame(i) for i in range(3)]
    spans, offset = [], start
    for record in records:
        spans.append((offset, offset + len(record)))
        offset += len(record)
    head = b"" if kind == "raw" else valid_log(kind == "log_compressed")[:48]
    return head + b"".join(records), spans, frames


@settings(FUZZ, max_examples=120)
@given(st.sampled_from(["raw", "log", "log_compressed"]), st.integers(0, 2), st.data())
def test_corrupting_one_record_loses_no_other_record(kind, victim, data):
    recording, spans, frames = recording_records(kind)
    start, end = spans[victim]
    at = data.draw(st.integers(start, end - 1))
    mutated = bytearray(recording)
    action = data.draw(st.sampled_from(["flip", "insert", "delete"]))
    if action == "flip":
        mutated[at] ^= data.draw(st.integers(1, 255))
    elif action == "insert":
        mutated[at:at] = data.draw(st.binary(min_size=1, max_size=40))
    else:
        mutated[at:min(at + data.draw(st.integers(1, 40)), end)] = b""
    # A file that now begins with the SQLite magic is a V2 log to the reader (refused by design), not a
    # recording with one bad record: hypothesis found this by inserting the magic at byte 0 of a raw stream.
    assume(not mutated.startswith(SQLITE_MAGIC))
    report = ReadReport()
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "one_bad_record.bin")
        with open(path, "wb") as handle:
            handle.write(mutated)
        decoded = list(read_oculus(path, report))
    for index, frame in enumerate(frames):
        if index != victim:
            assert any(got.seq == frame.seq and np.array_equal(got.intensity, frame.intensity) for got in decoded), (
                f"record {index} lost after corrupting record {victim}: {report.as_dict()}")
