"""The launch's simulated scene, for the node types that take one (``scene:`` in a launch file).

The graph carries only the scene's spec (:attr:`aes_planner.graph.base.LaunchContext.scene`) and
never imports the simulator; a node type that needs the scene (a sim camera, a gimbal taking the
rig's limits, a planner taking its platform) loads it here, once per launch, and every other node
of the launch shares the same object.
"""

from __future__ import annotations

from aes_planner.graph.base import LaunchContext, NodeError

__all__ = ["launch_scene"]


def launch_scene(context: LaunchContext):
    """The :class:`aes_planner.sim.Scene` of ``context`` (loaded on first use, then shared);
    :class:`NodeError` when the launch names none."""
    if context.loaded_scene is None:
        if context.scene is None:
            raise NodeError(
                "this node needs a simulated scene: add 'scene: FAMILY:SEED' (or a scene file) to the launch file"
            )
        from aes_planner.sim import load_scene

        context.loaded_scene = load_scene(context.scene)
    return context.loaded_scene
