"""What our messages look like in Foxglove: typed ``foxglove.*`` messages beside our own bytes.

For a message on topic ``T`` (shown as ``/T``), :func:`foxglove_view` returns:

* ``PosedFrame``: ``/T/image`` (``foxglove.CompressedImage``, PNG), ``/tf``
  (``foxglove.FrameTransform`` world -> the camera's optical frame), ``/T/scene``
  (``foxglove.SceneUpdate``: the camera's frustum in white). The camera's frame id is stable, one
  per topic (:func:`camera_frame_id`: ``camera/frame`` -> ``camera_optical``), moving in the
  world as a tf frame does; the message's own ``frame_id`` (``sim_camera/000012``) names the image,
  not a frame of the tree.
* ``ViewSuggestion``: ``/T/scene`` (``foxglove.SceneUpdate``: a frustum per candidate coloured
  by score, red = worst to green = best, with its rank and score as text), ``/tf`` (world ->
  ``suggestion``, the best candidate), ``/T/scores`` (JSON: best score, coverage, each term,
  the best view in degrees, all scores: plottable). A search's exploratory candidate (schema 3's
  ``explore``) is a blue frustum labelled ``explore``, and it and ``covered_fraction`` are in
  ``/T/scores`` too.
* ``Diagnostics`` of the planner (``planner/diagnostics``): also ``/T/framing``
  (``foxglove.SceneUpdate``: the lifted 3D box of each kept subject, green, and avoided region,
  red, as a ``CubePrimitive``; empty when no framing is active; docs/guides/framing.md).
* every other type: ``/T/json`` (JSON of :func:`aes_planner.messages.to_jsonable`, plottable).

Our own channel ``/T`` carries the message's bytes unchanged (message encoding
``aes-planner``), so a replay feeds a node exactly what it saw.

Time: every Foxglove message carries the message's own stamp (``stamp_s``: the capture time of a
frame, the planning time of a suggestion), never the time it was received; see
:func:`stamp_ns`. :func:`view_channels` lists the channels a type's view writes, so a live
server can advertise them before the first message.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass

import numpy as np

from aes_planner.messages import (
    Diagnostics,
    Message,
    PosedFrame,
    ViewSuggestion,
    describe,
    message_type,
    to_jsonable,
)

__all__ = [
    "VizMessage",
    "foxglove_view",
    "view_channels",
    "camera_frame_id",
    "stamp_ns",
    "OUR_ENCODING",
    "our_schema",
    "FrustumStyle",
]

OUR_ENCODING = "aes-planner"


@dataclass(frozen=True)
class VizMessage:
    """One message for a Foxglove-readable channel."""

    topic: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str
    data: bytes


@functools.cache
def our_schema(type_name: str, version: int) -> tuple[str, str, bytes]:
    """(name, encoding, data) of the schema of our own channel for ``type_name``: the data is the
    type's machine-readable layout (:func:`aes_planner.messages.describe`, JSON; docs/wire.md), from
    which a reader in any language decodes the channel's messages."""
    cls = message_type(type_name)
    if version != cls.SCHEMA_VERSION:
        raise ValueError(f"this build describes {type_name} version {cls.SCHEMA_VERSION}, not {version}")
    return f"aes_planner.{type_name}", OUR_ENCODING, json.dumps(describe(cls), indent=1).encode()


@dataclass(frozen=True)
class FrustumStyle:
    depth_m: float = 0.25
    hfov_rad: float = math.radians(60.0)
    aspect: float = 4.0 / 3.0
    thickness_px: float = 2.0


_SCHEMAS: dict[str, tuple[str, str, bytes]] = {}


def _proto_schema(cls) -> tuple[str, str, bytes]:
    key = cls.__name__
    if key not in _SCHEMAS:
        s = cls.get_schema()
        _SCHEMAS[key] = (s.name, s.encoding, bytes(s.data))
    return _SCHEMAS[key]


def _proto(topic: str, msg) -> VizMessage:
    name, enc, data = _proto_schema(type(msg))
    return VizMessage(topic, name, enc, data, "protobuf", msg.encode())


_JSON_SCHEMA = json.dumps({"type": "object", "additionalProperties": True}).encode()


def _json(topic: str, name: str, obj) -> VizMessage:
    return VizMessage(topic, name, "jsonschema", _JSON_SCHEMA, "json", json.dumps(obj).encode())


