"""Wire format: round trips, zero-copy over real sockets, every rejection path, fuzzing."""

from __future__ import annotations

import dataclasses
import math
import sys
from concurrent.futures import ThreadPoolExecutor

import msgpack
import numpy as np
import pytest
import zmq
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sonar_realism.errors import WireError
from sonar_realism.frames import SUPPORTED_DTYPES, SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.wire import (
    FRAME_TYPE,
    MAX_HEADER_BYTES,
    STATUS_TYPE,
    Message,
    decode_frame,
    decode_message,
    encode_frame,
    encode_status,
)

OCULUS_LIKE_BEARINGS = np.sin(np.linspace(-1.0, 1.0, 16)) * 1.13  # non-uniform, like an Oculus table


def make_frame(dtype=np.uint8, shape=(24, 16), seq=7, meta=None) -> SonarImage:
    rng = np.random.default_rng(seq)
    dtype = np.dtype(dtype)
    if dtype.kind == "f":
        intensity = rng.random(shape).astype(dtype)
    else:
        intensity = rng.integers(0, np.iinfo(dtype).max, size=shape, dtype=dtype, endpoint=True)
    return SonarImage(intensity, uniform_ranges(shape[-2], 30.0, 0.3), np.sin(np.linspace(-1.0, 1.0, shape[-1])),
                      stamp_ns=1_754_406_000_123_456_789, seq=seq, frame_id="oculus_m1200d",
                      meta=meta if meta is not None else {"frequency_hz": 1.2e6, "gain_percent": 40.0})


def to_bytes(parts: list) -> list[bytes]:
    return [bytes(part) for part in parts]


def assert_same_frame(got: SonarImage, want: SonarImage) -> None:
    assert got.intensity.dtype == want.intensity.dtype
    np.testing.assert_array_equal(got.intensity, want.intensity)
    np.testing.assert_allclose(got.ranges_m, want.ranges_m, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got.azimuths_rad, want.azimuths_rad)
    assert (got.stamp_ns, got.seq, got.frame_id, got.intensity_scale) == (
        want.stamp_ns, want.seq, want.frame_id, want.intensity_scale)


@pytest.mark.parametrize("dtype", SUPPORTED_DTYPES, ids=str)
@pytest.mark.parametrize("shape", [(24, 16), (3, 24, 16)], ids=["plain", "samples"])
def test_round_trip_every_dtype_with_and_without_sample_axis(dtype, shape):
    frame = make_frame(dtype, shape)
    topic, decoded = decode_frame(to_bytes(encode_frame(frame, "sim/frames")))
    assert topic == "sim/frames"
    assert decoded.intensity.shape == shape
    assert_same_frame(decoded, frame)
    assert decoded.meta == frame.meta


@pytest.mark.parametrize("dtype", [">u2", ">u4", ">f4", ">f8"])
def test_big_endian_frames_keep_their_values(dtype):
    frame = make_frame(np.dtype(dtype).newbyteorder("="))
    swapped = frame.replace(intensity=frame.intensity.astype(dtype))
    parts = encode_frame(swapped, "t")
    assert msgpack.unpackb(parts[1])["dtype"] == dtype
    _, decoded = decode_frame(to_bytes(parts))
    # Byte order is normalised once, in the decoder: consumers only ever see native samples.
    assert decoded.intensity.dtype == frame.intensity.dtype and decoded.intensity.dtype.isnative
    np.testing.assert_array_equal(decoded.intensity, frame.intensity)
    assert not decoded.intensity.flags.writeable


def test_uniform_ranges_travel_compactly_and_explicit_bearings_exactly():
    frame = make_frame(shape=(2000, 16))
    header = msgpack.unpackb(encode_frame(frame, "t")[1])
    assert set(header["ranges_m"]) == {"start", "step", "count"}
    assert len(header["azimuths_rad"]) == 16 * 8  # bin of float64: non-uniform bearings are never rounded
    _, decoded = decode_frame(to_bytes(encode_frame(frame, "t")))
    assert_same_frame(decoded, frame)


