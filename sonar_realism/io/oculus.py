"""Blueprint Subsea Oculus recordings: simple ping result messages (0x23, v1 and v2), raw TCP message
streams and ViewPoint `.oculus` V1 logs.

Byte layouts (docs/oculus.md): everything little-endian, the
network structs packed, the log structs naturally aligned (48-byte file header, 40-byte item header).
Every size field is checked against the bytes actually present before anything is sliced or allocated,
so a lying size costs at most one bounded read. Readers stream one message at a time (positional reads
on the open file), never the whole file. Corrupt records are reported in a ReadReport and reading
resumes at the next magic, so nothing valid after a corrupt record is lost.
"""

from __future__ import annotations

import functools
import math
import os
import struct
import zlib
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from sonar_realism.errors import FormatError, FrameError, UnsupportedFormatError
from sonar_realism.frames import SonarImage
from sonar_realism.io.report import ReadReport

OCULUS_ID = 0x4F53  # b"SO" on the wire
OCULUS_ID_BYTES = b"SO"
MSG_SIMPLE_PING = 0x23
# Message ids a sonar or its client sends (section 3.2); only 0x23 carries an image we decode.
KNOWN_MESSAGE_IDS = {0x15: "simple fire", 0x22: "full ping result", 0x23: "simple ping result",
                     0x55: "user config", 0x80: "log text", 0xFF: "dummy"}

LOG_MAGIC = 0x11223344
ITEM_MAGIC = 0xAABBCCDD
ITEM_MAGIC_BYTES = struct.pack("<I", ITEM_MAGIC)
ITEM_TYPE_OCULUS_SONAR = 10
SQLITE_MAGIC = b"SQLite format 3\x00"

# No 0x23 message can exceed this: 512 beams x 65535 ranges x 4 bytes plus gain prefixes is ~135 MB.
# A size field above it is a lie, refused before any allocation.
MAX_MESSAGE_BYTES = 256 * 1024 * 1024
# Bearings are int16 hundredths of a degree; anything beyond half a turn is corrupt.
MAX_BEARING_CENTIDEG = 18000

MSG_HEADER = struct.Struct("<HHHHHIH")  # oculusId, src, dst, msgId, msgVersion, payloadSize, spare
LOG_HEADER = struct.Struct("<II16sHH4xqd")  # magic, sizeHeader, source, version, encryption, key, time
LOG_ITEM = struct.Struct("<IIHH4xdH2xII4x")  # magic, sizeHeader, type, version, time, compression, orig, payload

_FIRE_V1 = "BBBBBdddd"  # masterMode, pingRate, networkSpeed, gamma, flags, range, gain, speedOfSound, salinity
_FIRE_FIELDS_V1 = ("master_mode", "ping_rate", "network_speed", "gamma_correction", "flags", "range_demand",
                   "gain_percent", "sound_speed_demand_mps", "salinity_ppt")
PING_V1 = struct.Struct("<" + MSG_HEADER.format[1:] + _FIRE_V1 + "IIddddIBdHHIII")
PING_V1_FIELDS = ("oculus_id", "device_id", "dst_device_id", "msg_id", "msg_version", "payload_size", "spare2",
                  *_FIRE_FIELDS_V1, "ping_id", "status", "frequency_hz", "temperature_c", "pressure_bar",
                  "sound_speed_mps", "ping_start_time", "data_size", "range_resolution_m", "n_ranges", "n_beams",
                  "image_offset", "image_size", "message_size")
PING_V2 = struct.Struct("<" + MSG_HEADER.format[1:] + _FIRE_V1 + "I32x" + "IIddddddddBdHH16xIII")
PING_V2_FIELDS = ("oculus_id", "device_id", "dst_device_id", "msg_id", "msg_version", "payload_size", "spare2",
                  *_FIRE_FIELDS_V1, "ext_flags", "ping_id", "status", "frequency_hz", "temperature_c",
                  "pressure_bar", "heading_deg", "pitch_deg", "roll_deg", "sound_speed_mps", "ping_start_time",
                  "data_size", "range_resolution_m", "n_ranges", "n_beams", "image_offset", "image_size",
                  "message_size")
assert (PING_V1.size, PING_V2.size, LOG_HEADER.size, LOG_ITEM.size) == (122, 202, 48, 40)

