"""Hand-held suggestions refined at the best photo, scored on the photos themselves.

The teacher scores the real input photos exactly, so the best photo is known; what a photo set
cannot give is a faithful image of a view far from every photo (the field and renders of a
ten-photo reconstruction rank a hand-held search's candidates about as well as chance:
``docs/guides/photos.md``). Close to a photo it can: a turn of the camera on the spot maps the
photo onto the new view exactly (the homography ``K R K^-1``), and a short step towards the
subject nearly so (the homography of a plane facing the photo, 1.4 times as far as the subject:
most of a view lies behind what the photos are aimed at). :func:`refine_at_best_photo`
tries turns of a few degrees and short steps forward from the photo the teacher likes best,
builds each candidate's image from the photos warped into it (the best photo first, its
neighbours filling the strip it does not cover), scores those images with the teacher and
returns the candidates best first.

The estimate is unbiased but noisy (on twelve dev scenes its error against the true render has a
standard deviation of 0.02-0.075, growing with the step forward and with the share of the image
taken from other photos than the one refined at: :func:`estimate_error`), and the best of a few
hundred noisy estimates is mostly the luckiest one. So the candidates are ranked by a lower bound,
the prediction minus ``caution`` times the expected error, and a refined view is only trusted
when that bound clears the best photo by ``min_gain``; otherwise :attr:`RefineResult.confident` is
False and the photo itself, as taken, is the safe answer (its teacher score is exact).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from aes_planner.config import require, require_finite
from aes_planner.geometry.rotations import rot_x, rot_z
from aes_planner.search.photo_warp import photo_composite

if TYPE_CHECKING:
    from aes_planner.geometry.camera import Intrinsics

# cv2, torch and the pose helpers are imported where used: the CLI reads RefineConfig's defaults
# when it builds its parser

__all__ = [
    "RefineConfig",
    "RefineResult",
    "estimate_error",
    "refine_at_best_photo",
    "photo_composite",
    "subject_distance",
]

log = logging.getLogger(__name__)

# The photo-warped estimate's error (standard deviation of the teacher's score on the warped photos
# minus its score on the true render) with the plane at 1.4 x the subject's distance, fitted on the
# 2,282 candidates of eight dev grids (seeds 3, 10, 14, 16, 40, 41; ``scripts/photos_refine_check.py
# --planes``; weighted least squares of the binned standard deviations: 0.023 + 0.119 x step +
# 0.001 x other share): a base for resampling and levelling, a part growing with the step towards
# the subject (a plane is only right on that plane: parallax), and a little for the share of the
# image filled from other photos (their seams; it was 0.15 with the plane at the subject's distance,
# where the neighbours misregistered, and the tails were there). The size of the turn adds nothing
# measurable once those are known.
_ERR_BASE = 0.025
_ERR_PER_STEP = 0.12  # per fraction of the subject's distance stepped forward
_ERR_PER_OTHER = 0.05  # per share of the image from other photos than the one refined at


@dataclass(frozen=True)
class RefineConfig:
    """How far :func:`refine_at_best_photo` looks from the best photo.

    * ``max_turn_deg``: the largest change of yaw and of pitch tried (0: no refinement at all);
    * ``turn_step_deg``: the grid's step in yaw and pitch;
    * ``forward_fracs``: steps towards the subject tried, as fractions of its distance from the
      photo (0 = stay where the photo was taken);
    * ``work_width_px``: width of the images the candidates are scored on (the height keeps the
      photos' aspect; the default teacher judges a 64 x 64 frame);
    * ``around_best``: how many of the photos the teacher likes best are refined at;
    * ``min_photo_cover``: share of a candidate's image the photos must cover (the rest is
      filled from its surroundings); candidates below it are not tried;
    * ``caution``: how many of the estimate's expected errors (:func:`estimate_error`) are taken
      off each candidate's predicted score before ranking (0: rank by the prediction alone);
    * ``min_gain``: how far that lower bound must clear the best photo's teacher score for a
      refined view to be trusted; otherwise the best photo as taken is the answer;
    * ``keep_roll``: turn and tilt the photo as it was taken (its roll kept: the turn about the
      vertical, the tilt about the camera's own right axis) instead of the photo levelled; the
      photo itself is then exactly one of the grid's views and every turn on the spot an exact
      warp of it;
    * ``plane_depth``: the plane a step forward and the neighbours are warped through, at this
      multiple of the subject's distance along the photo's view (the subject is where the
      photos' axes meet; most of a view lies behind it);
    * ``fallback_turn``: when no refined view is trusted, try first the best photo as taken
      (its roll kept) turned and tilted on the spot by the grid's steps, where the photo covers
      at least ``fallback_min_own`` of the view (their estimate is the most faithful of all: the
      photo's own pixels, moved exactly), and take the best of those by the same lower bound when
      it clears the best photo by ``fallback_min_gain``; only then the photo as taken.
    """

    max_turn_deg: float = 6.0
    turn_step_deg: float = 2.0
    forward_fracs: tuple[float, ...] = (0.0, 0.1, 0.2, 0.3)
    work_width_px: int = 160
    around_best: int = 2
    min_photo_cover: float = 0.97
    caution: float = 1.0
    min_gain: float = 0.02
    keep_roll: bool = False
    plane_depth: float = 1.4
    fallback_turn: bool = False
    fallback_min_gain: float = 0.0
    fallback_min_own: float = 0.85

    def __post_init__(self):
        require_finite([self.max_turn_deg, self.turn_step_deg, self.min_photo_cover], "refine")
        require(0.0 <= self.max_turn_deg <= 30.0, "max_turn_deg", f"must be in [0, 30] deg, got {self.max_turn_deg!r}")
        require(
            0.1 <= self.turn_step_deg <= 30.0, "turn_step_deg", f"must be in [0.1, 30] deg, got {self.turn_step_deg!r}"
        )
        fr = tuple(self.forward_fracs)
        require(
            len(fr) >= 1 and all(isinstance(f, (int, float)) and math.isfinite(f) and 0.0 <= f <= 0.5 for f in fr),
            "forward_fracs",
            f"must be one or more fractions of the subject's distance in [0, 0.5], got {self.forward_fracs!r}",
        )
        object.__setattr__(self, "forward_fracs", tuple(float(f) for f in fr))
        require(
            isinstance(self.work_width_px, int) and 32 <= self.work_width_px <= 1024,
            "work_width_px",
            f"must be an integer in [32, 1024] px, got {self.work_width_px!r}",
        )
        require(
            isinstance(self.around_best, int) and 1 <= self.around_best <= 100,
            "around_best",
            f"must be an integer in [1, 100] photos, got {self.around_best!r}",
        )
        require(
            0.0 < self.min_photo_cover <= 1.0, "min_photo_cover", f"must be in (0, 1], got {self.min_photo_cover!r}"
        )
        # NaN fails these ranges too, named
        require(0.0 <= self.caution <= 10.0, "caution", f"must be in [0, 10] expected errors, got {self.caution!r}")
        require(-1.0 <= self.min_gain <= 1.0, "min_gain", f"must be in [-1, 1] (teacher score), got {self.min_gain!r}")
        require(isinstance(self.keep_roll, bool), "keep_roll", f"must be true or false, got {self.keep_roll!r}")
        require(
            0.25 <= self.plane_depth <= 4.0,
            "plane_depth",
            f"must be in [0.25, 4] times the subject's distance, got {self.plane_depth!r}",
        )
        require(
            isinstance(self.fallback_turn, bool), "fallback_turn", f"must be true or false, got {self.fallback_turn!r}"
        )
        require(
            -1.0 <= self.fallback_min_gain <= 1.0,
            "fallback_min_gain",
            f"must be in [-1, 1] (teacher score), got {self.fallback_min_gain!r}",
        )
        require(
            0.0 <= self.fallback_min_own <= 1.0,
            "fallback_min_own",
            f"must be in [0, 1] (share of the view), got {self.fallback_min_own!r}",
        )

    @property
    def enabled(self) -> bool:
        return self.max_turn_deg > 0


def subject_distance(photos_c2w: np.ndarray, index: int) -> float | None:
    """Distance along photo ``index``'s view to the point its cameras look at: the least-squares
    meeting point of all photos' optical axes (``photos_c2w [N, 4, 4]``). None when the axes do
    not meet in front of the photo (all parallel: a walk past a wall)."""
    c = photos_c2w[:, :3, 3]  # [N, 3]
    f = photos_c2w[:, :3, 2]  # [N, 3] forward (OpenCV z)
    proj = np.eye(3)[None] - f[:, :, None] * f[:, None, :]  # [N, 3, 3] perpendicular to each axis
    a, b = proj.sum(0), np.einsum("nij,nj->i", proj, c)
    if np.linalg.cond(a) > 1e6:
        return None
    point = np.linalg.solve(a, b)
    d = float((point - c[index]) @ f[index])
    spread = float(np.max(np.linalg.norm(c[:, None] - c[None], axis=-1))) if len(c) > 1 else 0.0
    return d if d > max(spread, 1e-9) * 0.1 else None


def estimate_error(step_frac, own_cover):
    """Expected error (standard deviation, teacher-score units) of a candidate's photo-warped
    score, for its step towards the subject (fraction of the subject's distance) and the share of
    its image the photo it is refined at covers itself (the rest comes from other photos)."""
    return _ERR_BASE + _ERR_PER_STEP * np.asarray(step_frac) + _ERR_PER_OTHER * (1.0 - np.asarray(own_cover))


@dataclass
class RefineResult:
    """What :func:`refine_at_best_photo` found: ``suggestions`` best first (by the lower bound
    ``terms["photo_gain_low"]``), and for each the photo it was refined at (``photo_of [C]``) and
    the share of its image that photo covers itself (``own_cover [C]``, the rest from its
    neighbours); the teacher's scores of the photos as taken (``photo_scores [N]``); ``as_taken``
    the best photo itself as a suggestion (its pose with its roll, its exact teacher score);
    ``confident`` whether the first suggestion's lower bound clears the best photo by the
    configuration's ``min_gain`` (else the best photo as taken is the safe answer)."""

    suggestions: list
    photo_of: np.ndarray  # [C] int
    own_cover: np.ndarray  # [C]
    photo_scores: np.ndarray  # [N]
    as_taken: object = None
    confident: bool = False
    turn: object = None  # the fall-back turn on the spot at the best photo (RefineConfig.fallback_turn), if any

    @property
    def best_photo(self) -> int:
        return int(np.argmax(self.photo_scores)) if len(self.photo_scores) else -1

    @property
    def kind(self) -> str:
        """What suggestion #1 is: ``"refined"`` (the first refined view, trusted), ``"turn"`` (the
        fall-back turn on the spot at the best photo) or ``"as_taken"`` (the best photo itself)."""
        if self.confident and self.suggestions:
            return "refined"
        return "turn" if self.turn is not None else "as_taken"

    @property
    def pick(self):
        """Suggestion #1: the first refined view when it is trusted, else the fall-back turn at the
        best photo when one cleared it, else the best photo as taken (None when nothing was refined)."""
        kind = self.kind
        if kind == "refined":
            return self.suggestions[0]
        return self.turn if kind == "turn" else self.as_taken


def refine_at_best_photo(
    teacher,
    photos_c2w: np.ndarray,
    images: list[np.ndarray],
    intrinsics: Intrinsics,
    cfg: RefineConfig,
    platform=None,
) -> RefineResult:
    """Candidates around the photos the teacher likes best, scored on the photos warped into them.

    ``photos_c2w [N, 4, 4]`` world, ``images`` the photos ([H, W, 3] uint8, one size; ``intrinsics``
    for the size of the posed frames, rescaled to theirs), ``platform`` (optional) keeps the
    candidates inside the hand-held region and its pitch limits. Each candidate is a
    :class:`~aes_planner.search.Suggestion`: ``score`` the teacher's on its image, ``terms`` the
    teacher's terms plus ``photo_gain`` (its score minus the best photo's), ``estimate_error``
    (:func:`estimate_error`) and ``photo_gain_low`` (the gain less ``caution`` times that error, the
    ranking), ``coverage`` the share of its image the photos cover. No candidates when refinement
    is off or the photos differ in size."""
    import cv2
    import torch

    from aes_planner.geometry.poses import cam2world_to_view, view_to_cam2world
    from aes_planner.search.pipeline import Suggestion

    none = RefineResult([], np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
    if not cfg.enabled or not images or len({im.shape for im in images}) != 1:
        return none
    h0, w0 = images[0].shape[:2]
    ww = cfg.work_width_px
    wh = max(8, round(ww * h0 / w0))
    small = [cv2.resize(im, (ww, wh), interpolation=cv2.INTER_AREA) for im in images]  # [wh, ww, 3] each
    k = intrinsics.K.astype(np.float64).copy()
    k[0] *= ww / intrinsics.width
    k[1] *= wh / intrinsics.height
    photos_c2w = np.asarray(photos_c2w, np.float64)

    def teacher_terms(batch: list[np.ndarray]) -> dict[str, np.ndarray]:
        x = torch.from_numpy(np.stack(batch)).permute(0, 3, 1, 2).float() / 255.0  # [B, 3, wh, ww]
        with torch.no_grad():
            terms = teacher.explain_map(teacher.features(x))
        return {name: t.double().numpy() for name, t in terms.items()}

    real_terms = teacher_terms(small)
    real = real_terms["score"]  # [N] the photos as taken
    none.photo_scores = real
    steps = np.arange(-cfg.max_turn_deg, cfg.max_turn_deg + 1e-9, cfg.turn_step_deg)
    steps = np.unique(np.round(np.concatenate([steps, [0.0]]), 9))
    lo, hi = platform.pitch_limits_deg if platform is not None and hasattr(platform, "pitch_limits_deg") else (-90, 90)
    centres = photos_c2w[:, :3, 3]
    views, shots, covers, owns, bases, fracs, spare = [], [], [], [], [], [], []
    best = int(np.argmax(real))
    # the grid at the best photos, then (for the fall-back) the photo the teacher likes best as
    # taken, turned on the spot: kept apart from the ranking (``spare``)
    grids = [(int(b), cfg.forward_fracs, cfg.keep_roll, False) for b in np.argsort(-real)[: cfg.around_best]]
    if cfg.fallback_turn:
        grids.append((best, (0.0,), True, True))
    for b, grid_fracs, keep_roll, is_spare in grids:
        base = cam2world_to_view(photos_c2w[b])  # [5] x, y, z, yaw, pitch (the photo levelled: roll dropped)
        dist = subject_distance(photos_c2w, b)
        forward = photos_c2w[b, :3, 2]
        # a step and the neighbours are warped through the plane at plane_depth x the subject's
        # distance (the photo itself, turned on the spot, is exact through any plane)
        plane = None if dist is None else (forward, float(forward @ photos_c2w[b, :3, 3]) + cfg.plane_depth * dist)
        heading = np.array([math.cos(base[3]), math.sin(base[3]), 0.0])  # level forward of the photo
        for frac in grid_fracs if dist is not None else (0.0,):  # no subject distance: turns only
            xyz = base[:3] + (frac * dist if frac else 0.0) * heading
            if frac and platform is not None and not bool(platform.contains(xyz)):
                continue
            order = [b] + [int(j) for j in np.argsort(np.linalg.norm(centres - xyz, axis=1)) if j != b]
            for dy in steps:
                for dp in steps:
                    if keep_roll:
                        if not frac and dy == 0 and dp == 0:
                            continue  # the photo itself: its score is exact, it is the as-taken answer
                        c2w = np.eye(4)
                        # turned about world +z (left positive), tilted about the camera's own x
                        # (right) axis: positive tilts an OpenCV camera up
                        c2w[:3, :3] = rot_z(math.radians(dy)) @ photos_c2w[b, :3, :3] @ rot_x(math.radians(dp))
                        c2w[:3, 3] = xyz
                        pitch = float(np.degrees(cam2world_to_view(c2w)[4]))
                    else:
                        pitch = float(np.degrees(base[4]) + dp)
                        c2w = view_to_cam2world(np.array([*xyz, base[3] + math.radians(dy), math.radians(pitch)]))
                    if not lo <= pitch <= hi:
                        continue
                    img, cover, own = photo_composite(small, photos_c2w, k, c2w, order, plane)
                    if cover < cfg.min_photo_cover:
                        continue
                    views.append(c2w)
                    shots.append(img)
                    covers.append(cover)
                    owns.append(own)
                    bases.append(b)
                    fracs.append(frac)
                    spare.append(is_spare)
    if not views:
        return none
    terms = teacher_terms(shots)
    score = terms["score"]
    spare = np.asarray(spare, bool)  # [C] the fall-back's turns, not ranked with the grid
    steps_frac = np.asarray(fracs)  # [C] step forward of each candidate, fraction of the subject's distance
    err = estimate_error(steps_frac, np.asarray(owns))  # [C] expected error of each estimate
    low = score - cfg.caution * err  # [C] the lower bound the candidates are ranked by
    out = []
    for i, c2w in enumerate(views):
        t = {name: float(v[i]) for name, v in terms.items()}
        t["photo_gain"] = float(score[i] - real[best])
        t["estimate_error"] = float(err[i])
        t["photo_gain_low"] = float(low[i] - real[best])
        v = cam2world_to_view(c2w)
        out.append(Suggestion(c2w, c2w[:3, 3].copy(), float(v[3]), float(v[4]), float(score[i]), covers[i], t))
    order = np.array([i for i in np.argsort(-low, kind="stable") if not spare[i]], np.int64)
    if not len(order):
        return none
    # the best photo as taken (with its roll): the teacher's score on it is exact
    t = {name: float(v[best]) for name, v in real_terms.items()}
    t.update(photo_gain=0.0, estimate_error=0.0, photo_gain_low=0.0)
    v = cam2world_to_view(photos_c2w[best])
    as_taken = Suggestion(photos_c2w[best].copy(), photos_c2w[best, :3, 3].copy(), float(v[3]), float(v[4]),
                          float(real[best]), 1.0, t)  # fmt: skip
    confident = bool(low[order[0]] - real[best] >= cfg.min_gain)
    turn = None
    if not confident and cfg.fallback_turn:
        # the best photo as taken turned on the spot, its own pixels covering most of the view
        on_spot = spare & (np.asarray(owns) >= cfg.fallback_min_own)  # [C]
        if on_spot.any():
            j = int(np.flatnonzero(on_spot)[np.argmax(low[on_spot])])
            if low[j] - real[best] >= cfg.fallback_min_gain:
                turn = out[j]
    log.info(
        "refined at photo(s) %s (teacher %s): %d candidates, best predicted %.3f (%+.3f), lower bound %+.3f: %s",
        sorted(set(bases)), np.round(real, 3), len(out), score.max(), score.max() - real[best],
        low[order[0]] - real[best], "trusted" if confident else
        "not trusted, a turn at the best photo instead" if turn is not None else
        "not trusted, the best photo as taken instead",
    )  # fmt: skip
    return RefineResult(
        [out[i] for i in order],
        np.asarray(bases, np.int64)[order],
        np.asarray(owns)[order],
        real,
        as_taken,
        confident,
        turn,
    )
