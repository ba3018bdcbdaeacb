"""``Diagnostics`` (a node's health: named counters and values, and its state) and
``PlannerRequest`` (ask the planner for something)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

from aes_planner.messages.codec import (
    Enum,
    List,
    Map,
    Message,
    MessageError,
    Scalar,
    Str,
    Struct,
    register_message,
    text_cap,
)
from aes_planner.messages.fields import check_finite, check_name_map, check_sequence, check_text

__all__ = ["Diagnostics", "FramingRegion", "PlannerRequest", "REQUEST_KINDS", "MAX_DIAG_ENTRIES", "MAX_REGIONS"]

MAX_DIAG_ENTRIES = 128
REQUEST_KINDS = ("suggest", "reset", "stop")
#: Most keep (and most avoid) regions one request carries.
MAX_REGIONS = 8


@dataclass
class FramingRegion:
    """A box ``[x0, x1] x [y0, y1]`` in pixels of the input frame named ``frame`` (its frame id,
    or the image file name as ``cameras.json`` has it): ``suggest --keep FRAME:X0,Y0,X1,Y1``."""

    FIELDS: ClassVar[tuple] = (
        Str("frame", 256, doc="the input frame the box is drawn on: its frame id, or its image file name"),
        Scalar("x0", "f64", doc="the box's left edge, pixels of that frame (x right, y down)"),
        Scalar("y0", "f64", doc="its top edge"),
        Scalar("x1", "f64", doc="its right edge, > x0"),
        Scalar("y1", "f64", doc="its bottom edge, > y0"),
    )
    WIRE_RULES: ClassVar[tuple[str, ...]] = (
        "a region with an empty `frame`, `x1 <= x0` or `y1 <= y0`, or `x0` or `y0` below 0",
    )

    frame: str
    x0: float
    y0: float
    x1: float
    y1: float

    def __post_init__(self):
        self.frame = check_text(self.frame, "FramingRegion.frame", text_cap(self.FIELDS, "frame"))
        if not self.frame:
            raise MessageError("FramingRegion.frame is empty; name the input frame the box is drawn on")
        for name in ("x0", "y0", "x1", "y1"):
            setattr(self, name, check_finite(getattr(self, name), f"FramingRegion.{name}"))
        if self.x1 <= self.x0 or self.y1 <= self.y0:
            raise MessageError(
                f"FramingRegion {self.frame}: the box ({self.x0:g}, {self.y0:g}, {self.x1:g}, {self.y1:g}) has zero "
                "size; x1 > x0 and y1 > y0 (pixels)"
            )
        if min(self.x0, self.y0) < 0:
            raise MessageError(f"FramingRegion {self.frame}: x0 and y0 must be >= 0 (pixels)")

    @classmethod
    def _from_wire(cls, values: dict, version: int) -> FramingRegion:
        return cls(**values)


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
    * ``set_framing`` (schema 2): when true, ``keep`` and ``avoid`` replace the framing the planner
      applies to its searches (both empty: no framing); when false they are ignored.
    * ``keep`` / ``avoid`` (schema 2): at most ``MAX_REGIONS`` :class:`FramingRegion` each: subjects
      every suggestion holds whole, regions suggestions steer away from.
    * ``keep_margin`` (schema 2): the kept subjects stay this fraction of the frame inside every
      edge, in [0, 0.4) (default 0.05).

    A version-1 message decodes with ``set_framing`` false: an older client leaves the framing alone.
    """

    TYPE_NAME: ClassVar[str] = "PlannerRequest"
    SCHEMA_VERSION: ClassVar[int] = 2
    MAX_BYTES: ClassVar[int] = 16 << 10
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
        Scalar(
            "set_framing",
            "bool",
            since=2,
            default=False,
            doc="true: `keep` and `avoid` replace the framing the planner applies to its searches (both empty: no "
            "framing); false: they are ignored",
        ),
        List(
            "keep",
            Struct("region", FramingRegion),
            "u8",
            MAX_REGIONS,
            since=2,
            default=[],
            doc="subjects every suggestion holds whole",
        ),
        List(
            "avoid",
            Struct("region", FramingRegion),
            "u8",
            MAX_REGIONS,
            since=2,
            default=[],
            doc="regions suggestions steer away from",
        ),
        Scalar(
            "keep_margin",
            "f64",
            since=2,
            default=0.05,
            doc="the kept subjects stay this fraction of the frame inside every edge, in [0, 0.4)",
        ),
    )
    WIRE_RULES: ClassVar[tuple[str, ...]] = ("`max_candidates` above 64, or `keep_margin` outside [0, 0.4)",)

    kind: str = "suggest"
    max_candidates: int = 0
    stamp_s: float = 0.0
    sequence: int = 0
    set_framing: bool = False
    keep: list[FramingRegion] = field(default_factory=list)
    avoid: list[FramingRegion] = field(default_factory=list)
    keep_margin: float = 0.05

    def __post_init__(self):
        if self.kind not in REQUEST_KINDS:
            raise MessageError(f"PlannerRequest.kind must be one of {REQUEST_KINDS}, got {self.kind!r}")
        self.max_candidates = check_sequence(self.max_candidates, "PlannerRequest.max_candidates")
        if self.max_candidates > 64:
            raise MessageError(f"PlannerRequest.max_candidates must be <= 64, got {self.max_candidates}")
        self.stamp_s = check_finite(self.stamp_s, "PlannerRequest.stamp_s")
        self.sequence = check_sequence(self.sequence, "PlannerRequest.sequence")
        self.set_framing = bool(self.set_framing)
        for name in ("keep", "avoid"):
            regions = getattr(self, name)
            if not isinstance(regions, (list, tuple)) or len(regions) > MAX_REGIONS:
                raise MessageError(f"PlannerRequest.{name} must be a list of at most {MAX_REGIONS} FramingRegion")
            for i, r in enumerate(regions):
                if not isinstance(r, FramingRegion):
                    raise MessageError(f"PlannerRequest.{name}[{i}] must be a FramingRegion, got {type(r).__name__}")
            setattr(self, name, list(regions))
        self.keep_margin = check_finite(self.keep_margin, "PlannerRequest.keep_margin")
        if not 0.0 <= self.keep_margin < 0.4 or math.isnan(self.keep_margin):
            raise MessageError(f"PlannerRequest.keep_margin must be in [0, 0.4), got {self.keep_margin}")
