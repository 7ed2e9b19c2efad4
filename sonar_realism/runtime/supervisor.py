"""Runs a LaunchGraph: starts consumers before sources, restarts failed nodes when asked, collects
status, and shuts down in reverse order (sources first, so end of stream flushes the pipeline),
escalating SIGINT -> SIGTERM -> SIGKILL for node processes.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import zmq

from sonar_realism.config import to_dict
from sonar_realism.errors import WireError
from sonar_realism.runtime.graph import LaunchGraph, ResolvedNode
from sonar_realism.runtime.process import RESTARTED_ENV, node_spec
from sonar_realism.wire import STATUS_TYPE, decode_message

log = logging.getLogger(__name__)

# Status counters that add up over a node's lives: run_summary.json reports their sum over every session
# (a restarted node starts counting from 0 again).
SUMMED_COUNTERS = ("frames_in", "frames_out", "dropped", "stale", "seq_gaps", "out_of_order", "malformed",
                   "other_topic", "duplicates", "resent")


class ThreadWorker:
    """A node running as a thread of the launcher (inproc mode). Threads cannot be killed: a node that
    ignores its stop request is reported and left to die with the process (daemon thread)."""

    def __init__(self, node: ResolvedNode, context: zmq.Context, run_dir: Path, restarted: bool = False) -> None:
        self.spec = node
        self.context = context
        self.error: BaseException | None = None
        self.instance = node.node_class(node.name, node.params, node.wiring, context)
        self.instance.restarted = restarted
        self.thread = threading.Thread(target=self._run, name=f"node:{node.name}", daemon=True)

    def _run(self) -> None:
        try:
            self.instance.run()
        except BaseException as error:  # reported by exit_code; the supervisor decides about restarts
            self.error = error
            log.exception("node %s failed", self.spec.name)

    def start(self) -> None:
        self.thread.start()

    @property
    def exit_code(self) -> int | None:
        if self.thread.is_alive():
            return None
        return 1 if self.error is not None else 0

    def interrupt(self) -> None:
        self.instance.request_stop()

    def producers_finished(self) -> None:
        self.instance.producers_finished()

    def terminate(self) -> None:
        self.instance.request_stop()

    def kill(self) -> None:
        log.error("node %s (thread) did not stop; it is abandoned", self.spec.name)

    def wait(self, timeout_s: float) -> bool:
        self.thread.join(timeout_s)
        return not self.thread.is_alive()


class ProcessWorker:
    """A node as its own OS process (process mode), logging to <run>/logs/<node>.log."""

    def __init__(self, node: ResolvedNode, context: zmq.Context, run_dir: Path, restarted: bool = False) -> None:
        self.spec = node
        spec_path = run_dir / "nodes" / f"{node.name}.json"
        spec_path.parent.mkdir(parents=True, exist_ok=True)
        spec_path.write_text(node_spec(node.name, node.type, to_dict(node.params), node.wiring))
        log_path = run_dir / "logs" / f"{node.name}.log"
        log_path.parent.mkdir(parents=True, exist_ok=True)
        self.log_file = open(log_path, "ab")  # noqa: SIM115 - closed in wait()/when the process ends
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p),
               RESTARTED_ENV: "1" if restarted else "0"}
        self.command = [sys.executable, "-m", "sonar_realism.runtime.process", str(spec_path)]
        self.env = env
        self.process: subprocess.Popen | None = None

    def start(self) -> None:
        # Own session: a Ctrl-C in the terminal reaches the launcher only, which stops nodes in order.
        self.process = subprocess.Popen(self.command, env=self.env, stdout=self.log_file, stderr=subprocess.STDOUT,
                                        start_new_session=True)

    @property
    def exit_code(self) -> int | None:
        assert self.process is not None
        code = self.process.poll()
        if code is not None and not self.log_file.closed:
            self.log_file.close()
        return code

    def _signal(self, signum: int) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signum)

    def interrupt(self) -> None:
        self._signal(signal.SIGINT)

    def producers_finished(self) -> None:
        self._signal(signal.SIGUSR1)

    def terminate(self) -> None:
        self._signal(signal.SIGTERM)

    def kill(self) -> None:
        self._signal(signal.SIGKILL)

    def wait(self, timeout_s: float) -> bool:
        assert self.process is not None
        try:
            self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            return False
        self.exit_code  # noqa: B018 - closes the log file
        return True


class Supervisor:
    def __init__(self, graph: LaunchGraph, run_dir: Path, context: zmq.Context | None = None) -> None:
        self.graph = graph
        self.run_dir = run_dir
        self.context = context or zmq.Context.instance()
        self.worker_class = ThreadWorker if graph.settings.mode == "inproc" else ProcessWorker
        self._told_producers_ended: set[tuple[str, int]] = set()  # (node, restart) already told
        self._sessions_at_start: dict[str, int] = {}  # sessions heard from a node when it was last started
        self.workers: dict[str, ThreadWorker | ProcessWorker] = {}
        self.restarts: dict[str, int] = dict.fromkeys(graph.nodes, 0)
        self.exit_codes: dict[str, int] = {}
        self.last_status: dict[str, dict[str, Any]] = {}
        self.sessions: dict[str, dict[str, dict[str, Any]]] = {name: {} for name in graph.nodes}
        self._stop = threading.Event()
        self._status_socket: zmq.Socket | None = None

    def request_stop(self) -> None:
        """Thread- and signal-safe: begin an orderly shutdown."""
        self._stop.set()

    def run(self) -> int:
        """Run until every node has ended; 0 if all ended cleanly, 1 if any failed for good."""
        self._status_socket = self.context.socket(zmq.SUB)
        self._status_socket.linger = 0
        self._status_socket.setsockopt(zmq.SUBSCRIBE, b"")
        try:
            for node in self.graph.nodes.values():
                self._status_socket.connect(node.wiring.status_endpoint)
            for name in self.graph.start_order:
                self._start(name)
            failed = self._supervise()
            if failed or self._stop.is_set():
                self._shutdown()
            self._collect_status(0.2)
            return 1 if failed or any(code != 0 for code in self.exit_codes.values()) else 0
        finally:
            for worker in self.workers.values():
                if worker.exit_code is None:
                    worker.kill()
            self._status_socket.close()

    def _start(self, name: str) -> None:
        worker = self.worker_class(self.graph.nodes[name], self.context, self.run_dir, self.restarts[name] > 0)
        self._sessions_at_start[name] = len(self.sessions[name])
        worker.start()
        self.workers[name] = worker
        log.info("started %s (%s)", name, self.graph.nodes[name].type)

    def _supervise(self) -> bool:
        """Watch the nodes; True if one failed and could not be restarted."""
        while not self._stop.is_set():
            self._collect_status(0.05)
            running = 0
            for name, worker in list(self.workers.items()):
                if name in self.exit_codes:
                    continue
                code = worker.exit_code
                if code is None:
                    running += 1
                    continue
                node = self.graph.nodes[name]
                if code != 0 and node.restart == "on-failure" and self.restarts[name] < node.max_restarts:
                    self.restarts[name] += 1
                    log.warning("node %s exited with %s; restart %d/%d", name, code, self.restarts[name],
                                node.max_restarts)
                    self._start(name)
                    running += 1
                    continue
                self.exit_codes[name] = code
                if code != 0:
                    log.error("node %s failed (exit %s); stopping the launch", name, code)
                    return True
            if running == 0:
                return False
            self._tell_consumers_whose_producers_ended()
        return False

    def _tell_consumers_whose_producers_ended(self) -> None:
        """Only a restarted node can have lost its end of stream (in flight when it crashed); tell it, once its new
        session has reported (before, a process has not yet set up its signal handlers, and the signal's default
        action would end it)."""
        for name, worker in self.workers.items():
            node = self.graph.nodes[name]
            start = (name, self.restarts[name])
            if (node.producers and self.restarts[name] and start not in self._told_producers_ended
                    and len(self.sessions[name]) > self._sessions_at_start[name]
                    and name not in self.exit_codes and all(p in self.exit_codes for p in node.producers)):
                self._told_producers_ended.add(start)
                worker.producers_finished()

    def _shutdown(self) -> None:
        """Sources first: their end of stream lets the rest drain by itself; then escalate, in order."""
        timeout = self.graph.settings.stop_timeout_s
        order = [n for n in reversed(self.graph.start_order) if n in self.workers and n not in self.exit_codes]
        for name in order:
            if self.graph.nodes[name].is_source:
                self.workers[name].interrupt()
        for name in order:
            worker = self.workers[name]
            if not worker.wait(timeout):
                for step in (worker.interrupt, worker.terminate, worker.kill):
                    log.warning("node %s still running: %s", name, step.__name__)
                    step()
                    if worker.wait(timeout):
                        break
            code = worker.exit_code
            self.exit_codes[name] = -9 if code is None else code

    def _collect_status(self, timeout_s: float) -> None:
        assert self._status_socket is not None
        if not self._status_socket.poll(timeout_s * 1000):
            return
        while True:
            try:
                parts = self._status_socket.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            try:
                message = decode_message(parts)
            except WireError:
                continue
            if message.kind == STATUS_TYPE and message.body["node"] in self.sessions:
                body = message.body
                self.last_status[body["node"]] = body
                self.sessions[body["node"]][str(body.get("session", ""))] = body

    def summary(self) -> dict[str, Any]:
        """Per node: exit code, restarts, `totals` (SUMMED_COUNTERS over all its sessions, i.e. restarts
        included) and `status` (the last status message of its last session)."""
        return {name: {"exit_code": self.exit_codes.get(name), "restarts": self.restarts[name],
                       "sessions": len(self.sessions[name]),
                       "totals": {key: sum(int(s.get(key, 0)) for s in self.sessions[name].values())
                                  for key in SUMMED_COUNTERS},
                       "status": self.last_status.get(name)} for name in self.graph.nodes}
