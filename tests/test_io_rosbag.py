"""ROS bags without ROS: bags written by rosbags' own writers (as a user's logger writes them) read back exactly;
our MCAP output reads back exactly and opens as a ROS 2 bag; bad bags give clear errors or counted skips."""

import json
import math
import struct

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import Reader as Ros2Reader
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.rosbag2.storage_mcap import McapReader

from sonar_realism import FormatError, FrameError, SonarImage
from sonar_realism.frames import uniform_azimuths, uniform_ranges
from sonar_realism.io import ReadReport, read_frames, sniff, write_frames
from sonar_realism.io import ros_messages as msgs
from sonar_realism.io.rosbag import MCAP_MAGIC
from sonar_realism.runtime.recording import Recording
from sonar_realism.runtime.sources import ReplaySource

PSI = msgs.PROJECTED_SONAR_IMAGE
N_RANGES, N_BEAMS = 24, 16
BEARINGS = np.arcsin(np.linspace(-0.7, 0.7, N_BEAMS))  # not uniform, like an Oculus bearing table
RANGES32 = (0.2 + 0.05 * np.arange(N_RANGES)).astype(np.float32)
T0 = 1_754_412_000_123_456_789


def header(store, stamp, frame_id="oculus", seq=None):
    time = store.types["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
    fields = {"stamp": time, "frame_id": frame_id}
    if seq is not None:
        fields["seq"] = seq
    return store.types["std_msgs/msg/Header"](**fields)


def samples_of(code, index, big_endian=False):
    """A [ranges, beams] array of the message dtype `code`, using its extremes."""
    dtype = msgs.SAMPLE_DTYPES[code]
    rng = np.random.default_rng(index)
    if dtype.kind == "f":
        values = rng.normal(0, 3, (N_RANGES, N_BEAMS))
    else:
        info = np.iinfo(dtype)
        low, high = max(info.min, -(2**40)), min(info.max, 2**40)
        values = rng.integers(low, high, (N_RANGES, N_BEAMS), endpoint=True)
        values[0, 0], values[0, 1] = max(info.min, -(2**53)), min(info.max, 2**53) if dtype.itemsize > 4 else info.max
    return values.astype(dtype.newbyteorder(">" if big_endian else "<"))


def psi_message(store, index, code=0, ros1=False, big_endian=False):
    """A ProjectedSonarImage as the APL Oculus driver fills it: range-major data, directions (0, -sin θ, cos θ)."""
    types = store.types
    data = samples_of(code, index, big_endian)
    directions = [types["geometry_msgs/msg/Vector3"](x=0.0, y=-math.sin(a), z=math.cos(a)) for a in BEARINGS]
    ping = types["marine_acoustic_msgs/msg/PingInfo"](frequency=1.2e6, sound_speed=1500.0,
                                                     tx_beamwidths=np.full(N_BEAMS, 0.35, np.float32),
                                                     rx_beamwidths=np.full(N_BEAMS, 0.01, np.float32))
    image = types["marine_acoustic_msgs/msg/SonarImageData"](is_bigendian=big_endian, dtype=code, beam_count=N_BEAMS,
                                                            data=data.view(np.uint8).reshape(-1))
    return types[PSI](header=header(store, T0 + index * 100_000_000, seq=7 + index if ros1 else None),
                      ping_info=ping, beam_directions=directions, ranges=RANGES32, image=image), data


def write_user_bag(path, kind, messages_by_topic, ros1_store=None, ros1_chunk_bytes=None):
    """Write {topic: (msgtype, [message, ...])} with rosbags' writers; stamps from each message's header."""
    if kind == "ros1":
        store = ros1_store or msgs.typestore_for({}, ros1=True)
        with Ros1Writer(path) as writer:
            if ros1_chunk_bytes:
                writer.chunk_threshold = ros1_chunk_bytes  # rosbag record's chunks are 768 KiB; these frames are tiny
            for topic, (msgtype, messages) in messages_by_topic.items():
                connection = writer.add_connection(topic, msgtype, typestore=store)
                for i, message in enumerate(messages):
                    writer.write(connection, T0 + i, store.serialize_ros1(message, msgtype))
        return
    store = msgs.typestore_for({}, ros1=False)
    plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
    with Ros2Writer(path, version=9, storage_plugin=plugin) as writer:
        for topic, (msgtype, messages) in messages_by_topic.items():
            connection = writer.add_connection(topic, msgtype, typestore=store)
            for i, message in enumerate(messages):
                writer.write(connection, T0 + i, store.serialize_cdr(message, msgtype))


def expected_frame(data, index, seq):
    samples = data.astype(data.dtype.newbyteorder("="))
    return samples, T0 + index * 100_000_000, seq


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_bag_written_by_rosbags_reads_back_exactly(tmp_path, kind):
    ros1 = kind == "ros1"
    store = msgs.typestore_for({}, ros1=ros1)
    pairs = [psi_message(store, i, code=code, ros1=ros1) for i, code in enumerate([0, 2, 4, 8])]
    chatter = [store.types["std_msgs/msg/String"](data="hello")]
    path = tmp_path / ("user.bag" if ros1 else "user_bag")
    write_user_bag(path, kind, {"/oculus/sonar_image": (PSI, [m for m, _ in pairs]),
                                "/chatter": ("std_msgs/msg/String", chatter)}, store if ros1 else None)
    assert sniff(path) == ("ros1_bag" if ros1 else "ros2_bag")
    report = ReadReport()
    frames = list(read_frames(path, report))
    assert report.frames == 4 and not report.skipped and not report.problems
    for index, (frame, (_, data)) in enumerate(zip(frames, pairs, strict=True)):
        assert frame.intensity.dtype == data.dtype.newbyteorder("=")
        assert np.array_equal(frame.intensity, data)
        assert np.array_equal(frame.ranges_m, RANGES32.astype(np.float64))
        assert np.array_equal(frame.azimuths_rad, np.arctan2(np.sin(BEARINGS), np.cos(BEARINGS)))
        np.testing.assert_allclose(frame.azimuths_rad, BEARINGS, atol=1e-15)
        assert frame.stamp_ns == T0 + index * 100_000_000
        assert frame.seq == (7 + index if ros1 else index)
        assert frame.frame_id == "oculus"
        assert frame.meta["frequency_hz"] == 1.2e6 and frame.meta["sound_speed_mps"] == 1500.0
        assert frame.meta["vertical_aperture_rad"] == pytest.approx(0.35)


@pytest.mark.parametrize("code", range(10))
@pytest.mark.parametrize("big_endian", [False, True])
def test_every_sample_dtype_of_the_message_maps_exactly(tmp_path, code, big_endian):
    store = msgs.typestore_for({}, ros1=False)
    message, data = psi_message(store, code, code=code, big_endian=big_endian)
    write_user_bag(tmp_path / "bag", "mcap", {"/sonar": (PSI, [message])})
    (frame,) = read_frames(tmp_path / "bag")
    native = data.astype(data.dtype.newbyteorder("="))
    assert np.array_equal(frame.intensity, native)  # value for value, whatever type holds them
    if native.dtype in (np.uint8, np.uint16, np.uint32, np.float32, np.float64):
        assert frame.intensity.dtype == native.dtype and "ros_sample_dtype" not in frame.meta
    else:
        assert frame.meta["ros_sample_dtype"] == native.dtype.name
        assert frame.intensity_scale == float(np.iinfo(native.dtype).max)


def image_message(store, index, encoding, pixels, big_endian=False):
    data = pixels.astype(pixels.dtype.newbyteorder(">" if big_endian else "<")).view(np.uint8).reshape(-1)
    return store.types[msgs.IMAGE](header=header(store, T0 + index), height=pixels.shape[0], width=pixels.shape[1],
                                   encoding=encoding, is_bigendian=int(big_endian),
                                   step=pixels.shape[1] * pixels.dtype.itemsize, data=data)


def test_polar_images_map_with_geometry_from_a_sidecar_or_options(tmp_path):
    store = msgs.typestore_for({}, ros1=False)
    rng = np.random.default_rng(3)
    mono8 = rng.integers(1, 255, (N_RANGES, N_BEAMS), dtype=np.uint8)
    mono16 = rng.integers(1, 65535, (N_RANGES, N_BEAMS), dtype=np.uint16)
    float32 = rng.random((N_RANGES, N_BEAMS)).astype(np.float32) + 0.1
    rgb = rng.integers(0, 255, (N_RANGES, N_BEAMS * 3), dtype=np.uint8)
    messages = [image_message(store, 0, "mono8", mono8), image_message(store, 1, "mono16", mono16, big_endian=True),
                image_message(store, 2, "32FC1", float32), image_message(store, 3, "rgb8", rgb)]
    messages[3].width = N_BEAMS
    write_user_bag(tmp_path / "cam", "sqlite3", {"/sonar/polar": (msgs.IMAGE, messages)})
    (tmp_path / "cam.json").write_text(json.dumps({"kind": "polar", "fov_deg": 60.0, "min_range_m": 0.5,
                                                   "max_range_m": 12.5}))
    report = ReadReport()
    frames = list(read_frames(tmp_path / "cam", report))
    assert [f.intensity.dtype for f in frames] == [np.uint8, np.uint16, np.float32]
    for frame, pixels in zip(frames, [mono8, mono16, float32], strict=True):
        assert np.array_equal(frame.intensity, pixels)
        assert np.allclose(frame.ranges_m, uniform_ranges(N_RANGES, 12.5, 0.5))
        assert np.allclose(frame.azimuths_rad, uniform_azimuths(N_BEAMS, math.radians(60.0)))
        assert not frame.meta.get("geometry_assumed")
    assert [f.stamp_ns for f in frames] == [T0, T0 + 1, T0 + 2]
    assert sum(report.skipped.values()) == 1 and "rgb8" in next(iter(report.skipped))

    options = {"fov_deg": 20.0, "max_range_m": 3.0}  # over the sidecar, whose min_range_m 0.5 stays
    first = next(read_frames(tmp_path / "cam", geometry=options))
    assert first.fov_rad == pytest.approx(math.radians(20.0) * (N_BEAMS - 1) / N_BEAMS)
    assert first.max_range_m == pytest.approx(3.0 - 0.5 * 2.5 / N_RANGES)


def frames_to_write():
    rng = np.random.default_rng(1)
    ranges, bearings = uniform_ranges(30, 12.0, 0.4), BEARINGS
    frames = [SonarImage(rng.integers(0, 255, (30, N_BEAMS), dtype=np.uint8), ranges, bearings, stamp_ns=T0,
                         seq=3, frame_id="fls", meta={"gain_percent": 40.0, "frequency_hz": 1.2e6}),
              SonarImage(rng.random((30, N_BEAMS)), ranges * 1.5, bearings, stamp_ns=T0, seq=4,
                         intensity_scale=2.0, meta={"note": [1, 2]}),  # repeated stamp, float64, new geometry
              SonarImage(rng.random((4, 30, N_BEAMS)).astype(np.float32), ranges, bearings, stamp_ns=T0 + 10**8,
                         seq=5, meta={}),
              SonarImage(rng.integers(0, 2**32 - 1, (30, N_BEAMS), dtype=np.uint32), ranges, bearings, stamp_ns=0,
                         seq=6)]
    return frames


def assert_same(a, b):
    assert a.intensity.dtype == b.intensity.dtype and np.array_equal(a.intensity, b.intensity)
    assert np.array_equal(a.ranges_m, b.ranges_m) and np.array_equal(a.azimuths_rad, b.azimuths_rad)
    assert (a.stamp_ns, a.seq, a.frame_id, a.intensity_scale, a.meta) == \
        (b.stamp_ns, b.seq, b.frame_id, b.intensity_scale, b.meta)


def test_our_mcap_reads_back_exactly_and_opens_as_a_ros2_bag(tmp_path):
    frames = frames_to_write()
    path = tmp_path / "out" / "run.mcap"
    assert write_frames(iter(frames), path) == 4
    assert path.is_file() and sniff(path) == "mcap"
    report = ReadReport()
    back = list(read_frames(path, report))
    assert report.frames == 4 and not report.problems
    for a, b in zip(frames, back, strict=True):
        assert_same(a, b)

    storage = McapReader(path)  # rosbags' own ROS 2 MCAP storage reader
    storage.open()
    counts = {c.topic: (c.msgtype, c.msgcount) for c in storage.connections}
    storage.close()
    assert counts == {"/sonar/image": (PSI, 7), "/sonar/image/frame_info": ("std_msgs/msg/String", 7),
                      "/sonar/fan": (msgs.IMAGE, 4)}
    # As a ROS 2 bag folder: the file plus the metadata.yaml that the file embeds (what `ros2 bag reindex`
    # would write), opened with rosbags' Reader; the messages decode as a ROS 2 driver would see them.
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "run.mcap").write_bytes(path.read_bytes())
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n" + "".join(
        f"  {line}\n" for line in embedded_rosbag2_metadata(path).splitlines()))
    store = msgs.typestore_for({}, ros1=False)
    with Ros2Reader(bag) as reader:
        assert reader.message_count == 18
        connection = next(c for c in reader.connections if c.topic == "/sonar/fan")
        _, _, raw = next(reader.messages(connections=[connection]))
        fan = store.deserialize_cdr(raw, msgs.IMAGE)
        assert fan.encoding == "mono8" and fan.width == 512 and fan.data.max() > 0
        connection = next(c for c in reader.connections if c.topic == "/sonar/image")
        _, _, raw = next(reader.messages(connections=[connection]))
        message = store.deserialize_cdr(raw, PSI)
        assert np.allclose(np.arctan2(-np.array([d.y for d in message.beam_directions]),
                                      [d.z for d in message.beam_directions]), BEARINGS)
    assert [f.seq for f in read_frames(bag)] == [3, 4, 5, 6]


