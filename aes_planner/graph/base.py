"""The node contract: a pure ``step(inputs, now) -> outputs`` core, and a registry of node types.

A node declares the topics it reads (:attr:`Node.inputs`: default topic -> :class:`Input`, the
message type and keep-last depth) and writes (:attr:`Node.outputs`: default topic ->
:class:`Output`, the message type, whether the topic is latched, and whether it is reliable or
best-effort: a camera's frames may drop to the latest rather than block the camera). The QoS is
declared here, beside the topic, and the runner applies it as declared. Its :meth:`Node.step` takes the messages that arrived since the last step, per
input topic (oldest first), and the present time, and returns the messages to publish, per
output topic. It never touches a bus: tests call ``step`` directly, and
:class:`aes_planner.graph.runner.NodeRunner` (the thin loop) moves messages between a bus and
``step``. Topic remaps are the runner's business; inside a node topics keep their default names.

Devices and other resources are opened in :meth:`Node.start` and released in :meth:`Node.stop`
(safe to call twice, and after a failed start), so a node can be built cheaply from a launch
entry in any process and started there.

Node types are registered by a ``type:`` word (``planner``, ``gimbal``, ``sim_camera``,
``sim_drone``, ``camera``); :func:`make_node` builds one from a launch entry's config mapping
through the type's config dataclass (unknown keys are errors naming the key).
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple

from aes_planner.config import ConfigError, from_dict
from aes_planner.errors import AesPlannerError

__all__ = [
    "NODE_TYPES",
    "Input",
    "LaunchContext",
    "Node",
    "NodeError",
    "Output",
    "Outputs",
    "input_specs",
    "make_node",
    "node_class",
    "output_specs",
]

Outputs = dict[str, list]


class Input(NamedTuple):
    """An input topic's declaration: its message type and the keep-last depth of its queue."""

    msg_type: type
    depth: int = 1


class Output(NamedTuple):
    """An output topic's declaration (its QoS): ``latched``: a late subscriber still gets the last
    message; ``reliable``: block rather than drop under load (False: best-effort, may drop to the
    latest, for a stream like camera frames)."""

    msg_type: type
    latched: bool = False
    reliable: bool = True


class NodeError(AesPlannerError):
    """A node cannot be built or run as configured; the message says what to change."""


@dataclass
class LaunchContext:
    """What a launch file shares with every node it builds.

    ``scene``: the simulated scene spec (``"indoor:3"`` or a YAML path) of a sim launch, else None;
    ``loaded_scene``: that scene once loaded (the graph never loads the simulator: the node types
    that take a scene load it through :func:`aes_planner.node.scene.launch_scene`, once per launch,
    or a caller that has it already puts it here); ``clock``: ``wall`` or ``sim`` (the launch's
    :class:`~aes_planner.graph.clock.ClockConfig` source: on ``sim`` a node's devices take their
    time from ``now``); ``values``: free-form extras (the run folder...).
    """

    scene: str | None = None
    clock: str = "wall"
    values: dict[str, Any] = field(default_factory=dict)
    loaded_scene: Any = None