def test_provenance_lands_in_meta_and_explicit_provenance_wins():
    frame = make_frame(meta={"source": "sim", "provenance": {"node": "old"}})
    _, forwarded = decode_frame(to_bytes(encode_frame(frame, "t")))
    assert forwarded.meta == {"source": "sim", "provenance": {"node": "old"}}
    provenance = {"input_seq": 41, "input_stamp_ns": 5, "checkpoint_sha256": "ab" * 32, "node": "translator"}
    _, translated = decode_frame(to_bytes(encode_frame(frame, "t", provenance=provenance)))
    assert translated.meta == {"source": "sim", "provenance": provenance}


def test_numpy_values_in_meta_become_plain_values():
    frame = make_frame(meta={"gain": np.float32(0.5), "beams": np.arange(3), "n": np.int64(4)})
    _, decoded = decode_frame(to_bytes(encode_frame(frame, "t")))
    assert decoded.meta == {"gain": 0.5, "beams": [0, 1, 2], "n": 4}


def test_non_contiguous_intensity_is_sent_in_c_order():
    frame = make_frame(shape=(16, 24))
    transposed = frame.replace(intensity=frame.intensity.T, ranges_m=uniform_ranges(24, 10.0),
                               azimuths_rad=uniform_azimuths(16, 2.0))
    _, decoded = decode_frame(to_bytes(encode_frame(transposed, "t")))
    np.testing.assert_array_equal(decoded.intensity, frame.intensity.T)


def test_data_part_is_the_arrays_own_memory():
    frame = make_frame(np.float32, (64, 32))
    data = encode_frame(frame, "t")[2]
    assert np.shares_memory(np.frombuffer(data, np.uint8), frame.intensity)


@pytest.fixture
def pair():
    context = zmq.Context()
    sender, receiver = context.socket(zmq.PAIR), context.socket(zmq.PAIR)
    sender.linger = receiver.linger = 0
    receiver.bind("inproc://wire-test")
    sender.connect("inproc://wire-test")
    yield sender, receiver
    sender.close()
    receiver.close()
    context.term()


def test_zero_copy_over_a_real_inproc_socket(pair):
    sender, receiver = pair
    frame = make_frame(np.float32, (512, 256))  # 512 KiB: above pyzmq's 64 KiB copy threshold
    sender.send_multipart(encode_frame(frame, "sonar/sim"), copy=False)
    parts = receiver.recv_multipart(copy=False)
    topic, decoded = decode_frame(parts)
    assert topic == "sonar/sim"
    assert_same_frame(decoded, frame)
    # The view is over the received ZeroMQ message; over inproc that message is the sender's array itself.
    assert np.shares_memory(decoded.intensity, np.frombuffer(parts[2].buffer, np.uint8))
    assert np.shares_memory(decoded.intensity, frame.intensity)
    assert not decoded.intensity.flags.writeable


def test_status_round_trip_over_a_socket(pair):
    sender, receiver = pair
    status = {"node": "translator", "state": "running", "seq": 3, "frames_in": 10, "frames_out": 9,
              "dropped": 1, "seq_gaps": 0, "malformed": 2, "inference_ms": 12.5, "uptime_s": 4.0,
              "endpoint": "tcp://127.0.0.1:5556"}
    sender.send_multipart(encode_status("translator/status", status))
    message = decode_message(receiver.recv_multipart(copy=False))
    assert (message.topic, message.kind, message.body) == ("translator/status", STATUS_TYPE, status)
    assert message.sent_ns > 0
    assert message == Message("translator/status", STATUS_TYPE, status, message.sent_ns)  # a value, by its fields
    with pytest.raises(dataclasses.FrozenInstanceError):
        message.topic = "other"
    with pytest.raises(WireError, match="expected a frame message"):
        decode_frame(encode_status("translator/status", status))


def test_decode_message_reports_frames_as_frames():
    frame = make_frame()
    message = decode_message(to_bytes(encode_frame(frame, "a/b")))
    assert (message.topic, message.kind) == ("a/b", FRAME_TYPE)
    assert_same_frame(message.body, frame)


@pytest.mark.parametrize("status, field", [
    ({"state": "running"}, "node"),
    ({"node": "n", "state": "dancing"}, "state"),
    ({"node": "n", "state": "running", "frames_in": -1}, "frames_in"),
    ({"node": "n", "state": "running", "dropped": 1.5}, "dropped"),
    ({"node": "n", "state": "running", "inference_ms": math.nan}, "inference_ms"),
    ({"node": "n", "state": "running", "log": object()}, "cannot encode"),
])
def test_bad_status_is_rejected(status, field):
    with pytest.raises(WireError, match=field):
        encode_status("n/status", status)