FLAG_RANGE_IN_METRES = 0x01
FLAG_16_BIT = 0x02
FLAG_ROW_GAINS = 0x04
FLAG_SIMPLE_RETURN = 0x08
FLAG_GAIN_ASSIST = 0x10
FLAG_512_BEAMS = 0x40
ROW_GAIN_BYTES = 4
DATA_SIZE_BYTES = {0: 1, 1: 2, 2: 3, 3: 4}  # DataSizeType -> bytes per sample (2 = 24-bit, unsupported)

# Ping fields that go into SonarImage.meta (the rest are geometry, sizes or already in seq).
_META_FIELDS = ("device_id", "msg_version", "master_mode", "ping_rate", "gamma_correction", "flags", "range_demand",
                "gain_percent", "sound_speed_demand_mps", "salinity_ppt", "status", "frequency_hz", "temperature_c",
                "pressure_bar", "sound_speed_mps", "ping_start_time", "range_resolution_m", "heading_deg",
                "pitch_deg", "roll_deg", "ext_flags")
_FIND_CHUNK = 1 << 20


def sniff(head: bytes) -> str | None:
    """"oculus_log" for a V1 `.oculus` log, "oculus_raw" for a raw message stream, None otherwise.

    `head` is the first bytes of the file (at least 16 are needed for a raw stream)."""
    if len(head) >= 4 and struct.unpack_from("<I", head)[0] == LOG_MAGIC:
        return "oculus_log"
    if len(head) >= MSG_HEADER.size:
        oculus_id, _src, _dst, msg_id, _version, payload_size, _spare = MSG_HEADER.unpack_from(head)
        if oculus_id == OCULUS_ID and msg_id in KNOWN_MESSAGE_IDS and payload_size <= MAX_MESSAGE_BYTES:
            return "oculus_raw"
    return None


def _ping_fields(message: bytes | memoryview, source: str) -> dict[str, Any]:
    """Parse and cross-check the fixed part of a 0x23 message. `message` may hold only the fixed part:
    every size is checked against the declared message size, so a reader can vet a message before reading it."""
    if len(message) < MSG_HEADER.size:
        raise FormatError(source, "header", f"{len(message)} bytes, a message header needs {MSG_HEADER.size}")
    oculus_id, _src, _dst, msg_id, msg_version, payload_size, _spare = MSG_HEADER.unpack_from(message)
    if oculus_id != OCULUS_ID:
        raise FormatError(source, "oculusId", f"0x{oculus_id:04x}, expected 0x{OCULUS_ID:04x} (b'SO')")
    if msg_id != MSG_SIMPLE_PING:
        raise FormatError(source, "msgId", f"0x{msg_id:02x} is not a simple ping result (0x23)")
    layout, names = (PING_V2, PING_V2_FIELDS) if msg_version == 2 else (PING_V1, PING_V1_FIELDS)
    message_size = MSG_HEADER.size + payload_size
    if message_size < layout.size or len(message) < layout.size:
        raise FormatError(source, "payloadSize", f"{min(message_size, len(message))} bytes, a v{1 + (msg_version == 2)}"
                          f" simple ping result needs at least {layout.size}")
    fields = dict(zip(names, layout.unpack_from(message), strict=True))
    if fields["message_size"] != message_size:
        raise FormatError(source, "messageSize", f"{fields['message_size']} but the header declares "
                          f"16 + payloadSize = {message_size}")
    if fields["data_size"] not in DATA_SIZE_BYTES:
        raise FormatError(source, "dataSize", f"{fields['data_size']} is not a sample size (0, 1, 2 or 3)")
    n_ranges, n_beams = fields["n_ranges"], fields["n_beams"]
    if n_ranges == 0 or n_beams == 0:
        raise FormatError(source, "nRanges/nBeams", f"empty image {n_ranges} x {n_beams}")
    bearings_end = layout.size + 2 * n_beams
    if fields["image_offset"] < bearings_end:
        raise FormatError(source, "imageOffset", f"{fields['image_offset']} overlaps the bearing table "
                          f"(ends at byte {bearings_end})")
    if fields["image_offset"] + fields["image_size"] > message_size:
        raise FormatError(source, "imageSize", f"image of {fields['image_size']} bytes at {fields['image_offset']} "
                          f"runs past the end of the {message_size}-byte message")
    sample_bytes = DATA_SIZE_BYTES[fields["data_size"]]
    row_bytes = n_beams * sample_bytes
    gains_flagged = bool(fields["flags"] & FLAG_ROW_GAINS)
    expected = n_ranges * (row_bytes + ROW_GAIN_BYTES * gains_flagged)
    if fields["image_size"] != expected:
        raise FormatError(source, "imageSize", f"{fields['image_size']} bytes, but {n_ranges} ranges x {n_beams} "
                          f"beams x {sample_bytes} bytes {'with' if gains_flagged else 'without'} per-row gains "
                          f"(flags 0x{fields['flags']:02x}) make {expected}")
    if sample_bytes == 3:
        raise UnsupportedFormatError(source, "dataSize", "24-bit samples are unsupported (8, 16 and 32-bit are)")
    resolution = fields["range_resolution_m"]
    if not (math.isfinite(resolution) and 1e-9 <= resolution <= 1e4):
        raise FormatError(source, "rangeResolution", f"{resolution} m per range bin is not plausible")
    fields.update(layout=layout, sample_bytes=sample_bytes, has_gains=gains_flagged)
    return fields


