"""``Reconstructor``: posed frames in, a budgeted set of Gaussians out, one frame at a time.

Read top to bottom: :func:`detect_mode` (what the frames carry), :func:`parallax_px` (the
rotation-versus-translation test), the stages both paths share (:func:`frame_mode`,
:func:`frame_depth`, :func:`integrate`: splats -> dedupe into the map, :func:`enforce_budget`),
the :class:`Reconstructor` (``add_frame``, frame by frame) and :func:`reconstruct` (a batch of
frames: stereo neighbours from the whole batch, hidden-splat pruning over every input view).
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np
import torch

from aes_planner.gaussians import Gaussians, RasterOutput, rasterize
from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.poses import LocalFrame
from aes_planner.messages import PosedFrame
from aes_planner.reconstruct.config import ReconstructConfig, ReconstructError
from aes_planner.reconstruct.merge import coarsen, dedupe, prune_hidden, refit_colors
from aes_planner.reconstruct.splats import (
    SplatParams,
    SplatSet,
    fill_inverse_depth,
    ray_sphere_depth,
    sharpen_colors,
    splats_from_depth,
)
from aes_planner.reconstruct.stereo import StereoResult, consistent_depth, plane_sweep_depth

__all__ = [
    "Reconstruction",
    "Reconstructor",
    "budget_for",
    "detect_mode",
    "enforce_budget",
    "frame_depth",
    "frame_mode",
    "integrate",
    "parallax_px",
    "reconstruct",
]

log = logging.getLogger(__name__)


@dataclass
class _Local:
    """A frame moved into the reconstruction's local frame."""

    frame: PosedFrame  # cam2world replaced by the local pose
    index: int  # position in the stream (provenance)
    stereo: StereoResult | None = None  # raw plane-sweep result, once computed


def _overlap(a: PosedFrame, b: PosedFrame) -> bool:
    """Whether two cameras can see the same things: optical axes within 3/4 of a field of view."""
    fov = max(a.intrinsics.hfov_rad, b.intrinsics.hfov_rad)
    cos = float(a.cam2world[:3, 2] @ b.cam2world[:3, 2])
    return cos > math.cos(0.75 * fov)


def _pair_parallax_px(a: PosedFrame, b: PosedFrame, depth_m: float) -> float:
    """Parallax (pixels) a point at ``depth_m`` shows between two cameras: focal x the baseline
    across the mean viewing direction / depth."""
    base = b.cam2world[:3, 3] - a.cam2world[:3, 3]
    view = a.cam2world[:3, 2] + b.cam2world[:3, 2]
    view /= max(np.linalg.norm(view), 1e-12)
    across = float(np.linalg.norm(base - (base @ view) * view))
    focal = min(a.intrinsics.fx, b.intrinsics.fx)
    return focal * across / depth_m


def parallax_px(frames: list[PosedFrame], depth_m: float) -> float:
    """Largest parallax (pixels) a point at ``depth_m`` shows between two frames that overlap.

    Better than :func:`~aes_planner.reconstruct.stereo.expected_disparity_px` for deciding
    whether stereo can work: it ignores pairs that look in different directions (a pan-tilt rig
    panning 180 degrees moves its camera by twice the lever arm, but those two views share no
    pixel) and the part of the baseline along the line of sight (which shifts pixels little).
    0 for fewer than two frames or no overlapping pair.
    """
    best = 0.0
    for i, a in enumerate(frames):
        for b in frames[i + 1 :]:
            if _overlap(a, b):
                best = max(best, _pair_parallax_px(a, b, depth_m))
    return best


def detect_mode(frames: list[PosedFrame], config: ReconstructConfig | None = None) -> str:
    """``depth`` when every frame carries depth; otherwise ``stereo`` when two overlapping frames
    show at least ``min_parallax_px`` of parallax at ``nominal_depth_m``; otherwise ``sphere``
    (a rotating rig, or a single RGB frame)."""
    cfg = config or ReconstructConfig()
    if frames and all(f.depth_m is not None for f in frames):
        return "depth"
    rgb = [f for f in frames if f.depth_m is None]
    return "stereo" if parallax_px(rgb, cfg.nominal_depth_m) >= cfg.min_parallax_px else "sphere"


