"""ROS bags without ROS: ROS 1 `.bag`, ROS 2 bag folders (sqlite3 or MCAP storage) and bare `.mcap` files.

Reading picks the sonar topic by type (marine_acoustic_msgs/ProjectedSonarImage first, else sensor_msgs/Image;
`topic` chooses) and maps each message to a SonarImage (`sonar_realism.io.ros_messages`, docs/formats.md).
MCAP files and ROS 1 bags are walked record by record in file order, so a file cut short (a logger that
died) reads every frame before the damage and reports where it ends; rosbags' own readers refuse a file
without its index. sqlite3 storage goes through rosbags' Reader. Messages are decoded with rosbags' type
system from the definitions the bag carries.

Writing (`write_frames(frames, "x.mcap")`) uses rosbags' ROS 2 Writer with MCAP storage and keeps the one
.mcap file it makes (its "rosbag2" metadata record is what `ros2 bag play x.mcap` reads): per frame a
ProjectedSonarImage on /sonar/image, a std_msgs/String JSON on /sonar/image/frame_info with what the message
cannot hold (seq, intensity_scale, meta, float64 geometry), and a mono8 fan on /sonar/fan for viewers.
"""

from __future__ import annotations

import bz2
import itertools
import os
import shutil
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from sonar_realism.errors import FormatError, FrameError
from sonar_realism.frames import SonarImage
from sonar_realism.io import ros_messages as msgs
from sonar_realism.io.common import ImageSidecar, load_sidecar
from sonar_realism.io.folder import image_to_frame, natural_key
from sonar_realism.io.report import ReadReport

ROS1_MAGIC = b"#ROSBAG V2.0\n"
MCAP_MAGIC = b"\x89MCAP0\r\n"
ROS2_METADATA = "metadata.yaml"
SONAR_TOPIC = "/sonar/image"
FAN_TOPIC = "/sonar/fan"
INFO_SUFFIX = "/frame_info"
FAN_WIDTH_PX = 512
KINDS = ("ros1_bag", "ros2_bag", "mcap")


@dataclass(frozen=True)
class Topic:
    name: str
    msgtype: str
    definition: str  # ros1msg/ros2msg text with dependencies, "" when the container has none


@dataclass(frozen=True)
class RawMessage:
    topic: str
    log_time: int
    data: bytes


def sniff(path: Path, head: bytes) -> str | None:
    """"ros2_bag" (a folder with metadata.yaml), "ros1_bag", "mcap", or None."""
    if path.is_dir():
        return "ros2_bag" if (path / ROS2_METADATA).is_file() else None
    if head.startswith(ROS1_MAGIC):
        return "ros1_bag"
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    return None


