"""`sonar-realism launch FILE [--set node.param=value] [--out DIR] [--mode inproc|process]`.

Reads a TOML launch file (format: sonar_realism/runtime/graph.py, docs/nodes.md), checks the whole
graph before starting anything, saves the resolved configuration in the run folder (resolved.json),
runs it, and writes each node's last status to run_summary.json. Ctrl-C (or SIGTERM) shuts down in
order; a second Ctrl-C is handled the same way (the escalation is the launcher's job, not the user's).
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import signal
import threading
import tomllib
from pathlib import Path
from typing import Any

from sonar_realism.errors import ConfigError
from sonar_realism.runtime.graph import LaunchGraph, apply_overrides, build_graph
from sonar_realism.runtime.supervisor import Supervisor


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="launch file (TOML), e.g. launch/demo.toml")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="NODE.PARAM=VALUE",
                        help="override a node parameter (TOML value syntax) or launch.KEY; repeatable")
    parser.add_argument("--out", default=None, help="run folder (default: the file's launch.out)")
    parser.add_argument("--mode", choices=("inproc", "process"), default=None,
                        help="inproc: nodes are threads of this process; process: one process per node")
    parser.add_argument("--check", action="store_true", help="validate the graph and print it; start nothing")


def load_graph(path: Path, overrides: list[str] = (), out: str | None = None,  # type: ignore[assignment]
               mode: str | None = None) -> LaunchGraph:
    try:
        data: dict[str, Any] = tomllib.loads(Path(path).read_text())
    except FileNotFoundError as error:
        raise ConfigError(f"{path}: no such launch file") from error
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: not valid TOML: {error}") from error
    overrides = list(overrides) + ([f"launch.mode=\"{mode}\""] if mode else [])
    try:
        return build_graph(apply_overrides(data, overrides), out)
    except ConfigError as error:
        raise ConfigError(f"{path}: {error}") from error


def launch(graph: LaunchGraph, install_signal_handlers: bool = True) -> tuple[int, dict[str, Any]]:
    """Run `graph` to the end; returns (exit code, per-node summary). Writes resolved.json first."""
    run_dir = Path(graph.settings.out)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "resolved.json").write_text(json.dumps(graph.resolved_config(), indent=2))
    supervisor = Supervisor(graph, run_dir)
    previous = {}
    if install_signal_handlers and threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGINT, signal.SIGTERM):
            previous[signum] = signal.signal(signum, lambda *_: supervisor.request_stop())
    try:
        code = supervisor.run()
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if graph.ipc_dir:
            shutil.rmtree(graph.ipc_dir, ignore_errors=True)
    summary = supervisor.summary()
    (run_dir / "run_summary.json").write_text(json.dumps(summary, indent=2, default=str))
    return code, summary


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    graph = load_graph(args.file, args.overrides, args.out, args.mode)
    if args.check:
        print(json.dumps(graph.resolved_config(), indent=2))
        if graph.ipc_dir:
            shutil.rmtree(graph.ipc_dir, ignore_errors=True)
        return 0
    code, summary = launch(graph)
    for name, item in summary.items():
        totals, status = item["totals"], item["status"] or {}
        print(f"{name:>14}: exit {item['exit_code']}, restarts {item['restarts']}, in {totals['frames_in']}, "
              f"out {totals['frames_out']}, dropped {totals['dropped']}, stale {totals['stale']}, "
              f"seq gaps {totals['seq_gaps']}, malformed {totals['malformed']}, other topic {totals['other_topic']}, "
              f"resent {totals['resent']}, inference {status.get('inference_ms', 0.0):.1f} ms/frame")
    print(f"run folder: {graph.settings.out}")
    return code
