"""Streaming pipeline cost: source -> translator node -> receiver over real ZeroMQ sockets, against the
translator's own compute time measured in the same run (the library's `Translator.translate`, no sockets).

    python bench/bench_pipeline.py [--frames N] [--device auto|cpu|cuda] [--samples 1,8]   (or: bench/run.py pipeline)

Set-up, per n (samples per frame) and transport (ipc, tcp on loopback):
- The translator is the shipped node (`sonar_realism_nodes.translator`, shipped checkpoint, seed 0, batch 1 = one
  ping per model call, as live) started the way the launcher's process mode starts it: its own OS process via
  `python -m sonar_realism.runtime.process SPEC.json`. Both edges are lossless (PUSH/PULL, the in-graph default).
  The only change is `TimedTranslatorNode`, which adds the model time of each call (and when it started) to
  the output's provenance, so that each frame's own compute can be subtracted from its end-to-end latency.
- This process is the source (binds a PUSH, `encode_frame`) and the receiver (PULL, `decode_message`, i.e. a
  validated SonarImage of n samples). Frames are 512 ranges x 256 beams float32 from the built-in simulator
  (`SimSource`, the sim_source node's frame maker), made before timing starts and cycled.

Series, interleaved in blocks of BLOCK frames so that a busy machine hurts all of them alike:
- `compute`: `Translator.translate([frame], n, seed=seq)` back to back in this process (nothing else runs).
- `latency` (per transport): closed loop, one frame in flight: e2e = from just before the source encodes the
  frame to the receiver holding the decoded output. overhead_i = e2e_i - compute_i, with compute_i the model
  time the node measured for that very frame: transport both ways, both encodes and decodes, the node's
  queueing, wake-ups and provenance. This is the primary overhead figure (`overhead p99 ms`);
  `e2e p99 - compute-only p99` is given too, but it subtracts times of different calls.
  Its legs at p50, on the wall clock: `in` (source encode -> the node starts the model), `node post` (model
  done -> the node encodes the output) and `out` (node encode -> decoded here). `codec only` is the framing's
  CPU time without sockets (encode + decode of one input and one output, median).
- `throughput` (per transport): WINDOW frames in flight, so the node always has the next frame queued;
  rate = 1 / mean interval between consecutive outputs within a block (steady state, no fill or drain).
  `throughput cost` = 1 - rate_pipeline / rate_compute-only; `in-trip cost` = 1 - (node model time of those
  outputs) / (their intervals), which does not compare blocks run at different moments of a busy machine.
  `thr node compute mean` against `compute-only mean` tells which of the two a gap between them comes from:
  a model that itself ran slower (CPU shared with the transport, or the load changed) or a model left waiting.
- `max abs diff vs direct`: a warm-up output against a direct call with the same seed (0 = same samples).
Goal (issue): transport + framing add <= 2 ms at p99 and cost <= 10 % of throughput.
"""

# No `from __future__ import annotations`: bench/run.py loads this file without putting it in sys.modules, and
# dataclasses cannot resolve string annotations of such a module.
import argparse
import gc
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zmq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from sonar_realism.runtime.process import use_passive_thread_pools  # noqa: E402  (imports neither torch nor cv2)

# This process stands in for the source and receiver nodes, whose thread pools sleep between calls
# (runtime/process.py); its own torch and OpenCV (the compute-only series) must not spin on the cores after each
# call while the next latency trip runs. No effect when they were loaded before this module (bench/run.py).
use_passive_thread_pools()

from sonar_realism.frames import SonarImage  # noqa: E402
from sonar_realism.runtime.delivery import InputPolicy  # noqa: E402
from sonar_realism.runtime.graph import resolve_node_type  # noqa: E402
from sonar_realism.runtime.node import end_of_stream_message  # noqa: E402
from sonar_realism.runtime.process import node_spec  # noqa: E402
from sonar_realism.runtime.wiring import InputWiring, OutputWiring, Wiring  # noqa: E402
from sonar_realism.wire import FRAME_TYPE, decode_message, encode_frame  # noqa: E402

TranslatorNode = resolve_node_type("translator")