def read_bag(path: str | Path, kind: str, report: ReadReport, topic: str | None = None,
             geometry: dict[str, Any] | None = None) -> Iterator[SonarImage]:
    """Frames of the sonar topic of the bag at `path` (`kind` from sniff). `geometry` (sidecar keys) gives
    sensor_msgs/Image frames their geometry, over a sidecar JSON beside the bag."""
    path = Path(path)
    source = str(path)
    container = _container(path, kind)
    topics = container.topics()
    chosen = choose_topic(topics, topic, source)
    info_topic = next((t for t in topics if t.name == chosen.name + INFO_SUFFIX and t.msgtype == msgs.STRING), None)
    wanted = [chosen] + ([info_topic] if info_topic else [])
    store = msgs.typestore_for({t.msgtype: t.definition for t in wanted}, ros1=kind == "ros1_bag")
    if chosen.msgtype not in store.types:
        raise FormatError(source, chosen.name, f"message type {chosen.msgtype} is unknown (no definition in the bag)")
    decode = store.deserialize_ros1 if kind == "ros1_bag" else store.deserialize_cdr
    sidecar = load_sidecar(path, overrides=geometry) if chosen.msgtype == msgs.IMAGE else None
    where = f"{source} {chosen.name}"
    assembler = _Assembler(where, report)
    count = 0
    messages = container.messages({t.name for t in wanted}, report)
    for _, group in itertools.groupby(messages, key=lambda message: message.log_time):
        infos, images = [], []
        for message in group:
            (infos if message.topic != chosen.name else images).append(message)
        if infos and len(infos) != len(images):
            report.problem(f"{where}: {len(infos)} frame_info record(s) for {len(images)} message(s) at "
                           f"log time {images[0].log_time if images else infos[0].log_time}; infos ignored")
            infos = []
        for position, message in enumerate(images):
            try:
                decoded = decode(message.data, chosen.msgtype)
                if chosen.msgtype == msgs.IMAGE:
                    frame = _image_frame(decoded, path, sidecar, count)
                else:
                    frame = msgs.sonar_image_to_frame(decoded, where, count)
                info = msgs.FrameInfo.from_json(decode(infos[position].data, msgs.STRING).data, where) \
                    if infos else None
            except FormatError as exc:  # a message we cannot map (an RGB image, a short data array): counted
                report.skip(f"{chosen.msgtype} {str(exc).removeprefix(exc.source + ': ')}")
                count += 1
                continue
            except Exception as exc:  # a corrupt payload: rosbags raises whatever its decoder meets
                report.problem(f"{where} message {count}: cannot decode ({type(exc).__name__}: {exc})")
                count += 1
                continue
            count += 1
            frame = assembler.add(frame, info)
            if frame is not None:
                report.frames += 1
                yield frame


class _Assembler:
    """Applies our frame_info records: exact geometry, seq, scale, meta; stacks multi-sample frames."""

    def __init__(self, where: str, report: ReadReport) -> None:
        self.where, self.report = where, report
        self.geometry: tuple[np.ndarray, np.ndarray] | None = None
        self.planes: list[SonarImage] = []

    def add(self, frame: SonarImage, info: msgs.FrameInfo | None) -> SonarImage | None:
        if info is None:
            return frame
        if info.ranges_m is not None and info.azimuths_rad is not None:
            self.geometry = (np.asarray(info.ranges_m, np.float64), np.asarray(info.azimuths_rad, np.float64))
        geometry = self.geometry or (frame.ranges_m, frame.azimuths_rad)
        frame = frame.replace(seq=info.seq, intensity_scale=info.intensity_scale, meta=info.meta,
                              ranges_m=geometry[0], azimuths_rad=geometry[1])
        if info.samples == 1:
            return frame
        if info.sample != len(self.planes):
            self.report.problem(f"{self.where}: sample {info.sample} of seq {info.seq} out of order; "
                                f"{len(self.planes)} earlier sample(s) dropped")
            self.planes = []
            if info.sample != 0:
                return None
        self.planes.append(frame)
        if len(self.planes) < info.samples:
            return None
        stacked = frame.replace(intensity=np.stack([plane.intensity for plane in self.planes]))
        self.planes = []
        return stacked


def choose_topic(topics: list[Topic], topic: str | None, source: str) -> Topic:
    listing = ", ".join(f"{t.name} ({t.msgtype})" for t in topics) or "none"
    if topic is not None:
        match = next((t for t in topics if t.name == topic), None)
        if match is None:
            raise FormatError(source, "topic", f"no topic {topic!r}; the bag has: {listing}")
        if match.msgtype not in msgs.SONAR_TYPES:
            raise FormatError(source, "topic", f"{topic} is {match.msgtype}, not a sonar message type "
                                               f"({', '.join(msgs.SONAR_TYPES)})")
        return match
    for kind in (msgs.SONAR_TYPES[:2], msgs.SONAR_TYPES[2:]):
        candidates = [t for t in topics if t.msgtype in kind]
        if len(candidates) == 1:
            return candidates[0]
        if candidates:
            raise FormatError(source, "topic", f"several sonar topics ({', '.join(t.name for t in candidates)}); "
                                               "choose one (topic=..., --topic)")
    raise FormatError(source, "topic", f"no sonar topic (ProjectedSonarImage or sensor_msgs/Image); "
                                       f"the bag has: {listing}")


