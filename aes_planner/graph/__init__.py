"""The graph machinery: what runs nodes, one layer above the transport and below the node types.

* :mod:`.base` -- the node contract (:class:`Node`: a pure ``step(inputs, now) -> outputs``
  core tested without a bus), :class:`LaunchContext`, and the registry of node types
  (:data:`NODE_TYPES`, a ``type:`` word -> ``"module:Class"``; :func:`make_node`).
* :mod:`.runner` -- :class:`NodeRunner`, the thin loop that wires one node to a bus, and
  :class:`Launch`, a launch file's nodes in one process, each in its own thread.
* :mod:`.launch_file` -- launch-file YAML -> :class:`LaunchSpec` (:func:`load_launch`,
  ``--set`` overrides, :func:`build_nodes`).
* :mod:`.supervisor` -- :class:`Supervisor`: one process per node over Zenoh, respawned,
  stopped in reverse order.

* :mod:`.signals` -- :func:`stop_on_signals`: the first SIGINT/SIGTERM stops the work, later ones
  wait for the clean-up (torque off), the exit status is 128 + the first.

Layers: this package imports :mod:`aes_planner.transport` and the messages, names the node types
only by import path (a launch file's ``type:`` word), and never loads the simulator (the node
types that take a scene load it: :func:`aes_planner.node.scene.launch_scene`); the node types
(:mod:`aes_planner.node`) import this package; the transport imports neither. Names are imported
lazily, so ``import aes_planner.graph`` costs nothing.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "NODE_TYPES": "base",
    "LaunchContext": "base",
    "Node": "base",
    "NodeError": "base",
    "make_node": "base",
    "node_class": "base",
    "Launch": "runner",
    "NodeRunner": "runner",
    "LaunchEntry": "launch_file",
    "LaunchSpec": "launch_file",
    "build_nodes": "launch_file",
    "load_launch": "launch_file",
    "Supervisor": "supervisor",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'aes_planner.graph' has no attribute {name!r}")
    return getattr(importlib.import_module(f"aes_planner.graph.{module}"), name)


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])
