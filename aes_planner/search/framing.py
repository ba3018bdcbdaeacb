"""User-guided framing: "keep this subject in frame, avoid that" as a constraint on the search.

A user names a box in pixels of one input image (``00003.png:21,0,61,36``). :func:`lift_region`
lifts it into 3D from the reconstruction's Gaussians behind the box, and :class:`Framing` turns
the lifted subjects into what the two-stage search needs:

* **the lift** (robust to background pixels inside the box). The reconstruction's depth is
  rendered at the box's view; the box's pixels (or, where nothing renders, the Gaussians whose
  centres project into the box) are binned by log depth (bins ``depth_bin`` wide), each weighted
  by a centre weight (1 at the box centre, ``edge_weight`` at its edge: a box is drawn around its
  subject, background shows at its rim; a Gaussian also by its opacity). The depths of a ring
  just outside the box (``ring_frac`` of its shorter side wide, at least 2 px) are binned the same
  way: a bin holding a larger share of the ring than of the box is ground, the rest figure (a
  thin subject, a table leg, covers a minority of its box: the floor behind it can outweigh it
  inside the box, but fills the ring more). The heaviest figure bin (after a [1, 2, 1] smoothing)
  is the subject's depth mode; the slab grows from it over neighbouring figure bins while they
  hold at least ``grow_frac`` of the peak's weight (one empty bin is bridged),
  never further than ``depth_cap`` times the box's larger side at the mode's depth from the mode
  (a floor running through the box does not drag the subject to the horizon). The subject is what
  lies in that slab: the box's pixels there (unprojected), the Gaussians behind the box there
  (sides other views saw) and the box's own rectangle at the mode's depth (what the user drew is
  held whole, also where this view hides part of it). Its 3D box is their extent (min/max) in an
  oriented box whose vertical axis is world z and whose horizontal axes are the principal axes of
  their x-y spread.
* **the constraint** (:meth:`Framing.violation`, differentiable): 0 exactly when every corner of
  every kept subject's box lies in front of the camera and projects inside the frame shrunk by
  ``margin_frac`` of its width and height on every side; above 0 it grows with how far they are
  out. Stage 1 keeps only feasible candidates (and adds views aimed at the subject from every
  trajectory sample, so a feasible start exists wherever one is reachable); stage 2 backtracks
  each Adam step (halving it) until it stays feasible, so the refinement never leaves the set.
* **the soft terms**, added to the score the search maximises (:class:`FramedScorer`): minus
  ``avoid_weight`` times the visible fraction of each avoided box's projection (the part of its
  projected bounding rectangle inside the frame; not occlusion-aware), plus ``placement_weight``
  times the placement term of ``keep_at`` (``centre``: 1 at the image centre, 0 at a corner;
  ``thirds``: the same towards the nearest third-lines crossing).

:class:`FramingError` says when it cannot be done: no reachable view holds the subject (with the
closest view and how much of the subject it holds), a box outside its image, of zero size, or in
a frame the inputs do not have.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import re
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from aes_planner.config import require, require_bools, require_within
from aes_planner.errors import AesPlannerError
from aes_planner.field.scorer import ScoreOutput, Scorer
from aes_planner.geometry.camera import Intrinsics

log = logging.getLogger(__name__)

__all__ = [
    "KEEP_AT",
    "Framing",
    "FramedScorer",
    "FramingConfig",
    "FramingError",
    "Region",
    "Subject",
    "build_framing",
    "dataset_frames",
    "feasible_candidates",
    "frame_index",
    "lift_region",
    "render_depth",
    "verified_scores",
    "world_gaussians",
]

#: Placement terms ``--keep-at`` takes.
KEEP_AT = ("centre", "thirds")
#: What a view must hold of a kept subject (``FramingConfig.hold_by``).
HOLD_BY = ("box", "points")
#: Nearest camera depth a subject's corner may have (metres): behind it a corner is "not in view".
NEAR_M = 0.05


class FramingError(AesPlannerError, ValueError):
    """A keep/avoid region that cannot be used, or a subject no reachable view holds."""


@dataclass(frozen=True)
class Region:
    """A box ``[x0, x1] x [y0, y1]`` in pixels of the input image named ``frame`` (x right, y down)."""

    frame: str
    x0: float
    y0: float
    x1: float
    y1: float

    @classmethod
    def parse(cls, text: str, key: str = "--keep") -> Region:
        """``FRAME:X0,Y0,X1,Y1`` (``00003.png:21,0,61,36``) -> a Region; errors name ``key``."""
        m = re.fullmatch(r"\s*(.+?):\s*([^,:]+),([^,:]+),([^,:]+),([^,:]+)\s*", str(text))
        if not m:
            raise FramingError(f"{key} {text!r}: expected FRAME:X0,Y0,X1,Y1 (e.g. 00003.png:21,0,61,36)")
        try:
            x0, y0, x1, y1 = (float(v) for v in m.groups()[1:])
        except ValueError:
            raise FramingError(f"{key} {text!r}: X0,Y0,X1,Y1 must be numbers (pixels)") from None
        return cls(m.group(1).strip(), x0, y0, x1, y1).checked(key)

    def checked(self, key: str, width: int | None = None, height: int | None = None) -> Region:
        """This region, or a :class:`FramingError` naming ``key`` when it is not finite, of zero
        size or (when the image size is given) outside the image."""
        vals = (self.x0, self.y0, self.x1, self.y1)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in vals):
            raise FramingError(f"{key}: the box {vals} must be four finite numbers (pixels)")
        if not self.frame:
            raise FramingError(f"{key}: the frame name is empty; give an image file name as in cameras.json")
        if self.x1 <= self.x0 or self.y1 <= self.y0:
            raise FramingError(
                f"{key} {self.frame}: the box {self.x0:g},{self.y0:g},{self.x1:g},{self.y1:g} has zero size; "
                "give X0,Y0,X1,Y1 with X1 > X0 and Y1 > Y0"
            )
        if width is not None and height is not None:
            if self.x0 < 0 or self.y0 < 0 or self.x1 > width or self.y1 > height:
                raise FramingError(
                    f"{key} {self.frame}: the box {self.x0:g},{self.y0:g},{self.x1:g},{self.y1:g} is outside the "
                    f"{width}x{height} image; give pixels inside [0, {width}] x [0, {height}]"
                )
        return self

    def scaled(self, sx: float, sy: float) -> Region:
        return Region(self.frame, self.x0 * sx, self.y0 * sy, self.x1 * sx, self.y1 * sy)

    def text(self) -> str:
        return f"{self.frame}:{self.x0:g},{self.y0:g},{self.x1:g},{self.y1:g}"


@dataclass
class FramingConfig:
    """Knobs of the framing constraint (see the module docstring).

    ``margin_frac``: the subject must project inside the frame shrunk by this fraction of the
    width/height on every side (0.05: 5 %). ``keep_at``: None, ``centre`` or ``thirds``.
    ``placement_weight`` / ``avoid_weight``: weights of the soft terms, in units of the score.
    ``depth_bin``, ``edge_weight``, ``grow_frac``, ``depth_cap``, ``ring_frac``: the lift's robust rule
    (``depth_cap`` 0.3, was 0.75: the lifted box then kept more of the views that hold the subject
    and none that cut it; docs/results/framing_gap_dev.md. ``ring_frac`` 0.25, 0 turns the
    figure-ground test off: on the dev scenes it put the two table legs' boxes 5-9 cm from the leg
    instead of 28-30 cm, and raised the framed suggestion's median from 0.41 to 0.52;
    docs/results/framing_composition_dev.md).
    ``hold_by``: what a view must hold of a kept subject, inside the frame shrunk by the margin:
    ``points`` (the default), the outline of the points the subject was lifted from (their extreme
    points in ``outline_dirs`` directions, vertices of their convex hull), or ``box``, the corners
    of its oriented 3D box (the rule before 2026-11-29). The box's corners are empty space: on the
    dev scenes they kept a median 69 % of the grid views that truly hold the subject (best kept
    view 0.84 of the constrained oracle), the outline 75 % (0.87), and neither kept a view that
    cuts a subject (docs/results/framing_lift_views_dev.md). ``occluded_max``: a subject whose box
    has more than this share of its pixels nearer than the subject (something hides part of it,
    and it may go on behind) is held by its box all the same; on the dev scenes the two table legs
    behind a table top (0.26-0.35) would otherwise have kept views that cut the hidden part.
    ``feasibility_samples``: extra random views tried (geometry only, cheap) before saying that
    no reachable view holds the subject. ``explore_samples``: random views (and the same turned to
    the subject) checked every search; at most ``explore_keep`` of those that hold the subject join
    stage 1's candidates, so the whole feasible set competes, not only the trajectory's part.
    ``verify_top``: the refined suggestions and this many distinct best stage-1 candidates (all
    holding the subject) are verified: RGB of the reconstruction rendered at ``verify_width_px``
    and scored by the teacher; they are ranked by ``verify_weight`` times that score plus
    ``1 - verify_weight`` times the field's (0, the default: no verification; on the dev scenes
    the teacher on those renders ranked the views that hold a subject no better than the field).
    ``refine``: run stage 2 (gradient ascent, kept feasible by backtracking) on the feasible
    stage-1 picks. Off by default: with a kept subject the feasible set is small and stage 2
    climbs the field's errors away from the pick (on dev and held-out scenes the framed
    suggestion scored higher without it, for half the time; docs/decisions.md).
    ``coverage_min`` / ``coverage_penalty``: the search's coverage rule (``SearchConfig``'s keys of
    the same names: the objective loses ``coverage_penalty`` times the shortfall below
    ``coverage_min``, and final views below it are dropped unless none reaches it) while a
    subject is kept. Milder than the search's own (0.7 and 2): every candidate then holds a
    subject the inputs saw, and among those views the field's own score ranks far closer to the
    teacher's ground truth (median Spearman 0.71 on the dev scenes) than the penalised objective
    (0.27), which pushed the pick to the most covered view instead of the best one
    (docs/guides/framing.md, "Ranking the views that hold the subject").
    ``photo_rank``: re-rank the suggestions by the teacher's score of the input photos warped
    into each view (:func:`~aes_planner.search.photo_warp.warped_photo_scores`; needs the input
    images, ``build_framing(photos=...)``). The pool: the suggestions, the ``photo_top`` best
    stage-1 candidates, and turns and tilts ``photo_step_deg`` apart of up to ``photo_turn_deg``
    around each input view and of up to a third of that around the 8 best candidates, all that
    hold the subject; views the photos cover less than ``photo_min_cover`` are not ranked by them.
    The warp is exact for a turn on the spot, so nearly exact on a pan-tilt rig (its lens a few
    centimetres from the pivot). ``photo_width_px``: the width of the warped images. Off by
    default: on the dev scenes it raised the teacher-normalised mean from 0.38 to 0.47, on the
    held-out scenes it lowered it from 0.57 to 0.51 (median 0.67 -> 0.60), at ten times the
    search time (four input views leave most of those views a tenth to a half uncovered;
    docs/guides/framing.md, "Ranked on the input photos").
    ``grow_beyond_frame``: a box at its image's border grows over what the other inputs
    reconstructed beyond it (:func:`_grow_beyond_frame`: on the subject's plane within
    ``grow_plane_tol`` m when its points' thickness is at most ``grow_flat_ratio`` of their extent,
    else in its depth slab; the subject's colours, not the ring's, those within ``grow_colour_tol``
    of the ring's being the rim's background). A side past which the inputs never saw it end stays
    open, and a view holds the subject with room beyond it: its outline shifted ``open_reach`` of its
    extent that way (0.5, then 0.25 when no reachable view gives 0.5; 1.0 lowered the dev mean).
    ``open_refuse``: with no view giving that room, the search fails with the closest view (no view
    can be trusted to hold it); off, it holds what was seen, with a warning. ``hidden_frac`` /
    ``hidden_ratio``: a side of the box along which something nearer than ``hidden_ratio`` times
    the subject's depth covers ``hidden_frac`` of the ring is open too (1.0, off: the ground in
    front of a standing object opened sides of 9 of 17 dev subjects). ``fill_weight``: a prior on
    the share of the frame the subject covers, added to the score (0, off); ``smooth_dedup``: stage
    1 ranks each feasible view by the Gaussian-weighted mean of those around it, sigma in units of
    the duplicate distance (0, off). Neither raised the dev mean (docs/results/framing_photo_dev.md).
    """

    margin_frac: float = 0.05
    keep_at: str | None = None
    placement_weight: float = 0.05
    avoid_weight: float = 0.2
    depth_bin: float = 0.04
    edge_weight: float = 0.2
    grow_frac: float = 0.08
    depth_cap: float = 0.3
    ring_frac: float = 0.25
    hold_by: str = "points"
    outline_dirs: int = 64
    occluded_max: float = 0.2
    feasibility_samples: int = 4096
    backtrack_steps: int = 6
    explore_samples: int = 512
    explore_keep: int = 64
    verify_top: int = 0
    verify_weight: float = 1.0
    verify_width_px: int = 96
    refine: bool = False
    coverage_min: float = 0.5
    coverage_penalty: float = 0.5
    photo_rank: bool = False
    photo_top: int = 32
    photo_turn_deg: float = 12.0
    photo_step_deg: float = 2.0
    photo_min_cover: float = 0.0
    photo_width_px: int = 160
    grow_beyond_frame: bool = True
    grow_plane_tol: float = 0.03
    grow_flat_ratio: float = 0.1
    grow_colour_tol: float = 0.1
    open_reach: float = 0.5
    hidden_frac: float = 1.0
    hidden_ratio: float = 0.8
    open_refuse: bool = True
    fill_weight: float = 0.0
    smooth_dedup: float = 0.0

    def __post_init__(self):
        require(
            isinstance(self.margin_frac, (int, float)) and 0.0 <= self.margin_frac < 0.4,
            "keep_margin",
            f"must be a fraction of the frame in [0, 0.4), got {self.margin_frac!r}",
        )
        require(
            self.keep_at in (None, *KEEP_AT), "keep_at", f"must be one of {list(KEEP_AT)} or none, got {self.keep_at!r}"
        )
        require_within(self, ("occluded_max",), 0.0, 1.0)
        require_bools(self, ("grow_beyond_frame", "open_refuse", "refine", "photo_rank"))
        require_within(
            self, ("grow_flat_ratio", "grow_colour_tol", "grow_plane_tol", "hidden_frac", "hidden_ratio"), 0.0, 1.0
        )
        require_within(self, ("open_reach",), 0.0, 4.0)
        require_within(self, ("fill_weight", "smooth_dedup"), 0.0, 10.0)
        for name in ("placement_weight", "avoid_weight", "edge_weight", "grow_frac", "ring_frac"):
            v = getattr(self, name)
            require(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0, name, f"must be >= 0, got {v!r}")
        require(
            isinstance(self.coverage_min, (int, float)) and 0.0 <= self.coverage_min <= 1.0,
            "coverage_min",
            f"must be a fraction of the view in [0, 1], got {self.coverage_min!r}",
        )
        require(
            isinstance(self.coverage_penalty, (int, float)) and 0.0 <= self.coverage_penalty <= 1e6,
            "coverage_penalty",
            f"must be in [0, 1e6], got {self.coverage_penalty!r}",
        )
        require(self.hold_by in HOLD_BY, "hold_by", f"must be one of {list(HOLD_BY)}, got {self.hold_by!r}")
        require(
            isinstance(self.outline_dirs, int) and 6 <= self.outline_dirs <= 4096,
            "outline_dirs",
            f"must be an integer in [6, 4096], got {self.outline_dirs!r}",
        )
        require(
            isinstance(self.photo_top, int) and 0 <= self.photo_top <= 10_000,
            "photo_top",
            f"must be an integer in [0, 10000], got {self.photo_top!r}",
        )
        require_within(self, ("photo_turn_deg",), 0.0, 45.0)
        require_within(self, ("photo_step_deg",), 0.5, 45.0)
        require_within(self, ("photo_min_cover",), 0.0, 1.0)
        require(
            isinstance(self.photo_width_px, int) and 32 <= self.photo_width_px <= 1024,
            "photo_width_px",
            f"must be an integer in [32, 1024] px, got {self.photo_width_px!r}",
        )
        require(
            isinstance(self.verify_weight, (int, float)) and 0.0 <= self.verify_weight <= 1.0,
            "verify_weight",
            f"must be in [0, 1], got {self.verify_weight!r}",
        )
        require(
            isinstance(self.verify_width_px, int) and 16 <= self.verify_width_px <= 1024,
            "verify_width_px",
            f"must be an integer in [16, 1024] px, got {self.verify_width_px!r}",
        )
        for name in ("explore_samples", "explore_keep", "verify_top"):
            v = getattr(self, name)
            require(isinstance(v, int) and 0 <= v <= 100_000, name, f"must be an integer in [0, 100000], got {v!r}")
        for name in ("depth_bin", "depth_cap"):
            v = getattr(self, name)
            require(isinstance(v, (int, float)) and math.isfinite(v) and v > 0, name, f"must be > 0, got {v!r}")
        require(
            isinstance(self.feasibility_samples, int) and 0 <= self.feasibility_samples <= 1_000_000,
            "feasibility_samples",
            f"must be an integer in [0, 1000000], got {self.feasibility_samples!r}",
        )
        require(
            isinstance(self.backtrack_steps, int) and 0 <= self.backtrack_steps <= 30,
            "backtrack_steps",
            f"must be an integer in [0, 30], got {self.backtrack_steps!r}",
        )


@dataclass
class Subject:
    """A region lifted into 3D: an oriented box (world frame, metres)."""

    region: Region
    centre_m: np.ndarray  # [3]
    axes: np.ndarray  # [3, 3] rows: the box's unit axes in the world (the last is world z)
    half_extent_m: np.ndarray  # [3] half sizes along the axes
    gaussians: int = 0  # Gaussians the box was fitted to
    depth_range_m: tuple[float, float] = (0.0, 0.0)  # the slab, camera depth in the region's frame
    outline_m: np.ndarray | None = None  # [P, 3] world: the lifted points' extreme points (vertices of their hull)
    occluded_frac: float = 0.0  # share of the box's pixels nearer than the subject: something hides part of it
    cut_by_frame: bool = False  # the box touches its image's border: the subject may go on beyond it
    open_sides: tuple[str, ...] = ()  # borders the box touches beyond which the inputs never saw the subject end
    grown: int = 0  # Gaussians beyond the image's border added to the subject (its continuation other views saw)
    reach_m: np.ndarray | None = None  # [O, 3] world: per open side, the subject's extent along it (towards that side)

    @property
    def corners_m(self) -> np.ndarray:  # -> [8, 3] world
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
        return self.centre_m + (signs * self.half_extent_m) @ self.axes

    def hold_points_m(
        self, hold_by: str = "box", occluded_max: float = 1.0, reach: float = 0.0
    ) -> np.ndarray:  # -> [P, 3] world
        """What a view must hold of this subject: the box's corners, or (``points``) the lifted
        points' outline, which a view can hold where the box's empty corners stick out. A subject
        that something hides in part (more than ``occluded_max`` of its box nearer than it) may
        go on behind what hides it: it is held by its box. ``reach`` > 0: beyond each open side
        (the inputs never saw the subject end there) the points are held shifted that far out too,
        as a share of the subject's own extent along that side: room for its unseen continuation."""
        pts = self.corners_m
        if hold_by == "points" and self.outline_m is not None and len(self.outline_m):
            if self.occluded_frac <= occluded_max:
                pts = self.outline_m
        if reach > 0 and self.reach_m is not None and len(self.reach_m):
            pts = np.concatenate([pts, *(pts + reach * r for r in self.reach_m)])
        return pts

    @property
    def size_m(self) -> np.ndarray:
        return 2.0 * self.half_extent_m

    def to_json(self) -> dict:
        return {
            "region": self.region.text(),
            "centre_m": self.centre_m.tolist(),
            "size_m": self.size_m.tolist(),
            "axes": self.axes.tolist(),
            "gaussians": self.gaussians,
        }