def _image_frame(message: Any, path: Path, sidecar: tuple[ImageSidecar | None, str] | None,
                 position: int) -> SonarImage:
    source = f"{path} {message.header.frame_id}"
    pixels = msgs.image_pixels(message, source)
    loaded, sidecar_source = sidecar if sidecar is not None else (None, "")
    seq = int(getattr(message.header, "seq", position))
    frame = image_to_frame(pixels, path, loaded, sidecar_source, seq, {"source": path.name})
    return frame.replace(stamp_ns=msgs.stamp_ns(message.header), frame_id=message.header.frame_id)


# ------------------------------------------------------------------------------------------------- containers


def _container(path: Path, kind: str) -> _Mcap | _Ros1 | _Sqlite:
    if kind == "mcap":
        return _Mcap([path])
    if kind == "ros1_bag":
        return _Ros1(path)
    mcaps = sorted(path.glob("*.mcap"), key=natural_key)
    if mcaps:
        return _Mcap(mcaps)
    if any(path.glob("*.db3")):
        return _Sqlite(path)
    raise FormatError(str(path), "storage", "a ROS 2 bag folder without .mcap or .db3 files "
                                            "(compressed bags: decompress with `ros2 bag convert` first)")


class _Truncated(Exception):
    """The file ends inside a record."""


def _read(stream: BinaryIO, size: int) -> bytes:
    data = stream.read(size)
    if len(data) != size:
        raise _Truncated
    return data


def _string(buffer: memoryview, at: int) -> tuple[str, int]:
    (length,) = struct.unpack_from("<I", buffer, at)
    end = at + 4 + length
    if end > len(buffer):
        raise _Truncated
    return bytes(buffer[at + 4:end]).decode("utf-8"), end


class _Mcap:
    """MCAP files walked record by record (https://mcap.dev/spec), chunks decompressed one at a time."""

    def __init__(self, files: list[Path]) -> None:
        self.files = files

    def topics(self) -> list[Topic]:
        topics: dict[str, Topic] = {}
        for path in self.files:
            records = self._summary(path)
            if records is None:
                records = self._records(path, None)
            for topic in self._channels(records):
                topics.setdefault(topic.name, topic)
        return list(topics.values())

    def messages(self, wanted: set[str], report: ReadReport) -> Iterator[RawMessage]:
        for path in self.files:
            channels: dict[int, str] = {}
            for opcode, body in self._records(path, report):
                if opcode == 0x04:
                    channel_id, topic = self._channel_topic(body)
                    channels[channel_id] = topic
                elif opcode == 0x05:
                    channel_id, _, log_time, _ = struct.unpack_from("<HIQQ", body)
                    topic = channels.get(channel_id)
                    if topic in wanted:
                        yield RawMessage(topic, log_time, bytes(body[22:]))

    @staticmethod
    def _channel_topic(body: memoryview) -> tuple[int, str]:
        channel_id, _ = struct.unpack_from("<HH", body)
        topic, _ = _string(body, 4)
        return channel_id, topic

    @staticmethod
    def _channels(records: Iterable[tuple[int, memoryview]]) -> Iterator[Topic]:
        schemas: dict[int, tuple[str, str]] = {}
        for opcode, body in records:
            if opcode == 0x03:
                (schema_id,) = struct.unpack_from("<H", body)
                name, at = _string(body, 2)
                _, at = _string(body, at)
                definition, _ = _string(body, at)
                schemas[schema_id] = (name, definition)
            elif opcode == 0x04:
                channel_id, schema_id = struct.unpack_from("<HH", body)
                topic, _ = _string(body, 4)
                name, definition = schemas.get(schema_id, ("", ""))
                yield Topic(topic, _normalise_type(name), definition)

    @staticmethod
    def _summary(path: Path) -> list[tuple[int, memoryview]] | None:
        """Schema and channel records of the summary section, or None when the footer is missing."""
        size = path.stat().st_size
        if size < 8 + 37 + 8:
            return None
        with open(path, "rb") as stream:
            stream.seek(size - 37)
            footer = stream.read(37)
            if footer[:9] != b"\x02\x14\x00\x00\x00\x00\x00\x00\x00" or footer[-8:] != MCAP_MAGIC:
                return None
            (summary_start,) = struct.unpack_from("<Q", footer, 9)
            if not 8 < summary_start < size - 37:
                return None
            stream.seek(summary_start)
            summary = memoryview(stream.read(size - 37 - summary_start))
        records, at = [], 0
        while at + 9 <= len(summary):
            opcode, length = struct.unpack_from("<BQ", summary, at)
            if opcode in (0x03, 0x04):
                records.append((opcode, summary[at + 9:at + 9 + length]))
            at += 9 + length
        return records if any(opcode == 0x04 for opcode, _ in records) else None

    @staticmethod
    def _records(path: Path, report: ReadReport | None) -> Iterator[tuple[int, memoryview]]:
        """(opcode, body) of every record in file order, chunk contents in place of chunks."""
        with open(path, "rb") as stream:
            if stream.read(8) != MCAP_MAGIC:
                raise FormatError(str(path), "magic", "not an MCAP file")
            offset = 8
            try:
                while True:
                    opcode, length = struct.unpack("<BQ", _read(stream, 9))
                    body = memoryview(_read(stream, length))
                    if opcode == 0x02:  # footer
                        return
                    if opcode == 0x06:
                        yield from _chunk_records(body, str(path))
                    else:
                        yield opcode, body
                    offset += 9 + length
            except (_Truncated, struct.error):
                if report is not None:
                    report.problem(f"{path}: ends inside a record at byte {offset} (truncated?); the frames "
                                   "before it were read")