def stamp_ns(msg: Message, fallback_ns: int) -> int:
    """The message's own stamp (``stamp_s``) in integer nanoseconds; ``fallback_ns`` (the receive
    time) for a message without one or with a stamp before 1970, which no timestamp can hold."""
    stamp_s = getattr(msg, "stamp_s", None)
    if stamp_s is None or not math.isfinite(stamp_s) or stamp_s < 0 or stamp_s >= 2**63 / 1e9:
        return int(fallback_ns)
    return round(stamp_s * 1e9)


def camera_frame_id(topic: str) -> str:
    """The stable tf frame of the camera publishing on ``topic``: its tokens without a last
    ``frame``, joined by ``_``, with REP-103's ``_optical`` suffix (OpenCV axes):
    ``camera/frame`` -> ``camera_optical``, ``left/camera/frame`` -> ``left_camera_optical``."""
    tokens = topic.strip("/").split("/")
    if len(tokens) > 1 and tokens[-1] == "frame":
        tokens = tokens[:-1]
    return "_".join(tokens) + "_optical"


#: The tf frame of the best suggestion (world -> suggestion).
SUGGESTION_FRAME = "suggestion"
#: The colour (RGBA) of a suggestion's exploratory candidate: apart from the red-to-green ranked ones.
EXPLORE_COLOR = (0.2, 0.5, 1.0, 1.0)


def _stamp(t_ns: int):
    from foxglove.messages import Timestamp

    return Timestamp(t_ns // 1_000_000_000, t_ns % 1_000_000_000)


def _quat_xyzw(rotation: np.ndarray):
    from foxglove.messages import Quaternion

    from aes_planner.geometry import matrix_to_quat

    w, x, y, z = (float(v) for v in np.asarray(matrix_to_quat(rotation), dtype=np.float64))
    return Quaternion(x=x, y=y, z=z, w=w)


def _transform(parent: str, child: str, cam2world: np.ndarray, log_time_ns: int):
    from foxglove.messages import FrameTransform, Vector3

    t = cam2world[:3, 3]
    return FrameTransform(
        timestamp=_stamp(log_time_ns),
        parent_frame_id=parent,
        child_frame_id=child,
        translation=Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2])),
        rotation=_quat_xyzw(cam2world[:3, :3]),
    )


def _frustum_points(cam2world: np.ndarray, style: FrustumStyle, hfov_rad: float, aspect: float) -> list:
    """LINE_LIST points (pairs) of a pyramid from the optical centre to the image corners."""
    from foxglove.messages import Point3

    half_w = math.tan(hfov_rad / 2) * style.depth_m
    half_h = half_w / aspect
    d = style.depth_m
    corners = np.array([[-half_w, -half_h, d], [half_w, -half_h, d], [half_w, half_h, d], [-half_w, half_h, d]])
    world = corners @ cam2world[:3, :3].T + cam2world[:3, 3]  # [4, 3]
    origin = cam2world[:3, 3]
    pts = []
    for i in range(4):
        pts += [origin, world[i], world[i], world[(i + 1) % 4]]
    return [Point3(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in pts]


def _entity(eid: str, cam2world, color, label: str, log_time_ns: int, style: FrustumStyle, hfov, aspect):
    from foxglove.messages import (
        Color,
        LinePrimitive,
        LinePrimitiveLineType,
        Pose,
        Quaternion,
        SceneEntity,
        TextPrimitive,
        Vector3,
    )

    r, g, b, a = color
    identity = Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
    line = LinePrimitive(
        type=LinePrimitiveLineType.LineList,
        pose=identity,
        thickness=style.thickness_px,
        scale_invariant=True,
        points=_frustum_points(cam2world, style, hfov, aspect),
        color=Color(r=r, g=g, b=b, a=a),
    )
    t = cam2world[:3, 3]
    texts = []
    if label:
        texts.append(
            TextPrimitive(
                pose=Pose(
                    position=Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2]) + 0.05),
                    orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                ),
                billboard=True,
                font_size=12.0,
                scale_invariant=True,
                color=Color(r=r, g=g, b=b, a=1.0),
                text=label,
            )
        )
    return SceneEntity(timestamp=_stamp(log_time_ns), frame_id="world", id=eid, lines=[line], texts=texts)


def score_color(score: float, lo: float, hi: float) -> tuple[float, float, float, float]:
    """Red (worst) to green (best) over [lo, hi]; green when all scores are equal."""
    t = 1.0 if hi - lo <= 1e-12 else (score - lo) / (hi - lo)
    t = min(1.0, max(0.0, t))
    return (1.0 - t, t, 0.15, 1.0)


#: Colours (RGBA) of the framing boxes: the kept subject green, an avoided region red; see-through.
FRAMING_COLORS = {"keep": (0.15, 0.85, 0.25, 0.35), "avoid": (0.9, 0.15, 0.15, 0.35)}


