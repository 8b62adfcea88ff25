"""What the ROS 1 and ROS 2 nodes share: messages in, a :class:`~fingerloc.ros.live.LiveLocalizer`, messages out.

A node creates its publishers and subscriptions with its own client library
(rospy, rclpy) and hands every message to one :class:`MessageHandlers`. The
handlers convert the message, feed the localizer under one lock (callbacks
may come from several threads) and turn a :class:`~fingerloc.errors.FingerlocError`
of one message (a malformed scan, an odometry jump) into a throttled warning:
the node goes on with the next message.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from ..errors import FingerlocError
from .convert import answer_json, fill_pose_with_covariance, odometry_from_msg, scan_from_msg, transforms_from_msg
from .live import LiveLocalizer, NodeConfig, StepTracker

__all__ = ["MessageHandlers"]


class MessageHandlers:
    """The callbacks of a fingerloc node, around one :class:`LiveLocalizer`.

    Parameters
    ----------
    tracker : StepTracker
    config : NodeConfig
    publish_place : callable
        ``publish_place(text)``: the best place's label (``~current_place``), at the first answer and on change.
    publish_answer : callable
        ``publish_answer(text)``: every answer as one line of JSON (``~posterior``).
    publish_pose : callable
        ``publish_pose(msg)``: a filled ``geometry_msgs/PoseWithCovarianceStamped`` (``~pose``).
    pose_message : callable
        Makes an empty ``PoseWithCovarianceStamped`` of the node's client library.
    stamp : callable
        Seconds (float) to the client library's header stamp.
    warn : callable
        Gets one line per message that could not be used (the node throttles it).
    """

    def __init__(
        self,
        tracker: StepTracker,
        config: NodeConfig,
        *,
        publish_place: Callable[[str], Any],
        publish_answer: Callable[[str], Any],
        publish_pose: Callable[[Any], Any],
        pose_message: Callable[[], Any],
        stamp: Callable[[float], Any],
        warn: Callable[[str], Any],
    ) -> None:
        def pose(ans: Any) -> None:
            msg = pose_message()
            msg.header.stamp = stamp(float(ans.stamp or 0.0))
            msg.header.frame_id = config.map_frame
            fill_pose_with_covariance(msg.pose, ans.pose, ans.covariance)
            publish_pose(msg)

        self.localizer = LiveLocalizer(
            tracker,
            config,
            on_place=lambda place: publish_place(str(place)),
            on_answer=lambda ans: publish_answer(answer_json(ans)),
            on_pose=pose,
        )
        self._warn = warn
        self._lock = threading.Lock()

    def _guarded(self, what: str, fn: Callable[[], Any]) -> None:
        with self._lock:
            try:
                fn()
            except FingerlocError as err:
                self._warn(f"{what}: {err}")

    def scan(self, msg: Any, topic: str) -> None:
        """A ``sensor_msgs/LaserScan`` on ``topic``."""

        def go() -> None:
            scan, frame = scan_from_msg(msg)
            self.localizer.scan(topic, scan, frame)

        self._guarded(f"scan on {topic}", go)

    def odometry(self, msg: Any) -> None:
        """A ``nav_msgs/Odometry``."""

        def go() -> None:
            t, pose, _, child = odometry_from_msg(msg)
            self.localizer.odometry(t, pose, child)

        self._guarded("odometry", go)

    def transforms(self, msg: Any, static: bool) -> None:
        """A ``tf2_msgs/TFMessage`` of ``/tf`` (``static=False``) or ``/tf_static``."""
        self._guarded("/tf_static" if static else "/tf", lambda: self.localizer.transforms(transforms_from_msg(msg),
                                                                                           static=static))  # fmt: skip

    def poll(self) -> None:
        """The scans whose wait for odometry is over (call it from a timer)."""
        self._guarded("timer", self.localizer.poll)