def header_of(frame: SonarImage, **changes) -> bytes:
    header = msgpack.unpackb(encode_frame(frame, "t")[1])
    header.update(changes)
    return msgpack.packb({k: v for k, v in header.items() if v is not None}, use_bin_type=True)


FRAME = make_frame(np.uint16, (24, 16))
DATA = FRAME.intensity.tobytes()


@pytest.mark.parametrize("parts, message", [
    ([b"t", header_of(FRAME, v=2), DATA], "version 2 is not supported"),
    ([b"t", header_of(FRAME, v=True), DATA], "version True"),
    ([b"t", header_of(FRAME), DATA[:-2]], "expected 768 bytes .* got 766"),
    ([b"t", header_of(FRAME), DATA + b"\0\0"], "expected 768 bytes .* got 770"),
    ([b"t", header_of(FRAME, dtype="<i2"), DATA], "unknown dtype '<i2'"),
    ([b"t", header_of(FRAME, dtype="float16"), DATA], "unknown dtype"),
    ([b"t", header_of(FRAME, meta={"pad": "x" * MAX_HEADER_BYTES}), DATA], "exceeds the 65536-byte limit"),
    ([b"t", b"\xc1\x00garbage", DATA], "not valid msgpack"),
    ([b"t", msgpack.packb([1, 2, 3]), DATA], "expected a msgpack map"),
    ([b"t", header_of(FRAME) + b"\x00", DATA], "not valid msgpack"),
    ([b"t", header_of(FRAME)], "3 parts"),
    ([b"t", header_of(FRAME), DATA, DATA], "got 4"),
    ([b"t"], "got 1"),
    ([b"\xff\xfe", header_of(FRAME), DATA], "topic: not UTF-8"),
    ([b"t", header_of(FRAME, type="image"), DATA], "type: "),
    ([b"t", header_of(FRAME, shape=[16, 24, 0]), DATA], "shape: "),
    ([b"t", header_of(FRAME, shape=[384]), DATA], "shape: "),
    ([b"t", header_of(FRAME, layout="beam_range"), DATA], "layout: "),
    ([b"t", header_of(FRAME, seq=None), DATA], "missing field.*seq"),
    ([b"t", header_of(FRAME, seq=-1), DATA], "seq"),
    ([b"t", header_of(FRAME, stamp_ns="now"), DATA], "stamp_ns"),
    ([b"t", header_of(FRAME, frame_id=3), DATA], "frame_id"),
    ([b"t", header_of(FRAME, meta=[1]), DATA], "meta: "),
    ([b"t", header_of(FRAME, provenance="me"), DATA], "provenance: "),
    ([b"t", header_of(FRAME, ranges_m={"start": 0, "step": 1, "count": 23}), DATA], "count 23"),
    ([b"t", header_of(FRAME, ranges_m={"start": 0, "step": -1, "count": 24}), DATA], "strictly increasing"),
    ([b"t", header_of(FRAME, azimuths_rad=b"\0" * 8), DATA], "expected 16 float64"),
    ([b"t", header_of(FRAME, azimuths_rad=list(range(16))), DATA], "beyond"),
    ([b"t", header_of(FRAME, azimuths_rad="left"), DATA], "azimuths_rad"),
    ([b"t", msgpack.packb({"v": 1, "type": "frame", "x": msgpack.ExtType(5, b"")}), DATA], "extension type"),
    ([b"t", msgpack.packb({"v": 1, "type": "status"})], "missing field"),
    ([b"t", msgpack.packb({"v": 1, "type": "status", "status": {"node": "n"}})], "state"),
    ([b"t", msgpack.packb({"v": 1, "type": "status", "status": {"node": "n", "state": "running"}}), b""], "2 parts"),
    ([b"t", memoryview(np.zeros((4, 4), np.uint8)[:, ::2]), DATA], "contiguous"),
    ([b"t", "a str, not bytes", DATA], "expected bytes"),
])
def test_malformed_messages_raise_wire_error(parts, message):
    with pytest.raises(WireError, match=message) as caught:
        decode_message(parts)
    assert caught.value.field and str(caught.value).startswith(caught.value.field if caught.value.topic is None
                                                               else f"topic {caught.value.topic!r}: ")


