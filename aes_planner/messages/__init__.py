"""Typed messages exchanged between the parts of the planner, and their wire format.

Types (each a validated dataclass; construction raises :class:`MessageError` naming the field):

=================  ==========================  ================================================
type               usual topic                 what
=================  ==========================  ================================================
``PosedFrame``     ``camera/frame``            image + intrinsics + pose (+ depth, joints)
``ViewSuggestion`` ``planner/suggestion``      ranked :class:`Candidate` views, scores explained
``GimbalCommand``  ``gimbal/command``          move to pan/tilt (rad), stop, reboot
``GimbalState``    ``gimbal/state``            present and goal pan/tilt, moving, faults
``Diagnostics``    ``<node>/diagnostics``      named counters and values, a state word
``PlannerRequest`` ``planner/request``         ask for a suggestion now, reset, stop
``DroneState``     ``drone/state``             a vehicle's pose, camera pose, mode, link (ENU)
``Clock``          ``clock``                   a simulated graph's time (lockstep, ``--clock sim``)
``ClockAck``       ``clock/ack``               a node has handled a tick of the simulated clock
=================  ==========================  ================================================

Encoding: :func:`encode` / :func:`decode` (specified in ``docs/wire.md``; each type's fields are
declared once, in its ``FIELDS`` table, see :mod:`aes_planner.messages.codec`): a header naming
the type and its schema version, then fixed fields and raw little-endian arrays; no pickle.
:func:`describe` gives a type's layout as JSON (what recordings carry). :func:`decode` checks the magic, versions, size caps
(``MAX_BYTES`` per type), lengths, dtypes, shapes, finiteness and rigid rotations, and raises
only :class:`MessageError`. :func:`to_jsonable` gives a JSON-ready summary (images summarised).
"""

from __future__ import annotations

from typing import Any

from aes_planner.messages.clock import Clock, ClockAck
from aes_planner.messages.codec import (
    MESSAGE_TYPES,
    Header,
    Message,
    MessageError,
    check_envelope,
    decode,
    describe,
    encode,
    fields_json,
    message_type,
    peek_header,
)
from aes_planner.messages.diagnostics import Diagnostics, PlannerRequest
from aes_planner.messages.drone import DroneState
from aes_planner.messages.gimbal import GimbalCommand, GimbalState
from aes_planner.messages.posed_frame import PosedFrame
from aes_planner.messages.suggestion import Candidate, ViewSuggestion

__all__ = [
    "MESSAGE_TYPES",
    "Candidate",
    "Clock",
    "ClockAck",
    "Diagnostics",
    "DroneState",
    "GimbalCommand",
    "GimbalState",
    "Header",
    "Message",
    "MessageError",
    "PlannerRequest",
    "PosedFrame",
    "ViewSuggestion",
    "check_envelope",
    "decode",
    "describe",
    "encode",
    "message_type",
    "peek_header",
    "to_jsonable",
]


def to_jsonable(msg: Message) -> dict[str, Any]:
    """A JSON-ready dict of ``msg`` with its ``type``, by its field table: images and depth maps
    are summarised (size, mean), candidates gain their ``view`` (x, y, z, yaw, pitch)."""
    return {"type": type(msg).TYPE_NAME, **fields_json(msg, type(msg).FIELDS)}
