"""Launch files: a graph of nodes, checked completely before anything starts, with endpoints assigned.

```toml
[launch]                     # all optional
name = "demo"
mode = "inproc"              # inproc: every node a thread of one process; process: one OS process each
transport = "ipc"            # process mode: ipc (one host) or tcp
host = "127.0.0.1"           # tcp binds here; loopback unless you mean to serve other hosts
out = "out/demo"             # run folder; "{out}" in any string parameter becomes this folder

[nodes.sim]
type = "sim_source"          # module sonar_realism_nodes.sim_source, or "package.module", or "module:Class"
params = { count = 8 }
bind = { frames = "tcp://0.0.0.0:5601" }   # optional fixed endpoint of an output (other hosts connect)
                             # bind.status: a fixed endpoint for the node's status messages
restart = "on-failure"       # or "never" (default); at most max_restarts times

[nodes.translator]
type = "translator"
inputs.frames = "sim.frames"                                   # lossless by default inside the graph
# inputs.frames = { source = "sim.frames", policy = "latest" } # or latest / fifo (capacity), max_age_s
# inputs.frames = { source = "tcp://127.0.0.1:5555", topic = "sonar/sim" }   # an external publisher
```
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import itertools
import os
import re
import socket
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from sonar_realism.config import from_dict, to_dict
from sonar_realism.errors import ConfigError
from sonar_realism.runtime.delivery import InputPolicy
from sonar_realism.runtime.node import Node
from sonar_realism.runtime.wiring import InputWiring, OutputWiring, Wiring

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_-]*$")
_ENDPOINT = re.compile(r"^(tcp|ipc|inproc)://")
_run_counter = itertools.count()
NODES_PACKAGE = "sonar_realism_nodes"  # the repository's nodes/ folder (setup.py)
STATUS_BIND = "status"  # `bind.status` fixes where a node publishes its status messages


@dataclass(frozen=True)
class LaunchSettings:
    name: str = "launch"
    mode: Literal["inproc", "process"] = "inproc"
    transport: Literal["ipc", "tcp"] = "ipc"
    host: str = "127.0.0.1"
    out: str = "out/launch"
    heartbeat_s: float = 1.0
    ready_timeout_s: float = 120.0
    stop_timeout_s: float = 5.0   # each escalation step of a shutdown: SIGINT, then SIGTERM, then SIGKILL
    eos_linger_s: float = 5.0
    hwm: int = 16                 # per-socket high-water mark (frames) of every edge

    def validate(self) -> None:
        for key in ("heartbeat_s", "ready_timeout_s", "stop_timeout_s", "eos_linger_s"):
            if getattr(self, key) <= 0:
                raise ConfigError(f"launch.{key}: must be > 0")
        if self.hwm < 1:
            raise ConfigError("launch.hwm: must be >= 1")


@dataclass(frozen=True)
class InputSpec:
    source: str                # "node.output", or an endpoint of a publisher outside the graph
    topic: str = "sonar/sim"   # external publishers only: the topic to take
    type: str = "polar"        # external publishers only: what they send
    policy: str = ""           # "" = lossless inside the graph, latest from outside
    capacity: int = 8
    max_age_s: float = 0.0

    @property
    def external(self) -> bool:
        return bool(_ENDPOINT.match(self.source))


@dataclass(frozen=True)
class NodeSpec:
    type: str
    params: dict[str, Any] = field(default_factory=dict)
    inputs: dict[str, Any] = field(default_factory=dict)
    bind: dict[str, str] = field(default_factory=dict)
    restart: Literal["never", "on-failure"] = "never"
    max_restarts: int = 3


@dataclass(frozen=True)
class ResolvedNode:
    name: str
    type: str
    node_class: type[Node]
    params: Any
    wiring: Wiring
    restart: str
    max_restarts: int
    producers: tuple[str, ...] = ()  # in-graph nodes this one takes frames from

    @property
    def is_source(self) -> bool:
        return not self.node_class.INPUTS


@dataclass(frozen=True)
class LaunchGraph:
    settings: LaunchSettings
    nodes: dict[str, ResolvedNode]
    start_order: tuple[str, ...]     # consumers first, sources last
    ipc_dir: str = ""                # removed by the launcher at the end

    def resolved_config(self) -> dict[str, Any]:
        """Everything that was decided, JSON-able: what the run folder keeps next to the results."""
        return {
            "launch": to_dict(self.settings),
            "start_order": list(self.start_order),
            "nodes": {name: {"type": n.type, "params": to_dict(n.params), "restart": n.restart,
                             "max_restarts": n.max_restarts, "wiring": dataclasses.asdict(n.wiring)}
                      for name, n in self.nodes.items()},
        }


def resolve_node_type(type_name: str) -> type[Node]:
    """`translator` -> sonar_realism_nodes.translator.NODE; `pkg.mod` -> pkg.mod.NODE; `pkg.mod:Class` -> that
    class."""
    module_name, _, attribute = type_name.partition(":")
    if "." not in module_name and not attribute:
        _load_builtin_nodes()
        module_name = f"{NODES_PACKAGE}.{module_name}"
    try:
        module = importlib.import_module(module_name)
    except ImportError as error:
        raise ConfigError(f"unknown node type {type_name!r}: cannot import {module_name} ({error})") from error
    node_class = getattr(module, attribute or "NODE", None)
    if not (isinstance(node_class, type) and issubclass(node_class, Node)):
        raise ConfigError(f"unknown node type {type_name!r}: {module_name} has no Node subclass "
                          f"{attribute or 'NODE'}")
    return node_class


def _load_builtin_nodes() -> None:
    """The built-in nodes are the repository's `nodes/` folder, installed as `sonar_realism_nodes`. They are taken
    from the same checkout as this library when there is one (a source tree, an editable install made before the
    package had that name), else from the installed package."""
    if NODES_PACKAGE in sys.modules:
        return
    folder = Path(__file__).resolve().parents[2] / "nodes"
    if not (folder / "__init__.py").is_file():
        return  # a regular install: sonar_realism_nodes is an ordinary package
    spec = importlib.util.spec_from_file_location(NODES_PACKAGE, folder / "__init__.py",
                                                  submodule_search_locations=[str(folder)])
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules[NODES_PACKAGE] = module
    spec.loader.exec_module(module)  # type: ignore[union-attr]


def apply_overrides(data: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """`--set node.param=value` (value in TOML syntax, else taken as a string) and `--set launch.key=value`."""
    import tomllib

    data = {"launch": dict(data.get("launch", {})),
            "nodes": {k: {**v, "params": dict(v.get("params", {}))} if isinstance(v, dict) else v
                      for k, v in data.get("nodes", {}).items()},
            **{k: v for k, v in data.items() if k not in ("launch", "nodes")}}
    for item in overrides:
        target, sep, text = item.partition("=")
        node_name, dot, key = target.partition(".")
        if not sep or not dot or not key:
            raise ConfigError(f"--set {item!r}: expected NODE.PARAM=VALUE or launch.KEY=VALUE")
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text
        if node_name == "launch":
            data["launch"][key] = value
        elif node_name in data["nodes"]:
            data["nodes"][node_name]["params"][key] = value
        else:
            raise ConfigError(f"--set {item!r}: no node {node_name!r}; nodes: {', '.join(data['nodes'])}")
    return data


def build_graph(data: dict[str, Any], out_dir: str | None = None) -> LaunchGraph:
    """Check the whole launch description and assign endpoints; raises ConfigError naming what is wrong."""
    unknown = sorted(set(data) - {"launch", "nodes"})
    if unknown:
        raise ConfigError(f"launch file: unknown table(s) {', '.join(unknown)}; expected [launch] and [nodes.*]")
    launch = dict(data.get("launch", {}))
    if out_dir is not None:
        launch["out"] = out_dir
    settings = from_dict(LaunchSettings, launch, "launch")
    raw_nodes = data.get("nodes", {})
    if not isinstance(raw_nodes, dict) or not raw_nodes:
        raise ConfigError("launch file: no nodes (add [nodes.NAME] tables)")

    specs: dict[str, NodeSpec] = {}
    classes: dict[str, type[Node]] = {}
    params: dict[str, Any] = {}
    for name, raw in raw_nodes.items():
        if not _NAME.match(name):
            raise ConfigError(f"nodes.{name}: node names are letters, digits, _ and - (no '.' or '/')")
        spec = from_dict(NodeSpec, raw, f"nodes.{name}")
        specs[name] = spec
        classes[name] = resolve_node_type(spec.type)
        filled = {k: v.replace("{out}", settings.out) if isinstance(v, str) else v for k, v in spec.params.items()}
        params[name] = from_dict(classes[name].PARAMS, filled, f"nodes.{name}.params")

    inputs = {name: _parse_inputs(name, specs[name], classes) for name in specs}
    order = _topological_order(inputs)
    endpoints = _Endpoints(settings)
    outputs, edges = _assign_outputs(specs, classes, inputs, endpoints, settings)
    nodes = {}
    for name, spec in specs.items():
        wiring = Wiring(
            inputs={input_name: _input_wiring(name, input_name, spec_in, outputs, edges)
                    for input_name, spec_in in inputs[name].items()},
            outputs={output_name: out for (node, output_name), out in outputs.items() if node == name},
            status_endpoint=spec.bind.get(STATUS_BIND) or endpoints.make(name, "status",
                                                                         reconnect=spec.restart != "never"),
            status_subscribers=1,
            heartbeat_s=settings.heartbeat_s,
            ready_timeout_s=settings.ready_timeout_s,
            eos_linger_s=settings.eos_linger_s,
            exit_with_parent=settings.mode == "process",
        )
        producers = tuple(sorted({i.source.partition(".")[0] for i in inputs[name].values() if not i.external}))
        nodes[name] = ResolvedNode(name, spec.type, classes[name], params[name], wiring, spec.restart,
                                   spec.max_restarts, producers)
    return LaunchGraph(settings, nodes, tuple(reversed(order)), endpoints.ipc_dir)


def _parse_inputs(name: str, spec: NodeSpec, classes: dict[str, type[Node]]) -> dict[str, InputSpec]:
    declared = classes[name].INPUTS
    unknown = sorted(set(spec.inputs) - set(declared))
    if unknown:
        raise ConfigError(f"nodes.{name}.inputs: {', '.join(unknown)} not an input of {spec.type} "
                          f"(inputs: {', '.join(declared) or 'none'})")
    parsed = {}
    for input_name, accepted in declared.items():
        where = f"nodes.{name}.inputs.{input_name}"
        raw = spec.inputs.get(input_name)
        if raw is None:
            raise ConfigError(f"{where}: unconnected input of {spec.type} (connect it to NODE.OUTPUT or an endpoint)")
        item = from_dict(InputSpec, {"source": raw} if isinstance(raw, str) else raw, where)
        if item.external:
            policy = item.policy or "latest"
            if policy == "lossless":
                raise ConfigError(f"{where}: lossless needs an in-graph producer (PUSH/PULL); a publisher "
                                  f"outside the graph is PUB, which drops under load: use latest or fifo")
            source_type = item.type
        else:
            source_node, dot, output = item.source.partition(".")
            if not dot or source_node not in classes:
                raise ConfigError(f"{where}: {item.source!r} is neither NODE.OUTPUT of this graph nor an endpoint "
                                  f"(tcp://, ipc://); nodes: {', '.join(classes)}")
            outputs = classes[source_node].OUTPUTS
            if output not in outputs:
                raise ConfigError(f"{where}: node {source_node!r} has no output {output!r} "
                                  f"(outputs: {', '.join(outputs) or 'none'})")
            policy = item.policy or "lossless"
            source_type = outputs[output]
        if source_type not in accepted:
            raise ConfigError(f"{where}: topic type mismatch: {item.source} carries {source_type!r}, "
                              f"input accepts {', '.join(accepted)}")
        InputPolicy(policy, item.capacity, item.max_age_s).validate()  # type: ignore[arg-type]
        parsed[input_name] = dataclasses.replace(item, policy=policy)
    return parsed


def _topological_order(inputs: dict[str, dict[str, InputSpec]]) -> list[str]:
    """Sources first. A cycle cannot be started consumers-first, so it is an error."""
    upstream = {name: {i.source.partition(".")[0] for i in ins.values() if not i.external}
                for name, ins in inputs.items()}
    order: list[str] = []
    remaining = dict(upstream)
    while remaining:
        ready = sorted(name for name, deps in remaining.items() if deps <= set(order))
        if not ready:
            raise ConfigError(f"launch file: the nodes {', '.join(sorted(remaining))} form a cycle")
        order.extend(ready)
        for name in ready:
            del remaining[name]
    return order


class _Endpoints:
    """Endpoint names: inproc inside one process, ipc files in a private folder, or free tcp ports.

    inproc connections are not re-established when the bound side goes away, so in inproc mode the
    endpoints a restartable node binds use ipc: its consumers and the launcher reconnect by themselves.
    """

    def __init__(self, settings: LaunchSettings) -> None:
        self.settings = settings
        self.run_id = f"{settings.name}-{os.getpid()}-{next(_run_counter)}"
        self.ipc_dir = ""

    def make(self, *names: str, reconnect: bool = False) -> str:
        if self.settings.mode == "inproc" and not reconnect:
            return f"inproc://{self.run_id}/{'/'.join(names)}"
        if self.settings.mode == "inproc" or self.settings.transport == "ipc":
            if not self.ipc_dir:
                self.ipc_dir = tempfile.mkdtemp(prefix="sr-")
            return f"ipc://{self.ipc_dir}/{'.'.join(names)}"
        return f"tcp://{self.settings.host}:{_free_port(self.settings.host)}"


def _free_port(host: str) -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind((host, 0))
        return probe.getsockname()[1]


def _assign_outputs(specs: dict[str, NodeSpec], classes: dict[str, type[Node]],
                    inputs: dict[str, dict[str, InputSpec]], endpoints: _Endpoints, settings: LaunchSettings,
                    ) -> tuple[dict[tuple[str, str], OutputWiring], dict[tuple[str, str], tuple[str, str]]]:
    """Output wirings by (node, output), and the (PUSH, ack) endpoints of each lossless edge by (consumer, input)."""
    outputs = {}
    edges: dict[tuple[str, str], tuple[str, str]] = {}
    for name, node_class in classes.items():
        unknown = sorted(set(specs[name].bind) - set(node_class.OUTPUTS) - {STATUS_BIND})
        if unknown:
            raise ConfigError(f"nodes.{name}.bind: {', '.join(unknown)} not an output of {specs[name].type} "
                              f"(nor {STATUS_BIND!r}, the node's status endpoint)")
        reconnect = specs[name].restart != "never"
        for output in node_class.OUTPUTS:
            consumers = [(consumer, input_name, spec) for consumer, ins in inputs.items()
                         for input_name, spec in ins.items() if spec.source == f"{name}.{output}"]
            pushes, acks = [], []
            for consumer, input_name, spec in consumers:
                if spec.policy == "lossless":
                    push = endpoints.make(name, output, "to", consumer, input_name, reconnect=reconnect)
                    ack = endpoints.make(name, output, "ack", consumer, input_name, reconnect=reconnect)
                    edges[(consumer, input_name)] = (push, ack)
                    pushes.append(push)
                    acks.append(ack)
            subscribers = sum(1 for _, _, spec in consumers if spec.policy != "lossless")
            outputs[(name, output)] = OutputWiring(
                topic=f"{name}/{output}",
                pub_endpoint=specs[name].bind.get(output) or endpoints.make(name, output, reconnect=reconnect),
                expected_subscribers=subscribers, push_endpoints=tuple(pushes), ack_endpoints=tuple(acks),
                hwm=settings.hwm)
    return outputs, edges


def _input_wiring(name: str, input_name: str, spec: InputSpec, outputs: dict[tuple[str, str], OutputWiring],
                  edges: dict[tuple[str, str], tuple[str, str]]) -> InputWiring:
    policy = InputPolicy(spec.policy, spec.capacity, spec.max_age_s)  # type: ignore[arg-type]
    if spec.external:
        return InputWiring(spec.source, spec.topic, policy)
    source_node, _, output = spec.source.partition(".")
    out = outputs[(source_node, output)]
    if spec.policy == "lossless":
        push, ack = edges[(name, input_name)]
        return InputWiring(push, out.topic, policy, in_graph=True, ack_endpoint=ack)
    # A producer bound to every interface is reached over loopback from this host.
    connect = out.pub_endpoint.replace("//0.0.0.0:", "//127.0.0.1:").replace("//*:", "//127.0.0.1:")
    return InputWiring(connect, out.topic, policy, in_graph=True)