@pytest.mark.parametrize("meta", [
    {"when": msgpack.Timestamp(1_700_000_000, 5)},
    {"nested": [1, {"deeper": msgpack.Timestamp(0, 0)}]},
    {"ext": msgpack.ExtType(3, b"xyz")},
], ids=["timestamp", "nested-timestamp", "ext-3"])
def test_extension_types_are_rejected_wherever_they_sit(meta):
    with pytest.raises(WireError, match="extension type") as caught:
        decode_message([b"t", header_of(FRAME, meta=meta), DATA])
    assert (caught.value.topic, caught.value.field) == ("t", "header")



@pytest.mark.parametrize("meta", [{"sound_speed_mps": float("nan")}, {"gain": float("inf")}, {"raw": b"\x00\x01"},
                                  {"nested": [1.0, {"deeper": float("-inf")}]}],
                         ids=["nan", "inf", "bytes", "nested-inf"])
def test_meta_a_recorder_could_not_write_as_json_is_rejected_on_arrival(meta):
    with pytest.raises(WireError, match="not JSON-like") as caught:
        decode_message([b"t", header_of(FRAME, meta=meta), DATA])
    assert (caught.value.topic, caught.value.field) == ("t", "meta")

# Every encoding msgpack decodes as a timestamp (-1): fixext 4/8 and ext 8/16/32 with 4, 8 or 12 data bytes,
# the long forms being what a publisher's library may write. `seq` is the last key, so the header's map is complete.
_TIMESTAMPS = {"fixext4": b"\xd6\xff" + bytes(4), "fixext8": b"\xd7\xff" + bytes(8),
               "ext8-12": b"\xc7\x0c\xff" + bytes(12), "ext16-8": b"\xc8\x00\x08\xff" + bytes(8),
               "ext32-4": b"\xc9\x00\x00\x00\x04\xff" + bytes(4)}


@pytest.mark.parametrize("encoded", _TIMESTAMPS.values(), ids=_TIMESTAMPS)
@pytest.mark.parametrize("where", ["value", "in-list", "whole-header"])
def test_every_timestamp_encoding_is_rejected_naming_the_extension(encoded, where):
    frame_header = msgpack.packb({k: v for k, v in msgpack.unpackb(header_of(FRAME)).items() if k != "seq"})
    if where == "whole-header":
        header = encoded
    else:
        value = b"\x91" + encoded if where == "in-list" else encoded
        header = bytes([frame_header[0] + 1]) + frame_header[1:] + b"\xa3seq" + value  # one more map entry
    with pytest.raises(WireError, match="extension type -1") as caught:
        decode_message([b"t", header, DATA])
    assert (caught.value.topic, caught.value.field) == ("t", "header")


@pytest.mark.parametrize("header, reason", [
    (b"", "empty part"),
    (b"\xc1", "starts no msgpack value"),
    (b"\x81\xa1v", "incomplete input"),
    (b"\x81\x01\x02", "not allowed for map key"),
])
def test_garbage_headers_give_a_reason_a_publisher_can_act_on(header, reason):
    with pytest.raises(WireError, match=reason) as caught:
        decode_message([b"sonar/sim", header, DATA])
    assert (caught.value.topic, caught.value.field) == ("sonar/sim", "header")


@pytest.mark.parametrize("field, value", [("stamp_ns", 2**64 - 1), ("seq", 2**63)])
def test_64_bit_unsigned_counters_are_accepted(field, value):
    _, frame = decode_frame([b"t", header_of(FRAME, **{field: value}), DATA])
    assert getattr(frame, field) == value


@pytest.mark.parametrize("field, value", [("stamp_ns", -1), ("sent_ns", -5), ("sent_ns", "now"), ("seq", 1.0)])
def test_counters_outside_uint64_are_rejected_with_their_field(field, value):
    with pytest.raises(WireError) as caught:
        decode_message([b"t", header_of(FRAME, **{field: value}), DATA])
    assert caught.value.field == field


