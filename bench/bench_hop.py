"""Where a pipeline hop's time goes: wall-clock stamps along bench_pipeline's latency trip, step by step.

    python bench/bench_hop.py [--frames N] [--transports ipc,tcp]    (or: bench/run.py hop)

The trip is bench_pipeline's (this process is the source and the receiver; the shipped translator node in its own
process, n = 1, batch 1, lossless edges, one frame in flight). Stamps are CLOCK_REALTIME, which all processes of
a host share. The node's are taken by wrapping, in the node process only, what its loop calls: zmq's poll,
recv_multipart and send_multipart, and the node module's decode_message and encode_frame; they come back in the
output's provenance (the output's own send steps one frame late). One row per step, p50 / p90 / p99 in µs:

- in leg (source encode start -> the model starts): `source encode`, `source send` (send_multipart returns),
  `in transit` (send returned -> the node's poll wakes: both I/O threads, the kernel, the node waking, and the
  node finishing its previous publish if it had not yet), `node recv`, `node decode` (with its NaN/inf pass,
  also shown alone), `node queue -> process()` (the policy queue and the loop), `process() -> model`.
- out leg (the model ends -> decoded here): `node post` (provenance, relabelling), `node encode`,
  `node zmq.Frame` (the zero-copy message), `node PUSH send`, `node XPUB send`, `out transit` (PUSH send
  returned -> our poll wakes; negative when the frame got here before the node's send call returned),
  `receiver recv`, `receiver decode`.
- `overhead` = the whole trip minus the model, as bench_pipeline's.
Goal (issue #14): overhead <= 2 ms at p99.
"""

# No `from __future__ import annotations`: bench/run.py loads this file without putting it in sys.modules, and
# dataclasses cannot resolve string annotations of such a module.
import argparse
import gc
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import zmq

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import bench_pipeline as pipeline  # noqa: E402  (sets the passive thread-pool policy before torch loads)

from sonar_realism.frames import SonarImage  # noqa: E402
from sonar_realism.wire import decode_message, encode_frame  # noqa: E402

DEFAULT_FRAMES = 100
WARMUP = 3
_STAMPS: dict[str, int] = {}    # node process: this frame's in-leg stamps
_SENDING: dict[str, int] = {}   # node process: the last output's send stamps


def _stamp_node_calls() -> None:
    """In the node process: stamp the steps of the node's loop (see the module docstring)."""
    import sonar_realism.frames as frames
    import sonar_realism.runtime.node as node_module

    poll, recv, send = zmq.zmq_poll, zmq.Socket.recv_multipart, zmq.Socket.send_multipart
    decode, encode, all_finite = node_module.decode_message, node_module.encode_frame, frames.all_finite

    def stamped_poll(*args: Any, **kwargs: Any) -> Any:
        ready = poll(*args, **kwargs)
        if ready and "poll" not in _STAMPS:
            _STAMPS["poll"] = time.time_ns()
        return ready

    def stamped_recv(self: zmq.Socket, *args: Any, **kwargs: Any) -> list:
        parts = recv(self, *args, **kwargs)
        _STAMPS["recv"] = time.time_ns()
        return parts

    def stamped_decode(parts: list) -> Any:
        message = decode(parts)
        _STAMPS["decode"] = time.time_ns()
        return message

    def timed_all_finite(values: np.ndarray) -> bool:
        start = time.time_ns()
        finite = all_finite(values)
        _STAMPS.setdefault("finite_ns", time.time_ns() - start)  # the input's (the model's output is checked too)
        return finite

    def stamped_encode(*args: Any, **kwargs: Any) -> list:
        _SENDING["encode_start"] = time.time_ns()
        parts = encode(*args, **kwargs)
        _SENDING["encode"] = time.time_ns()
        return parts

    def stamped_send(self: zmq.Socket, parts: list, *args: Any, **kwargs: Any) -> None:
        if len(parts) == 3 and isinstance(parts[2], zmq.Frame):  # a frame the node publishes
            _SENDING.setdefault("frame", time.time_ns())  # the data part is a zmq.Frame by now
        send(self, parts, *args, **kwargs)
        if len(parts) == 3:
            _SENDING["push" if self.socket_type == zmq.PUSH else "xpub"] = time.time_ns()

    zmq.zmq_poll, zmq.Socket.recv_multipart, zmq.Socket.send_multipart = stamped_poll, stamped_recv, stamped_send
    node_module.decode_message, node_module.encode_frame = stamped_decode, stamped_encode
    frames.all_finite = timed_all_finite


class _StampingStage(pipeline.ComputeStampingStage):
    def __call__(self, frames: list[SonarImage]) -> list[SonarImage]:
        outputs = super().__call__(frames)
        for output in outputs:
            output.meta["provenance"].update(hop_in=dict(_STAMPS), hop_out_previous=dict(_SENDING))
        _STAMPS.clear()
        _SENDING.clear()
        return outputs


