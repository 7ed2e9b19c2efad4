"""The node runtime: lifecycle, sockets, delivery policies, readiness, heartbeat, end of stream.

A node subclass declares PARAMS (a frozen config dataclass), INPUTS (name -> accepted topic types)
and OUTPUTS (name -> topic type), and overrides some of:
    configure()              load models, open files (before any socket exists)
    process(input, frames)   consumers: handle a batch of frames from one input
    produce() -> float|None  sources: publish what is due; seconds until the next call, None when done
    finish()                 after the last frame (end of stream or stop), before end of stream goes out
It calls `publish(output, frame, provenance)` and `record_inference(ms, n_frames)`.

Lifecycle of `run()`: configure -> bind outputs -> wait until every expected consumer is subscribed
-> connect inputs -> loop -> finish -> end of stream -> shutdown. While the node waits for news, its own
thread reads the inputs, so a frame that finds it idle is received, decoded and processed without a hand-over
between threads; while process() or produce() runs, a receive thread keeps draining inputs that drop
(`latest`, `fifo`) into the policy queues, so `latest` really is the newest frame even while the model runs,
and reads acknowledgements of lossless outputs. Other (lossless) inputs wait in their socket meanwhile.
The loop never blocks for more than `_TICK_S`; `request_stop()` (signal handlers, the launcher) ends it.
`shutdown()` is idempotent.

End of stream on the wire: a status message on the DATA topic with `end_of_stream: true`. On XPUB
outputs it is repeated until every subscriber has hung up (or `eos_linger_s`), because PUB may drop.
On lossless edges with an acknowledgement channel, frames survive a consumer crash (runtime/lossless.py):
end of stream goes out only once every frame has been acknowledged.

A frame the node cannot handle (process() raises FrameError, WireError or another ValueError for it) is
counted as `malformed` and logged with its topic and the reason, like a message that breaks the wire
format; the node goes on. Any other exception is a fault of the node and ends it (the launcher may
restart it).
"""

from __future__ import annotations

import gc
import logging
import os
import threading
import time
import uuid
from dataclasses import dataclass, field
from typing import Any, ClassVar

import zmq

from sonar_realism.errors import ConfigError, SonarRealismError, WireError
from sonar_realism.frames import SonarImage
from sonar_realism.runtime.delivery import EndOfStream, InputQueue
from sonar_realism.runtime.lossless import (
    AckTracker,
    InputSync,
    ResendBuffer,
    ack_message,
    hello_message,
    parse_control,
)
from sonar_realism.runtime.wiring import InputWiring, OutputWiring, Wiring
from sonar_realism.wire import FRAME_TYPE, STATUS_TYPE, decode_message, encode_frame, encode_status

log = logging.getLogger(__name__)

_TICK_S = 0.05  # longest any wait inside the loop may last: bounds the reaction time to a stop request
_EOS_RESEND_S = 0.1
_ROOM_POLL_S = 0.005  # how soon the receive thread looks again at a full queue while it also watches acks
_STATUS_SOON_S = 0.1  # after a rejection, the next status goes out this soon (counters survive a crash)
_WARN_FIRST = 20  # rejections logged one by one per input; after that every _WARN_EVERY-th
_WARN_EVERY = 1000
# What process() may raise about one frame (its content), as opposed to a fault of the node itself.
_FRAME_FAULTS = (SonarRealismError, ValueError)
_COUNTER_MAX = (1 << 64) - 1


def end_of_stream_message(topic: str, node: str, reason: str) -> list:
    return encode_status(topic, {"node": node, "state": "stopped", "end_of_stream": True, "reason": reason})


def resync_message(topic: str, node: str, session: str) -> list:
    return encode_status(topic, {"node": node, "state": "running", "resync": session})


@dataclass
class _Edge:
    """One lossless consumer of an output: its PUSH, and (in a launch) its acknowledgements."""

    push: zmq.Socket
    acks: zmq.Socket | None = None
    buffer: ResendBuffer | None = None


@dataclass
class _Output:
    wiring: OutputWiring
    xpub: zmq.Socket
    edges: list[_Edge]
    subscribers: int = 0


