"""The novel-view protocol: input views and held-out target poses for training and evaluation.

Two kinds of input, as a camera gives them (the paper's protocol, 2-6 input views):

* ``rig`` -- a pan sweep across part of a pan-tilt rig's joint range, RGB only (a real rig has
  no depth; reconstruction runs in sphere mode). Targets: a continuous pan-tilt trajectory over
  the same pan span at other tilts, never an input pose.
* ``free`` -- a translating trajectory (a drone, a hand-held camera) with depth: the camera
  moves sideways ``0.6-1.4 m`` while slowly turning. Targets: the same path at other headings
  and heights.

Two more kinds take their inputs the way the product does, so the field also learns from what it
is later given:

* ``sweep`` -- a rig's survey sweep (:meth:`PanTilt.sweep`: the whole pan range, tilt zig-zagging),
  as ``aes-planner sim render`` writes it, the planner node explores and ``eval search`` feeds the
  search; depth on half of the samples (the simulator writes it, a real rig has none).
* ``survey`` -- free flight from a box around the rig's base (:meth:`Platform.free_box`, as ``eval
  search`` flies a rig scene): the sweep's directions from positions along the box's diagonal, or
  an arc inside the box looking across its centre (a drone scene's ``survey_poses``); with depth.

For these two the targets are drawn the way the search's stage 1 draws its candidates: points
along the slerp/lerp trajectory through the inputs, each jittered in direction by up to
``CANDIDATE_JITTER_FOV`` of the field of view (free: also shifted in position) -- the candidates
among which the search's argmax picks, where a field's small errors decide.

Training also asks for **search targets** (``n_search``): poses drawn the way the viewpoint search
queries the field -- anywhere in the rig's joint range (rig), or anywhere in a box around the
trajectory with headings up to 70 degrees off it (free). A field trained on trajectory targets
alone ranks the far corners of the search space poorly (measured: PLCC over a pan x tilt grid 0.57-0.74
against 0.78 along trajectories), and those corners are where the search's argmax lands.
Evaluation (``aes-planner eval field``) keeps to the trajectory, as the paper's protocol.

Every function takes a seeded ``numpy.random.Generator``, so a (scene, seed) pair always gives
the same poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aes_planner.config import require
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.geometry.poses import cam2world_to_view, view_to_cam2world
from aes_planner.geometry.trajectory import interpolate_poses
from aes_planner.platform import Platform, RigPlatform

__all__ = ["SOURCES", "ViewPlan", "plan_views"]

SOURCES = ("rig", "free", "sweep", "survey")
RIG_SOURCES = ("rig", "sweep")  # inputs a rig's joints take
CANDIDATE_JITTER_FOV = 0.35  # the search's direction jitter (SearchConfig.jitter_fov)


@dataclass
class ViewPlan:
    """Input and target poses (world cam2world, float64) and whether inputs carry depth."""

    inputs: np.ndarray  # [V, 4, 4]
    targets: np.ndarray  # [T, 4, 4], along a trajectory (consecutive poses are neighbours)
    depth: bool
    search_targets: np.ndarray | None = None  # [S, 4, 4], spread over the search space (no order)


def _rig_plan(platform: Platform, n_views: int, n_targets: int, n_search: int, rng: np.random.Generator) -> ViewPlan:
    pt = PanTilt(platform.rig)
    (plo, phi), (tlo, thi) = pt.pan_limits_rad, pt.tilt_limits_rad
    span = min(rng.uniform(np.radians(50), np.radians(110)), phi - plo)
    centre = rng.uniform(plo + span / 2, phi - span / 2)
    tilt0 = float(np.clip(rng.uniform(np.radians(-20), np.radians(10)), tlo, thi))
    pans = centre + np.linspace(-span / 2, span / 2, n_views) if n_views > 1 else np.array([centre])
    tilts = np.clip(tilt0 + rng.uniform(-np.radians(4), np.radians(4), n_views), tlo, thi)
    s = np.linspace(0.0, 1.0, n_targets)
    t_pans = centre + span * (s - 0.5) * 0.9
    t_tilts = np.clip(
        tilt0 + np.radians(7) * np.sin(2 * np.pi * s * rng.uniform(0.7, 1.5) + rng.uniform(0, 6.3)), tlo, thi
    )
    plan = ViewPlan(pt.forward(pans, tilts), pt.forward(t_pans, t_tilts), depth=False)
    if n_search:  # the whole joint range, as the search samples it (drawn after the trajectory: same seeds, same plan)
        plan.search_targets = pt.forward(rng.uniform(plo, phi, n_search), rng.uniform(tlo, thi, n_search))
    return plan


def _free_plan(platform: Platform, n_views: int, n_targets: int, n_search: int, rng: np.random.Generator) -> ViewPlan:
    if isinstance(platform, RigPlatform):  # near the rig: a path through its camera's place
        pt = PanTilt(platform.rig)
        (plo, phi), _ = pt.pan_limits_rad, pt.tilt_limits_rad
        centre = pt.forward(0.0, 0.0)[:3, 3]
        heading = pt.forward(rng.uniform(0.6 * plo, 0.6 * phi), 0.0)[:3, 2]
        yaw0 = float(np.arctan2(heading[1], heading[0]))
        lo, hi = centre - np.array([0.5, 0.5, 0.3]), centre + np.array([0.5, 0.5, 0.3])
    else:
        box = platform.drone
        lo, hi = np.asarray(box.bounds_min_m), np.asarray(box.bounds_max_m)
        centre = (lo + hi) / 2
        yaw0 = rng.uniform(-np.pi, np.pi)
    length = rng.uniform(0.6, 1.4)
    side = np.array([-np.sin(yaw0), np.cos(yaw0), 0.0])  # left of the heading
    start = np.clip(centre + rng.uniform(-0.3, 0.3, 3) * [1, 1, 0.5], lo, hi)
    turn = rng.uniform(-0.5, 0.5)  # rad over the path
    pitch0 = rng.uniform(np.radians(-15), np.radians(5))

    def at(s: np.ndarray, dyaw: np.ndarray, dpitch: np.ndarray, dz: np.ndarray) -> np.ndarray:
        xyz = start[None] + (s[:, None] - 0.5) * length * side[None] + dz[:, None] * np.array([0, 0, 1.0])
        views = np.concatenate(
            [xyz, (yaw0 + turn * (s - 0.5) + dyaw)[:, None], np.clip(pitch0 + dpitch, -1.2, 1.2)[:, None]], 1
        )
        return view_to_cam2world(views)

    s_in = np.linspace(0, 1, n_views) if n_views > 1 else np.array([0.5])
    zeros = np.zeros(n_views)
    inputs = at(s_in, rng.uniform(-0.05, 0.05, n_views), zeros, zeros)
    s = np.linspace(0.02, 0.98, n_targets)
    phase = rng.uniform(0, 6.3)
    targets = at(
        s,
        np.radians(10) * np.sin(2 * np.pi * 1.1 * s + phase),
        np.radians(5) * np.sin(2 * np.pi * 0.8 * s + 1.3 * phase),
        0.1 * np.sin(2 * np.pi * 0.6 * s + phase),
    )
    plan = ViewPlan(inputs, targets, depth=True)
    if n_search:  # anywhere near the path, headings well off it (the search's neighbours and refinement)
        s = rng.uniform(-0.1, 1.1, n_search)
        views = np.concatenate(
            [
                np.clip(
                    start[None]
                    + (s[:, None] - 0.5) * length * side[None]
                    + rng.uniform(-0.3, 0.3, (n_search, 3)) * [1, 1, 0.5],
                    lo,
                    hi,
                ),
                (yaw0 + turn * (s - 0.5) + rng.uniform(-1.2, 1.2, n_search))[:, None],
                rng.uniform(np.radians(-45), np.radians(20), n_search)[:, None],
            ],
            1,
        )
        plan.search_targets = view_to_cam2world(views)
    return plan


def _along(inputs: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:  # [V, 4, 4] -> [n, 4, 4]
    """``n`` poses at sorted random points of the slerp/lerp trajectory through ``inputs``."""
    if len(inputs) == 1:
        return np.repeat(inputs, n, axis=0)
    dense = interpolate_poses(inputs, 32)  # [(V - 1) * 32 + 1, 4, 4]
    return dense[np.sort(rng.integers(0, len(dense), n))]


def _sweep_plan(platform: Platform, n_views: int, n_targets: int, n_search: int, rng: np.random.Generator) -> ViewPlan:
    pt = PanTilt(platform.rig)
    (plo, phi), (tlo, thi) = pt.pan_limits_rad, pt.tilt_limits_rad
    joints = pt.sweep(n_views)  # [V, 2]
    inputs = pt.forward(joints[:, 0], joints[:, 1])
    jitter = CANDIDATE_JITTER_FOV * platform.intrinsics.hfov_rad
    pos = np.sort(rng.uniform(0, n_views - 1, n_targets))  # along the sweep, in joint space (a rig's slerp)
    pans, tilts = (np.interp(pos, np.arange(n_views), joints[:, k]) for k in (0, 1))  # [T] each
    pans = np.clip(pans + rng.uniform(-jitter, jitter, n_targets), plo, phi)
    tilts = np.clip(tilts + rng.uniform(-jitter, jitter, n_targets), tlo, thi)
    plan = ViewPlan(inputs, pt.forward(pans, tilts), depth=bool(rng.random() < 0.5))
    if n_search:
        plan.search_targets = pt.forward(rng.uniform(plo, phi, n_search), rng.uniform(tlo, thi, n_search))
    return plan


def _survey_plan(platform: Platform, n_views: int, n_targets: int, n_search: int, rng: np.random.Generator) -> ViewPlan:
    box = platform.free_box()
    if isinstance(platform, RigPlatform):  # the rig's survey directions
        pt = PanTilt(platform.rig)
        sweep = pt.sweep(n_views)
        yaw_pitch = cam2world_to_view(pt.forward(sweep[:, 0], sweep[:, 1]))[:, 3:]  # [V, 2]
    else:
        yaw_pitch = np.stack([rng.uniform(-np.pi, np.pi, n_views), np.full(n_views, np.radians(-10))], 1)
    lo, hi = np.asarray(box.bounds_min_m), np.asarray(box.bounds_max_m)
    if rng.random() < 0.5:  # along the box's horizontal diagonal at mid height, the sweep's directions
        inputs = view_to_cam2world(np.concatenate([box.diagonal_positions_m(n_views), yaw_pitch], 1))
    else:  # a drone scene's survey: an arc a quarter of the way in, looking back across the centre
        inputs = box.survey_poses(n_views)
    jitter = CANDIDATE_JITTER_FOV * platform.intrinsics.hfov_rad
    views = cam2world_to_view(_along(inputs, n_targets, rng))  # [T, 5]
    views[:, :3] = np.clip(views[:, :3] + rng.uniform(-0.15, 0.15, (n_targets, 3)) * (hi - lo), lo, hi)
    views[:, 3:] += rng.uniform(-jitter, jitter, (n_targets, 2))
    views[:, 4] = np.clip(views[:, 4], -1.2, 1.2)
    plan = ViewPlan(inputs, view_to_cam2world(views), depth=True)
    if n_search:  # anywhere in the box, any heading
        plan.search_targets = view_to_cam2world(
            np.concatenate(
                [
                    rng.uniform(lo, hi, (n_search, 3)),
                    rng.uniform(-np.pi, np.pi, (n_search, 1)),
                    rng.uniform(np.radians(-45), np.radians(20), (n_search, 1)),
                ],
                1,
            )
        )
    return plan


def plan_views(
    platform: Platform, source: str, n_views: int, n_targets: int, rng: np.random.Generator, n_search: int = 0
) -> ViewPlan:
    """Input poses, a target trajectory and ``n_search`` search targets for one scene (see the
    module docstring)."""
    require(source in SOURCES, "source", f"must be one of {list(SOURCES)}, got {source!r}")
    require(n_views >= 1 and n_targets >= 1, "n_views", f"need >= 1 input and target, got {n_views}, {n_targets}")
    require(n_search >= 0, "n_search", f"must be >= 0, got {n_search}")
    require(
        source not in RIG_SOURCES or isinstance(platform, RigPlatform),
        "source",
        f"{source!r} inputs need a scene with a pan-tilt rig; use --source free",
    )
    return _PLANS[source](platform, n_views, n_targets, n_search, rng)


_PLANS = {"rig": _rig_plan, "free": _free_plan, "sweep": _sweep_plan, "survey": _survey_plan}