def decode_ping(message: bytes | bytearray | memoryview, source: str = "<bytes>", stamp_ns: int = 0) -> SonarImage:
    """Decode one complete simple ping result (msgId 0x23, layout v2 when msgVersion == 2, else v1).

    intensity is a read-only zero-copy view of `message` (copied only when per-row gain prefixes are
    stripped; their raw uint32 words go to meta["row_gains"]). ranges_m are range-bin centres,
    (r + 0.5) * rangeResolution. azimuths_rad come from the per-ping bearing table. seq is the ping id.
    stamp_ns is whatever the caller knows (a log item's time; 0 for raw streams, which carry no clock).
    """
    return _decode_vetted_ping(message, _ping_fields(message, source), source, stamp_ns)


def _decode_vetted_ping(message: bytes | bytearray | memoryview, fields: dict[str, Any], source: str,
                        stamp_ns: int) -> SonarImage:
    """decode_ping for a message whose fixed part `_ping_fields` already checked (readers vet before reading)."""
    if len(message) != fields["message_size"]:
        raise FormatError(source, "payloadSize", f"message has {len(message)} bytes but its header declares "
                          f"{fields['message_size']}")
    n_ranges, n_beams, sample_bytes = fields["n_ranges"], fields["n_beams"], fields["sample_bytes"]
    bearings_start = fields["layout"].size
    axes = _axes(bytes(message[bearings_start:bearings_start + 2 * n_beams]), n_ranges, fields["range_resolution_m"])
    if axes is None:
        raise FormatError(source, "bearings", "bearing table is not strictly increasing within ±180°")
    sample_dtype = np.dtype(f"<u{sample_bytes}")
    meta: dict[str, Any] = {"source": "oculus", "sample_bits": 8 * sample_bytes}
    if fields["has_gains"]:
        rows = np.frombuffer(message, dtype=np.uint8, count=fields["image_size"], offset=fields["image_offset"])
        rows = rows.reshape(n_ranges, ROW_GAIN_BYTES + n_beams * sample_bytes)
        meta["row_gains"] = np.ascontiguousarray(rows[:, :ROW_GAIN_BYTES]).view("<u4").ravel().tolist()
        intensity = np.ascontiguousarray(rows[:, ROW_GAIN_BYTES:]).view(sample_dtype)
    else:
        intensity = np.frombuffer(message, dtype=sample_dtype, count=n_ranges * n_beams,
                                  offset=fields["image_offset"]).reshape(n_ranges, n_beams)
    intensity.flags.writeable = False
    for name in _META_FIELDS:
        if name in fields:
            value = fields[name]
            meta[name] = value if not isinstance(value, float) or math.isfinite(value) else None
    try:
        return SonarImage(intensity=intensity, ranges_m=axes[0], azimuths_rad=axes[1], stamp_ns=stamp_ns,
                          seq=fields["ping_id"], frame_id="oculus", meta=meta)
    except FrameError as error:
        raise FormatError(source, "ping", str(error)) from error