def _centre_weight(u: np.ndarray, v: np.ndarray, region: Region, edge: float) -> np.ndarray:
    cx, cy = 0.5 * (region.x0 + region.x1), 0.5 * (region.y0 + region.y1)
    hx, hy = 0.5 * (region.x1 - region.x0), 0.5 * (region.y1 - region.y0)
    r = np.maximum(np.abs(u - cx) / hx, np.abs(v - cy) / hy).clip(0.0, 1.0)  # 0 centre, 1 edge
    return 1.0 - (1.0 - edge) * r


def _ring_depths(depth_map: np.ndarray, region: Region, pad: float) -> np.ndarray:
    """The rendered depths ``[R]`` of the ring ``pad`` pixels wide just outside ``region`` (inside
    the image, where something renders): the surroundings the box was drawn against."""
    if pad <= 0:
        return np.zeros(0)
    h, w = depth_map.shape
    c0, c1 = max(0, int(math.floor(region.x0 - pad))), min(w, int(math.ceil(region.x1 + pad)))
    r0, r1 = max(0, int(math.floor(region.y0 - pad))), min(h, int(math.ceil(region.y1 + pad)))
    uu, vv = np.meshgrid(np.arange(c0, c1) + 0.5, np.arange(r0, r1) + 0.5)
    out = (uu < region.x0) | (uu > region.x1) | (vv < region.y0) | (vv > region.y1)
    dd = depth_map[r0:r1, c0:c1][out]
    return dd[np.isfinite(dd) & (dd > NEAR_M)].astype(np.float64)