def framing_boxes(values: dict[str, float]) -> list[tuple[str, np.ndarray, np.ndarray, float]]:
    """The planner's lifted framing boxes from its diagnostics values (``framing.box<i>.<keep|avoid>``
    ``.cx .cy .cz .sx .sy .sz .yaw_rad``, :func:`aes_planner.node.planner.box_values`):
    ``[(kind, centre [3], size [3], yaw_rad)]``; incomplete or non-finite boxes are left out."""
    found: dict[tuple[str, str], dict[str, float]] = {}
    for name, v in values.items():
        parts = name.split(".")
        if len(parts) == 4 and parts[0] == "framing" and parts[1].startswith("box") and parts[2] in FRAMING_COLORS:
            found.setdefault((parts[1], parts[2]), {})[parts[3]] = v
    out = []
    for (_, kind), d in sorted(found.items()):
        keys = ("cx", "cy", "cz", "sx", "sy", "sz", "yaw_rad")
        if all(k in d and math.isfinite(d[k]) for k in keys):
            out.append(
                (kind, np.array([d["cx"], d["cy"], d["cz"]]), np.array([d["sx"], d["sy"], d["sz"]]), d["yaw_rad"])
            )
    return out


def _framing_scene(boxes, log_time_ns: int):
    """A SceneUpdate that replaces every framing box with ``boxes`` (a CubePrimitive each, in world)."""
    from foxglove.messages import (
        Color,
        CubePrimitive,
        Pose,
        Quaternion,
        SceneEntity,
        SceneEntityDeletion,
        SceneEntityDeletionType,
        SceneUpdate,
        Vector3,
    )

    entities = []
    for i, (kind, centre, size, yaw) in enumerate(boxes):
        r, g, b, a = FRAMING_COLORS[kind]
        pose = Pose(
            position=Vector3(x=float(centre[0]), y=float(centre[1]), z=float(centre[2])),
            orientation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
        )
        cube = CubePrimitive(
            pose=pose,
            size=Vector3(x=float(size[0]), y=float(size[1]), z=float(size[2])),
            color=Color(r=r, g=g, b=b, a=a),
        )
        entities.append(SceneEntity(timestamp=_stamp(log_time_ns), frame_id="world", id=f"{kind}_{i}", cubes=[cube]))
    deletions = [SceneEntityDeletion(timestamp=_stamp(log_time_ns), type=SceneEntityDeletionType.All, id="")]
    return SceneUpdate(deletions=deletions, entities=entities)


def view_channels(topic: str, msg_type: type[Message]) -> list[tuple[str, tuple[str, str, bytes], str]]:
    """``[(channel topic, (schema name, schema encoding, schema data), message encoding)]`` that
    :func:`foxglove_view` writes for messages of ``msg_type`` on ``topic`` (our own channel not
    included): what a live server advertises before the first message arrives."""
    from foxglove.messages import CompressedImage, FrameTransform, SceneUpdate

    base = "/" + topic.strip("/")
    if issubclass(msg_type, PosedFrame):
        return [
            (f"{base}/image", _proto_schema(CompressedImage), "protobuf"),
            ("/tf", _proto_schema(FrameTransform), "protobuf"),
            (f"{base}/scene", _proto_schema(SceneUpdate), "protobuf"),
        ]
    if issubclass(msg_type, ViewSuggestion):
        return [
            (f"{base}/scene", _proto_schema(SceneUpdate), "protobuf"),
            ("/tf", _proto_schema(FrameTransform), "protobuf"),
            (f"{base}/scores", ("aes_planner.SuggestionScores", "jsonschema", _JSON_SCHEMA), "json"),
        ]
    out = [(f"{base}/json", (f"aes_planner.{msg_type.TYPE_NAME}Json", "jsonschema", _JSON_SCHEMA), "json")]
    if issubclass(msg_type, Diagnostics) and base.endswith("planner/diagnostics"):
        out.append((f"{base}/framing", _proto_schema(SceneUpdate), "protobuf"))
    return out


class _ViewState:
    """Remembers the last camera's field of view so suggestion frustums match it."""

    hfov_rad = FrustumStyle.hfov_rad
    aspect = FrustumStyle.aspect


