"""Launch files: validation before anything starts, overrides, the resolved config, restart on failure,
and the `sonar-realism launch` CLI end to end in process mode (incl. SIGINT: clean exit, no orphans)."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.io import read_frames, write_frames
from sonar_realism.runtime.graph import apply_overrides, build_graph
from sonar_realism.runtime.launch import launch, load_graph
from sonar_realism.runtime.node import Node

REPO = Path(__file__).resolve().parents[1]
PROCESS_TIMEOUT_S = 120


@dataclass(frozen=True)
class TickerParams:
    count: int = 5


class Ticker(Node):
    PARAMS = TickerParams
    OUTPUTS = {"frames": "polar"}

    def configure(self) -> None:
        self.next_seq = 0

    def produce(self) -> float | None:
        if self.next_seq >= self.params.count:
            return None
        self.publish("frames", SonarImage(np.zeros((4, 3), np.uint8), uniform_ranges(4, 5.0),
                                          uniform_azimuths(3, 1.0), seq=self.next_seq))
        self.next_seq += 1
        return 0.0


@dataclass(frozen=True)
class FlakyParams:
    failures: int = 1


class FlakySink(Node):
    """Fails on its first frame in each of its first `failures` lives (lives are counted per class)."""

    PARAMS = FlakyParams
    INPUTS = {"frames": ("polar",)}
    lives = 0
    received: list[int] = []

    def configure(self) -> None:
        type(self).lives += 1

    def process(self, input_name: str, frames: list[SonarImage]) -> None:
        if type(self).lives <= self.params.failures:
            raise RuntimeError("simulated crash")
        type(self).received.extend(f.seq for f in frames)


@dataclass(frozen=True)
class RelayParams:
    pass


class Relay(Node):
    PARAMS = RelayParams
    INPUTS = {"frames": ("polar",)}
    OUTPUTS = {"frames": "polar"}


def graph_data(**nodes) -> dict:
    return {"launch": {"name": "t"}, "nodes": nodes}


SIM = {"type": "sim_source"}
TRANSLATOR = {"type": "translator", "inputs": {"frames": "sim.frames"}}


# ---- validation: everything is checked before anything starts -----------------------------------------
@pytest.mark.parametrize("nodes, message", [
    ({"a": {"type": "no_such_node"}}, "unknown node type"),
    ({"sim": {"type": "sim_source", "params": {"frames_per_second": 3}}}, "unknown key"),
    ({"sim": SIM, "translator": {"type": "translator"}}, "unconnected input"),
    ({"sim": SIM, "translator": {"type": "translator", "inputs": {"frames": "sim.masks"}}}, "type mismatch"),
    ({"sim": SIM, "translator": {"type": "translator", "inputs": {"frames": "sim.sonar"}}}, "no output"),
    ({"sim": SIM, "translator": {"type": "translator", "inputs": {"frames": "simulator.frames"}}}, "neither"),
    ({"sim": SIM, "translator": {**TRANSLATOR, "inputs": {"frames": "sim.frames", "extra": "sim.frames"}}},
     "not an input"),
    ({"t": {"type": "translator", "inputs": {"frames": {"source": "tcp://127.0.0.1:5555", "policy": "lossless"}}}},
     "lossless needs an in-graph producer"),
    ({"sim": SIM, "translator": {**TRANSLATOR, "inputs": {"frames": {"source": "sim.frames", "policy": "newest"}}}},
     "policy"),
    ({"a": {"type": "test_launch:Relay", "inputs": {"frames": "b.frames"}},
      "b": {"type": "test_launch:Relay", "inputs": {"frames": "a.frames"}}}, "cycle"),
    ({"sim": {**SIM, "bind": {"sonar": "tcp://127.0.0.1:5601"}}}, "not an output"),
    ({"bad.name": SIM}, "node names"),
])
def test_invalid_graphs_are_rejected_with_a_named_reason(nodes, message):
    with pytest.raises(ConfigError, match=message):
        build_graph(graph_data(**nodes))


def test_unknown_launch_keys_and_bad_overrides_are_rejected():
    with pytest.raises(ConfigError, match="unknown key"):
        build_graph({"launch": {"modus": "inproc"}, "nodes": {"sim": SIM}})
    with pytest.raises(ConfigError, match="no node"):
        apply_overrides(graph_data(sim=SIM), ["simulator.count=3"])
    with pytest.raises(ConfigError, match="expected NODE.PARAM=VALUE"):
        apply_overrides(graph_data(sim=SIM), ["count=3"])


def test_an_invalid_launch_file_starts_nothing_and_creates_no_run_folder(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[nodes.sim]\ntype = "sim_source"\n[nodes.rec]\ntype = "recorder"\n')
    result = subprocess.run([sys.executable, "-m", "sonar_realism.cli", "launch", str(bad), "--out",
                             str(tmp_path / "run")], capture_output=True, text=True, timeout=PROCESS_TIMEOUT_S)
    assert result.returncode == 2 and "unconnected input" in result.stderr
    assert not (tmp_path / "run").exists()


def test_overrides_and_defaults_end_up_in_the_resolved_config(tmp_path):
    graph = load_graph(REPO / "launch" / "demo.toml", ["sim.count=3", 'translator.device="cpu"', "launch.hwm=4"],
                       out=str(tmp_path))
    config = graph.resolved_config()
    assert config["nodes"]["sim"]["params"]["count"] == 3
    assert config["nodes"]["translator"]["params"]["device"] == "cpu"
    assert config["nodes"]["recorder"]["params"]["path"] == f"{tmp_path}/translated"
    assert config["launch"]["hwm"] == 4 and config["launch"]["out"] == str(tmp_path)
    # consumers start before sources; lossless edges get one PUSH endpoint each
    assert graph.start_order.index("recorder") < graph.start_order.index("translator") < \
        graph.start_order.index("sim")
    assert len(graph.nodes["sim"].wiring.outputs["frames"].push_endpoints) == 3  # translator, recorder, page


def test_shipped_launch_files_are_valid():
    for path in sorted((REPO / "launch").glob("*.toml")):
        graph = load_graph(path)
        assert graph.nodes, path


# ---- running ------------------------------------------------------------------------------------------
def test_a_failed_node_is_restarted_when_asked(tmp_path):
    FlakySink.lives, FlakySink.received = 0, []
    # The source outlives the crash (200 frames through 4-frame socket buffers): frames in flight to the
    # crashed instance are sent again to the restarted one, so it gets the whole stream exactly once.
    graph = build_graph({"launch": {"name": "restart", "out": str(tmp_path), "stop_timeout_s": 2.0,
                                    "ready_timeout_s": 20.0, "hwm": 4},
                         "nodes": {"tick": {"type": "test_launch:Ticker", "params": {"count": 200}},
                                   "sink": {"type": "test_launch:FlakySink", "inputs": {"frames": "tick.frames"},
                                            "restart": "on-failure", "max_restarts": 2}}})
    code, summary = launch(graph, install_signal_handlers=False)
    assert code == 0 and summary["sink"]["restarts"] == 1 and FlakySink.lives == 2
    assert FlakySink.received == list(range(200))
    assert summary["tick"]["totals"]["resent"] >= 1 and summary["sink"]["totals"]["seq_gaps"] == 0
    saved = json.loads((tmp_path / "run_summary.json").read_text())["sink"]
    assert saved["restarts"] == 1 and saved["sessions"] == 2 and saved["totals"]["frames_in"] >= 200


def test_a_failed_node_without_restart_stops_the_launch_with_an_error(tmp_path):
    FlakySink.lives, FlakySink.received = 0, []
    # The source's end of stream is repeated until its consumer hangs up or eos_linger_s passes; the consumer
    # here is dead, so the linger has to end well inside the stop window for the source to exit cleanly. The window
    # is wide (12x the linger) because a loaded 2-core machine once took more than 2 s to get there; a source that
    # exits on time costs nothing of it.
    graph = build_graph({"launch": {"name": "fail", "out": str(tmp_path), "stop_timeout_s": 6.0,
                                    "ready_timeout_s": 20.0, "eos_linger_s": 0.5},
                         "nodes": {"tick": {"type": "test_launch:Ticker", "params": {"count": 1000}},
                                   "sink": {"type": "test_launch:FlakySink", "inputs": {"frames": "tick.frames"}}}})
    code, summary = launch(graph, install_signal_handlers=False)
    assert code == 1 and summary["sink"]["exit_code"] == 1 and summary["tick"]["exit_code"] == 0


def _processes_mentioning(text: str) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                if text in (entry / "cmdline").read_bytes().decode(errors="replace"):
                    found.append(int(entry.name))
            except OSError:
                continue
    return found


def test_cli_runs_the_demo_in_process_mode_end_to_end(tmp_path):
    from test_nodes import tiny_checkpoint

    checkpoint = tiny_checkpoint(tmp_path)
    run = tmp_path / "run"
    result = subprocess.run(
        [sys.executable, "-m", "sonar_realism.cli", "launch", str(REPO / "launch" / "demo.toml"), "--mode", "process",
         "--out", str(run), "--set", "sim.count=2", "--set", f'translator.checkpoint="{checkpoint}"',
         "--set", "translator.n=2", "--set", 'translator.device="cpu"'],
        capture_output=True, text=True, timeout=PROCESS_TIMEOUT_S, cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    translated = list(read_frames(run / "translated"))
    assert [f.seq for f in translated] == [0, 1] and translated[0].intensity.shape[0] == 2
    sha256 = hashlib.sha256(Path(checkpoint).read_bytes()).hexdigest()
    assert [f.meta["provenance"]["checkpoint_sha256"] for f in translated] == [sha256, sha256]
    assert (run / "translated_contact_sheet.png").stat().st_size > 0
    assert len(list(read_frames(run / "simulated"))) == 2
    page = (run / "demo.html").read_text()
    assert page.count("data:image/png;base64,") == 1 and "sample 2" not in page  # labels are inside the PNG
    assert "2 simulated, 2 translated" in page
    resolved = json.loads((run / "resolved.json").read_text())
    assert resolved["launch"]["mode"] == "process" and resolved["nodes"]["sim"]["params"]["count"] == 2
    assert all(item["exit_code"] == 0 for item in json.loads((run / "run_summary.json").read_text()).values())
    assert not _processes_mentioning(str(run))


def test_demo_view_runs_the_viewer_node_on_the_live_streams(tmp_path):
    from test_nodes import tiny_checkpoint

    checkpoint = tiny_checkpoint(tmp_path)
    run = tmp_path / "run"
    result = subprocess.run(
        [sys.executable, "-m", "sonar_realism.cli", "launch", str(REPO / "launch" / "demo_view.toml"), "--out",
         str(run), "--set", "sim.count=3", "--set", "sim.rate_hz=5.0", "--set", "viewer.port=0",
         "--set", f'translator.checkpoint="{checkpoint}"', "--set", "translator.n=2",
         "--set", 'translator.device="cpu"'], capture_output=True, text=True, timeout=PROCESS_TIMEOUT_S, cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    summary = json.loads((run / "run_summary.json").read_text())
    assert summary["viewer"]["exit_code"] == 0 and summary["viewer"]["status"]["frames_in"] >= 2


def test_sigint_to_the_launcher_stops_an_endless_pipeline_cleanly(tmp_path):
    write_frames([SonarImage(np.full((16, 8), i, np.uint8), uniform_ranges(16, 5.0), uniform_azimuths(8, 1.0),
                             seq=i) for i in range(5)], tmp_path / "rec")
    launch_file = tmp_path / "endless.toml"
    launch_file.write_text(f"""
