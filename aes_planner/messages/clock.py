"""``Clock`` (the simulated time of a graph, on ``clock``) and ``ClockAck`` (a node's "done up to
this tick", on ``clock/ack``): the two messages of a graph that runs on a simulated clock in
lockstep (:mod:`aes_planner.graph.clock`).

``Clock`` is ROS 2's ``rosgraph_msgs/Clock`` (one time, published by whoever owns time) plus what
lockstep needs: the tick's number, and how many messages the graph published on each topic in the
tick before, so a node knows when it has received all of them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from aes_planner.messages.codec import Map, Message, MessageError, Scalar, Str, register_message, text_cap
from aes_planner.messages.fields import check_name_map, check_sequence, check_text

__all__ = ["MAX_CLOCK_TOPICS", "NEVER_NS", "Clock", "ClockAck"]

MAX_CLOCK_TOPICS = 128
#: ``ClockAck.next_ns`` of a node that has nothing due (it steps only when a message arrives).
NEVER_NS = (1 << 63) - 1


@register_message
@dataclass
class Clock(Message):
    """What ``clock`` carries: the graph's time.

    * ``stamp_ns``: the simulated time, integer nanoseconds from the start of the run (0);
    * ``tick``: its number (1, 2, ...; a node acknowledges each one);
    * ``sent``: per topic, how many messages the graph's nodes published during the previous tick
      (a subscriber of the topic waits until it has received them before it steps).
    """

    TYPE_NAME: ClassVar[str] = "Clock"
    SCHEMA_VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = 16 << 10
    FIELDS = (
        Scalar("stamp_ns", "u64", doc="the simulated time, integer nanoseconds from the start of the run (0)"),
        Scalar("tick", "u64", doc="its number (1, 2, ...; every node acknowledges each one)"),
        Map(
            "sent",
            Scalar("count", "u64"),
            MAX_CLOCK_TOPICS,
            doc="per topic, how many messages the graph's nodes published during the previous tick",
        ),
    )
    WIRE_RULES: ClassVar[tuple[str, ...]] = ("a `sent` key that is not 1-64 characters of `A-Z a-z 0-9 _ . : / -`",)

    stamp_ns: int
    tick: int
    sent: dict[str, int] = field(default_factory=dict)

    def __post_init__(self):
        self.stamp_ns = check_sequence(self.stamp_ns, "Clock.stamp_ns")
        self.tick = check_sequence(self.tick, "Clock.tick")
        self.sent = check_name_map(self.sent, "Clock.sent", int, MAX_CLOCK_TOPICS)

    @property
    def stamp_s(self) -> float:
        return self.stamp_ns / 1e9


@register_message
@dataclass
class ClockAck(Message):
    """What ``clock/ack`` carries: node ``node`` has handled everything up to tick ``tick``.

    * ``sent``: per topic, how many messages it published during that tick;
    * ``next_ns``: when it next wants to step (:data:`NEVER_NS`: only when a message arrives);
    * ``tick`` 0 says "ready": subscribed, waiting for the first tick.
    """

    TYPE_NAME: ClassVar[str] = "ClockAck"
    SCHEMA_VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = 16 << 10
    FIELDS = (
        Str("node", 256, doc="the node's id"),
        Scalar("tick", "u64", doc="the tick it has handled everything up to; 0 = ready, waiting for the first"),
        Scalar("next_ns", "u64", doc=f"when it next wants to step; {NEVER_NS} = only when a message arrives"),
        Map(
            "sent", Scalar("count", "u64"), MAX_CLOCK_TOPICS, doc="per topic, how many messages it published that tick"
        ),
    )
    WIRE_RULES: ClassVar[tuple[str, ...]] = (
        "an empty `node`, or a `sent` key that is not 1-64 characters of `A-Z a-z 0-9 _ . : / -`",
    )

    node: str
    tick: int
    next_ns: int = NEVER_NS
    sent: dict[str, int] = field(default_factory=dict)

    def __post_init__(self):
        self.node = check_text(self.node, "ClockAck.node", text_cap(self.FIELDS, "node"))
        if not self.node:
            raise MessageError("ClockAck.node must name the node")
        self.tick = check_sequence(self.tick, "ClockAck.tick")
        self.next_ns = check_sequence(self.next_ns, "ClockAck.next_ns")
        self.sent = check_name_map(self.sent, "ClockAck.sent", int, MAX_CLOCK_TOPICS)
