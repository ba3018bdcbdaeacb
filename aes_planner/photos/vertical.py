"""Gravity from the scene: the vertical vanishing direction of the photos' straight lines, lifted to
the structure-from-motion frame through each registered camera's rotation.

A straight segment in a photo and the camera's centre span a plane (its *interpretation plane*);
a segment of a vertical edge (a wall's corner, a box's side, a door frame) has a plane that holds
the up direction. With ``K`` and the camera's rotation ``R`` from the pose step, each segment's
plane normal in the world is ``n = R K^T l`` (``l`` the segment's image line, homogeneous), and up
is the direction perpendicular to the normals of every vertical segment, in every photo at once.

Steps (:func:`vertical_from_lines`):

1. **Segments**: OpenCV's line segment detector (LSD, ``cv2.createLineSegmentDetector``) on each
   undistorted photo; segments shorter than :data:`MIN_SEGMENT_FRAC` of the photo's diagonal dropped.
2. **Candidates**: segments whose plane holds a direction within :data:`PRIOR_CONE_DEG` of the
   cameras' own up (:func:`aes_planner.photos.sfm.gravity_up`): the near-vertical ones. The prior
   only selects; it does not pull the answer.
3. **Robust fit**: RANSAC over pairs of segments (``u = n_a x n_b``), length-weighted inliers within
   :data:`INLIER_DEG` (or, for a short segment, its direction's own uncertainty: 1 / length rad), then the smallest eigenvector of the inliers' weighted scatter
   ``sum w n n^T`` (re-fitted three times).
4. **Confidence**: the photos with :data:`MIN_SEGMENTS_PER_PHOTO` or more inlier segments each fit
   their own up; the fit is used when at least :data:`MIN_PHOTOS` photos do, :data:`MIN_SEGMENTS`
   segments agree in all, and the photos' own ups lie within :data:`MAX_SPREAD_DEG` (median) of the
   joint one (``confident``). Otherwise the caller keeps the cameras' up.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from aes_planner.geometry.camera import Intrinsics

log = logging.getLogger(__name__)

__all__ = ["VerticalLines", "line_segments", "vertical_from_lines"]

#: Segments shorter than this share of the photo's diagonal are left out (too noisy in direction).
MIN_SEGMENT_FRAC = 0.04
#: Candidates: segments whose plane holds a direction within this of the cameras' up.
PRIOR_CONE_DEG = 30.0
#: A segment agrees with an up direction when its plane holds it within this angle.
INLIER_DEG = 1.0
#: Confidence: photos with this many agreeing segments count as seeing verticals ...
MIN_SEGMENTS_PER_PHOTO = 4
#: ... at least this many such photos, this many agreeing segments in all ...
MIN_PHOTOS, MIN_SEGMENTS = 3, 20
#: ... and the photos' own ups within this (median) of the joint one.
MAX_SPREAD_DEG = 2.0
#: RANSAC hypotheses (pairs of segments).
HYPOTHESES = 400


@dataclass(frozen=True)
class VerticalLines:
    """The up direction the photos' vertical lines agree on (world frame of the cameras given),
    with what supports it: ``segments`` agreeing segments in ``photos`` photos, the photos' own ups
    ``spread_deg`` (median) from the joint one, and ``off_cameras_deg`` from the cameras' up."""

    up: np.ndarray  # [3] unit
    segments: int
    photos: int
    spread_deg: float
    off_cameras_deg: float

    @property
    def confident(self) -> bool:
        """Enough vertical segments, in enough photos, agreeing (the module docstring's step 4)."""
        return self.segments >= MIN_SEGMENTS and self.photos >= MIN_PHOTOS and self.spread_deg <= MAX_SPREAD_DEG

    def text(self) -> str:
        spread = f"agreeing within {self.spread_deg:.1f} deg" if math.isfinite(self.spread_deg) else "no photo alone"
        return (
            f"{self.segments} vertical segments in {self.photos} photos, {spread}, "
            f"{self.off_cameras_deg:.1f} deg from the cameras' up"
        )

    def to_json(self) -> dict:
        return {
            "segments": self.segments,
            "photos": self.photos,
            "spread_deg": self.spread_deg if math.isfinite(self.spread_deg) else None,
            "off_cameras_deg": self.off_cameras_deg,
            "confident": self.confident,
        }


