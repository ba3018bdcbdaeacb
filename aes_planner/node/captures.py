"""What the planner's active loop keeps: the views it captured (:class:`Capture`) and the views it
goes to (:class:`Target`), and two questions asked of the captures: is a view already captured
(:func:`near_captured`), and what may a candidate score given the scorer's errors at the captures
(:func:`hopes`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from aes_planner.geometry.poses import cam2world_to_view
from aes_planner.messages import Candidate
from aes_planner.platform import view_angle_deg

__all__ = ["Capture", "CaptureKind", "Target", "decision_order", "hopes", "near_captured", "shortfall"]


class CaptureKind(str, Enum):
    """Why the loop took (or goes to take) a view. A ``str`` enum: it compares equal to, prints
    and serialises as its word (``"move"``), so summaries and reports keep their text."""

    INITIAL = "initial"  # the view the camera showed when the loop started
    EXPLORE = "explore"  # spread over the range before the field can be trusted
    MOVE = "move"  # a suggestion the field expects to beat the best capture
    VERIFY = "verify"  # the best predicted view of a hill not captured yet, before the polish
    POLISH = "polish"  # a compass step around the best capture
    SETTLE = "settle"  # back to the best capture, the loop's result
    PASSIVE = "passive"  # a passive planner's last pose seen (no capture of its own)
    QUEUED = "queued"  # a target not captured yet, counted as taken when ranking candidates

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


@dataclass
class Capture:
    """A view the active loop captured and scored with the teacher (the real image)."""

    kind: CaptureKind  # a word is read as its CaptureKind; an unknown one is refused
    cam2world: np.ndarray  # [4, 4]
    score: float
    stamp_s: float
    pan_rad: float | None = None
    tilt_rad: float | None = None
    predicted: float | None = None
    image: np.ndarray | None = field(default=None, repr=False)  # [H, W, 3] uint8
    look_m: float | None = None  # how far the view's middle is (median depth of its central ninth); None: no depth

    def __post_init__(self):
        self.kind = CaptureKind(self.kind)


@dataclass
class Target:
    """A view the loop commands and then captures (joints on a rig; the pose always)."""

    kind: CaptureKind  # what its capture will be
    cam2world: np.ndarray  # [4, 4]
    pan_rad: float | None = None
    tilt_rad: float | None = None
    predicted: float | None = None
    sent_s: float = -1.0
    arrived_s: float | None = None
    resent: bool = False
    on_path: bool = True  # its capture joins the search's input trajectory (False: the field only)
    far_best: float | None = None  # a move to an unvisited place: the best captured score when it was chosen

    def __post_init__(self):
        self.kind = CaptureKind(self.kind)


def look_distance_m(depth_m: np.ndarray | None) -> float | None:
    """The median z-depth (metres) of a frame's central ninth (``depth_m`` ``[H, W]``, 0 = no
    measurement); None without depth or without a measured pixel there."""
    if depth_m is None:
        return None
    h, w = depth_m.shape
    mid = depth_m[h // 3 : h - h // 3, w // 3 : w - w // 3]  # [h/3, w/3]
    seen = mid[np.isfinite(mid) & (mid > 0)]
    return float(np.median(seen)) if seen.size else None


def near_captured(captures: list[Capture], cam2world: np.ndarray, limit_deg: float, limit_m: float) -> bool:
    """Whether a capture looks (almost) the same way from (almost) the same place: closer than
    ``limit_deg`` with at most ``limit_m`` between them."""
    for cap in captures:
        if (
            view_angle_deg(cap.cam2world, cam2world) < limit_deg
            and np.linalg.norm(cap.cam2world[:3, 3] - cam2world[:3, 3]) <= limit_m
        ):
            return True
    return False


def hopes(
    cands: list[Candidate],
    captures: list[Capture],
    captured_pred: np.ndarray,  # [M]
    optimism: float,
    min_sigma: float,
    residual_length_deg: float,
    residual_length_m: float | None = None,
) -> np.ndarray:  # -> [C]
    """What each candidate may score (teacher units): the scorer's prediction corrected by its
    errors at the captures (true teacher score - prediction; the median error everywhere, the
    nearby captures' errors on top, by a Gaussian kernel of ``residual_length_deg`` on the view
    direction and, with ``residual_length_m``, of that length on the place: a capture from across
    a drone's box looking the same way does not calibrate a view), plus ``optimism`` times the
    errors' spread (at least ``min_sigma``), shrinking near the captures. ``residual_length_m``
    None: the direction alone (a rig, whose views share one place)."""
    scores = np.array([cd.score for cd in cands], dtype=np.float64)
    true = np.array([cap.score for cap in captures], dtype=np.float64)
    pred = np.asarray(captured_pred, dtype=np.float64)
    if not len(cands) or pred.shape != true.shape or not len(true) or not np.all(np.isfinite(pred)):
        return scores
    resid = true - pred
    offset = float(np.median(resid))
    sigma = max(float(np.sqrt(np.mean((resid - offset) ** 2))) if len(resid) > 1 else 0.0, min_sigma)
    out = np.empty(len(cands))
    for j, cd in enumerate(cands):
        ang = np.array([view_angle_deg(cd.cam2world, cap.cam2world) for cap in captures])
        w = np.exp(-((ang / residual_length_deg) ** 2))  # [M]
        if residual_length_m is not None:
            dist = np.array([np.linalg.norm(cap.cam2world[:3, 3] - cd.cam2world[:3, 3]) for cap in captures])  # [M]
            w = w * np.exp(-((dist / residual_length_m) ** 2))
        local = float(np.sum(w * (resid - offset)) / (1.0 + np.sum(w)))
        out[j] = cd.score + offset + local + optimism * sigma / math.sqrt(1.0 + float(np.sum(w)))
    return out


def shortfall(
    cands: list[Candidate], captures: list[Capture], length_deg: float, slack: float, gate: float = 0.0
) -> np.ndarray:  # -> [C] <= 0
    """How far below its hope each candidate's region has captured (teacher units, <= 0): at each
    move and hill verification (the captures that carried a hope, ``Capture.predicted``) the miss
    ``score - predicted`` beyond ``slack`` (a miss within the hope's usual optimism is no region's
    bias), weighed by a Gaussian of ``length_deg`` on the view direction, ``sum(w miss) / (1 +
    sum(w))``. The scorer's residuals at the captures (:func:`hopes`) do not see this: the field is
    refit on every capture and then predicts the captured views well, while it may still over-rate
    the views around them (dev photo_ring_room: four moves into one corner, each hoped 0.74-0.83 and
    captured 0.48-0.71). Zeros when no such capture missed by more than ``slack``. ``gate`` > 0:
    scaled by ``clip(sum(w) - gate, 0, 1)``, so one miss (``gate`` 1) lowers nothing and a region
    counts once more than that many misses lie in it: a single miss is as often the flank of a
    narrow peak beside it (dev tabletop:236, indoor:239, gallery:244: the next move beside the
    miss found the peak)."""
    out = np.zeros(len(cands))
    missed = [
        (cap, cap.score - cap.predicted + slack)
        for cap in captures
        if cap.kind in (CaptureKind.MOVE, CaptureKind.VERIFY)
        and cap.predicted is not None
        and math.isfinite(cap.predicted)
        and math.isfinite(cap.score)
        and cap.score - cap.predicted + slack < 0.0
    ]
    if not missed or not len(cands) or length_deg <= 0.0:
        return out
    miss = np.array([m for _, m in missed], dtype=np.float64)  # [K]
    for j, cd in enumerate(cands):
        ang = np.array([view_angle_deg(cd.cam2world, cap.cam2world) for cap, _ in missed])  # [K]
        w = np.exp(-((np.minimum(ang, 1e3 * length_deg) / length_deg) ** 2))  # [K]; a tiny length: weight 0
        scale = 1.0 if gate <= 0.0 else min(max(float(np.sum(w)) - gate, 0.0), 1.0)
        out[j] = scale * float(np.sum(w * miss) / (1.0 + np.sum(w)))
    return out


def decision_order(hope: np.ndarray, cands: list[Candidate], quantum: float, tie_margin: float = 0.0) -> list[int]:
    """Candidate indices best first, by hope rounded to ``quantum`` (teacher units), ties by where
    they look (pan, then tilt, in whole degrees; a drone's yaw and pitch) -- never by the last
    bits of two nearly equal predictions, which differ between processors. ``tie_margin`` > 0:
    every candidate within it of the best hope is one tie with the best (first, by where they
    look): two hopes 0.001 apart on either side of a quantum's edge are not ranked by that edge."""
    finite = [float(h) for h in hope if math.isfinite(float(h))]
    top = max(finite) if finite and tie_margin > 0 else math.inf

    def key(i: int) -> tuple:
        h = float(hope[i])
        level = math.floor(h / quantum + 0.5) if quantum > 0 and math.isfinite(h) else h
        if math.isfinite(h) and h >= top - tie_margin:
            level = math.inf  # with the best: ranked by where it looks
        cd = cands[i]
        if cd.pan_rad is not None and cd.tilt_rad is not None:
            where = (round(math.degrees(cd.pan_rad)), round(math.degrees(cd.tilt_rad)))
        else:
            view = cam2world_to_view(cd.cam2world)
            where = tuple(round(float(v), 1) for v in view[:3]) + tuple(round(math.degrees(float(v))) for v in view[3:])
        return (-level if math.isfinite(h) else math.inf, where)

    return sorted(range(len(cands)), key=key)
