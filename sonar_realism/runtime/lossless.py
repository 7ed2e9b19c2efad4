"""Lossless across a crash: frames on an in-graph lossless edge are kept by the producer until the consumer
has finished with them, and sent again to a consumer that was restarted. Socket-free; node.py wires it.

Protocol, per lossless edge (data: producer PUSH -> consumer PULL; acks: consumer PUSH -> producer PULL):
- The consumer process starts with a random `session` and sends `{"hello": session}` on the ack channel.
  Until it sees a resync marker for its session (a status message on the data topic with
  `"resync": session`) it discards data: whatever arrives before it will be sent again after it.
- The producer answers a hello it has not seen with the marker, then every unacknowledged frame in order.
- The consumer acknowledges cumulatively, `{"ack": seq}`: every frame up to `seq` is finished, i.e. it was
  handled (processed, rejected as malformed or dropped as stale) AND everything the node published while
  handling it has been acknowledged by its own lossless consumers. A SIGKILL anywhere in a chain therefore
  loses nothing: what the dead node had not passed on is still unacknowledged upstream.
- Frames sent again reach consumers that already have them (the killed node's outputs that did arrive):
  a consumer drops every frame whose `seq` is not above the last one it took (counted as `duplicates`)
  and acknowledges again, so seq must increase along an edge (sim_source, file_replay and the translator,
  which keeps its input's seq, do this).
- The producer keeps at most `window` frames unacknowledged per edge; a full window blocks publishing
  (backpressure, like a full socket), so memory stays bounded.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

import msgpack


def hello_message(session: str) -> bytes:
    return msgpack.packb({"hello": session})


def ack_message(seq: int) -> bytes:
    return msgpack.packb({"ack": seq})


def parse_control(data: bytes) -> tuple[str, Any] | None:
    """("hello", session) or ("ack", seq) from an ack-channel message; None for anything else."""
    try:
        message = msgpack.unpackb(data, raw=False)
    except Exception:  # only our own nodes write here; a stray message is ignored, never fatal
        return None
    if isinstance(message, dict) and len(message) == 1:
        (kind, value), = message.items()
        if kind == "hello" and isinstance(value, str):
            return kind, value
        if kind == "ack" and type(value) is int:
            return kind, value
    return None


@dataclass
class _Sent:
    count: int      # this edge's send counter when the frame was sent (1 = first)
    seq: int
    parts: list


class ResendBuffer:
    """Producer side of one lossless edge: the frames sent and not acknowledged yet.

    `on_ack` / `on_hello` are called by the node's receive thread; everything else by its main thread.
    """

    def __init__(self, window: int) -> None:
        self.window = window
        self.sent = 0
        self.resent = 0
        self._entries: deque[_Sent] = deque()
        self._acked: int | None = None
        self._hellos: deque[str] = deque()
        self._sessions: set[str] = set()

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def full(self) -> bool:
        return len(self._entries) >= self.window

    def record(self, seq: int, parts: list) -> None:
        self.sent += 1
        self._entries.append(_Sent(self.sent, seq, parts))

    def on_ack(self, seq: int) -> None:
        if self._acked is None or seq > self._acked:
            self._acked = seq

    def on_hello(self, session: str) -> None:
        self._hellos.append(session)

    def settle(self) -> list[str]:
        """Forget acknowledged frames; the sessions that said hello for the first time (each needs a resync)."""
        acked = self._acked
        while self._entries and acked is not None and self._entries[0].seq <= acked:
            self._entries.popleft()
        new = []
        while self._hellos:
            session = self._hellos.popleft()
            if session not in self._sessions:
                self._sessions.add(session)
                new.append(session)
        return new

    def unacknowledged(self) -> list[list]:
        """Message parts of every unacknowledged frame, oldest first (what a resync sends again)."""
        self.resent += len(self._entries)
        return [entry.parts for entry in self._entries]

    def done_through(self, count: int) -> bool:
        """Whether every frame up to send number `count` has been acknowledged."""
        return not self._entries or self._entries[0].count > count


class AckTracker:
    """Consumer side of one lossless input: frames taken, and when each is finished (see the module doc)."""

    def __init__(self) -> None:
        self._pending: deque[tuple[int, list[tuple[ResendBuffer, int]]]] = deque()
        self.last_taken: int | None = None
        self.last_acked: int | None = None

    def taken(self, seq: int, outputs: list[ResendBuffer]) -> None:
        """Frames up to `seq` were handled; they are finished once `outputs` have acknowledged what was sent."""
        self.last_taken = seq
        self._pending.append((seq, [(buffer, buffer.sent) for buffer in outputs]))

    def due(self) -> int | None:
        """The seq to acknowledge now, or None when nothing new is finished."""
        finished = None
        while self._pending and all(buffer.done_through(count) for buffer, count in self._pending[0][1]):
            finished = self._pending.popleft()[0]
        if finished is None:
            return None
        self.last_acked = finished
        return finished


class InputSync:
    """Consumer side, receive thread: discard until our resync marker, then drop duplicates by seq."""

    def __init__(self, session: str) -> None:
        self.session = session
        self.synced = False
        self.last_seq: int | None = None
        self.duplicates = 0
        self.reack = False  # a duplicate came: the producer is waiting for an acknowledgement we already sent

    def on_status(self, status: dict) -> None:
        if status.get("resync") == self.session:
            self.synced = True

    def accept(self, seq: int) -> bool:
        if not self.synced:
            return False
        if self.last_seq is not None and seq <= self.last_seq:
            self.duplicates += 1
            self.reack = True
            return False
        self.last_seq = seq
        return True