def _figure_bins(
    p_in: np.ndarray, ring_z: np.ndarray, ring_w: np.ndarray, lo: float, n_bins: int, bin_w: float
) -> np.ndarray:  # [n_bins] smoothed shares inside the box -> [n_bins] bool
    """The log-depth bins that hold no larger a share of the ring around the box than of its
    inside: the figure, as against the ground the box was drawn on (outside a box is background,
    as GrabCut takes it). A thin subject (a table leg) covers a minority of its box, so the heaviest depth
    inside can be the floor behind it; the floor fills the ring more than the box, the leg the
    reverse. All bins when the ring has too little to compare with, or when no bin passes."""
    if len(ring_z) < 4 or ring_w.sum() <= 0:
        return np.ones(n_bins, bool)
    rz = np.log(ring_z)
    ok = (rz >= lo) & (rz < lo + n_bins * bin_w)
    idx = np.clip(((rz[ok] - lo) / bin_w).astype(np.int64), 0, n_bins - 1)
    hist = np.bincount(idx, weights=ring_w[ok], minlength=n_bins)
    p_out = np.convolve(np.pad(hist, 1), [1.0, 2.0, 1.0], mode="valid") / (4.0 * ring_w.sum())
    figure = ~(p_out > p_in)  # an empty bin is not ground: the slab may bridge it
    return figure if figure.any() else np.ones(n_bins, bool)


def _sphere_dirs(n: int) -> np.ndarray:  # -> [n, 3] unit vectors spread evenly (a Fibonacci lattice)
    i = np.arange(n) + 0.5
    phi, theta = np.arccos(1.0 - 2.0 * i / n), math.pi * (1.0 + 5.0**0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], -1)


def _plane_of(
    pts: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, float, float]:  # [M, 3] -> centre, normal, thickness, size
    """The best-fitting plane of points: centre, unit normal, their spread across it and along it (std, m)."""
    c = pts.mean(0)
    vals, vecs = np.linalg.eigh(np.cov((pts - c).T) + 1e-12 * np.eye(3))
    return c, vecs[:, 0], float(math.sqrt(max(vals[0], 0.0))), float(math.sqrt(max(vals[2], 0.0)))


