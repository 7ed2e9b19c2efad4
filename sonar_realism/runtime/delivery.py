"""Per-input delivery policies: what a node does when frames arrive faster than it can use them.

- `latest`:   keep only the newest frame (live streams: a translator should work on what the sonar
              sees now, not on a backlog). Every frame pushed out is counted as dropped.
- `fifo`:     a bounded queue of `capacity` frames; when full the OLDEST is dropped and counted, so
              short bursts are absorbed and a long overload degrades to "recent frames".
- `lossless`: a bounded queue that never drops. When it is full the node stops reading the socket,
              and because lossless edges are PUSH/PULL (see node.py) the producer's send blocks:
              real backpressure, end to end, with memory bounded by `capacity` plus the socket HWMs.

Control items (end of stream) are never dropped by any policy. The queue is shared between the
node's receive thread and its processing thread, hence the condition variable.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Literal

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage

Policy = Literal["latest", "fifo", "lossless"]
POLICIES: tuple[str, ...] = ("latest", "fifo", "lossless")


@dataclass(frozen=True)
class InputPolicy:
    """How one input is delivered. `max_age_s` > 0 drops frames whose stamp is older than that when
    they are taken for processing (clocks of all hosts must agree; 0 disables the check)."""

    policy: Policy = "lossless"
    capacity: int = 8
    max_age_s: float = 0.0

    def validate(self) -> None:
        if self.policy not in POLICIES:
            raise ConfigError(f"policy: {self.policy!r} is not one of {', '.join(POLICIES)}")
        if self.capacity < 1:
            raise ConfigError(f"capacity: must be >= 1, got {self.capacity}")
        if self.max_age_s < 0:
            raise ConfigError(f"max_age_s: must be >= 0, got {self.max_age_s}")

    @property
    def effective_capacity(self) -> int:
        return 1 if self.policy == "latest" else self.capacity


# A seq further back than a network reorders frames, or further ahead than a stream drops them, is a source that
# started again (a simulator restarted at 0, a counter of its own): counted once as out of order and followed from
# there, instead of every later frame counting as late or a jump counting as a gap of billions.
REORDER_WINDOW = 64
MAX_GAP = 1 << 20


class SeqTracker:
    """Counts frames missing from a stream (gaps in `seq`) and frames arriving out of order."""

    def __init__(self) -> None:
        self.last: int | None = None
        self.gaps = 0
        self.out_of_order = 0

    def observe(self, seq: int) -> None:
        if self.last is not None and not self.last - REORDER_WINDOW <= seq <= self.last + 1 + MAX_GAP:
            self.out_of_order += 1
            self.last = seq
            return
        if self.last is not None:
            if seq > self.last + 1:
                self.gaps += seq - self.last - 1
            elif seq <= self.last:
                self.out_of_order += 1
                if seq < self.last:
                    return  # keep the high-water mark so a late frame does not create a false gap
        self.last = seq


@dataclass(frozen=True)
class EndOfStream:
    """Marks that the producer of an input will send no more frames."""

    reason: str = "finished"


class InputQueue:
    """Thread-safe queue implementing one InputPolicy, with counters for the status message."""

    def __init__(self, policy: InputPolicy) -> None:
        policy.validate()
        self.policy = policy
        self._items: deque[tuple[SonarImage, int] | EndOfStream] = deque()  # (frame, born_ns) or end of stream
        self._frames = 0
        self._cond = threading.Condition()
        self.received = 0
        self.dropped = 0
        self.stale = 0
        self.seq = SeqTracker()
        self.ended = False
        self.last_taken_seq: int | None = None  # newest frame taken out (handed on or dropped as stale)

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)

    def has_room(self) -> bool:
        """False only for a full lossless queue: the receiver must stop reading its socket."""
        with self._cond:
            return self.policy.policy != "lossless" or self._frames < self.policy.capacity

    def put(self, item: SonarImage | EndOfStream, born_ns: int | None = None) -> None:
        """Queue a frame (or end of stream). `born_ns` is when the frame was sent (wall clock, the header's
        `sent_ns`); without it, now. `max_age_s` counts from there, never from the acquisition stamp."""
        with self._cond:
            if isinstance(item, EndOfStream):
                if not self.ended:
                    self.ended = True
                    self._items.append(item)
                    self._cond.notify_all()
                return
            if self.ended:
                return  # a late duplicate after end of stream (e.g. a resent EOS race) is ignored
            self.received += 1
            self.seq.observe(item.seq)
            if self.policy.policy != "lossless":
                while self._frames >= self.policy.effective_capacity:
                    self._drop_oldest_frame()
            self._items.append((item, time.time_ns() if born_ns is None else born_ns))
            self._frames += 1
            self._cond.notify_all()

    def take(self, max_items: int, timeout_s: float = 0.0) -> list[SonarImage | EndOfStream]:
        """Up to `max_items` items in arrival order (stale frames removed and counted); waits at most
        `timeout_s` for the first one. An EndOfStream is always returned last and alone ends a batch."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while not self._items:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return []
                self._cond.wait(remaining)
            out: list[SonarImage | EndOfStream] = []
            now_ns = time.time_ns()
            while self._items and len(out) < max_items:
                item = self._items.popleft()
                if isinstance(item, EndOfStream):
                    out.append(item)
                    break
                self._frames -= 1
                frame, born_ns = item
                self.last_taken_seq = frame.seq
                if self._is_stale(born_ns, now_ns):
                    self.stale += 1
                    continue
                out.append(frame)
            self._cond.notify_all()
            return out

    def _drop_oldest_frame(self) -> None:
        for index, item in enumerate(self._items):
            if not isinstance(item, EndOfStream):
                del self._items[index]
                self._frames -= 1
                self.dropped += 1
                return

    def _is_stale(self, born_ns: int, now_ns: int) -> bool:
        max_age_s = self.policy.max_age_s
        return max_age_s > 0 and (now_ns - born_ns) > max_age_s * 1e9
