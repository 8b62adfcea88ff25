"""The live localizer on a robot: a ROS node (ROS 1 or ROS 2) around the streaming tracker.

* :mod:`.convert`: ROS messages <-> fingerloc values (shared by both ROS versions);
* :mod:`.live`: the robot side without a ROS library (scans merged in the base
  frame, odometry at each scan's stamp, rate limit; answers to publishers);
* :mod:`.node` (ROS 1, rospy) and :mod:`.node2` (ROS 2, rclpy): the transports,
  the ``fingerloc-ros`` command.

Nothing here imports a ROS library at module level.
"""