def _grow_beyond_frame(
    means: np.ndarray,  # [N, 3] world
    colours: np.ndarray,  # [N, 3]
    alpha: np.ndarray,  # [N]
    u: np.ndarray,  # [N] px in the box's view
    v: np.ndarray,  # [N]
    z: np.ndarray,  # [N] camera depth
    front: np.ndarray,  # [N] bool
    inside: np.ndarray,  # [N] bool: projects into the box
    slab: tuple[float, float],
    subject_pts: np.ndarray,  # [M, 3] world: what the lift found inside the box
    region: Region,
    intrinsics: Intrinsics,
    touched: tuple[str, ...],
    pad: float,
    cfg: FramingConfig,
) -> tuple[np.ndarray, tuple[str, ...]]:
    """The subject's continuation beyond the image borders its box touches, from what other
    views reconstructed: ``(points [E, 3] world, the sides still open)``.

    A box cut by the frame holds only what its image shows; the subject may go on past the border,
    where the other input views may have seen it. The candidates are the Gaussians beyond the
    touched borders (within the box's span along them) that lie on the subject's surface: within
    ``grow_plane_tol`` of the plane through the subject's points when it is flat (a picture seen at
    a slant leaves the depth slab beyond the border, not its plane), else in its depth slab. They
    are figure when their colour is nearer to the subject's own Gaussians' colours than to those
    of the ring around the box at the subject's depth (the wall a picture hangs on), and the subject
    grows from its Gaussians over figure candidates within a link distance (three times the median
    spacing of its Gaussians), as a flood fill. A side stays **open** when the grown subject
    reaches as far as anything was reconstructed there: no ground (background at its surface) was
    seen beyond its end, so the inputs never saw where it stops."""
    w, h = intrinsics.width, intrinsics.height
    z_lo, z_hi = slab
    on_slab = front & (z >= z_lo * (1 - cfg.depth_bin)) & (z <= z_hi * (1 + cfg.depth_bin)) & (alpha > 0.01)
    own = inside & on_slab
    if int(own.sum()) < 4:
        return np.zeros((0, 3)), touched
    c, normal, thick, size = _plane_of(np.concatenate([means[own], subject_pts]))
    flat = thick <= cfg.grow_flat_ratio * size
    tol = max(cfg.grow_plane_tol, 2.0 * thick) if flat else 0.0
    on_surface = front & (alpha > 0.01) & ((np.abs((means - c) @ normal) <= tol) if flat else on_slab)
    big = 1e9
    u_lo = -big if "left" in touched else region.x0 - pad
    u_hi = big if "right" in touched else region.x1 + pad
    v_lo = -big if "top" in touched else region.y0 - pad
    v_hi = big if "bottom" in touched else region.y1 + pad
    ok_uv = np.isfinite(u) & np.isfinite(v)
    beyond = on_surface & ok_uv & (u >= u_lo) & (u <= u_hi) & (v >= v_lo) & (v <= v_hi)
    beyond &= (u < 0) | (u > w) | (v < 0) | (v > h)
    # the ground: the ring around the box (inside the image) on the subject's surface
    ring = on_surface & ok_uv & ~inside & (u >= 0) & (u <= w) & (v >= 0) & (v <= h)
    ring &= (u >= region.x0 - pad) & (u <= region.x1 + pad) & (v >= region.y0 - pad) & (v <= region.y1 + pad)
    if not beyond.any():
        return np.zeros((0, 3)), touched
    fig_c = colours[own][:: max(1, int(own.sum()) // 512)]
    gnd_c = colours[ring][:: max(1, int(ring.sum()) // 512)]

    def nearest(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # [A, 3], [B, 3] -> [A] distance to the nearest of b
        if len(b) == 0:
            return np.full(len(a), np.inf)
        return torch.cdist(torch.as_tensor(a), torch.as_tensor(b)).amin(1).numpy()

    idx = np.flatnonzero(beyond)
    if len(gnd_c) >= 4:  # the box's rim shows the ground too: its colours are not the subject's
        fig_c = fig_c[nearest(fig_c, gnd_c) > cfg.grow_colour_tol]
        figure = nearest(colours[idx], fig_c) < nearest(colours[idx], gnd_c)
    else:  # nothing around the box at its depth: all on its surface is the subject
        figure = np.ones(len(idx), bool)
    seeds = means[own]
    sub = seeds[:: max(1, len(seeds) // 1024)]
    d = torch.cdist(torch.as_tensor(sub), torch.as_tensor(sub))
    d.fill_diagonal_(float("inf"))
    link = max(3.0 * float(torch.median(d.amin(1))), cfg.grow_plane_tol)
    # flood fill over the candidates (figure and ground alike are reached; only figure joins and spreads)
    cand = means[idx]
    joined = np.zeros(len(idx), bool)
    frontier = seeds
    while len(frontier):
        near = np.zeros(len(idx), bool)
        for i in range(0, len(frontier), 2048):
            near |= nearest(cand, frontier[i : i + 2048]) <= link
        new = near & figure & ~joined
        joined |= new
        frontier = cand[new]
    grown = cand[joined]
    # open or closed, side by side: is ground seen just beyond the grown subject's end on that side?
    open_sides = []
    gu, gv = u[idx][joined], v[idx][joined]
    ground = ~figure & (nearest(cand, np.concatenate([seeds, grown])) <= 4.0 * link)  # just beyond, not far off
    bu, bv = u[idx][ground], v[idx][ground]
    for side in touched:
        if side in ("left", "right"):
            end = (gu.min() if side == "left" else gu.max()) if len(gu) else (0.0 if side == "left" else float(w))
            past = (bu < end) if side == "left" else (bu > end)
        else:
            end = (gv.min() if side == "top" else gv.max()) if len(gv) else (0.0 if side == "top" else float(h))
            past = (bv < end) if side == "top" else (bv > end)
        if not past.any():
            open_sides.append(side)
    return grown, tuple(open_sides)


def _hidden_sides(
    depth_map: np.ndarray | None, region: Region, pad: float, nearer_m: float, frac: float, touched: tuple[str, ...]
) -> tuple[str, ...]:
    """The sides of ``region`` (not at the image's border) along which something nearer than the
    subject (depth below ``nearer_m``) covers at least ``frac`` of the ring strip just outside: the
    subject may go on behind it, where this view cannot see it end."""
    if depth_map is None or pad <= 0 or frac >= 1.0:
        return ()
    h, w = depth_map.shape
    x0, y0 = int(math.floor(region.x0)), int(math.floor(region.y0))
    x1, y1 = int(math.ceil(region.x1)), int(math.ceil(region.y1))
    p = max(1, int(math.ceil(pad)))
    strips = {
        "left": depth_map[y0:y1, max(0, x0 - p) : x0],
        "right": depth_map[y0:y1, x1 : min(w, x1 + p)],
        "top": depth_map[max(0, y0 - p) : y0, x0:x1],
        "bottom": depth_map[y1 : min(h, y1 + p), x0:x1],
    }
    out = []
    for side, strip in strips.items():
        if side in touched or strip.size == 0:
            continue
        d = strip[np.isfinite(strip)]
        if len(d) and float(((d > NEAR_M) & (d < nearer_m)).mean()) >= frac:
            out.append(side)
    return tuple(out)


def _reach(pts: np.ndarray, cam2world: np.ndarray, sides) -> np.ndarray:  # [M, 3], [4, 4] -> [O, 3]
    """Per open side, a vector from the subject towards that side (the box's view's image direction:
    left, right, up or down, laid into the subject's plane when it is flat) as long as the
    subject's extent along it."""
    axis = {"left": -cam2world[:3, 0], "right": cam2world[:3, 0], "top": -cam2world[:3, 1], "bottom": cam2world[:3, 1]}
    _, normal, thick, size = _plane_of(pts)
    out = []
    for side in sides:
        d = axis[side].astype(np.float64)
        if thick <= 0.1 * size:  # flat: along its plane
            d = d - (d @ normal) * normal
        n = float(np.linalg.norm(d))
        if n < 1e-9:
            continue
        d = d / n
        extent = float(np.ptp(pts @ d))
        out.append(d * extent)
    return np.asarray(out, dtype=np.float64).reshape(-1, 3)


def lift_region(
    means_m: np.ndarray,
    opacities: np.ndarray,
    cam2world: np.ndarray,
    intrinsics: Intrinsics,
    region: Region,
    cfg: FramingConfig | None = None,
    key: str = "--keep",
    depth_map: np.ndarray | None = None,
    colours: np.ndarray | None = None,
) -> Subject:
    """Lift ``region`` (pixels of an image seen by ``intrinsics`` at ``cam2world``) into a
    :class:`Subject` from Gaussian centres ``means_m [N, 3]`` (world) and ``opacities [N]``;
    ``depth_map [H, W]`` (the reconstruction's depth rendered at that view, 0 where nothing was
    drawn) gives the depth mode per pixel, else the Gaussians behind the box do. ``colours``
    ``[N, 3]`` (the Gaussians' RGB): where the box touches the image's border, the subject is
    grown beyond it over what other views saw (:func:`_grow_beyond_frame`)."""
    cfg = cfg or FramingConfig()
    means = np.asarray(means_m, dtype=np.float64).reshape(-1, 3)
    alpha = np.asarray(opacities, dtype=np.float64).reshape(-1)
    c2w = np.asarray(cam2world, dtype=np.float64)
    w2c = np.linalg.inv(c2w)
    pc = means @ w2c[:3, :3].T + w2c[:3, 3]  # [N, 3] camera
    z = pc[:, 2]
    front = z > NEAR_M
    zs = np.where(front, z, 1.0)
    u = intrinsics.fx * pc[:, 0] / zs + intrinsics.cx
    v = intrinsics.fy * pc[:, 1] / zs + intrinsics.cy
    inside = front & (u >= region.x0) & (u <= region.x1) & (v >= region.y0) & (v <= region.y1)
    inside &= np.isfinite(u) & np.isfinite(v) & (alpha > 0.01)
    # the samples the depth mode is found from: the box's pixels (rendered depth) or its Gaussians
    pix_uv = np.zeros((0, 2))
    if depth_map is not None:
        h, w = depth_map.shape
        cols = np.arange(max(0, int(math.floor(region.x0))), min(w, int(math.ceil(region.x1))))
        rows = np.arange(max(0, int(math.floor(region.y0))), min(h, int(math.ceil(region.y1))))
        uu, vv = np.meshgrid(cols + 0.5, rows + 0.5)
        dd = depth_map[np.ix_(rows, cols)]
        ok = np.isfinite(dd) & (dd > NEAR_M)
        pix_uv, pix_z = np.stack([uu[ok], vv[ok]], -1), dd[ok].astype(np.float64)
    pad = max(2.0, cfg.ring_frac * min(region.x1 - region.x0, region.y1 - region.y0)) if cfg.ring_frac > 0 else 0.0
    if len(pix_uv) >= 4:
        sample_z, sample_w = pix_z, _centre_weight(pix_uv[:, 0], pix_uv[:, 1], region, cfg.edge_weight)
        ring_z = _ring_depths(depth_map, region, pad)
        ring_w = np.ones_like(ring_z)
    elif int(inside.sum()) >= 4:
        sample_z = z[inside]
        sample_w = alpha[inside] * _centre_weight(u[inside], v[inside], region, cfg.edge_weight)
        near = front & (alpha > 0.01) & np.isfinite(u) & np.isfinite(v) & ~inside
        near &= (u >= region.x0 - pad) & (u <= region.x1 + pad) & (v >= region.y0 - pad) & (v <= region.y1 + pad)
        ring_z, ring_w = (z[near], alpha[near]) if pad > 0 else (np.zeros(0), np.zeros(0))
    else:
        raise FramingError(
            f"{key} {region.text()}: the reconstruction has nothing behind this box; the subject is not "
            "reconstructed there: draw the box over something the inputs saw (or add views)"
        )
    logz = np.log(sample_z)
    lo, hi = float(logz.min()), float(logz.max())
    n_bins = max(1, int(math.ceil((hi - lo) / cfg.depth_bin)) + 1)
    idx = np.clip(((logz - lo) / cfg.depth_bin).astype(np.int64), 0, n_bins - 1)
    hist = np.bincount(idx, weights=sample_w, minlength=n_bins)
    smooth = np.convolve(np.pad(hist, 1), [1.0, 2.0, 1.0], mode="valid")
    figure = _figure_bins(smooth / (4.0 * sample_w.sum()), ring_z, ring_w, lo, n_bins, cfg.depth_bin)
    peak = int(np.argmax(np.where(figure, smooth, -np.inf)))
    z_mode = math.exp(lo + (peak + 0.5) * cfg.depth_bin)
    side_m = max(region.x1 - region.x0, region.y1 - region.y0) / intrinsics.fx * z_mode  # the box's side there
    cap = max(cfg.depth_cap * side_m, z_mode * cfg.depth_bin)
    floor = cfg.grow_frac * smooth[peak]

    def grow(step: int) -> int:
        i, gap = peak, 0
        while 0 <= i + step < n_bins:
            j = i + step
            if abs(math.exp(lo + (j + 0.5) * cfg.depth_bin) - z_mode) > cap or not figure[j]:
                break
            if smooth[j] < floor:
                if gap >= 1:
                    break
                gap += 1
            else:
                gap = 0
            i = j
        return i

    first, last = grow(-1), grow(+1)
    z_lo, z_hi = math.exp(lo + first * cfg.depth_bin), math.exp(lo + (last + 1) * cfg.depth_bin)
    occluded = float((sample_z < z_lo * (1.0 - cfg.depth_bin)).mean())  # nearer than the subject: an occluder
    parts = [means[inside & (z >= z_lo) & (z <= z_hi)]]  # the Gaussians in the slab (sides other views saw)
    if len(pix_uv):  # the visible surface: the box's pixels in the slab, unprojected
        sel = (pix_z >= z_lo) & (pix_z <= z_hi)
        cam = np.stack(
            [(pix_uv[sel, 0] - intrinsics.cx) / intrinsics.fx, (pix_uv[sel, 1] - intrinsics.cy) / intrinsics.fy,
             np.ones(int(sel.sum()))], -1,
        ) * pix_z[sel, None]  # fmt: skip
        parts.append(cam @ c2w[:3, :3].T + c2w[:3, 3])
    # the box itself at the mode's depth: what the user drew is held whole even where the view hides it
    bu = np.array([region.x0, region.x1, region.x0, region.x1])
    bv = np.array([region.y0, region.y0, region.y1, region.y1])
    cam = np.stack([(bu - intrinsics.cx) / intrinsics.fx, (bv - intrinsics.cy) / intrinsics.fy, np.ones(4)], -1)
    parts.append((cam * z_mode) @ c2w[:3, :3].T + c2w[:3, 3])
    edge = 1e-6  # px: a box scaled to the reconstruction's resolution may miss the border by rounding
    touched = tuple(
        side
        for side, hit in (
            ("left", region.x0 <= edge),
            ("top", region.y0 <= edge),
            ("right", region.x1 >= intrinsics.width - edge),
            ("bottom", region.y1 >= intrinsics.height - edge),
        )  # fmt: skip
        if hit
    )
    hidden = _hidden_sides(depth_map, region, pad, z_lo * cfg.hidden_ratio, cfg.hidden_frac, touched)
    grown, open_sides = 0, touched
    if touched and colours is not None and cfg.grow_beyond_frame:
        extra, open_sides = _grow_beyond_frame(
            means, np.asarray(colours, dtype=np.float64).reshape(-1, 3), alpha, u, v, z, front, inside,
            (z_lo, z_hi), np.concatenate(parts[:-1]), region, intrinsics, touched, pad, cfg,
        )  # fmt: skip
        grown = len(extra)
        parts.append(extra)
    pts = np.concatenate(parts)  # [M, 3] world
    if len(pts) < 4:
        raise FramingError(
            f"{key} {region.text()}: too little at the subject's depth ({len(pts)} points); draw the box tighter"
        )
    xy = pts[:, :2] - pts[:, :2].mean(0)
    _, vecs = np.linalg.eigh(xy.T @ xy / len(xy))  # ascending: columns are the principal axes
    a0, a1 = vecs[:, 1], vecs[:, 0]
    axes = np.array([[a0[0], a0[1], 0.0], [a1[0], a1[1], 0.0], [0.0, 0.0, 1.0]])
    local = pts @ axes.T  # [M, 3] in the box's axes
    mn, mx = local.min(0), local.max(0)
    half = np.maximum(0.5 * (mx - mn), 1e-3)
    centre = (0.5 * (mn + mx)) @ axes
    n_gauss = len(parts[0])
    outline = pts[np.unique(np.argmax(pts @ _sphere_dirs(cfg.outline_dirs).T, axis=0))]  # [P, 3]
    log.info(
        "%s %s: %d Gaussians and %d pixels at %.2f-%.2f m (mode %.2f m) -> a box %s m",
        key, region.text(), n_gauss, len(pts) - n_gauss, z_lo, z_hi, z_mode, np.round(2 * half, 2).tolist(),
    )  # fmt: skip
    open_sides = tuple(open_sides) + hidden
    reach = _reach(pts, c2w, open_sides) if open_sides else None
    return Subject(region, centre, axes, half, int(n_gauss), (z_lo, z_hi), outline, occluded, bool(touched),
                   tuple(open_sides), grown, reach)  # fmt: skip


def render_depth(scorer: Scorer, cam2world: np.ndarray, intrinsics: Intrinsics) -> np.ndarray | None:
    """The reconstruction's depth ``[H, W]`` (metres, 0 where alpha < 0.5) at a world pose, at
    ``intrinsics``' resolution; None when the scorer has no Gaussians to render."""
    from aes_planner.field.common import local_world2cam
    from aes_planner.gaussians import Gaussians, rasterize

    g, local = _reconstruction(scorer)
    if g is None or len(g) == 0:
        return None
    bare = Gaussians(g.means.detach(), g.quats.detach(), g.log_scales.detach(), g.opacities.detach(),
                     g.colors.detach())  # fmt: skip
    w2c = local_world2cam(torch.as_tensor(np.asarray(cam2world, dtype=np.float64)[None]), local)
    with torch.no_grad():
        out = rasterize(bare, w2c, torch.from_numpy(intrinsics.K), intrinsics.width, intrinsics.height, validate=False)
    depth = out.depth[0].double().numpy()
    return np.where(out.alpha[0].numpy() >= 0.5, depth, 0.0)


def _colour_reconstruction(scorer: Scorer):
    """The reconstruction's Gaussians with their RGB colours and its local frame (the field's own
    Gaussians carry features, not colours), or ``(None, None)``."""
    inner = getattr(scorer, "inner", scorer)
    inputs = getattr(inner, "inputs", None)
    if inputs is not None and getattr(inputs, "splats", None) is not None:
        return inputs.splats.to_gaussians(), inputs.local_frame
    rec = getattr(inner, "reconstruction", None)
    if rec is not None:
        return rec.gaussians, rec.local_frame
    return None, None


def rendered_rgb(scorer: Scorer, cam2world: Tensor, intrinsics: Intrinsics, width_px: int, batch: int = 16):
    """RGB ``[B, 3, h, w]`` in [0, 1] rendered from the reconstruction behind ``scorer`` at poses
    ``[B, 4, 4]`` (``intrinsics``' field of view, ``width_px`` wide), batch by batch (a generator),
    or None when the scorer has no coloured reconstruction."""
    from aes_planner.field.common import local_world2cam, render_intrinsics
    from aes_planner.gaussians import Gaussians, rasterize

    g, local = _colour_reconstruction(scorer)
    if g is None or len(g) == 0:
        return None
    bare = Gaussians(g.means.detach(), g.quats.detach(), g.log_scales.detach(), g.opacities.detach(),
                     g.colors.detach().float())  # fmt: skip
    k = render_intrinsics(intrinsics, width_px)
    K = torch.from_numpy(k.K)  # [3, 3]
    background = torch.tensor(getattr(getattr(scorer, "config", None), "background", (0.0, 0.0, 0.0)))

    def batches():
        with torch.no_grad():
            for i in range(0, len(cam2world), batch):
                w2c = local_world2cam(cam2world[i : i + batch].detach().to(torch.float64), local)
                yield rasterize(bare, w2c, K, k.width, k.height, background=background.float(), validate=False).rgb

    return batches()


def verified_scores(
    scorer: Scorer, cam2world: Tensor, intrinsics: Intrinsics, width_px: int, batch: int = 16
) -> Tensor | None:
    """The teacher's scores ``[B]`` of RGB rendered from the reconstruction behind ``scorer`` at
    poses ``[B, 4, 4]`` (``intrinsics``' field of view, ``width_px`` wide), or None when the scorer
    has no coloured reconstruction or no teacher. The field tracks the teacher only roughly
    among views that all hold a subject; a render of what the inputs saw, scored by the teacher
    itself, might separate them better (an option: on the dev scenes it did not)."""
    teacher = getattr(scorer, "teacher", None)
    rgbs = rendered_rgb(scorer, cam2world, intrinsics, width_px, batch) if teacher is not None else None
    if rgbs is None or len(cam2world) == 0:
        return None
    with torch.no_grad():
        out = [teacher.explain_map(teacher.features(rgb.clamp(0.0, 1.0)))["score"].double() for rgb in rgbs]
    return torch.cat(out)  # [B]


def project_corners(corners: Tensor, cam2world: Tensor, intrinsics: Intrinsics) -> tuple[Tensor, Tensor, Tensor]:
    """Corners ``[S, 8, 3]`` seen from poses ``[B, 4, 4]`` -> normalised image coordinates u, v
    ``[B, S, 8]`` (0..1 across the frame) and camera depth z ``[B, S, 8]`` (z clamped at NEAR_M
    for u, v: a corner behind the camera lands far outside)."""
    rot = cam2world[:, :3, :3]  # [B, 3, 3]
    t = cam2world[:, :3, 3]  # [B, 3]
    rel = corners[None] - t[:, None, None, :]  # [B, S, 8, 3]
    pc = torch.einsum("bji,bskj->bski", rot, rel)  # R^T (p - t): [B, S, 8, 3]
    z = pc[..., 2]
    zc = z.clamp_min(NEAR_M)
    u = (intrinsics.fx * pc[..., 0] / zc + intrinsics.cx) / intrinsics.width
    v = (intrinsics.fy * pc[..., 1] / zc + intrinsics.cy) / intrinsics.height
    return u, v, z


@dataclass(frozen=True)
class PhotoSet:
    """The input images the suggestions are re-ranked on (``FramingConfig.photo_rank``): ``images``
    [H, W, 3] uint8 of one size, taken at ``cam2world [N, 4, 4]`` with ``intrinsics`` (any scale
    of the images' own camera)."""

    images: list
    cam2world: np.ndarray  # [N, 4, 4]
    intrinsics: Intrinsics

    @classmethod
    def of(cls, frames: list) -> PhotoSet | None:
        """The frames (``image``, ``cam2world``, ``intrinsics``) of the most common image size; None
        when there are none."""
        usable = [f for f in frames if getattr(f, "image", None) is not None and np.ndim(f.image) == 3]
        if not usable:
            return None
        shapes = [f.image.shape for f in usable]
        common = max(set(shapes), key=shapes.count)
        kept = [f for f in usable if f.image.shape == common]
        if len(kept) < len(frames):
            log.info("framing: %d of %d input images re-rank the views (one size only)", len(kept), len(frames))
        return cls([np.ascontiguousarray(f.image[..., :3]) for f in kept],
                   np.stack([np.asarray(f.cam2world, np.float64) for f in kept]), kept[0].intrinsics)  # fmt: skip


def _stacked(points: list[np.ndarray]) -> np.ndarray:  # S x [P_i, 3] -> [S, max P_i, 3]
    """Point sets of different sizes as one array, each padded with copies of its first point."""
    if not points:
        return np.zeros((0, 8, 3))
    n = max(len(p) for p in points)
    return np.stack([np.concatenate([p, np.repeat(p[:1], n - len(p), 0)]) for p in points])


class Framing:
    """Kept subjects and avoided regions, lifted, as the search's constraint and soft terms.

    ``intrinsics``: the camera the suggestion will be taken with (the platform's)."""

    def __init__(
        self,
        keep: list[Subject],
        avoid: list[Subject],
        intrinsics: Intrinsics,
        cfg: FramingConfig,
        photos: PhotoSet | None = None,
    ):
        self.keep, self.avoid, self.intrinsics, self.cfg = list(keep), list(avoid), intrinsics, cfg
        self.photos = photos  # the input images, for FramingConfig.photo_rank
        self._keep = torch.as_tensor(
            _stacked([s.hold_points_m(cfg.hold_by, cfg.occluded_max, cfg.open_reach) for s in keep])
        )  # [S, P, 3]
        self._keep_centres = torch.as_tensor(np.stack([s.centre_m for s in keep]) if keep else np.zeros((0, 3)))
        self._avoid = torch.as_tensor(np.stack([s.corners_m for s in avoid]) if avoid else np.zeros((0, 8, 3)))

    @property
    def active(self) -> bool:
        return bool(self.keep or self.avoid)

    def describe(self) -> list[str]:
        """One line per region: what the search keeps and avoids (diagnostics, the CLI)."""
        out = [
            f"keep {s.region.text()} ({s.gaussians} Gaussians, box {np.round(s.size_m, 2).tolist()} m)"
            for s in self.keep
        ]
        out += [f"avoid {s.region.text()}" for s in self.avoid]
        return out

    # ---------------------------------------------------------------- the hard constraint
    def violation(self, cam2world: Tensor) -> Tensor:  # [B, 4, 4] -> [B], 0 = feasible
        """How far the kept subjects' corners are outside the shrunk frame (differentiable)."""
        if not self.keep:
            return torch.zeros(cam2world.shape[0], dtype=torch.float64)
        u, v, z = project_corners(self._keep, cam2world.to(torch.float64), self.intrinsics)
        m = self.cfg.margin_frac
        out = (m - u).clamp_min(0) + (u - (1 - m)).clamp_min(0) + (m - v).clamp_min(0) + (v - (1 - m)).clamp_min(0)
        out = out + (NEAR_M - z).clamp_min(0) * 10.0
        return out.sum((1, 2))

    def feasible(self, cam2world: Tensor) -> Tensor:  # [B, 4, 4] -> [B] bool
        with torch.no_grad():
            return self.violation(cam2world) <= 0.0

    def held(self, cam2world: Tensor) -> Tensor:  # [B, 4, 4] -> [B] in [0, 1]
        """How much of the (least-held) kept subject a view holds: the fraction of its projected
        box's bounding rectangle inside the frame (0 when a corner is behind the camera)."""
        if not self.keep:
            return torch.ones(cam2world.shape[0], dtype=torch.float64)
        return self.held_each(cam2world).min(-1).values

    def held_each(self, cam2world: Tensor) -> Tensor:  # [B, 4, 4] -> [B, S] in [0, 1]
        """:meth:`held` per kept subject."""
        with torch.no_grad():
            u, v, z = project_corners(self._keep, cam2world.to(torch.float64), self.intrinsics)
            frac = _inside_fraction(u, v)
            return torch.where((z > NEAR_M).all(-1), frac, torch.zeros_like(frac))

    # ---------------------------------------------------------------- the soft terms
    def avoid_visible(self, cam2world: Tensor) -> Tensor:  # [B, 4, 4] -> [B] (sum over avoided regions)
        if not self.avoid:
            return torch.zeros(cam2world.shape[0], dtype=torch.float64)
        u, v, z = project_corners(self._avoid, cam2world.to(torch.float64), self.intrinsics)
        frac = _inside_fraction(u, v)  # [B, S]
        front = (z > NEAR_M).to(frac.dtype).mean(-1)  # a box behind the camera is not in view
        return (frac * front).sum(-1)

    def placement(self, cam2world: Tensor) -> Tensor:  # [B, 4, 4] -> [B] in [0, 1]
        if not self.keep or self.cfg.keep_at is None:
            return torch.zeros(cam2world.shape[0], dtype=torch.float64)
        centres = self._keep_centres[:, None]  # [S, 1, 3]
        u, v, _ = project_corners(centres, cam2world.to(torch.float64), self.intrinsics)  # [B, S, 1]
        if self.cfg.keep_at == "centre":
            d = torch.sqrt((u - 0.5) ** 2 + (v - 0.5) ** 2 + 1e-12)
        else:
            pts = torch.tensor([1 / 3, 2 / 3], dtype=torch.float64)
            du = (u[..., None] - pts).abs().amin(-1)
            dv = (v[..., None] - pts).abs().amin(-1)
            d = torch.sqrt(du**2 + dv**2 + 1e-12)
        return (1.0 - d[..., 0] / math.sqrt(0.5)).clamp(0.0, 1.0).mean(-1)

    def fill(self, cam2world: Tensor) -> Tensor:  # [B, 4, 4] -> [B] in [0, 1]
        """The share of the frame the kept subjects' projected bounding rectangles cover (mean over subjects)."""
        if not self.keep:
            return torch.zeros(cam2world.shape[0], dtype=torch.float64)
        u, v, _ = project_corners(self._keep, cam2world.to(torch.float64), self.intrinsics)  # [B, S, P]
        w = u.amax(-1).clamp(0, 1) - u.amin(-1).clamp(0, 1)
        h = v.amax(-1).clamp(0, 1) - v.amin(-1).clamp(0, 1)
        return (w * h).mean(-1)

    def soft_terms(self, cam2world: Tensor) -> Tensor:  # [B, 4, 4] -> [B] added to the score
        out = self.cfg.placement_weight * self.placement(cam2world) - self.cfg.avoid_weight * self.avoid_visible(
            cam2world
        )
        if self.cfg.fill_weight:
            out = out + self.cfg.fill_weight * self.fill(cam2world)
        return out

    # ---------------------------------------------------------------- search hooks
    def aimed(self, cam2world: np.ndarray) -> np.ndarray:  # [T, 4, 4] -> [T, 4, 4]
        """Views from the same camera centres turned to look at the kept subjects' centre."""
        from aes_planner.geometry.poses import look_at

        if not self.keep or len(cam2world) == 0:
            return np.zeros((0, 4, 4))
        target = np.mean([s.centre_m for s in self.keep], axis=0)
        eyes = np.asarray(cam2world, dtype=np.float64)[:, :3, 3]
        far = np.linalg.norm(eyes - target, axis=1) > 1e-6
        if not far.any():
            return np.zeros((0, 4, 4))
        return np.asarray(look_at(eyes[far], np.broadcast_to(target, eyes[far].shape).copy()), dtype=np.float64)

    def notes(self) -> list[str]:
        """What the suggestions cannot promise, one line per kept subject concerned (the search's warnings)."""
        return [
            f"--keep {s.region.text()}: the box touches its image's border ({', '.join(s.open_sides)}) and the "
            "inputs never saw where the subject ends beyond it; the suggestions hold what they saw of it: "
            "draw the box in a view that shows all of it"
            for s in self.keep
            if s.cut_by_frame and s.open_sides
        ]

    def with_margin(self, margin_frac: float, open_reach: float | None = None) -> Framing:
        """The same subjects and regions, held with ``margin_frac`` of the frame instead (and
        ``open_reach`` beyond their open sides, when given)."""
        reach = self.cfg.open_reach if open_reach is None else open_reach
        cfg = dataclasses.replace(self.cfg, margin_frac=margin_frac, open_reach=reach)
        return Framing(self.keep, self.avoid, self.intrinsics, cfg, self.photos)

    def wrap(self, scorer: Scorer) -> Scorer:
        return FramedScorer(scorer, self) if self.avoid or self.cfg.keep_at or self.cfg.fill_weight else scorer

    def open_error(self, best_pose: np.ndarray, best_held: float, platform_kind: str) -> FramingError:
        """No reachable view leaves room beyond a kept subject's open sides (where the inputs never
        saw it end): no view can be trusted to hold all of it."""
        pos = ", ".join(f"{x:.2f}" for x in best_pose[:3, 3])
        fwd = ", ".join(f"{x:.2f}" for x in best_pose[:3, 2])
        where = "the rig's joint limits" if platform_kind == "rig" else "the drone's box and pitch limits"
        opened = [s for s in self.keep if s.open_sides]
        names = ", ".join(f"{s.region.text()} ({'/'.join(s.open_sides)})" for s in opened)
        return FramingError(
            f"--keep {names}: the subject goes on past its box on that side (the image's border, or something in "
            f"front of it) where the inputs never saw it end, and no reachable view ({where}) leaves room for it "
            f"there: no view can be trusted to hold all of it; the closest view (camera at [{pos}] m, looking along "
            f"[{fwd}]) holds {best_held:.0%} of it with that room: draw the box in a view that shows all of the "
            "subject, or widen the limits"
        )

    def no_view_error(self, best_pose: np.ndarray, best_held: float, platform_kind: str) -> FramingError:
        pos = ", ".join(f"{x:.2f}" for x in best_pose[:3, 3])
        fwd = ", ".join(f"{x:.2f}" for x in best_pose[:3, 2])
        where = "the rig's joint limits" if platform_kind == "rig" else "the drone's box and pitch limits"
        names = ", ".join(s.region.text() for s in self.keep)
        return FramingError(
            f"--keep {names}: no reachable view holds the whole subject inside the frame with a "
            f"{self.cfg.margin_frac:.0%} margin ({where}); the closest view (camera at [{pos}] m, looking along "
            f"[{fwd}]) holds {best_held:.0%} of it: widen the limits, lower --keep-margin or draw a smaller box"
        )


def _inside_fraction(u: Tensor, v: Tensor) -> Tensor:  # [B, S, 8] normalised -> [B, S]
    """Area fraction of the corners' bounding rectangle that lies inside the unit frame."""
    u0, u1 = u.amin(-1), u.amax(-1)
    v0, v1 = v.amin(-1), v.amax(-1)
    area = (u1 - u0).clamp_min(1e-9) * (v1 - v0).clamp_min(1e-9)
    iu = (u1.clamp(0, 1) - u0.clamp(0, 1)).clamp_min(0)
    iv = (v1.clamp(0, 1) - v0.clamp(0, 1)).clamp_min(0)
    return (iu * iv / area).clamp(0.0, 1.0)


class FramedScorer(Scorer):
    """A scorer whose score carries the framing's soft terms (avoided regions, placement); the
    aesthetic score stays in ``terms["aesthetic"]``."""

    def __init__(self, inner: Scorer, framing: Framing):
        self.inner, self.framing = inner, framing
        self.name = inner.name
        self.differentiable = inner.differentiable
        self.intrinsics = inner.intrinsics

    def __getattr__(self, name):  # teacher, gaussians, render... of the scorer it wraps
        if name in ("inner", "framing"):
            raise AttributeError(name)
        return getattr(self.inner, name)

    def score(self, cam2world: Tensor) -> ScoreOutput:  # [B, 4, 4] -> ScoreOutput [B]
        out = self.inner.score(cam2world)
        extra = self.framing.soft_terms(cam2world.to(torch.float64))
        terms = dict(out.terms)
        terms["aesthetic"] = out.score.detach()
        if self.framing.avoid:
            terms["avoid_visible"] = self.framing.avoid_visible(cam2world.detach().to(torch.float64)).float()
        return ScoreOutput(out.score + extra.to(out.score.dtype), out.coverage, terms)


def _reconstruction(scorer: Scorer):
    """The Gaussians behind a field or RGB scorer (or one wrapping it) and their local frame."""
    inner = getattr(scorer, "inner", scorer)
    local = getattr(inner, "local_frame", None)
    if local is None and getattr(inner, "reconstruction", None) is not None:
        local = inner.reconstruction.local_frame
    return getattr(inner, "gaussians", None), local


def world_colours(scorer: Scorer) -> np.ndarray | None:
    """The RGB ``[N, 3]`` of the Gaussians :func:`world_gaussians` gives (the reconstruction's
    colours, in the same order), or None when the scorer has none."""
    g, _ = _reconstruction(scorer)
    inputs = getattr(getattr(scorer, "inner", scorer), "inputs", None)
    splats = getattr(inputs, "splats", None)
    if g is None:
        return None
    if splats is not None and len(splats) == len(g):
        return np.asarray(splats.colors, dtype=np.float64)
    if g.colors is not None and g.colors.shape[-1] == 3 and getattr(g, "features", None) is None:
        return g.colors.detach().double().cpu().numpy()
    return None


def world_gaussians(scorer: Scorer) -> tuple[np.ndarray, np.ndarray]:
    """The Gaussian centres ``[N, 3]`` (world frame) and opacities ``[N]`` behind a field or RGB scorer."""
    g, local = _reconstruction(scorer)
    if g is None or len(g) == 0:
        raise FramingError(
            f"the {getattr(scorer, 'name', 'scorer')!r} scorer has no reconstruction to lift a region from; "
            "--keep/--avoid need the field or RGB scoring of posed frames"
        )
    means = g.means.detach().double().cpu().numpy()
    if local is not None:
        means = means + local.origin
    return means, g.opacities.detach().double().cpu().numpy()


def build_framing(
    scorer: Scorer,
    frames: dict,
    keep: list[Region],
    avoid: list[Region],
    intrinsics: Intrinsics,
    cfg: FramingConfig | None = None,
    photos: list | None = None,
) -> Framing:
    """Lift ``keep`` and ``avoid`` regions into a :class:`Framing` for cameras of ``intrinsics``.

    ``frames``: ``{name: (cam2world [4, 4], intrinsics of the frame as the scorer saw it,
    (width, height) of the image the boxes are drawn on)}``; a region naming another frame, a
    box outside its image or of zero size is a :class:`FramingError` naming the field.
    ``photos``: the input frames (``image``, ``cam2world``, ``intrinsics`` each), for
    ``FramingConfig.photo_rank`` (:meth:`PhotoSet.of`).
    """
    cfg = cfg or FramingConfig()
    means = opac = colours = None
    subjects: dict[str, list[Subject]] = {"keep": [], "avoid": []}
    for key, regions in (("keep", keep), ("avoid", avoid)):
        for region in regions:
            flag = f"--{key}"
            if region.frame not in frames:
                known = sorted(frames)
                shown = ", ".join(known[:6]) + (", ..." if len(known) > 6 else "")
                raise FramingError(f"{flag} {region.text()}: no input frame is named {region.frame!r}; known: {shown}")
            cam2world, k, (w, h) = frames[region.frame]
            region.checked(flag, w, h)
            if means is None:
                means, opac = world_gaussians(scorer)
                colours = world_colours(scorer)
            scaled = region.scaled(k.width / w, k.height / h)
            depth = render_depth(scorer, cam2world, k)
            subjects[key].append(lift_region(means, opac, cam2world, k, scaled, cfg, flag, depth, colours))
            subjects[key][-1].region = region
    photo_set = PhotoSet.of(photos) if photos and cfg.photo_rank and subjects["keep"] else None
    return Framing(subjects["keep"], subjects["avoid"], intrinsics, cfg, photo_set)


def feasible_candidates(
    framing: Framing, space, candidates: Tensor, trajectory: np.ndarray, cfg, rng
) -> tuple[Tensor, Framing]:
    """Stage 1's candidates ``[C, D]`` that hold every kept subject, and the framing they hold it
    under: ``framing`` itself, or, when no reachable view holds the subject with the margin asked,
    the same with the margin halved, then none (the subject held whole but closer to the frame's
    edge: :meth:`Framing.with_margin`; the caller says so). A :class:`FramingError` with the
    closest view (at the margin asked) when no view holds it even at the frame's edge."""
    reach = framing.cfg.open_reach
    open_subject = reach > 0 and any(s.open_sides and s.reach_m is not None and len(s.reach_m) for s in framing.keep)
    for r in (reach, reach / 2) if open_subject else ():  # room beyond an open side, while some view gives it
        try:
            relaxed = framing.with_margin(framing.cfg.margin_frac, r)
            return _feasible_pool(relaxed, space, candidates, trajectory, cfg, rng), relaxed
        except FramingError:
            continue
    if open_subject:
        roomy = framing.with_margin(framing.cfg.margin_frac, reach / 2)
        framing = framing.with_margin(framing.cfg.margin_frac, 0.0)
        if framing.cfg.open_refuse:  # what was seen may be held, but nothing says the rest is: say so
            seen = _feasible_pool(framing, space, candidates, trajectory, cfg, rng)
            poses = space.to_poses(seen).detach()
            held = roomy.held(poses)
            i = int(torch.argmax(held))
            raise roomy.open_error(poses[i].numpy(), float(held[i]), space.kind)
        log.info("framing: no reachable view leaves room beyond the subject's open sides; holding what was seen")
    try:
        return _feasible_pool(framing, space, candidates, trajectory, cfg, rng), framing
    except FramingError as asked:
        if not framing.keep or framing.cfg.margin_frac <= 0.0:
            raise
        for margin in (framing.cfg.margin_frac / 2, 0.0):
            relaxed = framing.with_margin(margin)
            try:
                pool = _feasible_pool(relaxed, space, candidates, trajectory, cfg, rng)
            except FramingError:
                continue
            log.warning("framing: %s; a %g%% margin holds it", asked, 100 * margin)
            return pool, relaxed
        raise asked from None


def _feasible_pool(framing: Framing, space, candidates: Tensor, trajectory: np.ndarray, cfg, rng) -> Tensor:
    """:func:`feasible_candidates` at ``framing``'s own margin: the candidates that hold every
    kept subject, with views aimed at the subject from every trajectory sample (and their
    neighbours) among them; when none holds it, ``framing.cfg.feasibility_samples`` random views
    (and those aimed from their camera centres) are tried, geometry only. A :class:`FramingError`
    with the closest view when nothing holds it."""
    aimed = framing.aimed(trajectory)
    pool = candidates
    if len(aimed):
        a = space.from_poses(aimed)  # [T, D]
        pool = torch.cat([candidates, a, space.neighbours(a, cfg.neighbours, rng)])
    if framing.cfg.explore_samples:  # the feasible set away from the trajectory competes too
        spread = space.random(framing.cfg.explore_samples, rng)
        turned = framing.aimed(space.to_poses(spread).detach().numpy())
        if len(turned):
            spread = torch.cat([spread, space.from_poses(turned)])
        fine = framing.feasible(space.to_poses(spread))
        spread = spread[fine]
        if len(spread) > framing.cfg.explore_keep:
            spread = spread[torch.as_tensor(rng.choice(len(spread), framing.cfg.explore_keep, replace=False))]
        pool = torch.cat([pool, spread])
    ok = framing.feasible(space.to_poses(pool))
    if bool(ok.any()):
        return pool[ok]
    extra = space.random(framing.cfg.feasibility_samples, rng) if framing.cfg.feasibility_samples else pool[:0]
    if len(extra):
        turned = framing.aimed(space.to_poses(extra).detach().numpy())
        extra = torch.cat([extra, space.from_poses(turned)]) if len(turned) else extra
        ok = framing.feasible(space.to_poses(extra))
        if bool(ok.any()):
            found = extra[ok][: max(len(candidates), 1)]
            log.info("framing: no trajectory view holds the subject; %d random view(s) do", int(ok.sum()))
            return found
    tried = torch.cat([pool, extra])
    poses = space.to_poses(tried).detach()
    held = framing.held(poses)
    i = int(torch.argmax(held))
    raise framing.no_view_error(poses[i].numpy(), float(held[i]), space.kind)


def frame_index(frames) -> dict[str, int]:
    """``{name: index}`` of posed frames by the names a region may give: the image file name as
    ``cameras.json`` has it (``images/00003.png``), its base name (``00003.png``) and the frame id."""
    out: dict[str, int] = {}
    for i, f in enumerate(frames):
        name = f.extras.get("image_name")
        if isinstance(name, str) and name:
            out.setdefault(name, i)
            out.setdefault(name.replace("\\", "/").rsplit("/", 1)[-1], i)
        if f.frame_id:
            out.setdefault(str(f.frame_id), i)
    return out


def dataset_frames(frames) -> dict:
    """:func:`build_framing`'s ``frames`` from posed frames (names: :func:`frame_index`); boxes are in
    pixels of the image as stored (``extras["stored_size"]``, before any downscale)."""
    out = {}
    for name, i in frame_index(frames).items():
        f = frames[i]
        size = f.extras.get("stored_size", (f.intrinsics.width, f.intrinsics.height))
        out[name] = (f.cam2world, f.intrinsics, tuple(int(v) for v in size))
    return out
