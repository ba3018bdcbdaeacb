"""``Diagnostics`` (a node's health: named counters and values, and its state) and
``PlannerRequest`` (ask the planner for something)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from aes_planner.messages.codec import Enum, Map, Message, MessageError, Scalar, Str, register_message, text_cap
from aes_planner.messages.fields import check_finite, check_name_map, check_sequence, check_text

__all__ = ["Diagnostics", "PlannerRequest", "REQUEST_KINDS", "MAX_DIAG_ENTRIES"]

MAX_DIAG_ENTRIES = 128
REQUEST_KINDS = ("suggest", "reset", "stop")


@register_message
@dataclass
class Diagnostics(Message):
    """What ``<node>/diagnostics`` carries.

    * ``node``: the node's id; ``state``: its state word (the planner's are
      :class:`aes_planner.node.active_loop.LoopState`: ``"exploring"``, ``"settling"``, ``"done"``...).
    * ``counters``: named non-negative integers (``frames_in``, ``frames_dropped``...).
    * ``values``: named finite floats (``latency_p50_s``, ``field_gaussians``...).
    At most ``MAX_DIAG_ENTRIES`` of each; names are 1-64 chars of ``[A-Za-z0-9_.:/-]``.
    """

    TYPE_NAME: ClassVar[str] = "Diagnostics"
    SCHEMA_VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = 64 << 10
    FIELDS = (
        Scalar("stamp_s", "f64", doc="the node's step time when it reported"),
        Scalar("sequence", "u64", doc="the node's diagnostics counter: 1 for its first report, +1 for each"),
        Str("node", 256, doc="the node's id"),
        Str("state", 1024, doc="its state word"),
        Map("counters", Scalar("value", "u64"), MAX_DIAG_ENTRIES, doc="named counts since the node started"),
        Map("values", Scalar("value", "f64"), MAX_DIAG_ENTRIES, doc="named figures (`latency_p50_s`, ...)"),
    )
    WIRE_RULES: ClassVar[tuple[str, ...]] = (
        "a `counters` or `values` key that is not 1-64 characters of `A-Z a-z 0-9 _ . : / -`",
    )

    stamp_s: float
    node: str
    state: str = ""
    counters: dict[str, int] = field(default_factory=dict)
    values: dict[str, float] = field(default_factory=dict)
    sequence: int = 0

    def __post_init__(self):
        self.stamp_s = check_finite(self.stamp_s, "Diagnostics.stamp_s")
        self.node = check_text(self.node, "Diagnostics.node", text_cap(self.FIELDS, "node"))
        self.state = check_text(self.state, "Diagnostics.state", text_cap(self.FIELDS, "state"))
        self.counters = check_name_map(self.counters, "Diagnostics.counters", int, MAX_DIAG_ENTRIES)
        self.values = check_name_map(self.values, "Diagnostics.values", float, MAX_DIAG_ENTRIES)
        self.sequence = check_sequence(self.sequence, "Diagnostics.sequence")


@register_message
@dataclass
class PlannerRequest(Message):
    """What ``planner/request`` carries.

    * ``kind``: ``"suggest"`` (a suggestion now: a passive planner searches at once, the active
      loop re-publishes its newest), ``"reset"``
      (forget the field and start over), ``"stop"`` (end the active loop and settle).
    * ``max_candidates``: how many candidates to return; 0 = the planner's default.
    """

    TYPE_NAME: ClassVar[str] = "PlannerRequest"
    SCHEMA_VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = 1024
    FIELDS = (
        Enum(
            "kind",
            REQUEST_KINDS,
            doc="`suggest`: a suggestion on `planner/suggestion` now. A passive planner (`active: false`) searches "
            "its newest field at once; the active loop's planner does not start a search (it searches on its own "
            "schedule) and publishes its newest suggestion again, the same message with the same `sequence` (nothing "
            "before its first). `reset`: forget the field and start over; `stop`: end the active loop and settle",
        ),
        Scalar(
            "max_candidates", "u32", doc="at most 64; 0 = the planner's default (the planner node does not use it yet)"
        ),
        Scalar("stamp_s", "f64", doc="when it was sent"),
        Scalar("sequence", "u64", doc="the sender's request counter"),
    )
    WIRE_RULES: ClassVar[tuple[str, ...]] = ("`max_candidates` above 64",)

    kind: str = "suggest"
    max_candidates: int = 0
    stamp_s: float = 0.0
    sequence: int = 0

    def __post_init__(self):
        if self.kind not in REQUEST_KINDS:
            raise MessageError(f"PlannerRequest.kind must be one of {REQUEST_KINDS}, got {self.kind!r}")
        self.max_candidates = check_sequence(self.max_candidates, "PlannerRequest.max_candidates")
        if self.max_candidates > 64:
            raise MessageError(f"PlannerRequest.max_candidates must be <= 64, got {self.max_candidates}")
        self.stamp_s = check_finite(self.stamp_s, "PlannerRequest.stamp_s")
        self.sequence = check_sequence(self.sequence, "PlannerRequest.sequence")
