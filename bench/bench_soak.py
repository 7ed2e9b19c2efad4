"""Soak: 20,000 frames through replay -> translator -> recorder (process mode, lossless edges, real sockets),
watching each node process's resident memory and open file descriptors.

    python bench/bench_soak.py [--frames 20000]          (or: python bench/run.py soak; takes minutes)

The recording is 20,000 distinct 32 x 16 uint8 frames in one NPZ file; the translator runs a tiny cDFCVAE
checkpoint (the soak is about the runtime, not the model) with n = 1; the recorder writes a frames folder
(streamed; an NPZ recording keeps every frame's metadata in memory until it is closed, by design). Every SAMPLE_S
this process reads VmRSS and the fd count of each node from /proc. Warm-up = until the replay has published
WARMUP_FRACTION of the frames (its status messages say how many); growth = (RSS at the end of the run - RSS
right after warm-up) / RSS right after warm-up, per node, "end" being the last reading before the replay has
published END_FRACTION of the frames (later ones catch nodes shutting down). Goal (issue): < 5 % growth after
warm-up, no fd growth, under 10 minutes.
"""

# No `from __future__ import annotations`: bench/run.py loads this file without putting it in sys.modules.
import argparse
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zmq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges  # noqa: E402
from sonar_realism.io import write_frames  # noqa: E402
from sonar_realism.runtime.graph import build_graph  # noqa: E402
from sonar_realism.runtime.launch import launch  # noqa: E402
from sonar_realism.wire import decode_message  # noqa: E402

FRAMES = 20_000
SAMPLE_S = 0.5
WARMUP_FRACTION = 0.1
END_FRACTION = 0.95  # "end" readings stop here: the replay reports by heartbeat, and finishing nodes close fds
GOAL_GROWTH = 0.05
NODES = ("replay", "translator", "recorder")


def node_pids(run_dir: Path) -> dict[str, int]:
    """PIDs of this run's node processes, found by the spec file on their command line."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            command = (entry / "cmdline").read_bytes().decode(errors="replace")
        except OSError:
            continue
        for name in NODES:
            if str(run_dir / "nodes" / f"{name}.json") in command:
                found[name] = int(entry.name)
    return found


def rss_and_fds(pid: int) -> tuple[float, int] | None:
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        fds = len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None
    kib = [int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS:")]
    return (kib[0] / 1024.0, fds) if kib else None  # no VmRSS: the process has exited (a zombie)


def make_recording(path: Path, frames: int) -> None:
    rng = np.random.default_rng(0)
    ranges, bearings = uniform_ranges(32, 5.0), uniform_azimuths(16, 1.0)
    write_frames((SonarImage(rng.integers(0, 255, (32, 16), np.uint8), ranges, bearings, seq=i,
                             stamp_ns=1_700_000_000_000_000_000 + i * 100_000_000) for i in range(frames)), path)


def run(frames: int = FRAMES) -> list[dict]:
    from test_nodes import tiny_checkpoint  # a real, tiny cDFCVAE checkpoint

    with tempfile.TemporaryDirectory(prefix="bench-soak-") as folder:
        folder = Path(folder)
        make_recording(folder / "input.npz", frames)
        run_dir = folder / "run"
        graph = build_graph({
            "launch": {"name": "soak", "mode": "process", "out": str(run_dir), "ready_timeout_s": 120.0},
            "nodes": {"replay": {"type": "file_replay", "params": {"path": str(folder / "input.npz"), "speed": 0.0}},
                      "translator": {"type": "translator", "inputs": {"frames": "replay.frames"},
                                     "params": {"checkpoint": tiny_checkpoint(folder), "n": 1, "seed": 0,
                                                "device": "cpu", "batch": 4}},
                      "recorder": {"type": "recorder", "inputs": {"frames": "translator.frames"},
                                   "params": {"path": "{out}/translated", "sheet_tiles": 4}}}})
        status = zmq.Context.instance().socket(zmq.SUB)  # the replay's heartbeat says how far it got
        status.linger = 0
        status.setsockopt(zmq.SUBSCRIBE, b"replay/status")
        status.connect(graph.nodes["replay"].wiring.status_endpoint)
        result: list = []
        start = time.monotonic()
        runner = threading.Thread(target=lambda: result.append(launch(graph, install_signal_handlers=False)))
        runner.start()
        samples: dict[str, list[tuple[float, float, int]]] = {name: [] for name in NODES}  # (t, rss MiB, fds)
        pids: dict[str, int] = {}
        warm_at: float | None = None
        published = 0
        done_at: float | None = None
        while runner.is_alive():
            pids = pids or (node_pids(run_dir) if len(node_pids(run_dir)) == len(NODES) else {})
            now = time.monotonic() - start
            for name, pid in pids.items():
                reading = rss_and_fds(pid)
                if reading is not None:
                    samples[name].append((now, *reading))
            while status.poll(0):
                published = decode_message(status.recv_multipart()).body.get("frames_out", published)
            if warm_at is None and published >= WARMUP_FRACTION * frames:
                warm_at = now
            if done_at is None and published >= END_FRACTION * frames:
                done_at = now
            runner.join(SAMPLE_S)
        elapsed = time.monotonic() - start
        status.close()
        code, summary = result[0]
    rows = []
    for name in NODES:
        after_warmup = [s for s in samples[name] if warm_at is not None and warm_at <= s[0] <= (done_at or 1e9)]
        if len(after_warmup) < 2:
            rows.append({"node": name, "note": "too few samples after warm-up"})
            continue
        first, last = after_warmup[0], after_warmup[-1]
        peak = max(s[1] for s in after_warmup)
        growth = (last[1] - first[1]) / first[1]
        rows.append({
            "node": name, "frames": frames, "exit": code, "restarts": summary[name]["restarts"],
            "frames_in": summary[name]["totals"]["frames_in"], "frames_out": summary[name]["totals"]["frames_out"],
            "run_s": elapsed, "warm-up_s": warm_at, "rss_after_warmup_MiB": first[1], "rss_end_MiB": last[1],
            "rss_peak_MiB": peak, "rss_growth_%": 100.0 * growth,
            "fds_after_warmup": first[2], "fds_end": last[2], "fds_max": max(s[2] for s in after_warmup),
            "goal": f"growth < {100 * GOAL_GROWTH:g} %, no fd growth, < 600 s",
            "verdict": "met" if growth < GOAL_GROWTH and last[2] <= first[2] and elapsed < 600 else "missed",
        })
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=FRAMES)
    args = parser.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from run import markdown

    print(markdown(run(args.frames)))
