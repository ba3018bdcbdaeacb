"""The pan-tilt rig as tf links: which transforms are fixed (``/tf_static``) and which move with
the joints (``/tf``), composed exactly as :class:`aes_planner.geometry.pantilt.PanTilt` chains them::

    world --static--> base --Rz(pan)--> pan --T(tilt_offset) Ry(-tilt)--> tilt
          --static T(lever_arm)--> camera_link --static BODY_TO_OPTICAL Rz(roll)--> camera_optical

``camera_link`` is a REP-103 body frame (x forward, y left, z up); ``camera_optical`` is the
OpenCV frame the package's poses use.
"""

from __future__ import annotations

import numpy as np

from aes_planner.geometry.rig import PanTiltConfig
from aes_planner.geometry.rotations import rot_y, rot_z

__all__ = ["RigLinks"]


def _rotation(r: np.ndarray) -> np.ndarray:  # [3, 3] -> [4, 4]
    m = np.eye(4)
    m[:3, :3] = r
    return m


def _t(xyz) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = xyz
    return m


class RigLinks:
    """The link transforms of a :class:`PanTiltConfig` rig (all ``child2parent`` ``[4, 4]``)."""

    def __init__(self, config: PanTiltConfig):
        from aes_planner.geometry.pantilt import PanTilt

        self.kinematics = PanTilt(config)
        k = self.kinematics
        self.base2world = k.base2world.copy()
        self.link2tilt = _t(k.lever_arm)
        self.optical2link = np.eye(4)
        self.optical2link[:3, :3] = k.body_to_camera

    def pan2base(self, pan_rad: float) -> np.ndarray:
        return _rotation(rot_z(pan_rad))

    def tilt2pan(self, tilt_rad: float) -> np.ndarray:
        return _t(self.kinematics.tilt_offset) @ _rotation(rot_y(-tilt_rad))

    def cam2world(self, pan_rad: float, tilt_rad: float) -> np.ndarray:
        """The composed chain (equals ``PanTilt.forward``; a test checks it)."""
        return self.base2world @ self.pan2base(pan_rad) @ self.tilt2pan(tilt_rad) @ self.link2tilt @ self.optical2link

    def static_transforms(self, c, stamp_s: float) -> list:
        """world -> base, tilt -> camera_link, camera_link -> camera_optical (``c``: the bridge config)."""
        from aes_planner.ros2.convert import transform_stamped

        base, _, tilt, link = c.rig_frames
        return [
            transform_stamped(c.world_frame, base, self.base2world, stamp_s),
            transform_stamped(tilt, link, self.link2tilt, stamp_s),
            transform_stamped(link, c.camera_frame, self.optical2link, stamp_s),
        ]

    def joint_transforms(self, c, pan_rad: float, tilt_rad: float, stamp_s: float) -> list:
        """base -> pan and pan -> tilt at the joints' stamp."""
        from aes_planner.ros2.convert import transform_stamped

        base, pan, tilt, _ = c.rig_frames
        return [
            transform_stamped(base, pan, self.pan2base(pan_rad), stamp_s),
            transform_stamped(pan, tilt, self.tilt2pan(tilt_rad), stamp_s),
        ]