def test_nan_in_a_float_frame_is_rejected():
    frame = make_frame(np.float32)
    data = bytearray(frame.intensity.tobytes())
    data[:4] = np.float32(np.nan).tobytes()
    with pytest.raises(WireError, match="NaN"):
        decode_frame([b"t", bytes(encode_frame(frame, "t")[1]), bytes(data)])


def test_encoder_rejects_what_a_receiver_would_reject():
    with pytest.raises(WireError, match="exceeds the 65536-byte limit"):
        encode_frame(make_frame(meta={"blob": b"\0" * MAX_HEADER_BYTES}), "t")
    with pytest.raises(WireError, match="cannot encode"):
        encode_frame(make_frame(meta={"when": object()}), "t")
    with pytest.raises(WireError, match="topic"):
        encode_frame(make_frame(), "t" * 2000)


def test_a_failed_encode_leaves_nothing_behind_for_the_next_one():
    # The encoder keeps one msgpack packer per thread: what a failed or oversized header wrote must not leak
    # into the next message's header.
    frame = make_frame(meta={"gain_percent": 40.0})
    expected = decode_frame(encode_frame(frame, "t"))[1]
    for bad_meta in ({"when": object()}, {"blob": b"\0" * MAX_HEADER_BYTES}):
        with pytest.raises(WireError):
            encode_frame(make_frame(meta=bad_meta), "t")
        got = decode_frame(encode_frame(frame, "t"))[1]
        assert got.meta == expected.meta and got.seq == expected.seq


def test_frames_encoded_on_several_threads_at_once_decode_to_their_own_content():
    # numpy scalars in meta make the packer call back into Python mid-header, where another thread can run
    # (switching threads as often as possible here).
    frames = [make_frame(seq=seq, meta={"gains": [np.float32(seq)] * 50, "who": "x" * seq}) for seq in range(8)]

    def round_trips(frame: SonarImage) -> bool:
        for _ in range(200):
            got = decode_frame(encode_frame(frame, "t"))[1]
            if got.seq != frame.seq or got.meta != frame.meta or not np.array_equal(got.intensity, frame.intensity):
                return False
        return True

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        with ThreadPoolExecutor(max_workers=len(frames)) as pool:
            assert all(pool.map(round_trips, frames))
    finally:
        sys.setswitchinterval(interval)


def test_parts_are_read_through_the_buffer_protocol_or_a_buffer_attribute():
    frame = make_frame()
    topic, header, data = encode_frame(frame, "t")

    class BufferHolder:  # an object that is no buffer itself but exposes one, as zmq.Frame's .buffer does
        def __init__(self, payload: bytes) -> None:
            self.buffer = memoryview(payload)

    for parts in ([topic, header, bytes(data)], [bytearray(topic), memoryview(header), bytearray(data)],
                  [BufferHolder(topic), BufferHolder(header), BufferHolder(bytes(data))]):
        assert np.array_equal(decode_frame(parts)[1].intensity, frame.intensity)
    with pytest.raises(WireError, match="expected bytes or a zmq.Frame"):
        decode_frame([topic, header, 42])


def test_a_hand_written_header_with_list_geometry_decodes():
    header = {"v": 1, "type": "frame", "seq": 0, "stamp_ns": 0, "frame_id": "sonar", "dtype": "|u1",
              "shape": [2, 3], "layout": "range_beam", "ranges_m": [1.0, 2], "azimuths_rad": [-0.5, 0.0, 0.5],
              "unknown_future_key": {"ignored": True}}
    _, frame = decode_frame([b"sim", msgpack.packb(header), bytes([0, 1, 2, 3, 4, 255])])
    np.testing.assert_array_equal(frame.intensity, [[0, 1, 2], [3, 4, 255]])
    np.testing.assert_array_equal(frame.ranges_m, [1.0, 2.0])
    assert frame.intensity_scale == 255.0 and frame.meta == {}


json_like = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=8) | st.binary(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=4),
    max_leaves=12)
header_keys = st.sampled_from(["v", "type", "seq", "stamp_ns", "sent_ns", "frame_id", "dtype", "shape", "layout",
                               "ranges_m", "azimuths_rad", "intensity_scale", "meta", "provenance", "status"])


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(changes=st.dictionaries(header_keys, json_like, max_size=4), drop=st.sets(header_keys, max_size=3),
       data=st.binary(max_size=900), two_parts=st.booleans())
