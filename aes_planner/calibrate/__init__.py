"""Calibration of a real rig: camera intrinsics from a printed board, the pan-tilt's kinematic
parameters from the gimbal's own sweep, and the camera's time offset (``aes-planner calibrate``).

* :mod:`.board`: board specs, the printable pattern, corner detection in canonical order.
* :mod:`.intrinsics`: OpenCV's calibration of a camera from board images, ROS camera_info out.
* :mod:`.rig`: the kinematic model's least squares on reprojection error (torch, float64).
* :mod:`.capture`: where rig views come from (the simulator, or a gimbal and a camera).
* :mod:`.latency`: the camera's delay behind the joint states, from a continuous sweep.
"""
