"""Viewpoint search: the paper's two-stage search over a pan-tilt rig's joints or a drone's 5-DoF.

::

    from aes_planner.search import SearchConfig, search_views

    cfg = SearchConfig.preset("balanced", mode=platform.kind, steps=30)  # fast | balanced; rig | drone
    result = search_views(scorer, inputs_cam2world, platform, cfg)   # [N, 4, 4] world poses
    best = result.suggestions[0]   # cam2world, pan_rad/tilt_rad (rig), position_m, yaw/pitch, score...

The loop is :mod:`aes_planner.search.pipeline`; the spaces (rig joints, a drone's 5 DoF) are
:mod:`aes_planner.search.space`; :class:`GroundTruthScorer` scores ground-truth renders of a
scene source; :func:`oracle_search` searches the whole feasible space on them (cached).
"""

from __future__ import annotations

from aes_planner.search.config import (
    DRONE_PLANNER_PRESETS,
    FREE_MODE_PRESETS,
    PLANNER_PRESETS,
    PRESETS,
    SearchConfig,
)
from aes_planner.search.ground_truth import GroundTruthScorer
from aes_planner.search.oracle import normalized, oracle_search
from aes_planner.search.pipeline import SearchError, SearchResult, Suggestion, search_views
from aes_planner.search.scorers import SCORERS, build_search_scorer

__all__ = [
    "DRONE_PLANNER_PRESETS",
    "FREE_MODE_PRESETS",
    "PLANNER_PRESETS",
    "PRESETS",
    "SCORERS",
    "GroundTruthScorer",
    "SearchConfig",
    "SearchError",
    "SearchResult",
    "build_search_scorer",
    "Suggestion",
    "normalized",
    "oracle_search",
    "search_views",
]
