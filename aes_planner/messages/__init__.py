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
=================  ==========================  ================================================

Encoding: :func:`encode` / :func:`decode` (see :mod:`aes_planner.messages.codec` for the
layout): a header naming the type and its schema version, then fixed fields and raw
little-endian arrays; no pickle. :func:`decode` checks the magic, versions, size caps
(``MAX_BYTES`` per type), lengths, dtypes, shapes, finiteness and rigid rotations, and raises
only :class:`MessageError`. :func:`to_jsonable` gives a JSON-ready summary (images summarised).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from aes_planner.messages.codec import (
    MESSAGE_TYPES,
    Header,
    Message,
    MessageError,
    decode,
    encode,
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
    "decode",
    "encode",
    "message_type",
    "peek_header",
    "to_jsonable",
]


def to_jsonable(msg: Message) -> dict[str, Any]:
    """A JSON-ready dict of ``msg`` with its ``type``; images and depth maps are summarised
    (shape, mean), candidates gain their ``view`` (x, y, z, yaw, pitch)."""
    out: dict[str, Any] = {"type": type(msg).TYPE_NAME}
    if isinstance(msg, PosedFrame):
        k = msg.intrinsics
        out.update(
            stamp_s=msg.stamp_s,
            sequence=msg.sequence,
            frame_id=msg.frame_id,
            image={"width": msg.width, "height": msg.height, "mean_rgb": msg.image.reshape(-1, 3).mean(0).tolist()},
            intrinsics={"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy},
            cam2world=msg.cam2world.tolist(),
            depth_m=None
            if msg.depth_m is None
            else {"valid": float((msg.depth_m > 0).mean()), "max": float(msg.depth_m.max())},
            pan_rad=msg.pan_rad,
            tilt_rad=msg.tilt_rad,
        )
        return out
    if isinstance(msg, ViewSuggestion):
        out.update(
            stamp_s=msg.stamp_s,
            sequence=msg.sequence,
            field_version=msg.field_version,
            frame_id=msg.frame_id,
            mode=msg.mode,
            candidates=[
                {
                    "score": c.score,
                    "coverage": c.coverage,
                    "view": c.view.tolist(),
                    "pan_rad": c.pan_rad,
                    "tilt_rad": c.tilt_rad,
                    "terms": dict(c.terms),
                    "cam2world": c.cam2world.tolist(),
                }
                for c in msg.candidates
            ],
        )
        return out
    import dataclasses

    for f in dataclasses.fields(msg):
        v = getattr(msg, f.name)
        if isinstance(v, np.ndarray):
            v = v.tolist()
        elif isinstance(v, tuple):
            v = list(v)
        out[f.name] = v
    return out