class Node(ABC):
    """A node core. Subclasses set the class attributes and implement :meth:`step`."""

    #: The dataclass a launch entry's ``config`` loads into.
    config_class: ClassVar[type]
    #: True for a node that cannot be built without the launch's simulated scene (``scene:``).
    needs_scene: ClassVar[bool] = False
    #: default input topic -> Input(message type, keep-last depth) (a plain 2-tuple works too)
    inputs: ClassVar[dict[str, tuple]] = {}
    #: default output topic -> Output(message type, latched, reliable) (a plain 2-tuple: reliable)
    outputs: ClassVar[dict[str, tuple]] = {}

    def __init__(self, config: Any, node_id: str = "", context: LaunchContext | None = None):
        self.config = config
        self.node_id = node_id or type(self).__name__.lower()
        self.context = context or LaunchContext()

    @property
    def period_s(self) -> float:
        """How often the loop steps the node when no input arrives (seconds)."""
        return 0.05

    @property
    def finished(self) -> bool:
        """True once the node has done its job (the planner settled); the launch may end."""
        return False

    @classmethod
    def can_finish(cls) -> bool:
        """Whether this node type can ever be :attr:`finished` (it overrides the property): a
        launch ends when every node that can finish has."""
        return cls.finished is not Node.finished

    @classmethod
    def sim_clock_problem(cls, config: Any) -> str | None:
        """Why a node of this type with ``config`` cannot run on a simulated clock (it talks to
        something that lives in real time: a camera, a servo bus, a flight stack), or None when it
        can (:mod:`aes_planner.graph.clock`)."""
        return None

    def transport_counters(self) -> dict[str, int]:
        """What the transport under the node counts (its inputs' received/dropped/rejected, the bus
        session's ``bus.*`` health, ``step_errors``): the runner that moves the node's messages
        replaces this when it opens, and adds the same to every :class:`Diagnostics` the node
        publishes. A node that reports elsewhere too (the ROS 2 bridge's ``/diagnostics``) reads it."""
        return {}

    def start(self) -> None:
        """Open devices and resources (called once, in the process that runs the node)."""
        return None

    def stop(self) -> None:
        """Release everything and leave hardware safe; safe to call twice and after a failed start."""
        return None

    @abstractmethod
    def step(self, inputs: Mapping[str, list], now: float) -> Outputs:
        """Messages in (per default input topic, oldest first) -> messages out (per output topic)."""


# type word -> "module:Class"
NODE_TYPES: dict[str, str] = {
    "planner": "aes_planner.node.planner:PlannerNode",
    "gimbal": "aes_planner.node.gimbal:GimbalNode",
    "sim_camera": "aes_planner.node.sim_camera:SimCameraNode",
    "sim_drone": "aes_planner.node.sim_drone:SimDroneNode",
    "sim": "aes_planner.node.sim_drone:SimDroneNode",  # drone.yaml: --set drone.type=sim
    "camera": "aes_planner.node.camera:CameraNode",
    "ros2_bridge": "aes_planner.ros2.bridge:Ros2BridgeNode",
    "mavlink_drone": "aes_planner.drone.node:MavlinkDroneNode",
    "sim_drone_camera": "aes_planner.drone.camera:DroneSimCameraNode",
}


def node_class(type_name: str, key: str = "type") -> type[Node]:
    target = NODE_TYPES.get(type_name) if isinstance(type_name, str) else None
    if target is None:
        raise ConfigError(key, f"unknown node type {type_name!r}; known types: {', '.join(sorted(NODE_TYPES))}")
    module_name, _, attr = target.partition(":")
    return getattr(importlib.import_module(module_name), attr)


def make_node(
    type_name: str, config: Mapping[str, Any] | None, node_id: str, context: LaunchContext | None = None, key: str = ""
) -> Node:
    """Build an unstarted node of ``type_name`` from a config mapping (unknown keys are errors)."""
    cls = node_class(type_name, f"{key}.type" if key else "type")
    cfg = from_dict(cls.config_class, config or {}, f"{key}.config" if key else "config")
    return cls(cfg, node_id=node_id, context=context)


def input_specs(node: Node | type[Node]) -> dict[str, Input]:
    """A node's (or node type's) :attr:`Node.inputs` as :class:`Input` declarations; an instance
    may narrow its class's (a bridge that serves some topics only)."""
    return {name: Input(*spec) for name, spec in node.inputs.items()}


def output_specs(node: Node | type[Node]) -> dict[str, Output]:
    """A node's (or node type's) :attr:`Node.outputs` as :class:`Output` declarations (reliable
    unless declared otherwise)."""
    return {name: Output(*spec) for name, spec in node.outputs.items()}