class HopStampingTranslatorNode(pipeline.TranslatorNode):
    """bench_pipeline's translator node, with the stamps of this module in every output's provenance."""

    def configure(self) -> None:
        _stamp_node_calls()
        super().configure()
        self.stage = _StampingStage(self.stage)

    def process(self, input_name: str, frames: list[SonarImage]) -> None:
        _STAMPS["process"] = time.time_ns()
        super().process(input_name, frames)


def trip(node: pipeline.TranslatorProcess, frame: SonarImage) -> tuple[dict[str, float], dict, dict[str, int]]:
    """One frame there and back: this trip's steps (ns), the node's stamps, our receive stamps."""
    start = time.time_ns()
    parts = encode_frame(frame, pipeline.TOPIC_IN)
    encoded = time.time_ns()
    node.source.send_multipart(parts, copy=False)
    sent = time.time_ns()
    if not node.sink.poll(pipeline.RECV_TIMEOUT_S * 1000):
        raise RuntimeError(f"{node.transport}: no output; node log:\n{node.log_tail()}")
    woke = time.time_ns()
    received = node.sink.recv_multipart(copy=False)
    got = time.time_ns()
    message = decode_message(received)
    decoded = time.time_ns()
    provenance = message.body.meta["provenance"]
    if provenance["input_seq"] != frame.seq:
        raise RuntimeError(f"{node.transport}: output of seq {provenance['input_seq']}, expected {frame.seq}")
    stamps = provenance["hop_in"]
    model_start = provenance["compute_start_ns"]
    model_end = model_start + provenance["compute_ms"] * 1e6
    steps = {
        "source encode": encoded - start, "source send": sent - encoded, "in transit": stamps["poll"] - sent,
        "node recv": stamps["recv"] - stamps["poll"], "node decode": stamps["decode"] - stamps["recv"],
        "  of which the NaN/inf pass": stamps["finite_ns"],
        "node queue -> process()": stamps["process"] - stamps["decode"],
        "process() -> model": model_start - stamps["process"], "node post": message.sent_ns - model_end,
        "receiver recv": got - woke, "receiver decode": decoded - got,
        "in leg": model_start - start, "out leg": decoded - message.sent_ns,
        "overhead": decoded - start - provenance["compute_ms"] * 1e6,
    }
    return steps, provenance["hop_out_previous"], {"woke": woke}


def measure(transport: str, frames: int, pool: list[SonarImage], context: zmq.Context, folder: Path) -> list[dict]:
    node = pipeline.start_translator(context, transport, 1, folder, "cpu", "bench_hop:HopStampingTranslatorNode")
    feed = pipeline.FrameFeed(pool)
    rows: list[dict[str, float]] = []
    try:
        previous: tuple[dict[str, float], dict[str, int]] | None = None
        for position in range(WARMUP + frames + 1):  # one more: its provenance carries the last one's send steps
            steps, sending, ours = trip(node, feed.take(position))
            if previous is not None and position > WARMUP:
                earlier_steps, earlier_ours = previous
                earlier_steps.update({
                    "node encode": sending["encode"] - sending["encode_start"],
                    "node zmq.Frame": sending["frame"] - sending["encode"],
                    "node PUSH send": sending["push"] - sending["frame"],
                    "node XPUB send": sending["xpub"] - sending["push"],
                    "out transit": earlier_ours["woke"] - sending["push"],
                })
                rows.append(earlier_steps)
            previous = (steps, ours)
    finally:
        pipeline.stop_translator(node)
    order = ["source encode", "source send", "in transit", "node recv", "node decode",
             "  of which the NaN/inf pass", "node queue -> process()", "process() -> model", "in leg", "node post",
             "node encode", "node zmq.Frame", "node PUSH send", "node XPUB send", "out transit", "receiver recv",
             "receiver decode", "out leg", "overhead"]
    return [{"transport": transport, "step": step, "frames": len(rows),
             **{f"p{q} us": float(np.percentile([row[step] for row in rows], q)) / 1e3 for q in (50, 90, 99)}}
            for step in order]


def run(frames: int = DEFAULT_FRAMES, transports: tuple[str, ...] = pipeline.TRANSPORTS) -> list[dict]:
    pool = pipeline.simulated_frames(pipeline.POOL)
    gc.collect()
    gc.freeze()  # as bench_pipeline and a node do
    context = zmq.Context()
    rows = []
    try:
        with tempfile.TemporaryDirectory(prefix="bench-hop-") as folder:
            for transport in transports:
                rows += measure(transport, frames, pool, context, Path(folder))
    finally:
        context.term()
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES, help=f"timed trips (default {DEFAULT_FRAMES})")
    parser.add_argument("--transports", default=",".join(pipeline.TRANSPORTS), help="comma-separated: ipc, tcp")
    args = parser.parse_args()
    from run import markdown

    print(markdown(run(args.frames, tuple(args.transports.split(",")))))
