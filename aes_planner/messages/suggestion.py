"""``ViewSuggestion``: the planner's ranked candidate views, each with its score explained."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from aes_planner.messages.codec import (
    Array,
    Enum,
    List,
    Map,
    Message,
    MessageError,
    Optional,
    Scalar,
    Str,
    Struct,
    register_message,
    text_cap,
)
from aes_planner.messages.fields import (
    check_finite,
    check_name_map,
    check_optional_finite,
    check_pose,
    check_sequence,
    check_text,
)

__all__ = ["Candidate", "ViewSuggestion", "MAX_CANDIDATES", "MAX_TERMS", "SUGGESTION_KINDS", "MODES"]

MAX_CANDIDATES = 64
MAX_TERMS = 32
MODES = ("rig", "free")
#: What a suggestion is: ``search`` (the ranked result of a search) or ``waypoint`` (the pose a
#: drone is flying to now: exploring, moving to a candidate, or polishing, scored by prediction).
SUGGESTION_KINDS = ("search", "waypoint")


def view_of(cam2world: np.ndarray) -> np.ndarray:
    """cam2world ``[4, 4]`` -> ``[5]`` (x, y, z, yaw, pitch) by the conventions of
    :mod:`aes_planner.geometry` (yaw from the optical axis, or from the right axis at the poles)."""
    right, forward = cam2world[:3, 0], cam2world[:3, 2]
    at_pole = forward[0] ** 2 + forward[1] ** 2 < 1e-12
    yaw = math.atan2(right[0], -right[1]) if at_pole else math.atan2(forward[1], forward[0])
    pitch = math.atan2(forward[2], forward[0] * math.cos(yaw) + forward[1] * math.sin(yaw))
    pitch = min(math.pi / 2, max(-math.pi / 2, pitch))
    return np.array([*cam2world[:3, 3], yaw, pitch], dtype=np.float64)


@dataclass
class Candidate:
    """One suggested view.

    * ``cam2world``: ``[4, 4]`` float64 WORLD pose (OpenCV camera axes), rigid.
    * ``score``: the predicted aesthetic score (the scorer's units; higher is better).
    * ``coverage``: fraction of the view the field covers, in [0, 1].
    * ``pan_rad``, ``tilt_rad``: the joint angles that reach it on a rig (both or neither).
    * ``terms``: named parts of the score (``{"thirds": 0.3, ...}``), at most ``MAX_TERMS``.

    ``position_m``, ``yaw_rad``, ``pitch_rad`` and ``view`` (x, y, z, yaw, pitch) are read from
    ``cam2world`` with the conventions of :mod:`aes_planner.geometry`.
    """

    FIELDS: ClassVar[tuple] = (
        Array("cam2world", "f8", (4, 4), exact=True, doc="the suggested camera pose"),
        Scalar("score", "f64", doc="predicted aesthetic score, higher is better"),
        Scalar("coverage", "f64", doc="fraction of the view the field covers, [0, 1]"),
        Optional(Scalar("pan_rad", "f64", doc="the joints that reach it on a rig (both or neither)")),
        Optional(Scalar("tilt_rad", "f64")),
        Map("terms", Scalar("value", "f64"), MAX_TERMS, doc="named parts of the score (`thirds`, ...)"),
    )
    WIRE_RULES: ClassVar[tuple[str, ...]] = (
        "a candidate's `cam2world` that is not rigid (as `PosedFrame.cam2world`)",
        "a candidate's `coverage` outside [0, 1], or `pan_rad` without `tilt_rad` (or the reverse)",
        "a `terms` key that is not 1-64 characters of `A-Z a-z 0-9 _ . : / -`",
    )

    cam2world: np.ndarray
    score: float
    coverage: float = 1.0
    pan_rad: float | None = None
    tilt_rad: float | None = None
    terms: dict[str, float] = field(default_factory=dict)

    def __post_init__(self):
        self.cam2world = check_pose(self.cam2world, "Candidate.cam2world")
        self.score = check_finite(self.score, "Candidate.score")
        self.coverage = check_finite(self.coverage, "Candidate.coverage")
        if not 0.0 <= self.coverage <= 1.0:
            raise MessageError(f"Candidate.coverage must be in [0, 1], got {self.coverage}")
        self.pan_rad = check_optional_finite(self.pan_rad, "Candidate.pan_rad")
        self.tilt_rad = check_optional_finite(self.tilt_rad, "Candidate.tilt_rad")
        if (self.pan_rad is None) != (self.tilt_rad is None):
            raise MessageError("Candidate.pan_rad and tilt_rad must be given together (or neither)")
        self.terms = check_name_map(self.terms, "Candidate.terms", float, MAX_TERMS)

    @property
    def position_m(self) -> np.ndarray:
        return self.cam2world[:3, 3].copy()

    @property
    def view(self) -> np.ndarray:
        """``[5]`` (x, y, z, yaw, pitch), yaw in (-pi, pi], pitch in [-pi/2, pi/2].

        The numpy twin of :func:`aes_planner.geometry.cam2world_to_view` (a test compares them),
        so that reading a suggestion needs no torch."""
        return view_of(self.cam2world)

    @property
    def yaw_rad(self) -> float:
        return float(self.view[3])

    @property
    def pitch_rad(self) -> float:
        return float(self.view[4])

    @classmethod
    def _from_wire(cls, values: dict, version: int) -> Candidate:
        return cls(**values)

    def _json_extra(self) -> dict:
        return {"view": self.view.tolist()}


@register_message
@dataclass
class ViewSuggestion(Message):
    """What ``planner/suggestion`` carries: ranked candidates, best first.

    * ``stamp_s``: when the search that made it began (the planner's step time; it is published
      when the search ends, seconds later).
    * ``sequence``: the planner's suggestion counter (1 for its first).
    * ``field_version``: the version of the aesthetic field the candidates were scored on
      (bumped on every update; two suggestions with the same version come from the same field).
    * ``candidates``: at most ``MAX_CANDIDATES`` :class:`Candidate`, best first; may be empty
      (nothing better to suggest).
    * ``frame_id``: the frame of the poses, ``"world"``.
    * ``mode``: ``"rig"`` (pan/tilt given) or ``"free"`` (5-DoF views for a drone).
    * ``kind``: ``"search"`` (the candidates a search ranked) or ``"waypoint"`` (one candidate: the
      pose the drone is being sent to now, scored by the field's prediction, 0 when it has none;
      free mode only). Schema version 2; a version-1 message decodes as ``"search"``.
    * ``covered_fraction``: the share of views spread over the platform's whole space that the
      inputs cover (the field has seen enough of them to score them), in [0, 1]; None when the
      search did not measure it (a waypoint, framing, ``explore_points: 0``). Schema version 3.
    * ``explore``: a second, exploratory candidate, not ranked with ``candidates``: the best-scored
      view at the edge of what the inputs saw (partly covered), for a loop or a user who would
      rather look where nothing was seen yet; None when everything is covered. Schema version 3;
      older messages decode both as None.
    """

    TYPE_NAME: ClassVar[str] = "ViewSuggestion"
    WIRE_RULES: ClassVar[tuple[str, ...]] = ("`covered_fraction` present and outside [0, 1]",)
    SCHEMA_VERSION: ClassVar[int] = 3
    MAX_BYTES: ClassVar[int] = 1 << 20
    FIELDS = (
        Scalar(
            "stamp_s",
            "f64",
            doc="when the search that made it **began** (the planner's step time); it is published when the "
            "search ends, seconds later (`latency_p50_s` in `planner/diagnostics`): judge a suggestion's age "
            "by `sequence` and arrival, not by this stamp",
        ),
        Scalar(
            "sequence",
            "u64",
            doc="the planner's suggestion counter: 1 for its first, +1 for each new one (one re-published on request keeps its number)",
        ),
        Scalar("field_version", "u64", doc="version of the aesthetic field that scored the candidates"),
        Str("frame_id", 4096, doc="frame of the poses: `world`"),
        Enum("mode", MODES, doc="`rig`: pan/tilt given; `free`: 5-DoF views for a drone"),
        List("candidates", Struct("candidate", Candidate), "u32", MAX_CANDIDATES, doc="best first; may be empty"),
        Enum(
            "kind",
            SUGGESTION_KINDS,
            since=2,
            default="search",
            doc="`search`: the ranked result of a search; `waypoint`: one candidate, the pose a drone is being "
            "sent to now, scored by the field's prediction (0 when none), free mode only",
        ),
        Optional(
            Scalar(
                "covered_fraction",
                "f64",
                doc="share of views spread over the platform's whole space that the inputs cover, [0, 1]; "
                "absent when not measured",
            ),
            since=3,
        ),
        Optional(
            Struct(
                "explore",
                Candidate,
                doc="an exploratory candidate at the edge of what the inputs saw, not ranked with `candidates`; "
                "absent when everything is covered",
            ),
            since=3,
        ),
    )

    stamp_s: float
    candidates: list[Candidate] = field(default_factory=list)
    field_version: int = 0
    sequence: int = 0
    frame_id: str = "world"
    mode: str = "free"
    kind: str = "search"
    covered_fraction: float | None = None
    explore: Candidate | None = None

    def __post_init__(self):
        self.stamp_s = check_finite(self.stamp_s, "ViewSuggestion.stamp_s")
        if not isinstance(self.candidates, (list, tuple)):
            raise MessageError(f"ViewSuggestion.candidates must be a list, got {type(self.candidates).__name__}")
        if len(self.candidates) > MAX_CANDIDATES:
            raise MessageError(f"ViewSuggestion has {len(self.candidates)} candidates; the cap is {MAX_CANDIDATES}")
        for i, c in enumerate(self.candidates):
            if not isinstance(c, Candidate):
                raise MessageError(f"ViewSuggestion.candidates[{i}] must be a Candidate, got {type(c).__name__}")
        self.candidates = list(self.candidates)
        self.field_version = check_sequence(self.field_version, "ViewSuggestion.field_version")
        self.sequence = check_sequence(self.sequence, "ViewSuggestion.sequence")
        self.frame_id = check_text(self.frame_id, "ViewSuggestion.frame_id", text_cap(self.FIELDS, "frame_id"))
        if self.mode not in MODES:
            raise MessageError(f"ViewSuggestion.mode must be 'rig' or 'free', got {self.mode!r}")
        if self.kind not in SUGGESTION_KINDS:
            raise MessageError(f"ViewSuggestion.kind must be one of {SUGGESTION_KINDS}, got {self.kind!r}")
        self.covered_fraction = check_optional_finite(self.covered_fraction, "ViewSuggestion.covered_fraction")
        if self.covered_fraction is not None and not 0.0 <= self.covered_fraction <= 1.0:
            raise MessageError(f"ViewSuggestion.covered_fraction must be in [0, 1], got {self.covered_fraction}")
        if self.explore is not None and not isinstance(self.explore, Candidate):
            raise MessageError(f"ViewSuggestion.explore must be a Candidate or None, got {type(self.explore).__name__}")

    @property
    def best(self) -> Candidate | None:
        return self.candidates[0] if self.candidates else None