SAMPLES = (1, 8)
TRANSPORTS = ("ipc", "tcp")
DEFAULT_FRAMES = 16      # per series; 5 series per n (compute, 2 x latency, 2 x throughput)
WARMUP = 2               # frames per series before timing (allocator, first-call costs)
BLOCK = 4                # frames per interleaved block
WINDOW = 2               # frames in flight in the throughput series: one computing, one queued
POOL = 16                # distinct simulated frames, cycled
SENSOR = "m1200d_1200khz"  # 256 beams x 512 ranges
GOAL_OVERHEAD_MS = 2.0
GOAL_COST = 0.10
TOPIC_IN = "sim/frames"
TOPIC_OUT = "translator/frames"
RECV_TIMEOUT_S = 120.0   # model load in a fresh process plus one frame on a crowded CPU


# ---- the node under test (runs in the translator process) ----------------------------------------------

class ComputeStampingStage:
    """Wraps the node's TranslationStage: writes the model time of the call, and when the call started on the
    wall clock (which all processes of a host share), into each output's provenance.

    The provenance dict is freshly built per output by the stage, so it is updated in place: a
    `SonarImage.replace` would add a validation pass over the samples that the real node does not make."""

    def __init__(self, stage: Any) -> None:
        self.stage = stage

    @property
    def last_ms(self) -> float:
        return self.stage.last_ms

    def __call__(self, frames: Sequence[SonarImage]) -> list[SonarImage]:
        start_ns = time.time_ns()
        outputs = self.stage(frames)
        for output in outputs:
            # With batch > 1 a frame waits for its whole batch, so the call time is that frame's compute.
            output.meta["provenance"].update(compute_ms=self.stage.last_ms, compute_start_ns=start_ns)
        return outputs


class TimedTranslatorNode(TranslatorNode):
    """The shipped translator node, plus `compute_ms` and `compute_start_ns` in the provenance of every output."""

    def configure(self) -> None:
        super().configure()
        self.stage = ComputeStampingStage(self.stage)


# ---- frames ------------------------------------------------------------------------------------------------

def simulated_frames(count: int) -> list[SonarImage]:
    """`count` float32 frames from the simulator, made the way the sim_source node makes them."""
    from sonar_realism.runtime.sources import SimSource

    source = SimSource(count=count, sensor=SENSOR)
    frames = []
    while (item := source.next()) is not None:
        frames.append(item[1])
    return frames


class FrameFeed:
    """Hands out the pool's frames in order, each with a fresh seq (the node seeds each frame with it)."""

    def __init__(self, pool: list[SonarImage]) -> None:
        self.pool = pool
        self.next_seq = 0

    def take(self, position: int) -> SonarImage:
        frame = self.pool[position % len(self.pool)].replace(seq=self.next_seq, stamp_ns=time.time_ns())
        self.next_seq += 1
        return frame


# ---- the translator process and its sockets ---------------------------------------------------------------

def _free_tcp_endpoint() -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{probe.getsockname()[1]}"


def _endpoint(transport: str, folder: Path, name: str) -> str:
    return f"ipc://{folder}/{name}.ipc" if transport == "ipc" else _free_tcp_endpoint()


@dataclass
class TranslatorProcess:
    transport: str
    n: int
    process: subprocess.Popen
    source: zmq.Socket   # PUSH bound here; the node's input PULL connects to it
    sink: zmq.Socket     # PULL connected to the node's output PUSH
    log_path: Path

    def log_tail(self) -> str:
        try:
            return "\n".join(self.log_path.read_text().splitlines()[-20:])
        except OSError:
            return "(no log)"