def test_fuzzed_headers_raise_only_wire_error(changes, drop, data, two_parts):
    header = msgpack.unpackb(encode_frame(FRAME, "t")[1])
    header.update(changes)
    for key in drop:
        header.pop(key, None)
    try:
        packed = msgpack.packb(header, use_bin_type=True)
    except (OverflowError, ValueError):
        return  # ints beyond 64 bits cannot even be packed, so no publisher can send them
    parts = [b"t", packed] if two_parts else [b"t", packed, data]
    try:
        message = decode_message(parts)
    except WireError as error:
        assert error.topic == "t" and error.field
        return
    assert message.kind in (FRAME_TYPE, STATUS_TYPE)
    if message.kind == FRAME_TYPE:
        assert message.body.intensity.nbytes == len(data)


@settings(max_examples=300, deadline=None)
@given(parts=st.lists(st.binary(max_size=64), min_size=0, max_size=4))
def test_fuzzed_bytes_raise_only_wire_error(parts):
    try:
        decode_message(parts)
    except WireError:
        pass


def test_a_streams_geometry_is_checked_once_and_shared_by_its_frames():
    first, second = make_frame(seq=1), make_frame(seq=2)
    _, a = decode_frame(to_bytes(encode_frame(first, "t")))
    _, b = decode_frame(to_bytes(encode_frame(second, "t")))
    assert b.ranges_m is a.ranges_m and b.azimuths_rad is a.azimuths_rad
    with pytest.raises(ValueError, match="read-only"):
        a.azimuths_rad[0] = 0.0  # shared by every later frame of the stream: nobody may change it


@pytest.mark.parametrize("form", ["bytes", "uniform"])
def test_a_changed_axis_is_checked_again_and_a_bad_one_rejected_with_its_field(form):
    good = make_frame()
    decode_frame(to_bytes(encode_frame(good, "t")))  # the stream's geometry is now known
    header = msgpack.unpackb(bytes(encode_frame(good, "t")[1]))
    data = good.intensity.tobytes()
    if form == "bytes":
        bearings = good.azimuths_rad.copy()
        bearings[[3, 4]] = bearings[[4, 3]]  # same length, one swap: no longer increasing
        header["azimuths_rad"] = bearings.astype("<f8").tobytes()
        field, reason = "azimuths_rad", "strictly increasing"
    else:
        header["ranges_m"] = {**header["ranges_m"], "start": -1.0}
        field, reason = "ranges_m", "negative range"
    with pytest.raises(WireError, match=reason) as caught:
        decode_frame([b"t", msgpack.packb(header, use_bin_type=True), data])
    assert caught.value.field == field
    _, again = decode_frame(to_bytes(encode_frame(good, "t")))  # the good geometry still decodes
    np.testing.assert_array_equal(again.azimuths_rad, good.azimuths_rad)


def test_forwarded_geometry_goes_out_as_it_came_in():
    # Received frames carry checked axes, which encode_frame knows by identity: two streams forwarded in turn
    # (each axis checked once, then met again) must each go out with their own geometry.
    streams = [make_frame(seq=1), make_frame(seq=2).replace(ranges_m=uniform_ranges(24, 7.0),
                                                            azimuths_rad=np.linspace(-0.5, 0.5, 16) ** 3)]
    received = [decode_frame(to_bytes(encode_frame(frame, "t")))[1] for frame in streams]
    for _ in range(2):
        for frame, original in zip(received, streams, strict=True):
            _, forwarded = decode_frame(to_bytes(encode_frame(frame, "t")))
            np.testing.assert_array_equal(forwarded.azimuths_rad, original.azimuths_rad)
            np.testing.assert_allclose(forwarded.ranges_m, original.ranges_m, rtol=0, atol=1e-12)


def test_bearings_that_change_every_frame_are_decoded_exactly():
    for seq in range(20):  # more distinct axes than are remembered
        bearings = np.sort(np.random.default_rng(seq).uniform(-1.0, 1.0, 16))
        frame = make_frame(seq=seq).replace(azimuths_rad=bearings)
        _, decoded = decode_frame(to_bytes(encode_frame(frame, "t")))
        np.testing.assert_array_equal(decoded.azimuths_rad, bearings)
