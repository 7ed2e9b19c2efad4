"""Node runtime: delivery policies, ordering and seq gaps, malformed input, lossless delivery, readiness,
status, and shutdown that never hangs. Real inproc sockets, real threads, tiny frames."""

from __future__ import annotations

import gc
import itertools
import os
import threading
import time
from dataclasses import dataclass

import msgpack
import numpy as np
import pytest
import zmq

from sonar_realism.errors import FrameError
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.runtime import EndOfStream, InputPolicy, InputQueue, InputWiring, Node, OutputWiring, SeqTracker
from sonar_realism.runtime.node import end_of_stream_message
from sonar_realism.runtime.wiring import Wiring
from sonar_realism.wire import decode_message, encode_frame

JOIN_TIMEOUT_S = 30.0
_ids = itertools.count()


def tiny_frame(seq: int, stamp_ns: int | None = None, shape: tuple[int, int] = (8, 6)) -> SonarImage:
    return SonarImage(np.full(shape, seq % 255, np.uint8), uniform_ranges(shape[0], 10.0),
                      uniform_azimuths(shape[1], 1.0), stamp_ns=time.time_ns() if stamp_ns is None else stamp_ns,
                      seq=seq)


@dataclass(frozen=True)
class SourceParams:
    count: int = 10
    skip: tuple[int, ...] = ()


class CountingSource(Node):
    PARAMS = SourceParams
    OUTPUTS = {"frames": "polar"}

    def configure(self) -> None:
        self.seqs = iter(s for s in range(self.params.count) if s not in self.params.skip)

    def produce(self) -> float | None:
        seq = next(self.seqs, None)
        if seq is None:
            return None
        self.publish("frames", tiny_frame(seq))
        return 0.0


@dataclass(frozen=True)
class SinkParams:
    delay_s: float = 0.0


class CollectingSink(Node):
    PARAMS = SinkParams
    INPUTS = {"frames": ("polar",)}

    def configure(self) -> None:
        self.frames: list[SonarImage] = []

    def process(self, input_name: str, frames: list[SonarImage]) -> None:
        if self.params.delay_s:
            time.sleep(self.params.delay_s)  # a slow consumer (e.g. a model), not a test synchronisation
        self.frames.extend(frames)


def pair(context: zmq.Context, policy: InputPolicy, source: SourceParams, sink: SinkParams = SinkParams(),
         hwm: int = 16) -> tuple[CountingSource, CollectingSink]:
    run = next(_ids)
    pub, push = f"inproc://rt{run}/src", f"inproc://rt{run}/src-to-sink"
    lossless = policy.policy == "lossless"
    out = OutputWiring("src/frames", pub, expected_subscribers=0 if lossless else 1,
                       push_endpoints=(push,) if lossless else (), hwm=hwm)
    src = CountingSource("src", source, Wiring(outputs={"frames": out}, heartbeat_s=0.2), context)
    sink_in = InputWiring(push if lossless else pub, "src/frames", policy)
    sink = CollectingSink("sink", sink, Wiring(inputs={"frames": sink_in}, heartbeat_s=0.2), context)
    return src, sink


