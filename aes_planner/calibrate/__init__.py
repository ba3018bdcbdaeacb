"""Calibration of a real rig: camera intrinsics from a printed board, the pan-tilt's kinematic
parameters from the gimbal's own sweep, and the camera's time offset (``aes-planner calibrate``;
docs/guides/calibration.md).

* :mod:`.board`: board specs, the printable pattern (and the sim's ``board:`` texture), corner
  detection in one canonical order.
* :mod:`.intrinsics`: OpenCV's calibration of a camera from board images, ROS camera_info out.
* :mod:`.rig`: the kinematic model's least squares on reprojection error (torch, float64), what
  it cannot observe, re-zeroing the tilt joint, comparing kinematics after rigid alignment.
* :mod:`.capture`: where views come from (the simulator, or a gimbal and a camera) and which
  joint poses to take them at.
* :mod:`.pipeline`: the runs behind ``calibrate rig`` (with ``--latency``) and ``calibrate verify``.
* :mod:`.simscene`: simulated set-ups (a board scene, rigs off their drawing) for tests and trials.
"""
