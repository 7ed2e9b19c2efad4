"""Client API over real sockets, and a publisher written from docs/wire-format.md alone (raw pyzmq + msgpack)."""

from __future__ import annotations

import time

import msgpack
import numpy as np
import pytest
import zmq

from sonar_realism.client import FramePublisher, FrameSubscriber
from sonar_realism.errors import ConfigError, WireError
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.wire import encode_frame, encode_status

BEARINGS = np.sin(np.linspace(-1.0, 1.0, 32)) * 1.1  # non-uniform bearings, like an Oculus table


@pytest.fixture
def context():
    context = zmq.Context()
    yield context
    context.destroy(linger=0)


def receive_while_publishing(send, subscriber: FrameSubscriber, attempts: int = 200) -> SonarImage:
    """PUB/SUB drops what is sent before the subscription arrives (slow joiner): resend until one gets through."""
    for _ in range(attempts):
        send()
        frame = subscriber.recv(timeout_ms=20)
        if frame is not None:
            return frame
    raise AssertionError("no frame arrived")


def drain(subscriber: FrameSubscriber, last: SonarImage) -> SonarImage:
    """Late copies of the resent frame may still be in flight; take them so the next recv sees new frames."""
    while (frame := subscriber.recv(timeout_ms=100)) is not None:
        last = frame
    return last


def test_external_publisher_written_from_the_spec_reaches_our_subscriber(context):
    """Everything the publisher does comes from docs/wire-format.md; no sonar_realism import on this side."""
    publisher = context.socket(zmq.PUB)
    publisher.linger = 0
    publisher.bind("tcp://127.0.0.1:*")
    endpoint = publisher.last_endpoint.decode()
    samples = np.arange(3 * 40 * 32, dtype="<f4").reshape(3, 40, 32) / (3 * 40 * 32)  # [sample, range, beam]
    header = {"v": 1, "type": "frame", "seq": 12, "stamp_ns": 1_754_406_000_000_000_001, "sent_ns": time.time_ns(),
              "frame_id": "unity_sonar", "dtype": "<f4", "shape": [3, 40, 32], "layout": "range_beam",
              "ranges_m": {"start": 0.5, "step": 0.25, "count": 40},
              "azimuths_rad": BEARINGS.astype("<f8").tobytes(),
              "meta": {"source": "unity-plugin", "frequency_hz": 1.2e6},
              "provenance": {"node": "unity"}}
    message = [b"sonar/sim", msgpack.packb(header, use_bin_type=True), samples.tobytes()]
    with FrameSubscriber(endpoint, topics=("sonar/sim",), context=context) as subscriber:
        frame = receive_while_publishing(lambda: publisher.send_multipart(message), subscriber)
        assert subscriber.last_topic == "sonar/sim"
    publisher.close()

    np.testing.assert_array_equal(frame.intensity, samples)
    assert frame.n_samples == 3 and frame.intensity.dtype == np.float32
    np.testing.assert_allclose(frame.ranges_m, 0.5 + 0.25 * np.arange(40))
    np.testing.assert_array_equal(frame.azimuths_rad, BEARINGS)
    assert (frame.seq, frame.stamp_ns, frame.frame_id) == (12, 1_754_406_000_000_000_001, "unity_sonar")
    assert frame.meta == {"source": "unity-plugin", "frequency_hz": 1.2e6, "provenance": {"node": "unity"}}
    # Row 0 is the nearest range bin, column 0 the leftmost beam: the documented byte offset formula holds.
    s, r, b = 2, 7, 5
    offset = ((s * 40 + r) * 32 + b) * 4
    assert frame.intensity[s, r, b] == np.frombuffer(samples.tobytes()[offset:offset + 4], "<f4")[0]


