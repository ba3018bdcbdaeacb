"""Launch files: YAML that names the nodes of a graph, their types, configs and topic remaps.

::

    scene: indoor:3                  # optional: the simulated scene every sim node (and the
                                     # planner's platform) uses; a family:seed or a scene file
    clock: sim                       # optional: wall (default, real time) or sim (simulated,
                                     # lockstep: docs/guides/clock.md); or {source: sim, step_s: 0.01}
    nodes:
      - id: gimbal                   # unique; the node's name on the bus and in --set
        type: gimbal                 # planner | gimbal | sim_camera | sim_drone | camera | external
        config: {rate_hz: 20, device: {type: emulated_pan_tilt}}   # the type's config dataclass
        remap: {gimbal/state: rig/state}                            # default topic -> actual
        respawn: false               # restart when it dies (multi-process launches)

``external`` marks a node that runs elsewhere (a flight stack): it is listed, not started.
Files are read with ``yaml.safe_load``; every unknown key, unknown type, bad value or remap is
a :class:`~aes_planner.config.ConfigError` naming the key (``nodes[2].config.rate_hz``).
``--set ID.KEY=VALUE`` overrides (VALUE parsed as YAML): ``ID.type``, ``ID.respawn``, any
config key (dotted for nested ones: ``gimbal.device.type=dynamixel_pan_tilt``), and the top-level
``scene=FAMILY:SEED`` and ``clock=sim|wall``.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from aes_planner.config import ConfigError, from_dict, load_yaml, load_yaml_text, short_repr, tag_of
from aes_planner.graph.base import NODE_TYPES, LaunchContext, Node, make_node, node_class
from aes_planner.graph.clock import ClockConfig, parse_clock

__all__ = [
    "LaunchEntry",
    "LaunchSpec",
    "apply_overrides",
    "build_nodes",
    "check_remap",
    "find_launch_file",
    "load_launch",
]

_ENTRY_KEYS = ("id", "type", "config", "remap", "respawn")
_TOP_KEYS = ("scene", "clock", "nodes", "bus")


@dataclass
class LaunchEntry:
    id: str
    type: str
    config: dict[str, Any] = field(default_factory=dict)
    remap: dict[str, str] = field(default_factory=dict)
    respawn: bool = False


@dataclass
class LaunchSpec:
    nodes: list[LaunchEntry]
    scene: str | None = None
    path: str = ""
    bus: Any = None  # aes_planner.transport.ZenohConfig of a multi-process launch (the ``bus:`` block)
    clock: ClockConfig = field(default_factory=ClockConfig)  # wall, or sim (lockstep)

    def entry(self, node_id: str) -> LaunchEntry:
        for e in self.nodes:
            if e.id == node_id:
                return e
        raise ConfigError(node_id, f"no node with this id; the launch has {[e.id for e in self.nodes]}")


def find_launch_file(name: str | Path) -> Path:
    """A path as given, or the name of a shipped launch file (``sim_closed_loop.yaml``)."""
    p = Path(name)
    if p.exists():
        return p
    shipped = resources.files("aes_planner.launch") / (p.name if p.suffix else f"{p.name}.yaml")
    if shipped.is_file():
        return Path(str(shipped))
    raise ConfigError("", f"{name}: no such launch file (shipped ones: sim_closed_loop, pan_tilt_rig, drone)")


def parse_launch(data: Any, path: str = "") -> LaunchSpec:
    if not isinstance(data, Mapping):
        raise ConfigError("", f"{path}: a launch file is a mapping with 'nodes' (and optionally 'scene')")
    for k in data:
        if k not in _TOP_KEYS:
            raise ConfigError(str(k), f"unknown key; expected one of: {', '.join(_TOP_KEYS)}")
    scene = data.get("scene")
    if scene is not None and not isinstance(scene, str):
        raise ConfigError("scene", f"expected FAMILY:SEED or a scene file path, got {scene!r}")
    entries, seen = [], set()
    for i, raw in enumerate(_node_list(data)):
        key = f"nodes[{i}]"
        tag_of(raw, key, [*NODE_TYPES, "external"])
        raw = {k: v for k, v in raw.items() if not (k in ("config", "remap") and v is None)}  # `config:` left empty
        entry = from_dict(LaunchEntry, raw, key)  # every key's type, unknown keys, named
        if not re.fullmatch(r"[A-Za-z0-9_]{1,64}", entry.id):
            raise ConfigError(
                f"{key}.id",
                f"expected a word like 'planner' (ASCII letters, digits, '_'; 64 at most), got {short_repr(entry.id)}",
            )
        if entry.id in seen:
            raise ConfigError(f"{key}.id", f"duplicate node id {entry.id!r}")
        seen.add(entry.id)
        from aes_planner.transport import validate_topic

        for a, b in entry.remap.items():
            for t in (a, b):
                try:
                    validate_topic(t)
                except Exception as exc:
                    raise ConfigError(f"{key}.remap", str(exc)) from None
        entries.append(entry)
    if all(e.type == "external" for e in entries):
        raise ConfigError("nodes", "every node is 'external' (runs elsewhere): this launch would start nothing here")
    bus = None
    if data.get("bus") is not None:  # where a multi-process launch's hub listens, whom it joins
        from aes_planner.transport.config import ZenohConfig

        bus = from_dict(ZenohConfig, data["bus"], "bus")
    clock = parse_clock(data.get("clock"), "clock")
    if clock.sim:
        check_sim_clock(entries)
    return LaunchSpec(entries, scene, path, bus, clock)


def check_sim_clock(entries: Sequence[LaunchEntry]) -> None:
    """Every node can run on a simulated clock (else a ConfigError naming the node and why)."""
    for i, e in enumerate(entries):
        if e.type == "external":
            raise ConfigError(
                f"nodes[{i}]",
                f"{e.id!r} runs elsewhere, in real time: a simulated clock cannot step it; use clock: wall (--clock wall)",
            )
        cls = node_class(e.type, f"nodes[{i}].type")
        problem = cls.sim_clock_problem(from_dict(cls.config_class, e.config, f"nodes[{i}].config"))
        if problem:
            raise ConfigError(
                f"nodes[{i}]", f"{e.id!r} {problem}: it cannot run on a simulated clock; use clock: wall (--clock wall)"
            )


def _node_list(data: Mapping[str, Any]) -> list:
    nodes = data.get("nodes")
    if not isinstance(nodes, list) or not nodes:
        raise ConfigError(
            "nodes", f"expected a non-empty list of nodes (each with id and type), got {short_repr(nodes)}"
        )
    return nodes


def apply_overrides(data: Mapping[str, Any], overrides: Sequence[str]) -> dict:
    """``ID.KEY=VALUE`` overrides applied to the raw launch mapping (see the module docstring)."""
    if not isinstance(data, Mapping):
        raise ConfigError(
            "", f"a launch file is a mapping with 'nodes' (and optionally 'scene'), got {short_repr(data)}"
        )
    if overrides:
        parse_launch(data)  # the file's own shape first, named as in a launch without --set
    out = copy.deepcopy(dict(data))
    for item in overrides:
        if "=" not in item:
            raise ConfigError("--set", f"expected ID.KEY=VALUE, got {item!r}")
        path, _, text = item.partition("=")
        try:  # the file loader's limits (size, aliases, depth) and one-line errors
            value = load_yaml_text(text, "value") if text.strip() else ""
        except ConfigError as exc:
            raise ConfigError(f"--set {short_repr(path, 80)}", exc.message) from None
        if path == "scene":
            out["scene"] = str(value)
            continue
        if path == "clock":
            out["clock"] = value
            continue
        node_id, _, key = path.partition(".")
        if not key:
            raise ConfigError("--set", f"expected ID.KEY=VALUE, got {item!r}")
        nodes = _node_list(out)
        entry = next((n for n in nodes if isinstance(n, Mapping) and n.get("id") == node_id), None)
        if entry is None:
            raise ConfigError(
                f"--set {path}",
                f"no node {node_id!r}; the launch has {[n.get('id') for n in nodes if isinstance(n, Mapping)]}",
            )
        if key in ("type", "respawn"):
            entry[key] = value
            continue
        target = entry.setdefault("config", {}) or {}
        entry["config"] = target
        parts = key.split(".")
        for p in parts[:-1]:
            nxt = target.get(p)
            if not isinstance(nxt, dict):
                nxt = target[p] = {}
            target = nxt
        target[parts[-1]] = value
    return out


def load_launch(path: str | Path, overrides: Sequence[str] = ()) -> LaunchSpec:
    p = find_launch_file(path)
    data = load_yaml(p)
    return parse_launch(apply_overrides(data or {}, overrides), str(p))


def build_nodes(spec: LaunchSpec, context: LaunchContext | None = None) -> list[tuple[Node, dict[str, str]]]:
    """Unstarted nodes of every non-external entry, with their remaps."""
    context = context or LaunchContext(scene=spec.scene, clock=spec.clock.source)
    if context.scene is None:
        context.scene = spec.scene
    context.clock = spec.clock.source
    out = []
    for i, e in enumerate(spec.nodes):
        if e.type == "external":
            continue
        node = make_node(e.type, e.config, e.id, context, key=f"nodes[{i}]")
        check_remap(e, type(node), f"nodes[{i}].remap")
        out.append((node, e.remap))
    return out


def check_remap(entry: LaunchEntry, cls: type[Node], key: str) -> None:
    """Every topic ``entry`` remaps is one its node type reads or writes (else the remap would be
    silently ignored)."""
    own = {*cls.inputs, *cls.outputs}
    for topic in entry.remap:
        if topic not in own:
            raise ConfigError(
                key, f"{topic!r} is not a topic of {entry.type} node {entry.id!r}; its topics: {sorted(own)}"
            )