def foxglove_view(
    topic: str, msg: Message, recv_time_ns: int, style: FrustumStyle | None = None, state: _ViewState | None = None
) -> list[VizMessage]:
    """The Foxglove-typed messages showing ``msg`` (published on ``topic``), stamped with the
    message's own stamp (``recv_time_ns`` only when it has none, see :func:`stamp_ns`); see the
    module doc."""
    import cv2
    from foxglove.messages import CompressedImage, SceneUpdate

    style = style or FrustumStyle()
    state = state or _ViewState()
    base = "/" + topic
    out: list[VizMessage] = []
    log_time_ns = stamp_ns(msg, recv_time_ns)
    if isinstance(msg, PosedFrame):
        ok, png = cv2.imencode(".png", np.ascontiguousarray(msg.image[..., ::-1]))
        camera = camera_frame_id(topic)
        if ok:
            out.append(
                _proto(
                    f"{base}/image",
                    CompressedImage(timestamp=_stamp(log_time_ns), frame_id=camera, data=png.tobytes(), format="png"),
                )
            )
        out.append(_proto("/tf", _transform("world", camera, msg.cam2world, log_time_ns)))
        state.hfov_rad = msg.intrinsics.hfov_rad
        state.aspect = msg.width / msg.height
        ent = _entity(
            "camera", msg.cam2world, (1.0, 1.0, 1.0, 1.0), "", log_time_ns, style, state.hfov_rad, state.aspect
        )
        out.append(_proto(f"{base}/scene", SceneUpdate(entities=[ent])))
        return out
    if isinstance(msg, ViewSuggestion):
        scores = [c.score for c in msg.candidates]
        lo, hi = (min(scores), max(scores)) if scores else (0.0, 0.0)
        entities = [
            _entity(
                f"candidate_{i}",
                c.cam2world,
                score_color(c.score, lo, hi),
                f"#{i + 1} {c.score:.3f}",
                log_time_ns,
                style,
                state.hfov_rad,
                state.aspect,
            )
            for i, c in enumerate(msg.candidates)
        ]
        if msg.explore is not None:  # the exploratory candidate: not ranked, drawn apart in blue
            entities.append(
                _entity(
                    "explore",
                    msg.explore.cam2world,
                    EXPLORE_COLOR,
                    f"explore {msg.explore.score:.3f}",
                    log_time_ns,
                    style,
                    state.hfov_rad,
                    state.aspect,
                )
            )
        from foxglove.messages import SceneEntityDeletion, SceneEntityDeletionType

        deletions = [SceneEntityDeletion(timestamp=_stamp(log_time_ns), type=SceneEntityDeletionType.All, id="")]
        out.append(_proto(f"{base}/scene", SceneUpdate(deletions=deletions, entities=entities)))
        summary: dict = {
            "stamp_s": msg.stamp_s,
            "kind": msg.kind,
            "field_version": msg.field_version,
            "count": len(scores),
        }
        best = msg.best
        if best is not None:
            out.append(_proto("/tf", _transform("world", SUGGESTION_FRAME, best.cam2world, log_time_ns)))
            x, y, z, yaw, pitch = best.view.tolist()
            summary["best"] = {
                "score": best.score,
                "coverage": best.coverage,
                "terms": dict(best.terms),
                "x_m": x,
                "y_m": y,
                "z_m": z,
                "yaw_deg": math.degrees(yaw),
                "pitch_deg": math.degrees(pitch),
            }
            if best.pan_rad is not None:
                summary["best"]["pan_deg"] = math.degrees(best.pan_rad)
                summary["best"]["tilt_deg"] = math.degrees(best.tilt_rad)
        summary["scores"] = scores
        if msg.covered_fraction is not None:
            summary["covered_fraction"] = msg.covered_fraction
        if msg.explore is not None:
            _, _, _, yaw, pitch = msg.explore.view.tolist()
            summary["explore"] = {"score": msg.explore.score, "coverage": msg.explore.coverage,
                                  "yaw_deg": math.degrees(yaw), "pitch_deg": math.degrees(pitch)}  # fmt: skip
        out.append(_json(f"{base}/scores", "aes_planner.SuggestionScores", summary))
        return out
    if isinstance(msg, Diagnostics):
        boxes = framing_boxes(msg.values)
        if boxes or any(k.startswith("framing.") for k in msg.values) or topic.endswith("planner/diagnostics"):
            out.append(_proto(f"{base}/framing", _framing_scene(boxes, log_time_ns)))
    obj = to_jsonable(msg)
    for key in ("pan_rad", "tilt_rad", "goal_pan_rad", "goal_tilt_rad"):
        if isinstance(obj.get(key), float):
            obj[key.replace("_rad", "_deg")] = math.degrees(obj[key])
    out.append(_json(f"{base}/json", f"aes_planner.{type(msg).TYPE_NAME}Json", obj))
    return out
