"""Photos without poses: a folder of ordinary photos made into the package's posed-frame folder.

* :func:`pose_images` (:mod:`aes_planner.photos.sfm`): structure from motion with pycolmap
  (COLMAP's bindings), levelled, metric when the user gives a scale; writes ``cameras.json`` and a
  nerfstudio ``transforms.json``. pycolmap is imported there, when the pose step runs: ``import
  aes_planner`` works without it.
* :func:`relative_move` (:mod:`aes_planner.photos.relative`): a suggestion said from the nearest
  input photo ("from IMG_0042.jpg: 0.6 m right, turn 12 deg left").
* :func:`pose_errors` (:mod:`aes_planner.photos.align`): recovered poses against known ones after a
  similarity (Umeyama) alignment.
* :mod:`aes_planner.photos.simscene`: photo-textured sim scenes and hand-held arcs, for tests and
  the ``bench photos`` figure.

The hand-held camera's search space is :class:`aes_planner.platform.HandHeldPlatform`: the region
the photographer walked, around the registered cameras with a stated margin.
"""

from aes_planner.photos.align import PoseErrors, pose_errors, umeyama
from aes_planner.photos.relative import RelativeMove, moves_from_photos, nearest_photo, relative_move
from aes_planner.photos.sfm import MIN_REGISTERED, PoseConfig, PoseError, PoseResult, list_images, pose_images

__all__ = [
    "MIN_REGISTERED",
    "PoseConfig",
    "PoseError",
    "PoseErrors",
    "PoseResult",
    "RelativeMove",
    "list_images",
    "moves_from_photos",
    "nearest_photo",
    "pose_errors",
    "pose_images",
    "relative_move",
    "umeyama",
]