def line_segments(rgb: np.ndarray) -> np.ndarray:  # [H, W, 3] uint8 -> [S, 4] x1, y1, x2, y2 (pixels)
    """LSD's straight segments of a photo longer than :data:`MIN_SEGMENT_FRAC` of its diagonal, in
    the package's pixel convention (pixel centres at half-integers)."""
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    found = cv2.createLineSegmentDetector().detect(gray)[0]
    if found is None:
        return np.zeros((0, 4))
    seg = found.reshape(-1, 4).astype(np.float64) + 0.5  # OpenCV's pixel centres sit at integers
    length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    return seg[length >= MIN_SEGMENT_FRAC * math.hypot(*gray.shape)]


def _plane_normals(seg: np.ndarray, k: Intrinsics, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World normals ``[S, 3]`` of the segments' interpretation planes and their lengths ``[S]``."""
    kinv = np.linalg.inv(k.K)
    ones = np.ones((len(seg), 1))
    p1 = np.hstack([seg[:, :2], ones]) @ kinv.T  # [S, 3] rays, camera frame
    p2 = np.hstack([seg[:, 2:], ones]) @ kinv.T
    n = np.cross(p1, p2) @ r.T  # [S, 3] world
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return n, np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])


def _fit(n: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The unit direction most nearly in every plane: smallest eigenvector of ``sum w n n^T``."""
    _, vecs = np.linalg.eigh((n * w[:, None]).T @ n)
    return vecs[:, 0]


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(min(1.0, abs(float(a @ b)))))


def vertical_from_lines(
    images: Sequence[np.ndarray], ks: Sequence[Intrinsics], c2w: np.ndarray, prior_up: np.ndarray, seed: int = 0
) -> VerticalLines:
    """Up from the vertical lines of undistorted photos ``images`` (RGB) with intrinsics ``ks`` and
    poses ``c2w [N, 4, 4]`` (OpenCV camera axes); ``prior_up [3]`` (the cameras' up) selects the
    near-vertical segments and gives the sign. Its ``confident`` says whether the lines say it
    confidently (see the module docstring); with no lines to go on, ``up`` is the prior."""
    prior = np.asarray(prior_up, np.float64) / np.linalg.norm(prior_up)
    cone = math.sin(math.radians(PRIOR_CONE_DEG))
    normals, weights, photo = [], [], []
    for i, (rgb, k, m) in enumerate(zip(images, ks, c2w)):
        n, w = _plane_normals(line_segments(rgb), k, m[:3, :3])
        keep = np.abs(n @ prior) < cone
        normals.append(n[keep])
        weights.append(w[keep])
        photo.append(np.full(int(keep.sum()), i))
    n, w, photo = np.concatenate(normals), np.concatenate(weights), np.concatenate(photo)  # [S, 3], [S], [S]
    nothing = VerticalLines(prior, 0, 0, math.inf, 0.0)
    if len(n) < 2:
        return nothing
    rng = np.random.default_rng(seed)
    # [S] each segment's tolerance: INLIER_DEG, or its direction's own uncertainty when it is short
    # (half a pixel at each end: about 1 / length radians)
    tol = np.sin(np.maximum(math.radians(INLIER_DEG), 1.0 / w))
    best, best_score = prior, -1.0
    for _ in range(HYPOTHESES):
        a, b = rng.choice(len(n), 2, replace=False)
        u = np.cross(n[a], n[b])
        norm = np.linalg.norm(u)
        if norm < 0.05:  # nearly the same plane: no direction
            continue
        u /= norm
        if abs(u @ prior) < math.cos(math.radians(PRIOR_CONE_DEG)):
            continue
        score = float(w[np.abs(n @ u) < tol].sum())
        if score > best_score:
            best, best_score = u, score
    up = best
    for _ in range(3):
        inl = np.abs(n @ up) < tol
        if inl.sum() < 2:
            return nothing
        up = _fit(n[inl], w[inl])
    inl = np.abs(n @ up) < tol
    up = up if up @ prior > 0 else -up
    per_photo = []
    for i in np.unique(photo[inl]):
        mine = inl & (photo == i)
        if mine.sum() >= MIN_SEGMENTS_PER_PHOTO:
            per_photo.append(_fit(n[mine], w[mine]))
    spread = float(np.median([_angle_deg(u, up) for u in per_photo])) if per_photo else math.inf
    found = VerticalLines(up, int(inl.sum()), len(per_photo), spread, _angle_deg(up, prior))
    log.info("vertical lines: %s (%s)", found.text(), "confident" if found.confident else "not confident")
    return found