[launch]
mode = "process"
stop_timeout_s = 5.0
[nodes.replay]
type = "file_replay"
params = {{ path = "{tmp_path / 'rec'}", speed = 0.0, loop = true }}
[nodes.recorder]
type = "recorder"
inputs.frames = "replay.frames"
params = {{ path = "{{out}}/copy" }}
""")
    run = tmp_path / "run"
    launcher = subprocess.Popen([sys.executable, "-m", "sonar_realism.cli", "launch", str(launch_file), "--out",
                                 str(run)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        index = run / "copy" / "frames.jsonl"
        deadline = time.monotonic() + PROCESS_TIMEOUT_S
        while not (index.exists() and index.read_text().count("\n") > 20):  # wait for frames to flow
            assert launcher.poll() is None and time.monotonic() < deadline, launcher.stderr.read() if \
                launcher.poll() is not None else "no frames recorded"
            time.sleep(0.05)
        launcher.send_signal(signal.SIGINT)
        _, stderr = launcher.communicate(timeout=PROCESS_TIMEOUT_S)
    finally:
        if launcher.poll() is None:
            launcher.kill()
    assert launcher.returncode == 0, stderr[-3000:]
    copy = list(read_frames(run / "copy"))
    assert len(copy) > 20 and [f.seq for f in copy] == list(range(len(copy)))  # lossless up to the stop
    summary = json.loads((run / "copy.summary.json").read_text())
    assert summary["frames"] == len(copy)
    assert not _processes_mentioning(str(run))


def test_nothing_an_external_publisher_sends_takes_the_translator_down(tmp_path):
    """A simulator plugin's worst day, against a real translator process: every spelling the spec allows is
    translated, everything it forbids is counted, no restart, and its end of stream ends the launch."""
    import threading

    import msgpack
    import zmq
    from test_nodes import tiny_checkpoint

    from sonar_realism.wire import encode_frame

    context = zmq.Context.instance()
    publisher = context.socket(zmq.XPUB)
    publisher.linger = 1000
    endpoint = publisher.bind_to_random_port("tcp://127.0.0.1")
    graph = build_graph({"launch": {"name": "hostile", "mode": "process", "transport": "tcp",
                                    "out": str(tmp_path / "run"), "ready_timeout_s": 60.0},
                         "nodes": {"translator": {"type": "translator", "restart": "on-failure",
                                                  "inputs": {"frames": {"source": f"tcp://127.0.0.1:{endpoint}",
                                                                        "policy": "fifo", "capacity": 64,
                                                                        "max_age_s": 30.0}},
                                                  "params": {"checkpoint": tiny_checkpoint(tmp_path), "n": 2,
                                                             "temperature": 0.0, "device": "cpu", "batch": 4}},
                                   "recorder": {"type": "recorder", "inputs": {"frames": "translator.frames"},
                                                "params": {"path": "{out}/translated"}}}})
    result: list = []
    runner = threading.Thread(target=lambda: result.append(launch(graph, install_signal_handlers=False)))
    runner.start()
    try:
        assert publisher.poll(PROCESS_TIMEOUT_S * 1000), "the translator never subscribed"
        publisher.recv()
        values = np.random.default_rng(0).random((40, 24))
        ranges, bearings = uniform_ranges(40, 12.0), uniform_azimuths(24, 2.0)

        def frame(seq, intensity, **fields):
            return encode_frame(SonarImage(intensity, ranges, bearings, seq=seq, **fields), "sonar/sim")

        def with_header(parts, **changes):
            header = {**msgpack.unpackb(bytes(parts[1])), **changes}
            return [parts[0], msgpack.packb(header, use_bin_type=True, datetime=False), parts[2]]

        nan = values.astype(np.float32)
        nan[3, 3] = np.nan
        messages = [
            frame(0, values.astype("<f4")),
            frame(1, values.astype(">f4")),
            frame(2, np.round(values * 65535).astype(">u2")),
            frame(3, values.astype(">f8")),
            frame(4, np.round(values * 255).astype(np.uint8)[None]),               # [1, ranges, beams]
            frame(5, values.astype("<f4"), stamp_ns=1_000_000_000),               # simulation time
            frame(6, np.stack([values, values]).astype("<f4")),                   # 2 samples: cannot translate
            with_header(frame(7, values.astype("<f4")), meta={"t": msgpack.Timestamp(5, 0)}),
            [b"sonar/sim", b"\xc1 garbage", b""],
            with_header(frame(8, values.astype("<f4")), dtype="<f4")[:2] + [nan.tobytes()],
            [b"sonar/sim2", *frame(9, values.astype("<f4"))[1:]],                 # a topic nobody takes
        ]
        for parts in messages:
            publisher.send_multipart(parts, copy=False)
        publisher.send_multipart([b"sonar/sim", msgpack.packb(
            {"v": 1, "type": "status", "status": {"node": "sim", "state": "stopped", "end_of_stream": True}})])
        runner.join(PROCESS_TIMEOUT_S)
    finally:
        publisher.close()
    assert not runner.is_alive() and result, "the launch did not end on the publisher's end of stream"
    code, summary = result[0]
    assert code == 0 and summary["translator"]["restarts"] == 0
    totals = summary["translator"]["totals"]
    assert totals["malformed"] == 4 and totals["other_topic"] == 1 and totals["stale"] == 0
    translated = {f.seq: f.intensity for f in read_frames(tmp_path / "run" / "translated")}
    assert sorted(translated) == [0, 1, 2, 3, 4, 5]
    for seq in (1, 2, 3, 4, 5):  # every byte order and the sample axis translate like the plain float frame
        np.testing.assert_allclose(translated[seq], translated[0], atol=0.02)


def test_a_status_endpoint_can_be_fixed_in_the_launch_file(tmp_path):
    graph = build_graph({"launch": {"name": "s", "out": str(tmp_path)},
                         "nodes": {"sim": {**SIM, "bind": {"status": "tcp://127.0.0.1:5599"}}}})
    assert graph.nodes["sim"].wiring.status_endpoint == "tcp://127.0.0.1:5599"
    assert graph.resolved_config()["nodes"]["sim"]["wiring"]["status_endpoint"] == "tcp://127.0.0.1:5599"


def test_nodes_install_under_the_projects_name_and_never_as_a_top_level_nodes_package(monkeypatch):
    import runpy

    import setuptools

    captured: dict = {}
    monkeypatch.setattr(setuptools, "setup", lambda **kwargs: captured.update(kwargs))
    monkeypatch.chdir(REPO)
    runpy.run_path(str(REPO / "setup.py"))
    assert "sonar_realism_nodes" in captured["packages"] and "sonar_realism.runtime" in captured["packages"]
    assert not any(p == "nodes" or p.startswith("nodes.") for p in captured["packages"])
    assert (REPO / captured["package_dir"]["sonar_realism_nodes"] / "translator.py").is_file()
    from sonar_realism.runtime.graph import resolve_node_type

    assert resolve_node_type("translator").__module__ == "sonar_realism_nodes.translator"


def kill_mid_run(runner, run: Path, node: str, index: Path, frames: int = 300) -> int:
    """Once `index` lists `frames` frames (under load, mid-run), SIGKILL node `node`'s process and wait for the
    launch `runner` to end; returns how many frames the index listed just before the kill."""
    deadline = time.monotonic() + PROCESS_TIMEOUT_S
    while not (index.exists() and index.read_text().count("\n") >= frames):
        assert runner.is_alive() and time.monotonic() < deadline, "no frames flowed"
        time.sleep(0.02)
    listed = index.read_text().count("\n") - 1
    processes = _processes_mentioning(str(run / "nodes" / f"{node}.json"))
    assert len(processes) == 1
    os.kill(processes[0], signal.SIGKILL)
    runner.join(PROCESS_TIMEOUT_S)
    return listed

def test_lossless_edges_lose_nothing_when_the_translator_is_killed_mid_run(tmp_path):
    """SIGKILL the translator process while frames are in flight: the restarted one gets every frame it had
    not passed on, the recorder drops what it already had, and all 2,000 frames arrive exactly once, in order."""
    import threading

    from test_nodes import tiny_checkpoint

    count = 2000
    write_frames((SonarImage(np.full((32, 16), i % 251, np.uint8), uniform_ranges(32, 5.0), uniform_azimuths(16, 1.0),
                             seq=i) for i in range(count)), tmp_path / "rec")
    run = tmp_path / "run"
    graph = build_graph({"launch": {"name": "kill", "mode": "process", "out": str(run), "ready_timeout_s": 60.0},
                         "nodes": {"replay": {"type": "file_replay", "params": {"path": str(tmp_path / "rec"),
                                                                                "speed": 0.0}},
                                   "translator": {"type": "translator", "inputs": {"frames": "replay.frames"},
                                                  "restart": "on-failure",
                                                  "params": {"checkpoint": tiny_checkpoint(tmp_path), "n": 1,
                                                             "seed": 0, "device": "cpu", "batch": 4}},
                                   "recorder": {"type": "recorder", "inputs": {"frames": "translator.frames"},
                                                "params": {"path": "{out}/translated"}}}})
    result: list = []
    runner = threading.Thread(target=lambda: result.append(launch(graph, install_signal_handlers=False)))
    runner.start()
    kill_mid_run(runner, run, "translator", run / "translated" / "frames.jsonl")
    assert not runner.is_alive() and result
    code, summary = result[0]
    assert code == 0 and summary["translator"]["restarts"] == 1
    assert [f.seq for f in read_frames(run / "translated")] == list(range(count))
    assert summary["replay"]["totals"]["resent"] > 0  # the killed translator had frames in flight


def test_a_recorder_killed_mid_run_goes_on_with_its_recording(tmp_path):
    """SIGKILL the recorder while frames flow: the restarted one keeps what is on disk, skips what comes again over
    the lossless edge and goes on. Only frames it had queued but not yet written can be missing (docs/nodes.md)."""
    import threading

    count = 2000
    write_frames((SonarImage(np.full((32, 16), i % 251, np.uint8), uniform_ranges(32, 5.0), uniform_azimuths(16, 1.0),
                             seq=i) for i in range(count)), tmp_path / "rec")
    run = tmp_path / "run"
    graph = build_graph({"launch": {"name": "kill_recorder", "mode": "process", "out": str(run),
                                    "ready_timeout_s": 60.0},
                         "nodes": {"replay": {"type": "file_replay", "params": {"path": str(tmp_path / "rec"),
                                                                                "speed": 0.0}},
                                   "recorder": {"type": "recorder", "inputs": {"frames": "replay.frames"},
                                                "restart": "on-failure", "params": {"path": "{out}/copy"}}}})
    result: list = []
    runner = threading.Thread(target=lambda: result.append(launch(graph, install_signal_handlers=False)))
    runner.start()
    before = kill_mid_run(runner, run, "recorder", run / "copy" / "frames.jsonl")
    assert not runner.is_alive() and result
    code, summary = result[0]
    assert code == 0 and summary["recorder"]["restarts"] == 1
    seqs = [f.seq for f in read_frames(run / "copy")]
    assert seqs[:before] == list(range(before))  # what was on disk before the kill is still there
    assert seqs == sorted(set(seqs)) and seqs[-1] == count - 1
    assert len(seqs) >= count - 100  # at most the writer's backlog and one batch were queued and not written


def test_a_frame_larger_than_the_translators_bound_is_refused_alone(tmp_path):
    from test_nodes import tiny_checkpoint

    sizes = [(32, 16), (64, 64), (32, 16)]  # the middle one is 4096 pixels, over a bound of 1024
    frames = (SonarImage(np.full(shape, 9, np.uint8), uniform_ranges(shape[0], 5.0), uniform_azimuths(shape[1], 1.0),
                         seq=i) for i, shape in enumerate(sizes))
    write_frames(frames, tmp_path / "rec")
    run = tmp_path / "run"
    graph = build_graph({"launch": {"name": "bound", "mode": "inproc", "out": str(run)},
                         "nodes": {"replay": {"type": "file_replay", "params": {"path": str(tmp_path / "rec"),
                                                                                "speed": 0.0}},
                                   "translator": {"type": "translator", "inputs": {"frames": "replay.frames"},
                                                  "params": {"checkpoint": tiny_checkpoint(tmp_path), "n": 1,
                                                             "seed": 0, "device": "cpu", "max_pixels": 1024}},
                                   "recorder": {"type": "recorder", "inputs": {"frames": "translator.frames"},
                                                "params": {"path": "{out}/translated"}}}})
    code, summary = launch(graph, install_signal_handlers=False)
    assert code == 0 and summary["translator"]["totals"]["malformed"] == 1
    assert [f.seq for f in read_frames(run / "translated")] == [0, 2]
