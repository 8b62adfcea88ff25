"""The live localizer as a ROS 2 node (rclpy): the transport only, all else shared with the ROS 1 node.

Run by ``fingerloc-ros`` when ``ROS_VERSION=2`` (set by a ROS 2 installation's
``setup.bash``), with the parameters of :class:`~fingerloc.ros.live.NodeConfig`
given as ``--ros-args -p database:=places.sqlite -p scan_topics:=[scan]``.
Topics as in ROS 1: ``~/current_place`` (transient local, the ROS 2 form of
latched), ``~/posterior``, ``~/pose``; scans are subscribed with the sensor-data
profile (best effort), ``/tf_static`` transient local.
"""

from __future__ import annotations

import sys
from typing import Any

from ..errors import FingerlocError
from .live import LiveLocalizer, NodeConfig, StepTracker, load_tracker

__all__ = ["main", "run"]

#: Seconds between two looks at scans waiting for odometry.
POLL_PERIOD_S = 0.05


def _stamp(t: float) -> Any:
    from builtin_interfaces.msg import Time

    sec = int(t // 1)
    return Time(sec=sec, nanosec=min(round((t - sec) * 1e9), 999_999_999))


def main(argv: list[str] | None = None) -> None:
    """Entry point for ROS 2: read the parameters, load the database, spin."""
    try:
        import rclpy
        from rclpy.node import Node
    except ImportError:
        sys.stderr.write("error: rclpy is not importable: source your ROS 2 installation's setup.bash first\n")
        raise SystemExit(2) from None
    rclpy.init(args=[sys.argv[0], *(argv or [])])
    node = Node("fingerloc", allow_undeclared_parameters=True, automatically_declare_parameters_from_overrides=True)
    try:
        params = {name: p.value for name, p in node.get_parameters_by_prefix("").items()}
        config = NodeConfig.from_params(params)
        tracker = load_tracker(config)
    except FingerlocError as err:
        node.get_logger().fatal(str(err))
        sys.stderr.write(f"error: {' '.join(str(err).split())}\n")
        raise SystemExit(2) from None
    try:
        run(node, config, tracker)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def run(node: Any, config: NodeConfig, tracker: StepTracker, *, spin: bool = True) -> LiveLocalizer:
    """Wire ``node``'s subscriptions and publishers to a :class:`LiveLocalizer`; spin unless ``spin=False``."""
    import rclpy
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
    from sensor_msgs.msg import LaserScan
    from std_msgs.msg import String
    from tf2_msgs.msg import TFMessage

    from .handlers import MessageHandlers

    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pub_place = node.create_publisher(String, "~/current_place", latched)
    pub_answer = node.create_publisher(String, "~/posterior", 100)
    pub_pose = node.create_publisher(PoseWithCovarianceStamped, "~/pose", 100)
    log = node.get_logger()
    h = MessageHandlers(
        tracker,
        config,
        publish_place=lambda text: pub_place.publish(String(data=text)),
        publish_answer=lambda text: pub_answer.publish(String(data=text)),
        publish_pose=pub_pose.publish,
        pose_message=PoseWithCovarianceStamped,
        stamp=_stamp,
        warn=lambda text: log.warning(text, throttle_duration_sec=5.0),
    )
    node.create_subscription(TFMessage, "/tf", lambda m: h.transforms(m, False), 100)
    tf_static = QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(TFMessage, "/tf_static", lambda m: h.transforms(m, True), tf_static)
    if config.pose_source == "odom":
        node.create_subscription(Odometry, config.odom_topic, h.odometry, 100)
    for topic in config.scan_topics:
        node.create_subscription(LaserScan, topic, lambda m, topic=topic: h.scan(m, topic), qos_profile_sensor_data)
    node.create_timer(POLL_PERIOD_S, h.poll)
    log.info(f"fingerloc: {config.database}, {config.filter} filter; scans {', '.join(config.scan_topics)}")
    if spin:
        try:
            rclpy.spin(node)
        except KeyboardInterrupt:
            pass
    return h.localizer