@functools.lru_cache(maxsize=16)
def _axes(bearing_table: bytes, n_ranges: int, resolution: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(ranges_m, azimuths_rad) of a ping, or None when its bearing table is corrupt.

    Consecutive pings share their geometry, so it is computed once and shared read-only between frames."""
    bearings = np.frombuffer(bearing_table, dtype="<i2")
    if np.abs(bearings.astype(np.int32)).max() > MAX_BEARING_CENTIDEG or (np.diff(bearings) <= 0).any():
        return None
    ranges = (np.arange(n_ranges) + 0.5) * resolution  # range-bin centres
    azimuths = np.radians(bearings / 100.0)
    ranges.flags.writeable = False
    azimuths.flags.writeable = False
    return ranges, azimuths


def encode_message(msg_id: int, payload: bytes, version: int = 0, device_id: int = 0) -> bytes:
    """One network message: the 16-byte header followed by `payload`."""
    return MSG_HEADER.pack(OCULUS_ID, device_id, 0, msg_id, version, len(payload), 0) + payload


def encode_ping(frame: SonarImage, version: int = 1, with_gains: bool = False,
                row_gains: Sequence[int] | None = None, image_offset: int | None = None) -> bytes:
    """A valid simple ping result message holding `frame` (uint8/16/32 intensity [ranges, beams]).

    version: 2 writes the v2 layout (msgVersion 2), 1 the v1 layout (msgVersion 1; real v1 sonars send 0,
    which reads the same). Ping fields come from frame.meta where present (the keys decode_ping writes),
    else from plausible defaults. Range resolution is taken from the range-bin centres, bearings are
    rounded to 1/100 degree. with_gains prefixes each row with a uint32 gain word: `row_gains`, else
    meta["row_gains"], else 0. image_offset places the image later (real sonars use 2048, leaving filler).
    """
    if version not in (1, 2):
        raise FrameError(f"version: {version}, expected 1 or 2")
    intensity = frame.intensity
    data_size = {1: 0, 2: 1, 4: 3}.get(intensity.dtype.itemsize) if intensity.dtype.kind == "u" else None
    if intensity.ndim != 2 or data_size is None:
        raise FrameError(f"intensity: an Oculus ping holds [ranges, beams] of uint8/16/32, got "
                         f"{intensity.dtype} {intensity.shape}")
    n_ranges, n_beams = intensity.shape
    if n_ranges > 0xFFFF or n_beams > 0xFFFF:
        raise FrameError(f"intensity: {n_ranges} x {n_beams} exceeds the 16-bit nRanges/nBeams fields")
    bearings = np.round(np.degrees(frame.azimuths_rad) * 100.0)
    if np.abs(bearings).max() > MAX_BEARING_CENTIDEG or (np.diff(bearings) <= 0).any():
        raise FrameError("azimuths_rad: not strictly increasing once rounded to 1/100 degree")
    meta = frame.meta
    gains: list[int] = []
    if with_gains:
        gains = list(row_gains if row_gains is not None else meta.get("row_gains", [0] * n_ranges))
        if len(gains) != n_ranges:
            raise FrameError(f"row_gains: {len(gains)} values for {n_ranges} range rows")

    layout = PING_V2 if version == 2 else PING_V1
    bearings_end = layout.size + 2 * n_beams
    image_offset = bearings_end if image_offset is None else image_offset
    if image_offset < bearings_end:
        raise FrameError(f"image_offset: {image_offset} would overlap the bearing table (ends at {bearings_end})")
    sample_rows = np.ascontiguousarray(intensity, dtype=intensity.dtype.newbyteorder("<")).view(np.uint8)
    if with_gains:
        gain_words = np.asarray(gains, dtype="<u4").view(np.uint8).reshape(n_ranges, ROW_GAIN_BYTES)
        sample_rows = np.concatenate([gain_words, sample_rows.reshape(n_ranges, -1)], axis=1)
    image = sample_rows.tobytes()
    message_size = image_offset + len(image)

    resolution = float(frame.ranges_m[0] + frame.ranges_m[-1]) / n_ranges  # centres are (r + 0.5) * resolution

    def number(name: str, default: float) -> float:
        value = meta.get(name)
        return default if value is None else float(value)

    flags = int(meta.get("flags", FLAG_RANGE_IN_METRES | FLAG_SIMPLE_RETURN | FLAG_GAIN_ASSIST))
    flags &= ~(FLAG_16_BIT | FLAG_ROW_GAINS | FLAG_512_BEAMS)
    flags |= FLAG_16_BIT * (data_size == 1) | FLAG_ROW_GAINS * with_gains | FLAG_512_BEAMS * (n_beams == 512)
    fire = (int(meta.get("master_mode", 2)), int(meta.get("ping_rate", 0)), 0xFF,
            int(meta.get("gamma_correction", 255)), flags, number("range_demand", resolution * n_ranges),
            number("gain_percent", 50.0), number("sound_speed_demand_mps", 0.0), number("salinity_ppt", 0.0))
    header = (OCULUS_ID, int(meta.get("device_id", 0)), 0, MSG_SIMPLE_PING, version,
              message_size - MSG_HEADER.size, 0)
    sizes = (data_size, resolution, n_ranges, n_beams)
    common = (frame.seq, int(meta.get("status", 0)), number("frequency_hz", 1.2e6), number("temperature_c", 15.0),
              number("pressure_bar", 1.0))
    if version == 2:
        fixed = layout.pack(*header, *fire, int(meta.get("ext_flags", 0)), *common, number("heading_deg", 0.0),
                            number("pitch_deg", 0.0), number("roll_deg", 0.0), number("sound_speed_mps", 1500.0),
                            number("ping_start_time", 0.0), *sizes, image_offset, len(image), message_size)
    else:
        fixed = layout.pack(*header, *fire, *common, number("sound_speed_mps", 1500.0),
                            int(number("ping_start_time", 0)) & 0xFFFFFFFF, *sizes, image_offset, len(image),
                            message_size)
    filler = bytes(image_offset - bearings_end)
    return fixed + bearings.astype("<i2").tobytes() + filler + image


def write_oculus_log(frames: Iterable[SonarImage], path: str | os.PathLike[str], version: int = 1,
                     compress: bool = False) -> int:
    """Write frames as a ViewPoint `.oculus` V1 log: one type-10 item per ping, item time = stamp_ns / 1e9.

    version is the ping message layout (1 or 2, see encode_ping). compress=True stores each message the
    way Qt's qCompress does (big-endian uint32 length, then a zlib stream). The file header's time is the
    first frame's stamp, so the same frames always give the same bytes. Returns the number of pings written.
    """
    path = Path(path)
    count = 0
    with open(path, "wb") as out:
        out.write(bytes(LOG_HEADER.size))  # patched with the first frame's time below
        first_time = 0.0
        for frame in frames:
            message = encode_ping(frame, version=version)
            payload = struct.pack(">I", len(message)) + zlib.compress(message, 1) if compress else message
            item_time = frame.stamp_ns / 1e9
            first_time = item_time if count == 0 else first_time
            out.write(LOG_ITEM.pack(ITEM_MAGIC, LOG_ITEM.size, ITEM_TYPE_OCULUS_SONAR, 0, item_time, int(compress),
                                    len(message), len(payload)))
            out.write(payload)
            count += 1
        out.seek(0)
        out.write(LOG_HEADER.pack(LOG_MAGIC, LOG_HEADER.size, b"Oculus", 1, 0, 0, first_time))
    return count


class _PositionalFile:
    """Positional reads on an open file, so readers can look ahead and resynchronise without state."""

    def __init__(self, handle: BinaryIO, name: str) -> None:
        self.handle = handle
        self.name = name
        self.size = os.fstat(handle.fileno()).st_size

    def read(self, offset: int, length: int) -> bytes:
        self.handle.seek(offset)
        return self.handle.read(length)

    def read_buffer(self, offset: int, length: int) -> memoryview:
        """`length` bytes into a fresh writable buffer (callers check length <= size first)."""
        buffer = np.empty(length, dtype=np.uint8)
        self.handle.seek(offset)
        got = self.handle.readinto(buffer)
        if got != length:
            raise FormatError(self.name, "file", f"expected {length} bytes at byte {offset}, got {got} "
                              f"(file changed while reading?)", offset)
        return memoryview(buffer)

    def find(self, pattern: bytes, start: int, stop: int | None = None) -> int:
        """Offset of the next `pattern` starting in [start, stop) (default: to the end of file), else stop."""
        stop = self.size if stop is None else min(stop, self.size)
        position = start
        while position < stop:
            span = min(_FIND_CHUNK, stop - position)
            hit = self.read(position, span + len(pattern) - 1).find(pattern)
            if 0 <= hit < span:
                return position + hit
            position += span
        return stop


class _UnsupportedTally:
    """Unsupported pings are skipped and counted; a file where nothing else decoded raises the first one."""

    def __init__(self) -> None:
        self.first: UnsupportedFormatError | None = None

    def skip(self, error: UnsupportedFormatError, report: ReadReport) -> None:
        self.first = self.first or error
        report.skip(f"unsupported {error.field}")

    def raise_if_nothing_read(self, report: ReadReport, frames_before: int) -> None:
        if self.first is not None and report.frames == frames_before:
            raise self.first


def read_oculus(path: str | os.PathLike[str], report: ReadReport | None = None) -> Iterator[SonarImage]:
    """Stream the pings of a V1 `.oculus` log or a raw message stream, one message in memory at a time.

    A raw capture may begin mid-message (garbage before the first ping header, within the first MiB).
    Otherwise a wrong file magic or log header raises FormatError. Inside the file, corrupt records, unknown
    message ids and item types are skipped and counted in `report`; reading resumes at the next magic.
    """
    report = report if report is not None else ReadReport()
    report.source = report.source or str(path)
    with open(path, "rb", buffering=0) as handle:  # positional reads: a read buffer would only add copies
        source = _PositionalFile(handle, str(path))
        head = source.read(0, 64)
        kind = sniff(head)
        if head.startswith(SQLITE_MAGIC):
            raise UnsupportedFormatError(source.name, "file magic", "V2 (SQLite) .oculus logs are unsupported; "
                                         "export the recording as a V1 log")
        if kind == "oculus_log":
            yield from _read_log(source, report)
        elif kind == "oculus_raw" or _starts_mid_capture(source):
            yield from _read_raw(source, report)
        else:
            raise FormatError(source.name, "file magic", f"starts with {head[:4].hex(' ')}: neither a V1 .oculus log "
                              f"(44 33 22 11) nor a raw Oculus message stream (53 4f)")


def starts_mid_capture(path: str | os.PathLike[str]) -> bool:
    """Whether the file is a raw capture that began mid-message (a capture started while the sonar was
    streaming): a valid ping header follows within the first MiB. Bounded: reads at most ~1 MiB."""
    with open(path, "rb", buffering=0) as handle:
        return _starts_mid_capture(_PositionalFile(handle, str(path)))


def _starts_mid_capture(source: _PositionalFile) -> bool:
    """A raw capture that began mid-message: a valid ping header follows within the first MiB of garbage."""
    candidate = _message_start(source, 1, _FIND_CHUNK)
    while candidate < min(_FIND_CHUNK, source.size):  # _message_start returns the clamped stop when none
        try:
            _ping_fields(source.read(candidate, PING_V2.size), source.name)
            return True
        except FormatError:
            candidate = _message_start(source, candidate + 1, _FIND_CHUNK)
    return False


def _message_reason(msg_id: int) -> str:
    return f"msg_id 0x{msg_id:02x} ({KNOWN_MESSAGE_IDS.get(msg_id, 'unknown')})"


def _skip_garbage(source: _PositionalFile, report: ReadReport, position: int, magic: bytes) -> int:
    """Skip to the next `magic` after `position`, counting the bytes passed over; returns the new position."""
    resume = source.find(magic, position + 1)
    report.skip("garbage bytes", resume - position)
    return resume


def _read_raw(source: _PositionalFile, report: ReadReport) -> Iterator[SonarImage]:
    """Raw TCP capture: messages back to back, no clock (stamp_ns = 0). Resynchronise on b"SO"."""
    unsupported = _UnsupportedTally()
    frames_before = report.frames
    position = 0
    while position < source.size:
        head = source.read(position, PING_V2.size)
        if len(head) < MSG_HEADER.size:
            report.problem(f"{source.name} at byte {position}: {len(head)} trailing bytes, a truncated message header")
            break
        oculus_id, _src, _dst, msg_id, _version, payload_size, _spare = MSG_HEADER.unpack_from(head)
        end = position + MSG_HEADER.size + payload_size
        known = msg_id in KNOWN_MESSAGE_IDS  # an unknown id after b"SO" is usually garbage, not a message
        if oculus_id != OCULUS_ID:
            position = _skip_garbage(source, report, position, OCULUS_ID_BYTES)
            continue
        if end > source.size:
            if known:
                report.problem(f"{source.name} at byte {position}: payloadSize {payload_size} runs past the end of "
                               f"the file ({source.size} bytes): truncated or corrupt message")
            position = _skip_garbage(source, report, position, OCULUS_ID_BYTES)
            continue
        # Sizes are confirmed when the next message (or the end of file) follows them. If not, and another
        # message starts inside this one, this one is cut short: resume there so that message is not lost.
        chained = end == source.size or source.read(end, 2) == OCULUS_ID_BYTES
        inner = source.size if chained else _message_start(source, position + 1, end)
        if inner < end:
            if known:
                report.problem(f"{source.name} at byte {position}: message 0x{msg_id:02x} of {end - position} bytes "
                               f"overlaps the message at byte {inner}: truncated or corrupt")
            report.skip("garbage bytes", inner - position)
            position = inner
            continue
        if msg_id != MSG_SIMPLE_PING:
            if chained:
                report.skip(_message_reason(msg_id))
                position = end
            else:
                position = _skip_garbage(source, report, position, OCULUS_ID_BYTES)
            continue
        name = f"{source.name} (message at byte {position})"
        try:
            fields = _ping_fields(head, name)
        except UnsupportedFormatError as error:
            unsupported.skip(error, report)
            position = end
            continue
        except FormatError as error:
            report.problem(str(error))
            position = _skip_garbage(source, report, position, OCULUS_ID_BYTES)
            continue
        try:
            frame = _decode_vetted_ping(source.read_buffer(position, end - position), fields, name, 0)
        except FormatError as error:
            report.problem(str(error))
        else:
            report.frames += 1
            yield frame
        position = end
    unsupported.raise_if_nothing_read(report, frames_before)


def _message_start(source: _PositionalFile, start: int, stop: int) -> int:
    """First offset in [start, stop) where a plausible message header starts, else stop (at most the file size)."""
    stop = min(stop, source.size)
    candidate = source.find(OCULUS_ID_BYTES, start, stop)
    while candidate < stop:
        if sniff(source.read(candidate, MSG_HEADER.size)) == "oculus_raw":
            return candidate
        candidate = source.find(OCULUS_ID_BYTES, candidate + 1, stop)
    return stop


def _read_log_header(source: _PositionalFile) -> int:
    """Validate the V1 file header; returns where the first item starts."""
    head = source.read(0, LOG_HEADER.size)
    if len(head) < LOG_HEADER.size:
        raise FormatError(source.name, "file header", f"{len(head)} bytes, a V1 log header needs {LOG_HEADER.size}")
    _magic, header_size, _name, _version, encryption, _key, _time = LOG_HEADER.unpack(head)
    if not LOG_HEADER.size <= header_size <= source.size:
        raise FormatError(source.name, "sizeHeader", f"{header_size}, expected >= {LOG_HEADER.size} and within "
                          f"the {source.size}-byte file")
    if encryption != 0:
        raise UnsupportedFormatError(source.name, "encryption", f"{encryption}: encrypted logs are unsupported")
    return header_size


def _stamp_ns(item_time: float) -> int | None:
    """Item time (Unix seconds, f64) to ns, kept to the microsecond the f64 can hold; None when implausible."""
    if not (math.isfinite(item_time) and 0.0 <= item_time < 2**63 / 1e9):
        return None
    return round(item_time * 1e6) * 1000


def _item_message(payload: memoryview, compression: int, original_size: int, name: str) -> memoryview:
    """The network message inside a type-10 item payload, inflating Qt qCompress framing when present."""
    # Tolerance from the spec: a payload that is not a message but carries a zlib header after a 4-byte
    # length is compressed whatever the flag says.
    looks_compressed = len(payload) >= 6 and bytes(payload[:2]) != OCULUS_ID_BYTES and payload[4] == 0x78
    if compression == 0 and not looks_compressed:
        return payload
    if compression not in (0, 1):
        raise UnsupportedFormatError(name, "compression", f"{compression} (only 0 = none and 1 = qCompress exist)")
    if len(payload) < 4:
        raise FormatError(name, "payload", "compressed payload shorter than its 4-byte length prefix")
    declared = int.from_bytes(payload[:4], "big")
    if declared != original_size or declared > MAX_MESSAGE_BYTES:
        raise FormatError(name, "originalSize", f"qCompress length prefix {declared}, item originalSize "
                          f"{original_size}")
    inflater = zlib.decompressobj()
    try:
        message = inflater.decompress(payload[4:], declared)
    except zlib.error as error:
        raise FormatError(name, "payload", f"zlib: {error}") from error
    if len(message) != declared or not inflater.eof:
        raise FormatError(name, "payload", f"compressed payload inflates to {len(message)}"
                          f"{'' if inflater.eof else '+'} bytes, expected {declared}")
    return memoryview(message)


def _read_log(source: _PositionalFile, report: ReadReport) -> Iterator[SonarImage]:
    """V1 log: header, then 40-byte items; type 10 holds one network message, stamped with the item time."""
    unsupported = _UnsupportedTally()
    frames_before = report.frames
    position = _read_log_header(source)
    while position < source.size:
        head = source.read(position, LOG_ITEM.size)
        if len(head) < LOG_ITEM.size:
            report.problem(f"{source.name} at byte {position}: {len(head)} trailing bytes, a truncated item header")
            break
        magic, header_size, item_type, _version, item_time, compression, original_size, payload_size = (
            LOG_ITEM.unpack(head))
        if magic != ITEM_MAGIC:
            position = _skip_garbage(source, report, position, ITEM_MAGIC_BYTES)
            continue
        end = position + header_size + payload_size
        if header_size < LOG_ITEM.size or end > source.size:
            report.problem(f"{source.name} at byte {position}: item sizeHeader {header_size} / payloadSize "
                           f"{payload_size} run past the end of the {source.size}-byte file")
            position = _skip_garbage(source, report, position, ITEM_MAGIC_BYTES)
            continue
        # Sizes of an item are confirmed when the next item (or the end of the file) follows them; a type-10
        # item is also confirmed by the message inside it.
        chained = end == source.size or source.read(end, 4) == ITEM_MAGIC_BYTES
        inner = source.size if chained else source.find(ITEM_MAGIC_BYTES, position + 1, end)
        if inner < end:  # the next item starts inside this one: this one is cut short, resume there
            report.problem(f"{source.name} at byte {position}: item of {end - position} bytes overlaps the item at "
                           f"byte {inner}: truncated or corrupt")
            report.skip("garbage bytes", inner - position)
            position = inner
            continue
        if item_type != ITEM_TYPE_OCULUS_SONAR:
            if chained:
                report.skip(f"item type {item_type}")
                position = end
            else:
                report.problem(f"{source.name} at byte {position}: item of type {item_type} with payloadSize "
                               f"{payload_size} is not followed by another item")
                position = _skip_garbage(source, report, position, ITEM_MAGIC_BYTES)
            continue
        name = f"{source.name} (item at byte {position})"
        stamp = _stamp_ns(item_time)
        try:
            frame, msg_id = _decode_item(source, position + header_size, payload_size, compression, original_size,
                                         name, stamp or 0, chained)
        except UnsupportedFormatError as error:
            unsupported.skip(error, report)
        except FormatError as error:
            report.problem(str(error))
            if not chained:
                position = _skip_garbage(source, report, position, ITEM_MAGIC_BYTES)
                continue
        else:
            if frame is None:
                report.skip(_message_reason(msg_id))
            else:
                if stamp is None:
                    report.skip("item time invalid (stamp_ns left 0)")
                report.frames += 1
                yield frame
        position = end
    unsupported.raise_if_nothing_read(report, frames_before)


def _decode_item(source: _PositionalFile, offset: int, payload_size: int, compression: int, original_size: int,
                 name: str, stamp_ns: int, chained: bool) -> tuple[SonarImage | None, int]:
    """(ping, msgId) of one type-10 item; the ping is None when the item holds another message.

    `chained`: the next item follows this one, which confirms its payloadSize. Otherwise the message
    header inside must confirm it before the payload is read."""
    if payload_size > MAX_MESSAGE_BYTES:
        raise FormatError(name, "payloadSize", f"{payload_size} bytes is more than any Oculus message")
    head = b"" if chained else source.read(offset, MSG_HEADER.size)
    if compression == 0 and len(head) == MSG_HEADER.size and head[:2] == OCULUS_ID_BYTES:
        declared = MSG_HEADER.size + MSG_HEADER.unpack(head)[5]
        if declared != payload_size:
            raise FormatError(name, "payloadSize", f"item payload of {payload_size} bytes holds a message of "
                              f"{declared}")
    message = _item_message(source.read_buffer(offset, payload_size), compression, original_size, name)
    if len(message) < MSG_HEADER.size or bytes(message[:2]) != OCULUS_ID_BYTES:
        raise FormatError(name, "oculusId", "item payload does not start with an Oculus message header")
    msg_id = struct.unpack_from("<H", message, 6)[0]
    return (decode_ping(message, name, stamp_ns) if msg_id == MSG_SIMPLE_PING else None), msg_id