@dataclass
class Reconstruction:
    """What :func:`reconstruct` returns: the Gaussians in ``local_frame`` coordinates."""

    gaussians: Gaussians
    local_frame: LocalFrame
    modes: list[str]  # the mode each input frame was reconstructed with ('' = not used)
    stats: dict = field(default_factory=dict)
    splats: SplatSet | None = None  # the same splats with their merge bookkeeping

    def render(self, cam2world: np.ndarray, intrinsics: Intrinsics, background=None) -> RasterOutput:
        """Render at a **world** pose ``cam2world [4, 4]`` (moved into the local frame in float64)."""
        return render_local(self.gaussians, self.local_frame.pose_to_local(cam2world), intrinsics, background)


def render_local(
    gaussians: Gaussians, cam2world_local: np.ndarray, intrinsics: Intrinsics, background=None
) -> RasterOutput:
    """Render Gaussians at a local-frame pose ``[4, 4]``."""
    w2c = torch.from_numpy(np.linalg.inv(np.asarray(cam2world_local, np.float64)))
    return rasterize(
        gaussians, w2c, torch.from_numpy(intrinsics.K), intrinsics.width, intrinsics.height, background=background
    )


# ---------------------------------------------------------------------------- stages
# Flat functions that both Reconstructor (frame by frame) and reconstruct (a batch) call.


def frame_mode(frame: PosedFrame, index: int, cfg: ReconstructConfig, rgb_mode: str | None) -> str | None:
    """The mode a frame is reconstructed with: ``depth`` when it has depth and the config allows,
    else ``rgb_mode`` (``stereo``/``sphere``; None while undecided)."""
    if cfg.mode == "depth" and frame.depth_m is None:
        raise ReconstructError(
            f"frame {index} has no depth but mode='depth'; use mode='auto' (or 'stereo'/'sphere') for RGB frames"
        )
    if frame.depth_m is not None and cfg.mode in ("auto", "depth"):
        return "depth"
    return rgb_mode