def _chunk_records(body: memoryview, source: str) -> Iterator[tuple[int, memoryview]]:
    _, _, uncompressed_size, _ = struct.unpack_from("<QQQI", body)
    compression, at = _string(body, 28)
    (compressed_size,) = struct.unpack_from("<Q", body, at)
    payload = body[at + 8:at + 8 + compressed_size]
    if len(payload) != compressed_size:
        raise _Truncated
    if compression == "zstd":
        try:
            from compression import zstd  # Python 3.14
        except ImportError:
            from backports import zstd  # installed with rosbags
        records = memoryview(zstd.decompress(bytes(payload)))
    elif compression == "lz4":
        import lz4.frame

        records = memoryview(lz4.frame.decompress(bytes(payload)))
    elif compression == "":
        records = payload
    else:
        raise FormatError(source, "chunk.compression", f"{compression!r} is not one MCAP defines")
    if len(records) != uncompressed_size:
        raise FormatError(source, "chunk", f"{len(records)} bytes after decompression, header says {uncompressed_size}")
    at = 0
    while at + 9 <= len(records):
        opcode, length = struct.unpack_from("<BQ", records, at)
        yield opcode, records[at + 9:at + 9 + length]
        at += 9 + length


def _normalise_type(name: str) -> str:
    """ROS 1 names (pkg/Type) as rosbags spells them (pkg/msg/Type)."""
    parts = name.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else name


