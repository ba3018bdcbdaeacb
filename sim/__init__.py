"""The synthetic camera simulator: scenes, an exact ray-cast renderer and a sim camera.

Installed as ``aes_planner.sim``. It depends on :mod:`aes_planner.geometry`,
:mod:`aes_planner.config` and :mod:`aes_planner.messages`, never the other way round.

* :func:`load_scene` (``"indoor:3"`` or a YAML path) -> :class:`Scene`; the format is in
  ``sim/README.md``; :func:`scene_to_yaml` writes any scene back.
* :func:`render` (scene, cam2world, intrinsics) -> :class:`RenderOutput` (RGB, depth, ids).
* :class:`SimCamera` renders :class:`~aes_planner.messages.PosedFrame` records from poses or
  rig joint angles, with optional pixel noise, pose noise and latency.
* :class:`SimSource`: a scene as an :class:`~aes_planner.sources.SceneSource` (frames and
  ground truth at any pose, for training and evaluation).
* :func:`render_survey`: a scene from survey poses, saved as a dataset folder.
* :data:`FAMILIES`: the procedural scene families (``indoor``, ``outdoor``, ``tabletop``,
  ``gallery``), each a function ``seed -> SceneSpec``.
"""

from aes_planner.sim.camera import SimCamera, SimCameraConfig
from aes_planner.sim.families import FAMILIES
from aes_planner.sim.raycast import RenderError, RenderOutput, render
from aes_planner.sim.scene import Scene, SceneError, load_scene, save_scene, scene_to_yaml
from aes_planner.sim.source import SimSource, platform_of
from aes_planner.sim.spec import CameraSpec, DroneSpec, RigSpec, SceneSpec
from aes_planner.sim.survey import render_survey

__all__ = [
    "FAMILIES",
    "CameraSpec",
    "DroneSpec",
    "RenderError",
    "RenderOutput",
    "RigSpec",
    "Scene",
    "SceneError",
    "SceneSpec",
    "SimCamera",
    "SimCameraConfig",
    "SimSource",
    "load_scene",
    "platform_of",
    "render",
    "render_survey",
    "save_scene",
    "scene_to_yaml",
]
