"""``Reconstructor``: posed frames in, a budgeted set of Gaussians out, one frame at a time.

Read top to bottom: :func:`detect_mode` (what the frames carry), :func:`parallax_px` (the
rotation-versus-translation test), the :class:`Reconstructor` (``add_frame`` -> depth for the
frame -> splats -> dedupe into the map -> prune -> budget), and :func:`reconstruct` (a batch of
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

__all__ = ["Reconstruction", "Reconstructor", "detect_mode", "parallax_px", "reconstruct"]

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
        """``min(max_gaussians, ceil(budget_ratio x samples))``: samples are the stride blocks the
        deduplicated scene holds, a measure of its extent as the views see it."""
        cfg = self.config
        if cfg.budget_ratio <= 0:
            return cfg.max_gaussians
        return int(min(cfg.max_gaussians, max(1, math.ceil(cfg.budget_ratio * float(self._map.samples.sum())))))

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
        self._enforce_budget(self.config.budget_slack)
        return added

    def render(self, cam2world: np.ndarray, intrinsics: Intrinsics, background=None) -> RasterOutput:
        """Render the current map at a **world** pose ``[4, 4]``."""
        if self.local_frame is None:
            raise ReconstructError("nothing to render yet: add a frame first")
        return render_local(self.gaussians, self.local_frame.pose_to_local(cam2world), intrinsics, background)

    # ------------------------------------------------------------------ modes
    def _mode_for(self, item: _Local) -> str:
        f = item.frame
        if self.config.mode == "depth" and f.depth_m is None:
            raise ReconstructError(
                f"frame {item.index} has no depth but mode='depth'; use mode='auto' (or 'stereo'/'sphere') for RGB frames"
            )
        if f.depth_m is not None and self.config.mode in ("auto", "depth"):
            return "depth"
        if self._rgb_mode is None:  # auto: decide once, from the first frames that overlap
            candidates = [r.frame for r in self._recent] + [f]
            if len(candidates) >= 2:
                self._rgb_mode = detect_mode(candidates, self.config)
                log.info(
                    "reconstruct: RGB frames %s (parallax %.2f px at %.1f m)",
                    "translate: stereo" if self._rgb_mode == "stereo" else "rotate: sphere",
                    parallax_px(candidates, self.config.nominal_depth_m),
                    self.config.nominal_depth_m,
                )
            else:
                return "wait"  # one RGB frame cannot tell rotation from translation
        return self._rgb_mode

    # ------------------------------------------------------------------ integration
    def _params(self, frame: PosedFrame) -> SplatParams:
        c = self.config
        return SplatParams(
            c.stride_for(frame.width), c.scale_factor, c.flatness, c.max_stretch, c.opacity, c.edge_rel, c.edge_ratio
        )

    def _integrate(
        self, item: _Local, mode: str, depth: np.ndarray | None = None, confidence: np.ndarray | None = None
    ) -> int:
        f = item.frame
        cfg = self.config
        if mode == "sphere":
            if self._sphere_centre is None:
                self._sphere_centre = f.cam2world[:3, 3].copy()
            depth = ray_sphere_depth(f.intrinsics, f.cam2world, self._sphere_centre, cfg.sphere_radius_m)
        elif mode == "depth":
            depth = f.depth_m.astype(np.float64)
        policy = cfg.unknown_depth if cfg.unknown_depth != "auto" else ("fill" if mode == "stereo" else "far")
        if mode != "sphere" and depth is not None:
            unknown = depth <= 0
            if unknown.any() and policy == "far":
                far = ray_sphere_depth(f.intrinsics, f.cam2world, np.zeros(3), cfg.far_radius_m)
                depth = np.where(unknown, far, depth)
            elif unknown.any() and policy == "fill":
                depth = fill_inverse_depth(depth)
                if confidence is not None:
                    confidence = np.where(unknown & (depth > 0), FILL_CONFIDENCE, confidence)
        params = self._params(f)
        new = splats_from_depth(f.image, depth, f.intrinsics, f.cam2world, params, item.index, confidence)
        new = sharpen_colors(new, f.image, f.intrinsics, f.cam2world, params.stride, cfg.sharpen_iterations)
        if cfg.dedupe:
            keep_old, keep_new = dedupe(self._map, new, cfg.merge_cell_factor, cfg.merge_margin)
            new = new.select(keep_new)
            self._map = self._map.select(keep_old)
        self._map = SplatSet.cat([self._map, new])
        self._map = self._map.select(self._map.opacities >= cfg.min_opacity)
        self.mode_counts[mode] += 1
        self.last_modes.append(mode)
        return len(new)

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

    # ------------------------------------------------------------------ budget
    def _enforce_budget(self, slack: float) -> None:
        budget = self.budget
        if len(self._map) > budget:
            target = max(1, int(budget * (1.0 - slack)))
            before = len(self._map)
            self._map = coarsen(self._map, target, self.config.scale_factor)
            log.debug("budget %d: merged %d -> %d Gaussians", budget, before, len(self._map))


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
    rec = Reconstructor(cfg)
    rec.local_frame = LocalFrame.centred_on(frames[0].cam2world)
    items = [_Local(_to_local(f, rec.local_frame), i) for i, f in enumerate(frames)]
    rec.frames_added = len(frames)
    if cfg.mode == "auto":
        rgb = [f for f in frames if f.depth_m is None]
        rec._rgb_mode = detect_mode(rgb, cfg) if rgb else None
    modes = [""] * len(frames)
    for item in items:
        mode = rec._mode_for(item)
        if mode == "stereo":
            depth = _stereo_depth(item, items, cfg)
            if depth is None:
                log.warning("reconstruct: frame %d has no stereo neighbour with parallax; skipped", item.index)
                continue
            rec._integrate(item, "stereo", *depth)
        else:
            rec._integrate(item, mode)
        modes[item.index] = mode
    views = [(it.frame.cam2world, it.frame.intrinsics) for it in items]
    unpruned = len(rec._map)
    if cfg.min_contribution > 0 and len(rec._map):
        rec._map = rec._map.select(prune_hidden(rec._map, views, cfg.min_contribution))
    hidden = unpruned - len(rec._map)
    rec._enforce_budget(0.0)
    if cfg.refit_iterations:
        rec._map = refit_colors(
            rec._map, [(it.frame.cam2world, it.frame.intrinsics, it.frame.image) for it in items], cfg.refit_iterations
        )
    if not len(rec._map) and cfg.unknown_depth != "skip":  # "skip" asks to drop pixels without depth
        if not any(modes):
            why = (
                "stereo found no neighbour frame with parallax for any frame (one frame, identical poses, or "
                "frames too small to match); give several RGB frames from different positions, or depth, or "
                "mode 'sphere'"
            )
        else:
            why = "no pixel had usable depth (non-positive or absurdly far); check the depth maps and their units"
        raise ReconstructError(f"reconstruct made no Gaussians from {len(frames)} frame(s): {why}")
    stats = {"unpruned": unpruned, "hidden_pruned": hidden, "budget": rec.budget, "count": len(rec._map)}
    return Reconstruction(rec.gaussians, rec.local_frame, modes, stats, rec.splats)
