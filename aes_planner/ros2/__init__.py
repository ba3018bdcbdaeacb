"""ROS 2 interop with no ROS installation: a DDS bridge and rosbag2 export.

* :mod:`aes_planner.ros2.idl`: the ROS 2 message types as Cyclone DDS IDL structs with ROS 2's
  wire names (``rt/<topic>``, ``<pkg>::msg::dds_::<Type>_``, plain CDR / XCDR1).
* :mod:`aes_planner.ros2.convert`: the package's messages <-> ROS 2 messages (shared by the
  bridge and the bag export).
* :mod:`aes_planner.ros2.dds`: domain, discovery range and QoS as rmw_cyclonedds does them.
* :mod:`aes_planner.ros2.bridge`: the ``ros2_bridge`` node; :mod:`aes_planner.ros2.inbound`
  its ROS 2 rig side; :mod:`aes_planner.ros2.links` the rig as tf links.
* :mod:`aes_planner.ros2.bag`: ``aes-planner export rosbag2``.

Needs the ``ros2`` extra (``pip install aes-planner[ros2]``); ``import aes_planner`` does not.
"""
