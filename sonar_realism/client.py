"""Thin ZeroMQ client for simulators and scripts: publish or receive frames in the wire format.

    with FramePublisher("tcp://127.0.0.1:5555") as pub:          # binds a publisher on loopback
        pub.publish(intensity, ranges_m, azimuths_rad)              # [n_ranges, n_beams] array + geometry
        pub.end_stream()                                            # the receivers end (docs/wire-format.md)

    with FrameSubscriber("tcp://127.0.0.1:5555", topics=("sonar/sim",)) as sub:
        frame = sub.recv(timeout_ms=1000)                           # SonarImage, or None on timeout

The message layout is docs/wire-format.md; this module only adds sockets around sonar_realism.wire.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import zmq

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.wire import FRAME_TYPE, decode_message, encode_frame, encode_status


class FramePublisher:
    """A publisher (an XPUB socket: a PUB that also hears who subscribes) that sends SonarImage frames on one
    topic; `seq` counts up from 0 unless given. `end_stream()` ends the stream for every receiver."""

    def __init__(self, endpoint: str, topic: str = "sonar/sim", bind: bool = True,
                 context: zmq.Context | None = None, linger_ms: int = 1000) -> None:
        self.topic = topic
        self._next_seq = 0
        self._socket = (context or zmq.Context.instance()).socket(zmq.XPUB)
        self._subscriptions: set[bytes] = set()  # the filters heard that take our topic
        # Frames still queued at close() get linger_ms to leave, so a short script's last frames arrive.
        self._socket.linger = linger_ms
        self.endpoint = _open(self._socket, endpoint, bind)

    def publish(self, intensity: np.ndarray, ranges_m: Any, azimuths_rad: Any, stamp_ns: int | None = None,
                seq: int | None = None, frame_id: str = "sonar", meta: dict | None = None) -> SonarImage:
        """Publish one frame (`stamp_ns` defaults to now, `seq` to the publisher's counter); returns it."""
        frame = SonarImage(intensity=np.asarray(intensity), ranges_m=ranges_m, azimuths_rad=azimuths_rad,
                           stamp_ns=time.time_ns() if stamp_ns is None else stamp_ns,
                           seq=self._next_seq if seq is None else seq, frame_id=frame_id, meta=meta or {})
        self.publish_frame(frame)
        return frame

    def publish_frame(self, frame: SonarImage) -> None:
        """Publish a ready SonarImage as it is (its own seq and stamp)."""
        # Encode fully before sending: a failure half-way must not leave a stray topic part on the socket.
        parts = encode_frame(frame, self.topic)
        self._socket.send_multipart(parts, copy=False)
        self._next_seq = frame.seq + 1

    def end_stream(self, reason: str = "finished", timeout_s: float = 10.0) -> bool:
        """Tell every receiver this topic sends no more frames (docs/wire-format.md, "End of stream"). A PUB queue
        drops what it cannot hold, so one marker after a burst may never arrive: it is sent again until every
        subscriber has hung up (our nodes do on end of stream) or `timeout_s` has passed. True if all hung up."""
        message = encode_status(self.topic, {"node": "client", "state": "stopped", "end_of_stream": True,
                                             "reason": reason})
        deadline = time.monotonic() + timeout_s
        while True:
            self._hear_subscriptions(0)
            if not self._subscriptions:
                return True
            try:
                self._socket.send_multipart(message, flags=zmq.NOBLOCK)
            except zmq.Again:
                pass
            if time.monotonic() > deadline:
                return False
            self._hear_subscriptions(_END_RESEND_MS)

    def subscribed(self, timeout_ms: int = 0) -> bool:
        """Whether a receiver takes this topic now (hearing subscriptions for up to `timeout_ms`). A PUB/SUB
        receiver that connects late misses what was sent before it subscribed: wait for this before a short run."""
        self._hear_subscriptions(timeout_ms)
        return bool(self._subscriptions)

    def _hear_subscriptions(self, timeout_ms: int) -> None:
        """Take the (un)subscriptions the socket has heard: a byte 1 or 0, then the filter."""
        topic = self.topic.encode("utf-8")
        while self._socket.poll(timeout_ms, zmq.POLLIN):
            timeout_ms = 0
            notice = self._socket.recv()
            if notice[:1] in (b"\x01", b"\x00") and topic.startswith(notice[1:]):
                (self._subscriptions.add if notice[:1] == b"\x01" else self._subscriptions.discard)(notice[1:])

    def close(self) -> None:
        self._socket.close()

    def __enter__(self) -> FramePublisher:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


# How often end_stream() sends its marker again while subscribers are still there.
_END_RESEND_MS = 50


class FrameSubscriber:
    """A SUB socket receiving frames whose topic starts with one of `topics` ("" = every topic)."""

    def __init__(self, endpoint: str, topics: Sequence[str] = ("",), bind: bool = False,
                 context: zmq.Context | None = None) -> None:
        if isinstance(topics, str):
            topics = (topics,)
        self.last_topic: str | None = None
        self._socket = (context or zmq.Context.instance()).socket(zmq.SUB)
        self._socket.linger = 0
        for topic in topics:
            self._socket.setsockopt(zmq.SUBSCRIBE, topic.encode("utf-8"))
        self.endpoint = _open(self._socket, endpoint, bind)

    def recv(self, timeout_ms: int = 1000) -> SonarImage | None:
        """The next frame within `timeout_ms` (status messages on the same topics are skipped), else None.

        Malformed messages raise WireError; the intensity is a read-only view over the received message.
        """
        deadline = time.monotonic() + timeout_ms / 1000.0
        while True:
            remaining_ms = max(0, round((deadline - time.monotonic()) * 1000.0))
            if not self._socket.poll(remaining_ms, zmq.POLLIN):
                return None
            message = decode_message(self._socket.recv_multipart(copy=False))
            if message.kind == FRAME_TYPE:
                self.last_topic = message.topic
                return message.body

    def close(self) -> None:
        self._socket.close()

    def __enter__(self) -> FrameSubscriber:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _open(socket: zmq.Socket, endpoint: str, bind: bool) -> str:
    """Bind or connect; returns the resolved endpoint (a bound `tcp://127.0.0.1:*` gets its real port)."""
    try:
        if not bind:
            socket.connect(endpoint)
            return endpoint
        socket.bind(endpoint)
    except zmq.ZMQError as error:
        socket.close(linger=0)
        raise ConfigError(f"endpoint {endpoint!r}: cannot {'bind' if bind else 'connect'} ({error})") from error
    return socket.last_endpoint.decode("utf-8")
