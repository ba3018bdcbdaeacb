"""A ROS 2 DDS peer built from the stock ROS 2 Jazzy message definitions, never from the bridge's code.

Types come from ``rosbags``' Jazzy typestore (plus ``aes_planner_msgs`` parsed from the shipped
``ros2/aes_planner_msgs/msg/*.msg`` files): :func:`idl_class` turns a typestore definition into
a Cyclone DDS IDL struct named as rmw_cyclonedds_cpp names it (``pkg::msg::dds_::Type_``), so
the DDS layer matches topics on the stock definition. :meth:`Peer.take_raw` hands back the CDR
bytes, which tests decode with ``rosbags``' CDR deserialiser (``typestore.deserialize_cdr``).
"""

from __future__ import annotations

import dataclasses
import os
import types as pytypes
from pathlib import Path

from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

ROOT = Path(__file__).resolve().parents[2]
MSG_DIR = ROOT / "ros2" / "aes_planner_msgs" / "msg"

_BASE = {
    "bool": bool,
    "byte": t.byte,
    "octet": t.byte,
    "char": t.uint8,
    "int8": t.int8,
    "uint8": t.uint8,
    "int16": t.int16,
    "uint16": t.uint16,
    "int32": t.int32,
    "uint32": t.uint32,
    "int64": t.int64,
    "uint64": t.uint64,
    "float32": t.float32,
    "float64": t.float64,
    "string": str,
}
_TYPESTORE = None
_CLASSES: dict[str, type] = {}


def typestore():
    """Jazzy's stock types plus aes_planner_msgs from its .msg files."""
    global _TYPESTORE
    if _TYPESTORE is None:
        ts = get_typestore(Stores.ROS2_JAZZY)
        add = {}
        for f in sorted(MSG_DIR.glob("*.msg")):
            add.update(get_types_from_msg(f.read_text(), f"aes_planner_msgs/msg/{f.stem}"))
        ts.register(add)
        _TYPESTORE = ts
    return _TYPESTORE


def _annotation(spec):
    kind, rest = spec
    if kind == Nodetype.BASE:
        if rest[0] == "string" and rest[1]:  # string<=N
            return t.bounded_str[rest[1]]
        return _BASE[rest[0]]
    if kind == Nodetype.NAME:
        return idl_class(rest)
    sub, n = rest
    if kind == Nodetype.ARRAY:
        return t.array[_annotation(sub), n]
    return t.sequence[_annotation(sub), n] if n else t.sequence[_annotation(sub)]  # T[<=n]: sequence<T, n>


def idl_class(name: str) -> type:
    """The IDL struct of ROS 2 type ``pkg/msg/Type`` from its stock definition."""
    if name in _CLASSES:
        return _CLASSES[name]
    _, fields = typestore().fielddefs[name]
    pkg, _, short = name.split("/")
    annotations = {fname: _annotation(spec) for fname, spec in fields}

    def body(ns):
        ns["__annotations__"] = annotations

    cls = pytypes.new_class(f"Stock_{short}", (IdlStruct,), {"typename": f"{pkg}::msg::dds_::{short}_"}, body)
    cls = dataclasses.dataclass(cls)
    _CLASSES[name] = cls
    return cls


def make(type_name: str, /, **values):
    """An instance of the stock IDL struct with every field given (nested values as dicts)."""
    cls = idl_class(type_name)
    _, fields = typestore().fielddefs[type_name]
    kw = {}
    for fname, (kind, rest) in fields:
        v = values[fname]
        if kind == Nodetype.NAME and isinstance(v, dict):
            v = make(rest, **v)
        elif kind == Nodetype.SEQUENCE and rest[0][0] == Nodetype.NAME:
            v = [make(rest[0][1], **x) if isinstance(x, dict) else x for x in v]
        kw[fname] = v
    return cls(**kw)


def qos(profile: str, depth: int = 10):
    from cyclonedds.qos import Policy, Qos

    x = Policy.DataRepresentation(use_cdrv0_representation=True)
    if profile == "latched":
        return Qos(
            Policy.Reliability.Reliable(100_000_000), Policy.Durability.TransientLocal, Policy.History.KeepLast(1), x
        )
    if profile == "sensor_data":
        return Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(5), x)
    return Qos(Policy.Reliability.Reliable(100_000_000), Policy.Durability.Volatile, Policy.History.KeepLast(depth), x)


class Peer:
    """A DDS participant on ``domain_id`` with stock-typed readers and writers."""

    def __init__(self, domain_id: int):
        from cyclonedds.domain import DomainParticipant

        self.participant = DomainParticipant(domain_id)
        self.topics = {}

    def _topic(self, topic: str, name: str):
        from cyclonedds.topic import Topic

        key = "rt" + topic
        if key not in self.topics:
            self.topics[key] = Topic(self.participant, key, idl_class(name))
        return self.topics[key]

    def reader(self, topic: str, name: str, profile: str = "reliable", depth: int = 100):
        from cyclonedds.sub import DataReader

        return DataReader(self.participant, self._topic(topic, name), qos(profile, depth))

    def writer(self, topic: str, name: str, profile: str = "reliable"):
        from cyclonedds.pub import DataWriter

        return DataWriter(self.participant, self._topic(topic, name), qos(profile))

    @staticmethod
    def take_raw(reader, n: int = 100) -> list[bytes]:
        """The CDR bytes (with the encapsulation header) of up to ``n`` samples."""
        from cyclonedds._clayer import ddspy_take
        from cyclonedds.core import InstanceState, SampleState, ViewState

        ret = ddspy_take(reader._ref, SampleState.Any | ViewState.Any | InstanceState.Any, n)
        return [bytes(data) for data, info in ret if info.valid_data]

    def close(self) -> None:
        self.participant.__del__()


def domain_for_tests() -> int:
    """A domain id of this test process's own (ports 7400 + 250 id: ids up to 232 are valid)."""
    return 100 + os.getpid() % 100
