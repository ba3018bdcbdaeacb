"""Flying a real drone over MAVLink (PX4 offboard, ArduPilot guided, gimbal protocol v2).

* :mod:`~aes_planner.drone.frames`: local NED / body FRD <-> the package's ENU world and OpenCV
  camera (the conversions happen there, once);
* :mod:`~aes_planner.drone.safety`: the gate every setpoint passes (box, speed, finiteness);
* :mod:`~aes_planner.drone.node`: the ``mavlink_drone`` node (telemetry in, setpoints out);
* :mod:`~aes_planner.drone.camera`: a sim camera rendering the pose the vehicle reports;
* :mod:`~aes_planner.drone.emulator`: a PX4-like MAVLink vehicle for dry runs and tests.

pymavlink is imported where used (the ``drone`` extra).
"""