def frame_depth(
    frame: PosedFrame,
    mode: str,
    cfg: ReconstructConfig,
    sphere_centre: np.ndarray | None,
    depth: np.ndarray | None = None,
    confidence: np.ndarray | None = None,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Depth ``[H, W]`` (and confidence) a frame's splats are built from: the sphere for
    ``sphere``, the sensor for ``depth``, ``depth`` as given for ``stereo``; pixels without depth
    handled by ``unknown_depth``."""
    if mode == "sphere":
        return ray_sphere_depth(frame.intrinsics, frame.cam2world, sphere_centre, cfg.sphere_radius_m), confidence
    if mode == "depth":
        depth = frame.depth_m.astype(np.float64)
    if depth is None:
        return None, confidence
    policy = cfg.unknown_depth if cfg.unknown_depth != "auto" else ("fill" if mode == "stereo" else "far")
    unknown = depth <= 0
    if unknown.any() and policy == "far":
        far = ray_sphere_depth(frame.intrinsics, frame.cam2world, np.zeros(3), cfg.far_radius_m)
        depth = np.where(unknown, far, depth)
    elif unknown.any() and policy == "fill":
        depth = fill_inverse_depth(depth)
        if confidence is not None:
            confidence = np.where(unknown & (depth > 0), FILL_CONFIDENCE, confidence)
    # beyond any sensor: no measurement, and not filled (a map of only such depths stays an error)
    return np.where(depth > MAX_DEPTH_M, 0.0, depth), confidence


#: Depth beyond this is no measurement (a broken file or wrong units; 3e38 overflowed the splats'
#: float32 means): such pixels make no splats.
MAX_DEPTH_M = 1e6


def integrate(
    splat_map: SplatSet,
    frame: PosedFrame,
    index: int,
    cfg: ReconstructConfig,
    depth: np.ndarray,
    confidence: np.ndarray | None = None,
) -> tuple[SplatSet, int]:
    """Splats of one (local-frame) frame merged into ``splat_map``: build, sharpen, deduplicate
    against the map, drop faint ones. Returns the new map and how many of the frame's splats
    entered it."""
    params = SplatParams.from_config(cfg, cfg.stride_for(frame.width))
    new = splats_from_depth(frame.image, depth, frame.intrinsics, frame.cam2world, params, index, confidence)
    new = sharpen_colors(new, frame.image, frame.intrinsics, frame.cam2world, params.stride, cfg.sharpen_iterations)
    if cfg.dedupe:
        keep_old, keep_new = dedupe(splat_map, new, cfg.merge_cell_factor, cfg.merge_margin)
        new = new.select(keep_new)
        splat_map = splat_map.select(keep_old)
    splat_map = SplatSet.cat([splat_map, new])
    return splat_map.select(splat_map.opacities >= cfg.min_opacity), len(new)


def budget_for(splat_map: SplatSet, cfg: ReconstructConfig) -> int:
    """``min(max_gaussians, ceil(budget_ratio x samples))``: samples are the stride blocks the
    deduplicated scene holds, a measure of its extent as the views see it."""
    if cfg.budget_ratio <= 0:
        return cfg.max_gaussians
    return int(min(cfg.max_gaussians, max(1, math.ceil(cfg.budget_ratio * float(splat_map.samples.sum())))))


def enforce_budget(splat_map: SplatSet, cfg: ReconstructConfig, slack: float) -> SplatSet:
    """Merge down to ``(1 - slack) x budget`` when over the budget."""
    budget = budget_for(splat_map, cfg)
    if len(splat_map) <= budget:
        return splat_map
    target = max(1, int(budget * (1.0 - slack)))
    merged = coarsen(splat_map, target, cfg.scale_factor)
    log.debug("budget %d: merged %d -> %d Gaussians", budget, len(splat_map), len(merged))
    return merged


# ---------------------------------------------------------------------------- streaming
class Reconstructor:
    """Incremental reconstruction: :meth:`add_frame` each posed frame; :attr:`gaussians` any time.

    The count stays under :attr:`budget` after every frame, and the state is the map plus a few
    recent frames for stereo, so memory is flat however long the stream. Coordinates are local to
    the first frame's camera (:attr:`local_frame`), so GNSS/UTM poses keep their precision.
    """

    def __init__(self, config: ReconstructConfig | None = None):
        self.config = config or ReconstructConfig()
        self.local_frame: LocalFrame | None = None
        self.frames_added = 0
        self.mode_counts: Counter[str] = Counter()  # frames integrated per mode (no per-frame list: memory stays flat)
        self.last_modes: list[str] = []  # the modes used by the latest add_frame (a waiting frame may join it)
        self._map = SplatSet.empty()
        self._rgb_mode: str | None = None if self.config.mode == "auto" else self.config.mode
        self._recent: deque[_Local] = deque(maxlen=max(4, 2 * self.config.stereo_neighbours + 1))
        self._pending: list[_Local] = []
        self._sphere_centre: np.ndarray | None = None

    # ------------------------------------------------------------------ public
    @property
    def gaussians(self) -> Gaussians:
        return self._map.to_gaussians()

    @property
    def splats(self) -> SplatSet:
        """The map with its merge bookkeeping (footprints, scores, samples)."""
        return self._map

    def __len__(self) -> int:
        return len(self._map)

    @property
    def budget(self) -> int:
        """The current Gaussian budget (:func:`budget_for`)."""
        return budget_for(self._map, self.config)

    def add_frame(self, frame: PosedFrame) -> int:
        """Integrate one frame; returns how many of its splats entered the map (0 while a stereo
        frame waits for a neighbour)."""
        if not isinstance(frame, PosedFrame):
            raise ReconstructError(f"add_frame takes a PosedFrame, got {type(frame).__name__}")
        if self.local_frame is None:
            self.local_frame = LocalFrame.centred_on(frame.cam2world)
        item = _Local(_to_local(frame, self.local_frame), self.frames_added)
        self.frames_added += 1
        self.last_modes = []
        mode = self._mode_for(item)
        added = 0
        if mode in ("wait", "stereo"):
            self._recent.append(item)
            self._pending.append(item)
            if mode == "stereo":
                added = self._integrate_stereo_pending()
        else:
            if mode == "sphere":  # frames that waited for the decision
                for waiting in self._pending:
                    added += self._integrate(waiting, "sphere")
                self._pending = []
            added += self._integrate(item, mode)
        self._map = enforce_budget(self._map, self.config, self.config.budget_slack)
        return added

    def render(self, cam2world: np.ndarray, intrinsics: Intrinsics, background=None) -> RasterOutput:
        """Render the current map at a **world** pose ``[4, 4]``."""
        if self.local_frame is None:
            raise ReconstructError("nothing to render yet: add a frame first")
        return render_local(self.gaussians, self.local_frame.pose_to_local(cam2world), intrinsics, background)

    # ------------------------------------------------------------------ internals
    def _mode_for(self, item: _Local) -> str:
        mode = frame_mode(item.frame, item.index, self.config, self._rgb_mode)
        if mode is not None:
            return mode
        # auto with RGB frames: decide once, from the first frames that overlap
        candidates = [r.frame for r in self._recent] + [item.frame]
        if len(candidates) < 2:
            return "wait"  # one RGB frame cannot tell rotation from translation
        self._rgb_mode = detect_mode(candidates, self.config)
        log.info(
            "reconstruct: RGB frames %s (parallax %.2f px at %.1f m)",
            "translate: stereo" if self._rgb_mode == "stereo" else "rotate: sphere",
            parallax_px(candidates, self.config.nominal_depth_m),
            self.config.nominal_depth_m,
        )
        return self._rgb_mode

    def _integrate(
        self, item: _Local, mode: str, depth: np.ndarray | None = None, confidence: np.ndarray | None = None
    ) -> int:
        if mode == "sphere" and self._sphere_centre is None:
            self._sphere_centre = item.frame.cam2world[:3, 3].copy()
        depth, confidence = frame_depth(item.frame, mode, self.config, self._sphere_centre, depth, confidence)
        self._map, added = integrate(self._map, item.frame, item.index, self.config, depth, confidence)
        self.mode_counts[mode] += 1
        self.last_modes.append(mode)
        return added

    def _integrate_stereo_pending(self) -> int:
        added = 0
        still = []
        pool = list(self._recent)
        for item in self._pending:
            depth = _stereo_depth(item, pool, self.config)
            if depth is None:
                still.append(item)
                continue
            added += self._integrate(item, "stereo", *depth)
        in_window = {id(r) for r in self._recent}
        dropped = [i.index for i in still if id(i) not in in_window]
        if dropped:
            log.warning("reconstruct: frames %s found no stereo neighbour with parallax and were skipped", dropped)
        self._pending = [i for i in still if id(i) in in_window]
        return added


FILL_CONFIDENCE = 0.05  # interpolated stereo depth: kept, but any measurement beats it in a merge


def _to_local(frame: PosedFrame, local: LocalFrame) -> PosedFrame:
    return PosedFrame(
        frame.image,
        frame.intrinsics,
        local.pose_to_local(frame.cam2world),
        frame.stamp_s,
        frame.depth_m,
        frame.frame_id,
    )


def _stereo_neighbours(ref: _Local, pool: list[_Local], cfg: ReconstructConfig) -> list[_Local]:
    """Up to ``stereo_neighbours`` frames of ``pool`` that overlap ``ref`` with enough parallax,
    those whose parallax is nearest a tenth of the image width first (wide enough to resolve
    depth, narrow enough to keep most pixels in common)."""
    ok = []
    for c in pool:
        if c is ref or not _overlap(ref.frame, c.frame):
            continue
        par = _pair_parallax_px(ref.frame, c.frame, cfg.nominal_depth_m)
        if par >= max(cfg.min_parallax_px, 1e-9):
            ok.append((abs(math.log(par / (0.1 * ref.frame.width))), c))
    ok.sort(key=lambda t: t[0])
    return [c for _, c in ok[: cfg.stereo_neighbours]]


def _raw_stereo(item: _Local, pool: list[_Local], cfg: ReconstructConfig) -> StereoResult | None:
    if item.stereo is None:
        nbs = _stereo_neighbours(item, pool, cfg)
        if not nbs:
            return None
        item.stereo = plane_sweep_depth(item.frame, [n.frame for n in nbs], cfg.stereo)
    return item.stereo


def _stereo_depth(item: _Local, pool: list[_Local], cfg: ReconstructConfig) -> tuple[np.ndarray, np.ndarray] | None:
    """Depth and confidence ``[H, W]`` for a frame from its stereo neighbours in ``pool``, kept
    where a neighbour's own stereo depth agrees (``stereo_consistency``); None without a
    neighbour."""
    raw = _raw_stereo(item, pool, cfg)
    if raw is None:
        return None
    depth = raw.depth_m
    if cfg.stereo_consistency > 0:
        others = []
        for nb in _stereo_neighbours(item, pool, cfg):
            nb_raw = _raw_stereo(nb, pool, cfg)
            if nb_raw is not None:
                others.append((nb.frame, nb_raw.depth_m))
        depth = consistent_depth(item.frame, depth, others, cfg.stereo_consistency)
    confidence = np.where(depth > 0, raw.confidence, 0.0)
    return depth.astype(np.float64), confidence


def reconstruct(frames: list[PosedFrame], config: ReconstructConfig | None = None) -> Reconstruction:
    """Reconstruct a batch of posed frames (the whole batch is known, so stereo picks neighbours
    from all of it and hidden splats are pruned over every input view)."""
    cfg = config or ReconstructConfig()
    frames = list(frames)
    if not frames:
        raise ReconstructError("reconstruct needs at least one posed frame")
    for i, f in enumerate(frames):
        if not isinstance(f, PosedFrame):
            raise ReconstructError(f"frames[{i}] is a {type(f).__name__}, not a PosedFrame")
    local = LocalFrame.centred_on(frames[0].cam2world)
    items = [_Local(_to_local(f, local), i) for i, f in enumerate(frames)]
    rgb_mode = None if cfg.mode == "auto" else cfg.mode
    if cfg.mode == "auto":
        rgb = [f for f in frames if f.depth_m is None]
        rgb_mode = detect_mode(rgb, cfg) if rgb else None
    splat_map = SplatSet.empty()
    sphere_centre = None
    modes = [""] * len(frames)
    for item in items:
        mode = frame_mode(item.frame, item.index, cfg, rgb_mode)
        stereo = (None, None)
        if mode == "stereo":
            stereo = _stereo_depth(item, items, cfg)
            if stereo is None:
                log.warning("reconstruct: frame %d has no stereo neighbour with parallax; skipped", item.index)
                continue
        if mode == "sphere" and sphere_centre is None:
            sphere_centre = item.frame.cam2world[:3, 3].copy()
        depth, confidence = frame_depth(item.frame, mode, cfg, sphere_centre, *stereo)
        splat_map, _ = integrate(splat_map, item.frame, item.index, cfg, depth, confidence)
        modes[item.index] = mode
    views = [(it.frame.cam2world, it.frame.intrinsics) for it in items]
    unpruned = len(splat_map)
    if cfg.min_contribution > 0 and len(splat_map):
        splat_map = splat_map.select(prune_hidden(splat_map, views, cfg.min_contribution))
    hidden = unpruned - len(splat_map)
    splat_map = enforce_budget(splat_map, cfg, 0.0)
    if cfg.refit_iterations:
        splat_map = refit_colors(
            splat_map, [(it.frame.cam2world, it.frame.intrinsics, it.frame.image) for it in items], cfg.refit_iterations
        )
    if not len(splat_map) and cfg.unknown_depth != "skip":  # "skip" asks to drop pixels without depth
        if not any(modes):
            why = (
                "stereo found no neighbour frame with parallax for any frame (one frame, identical poses, or "
                "frames too small to match); give several RGB frames from different positions, or depth, or "
                "mode 'sphere'"
            )
        elif all(m == "stereo" for m in modes if m):
            why = (
                "stereo matched no pixel between the frames (featureless views, e.g. sky or a blank wall); give "
                "views that see textured parts of the scene from different positions, or depth"
            )
        else:
            why = "no pixel had usable depth (non-positive or absurdly far); check the depth maps and their units"
        raise ReconstructError(f"reconstruct made no Gaussians from {len(frames)} frame(s): {why}")
    stats = {
        "unpruned": unpruned,
        "hidden_pruned": hidden,
        "budget": budget_for(splat_map, cfg),
        "count": len(splat_map),
    }
    return Reconstruction(splat_map.to_gaussians(), local, modes, stats, splat_map)