def run_all(*nodes: Node) -> None:
    """Start consumers first (as the launcher does) and fail, rather than hang, if a node does not end."""
    errors: list[BaseException] = []

    def target(node: Node) -> None:
        try:
            node.run()
        except BaseException as error:
            errors.append(error)

    threads = [threading.Thread(target=target, args=(n,), daemon=True) for n in reversed(nodes)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(JOIN_TIMEOUT_S)
    assert not any(t.is_alive() for t in threads), "a node did not finish"
    assert not errors, errors


@pytest.fixture
def context():
    ctx = zmq.Context()
    yield ctx
    ctx.term()


# ---- policies without sockets -------------------------------------------------------------------------
def test_latest_keeps_only_the_newest_frame_and_counts_drops():
    queue = InputQueue(InputPolicy("latest"))
    for seq in range(5):
        queue.put(tiny_frame(seq))
    taken = queue.take(10)
    assert [f.seq for f in taken] == [4]
    assert queue.dropped == 4 and queue.received == 5


def test_fifo_drops_the_oldest_when_full_but_never_end_of_stream():
    queue = InputQueue(InputPolicy("fifo", capacity=3))
    for seq in range(5):
        queue.put(tiny_frame(seq))
    queue.put(EndOfStream())
    queue.put(tiny_frame(99))  # after end of stream: ignored
    taken = queue.take(10)
    assert [getattr(item, "seq", "eos") for item in taken] == [2, 3, 4, "eos"]
    assert queue.dropped == 2 and queue.ended


def test_lossless_never_drops_and_reports_when_full():
    queue = InputQueue(InputPolicy("lossless", capacity=2))
    queue.put(tiny_frame(0))
    assert queue.has_room()
    queue.put(tiny_frame(1))
    assert not queue.has_room()
    assert [f.seq for f in queue.take(1)] == [0]
    assert queue.has_room() and queue.dropped == 0


def test_stale_frames_are_dropped_when_taken():
    queue = InputQueue(InputPolicy("fifo", capacity=4, max_age_s=1.0))
    queue.put(tiny_frame(0), born_ns=time.time_ns() - 5_000_000_000)  # sent 5 s ago
    queue.put(tiny_frame(1))
    assert [f.seq for f in queue.take(4)] == [1]
    assert queue.stale == 1 and queue.last_taken_seq == 1


def test_age_counts_from_sending_not_from_a_simulated_acquisition_stamp():
    # A simulator stamping sim time (here: 1 s after the epoch) must not lose every frame to max_age_s.
    queue = InputQueue(InputPolicy("latest", max_age_s=0.5))
    queue.put(tiny_frame(0, stamp_ns=1_000_000_000), born_ns=time.time_ns())
    assert [f.seq for f in queue.take(1)] == [0] and queue.stale == 0


def test_seq_tracker_counts_gaps_and_out_of_order_frames():
    tracker = SeqTracker()
    for seq in (0, 1, 4, 5, 3, 6, 9):
        tracker.observe(seq)
    assert tracker.gaps == 2 + 2  # 2,3 missing after 1; 7,8 missing after 6 (3 came late: not a new gap)
    assert tracker.out_of_order == 1


def test_a_source_that_starts_its_seq_again_is_followed_not_counted_late_for_ever():
    tracker = SeqTracker()
    for seq in (500, 501, 0, 1, 2, 3):  # a simulator restarted at 0
        tracker.observe(seq)
    assert (tracker.gaps, tracker.out_of_order) == (0, 1)
    for seq in (4, (1 << 64) - 3, (1 << 64) - 2):  # a counter of its own: no gap of billions
        tracker.observe(seq)
    assert (tracker.gaps, tracker.out_of_order) == (0, 2)


def test_a_status_with_counters_past_uint64_is_still_sent(context):
    from sonar_realism.wire import decode_message, encode_status

    _, sink = pair(context, InputPolicy("fifo"), SourceParams(count=1))
    sink.queues["frames"].seq.gaps = 1 << 70  # sums of a client's wild seqs
    parts = encode_status("sink/status", sink.status())
    assert decode_message(parts).body["seq_gaps"] == (1 << 64) - 1


def test_bad_policy_is_a_config_error():
    from sonar_realism.errors import ConfigError

    with pytest.raises(ConfigError, match="policy"):
        InputQueue(InputPolicy("newest"))  # type: ignore[arg-type]


# ---- over sockets -------------------------------------------------------------------------------------
def test_lossless_delivers_every_one_of_2000_frames_in_order_to_a_slower_consumer(context):
    src, sink = pair(context, InputPolicy("lossless", capacity=4), SourceParams(count=2000),
                     SinkParams(delay_s=0.0002), hwm=4)
    run_all(src, sink)
    assert [f.seq for f in sink.frames] == list(range(2000))
    status = sink.status()
    assert status["dropped"] == 0 and status["seq_gaps"] == 0 and status["frames_in"] == 2000
    assert src.status()["frames_out"] == 2000
    assert sink._pump is None  # lossless inputs are read by the node's own thread alone


def test_subscribers_get_the_first_frame_because_sources_wait_for_them(context):
    # fifo over PUB/SUB: without the XPUB readiness wait the first frames would vanish (slow joiner).
    src, sink = pair(context, InputPolicy("fifo", capacity=64), SourceParams(count=50))
    run_all(src, sink)
    assert [f.seq for f in sink.frames] == list(range(50))


def test_latest_policy_drops_for_a_slow_consumer_and_the_counts_add_up(context):
    src, sink = pair(context, InputPolicy("latest"), SourceParams(count=300), SinkParams(delay_s=0.01))
    run_all(src, sink)
    status = sink.status()
    seqs = [f.seq for f in sink.frames]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    assert status["dropped"] > 0
    assert status["frames_in"] == len(seqs) + status["dropped"]
    assert status["frames_in"] + status["seq_gaps"] <= 300


def test_seq_gaps_from_the_source_are_counted_downstream(context):
    src, sink = pair(context, InputPolicy("lossless"), SourceParams(count=20, skip=(3, 4, 10)))
    run_all(src, sink)
    assert [f.seq for f in sink.frames] == [s for s in range(20) if s not in (3, 4, 10)]
    assert sink.status()["seq_gaps"] == 3


def test_malformed_messages_are_counted_and_the_node_keeps_running(context):
    endpoint = f"inproc://rt{next(_ids)}/raw"
    push = context.socket(zmq.PUSH)
    push.bind(endpoint)
    sink = CollectingSink("sink", SinkParams(), Wiring(
        inputs={"frames": InputWiring(endpoint, "raw/frames", InputPolicy("lossless"))}), context)
    good = encode_frame(tiny_frame(7), "raw/frames")
    wrong_version = [b"raw/frames", msgpack.packb({**msgpack.unpackb(good[1]), "v": 99}), good[2]]
    short_buffer = [good[0], good[1], bytes(good[2])[:-5]]
    garbage = [b"raw/frames", b"\xc1\xff not msgpack", b"xx"]
    thread = threading.Thread(target=sink.run, daemon=True)
    thread.start()
    for message in (garbage, wrong_version, short_buffer, [b"only one part"], good,
                    end_of_stream_message("raw/frames", "test", "finished")):
        push.send_multipart(message)  # a PUSH waits for its peer: no message is sent before the sink connects
    thread.join(JOIN_TIMEOUT_S)
    push.close(linger=0)
    assert not thread.is_alive()
    assert [f.seq for f in sink.frames] == [7]
    assert sink.status()["malformed"] == 4


def test_status_heartbeat_reports_counters_and_the_final_state(context):
    status_endpoint = f"inproc://rt{next(_ids)}/status"
    sub = context.socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.connect(status_endpoint)
    src, sink = pair(context, InputPolicy("lossless"), SourceParams(count=30))
    sink = CollectingSink("sink", SinkParams(), Wiring(inputs=sink.wiring.inputs, status_endpoint=status_endpoint,
                                                       status_subscribers=1, heartbeat_s=0.05), context)
    run_all(src, sink)
    reports = []
    while sub.poll(200):
        message = decode_message(sub.recv_multipart())
        reports.append((message.topic, message.kind, message.body))
    sub.close(linger=0)
    states = [body["state"] for topic, kind, body in reports]
    assert all(topic == "sink/status" and kind == "status" for topic, kind, _ in reports)
    assert states[-1] == "stopped" and "running" in states
    assert reports[-1][2]["frames_in"] == 30


def test_stop_while_waiting_for_consumers_returns_and_shutdown_is_idempotent(context):
    out = OutputWiring("src/frames", f"inproc://rt{next(_ids)}/src", expected_subscribers=1)
    src = CountingSource("src", SourceParams(count=5), Wiring(outputs={"frames": out}), context)
    thread = threading.Thread(target=src.run, daemon=True)
    thread.start()
    src.request_stop()
    thread.join(JOIN_TIMEOUT_S)
    assert not thread.is_alive() and src.state == "stopped"
    src.shutdown()
    src.shutdown()


def test_stop_while_blocked_on_a_full_lossless_consumer_never_hangs(context):
    # The consumer never reads: the source's PUSH fills up and it waits; a stop request must still end it.
    endpoint = f"inproc://rt{next(_ids)}/push"
    out = OutputWiring("src/frames", f"inproc://rt{next(_ids)}/pub", push_endpoints=(endpoint,), hwm=1)
    src = CountingSource("src", SourceParams(count=10_000), Wiring(outputs={"frames": out}, eos_linger_s=0.2),
                         context)
    pull = context.socket(zmq.PULL)
    pull.rcvhwm = 1
    pull.connect(endpoint)
    thread = threading.Thread(target=src.run, daemon=True)
    thread.start()
    assert pull.poll(5000)  # the source is running and has filled the pipe
    src.request_stop()
    thread.join(JOIN_TIMEOUT_S)
    pull.close(linger=0)
    assert not thread.is_alive() and src.state == "stopped"
    assert src.status()["frames_out"] < 10_000


class PickySink(CollectingSink):
    """Cannot handle frames whose seq is a multiple of 5 (as a model cannot handle some shapes)."""

    BATCH_SIZE = 4

    def process(self, input_name: str, frames: list[SonarImage]) -> None:
        if any(f.seq % 5 == 0 for f in frames):
            raise FrameError("intensity: this node cannot take this frame")
        self.frames.extend(frames)


def test_frames_a_node_cannot_process_are_counted_as_malformed_and_the_rest_of_the_batch_goes_on(context, caplog):
    src, sink = pair(context, InputPolicy("lossless"), SourceParams(count=23))
    sink = PickySink("sink", SinkParams(), sink.wiring, context)
    run_all(src, sink)
    assert [f.seq for f in sink.frames] == [s for s in range(23) if s % 5]
    assert sink.status()["malformed"] == 5 and sink.state == "stopped"
    assert "topic 'src/frames'" in caplog.text and "frame seq 10 cannot be processed" in caplog.text


class BrokenSink(CollectingSink):
    def process(self, input_name: str, frames: list[SonarImage]) -> None:
        raise RuntimeError("a fault of the node, not of the frame")


def test_a_fault_of_the_node_itself_still_ends_it(context):
    src, sink = pair(context, InputPolicy("lossless"), SourceParams(count=3))
    sink = BrokenSink("sink", SinkParams(), sink.wiring, context)
    thread = threading.Thread(target=src.run, daemon=True)
    thread.start()
    with pytest.raises(RuntimeError, match="fault of the node"):
        sink.run()
    src.request_stop()
    thread.join(JOIN_TIMEOUT_S)
    assert sink.state == "error" and not thread.is_alive()


def test_frames_on_a_topic_nobody_takes_are_counted_not_lost_silently(context, caplog):
    endpoint = f"inproc://rt{next(_ids)}/external"
    publisher = context.socket(zmq.XPUB)
    publisher.bind(endpoint)
    sink = CollectingSink("sink", SinkParams(), Wiring(
        inputs={"frames": InputWiring(endpoint, "sonar/sim", InputPolicy("fifo", capacity=64))}), context)
    thread = threading.Thread(target=sink.run, daemon=True)
    thread.start()
    assert publisher.poll(JOIN_TIMEOUT_S * 1000) and publisher.recv()[0] == 1  # the sink has subscribed
    for seq, topic in enumerate(["sonar/sim", "sonar/sim2", "sim", "sonar/sim"]):
        publisher.send_multipart(encode_frame(tiny_frame(seq), topic))
    # the publisher's own telemetry in a format of its own, on another topic: not ours to call malformed
    publisher.send_multipart([b"sim/telemetry", b'{"battery": 0.8}'])
    publisher.send_multipart(end_of_stream_message("sonar/sim", "sim", "finished"))
    thread.join(JOIN_TIMEOUT_S)
    publisher.close(linger=0)
    assert [f.seq for f in sink.frames] == [0, 3]
    assert sink.status()["other_topic"] == 3 and sink.status()["malformed"] == 0
    assert "frames on topic 'sonar/sim2' are ignored" in caplog.text


def test_a_client_ends_the_stream_after_a_burst_a_slow_node_could_not_keep(context):
    # 3000 frames at once into a slow node (a queue of 8, 5 ms a frame): the publisher's queue overflows and a single
    # end-of-stream marker right after it would be dropped with the frames; end_stream() sends it until the node has
    # hung up, so the node ends instead of waiting for ever
    from sonar_realism.client import FramePublisher

    endpoint = f"inproc://rt{next(_ids)}/client"
    with FramePublisher(endpoint, topic="sonar/sim", context=context) as publisher:
        sink = CollectingSink("sink", SinkParams(delay_s=0.005), Wiring(
            inputs={"frames": InputWiring(endpoint, "sonar/sim", InputPolicy("fifo", capacity=8))}), context)
        thread = threading.Thread(target=sink.run, daemon=True)
        thread.start()
        wait_until(lambda: publisher.subscribed(10))
        for seq in range(3000):
            publisher.publish_frame(tiny_frame(seq))
        assert publisher.end_stream(timeout_s=JOIN_TIMEOUT_S)
        thread.join(JOIN_TIMEOUT_S)
    assert not thread.is_alive()
    status = sink.status()
    assert 0 < len(sink.frames) < 3000 and status["frames_in"] == len(sink.frames) + status["dropped"]


def wait_until(condition, timeout_s: float = JOIN_TIMEOUT_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.001)


def test_an_idle_node_reads_frames_on_its_own_thread_and_a_busy_one_on_its_receive_thread(context):
    # No hand-over between threads for a frame that finds the node waiting; while process() runs, the receive
    # thread keeps reading (so `latest`/`fifo` count drops as they happen).
    endpoint = f"inproc://rt{next(_ids)}/idle"
    push = context.socket(zmq.PUSH)
    push.bind(endpoint)
    release = threading.Event()

    class GatedSink(CollectingSink):
        def process(self, input_name: str, frames: list[SonarImage]) -> None:
            if frames[0].seq == 0:
                release.wait(JOIN_TIMEOUT_S)
            super().process(input_name, frames)

    sink = GatedSink("sink", SinkParams(), Wiring(
        inputs={"frames": InputWiring(endpoint, "raw/frames", InputPolicy("fifo", capacity=8))}), context)
    queued_by: dict[int, threading.Thread] = {}
    put = sink.queues["frames"].put

    def recording_put(item, born_ns=None):
        if isinstance(item, SonarImage):
            queued_by[item.seq] = threading.current_thread()
        put(item, born_ns)

    sink.queues["frames"].put = recording_put
    thread = threading.Thread(target=sink.run, daemon=True)
    thread.start()
    push.send_multipart(encode_frame(tiny_frame(0), "raw/frames"))
    wait_until(lambda: 0 in queued_by)
    push.send_multipart(encode_frame(tiny_frame(1), "raw/frames"))  # frame 0 is still being processed
    wait_until(lambda: 1 in queued_by)
    release.set()
    for seq in range(2, 12):
        wait_until(lambda n=seq: len(sink.frames) == n and not sink._sockets_lent.is_set())  # waiting for news
        time.sleep(0.005)
        push.send_multipart(encode_frame(tiny_frame(seq), "raw/frames"))
    push.send_multipart(end_of_stream_message("raw/frames", "test", "finished"))
    thread.join(JOIN_TIMEOUT_S)
    push.close(linger=0)
    assert not thread.is_alive()
    assert [f.seq for f in sink.frames] == list(range(12))
    assert queued_by[1] is not thread
    # The receive thread holds the sockets for a moment every tick while the node idles, so allow a few.
    assert sum(queued_by[seq] is thread for seq in range(2, 12)) >= 7


def test_what_a_node_made_before_running_is_left_out_of_garbage_collections(context):
    gc.unfreeze()
    src, sink = pair(context, InputPolicy("lossless"), SourceParams(count=3))
    run_all(src, sink)
    assert gc.get_freeze_count() > 0  # else a full collection walks the model's objects mid-stream
    gc.unfreeze()


def test_node_processes_make_thread_pools_sleep_between_calls_unless_told_otherwise(monkeypatch, tmp_path):
    from sonar_realism.runtime import process

    for name in process.PASSIVE_THREAD_POOLS:
        monkeypatch.setenv(name, "placeholder")  # recorded, so the test's environment comes back afterwards
        monkeypatch.delenv(name)
    monkeypatch.setenv("OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN", "5")  # a value already set wins
    with pytest.raises(FileNotFoundError):
        process.main([str(tmp_path / "missing.json")])  # the policy is set before the spec is even read
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"
    assert os.environ["OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER"] == "0"
    assert os.environ["OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN"] == "5"
