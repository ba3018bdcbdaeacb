"""Procedural scene families: ``FAMILIES[name](seed) -> SceneSpec``, seeded and reproducible.

``load_scene("indoor:3")`` builds family ``indoor`` with seed 3. Each family places a pan-tilt
rig whose sweep over its joint range sees both strong views (distinct subjects, lines,
clutter) and weak ones (bare walls, floor, sky), so that where the camera points matters.

* ``indoor``: a furnished room with a window, paintings, plants, shelves, a sofa.
* ``outdoor``: ground, horizon, hills, trees, a house, a fence, a pond.
* ``tabletop``: a still life on a table against a wall.
* ``gallery``: a wall of framed works under a skylight, a sculpture, a bench.
"""

from __future__ import annotations

from collections.abc import Callable

from aes_planner.sim.families.gallery import gallery
from aes_planner.sim.families.indoor import indoor
from aes_planner.sim.families.outdoor import outdoor
from aes_planner.sim.families.tabletop import tabletop
from aes_planner.sim.spec import SceneSpec

FAMILIES: dict[str, Callable[[int], SceneSpec]] = {
    "indoor": indoor,
    "outdoor": outdoor,
    "tabletop": tabletop,
    "gallery": gallery,
}

__all__ = ["FAMILIES"]
