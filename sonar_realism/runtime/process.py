"""Entry point of one node process (process mode): `python -m sonar_realism.runtime.process SPEC.json`.

SIGINT and SIGTERM ask the node to stop: it finishes the frame at hand, sends end of stream and exits 0.
The node also stops by itself when its launcher disappears (Wiring.exit_with_parent), so a killed
launcher leaves no orphans behind. Thread pools wait passively in node processes (docs/nodes.md).
"""

from __future__ import annotations

import json
import logging
import os
import signal
import sys
from pathlib import Path
from typing import Any

from sonar_realism.config import from_dict
from sonar_realism.runtime.graph import resolve_node_type
from sonar_realism.runtime.wiring import Wiring


def node_spec(name: str, type_name: str, params: dict[str, Any], wiring: Wiring) -> str:
    """The JSON a launcher writes for one node process."""
    return json.dumps({"name": name, "type": type_name, "params": params, "wiring": wiring.to_json()})


# Thread pools that otherwise spin after every call, taking the cores that the sockets and the other nodes need:
# torch's OpenMP workers, and OpenCV's own pool (cv2.remap/GaussianBlur in the translator), whose workers call
# sched_yield ~2000 times before they sleep. Read when the library loads: a node imports torch and cv2 only in
# configure(), after main() has set these (a value already in the environment wins).
PASSIVE_THREAD_POOLS = {
    "OMP_WAIT_POLICY": "PASSIVE",
    "OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER": "0",
    "OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN": "0",
}


def use_passive_thread_pools() -> None:
    """PASSIVE_THREAD_POOLS in this process's environment, where not set already (before torch or cv2 loads)."""
    for name, value in PASSIVE_THREAD_POOLS.items():
        os.environ.setdefault(name, value)


# Set to "1" by the launcher for a node it starts again after a failure (Node.restarted).
RESTARTED_ENV = "SONAR_REALISM_RESTARTED"


def main(argv: list[str]) -> int:
    use_passive_thread_pools()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    spec = json.loads(Path(argv[0]).read_text())
    node_class = resolve_node_type(spec["type"])
    params = from_dict(node_class.PARAMS, spec["params"], f"nodes.{spec['name']}.params")
    node = node_class(spec["name"], params, Wiring.from_json(spec["wiring"]))
    node.restarted = os.environ.get(RESTARTED_ENV) == "1"

    def stop(signum: int, _frame: object) -> None:
        logging.getLogger(__name__).info("node %s: signal %d, stopping", spec["name"], signum)
        node.request_stop()

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    # SIGUSR1 from the launcher: every in-graph producer of this node has exited (see Node.producers_finished).
    signal.signal(signal.SIGUSR1, lambda *_: node.producers_finished())
    try:
        node.run()
    except Exception:
        logging.getLogger(__name__).exception("node %s failed", spec["name"])
        return 1
    finally:
        # A late notice while the interpreter shuts down (handlers reset to default) must not kill us.
        signal.signal(signal.SIGUSR1, signal.SIG_IGN)
        # Zero-copy sends still lingering on closed sockets point into our arrays: wait for libzmq to finish
        # with them (up to each socket's linger) before the interpreter frees the arrays, or its I/O thread
        # reads freed memory and aborts ("Bad address (src/tcp.cpp)").
        node.context.destroy(linger=0)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