def start_translator(context: zmq.Context, transport: str, n: int, folder: Path, device: str,
                     node_type: str = "bench_pipeline:TimedTranslatorNode") -> TranslatorProcess:
    name = f"translator-{transport}-n{n}"
    source = context.socket(zmq.PUSH)
    source.linger = 0
    source.sndtimeo = int(RECV_TIMEOUT_S * 1000)  # a dead node must fail the bench, not hang it
    source.bind(f"ipc://{folder}/{name}-in.ipc" if transport == "ipc" else "tcp://127.0.0.1:*")
    input_endpoint = source.last_endpoint.decode()
    output_push, output_pub = _endpoint(transport, folder, f"{name}-out"), _endpoint(transport, folder, f"{name}-pub")
    wiring = Wiring(
        inputs={"frames": InputWiring(input_endpoint, TOPIC_IN, InputPolicy("lossless", capacity=8))},
        outputs={"frames": OutputWiring(TOPIC_OUT, output_pub, push_endpoints=(output_push,))},
        exit_with_parent=True,  # a crashed bench leaves no translator behind
    )
    params = {"n": n, "seed": 0, "batch": 1, "device": device}
    spec_path = folder / f"{name}.json"
    spec_path.write_text(node_spec(name, node_type, params, wiring))
    sink = context.socket(zmq.PULL)
    sink.linger = 0
    sink.connect(output_push)  # zmq retries until the node has bound it
    # The launcher passes its sys.path on; bench/ is added so the node process can import this module.
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "bench"), *(p for p in sys.path if p)])}
    log_path = folder / f"{name}.log"
    with open(log_path, "wb") as log:
        process = subprocess.Popen([sys.executable, "-m", "sonar_realism.runtime.process", str(spec_path)],
                                   cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    return TranslatorProcess(transport, n, process, source, sink, log_path)


def send(node: TranslatorProcess, frame: SonarImage) -> None:
    node.source.send_multipart(encode_frame(frame, TOPIC_IN), copy=False)


@dataclass
class Received:
    frame: SonarImage
    perf_s: float      # time.perf_counter() when the decoded frame was in hand
    wall_ns: int       # the same moment on the wall clock, for the per-leg breakdown
    sent_ns: int       # the node's encode time (header `sent_ns`)


def receive(node: TranslatorProcess, timeout_s: float = RECV_TIMEOUT_S) -> Received:
    if not node.sink.poll(timeout_s * 1000):
        raise RuntimeError(f"{node.transport} n={node.n}: no output within {timeout_s} s "
                           f"(exit code {node.process.poll()}); node log:\n{node.log_tail()}")
    parts = node.sink.recv_multipart(copy=False)
    message = decode_message(parts)
    perf_s, wall_ns = time.perf_counter(), time.time_ns()
    if message.kind != FRAME_TYPE:
        raise RuntimeError(f"{node.transport} n={node.n}: expected a frame on {message.topic}, got {message.body}")
    return Received(message.body, perf_s, wall_ns, message.sent_ns or 0)  # type: ignore[arg-type]


def stop_translator(node: TranslatorProcess) -> None:
    """End of stream in, then wait for it to come out (the node's PUSH waits for us to take it)."""
    try:
        node.source.send_multipart(end_of_stream_message(TOPIC_IN, "bench", "finished"), flags=zmq.NOBLOCK)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and node.sink.poll(100):
            message = decode_message(node.sink.recv_multipart(copy=False))
            if message.kind != FRAME_TYPE and message.body.get("end_of_stream"):  # type: ignore[union-attr]
                break
        node.process.wait(timeout=10.0)
    except (zmq.ZMQError, subprocess.TimeoutExpired):
        node.process.terminate()
        node.process.wait(timeout=10.0)
    finally:
        node.source.close(linger=0)
        node.sink.close(linger=0)
    if node.process.returncode != 0:
        print(f"warning: {node.transport} n={node.n} translator exited with {node.process.returncode}:\n"
              f"{node.log_tail()}", file=sys.stderr)


# ---- the series ------------------------------------------------------------------------------------------

@dataclass
class Series:
    e2e_ms: list[float] = field(default_factory=list)
    compute_ms: list[float] = field(default_factory=list)   # the node's (or the direct call's) model time
    interval_ms: list[float] = field(default_factory=list)  # steady-state time per frame (throughput)
    busy_ms: list[float] = field(default_factory=list)      # the node's model time within those intervals
    in_ms: list[float] = field(default_factory=list)        # source encode -> node starts the model
    post_ms: list[float] = field(default_factory=list)      # model done -> node encodes the output (provenance)
    out_ms: list[float] = field(default_factory=list)       # node encodes the output -> decoded here


def _provenance(frame: SonarImage) -> dict[str, Any]:
    provenance = frame.meta.get("provenance")
    return provenance if isinstance(provenance, dict) else {}


def latency_trip(node: TranslatorProcess, frame: SonarImage, series: Series | None) -> SonarImage:
    """One frame through the pipeline with nothing else in flight."""
    start, start_ns = time.perf_counter(), time.time_ns()
    send(node, frame)
    received = receive(node)
    output, provenance = received.frame, _provenance(received.frame)
    if provenance.get("input_seq") != frame.seq or output.intensity.shape != (node.n, *frame.intensity.shape):
        raise RuntimeError(f"{node.transport} n={node.n}: output {output.intensity.shape} for input_seq "
                           f"{provenance.get('input_seq')}, expected seq {frame.seq}")
    if series is not None:
        series.e2e_ms.append((received.perf_s - start) * 1e3)
        series.compute_ms.append(float(provenance["compute_ms"]))
        series.in_ms.append((provenance["compute_start_ns"] - start_ns) / 1e6)
        compute_end_ns = provenance["compute_start_ns"] + provenance["compute_ms"] * 1e6
        series.post_ms.append((received.sent_ns - compute_end_ns) / 1e6)
        series.out_ms.append((received.wall_ns - received.sent_ns) / 1e6)
    return output


def throughput_block(node: TranslatorProcess, frames: list[SonarImage], series: Series) -> None:
    """WINDOW frames in flight; keeps the intervals between consecutive outputs and the model time in each."""
    pending = deque(frames)
    in_flight = 0
    arrivals, computes = [], []
    while pending or in_flight:
        while pending and in_flight < WINDOW:
            send(node, pending.popleft())
            in_flight += 1
        received = receive(node)
        arrivals.append(received.perf_s)
        computes.append(float(_provenance(received.frame)["compute_ms"]))
        in_flight -= 1
    # In steady state the interval before output i is output i's model time plus whatever is not model time.
    series.interval_ms.extend(np.diff(arrivals) * 1e3)
    series.busy_ms.extend(computes[1:])


def compute_block(translator: Any, n: int, frames: list[SonarImage], series: Series) -> None:
    for frame in frames:
        start = time.perf_counter()
        translator.translate([frame], n, 1.0, seed=frame.seq)
        elapsed_ms = (time.perf_counter() - start) * 1e3
        series.compute_ms.append(elapsed_ms)
        series.interval_ms.append(elapsed_ms)


def codec_ms(frame: SonarImage, output: SonarImage, repeats: int = 20) -> float:
    """Median CPU time of the framing alone, no sockets: encode + decode of the input and of the n-sample output
    (decode includes SonarImage's validation, e.g. the NaN/inf pass over float samples)."""
    def trip() -> None:
        for item, topic in ((frame, TOPIC_IN), (output, TOPIC_OUT)):
            decode_message(encode_frame(item, topic))

    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        trip()
        times.append((time.perf_counter() - start) * 1e3)
    return float(np.median(times))


def warm_up(nodes: list[TranslatorProcess], translator: Any, feed: FrameFeed, n: int
            ) -> tuple[dict[str, float], float]:
    """WARMUP frames each; the last one is compared with a direct call of the same seed (same samples?).
    Also returns the codec time of that input and output."""
    for position in range(WARMUP):
        translator.translate([feed.take(position)], n, 1.0, seed=0)
    max_diff = {}
    for node in nodes:
        for position in range(WARMUP):
            frame = feed.take(position)
            output = latency_trip(node, frame, None)
        direct = translator.translate([frame], n, 1.0, seed=frame.seq)[0]
        max_diff[node.transport] = float(np.abs(output.intensity - direct.intensity).max())
    return max_diff, codec_ms(frame, output)


def measure(n: int, frames: int, pool: list[SonarImage], translator: Any, context: zmq.Context, device: str,
            folder: Path) -> list[dict]:
    nodes: list[TranslatorProcess] = []
    feed = FrameFeed(pool)
    compute = Series()
    latency = {transport: Series() for transport in TRANSPORTS}
    throughput = {transport: Series() for transport in TRANSPORTS}
    try:
        for transport in TRANSPORTS:  # both load the model at the same time; they idle while the other is timed
            nodes.append(start_translator(context, transport, n, folder, device))
        max_diff, codec = warm_up(nodes, translator, feed, n)
        for first in range(0, frames, BLOCK):
            positions = range(first, min(first + BLOCK, frames))
            compute_block(translator, n, [feed.take(p) for p in positions], compute)
            for node in nodes:
                for p in positions:
                    latency_trip(node, feed.take(p), latency[node.transport])
            for node in nodes:
                throughput_block(node, [feed.take(p) for p in positions], throughput[node.transport])
            print(f"  n={n}: {positions[-1] + 1}/{frames} frames per series", file=sys.stderr, flush=True)
    finally:
        for node in nodes:
            stop_translator(node)
    return [row(n, node.transport, compute, latency[node.transport], throughput[node.transport],
                max_diff[node.transport], codec) for node in nodes]


# ---- the table -------------------------------------------------------------------------------------------

def _p(values: Sequence[float], q: float) -> float:
    return float(np.percentile(values, q)) if len(values) else math.nan


def _verdict(ok: bool) -> str:
    return "met" if ok else "missed"


def row(n: int, transport: str, compute: Series, latency: Series, throughput: Series, max_diff: float,
        codec: float) -> dict:
    overhead = np.subtract(latency.e2e_ms, latency.compute_ms)
    overhead_p99 = _p(overhead, 99)
    interval_ms = float(np.mean(throughput.interval_ms)) if throughput.interval_ms else math.nan
    rate_pipeline = 1e3 / interval_ms
    rate_compute = 1e3 / float(np.mean(compute.interval_ms))
    cost = 1.0 - rate_pipeline / rate_compute
    # The same ratio against the model time of the very frames in those intervals: immune to the load
    # changing between the compute-only blocks and the pipeline blocks.
    cost_in_trip = 1.0 - float(np.mean(throughput.busy_ms)) / interval_ms
    return {
        "transport": transport, "frame": "512x256 f4", "n": n, "frames": len(latency.e2e_ms),
        "e2e p50 ms": _p(latency.e2e_ms, 50), "e2e p99 ms": _p(latency.e2e_ms, 99),
        "node compute p50 ms": _p(latency.compute_ms, 50), "node compute p99 ms": _p(latency.compute_ms, 99),
        "compute-only p50 ms": _p(compute.compute_ms, 50), "compute-only p99 ms": _p(compute.compute_ms, 99),
        "overhead p50 ms": _p(overhead, 50), "overhead p99 ms": overhead_p99,
        "e2e p99 - compute-only p99 ms": _p(latency.e2e_ms, 99) - _p(compute.compute_ms, 99),
        "in p50 ms": _p(latency.in_ms, 50), "node post p50 ms": _p(latency.post_ms, 50),
        "out p50 ms": _p(latency.out_ms, 50), "codec only ms": codec,
        "pipeline frames/s": rate_pipeline, "compute-only frames/s": rate_compute,
        # Model time per frame in the throughput series vs the compute-only series: tells a slower model
        # (CPU shared with the transport, or the machine's load changing) from a model left waiting.
        "thr node compute mean ms": float(np.mean(throughput.busy_ms)),
        "compute-only mean ms": float(np.mean(compute.interval_ms)),
        "throughput cost %": 100.0 * cost, "in-trip cost %": 100.0 * cost_in_trip,
        "goal": f"overhead p99 <= {GOAL_OVERHEAD_MS:g} ms, cost <= {100 * GOAL_COST:g} %",
        "overhead goal": _verdict(overhead_p99 <= GOAL_OVERHEAD_MS),
        "cost goal": _verdict(cost <= GOAL_COST),
        "in-trip cost goal": _verdict(cost_in_trip <= GOAL_COST),
        "max abs diff vs direct": max_diff,
    }


def run(frames: int = DEFAULT_FRAMES, device: str = "auto", samples: Sequence[int] = SAMPLES) -> list[dict]:
    from sonar_realism.models.translate import DEFAULT_CHECKPOINT, Translator  # torch: only when measuring

    translator = Translator.from_checkpoint(DEFAULT_CHECKPOINT, device=device)
    pool = simulated_frames(POOL)
    gc.collect()
    gc.freeze()  # as in a node (Node.run): the receiver's timing must not include a full collection over torch
    context = zmq.Context()
    rows = []
    try:
        with tempfile.TemporaryDirectory(prefix="bench-pipeline-") as folder:
            for n in samples:
                rows += measure(n, frames, pool, translator, context, device, Path(folder))
    finally:
        context.term()
    # What "auto" chose here; the node resolves "auto" the same way.
    return [{"device": translator.device.type, **item} for item in rows]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES,
                        help=f"timed frames per series (default {DEFAULT_FRAMES}; 5 series per n)")
    parser.add_argument("--device", default="auto", help="auto (cuda when available), cpu or cuda")
    parser.add_argument("--samples", default=",".join(map(str, SAMPLES)),
                        help=f"comma-separated n (samples per frame) to measure (default {SAMPLES})")
    args = parser.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from run import markdown

    print(markdown(run(args.frames, args.device, [int(n) for n in args.samples.split(",")])))