class _Ros1:
    """ROS 1 bag format 2.0 (http://wiki.ros.org/Bags/Format/2.0), walked record by record."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def topics(self) -> list[Topic]:
        topics: dict[str, Topic] = {}
        for fields, data in self._indexed_connections() or self._records(None):
            if fields.get("op") == b"\x07":
                connection = _ros1_fields(data)
                name = fields["topic"].decode()
                topics.setdefault(name, Topic(name, _normalise_type(connection["type"].decode()),
                                              connection.get("message_definition", b"").decode()))
        return list(topics.values())

    def messages(self, wanted: set[str], report: ReadReport) -> Iterator[RawMessage]:
        connections: dict[int, str] = {}
        for fields, data in self._records(report):
            op = fields.get("op")
            if op == b"\x07":
                connections[struct.unpack("<I", fields["conn"])[0]] = fields["topic"].decode()
            elif op == b"\x02":
                topic = connections.get(struct.unpack("<I", fields["conn"])[0])
                if topic in wanted:
                    seconds, nanoseconds = struct.unpack("<II", fields["time"])
                    yield RawMessage(topic, seconds * 1_000_000_000 + nanoseconds, data)

    def _indexed_connections(self) -> list[tuple[dict[str, bytes], bytes]]:
        """Connection records of the index at the end of a closed bag; [] when the bag was not closed."""
        with open(self.path, "rb") as stream:
            stream.seek(len(ROS1_MAGIC))
            try:
                fields, _ = _ros1_record(stream)
                index_pos = struct.unpack("<Q", fields["index_pos"])[0]
                count = struct.unpack("<I", fields["conn_count"])[0]
                if not index_pos:
                    return []
                stream.seek(index_pos)
                return [_ros1_record(stream) for _ in range(count)]
            except (_Truncated, KeyError, struct.error):
                return []

    def _records(self, report: ReadReport | None) -> Iterator[tuple[dict[str, bytes], bytes]]:
        with open(self.path, "rb") as stream:
            if stream.read(len(ROS1_MAGIC)) != ROS1_MAGIC:
                raise FormatError(str(self.path), "magic", "not a ROS 1 bag (format 2.0)")
            offset = stream.tell()
            try:
                while True:
                    if not stream.read(1):
                        return
                    stream.seek(-1, os.SEEK_CUR)
                    fields, data = _ros1_record(stream)
                    op = fields.get("op")
                    if op == b"\x05":
                        yield from self._chunk(fields, data)
                    elif op in (b"\x02", b"\x07"):
                        yield fields, data
                    offset = stream.tell()
            except (_Truncated, struct.error, KeyError):
                if report is not None:
                    report.problem(f"{self.path}: ends inside a record at byte {offset} (truncated?); the frames "
                                   "before it were read")

    def _chunk(self, fields: dict[str, bytes], data: bytes) -> Iterator[tuple[dict[str, bytes], bytes]]:
        compression = fields["compression"].decode()
        if compression == "bz2":
            data = bz2.decompress(data)
        elif compression == "lz4":
            import lz4.frame

            data = lz4.frame.decompress(data)
        elif compression != "none":
            raise FormatError(str(self.path), "chunk.compression", f"{compression!r} (known: none, bz2, lz4)")
        buffer = memoryview(data)
        at = 0
        while at < len(buffer):
            (header_length,) = struct.unpack_from("<I", buffer, at)
            fields_here = _ros1_fields(bytes(buffer[at + 4:at + 4 + header_length]))
            at += 4 + header_length
            (data_length,) = struct.unpack_from("<I", buffer, at)
            yield fields_here, bytes(buffer[at + 4:at + 4 + data_length])
            at += 4 + data_length


def _ros1_record(stream: BinaryIO) -> tuple[dict[str, bytes], bytes]:
    (header_length,) = struct.unpack("<I", _read(stream, 4))
    fields = _ros1_fields(_read(stream, header_length))
    (data_length,) = struct.unpack("<I", _read(stream, 4))
    return fields, _read(stream, data_length)


def _ros1_fields(header: bytes) -> dict[str, bytes]:
    fields, at = {}, 0
    while at + 4 <= len(header):
        (length,) = struct.unpack_from("<I", header, at)
        name, _, value = header[at + 4:at + 4 + length].partition(b"=")
        fields[name.decode()] = value
        at += 4 + length
    return fields


class _Sqlite:
    """ROS 2 sqlite3 storage, through rosbags' Reader."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def _reader(self) -> Any:
        from rosbags.rosbag2 import Reader

        try:
            reader = Reader(self.path)
            reader.open()
        except Exception as exc:  # rosbags' ReaderError, sqlite3's DatabaseError, a bad metadata.yaml
            raise FormatError(str(self.path), "bag", f"rosbags cannot open it ({exc})") from exc
        return reader

    def topics(self) -> list[Topic]:
        reader = self._reader()
        try:
            return [Topic(c.topic, c.msgtype, c.msgdef.data if c.msgdef else "") for c in reader.connections]
        finally:
            reader.close()

    def messages(self, wanted: set[str], report: ReadReport) -> Iterator[RawMessage]:
        reader = self._reader()
        try:
            connections = [c for c in reader.connections if c.topic in wanted]
            try:
                for connection, log_time, data in reader.messages(connections=connections):
                    yield RawMessage(connection.topic, log_time, bytes(data))
            except Exception as exc:  # a damaged database: keep what was read, say where it stopped
                report.problem(f"{self.path}: reading stopped ({type(exc).__name__}: {exc})")
        finally:
            reader.close()