def test_our_publisher_is_readable_from_the_spec_by_an_external_subscriber(context):
    with FramePublisher("tcp://127.0.0.1:*", topic="sim/frames", context=context) as publisher:
        subscriber = context.socket(zmq.SUB)
        subscriber.linger = 0
        subscriber.setsockopt(zmq.SUBSCRIBE, b"sim/frames")
        subscriber.connect(publisher.endpoint)
        intensity = np.arange(40 * 32, dtype=np.uint16).reshape(40, 32)
        for _ in range(200):
            publisher.publish(intensity, uniform_ranges(40, 20.0), BEARINGS, stamp_ns=99, meta={"gain_percent": 50})
            if subscriber.poll(20):
                break
        topic, header_bytes, data = subscriber.recv_multipart()
        subscriber.close()
    header = msgpack.unpackb(header_bytes)
    assert topic == b"sim/frames"
    assert (header["v"], header["type"], header["dtype"], header["shape"], header["layout"]) == (
        1, "frame", "<u2", [40, 32], "range_beam")
    np.testing.assert_array_equal(np.frombuffer(data, "<u2").reshape(40, 32), intensity)
    ranges = header["ranges_m"]
    np.testing.assert_allclose(ranges["start"] + ranges["step"] * np.arange(ranges["count"]), uniform_ranges(40, 20.0))
    np.testing.assert_array_equal(np.frombuffer(header["azimuths_rad"], "<f8"), BEARINGS)
    assert header["stamp_ns"] == 99 and header["meta"] == {"gain_percent": 50}


def test_publisher_counts_seq_and_stamps_frames_over_ipc(context, tmp_path):
    endpoint = f"ipc://{tmp_path}/sonar.ipc"
    with FramePublisher(endpoint, topic="sonar/sim", context=context) as publisher, \
            FrameSubscriber(endpoint, topics=("sonar/",), context=context) as subscriber:
        intensity = np.full((16, 32), 7, np.uint8)
        geometry = (uniform_ranges(16, 8.0), uniform_azimuths(32, 2.0))
        first = drain(subscriber, receive_while_publishing(lambda: publisher.publish(intensity, *geometry), subscriber))
        before = time.time_ns()
        sent = [publisher.publish(intensity, *geometry) for _ in range(3)]
        received = [subscriber.recv(timeout_ms=2000) for _ in range(3)]
        assert subscriber.recv(timeout_ms=50) is None
    assert [frame.seq for frame in received] == [first.seq + 1, first.seq + 2, first.seq + 3]
    assert [frame.seq for frame in sent] == [frame.seq for frame in received]
    assert all(frame.stamp_ns >= before for frame in received)
    np.testing.assert_array_equal(received[-1].intensity, intensity)


def test_subscriber_skips_status_messages_and_unsubscribed_topics(context):
    publisher = context.socket(zmq.PUB)
    publisher.linger = 0
    publisher.bind("tcp://127.0.0.1:*")
    frame = SonarImage(np.zeros((8, 4), np.uint8), uniform_ranges(8, 4.0), uniform_azimuths(4, 1.0))
    with FrameSubscriber(publisher.last_endpoint.decode(), topics=("sonar/",), context=context) as subscriber:
        drain(subscriber, receive_while_publishing(
            lambda: publisher.send_multipart(encode_frame(frame, "sonar/sim")), subscriber))
        # One socket keeps message order, so the status and the foreign frame arrive (or are filtered) first.
        publisher.send_multipart(encode_status("sonar/status", {"node": "sim", "state": "running"}))
        publisher.send_multipart(encode_frame(frame.replace(seq=5), "other/sim"))
        publisher.send_multipart(encode_frame(frame.replace(seq=6), "sonar/sim"))
        received = subscriber.recv(timeout_ms=2000)
    publisher.close()
    assert received.seq == 6 and subscriber.last_topic == "sonar/sim"


def test_malformed_message_raises_wire_error_at_the_subscriber(context):
    with FrameSubscriber("tcp://127.0.0.1:*", bind=True, context=context) as subscriber:
        publisher = context.socket(zmq.PUB)
        publisher.linger = 0
        publisher.connect(subscriber.endpoint)
        bad = [b"sonar/sim", msgpack.packb({"v": 9, "type": "frame"}), b"\0"]
        with pytest.raises(WireError, match="version 9"):
            for _ in range(200):
                publisher.send_multipart(bad)
                subscriber.recv(timeout_ms=20)
        publisher.close()


def test_bad_endpoint_is_a_config_error(context):
    with pytest.raises(ConfigError, match="nonsense"):
        FramePublisher("nonsense://here", context=context)
