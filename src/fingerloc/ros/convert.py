"""ROS messages <-> fingerloc values, the same for ROS 1 (rospy), ROS 2 (rclpy) and rosbags' message classes.

Messages are read and filled by their field names, which the three share;
only time stamps differ (``secs``/``nsecs`` in ROS 1, ``sec``/``nanosec`` in
ROS 2), and :func:`stamp_seconds` reads both. Nothing here imports a ROS
library: the transports (:mod:`fingerloc.ros.node`, :mod:`fingerloc.ros.node2`)
build the message objects and hand them over.

Inputs: ``sensor_msgs/LaserScan`` (:func:`scan_from_msg`, the bag reader's
rules: bearings increasing, beams past one turn dropped, readings outside
``[range_min, range_max]`` no return), ``nav_msgs/Odometry``
(:func:`odometry_from_msg`) and ``tf2_msgs/TFMessage`` (:func:`transforms_from_msg`).

Outputs: the pose of an answer as ``geometry_msgs/PoseWithCovariance``
fields (:func:`fill_pose_with_covariance`: the planar pose at ``z = 0``, its
3x3 covariance over ``(x, y, theta)`` placed in the 6x6 matrix over ``(x, y,
z, roll, pitch, yaw)``, zero elsewhere, as planar localizers publish it) and
the answer as JSON text for a ``std_msgs/String`` (:func:`answer_json`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from ..errors import DataFormatError
from ..io.frames import Transform3
from ..io.rosbag import _scan_from_msg
from ..io.trajectory import yaw_quaternion
from ..sensors import Scan

__all__ = [
    "COVARIANCE_INDEX",
    "TransformLink",
    "answer_json",
    "covariance_6x6",
    "fill_pose_with_covariance",
    "frame_name",
    "odometry_from_msg",
    "scan_from_msg",
    "stamp_seconds",
    "transforms_from_msg",
]

#: Rows/columns of ``(x, y, theta)`` in a ROS 6x6 pose covariance over ``(x, y, z, roll, pitch, yaw)``.
COVARIANCE_INDEX: tuple[int, int, int] = (0, 1, 5)


def stamp_seconds(stamp: Any) -> float:
    """Seconds of a ROS 1 (``secs``, ``nsecs``) or ROS 2 (``sec``, ``nanosec``) time stamp.

    Raises
    ------
    DataFormatError
        A stamp with neither pair of fields.
    """
    if hasattr(stamp, "sec") and hasattr(stamp, "nanosec"):
        return float(stamp.sec) + 1e-9 * float(stamp.nanosec)
    if hasattr(stamp, "secs") and hasattr(stamp, "nsecs"):
        return float(stamp.secs) + 1e-9 * float(stamp.nsecs)
    raise DataFormatError(f"not a ROS time stamp: {type(stamp).__name__}")


def frame_name(frame_id: Any) -> str:
    """A ``frame_id`` without its leading ``/`` (tf2 names frames without it)."""
    return str(frame_id).strip().lstrip("/")


def scan_from_msg(msg: Any) -> tuple[Scan, str]:
    """A ``sensor_msgs/LaserScan`` as a :class:`~fingerloc.sensors.Scan` in the lidar's frame, and that frame.

    The scan's ``timestamp`` is the header's stamp (seconds); ``pose`` is unset.

    Raises
    ------
    DataFormatError
        Fewer than 2 beams, or an angle increment that is zero or not a number.
    """
    scan = _scan_from_msg(msg, stamp_seconds(msg.header.stamp))
    return scan, frame_name(msg.header.frame_id)


@dataclass(frozen=True, slots=True)
class TransformLink:
    """One ``T_parent_child`` of a ``/tf`` or ``/tf_static`` message (frame names without a leading ``/``)."""

    parent: str
    child: str
    stamp: float
    transform: Transform3


def transforms_from_msg(msg: Any) -> list[TransformLink]:
    """The links of a ``tf2_msgs/TFMessage`` (or ``tf/tfMessage``), in message order."""
    out = []
    for tf in msg.transforms:
        value = Transform3.from_msg(tf.transform.translation, tf.transform.rotation)
        out.append(
            TransformLink(
                frame_name(tf.header.frame_id), frame_name(tf.child_frame_id), stamp_seconds(tf.header.stamp), value
            )
        )
    return out


def odometry_from_msg(msg: Any) -> tuple[float, Transform3, str, str]:
    """A ``nav_msgs/Odometry``: its stamp (s), the pose ``T_frame_child``, ``frame_id`` and ``child_frame_id``."""
    p = msg.pose.pose
    return (
        stamp_seconds(msg.header.stamp),
        Transform3.from_msg(p.position, p.orientation),
        frame_name(msg.header.frame_id),
        frame_name(msg.child_frame_id),
    )


def covariance_6x6(covariance: Sequence[Sequence[float]] | None) -> list[float]:
    """The 36 row-major entries of a ROS pose covariance from a 3x3 one over ``(x, y, theta)`` (m^2, m rad, rad^2).

    ``None`` gives zeros. The entries of ``z``, roll and pitch are zero.
    """
    out = [0.0] * 36
    if covariance is None:
        return out
    for a, i in enumerate(COVARIANCE_INDEX):
        for b, j in enumerate(COVARIANCE_INDEX):
            out[6 * i + j] = float(covariance[a][b])
    return out


def fill_pose_with_covariance(
    msg: Any, pose: Sequence[float], covariance: Sequence[Sequence[float]] | None = None
) -> Any:
    """Set a ``geometry_msgs/PoseWithCovariance``'s fields from a planar pose ``(x, y, theta)`` and its 3x3 covariance.

    ``msg`` is the message's ``PoseWithCovariance`` part (``stamped.pose``);
    its covariance field keeps its type (a list in ROS 1, an array in ROS 2).
    Returns ``msg``.
    """
    x, y, th = (float(v) for v in pose)
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = x, y, 0.0
    q = msg.pose.orientation
    q.x, q.y, q.z, q.w = yaw_quaternion(th)
    cov = covariance_6x6(covariance)
    old = msg.covariance
    if hasattr(old, "dtype"):  # a numpy array (ROS 2, rosbags): a new one of the same type
        import numpy as np

        msg.covariance = np.array(cov, dtype=old.dtype)
    else:
        msg.covariance = cov
    return msg


def answer_json(answer: Any) -> str:
    """An answer as one line of strict JSON (its ``to_json()`` record; a non-finite number becomes ``null``)."""

    def clean(v: Any) -> Any:
        if isinstance(v, float):
            return v if math.isfinite(v) else None
        if isinstance(v, dict):
            return {str(k): clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        item = getattr(v, "item", None)
        if callable(item) and not isinstance(v, (str, bytes)):
            return clean(item())
        return v

    return json.dumps(clean(answer.to_json()), allow_nan=False, separators=(",", ":"))
