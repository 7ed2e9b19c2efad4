"""The node runtime: lifecycle, sockets, delivery policies, readiness, heartbeat, end of stream.

A node subclass declares PARAMS (a frozen config dataclass), INPUTS (name -> accepted topic types)
and OUTPUTS (name -> topic type), and overrides some of:
    configure()              load models, open files (before any socket exists)
    process(input, frames)   consumers: handle a batch of frames from one input
    produce() -> float|None  sources: publish what is due; seconds until the next call, None when done
    finish()                 after the last frame (end of stream or stop), before end of stream goes out
It calls `publish(output, frame, provenance)` and `record_inference(ms, n_frames)`.

Lifecycle of `run()`: configure -> bind outputs -> wait until every expected consumer is subscribed
-> connect inputs (a receive thread keeps draining them into the policy queues, so `latest` really is
the newest frame even while the model runs) -> loop -> finish -> end of stream -> shutdown.
The loop never blocks for more than `_TICK_S`; `request_stop()` (signal handlers, the launcher) ends it.
`shutdown()` is idempotent.

End of stream on the wire: a status message on the DATA topic with `end_of_stream: true`. On XPUB
outputs it is repeated until every subscriber has hung up (or `eos_linger_s`), because PUB may drop.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from dataclasses import dataclass
from typing import Any, ClassVar

import zmq

from sonar_realism.errors import ConfigError, SonarRealismError, WireError
from sonar_realism.frames import SonarImage
from sonar_realism.runtime.delivery import EndOfStream, InputQueue
from sonar_realism.runtime.wiring import InputWiring, OutputWiring, Wiring
from sonar_realism.wire import FRAME_TYPE, STATUS_TYPE, decode_message, encode_frame, encode_status

log = logging.getLogger(__name__)

_TICK_S = 0.05  # longest any wait inside the loop may last: bounds the reaction time to a stop request
_EOS_RESEND_S = 0.1


def end_of_stream_message(topic: str, node: str, reason: str) -> list:
    return encode_status(topic, {"node": node, "state": "stopped", "end_of_stream": True, "reason": reason})


@dataclass
class _Output:
    wiring: OutputWiring
    xpub: zmq.Socket
    pushes: list[zmq.Socket]
    subscribers: int = 0


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
        self.state = "starting"
        self.frames_out = 0
        self.malformed = 0
        self._inference_ms_total = 0.0
        self._inference_frames = 0
        self._status_seq = 0
        self._started = time.monotonic()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._producers_ended = threading.Event()
        self._outputs: dict[str, _Output] = {}
        self._status_socket: zmq.Socket | None = None
        self._status_subscribers = 0
        self._pump: threading.Thread | None = None
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
        for push in out.pushes:
            self._send_waiting(push, parts, stop_aware=True)
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
        return {
            "node": self.name,
            "state": self.state,
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
            "inference_ms": self._inference_ms_total / self._inference_frames if self._inference_frames else 0.0,
            "queued": {name: len(q) for name, q in self.queues.items()},
        }

    def _send_status(self) -> None:
        if self._status_socket is None:
            return
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
        if self._pump is not None:
            self._pump.join(timeout=5.0)
        self._send_status()
        for out in self._outputs.values():
            out.xpub.close(linger=0)
            for push in out.pushes:
                push.close(linger=int(self.wiring.eos_linger_s * 1000))
        if self._status_socket is not None:
            self._status_socket.close(linger=200)

    def _open_outputs(self) -> None:
        for name, w in self.wiring.outputs.items():
            xpub = self.context.socket(zmq.XPUB)
            xpub.setsockopt(zmq.XPUB_VERBOSER, 1)  # every (un)subscription, so subscribers can be counted
            xpub.sndhwm = w.hwm
            xpub.linger = 0
            xpub.bind(w.pub_endpoint)
            pushes = []
            for endpoint in w.push_endpoints:
                push = self.context.socket(zmq.PUSH)
                push.sndhwm = w.hwm
                push.bind(endpoint)
                pushes.append(push)
            self._outputs[name] = _Output(w, xpub, pushes)
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
        if self.wiring.inputs:
            self._pump = threading.Thread(target=self._pump_inputs, name=f"{self.name}-inputs", daemon=True)
            self._pump.start()

    def _loop(self) -> None:
        next_produce = time.monotonic() if not self.INPUTS else None
        next_heartbeat = time.monotonic() + self.wiring.heartbeat_s
        while not self.stop_requested:
            now = time.monotonic()
            if now >= next_heartbeat:
                self._send_status()
                next_heartbeat = now + self.wiring.heartbeat_s
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
            if next_produce is not None:
                self._service_subscriptions(max(0.0, min(wait, next_produce - now)))
            else:
                self._wake.wait(wait)
                self._wake.clear()

    def _handle_inputs(self) -> bool:
        handled = False
        for input_name, queue in self.queues.items():
            items = queue.take(self.batch_size)
            frames = [item for item in items if isinstance(item, SonarImage)]
            if frames:
                self.process(input_name, frames)
                handled = True
        return handled

    def _send_end_of_stream(self, reason: str) -> None:
        for out in self._outputs.values():
            message = end_of_stream_message(out.wiring.topic, self.name, reason)
            for push in out.pushes:
                self._send_waiting(push, message, stop_aware=False)
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
        """Owns the input sockets: drains them into the policy queues until stop or every input ended."""
        sockets: dict[zmq.Socket, tuple[str, InputWiring]] = {}
        try:
            for input_name, w in self.wiring.inputs.items():
                sock = self.context.socket(zmq.PULL if w.socket_kind == "pull" else zmq.SUB)
                sock.linger = 0
                sock.rcvhwm = max(2, w.policy.capacity)
                if w.socket_kind == "sub":
                    sock.setsockopt(zmq.SUBSCRIBE, w.topic.encode())
                sock.connect(w.endpoint)
                sockets[sock] = (input_name, w)
            while not self._stop.is_set() and sockets:
                poller = zmq.Poller()
                for sock, (input_name, _) in sockets.items():
                    if self.queues[input_name].has_room():
                        poller.register(sock, zmq.POLLIN)
                if not poller.sockets:
                    next(iter(self.queues.values())).wait_for_room(_TICK_S)
                    continue
                readable = dict(poller.poll(_TICK_S * 1000))
                for sock, (input_name, w) in list(sockets.items()):
                    queue = self.queues[input_name]
                    if sock in readable:
                        self._drain(sock, input_name, w)
                    elif (w.in_graph and self._producers_ended.is_set() and queue.has_room()
                          and not sock.poll(0)):
                        queue.put(EndOfStream("producers ended"))
                        self._wake.set()
                    if queue.ended:
                        sock.close(linger=0)  # hanging up tells an XPUB producer we got end of stream
                        del sockets[sock]
        finally:
            for sock in sockets:
                sock.close(linger=0)

    def _drain(self, sock: zmq.Socket, input_name: str, w: InputWiring) -> None:
        queue = self.queues[input_name]
        while queue.has_room() and not queue.ended:
            try:
                parts = sock.recv_multipart(flags=zmq.NOBLOCK, copy=False)
            except zmq.Again:
                return
            try:
                topic, kind, body = decode_message(parts)
            except WireError as error:
                self.malformed += 1
                log.warning("node %s: input %s: malformed message: %s", self.name, input_name, error)
                continue
            if topic != w.topic:
                continue  # SUB matches prefixes; "sim/frames2" is not our "sim/frames"
            if kind == FRAME_TYPE:
                queue.put(body)
            elif kind == STATUS_TYPE and body.get("end_of_stream"):
                queue.put(EndOfStream(str(body.get("reason", "finished"))))
            self._wake.set()
