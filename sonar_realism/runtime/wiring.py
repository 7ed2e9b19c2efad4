"""Where a node's inputs and outputs live on the network: the part of a node's setup the launcher decides.

Socket pattern per edge, chosen by the consumer's delivery policy (the policy decides who waits):
- `latest` / `fifo`: the producer binds an XPUB, consumers connect a SUB. The producer never waits for
  a slow consumer; the consumer loses frames (counted). XPUB shows the producer each subscription, so a
  source holds its first frame until every in-graph subscriber is there (no slow-joiner loss, no sleeps).
- `lossless`: the producer binds one PUSH per consumer edge, the consumer connects a PULL. A PUSH
  send waits until the peer is connected and has room, so nothing is dropped and a slow consumer
  slows the producer down (backpressure). In a launch each such edge also has an acknowledgement
  channel back (producer binds a PULL, consumer connects a PUSH), so frames survive a consumer crash
  (runtime/lossless.py).
A node's status/heartbeat goes out on its own XPUB (`<node>/status`).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any

from sonar_realism.runtime.delivery import InputPolicy


@dataclass(frozen=True)
class InputWiring:
    """One input: connect to `endpoint` and take messages whose topic is exactly `topic`."""

    endpoint: str
    topic: str
    policy: InputPolicy = field(default_factory=InputPolicy)
    in_graph: bool = False  # produced by a node of the same launch (the launcher reports when it has ended)
    ack_endpoint: str = ""  # lossless in-graph edges: where acknowledgements go (runtime/lossless.py)

    @property
    def socket_kind(self) -> str:
        return "pull" if self.policy.policy == "lossless" else "sub"


@dataclass(frozen=True)
class OutputWiring:
    """One output: an XPUB at `pub_endpoint` for best-effort consumers (and anyone outside the graph),
    plus one PUSH per lossless consumer. `expected_subscribers` in-graph SUBs are awaited before sending.
    `ack_endpoints[i]` (when given) is where the consumer of `push_endpoints[i]` acknowledges frames; the
    producer then keeps up to `4 * hwm` unacknowledged frames to send again after a consumer restart."""

    topic: str
    pub_endpoint: str
    expected_subscribers: int = 0
    push_endpoints: tuple[str, ...] = ()
    ack_endpoints: tuple[str, ...] = ()
    hwm: int = 16


@dataclass(frozen=True)
class Wiring:
    inputs: dict[str, InputWiring] = field(default_factory=dict)
    outputs: dict[str, OutputWiring] = field(default_factory=dict)
    status_endpoint: str = ""
    status_subscribers: int = 0
    heartbeat_s: float = 1.0
    ready_timeout_s: float = 120.0
    eos_linger_s: float = 5.0
    exit_with_parent: bool = False

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> Wiring:
        data: dict[str, Any] = json.loads(text)
        inputs = {name: InputWiring(**{**w, "policy": InputPolicy(**w["policy"])})
                  for name, w in data.pop("inputs").items()}
        outputs = {name: OutputWiring(**{**w, "push_endpoints": tuple(w["push_endpoints"]),
                                         "ack_endpoints": tuple(w["ack_endpoints"])})
                   for name, w in data.pop("outputs").items()}
        return cls(inputs=inputs, outputs=outputs, **data)