@dataclass
class _Input:
    """Receive-side state of one input besides its queue: the acknowledgement channel of a lossless edge."""

    wiring: InputWiring
    ack_socket: zmq.Socket | None = None   # owned by the main thread
    sync: InputSync | None = None          # used by the receive thread
    tracker: AckTracker = field(default_factory=AckTracker)
    rejected: int = 0                      # messages on this input counted as malformed
    other_topics: set[str] = field(default_factory=set)


class NodeStopped(SonarRealismError):
    """Raised inside publish() when a stop request arrives while waiting for a lossless consumer."""


class Node:
    PARAMS: ClassVar[type]
    INPUTS: ClassVar[dict[str, tuple[str, ...]]] = {}
    OUTPUTS: ClassVar[dict[str, str]] = {}
    BATCH_SIZE: ClassVar[int] = 1  # frames handed to process() at once; subclasses may set self.batch_size

    def __init__(self, name: str, params: Any, wiring: Wiring, context: zmq.Context | None = None) -> None:
        missing = sorted(set(self.INPUTS) - set(wiring.inputs)) + sorted(set(self.OUTPUTS) - set(wiring.outputs))
        unknown = sorted(set(wiring.inputs) - set(self.INPUTS)) + sorted(set(wiring.outputs) - set(self.OUTPUTS))
        if missing or unknown:
            raise ConfigError(f"node {name!r}: wiring does not match {type(self).__name__}: "
                              f"missing {missing or 'none'}, unknown {unknown or 'none'}")
        self.name = name
        self.params = params
        self.wiring = wiring
        self.batch_size = self.BATCH_SIZE
        self.context = context or zmq.Context.instance()
        self.queues = {input_name: InputQueue(w.policy) for input_name, w in wiring.inputs.items()}
        self.session = uuid.uuid4().hex[:16]  # this instance; a restarted node is a new session
        # set by the launcher before run(): an earlier session of this node in the same launch failed (a recorder
        # then goes on with what that session wrote)
        self.restarted = False
        self._inputs = {input_name: _Input(w) for input_name, w in wiring.inputs.items()}
        self.state = "starting"
        self.frames_out = 0
        self.malformed = 0
        self.other_topic = 0
        self._status_due = False
        self._last_status = 0.0
        self._count_lock = threading.Lock()
        self._inference_ms_total = 0.0
        self._inference_frames = 0
        self._status_seq = 0
        self._started = time.monotonic()
        self._stop = threading.Event()
        self._closing = threading.Event()  # ends the receive thread (shutdown), later than _stop
        self._wake = threading.Event()
        self._producers_ended = threading.Event()
        self._outputs: dict[str, _Output] = {}
        self._status_socket: zmq.Socket | None = None
        self._status_subscribers = 0
        self._pump: threading.Thread | None = None
        # Input and acknowledgement sockets, used by one thread at a time, the one holding _sockets_held: the
        # main thread inside _wait_for_news, the receive thread otherwise (while _sockets_lent is set); the main
        # thread alone where no receive thread is needed (_start_input_pump).
        self._receivers: dict[zmq.Socket, str] = {}
        self._ack_readers: dict[zmq.Socket, ResendBuffer] = {}
        self._sockets_lent = threading.Event()
        self._sockets_held = threading.Lock()
        self._interrupt_in: zmq.Socket | None = None   # in every poll of those sockets; _reclaim_sockets writes
        self._interrupt_out: zmq.Socket | None = None
        self._parent_pid = os.getppid()
        self._closed = False

    # ---- hooks -----------------------------------------------------------------------------------
    def configure(self) -> None:
        """Prepare everything that can fail before any socket exists (models, files)."""

    def process(self, input_name: str, frames: list[SonarImage]) -> None:
        raise NotImplementedError(f"{type(self).__name__} has inputs but no process()")

    def produce(self) -> float | None:
        """Sources only: publish what is due; return seconds until the next call, or None when finished."""
        return None

    def finish(self) -> None:
        """Called once after the last frame was handled, before end of stream is sent downstream."""

    # ---- API for subclasses ----------------------------------------------------------------------
    def publish(self, output: str, frame: SonarImage, provenance: dict | None = None) -> None:
        """Send `frame` on `output` to every consumer. Waits for lossless consumers (backpressure);
        raises NodeStopped if a stop request arrives while waiting."""
        out = self._outputs[output]
        parts = encode_frame(frame, out.wiring.topic, provenance)  # encode fully first: no half-sent message
        # One zmq message for the samples, shared by every socket they go to (and any resend): a zero-copy
        # message wakes pyzmq's garbage-collector thread, which takes the GIL, once when libzmq is done with it,
        # not once per socket. (Under zmq.COPY_THRESHOLD bytes it is one copy, not one per socket.)
        parts[2] = zmq.Frame(parts[2])
        for edge in out.edges:
            if edge.buffer is not None:
                self._settle_outputs()
                while edge.buffer.full:  # wait for acknowledgements: bounded memory, backpressure
                    if self.stop_requested:
                        raise NodeStopped(f"node {self.name!r}: stopped while waiting for acknowledgements")
                    self._wait_for_news(_TICK_S)
                    self._settle_outputs()
            self._send_waiting(edge.push, parts, stop_aware=True)
            if edge.buffer is not None:
                edge.buffer.record(frame.seq, parts)
        out.xpub.send_multipart(parts, copy=False, flags=zmq.NOBLOCK)
        self.frames_out += 1

    def record_inference(self, milliseconds: float, n_frames: int) -> None:
        self._inference_ms_total += milliseconds
        self._inference_frames += n_frames

    @property
    def stop_requested(self) -> bool:
        return self._stop.is_set()

    def producers_finished(self) -> None:
        """The launcher's word that every in-graph producer has exited: once such an input's socket is
        empty, nothing more can come, so it counts as ended even if its end of stream was lost (a
        restarted node misses the one that was in flight when it crashed). Thread- and signal-safe."""
        self._producers_ended.set()
        self._wake.set()

    def request_stop(self) -> None:
        """Ask the loop to end (thread- and signal-safe); the node still finishes and sends end of stream."""
        self._stop.set()
        self._wake.set()

    # ---- status ----------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        queues = self.queues.values()
        buffers = self._buffers()
        syncs = [i.sync for i in self._inputs.values() if i.sync is not None]
        counters = {
            "node": self.name,
            "state": self.state,
            "session": self.session,
            "seq": self._status_seq,
            "stamp_ns": time.time_ns(),
            "uptime_s": time.monotonic() - self._started,
            "frames_in": sum(q.received for q in queues),
            "frames_out": self.frames_out,
            "dropped": sum(q.dropped for q in queues),
            "stale": sum(q.stale for q in queues),
            "seq_gaps": sum(q.seq.gaps for q in queues),
            "out_of_order": sum(q.seq.out_of_order for q in queues),
            "malformed": self.malformed,
            "other_topic": self.other_topic,
            "duplicates": sum(s.duplicates for s in syncs),
            "resent": sum(b.resent for b in buffers),
            "unacked": sum(len(b) for b in buffers),
            "inference_ms": self._inference_ms_total / self._inference_frames if self._inference_frames else 0.0,
            "queued": {name: len(q) for name, q in self.queues.items()},
        }
        # a status the wire cannot carry would end the node: a counter past uint64 (sums of a client's wild seqs)
        # is reported at the largest value it can hold
        return {key: min(value, _COUNTER_MAX) if type(value) is int else value for key, value in counters.items()}

    def _send_status(self) -> None:
        if self._status_socket is None:
            return
        self._status_due = False
        self._last_status = time.monotonic()
        self._status_seq += 1
        try:
            self._status_socket.send_multipart(encode_status(f"{self.name}/status", self.status()),
                                               flags=zmq.NOBLOCK)
        except zmq.Again:
            pass  # nobody is reading status right now; heartbeats are best effort by design

    # ---- lifecycle -------------------------------------------------------------------------------
    def run(self) -> None:
        """configure -> run -> shutdown. Raises what configure/process/produce raise (after shutting down)."""
        try:
            self.configure()
            # A full collection walks every object alive; with torch and a model loaded that is ~180 000 objects
            # and ~0.1 s, a pause in the middle of the stream whenever it comes. What configure() made lives as
            # long as the node: frozen, it is left out of every collection.
            gc.collect()
            gc.freeze()
            self._open_outputs()
            self._send_status()
            try:
                self._wait_until_consumers_ready()
                self._start_input_pump()
                self.state = "running"
                self._send_status()
                self._loop()
            except NodeStopped:
                pass  # a stop request while waiting on a consumer: still finish and say end of stream
            self.state = "stopping"
            self.finish()
            self._send_end_of_stream("stopped" if self.stop_requested else "finished")
            self.state = "stopped"
        except BaseException:
            self.state = "error"
            raise
        finally:
            self.shutdown()

    def shutdown(self) -> None:
        """Close every socket; safe to call any number of times, from the node's own thread."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._closing.set()
        if self._pump is not None:
            self._interrupt_out.send(b"", zmq.NOBLOCK)
            self._pump.join(timeout=5.0)
            self._interrupt_in.close(linger=0)
            self._interrupt_out.close(linger=0)
        for sock in self._receivers:
            sock.close(linger=0)
        self._send_status()
        for out in self._outputs.values():
            out.xpub.close(linger=0)
            for edge in out.edges:
                edge.push.close(linger=int(self.wiring.eos_linger_s * 1000))
                if edge.acks is not None:
                    edge.acks.close(linger=0)
        for state in self._inputs.values():
            if state.ack_socket is not None:
                state.ack_socket.close(linger=int(self.wiring.eos_linger_s * 1000))
        if self._status_socket is not None:
            self._status_socket.close(linger=200)

    def _open_outputs(self) -> None:
        for name, w in self.wiring.outputs.items():
            xpub = self.context.socket(zmq.XPUB)
            xpub.setsockopt(zmq.XPUB_VERBOSER, 1)  # every (un)subscription, so subscribers can be counted
            xpub.sndhwm = w.hwm
            xpub.linger = 0
            xpub.bind(w.pub_endpoint)
            edges = []
            for index, endpoint in enumerate(w.push_endpoints):
                edge = _Edge(self.context.socket(zmq.PUSH))
                edge.push.sndhwm = w.hwm
                edge.push.bind(endpoint)
                if index < len(w.ack_endpoints):
                    edge.acks = self.context.socket(zmq.PULL)
                    edge.acks.linger = 0
                    edge.acks.bind(w.ack_endpoints[index])
                    edge.buffer = ResendBuffer(window=4 * w.hwm)
                edges.append(edge)
            self._outputs[name] = _Output(w, xpub, edges)
        if self.wiring.status_endpoint:
            self._status_socket = self.context.socket(zmq.XPUB)
            self._status_socket.setsockopt(zmq.XPUB_VERBOSER, 1)
            self._status_socket.bind(self.wiring.status_endpoint)

    def _wait_until_consumers_ready(self) -> None:
        deadline = time.monotonic() + self.wiring.ready_timeout_s
        while not self._consumers_ready():
            if self.stop_requested:
                raise NodeStopped(f"node {self.name!r}: stopped while waiting for consumers")
            if time.monotonic() > deadline:
                raise SonarRealismError(f"node {self.name!r}: consumers not subscribed after "
                                        f"{self.wiring.ready_timeout_s} s: {self._readiness_text()}")
            self._service_subscriptions(_TICK_S)

    def _consumers_ready(self) -> bool:
        return (all(o.subscribers >= o.wiring.expected_subscribers for o in self._outputs.values())
                and self._status_subscribers >= self.wiring.status_subscribers)

    def _readiness_text(self) -> str:
        parts = [f"{n}: {o.subscribers}/{o.wiring.expected_subscribers}" for n, o in self._outputs.items()]
        parts.append(f"status: {self._status_subscribers}/{self.wiring.status_subscribers}")
        return ", ".join(parts)

    def _service_subscriptions(self, timeout_s: float) -> None:
        """Read (un)subscription notices from every XPUB and keep the subscriber counts."""
        poller = zmq.Poller()
        sockets = {o.xpub: o for o in self._outputs.values()}
        for sock in sockets:
            poller.register(sock, zmq.POLLIN)
        if self._status_socket is not None:
            poller.register(self._status_socket, zmq.POLLIN)
        if not sockets and self._status_socket is None:
            self._stop.wait(timeout_s)
            return
        for sock, _ in poller.poll(timeout_s * 1000):
            while True:
                try:
                    notice = sock.recv(zmq.NOBLOCK)
                except zmq.Again:
                    break
                delta = {1: 1, 0: -1}.get(notice[0], 0) if notice else 0
                if sock is self._status_socket:
                    self._status_subscribers += delta
                else:
                    sockets[sock].subscribers += delta

    def _start_input_pump(self) -> None:
        for state in self._inputs.values():
            if state.wiring.ack_endpoint:
                state.ack_socket = self.context.socket(zmq.PUSH)
                state.ack_socket.connect(state.wiring.ack_endpoint)
                state.ack_socket.send(hello_message(self.session))  # queued until the producer is there
                state.sync = InputSync(self.session)
        for input_name, w in self.wiring.inputs.items():
            sock = self.context.socket(zmq.PULL if w.socket_kind == "pull" else zmq.SUB)
            sock.linger = 0
            sock.rcvhwm = max(2, w.policy.capacity)
            if w.socket_kind == "sub":
                # An external publisher is heard on every topic, so frames on a topic nobody takes (a typo
                # in the simulator's topic) are counted and reported instead of vanishing in the filter.
                sock.setsockopt(zmq.SUBSCRIBE, w.topic.encode() if w.in_graph else b"")
            sock.connect(w.endpoint)
            self._receivers[sock] = input_name
        self._ack_readers = {e.acks: e.buffer for o in self._outputs.values() for e in o.edges
                             if e.acks is not None and e.buffer is not None}
        # A receive thread reads while process()/produce() runs only where that is needed: an input that drops
        # (`latest`, `fifo`) must count its drops as they happen and keep the newest frame, and acknowledgements
        # must be heard promptly (a restarted consumer waits for its resync; acknowledged frames leave the resend
        # buffer). Lossless inputs need none: their frames wait in the socket while the model runs
        # (backpressure, as a full queue).
        drops = any(w.policy.policy != "lossless" for w in self.wiring.inputs.values())
        if self._ack_readers or (self._receivers and drops):
            endpoint = f"inproc://{self.name}-{self.session}-interrupt"
            self._interrupt_in = self.context.socket(zmq.PAIR)
            self._interrupt_in.bind(endpoint)
            self._interrupt_out = self.context.socket(zmq.PAIR)
            self._interrupt_out.connect(endpoint)
            self._pump = threading.Thread(target=self._pump_inputs, name=f"{self.name}-inputs", daemon=True)
            self._sockets_held.acquire()
            self._lend_sockets()
            self._pump.start()

    def _buffers(self) -> list[ResendBuffer]:
        return [e.buffer for o in self._outputs.values() for e in o.edges if e.buffer is not None]

    def _settle_outputs(self) -> None:
        """Producer side: forget acknowledged frames; a consumer that (re)started gets a resync marker and
        every unacknowledged frame again, before anything new (main thread)."""
        for out in self._outputs.values():
            for edge in out.edges:
                if edge.buffer is None:
                    continue
                for session in edge.buffer.settle():
                    pending = edge.buffer.unacknowledged()
                    if pending:
                        log.warning("node %s: consumer session %s on %s: sending %d unacknowledged frame(s) again",
                                    self.name, session, out.wiring.topic, len(pending))
                    self._send_waiting(edge.push, resync_message(out.wiring.topic, self.name, session),
                                       stop_aware=False)
                    for parts in pending:
                        self._send_waiting(edge.push, parts, stop_aware=False)

    def _send_acks(self) -> None:
        """Consumer side: acknowledge what is finished (main thread)."""
        for state in self._inputs.values():
            if state.ack_socket is None:
                continue
            seq = state.tracker.due()
            if seq is None and state.sync is not None and state.sync.reack:
                state.sync.reack = False
                seq = state.tracker.last_acked
            if seq is not None:
                try:
                    state.ack_socket.send(ack_message(seq), flags=zmq.NOBLOCK)
                except zmq.Again:
                    pass  # acknowledgements are cumulative: the next one covers this

    def _wait_for_news(self, timeout_s: float) -> None:
        """Wait until something arrives (a frame, an acknowledgement) or `timeout_s`, reading the input and
        acknowledgement sockets on this thread meanwhile: a frame that finds the node idle is received,
        decoded and processed here, with no hand-over between threads. Outside this wait (while process()
        or produce() runs) the receive thread reads them, where there is one (_start_input_pump)."""
        if not (self._receivers or self._ack_readers):
            self._wake.wait(timeout_s)
        elif self._pump is None:
            if not self._wake.is_set():
                self._receive(timeout_s)
        else:
            self._reclaim_sockets()
            try:
                if not self._wake.is_set():  # the receive thread may have queued something as it let go
                    self._receive(timeout_s)
            finally:
                self._lend_sockets()
        self._wake.clear()

    def _lend_sockets(self) -> None:
        """Hand the input and acknowledgement sockets to the receive thread (main thread; cheap)."""
        self._sockets_held.release()
        self._sockets_lent.set()

    def _reclaim_sockets(self) -> None:
        """Take the sockets back: cut the receive thread's poll short and wait until it has let go (zmq sockets
        may change threads; the lock is the memory barrier that requires)."""
        self._sockets_lent.clear()
        self._interrupt_out.send(b"", zmq.NOBLOCK)
        self._sockets_held.acquire()
        while self._interrupt_in.poll(0):  # a cut the receive thread did not see must not cut our own poll short
            self._interrupt_in.recv()

    def _loop(self) -> None:
        next_produce = time.monotonic() if not self.INPUTS else None
        next_heartbeat = time.monotonic() + self.wiring.heartbeat_s
        while not self.stop_requested:
            now = time.monotonic()
            if now >= next_heartbeat or (self._status_due and now - self._last_status >= _STATUS_SOON_S):
                self._send_status()
                next_heartbeat = now + self.wiring.heartbeat_s
            self._settle_outputs()
            self._send_acks()
            if self.wiring.exit_with_parent and os.getppid() != self._parent_pid:
                log.warning("node %s: launcher is gone, stopping", self.name)
                self.request_stop()
            busy = False
            if next_produce is not None and now >= next_produce:
                delay = self.produce()
                if delay is None:
                    return
                next_produce = time.monotonic() + max(0.0, delay)
                busy = delay <= 0
            if self.INPUTS:
                busy = self._handle_inputs() or busy
                if all(q.ended and len(q) == 0 for q in self.queues.values()):
                    return
            if busy:
                continue
            now = time.monotonic()
            wait = max(0.0, min(_TICK_S, next_heartbeat - now))
            if self._status_due:
                wait = min(wait, _STATUS_SOON_S)
            if next_produce is not None:
                self._service_subscriptions(max(0.0, min(wait, next_produce - now)))
            else:
                self._wait_for_news(wait)

    def _handle_inputs(self) -> bool:
        handled = False
        for input_name, queue in self.queues.items():
            items = queue.take(self.batch_size)
            frames = [item for item in items if isinstance(item, SonarImage)]
            if frames:
                self._process_guarded(input_name, frames)
                handled = True
            state = self._inputs[input_name]
            if state.ack_socket is not None and queue.last_taken_seq not in (None, state.tracker.last_taken):
                state.tracker.taken(queue.last_taken_seq, self._buffers())
        return handled

    def _process_guarded(self, input_name: str, frames: list[SonarImage]) -> None:
        """process(); a frame it cannot handle is rejected alone (a batch is retried frame by frame, so
        process() must publish only once its whole batch succeeded)."""
        try:
            self.process(input_name, frames)
            return
        except _FRAME_FAULTS as error:
            if len(frames) == 1:
                self._reject(input_name, f"frame seq {frames[0].seq} cannot be processed: {error}")
                return
        for frame in frames:
            try:
                self.process(input_name, [frame])
            except _FRAME_FAULTS as error:
                self._reject(input_name, f"frame seq {frame.seq} cannot be processed: {error}")

    def _reject(self, input_name: str, reason: str) -> None:
        """Count one malformed message (receive thread) or unprocessable frame (main thread)."""
        with self._count_lock:
            self.malformed += 1
        self._status_due = True
        state = self._inputs[input_name]
        state.rejected += 1
        if state.rejected <= _WARN_FIRST or state.rejected % _WARN_EVERY == 0:
            log.warning("node %s: input %s (topic %r): rejected (%d so far on this input): %s", self.name,
                        input_name, state.wiring.topic, state.rejected, reason)

    def _send_end_of_stream(self, reason: str) -> None:
        self._send_acks()
        self._await_acknowledgements()
        for out in self._outputs.values():
            message = end_of_stream_message(out.wiring.topic, self.name, reason)
            for edge in out.edges:
                self._send_waiting(edge.push, message, stop_aware=False)
        # In-graph SUB consumers hang up when they see end of stream; resend until they all have (PUB may
        # drop under load). Subscribers from outside the graph are not waited for.
        deadline = time.monotonic() + self.wiring.eos_linger_s
        self._service_subscriptions(0)
        targets = {id(o): max(0, o.subscribers - o.wiring.expected_subscribers) for o in self._outputs.values()}
        pending = list(self._outputs.values())
        while pending:
            for out in pending:
                try:
                    out.xpub.send_multipart(end_of_stream_message(out.wiring.topic, self.name, reason),
                                            flags=zmq.NOBLOCK)
                except zmq.Again:
                    pass
            pending = [o for o in pending if o.subscribers > targets[id(o)]]
            if not pending or time.monotonic() > deadline:
                return
            self._service_subscriptions(_EOS_RESEND_S)

    def _await_acknowledgements(self) -> None:
        """Before end of stream: every frame acknowledged, resending to consumers that restart meanwhile
        (up to ready_timeout_s: a restarted consumer has to load its model again). A stop request ends the
        wait: what is in flight still arrives unless a consumer crashes now."""
        deadline = time.monotonic() + self.wiring.ready_timeout_s
        while not self.stop_requested:
            self._settle_outputs()
            self._send_acks()
            unacked = sum(len(b) for b in self._buffers())
            if not unacked:
                return
            if time.monotonic() > deadline:
                log.error("node %s: %d frame(s) never acknowledged by a lossless consumer; giving up on them",
                          self.name, unacked)
                return
            self._wait_for_news(_TICK_S)

    def _send_waiting(self, sock: zmq.Socket, parts: list, stop_aware: bool) -> None:
        """Send on a PUSH, waiting (in short polls) until the consumer has room."""
        deadline = time.monotonic() + self.wiring.eos_linger_s
        while True:
            try:
                sock.send_multipart(parts, copy=False, flags=zmq.NOBLOCK)
                return
            except zmq.Again:
                if stop_aware and self.stop_requested:
                    raise NodeStopped(f"node {self.name!r}: stopped while a lossless consumer was full") from None
                if not stop_aware and time.monotonic() > deadline:
                    log.warning("node %s: a lossless consumer did not take end of stream", self.name)
                    return
                sock.poll(_TICK_S * 1000, zmq.POLLOUT)

    # ---- receive thread --------------------------------------------------------------------------
    def _pump_inputs(self) -> None:
        """The receive thread: reads the inputs into the policy queues (until a stop request, or every input
        ended) and hands acknowledgements to the resend buffers (until shutdown: a stopping node still waits
        for its consumers' acknowledgements), whenever the main thread has lent it the sockets."""
        while not self._closing.is_set():
            if not self._sockets_lent.wait(_TICK_S):
                continue
            with self._sockets_held:  # lent may be taken back meanwhile: then this block ends at once
                while self._sockets_lent.is_set() and not self._closing.is_set():
                    self._receive(_TICK_S)

    def _receive(self, timeout_s: float) -> None:
        """One poll of the inputs and acknowledgement sockets (at most `timeout_s`), handling what is there;
        run by whichever thread holds the sockets."""
        # (zmq_poll on a list built here: a zmq.Poller, its registrations and the dict of its answer cost more,
        # on every wait of the loop)
        watched = [] if self._interrupt_in is None else [(self._interrupt_in, zmq.POLLIN)]
        waiting_for_room = False
        if not self._stop.is_set():
            for sock, input_name in self._receivers.items():
                if self.queues[input_name].has_room():
                    watched.append((sock, zmq.POLLIN))
                else:
                    waiting_for_room = True
        watched += [(sock, zmq.POLLIN) for sock in self._ack_readers]
        # A full queue frees up without any socket event: look again soon.
        wait_s = min(timeout_s, _ROOM_POLL_S) if waiting_for_room else timeout_s
        readable = {sock for sock, _ in zmq.zmq_poll(watched, int(wait_s * 1000))}
        if self._interrupt_in is not None and self._interrupt_in in readable:
            while self._interrupt_in.poll(0):
                self._interrupt_in.recv()
        for sock, buffer in self._ack_readers.items():
            if sock in readable:
                self._read_acknowledgements(sock, buffer)
        for sock, input_name in list(self._receivers.items()):
            w, queue = self.wiring.inputs[input_name], self.queues[input_name]
            if sock in readable:
                self._drain(sock, input_name)
            elif w.in_graph and self._producers_ended.is_set() and queue.has_room() and not sock.poll(0):
                queue.put(EndOfStream("producers ended"))
                self._wake.set()
            if queue.ended:
                sock.close(linger=0)  # hanging up tells an XPUB producer we got end of stream
                del self._receivers[sock]

    def _read_acknowledgements(self, sock: zmq.Socket, buffer: ResendBuffer) -> None:
        while True:
            try:
                control = parse_control(sock.recv(zmq.NOBLOCK))
            except zmq.Again:
                break
            if control is None:
                continue
            kind, value = control
            if kind == "ack":
                buffer.on_ack(value)
            else:
                buffer.on_hello(value)
        self._wake.set()

    def _drain(self, sock: zmq.Socket, input_name: str) -> None:
        queue, state = self.queues[input_name], self._inputs[input_name]
        # EVENTS rather than a recv that raises zmq.Again: after handing a frame over, this thread should get
        # back to its poll (which lets the processing thread have the GIL) as soon as it can.
        while queue.has_room() and not queue.ended and sock.get(zmq.EVENTS) & zmq.POLLIN:
            try:
                parts = sock.recv_multipart(flags=zmq.NOBLOCK, copy=False)
            except zmq.Again:
                return
            try:
                message = decode_message(parts)
            except WireError as error:
                if state.wiring.socket_kind == "sub" and error.topic not in (None, state.wiring.topic):
                    # an external publisher is heard on every topic: its own traffic on another (telemetry in a
                    # format of its own) is not ours to judge
                    self._count_other_topic(input_name, error.topic)
                else:
                    self._reject(input_name, f"malformed message: {error}")
                continue
            if message.topic != state.wiring.topic:
                if message.kind == FRAME_TYPE:
                    self._count_other_topic(input_name, message.topic)
                continue
            if message.kind == FRAME_TYPE:
                if state.sync is not None and not state.sync.accept(message.body.seq):
                    continue  # before our resync marker (it comes again after it), or a duplicate
                queue.put(message.body, message.sent_ns)
            elif message.kind == STATUS_TYPE:
                if state.sync is not None:
                    state.sync.on_status(message.body)
                if message.body.get("end_of_stream"):
                    queue.put(EndOfStream(str(message.body.get("reason", "finished"))))
            self._wake.set()

    def _count_other_topic(self, input_name: str, topic: str) -> None:
        self.other_topic += 1
        self._status_due = True
        state = self._inputs[input_name]
        if topic not in state.other_topics and len(state.other_topics) < _WARN_FIRST:
            state.other_topics.add(topic)
            log.warning("node %s: input %s takes topic %r only; frames on topic %r are ignored (counted as "
                        "other_topic)", self.name, input_name, state.wiring.topic, topic)


class TimedSourceNode(Node):
    """A source node over a timed source (runtime/sources.py): `configure` sets `self.source`, whose `next()`
    hands out `(due, message per output, in OUTPUTS order)` or None when finished; each item is published on
    every output once `time.monotonic()` reaches `due`."""

    source: Any
    _due_item: tuple | None = None

    def produce(self) -> float | None:
        if self._due_item is None:
            self._due_item = self.source.next()
            if self._due_item is None:
                return None
        due, *messages = self._due_item
        wait = due - time.monotonic()
        if wait > 0:
            return wait
        for output, message in zip(self.OUTPUTS, messages, strict=True):
            self.publish(output, message)
        self._due_item = None
        return 0.0