# ---------------------------------------------------------------------------------------------------- writing


def write_mcap(frames: Iterable[SonarImage], path: str | Path, topic: str = SONAR_TOPIC,
               fan_topic: str = FAN_TOPIC, fan_width_px: int = FAN_WIDTH_PX) -> int:
    """Write `frames` as a ROS 2 MCAP bag file at `path`; returns the count. Streams (one frame in memory)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # rosbags' Writer makes a folder holding <folder name>.mcap; named after the target, the file's embedded
    # metadata lists the right file name.
    staging_root = path.with_name(f".{path.name}.writing")
    shutil.rmtree(staging_root, ignore_errors=True)
    staging = staging_root / path.stem
    store = msgs.typestore_for({}, ros1=False)
    count = 0
    try:
        with Writer(staging, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            image_connection = writer.add_connection(topic, msgs.PROJECTED_SONAR_IMAGE, typestore=store)
            info_connection = writer.add_connection(topic + INFO_SUFFIX, msgs.STRING, typestore=store)
            fan_connection = writer.add_connection(fan_topic, msgs.IMAGE, typestore=store)
            log_time = -1
            geometry: tuple[np.ndarray, np.ndarray] | None = None
            for count, frame in enumerate(frames, start=1):
                if not isinstance(frame, SonarImage):
                    raise FrameError(f"write_frames: frame {count - 1} is a {type(frame).__name__}, not a SonarImage")
                changed = geometry is None or not (np.array_equal(geometry[0], frame.ranges_m)
                                                   and np.array_equal(geometry[1], frame.azimuths_rad))
                geometry = (frame.ranges_m, frame.azimuths_rad)
                samples = frame.n_samples if frame.intensity.ndim == 3 else 1
                for sample in range(samples):
                    # Unique, increasing log times pair each info with its image even when stamps repeat.
                    log_time = max(frame.stamp_ns, log_time + 1)
                    info = msgs.FrameInfo(seq=frame.seq, intensity_scale=frame.intensity_scale, meta=frame.meta,
                                          sample=sample, samples=samples,
                                          ranges_m=frame.ranges_m.tolist() if changed and sample == 0 else None,
                                          azimuths_rad=frame.azimuths_rad.tolist() if changed and sample == 0
                                          else None)
                    try:
                        text = info.to_json()
                    except (TypeError, ValueError) as exc:
                        raise FrameError(f"meta: frame {count - 1} meta is not JSON-able ({exc})") from exc
                    writer.write(info_connection, log_time,
                                 store.serialize_cdr(msgs.string_message(store, text), msgs.STRING))
                    message = msgs.frame_to_sonar_image(store, frame, sample if frame.intensity.ndim == 3 else None)
                    writer.write(image_connection, log_time, store.serialize_cdr(message, msgs.PROJECTED_SONAR_IMAGE))
                fan = msgs.fan_image_message(store, frame, fan_width_px)
                writer.write(fan_connection, log_time, store.serialize_cdr(fan, msgs.IMAGE))
        os.replace(staging / f"{staging.name}.mcap", path)
    finally:
        shutil.rmtree(staging_root, ignore_errors=True)
    return count
