"""The novel-view protocol: input views and held-out target poses for training and evaluation.

Two kinds of input, as a camera gives them (the paper's protocol, 2-6 input views):

* ``rig`` -- a pan sweep across part of a pan-tilt rig's joint range, RGB only (a real rig has
  no depth; reconstruction runs in sphere mode). Targets: a continuous pan-tilt trajectory over
  the same pan span at other tilts, never an input pose.
* ``free`` -- a translating trajectory (a drone, a hand-held camera) with depth: the camera
  moves sideways ``0.6-1.4 m`` while slowly turning. Targets: the same path at other headings
  and heights.

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
from aes_planner.geometry.poses import view_to_cam2world
from aes_planner.sources import Platform

__all__ = ["SOURCES", "ViewPlan", "plan_views"]

SOURCES = ("rig", "free")


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
    if platform.kind == "rig":
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


def plan_views(
    platform: Platform, source: str, n_views: int, n_targets: int, rng: np.random.Generator, n_search: int = 0
) -> ViewPlan:
    """Input poses, a target trajectory and ``n_search`` search targets for one scene (see the
    module docstring)."""
    require(source in SOURCES, "source", f"must be one of {list(SOURCES)}, got {source!r}")
    require(n_views >= 1 and n_targets >= 1, "n_views", f"need >= 1 input and target, got {n_views}, {n_targets}")
    require(n_search >= 0, "n_search", f"must be >= 0, got {n_search}")
    if source == "rig":
        require(platform.kind == "rig", "source", "'rig' inputs need a scene with a pan-tilt rig; use --source free")
        return _rig_plan(platform, n_views, n_targets, n_search, rng)
    return _free_plan(platform, n_views, n_targets, n_search, rng)
