"""The live view: fan images and status served over the Foxglove WebSocket protocol, read back by a real
WebSocket client (the `websockets` package) that subscribes and decodes the image."""

import asyncio
import json
import struct
import time

import cv2
import numpy as np
import pytest
import websockets

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.live_view import STATUS_TOPIC, LiveView, fan_png

SUBPROTOCOL = "foxglove.sdk.v1"  # what foxglove-sdk's server speaks (the successor of foxglove.websocket.v1)


def frame(samples=0, seq=0):
    shape = (samples, 60, 48) if samples else (60, 48)
    intensity = np.random.default_rng(seq).random(shape).astype(np.float32) * 0.9 + 0.1
    return SonarImage(intensity, uniform_ranges(60, 20.0, 1.0), uniform_azimuths(48, 2.0), seq=seq,
                      stamp_ns=1_754_412_000_000_000_000 + seq, frame_id="oculus")


def test_fan_png_draws_each_sample_as_a_fan():
    image = cv2.imdecode(np.frombuffer(fan_png(frame(samples=3), width_px=100, max_samples=2), np.uint8),
                         cv2.IMREAD_COLOR)
    assert image.shape[1] == 200  # two samples side by side
    assert not image[0, 0].any() and not image[-1, 0].any()  # outside the fan: black corners
    assert image[image.shape[0] // 4, 50].any() and image[image.shape[0] // 2, 50].any()  # inside: drawn


def protobuf_fields(payload):
    """{field number: value} of a flat protobuf message (varints and length-delimited fields)."""
    fields, at = {}, 0
    while at < len(payload):
        key, at = varint(payload, at)
        number, kind = key >> 3, key & 7
        if kind == 0:
            fields[number], at = varint(payload, at)
        elif kind == 2:
            length, at = varint(payload, at)
            fields[number], at = payload[at:at + length], at + length
        else:
            raise AssertionError(f"unexpected wire type {kind}")
    return fields


def varint(data, at):
    value = shift = 0
    while True:
        byte = data[at]
        at += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, at


async def subscribe_and_receive(view, shown, topics):
    """Connect, subscribe to `topics`, keep showing `shown` until a message of each topic arrived."""
    received = {}
    async with websockets.connect(f"ws://127.0.0.1:{view.port}", subprotocols=[SUBPROTOCOL]) as socket:
        assert socket.subprotocol == SUBPROTOCOL
        channels = {}
        while set(topics) - set(channels):
            message = json.loads(await asyncio.wait_for(socket.recv(), 5))
            if message["op"] == "advertise":
                channels.update({c["topic"]: c for c in message["channels"]})
        by_subscription = {i: channels[topic] for i, topic in enumerate(topics)}
        await socket.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": i, "channelId": c["id"]} for i, c in by_subscription.items()]}))
        deadline = time.monotonic() + 10
        while set(topics) - set(received) and time.monotonic() < deadline:
            shown()
            try:
                data = await asyncio.wait_for(socket.recv(), 0.5)
            except TimeoutError:
                continue
            if isinstance(data, bytes) and data[0] == 0x01:  # message data: opcode, subscription, log time, payload
                subscription, log_time = struct.unpack_from("<IQ", data, 1)
                channel = by_subscription[subscription]
                received[channel["topic"]] = (channel, log_time, data[13:])
    return received


def test_a_websocket_client_subscribes_and_receives_a_decodable_fan_image():
    view = LiveView(port=0, width_px=120, max_samples=2)
    translated = frame(samples=3, seq=7)
    try:
        view.show("/sonar/translated", translated)  # advertises the channel
        view.status({"node": "viewer", "frames_in": 1})

        def show():
            view.show("/sonar/translated", translated)
            view.status({"node": "viewer", "frames_in": view.shown})

        received = asyncio.run(subscribe_and_receive(view, show, ["/sonar/translated", STATUS_TOPIC]))
    finally:
        view.close()
    channel, log_time, payload = received["/sonar/translated"]
    assert channel["schemaName"] == "foxglove.CompressedImage" and channel["encoding"] == "protobuf"
    assert log_time == translated.stamp_ns
    fields = protobuf_fields(payload)  # foxglove.CompressedImage: 1 timestamp, 2 data, 3 format, 4 frame_id
    assert fields[3] == b"png" and fields[4] == b"oculus"
    assert fields[2] == fan_png(translated, 120, 2)
    image = cv2.imdecode(np.frombuffer(fields[2], np.uint8), cv2.IMREAD_COLOR)
    assert image.shape[1] == 240 and image.std() > 10
    status_channel, _, status = received[STATUS_TOPIC]
    assert status_channel["encoding"] == "json" and json.loads(status)["node"] == "viewer"


def test_the_view_serves_this_machine_only():
    with pytest.raises(ConfigError, match="localhost only"):
        LiveView(host="0.0.0.0", port=0)
