"""Streaming nodes: thin wrappers that connect library logic to sockets (see docs/nodes.md).

Each module exposes `NODE`, a `sonar_realism.runtime.Node` subclass with PARAMS (frozen config dataclass),
INPUTS and OUTPUTS. A launch file names a node type by module: `translator` means `sonar_realism_nodes.translator`
(this folder, installed under that name by setup.py; never as a top-level `nodes`).
"""
