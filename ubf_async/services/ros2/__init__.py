"""A ROS 2 bridge speaking rmw_zenoh's wire format, with no ROS installation (issue 27).

Scope: this subpackage, and nothing else of the framework, knows ROS 2.

* :mod:`~ubf_async.services.ros2.keys` — rmw_zenoh's key expressions (data keys,
  ``@ros2_lv`` liveliness tokens with their QoS field), the 33-byte attachment and publisher
  GIDs;
* :mod:`~ubf_async.services.ros2.messages` — CDR payloads and type hashes per distro (Humble,
  Jazzy, Kilted) through ``rosbags``' type stores, and the unit conversions (REP-103/105);
* :mod:`~ubf_async.services.ros2.bridge` — the
  :class:`~ubf_async.services.ros2.bridge.Ros2Bridge` component: the robot's drive command,
  odometry, range finders, camera, trace and clock out as ROS 2 topics;
  ``geometry_msgs/msg/Twist`` on ``cmd_vel_in`` in as a remote vote;
* ``python -m ubf_async.ros2`` (:mod:`ubf_async.tools.ros2`) — the bridge as a process of its
  own (docs/ros2.md); a robot file's ``ros2:`` section has ``launch`` run it in-process instead.

A service (:mod:`ubf_async.services`): it imports the rooms below it (the bus, components,
the wire, the robot file's ``ros2:`` spec, remote votes), never a tool; nothing of the framework
below it imports it, and it imports no component, simulator or OpenCV (``lint-imports``).
"""
