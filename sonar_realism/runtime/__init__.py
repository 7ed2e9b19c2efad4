"""The streaming runtime: nodes, delivery policies, launch graphs and their supervisor (docs/nodes.md).

This package is the only part of the library that imports zmq; models, sim, evaluate and diagnose never do.
"""

from sonar_realism.runtime.delivery import EndOfStream, InputPolicy, InputQueue, SeqTracker
from sonar_realism.runtime.node import Node, NodeStopped
from sonar_realism.runtime.wiring import InputWiring, OutputWiring, Wiring

__all__ = ["EndOfStream", "InputPolicy", "InputQueue", "SeqTracker", "Node", "NodeStopped", "InputWiring",
           "OutputWiring", "Wiring"]
