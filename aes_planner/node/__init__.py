"""Nodes: the planner, the gimbal, the sim camera and drone, a real camera; and launch files.

Each node is a pure ``step(inputs, now) -> outputs`` core (:class:`~aes_planner.node.base.Node`)
tested without a bus; :class:`~aes_planner.node.runner.NodeRunner` is the thin loop that wires
one to a bus, and :class:`~aes_planner.node.runner.Launch` runs a launch file's nodes in one
process (:mod:`aes_planner.node.launch_file` reads the YAML).
"""

from aes_planner.node.base import NODE_TYPES, LaunchContext, Node, NodeError, make_node
from aes_planner.node.launch_file import LaunchEntry, LaunchSpec, build_nodes, load_launch
from aes_planner.node.runner import Launch, NodeRunner

__all__ = [
    "NODE_TYPES",
    "Launch",
    "LaunchContext",
    "LaunchEntry",
    "LaunchSpec",
    "Node",
    "NodeError",
    "NodeRunner",
    "build_nodes",
    "load_launch",
    "make_node",
]