def embedded_rosbag2_metadata(path):
    """The serialized_metadata of the file's "rosbag2" metadata record (MCAP opcode 0x0C)."""
    data = path.read_bytes()
    at = len(MCAP_MAGIC)
    while at < len(data) - 8:
        opcode, length = struct.unpack_from("<BQ", data, at)
        body = data[at + 9:at + 9 + length]
        if opcode == 0x0C:
            (name_length,) = struct.unpack_from("<I", body)
            if body[4:4 + name_length] == b"rosbag2":
                key_at = 4 + name_length + 4  # after the map's byte length
                (key_length,) = struct.unpack_from("<I", body, key_at)
                assert body[key_at + 4:key_at + 4 + key_length] == b"serialized_metadata"
                value_at = key_at + 4 + key_length
                (value_length,) = struct.unpack_from("<I", body, value_at)
                return body[value_at + 4:value_at + 4 + value_length].decode()
        at += 9 + length
    raise AssertionError("no rosbag2 metadata record")


def test_truncated_mcap_and_ros1_bag_read_the_frames_before_the_damage(tmp_path):
    frames = [SonarImage(np.full((200, 64), i, np.uint8), uniform_ranges(200, 20.0), uniform_azimuths(64, 2.0),
                         stamp_ns=T0 + i, seq=i) for i in range(40)]
    write_frames(frames, tmp_path / "full.mcap")
    data = (tmp_path / "full.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: int(len(data) * 0.6)])
    report = ReadReport()
    back = list(read_frames(tmp_path / "cut.mcap", report))
    assert 10 <= len(back) < 40 and [f.seq for f in back] == list(range(len(back)))
    assert any("truncated" in problem for problem in report.problems)

    store = msgs.typestore_for({}, ros1=True)
    write_user_bag(tmp_path / "full.bag", "ros1", {"/sonar": (PSI, [psi_message(store, i, ros1=True)[0]
                                                                    for i in range(30)])}, store, 4096)
    data = (tmp_path / "full.bag").read_bytes()
    (tmp_path / "cut.bag").write_bytes(data[: int(len(data) * 0.5)])
    report = ReadReport()
    back = list(read_frames(tmp_path / "cut.bag", report))
    assert 5 <= len(back) < 30 and [f.seq for f in back] == list(range(7, 7 + len(back)))
    assert any("truncated" in problem for problem in report.problems)


def test_bags_without_a_usable_sonar_topic_say_what_they_have(tmp_path):
    store = msgs.typestore_for({}, ros1=False)
    write_user_bag(tmp_path / "chat", "mcap", {"/chatter": ("std_msgs/msg/String",
                                                            [store.types["std_msgs/msg/String"](data="x")])})
    with pytest.raises(FormatError, match=r"no sonar topic.*/chatter \(std_msgs/msg/String\)"):
        list(read_frames(tmp_path / "chat"))
    with pytest.raises(FormatError, match=r"/chatter is std_msgs/msg/String, not a sonar message type"):
        list(read_frames(tmp_path / "chat", topic="/chatter"))
    with pytest.raises(FormatError, match=r"no topic '/sonar'"):
        list(read_frames(tmp_path / "chat", topic="/sonar"))

    two = [psi_message(store, 0)[0]]
    write_user_bag(tmp_path / "two", "sqlite3", {"/port": (PSI, two), "/starboard": (PSI, two)})
    with pytest.raises(FormatError, match=r"several sonar topics \(/port, /starboard\)"):
        list(read_frames(tmp_path / "two"))
    assert len(list(read_frames(tmp_path / "two", topic="/starboard"))) == 1


def test_a_message_whose_data_does_not_fit_its_geometry_is_a_counted_skip(tmp_path):
    store = msgs.typestore_for({}, ros1=False)
    good, _ = psi_message(store, 0)
    bad, _ = psi_message(store, 1)
    bad.image.data = bad.image.data[:-3]
    write_user_bag(tmp_path / "bag", "mcap", {"/sonar": (PSI, [good, bad, good])})
    report = ReadReport()
    assert len(list(read_frames(tmp_path / "bag", report))) == 2
    assert sum(report.skipped.values()) == 1 and "image.data" in next(iter(report.skipped))


def test_replay_of_a_bag_keeps_the_recorded_timing(tmp_path):
    frames = [SonarImage(np.zeros((8, 4), np.uint8), uniform_ranges(8, 4.0), uniform_azimuths(4, 1.0),
                         stamp_ns=T0 + offset, seq=i) for i, offset in enumerate([0, 100_000_000, 350_000_000])]
    write_frames(frames, tmp_path / "rec.mcap")
    source = ReplaySource(tmp_path / "rec.mcap", speed=1.0, clock=lambda: 50.0)
    dues = [source.next()[0] for _ in frames]
    assert dues == pytest.approx([50.0, 50.1, 50.35])
    assert source.next() is None


def test_recorder_writes_an_mcap_bag(tmp_path):
    recording = Recording(tmp_path / "rec.mcap", contact_sheet=None)
    for frame in frames_to_write():
        recording.add(frame)
    assert recording.close()["frames"] == 4
    back = list(read_frames(tmp_path / "rec.mcap"))
    for a, b in zip(frames_to_write(), back, strict=True):
        assert_same(a, b)


def test_writing_refuses_what_a_bag_cannot_hold(tmp_path):
    good = frames_to_write()[0]
    with pytest.raises(FrameError, match="meta: frame 1 meta is not JSON-able"):
        write_frames([good, good.replace(meta={"when": object()})], tmp_path / "bad.mcap")
    with pytest.raises(FrameError, match="not a SonarImage"):
        write_frames([good.intensity], tmp_path / "bad.mcap")
    assert not (tmp_path / "bad.mcap").exists() and not list(tmp_path.iterdir())  # no half-written bag left
