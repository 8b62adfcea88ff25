"""ROS bags (ROS 1 ``.bag``, ROS 2 folders, ``.db3`` and ``.mcap`` files): laser scans with poses.

Built on the `rosbags <https://gitlab.com/ternaris/rosbags>`_ library (the only
module of fingerloc that imports it). Reads ``sensor_msgs/LaserScan`` messages
of any field of view (with intensities) into :class:`~fingerloc.sensors.Scan`.

What the reader resolves, and the rules it follows
--------------------------------------------------
* **Base frame.** The robot's frame, in which bearings are measured. Given
  (``base_frame=`` / ``--base-frame``), or by default the root of the static
  transforms above the lidar frames (``base_footprint`` on a robot whose
  lidars are mounted on ``base_link`` under ``base_footprint``): links of
  ``/tf_static``, and ``/tf`` links that never change unless they lead into
  ``odom``, ``map``, ``world`` or ``earth`` (older bags re-send fixed joints
  on ``/tf``). When no transform names the lidar frame, a single lidar's own
  frame is the base (a zero mount, said so in the plan). A base frame that no chain of
  ``/tf_static`` and ``/tf`` transforms links to a lidar frame is an error
  naming both frames, never a silent zero mount.
* **Lidar mount.** The full 3D transform from the lidar frame to the base
  frame (every link of the chain composed, ``/tf`` links at the scan's
  stamp), reduced to the plane: each beam's direction is rotated into the
  base frame and projected onto its plane (bearing and planar range). A lidar
  mounted upside down (roll 180 deg) sees its bearings mirrored: they run
  clockwise in the base frame, and the reader reverses them. A lidar tilted
  more than ``max_tilt_deg`` from the base plane is not a planar sensor and is
  refused.
* **Poses** (``pose_source``): ``odom`` / ``odom:TOPIC`` from a
  ``nav_msgs/Odometry`` topic (composed with the transform from its
  ``child_frame_id`` to the base frame when the tree links them), ``tf`` / ``tf:FRAME``
  the base frame's pose in FRAME (default: the root of its ``/tf`` tree, e.g.
  ``map``), ``none``, or ``auto`` (odometry if there is any, else ``/tf`` if
  the base frame moves in it, else none). Every pose, and every ``/tf`` link,
  is interpolated to the scan's stamp (linear in position, slerp in
  rotation) between the two samples around it when they are at most
  ``2 max_pose_gap`` seconds apart; else the nearest sample within
  ``max_pose_gap``; else no pose. A ``/tf`` link whose value never changes
  counts as static.
* **Several scan topics** (``topic=["/scan_front", "/scan_back"]``) give one
  scan per time step in the base frame (:func:`merge_scans`): the first topic
  is the reference; each of its scans is merged with, for every other topic,
  the scan whose stamp is nearest, if within ``pair_tolerance`` seconds
  (default: half the reference's scan period, from its ``scan_time`` or the
  spacing of its stamps). A reference scan that lacks a partner is dropped
  and counted (:class:`BagReadStats`). With poses, a partner scan is moved
  by the robot's motion between its stamp and the reference's.

A bag is streamed twice: once for the (small) pose messages, once for the
scans (after a look at the first few scans for their frames and period), so a
long bag is never held in memory; only the pose time series are. The options
and what they resolved to are in a :class:`BagPlan` (``on_plan=``,
:func:`bag_plan`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from ..errors import DataFormatError
from ..sensors import Scan
from ._bag_messages import (
    BAG_EXTENSIONS,
    LASER_SCAN,
    BagInfo,
    BagReadStats,
    _choose_scan_topics,
    _Open,
    _scan_from_msg,
    _stamp,
    bag_info,
    is_bag_path,
    messages,
)
from .bag_plan import (
    BagPlan,
    LidarMount,
    PoseTrack,
    _check_args,
    _frames_list,
    _mount_at,
    _plan,
    _pose_at,
    bag_plan,
    parse_pose_source,
)
from .carmen import ReadStats
from .frames import (
    Transform3,
    compose_planar,
    invert_planar,
    merge_scans,
    reduce_to_plane,
)

__all__ = [
    "BAG_EXTENSIONS",
    "BagInfo",
    "BagPlan",
    "BagReadStats",
    "LidarMount",
    "PoseTrack",
    "Transform3",
    "bag_info",
    "bag_plan",
    "is_bag_path",
    "iter_bag_scans",
    "merge_scans",
    "parse_pose_source",
    "read_bag_scans",
    "reduce_to_plane",
    "scan_topics",
]

#: Reference scans held back waiting for a partner before the oldest is settled anyway.
_MAX_PENDING = 64


def iter_bag_scans(
    path: str | Path,
    *,
    topic: str | Sequence[str] | None = None,
    pose_source: str = "auto",
    odom_topic: str | None = None,
    base_frame: str | None = None,
    max_pose_gap: float = 0.5,
    pair_tolerance: float | None = None,
    motion_compensation: bool = True,
    max_tilt_deg: float = 30.0,
    skip_bad: bool = False,
    stats: ReadStats | None = None,
    on_plan: Callable[[BagPlan], None] | None = None,
) -> Iterator[Scan]:
    """Stream the ``sensor_msgs/LaserScan`` messages of a ROS 1 or ROS 2 bag as scans, in time order.

    The rules (base frame, mount, poses, pairing) are in the module docstring.

    Parameters
    ----------
    path : str or Path
        A ROS 1 ``.bag`` file, a ROS 2 bag folder, or a ``.db3`` / ``.mcap`` file.
    topic : str or sequence of str, optional
        The scan topic; required when the bag has several laser topics (the
        error lists them). Several topics: one merged scan per time step of
        the first (the reference), in the base frame.
    pose_source : str, default "auto"
        ``"auto"``, ``"odom"``, ``"odom:TOPIC"``, ``"tf"``, ``"tf:FRAME"`` or ``"none"``.
    odom_topic : str, optional
        The odometry topic (same as ``pose_source="odom:TOPIC"``).
    base_frame : str, optional
        The robot's frame (default: the root of the ``/tf_static`` tree the lidar frames hang off).
    max_pose_gap : float, default 0.5
        Seconds: poses and ``/tf`` links are interpolated between the two
        samples around the stamp when at most twice this apart (else the
        nearest within it, else none).
    pair_tolerance : float, optional
        Seconds between a reference scan and its partners (default: half the
        reference's scan period, or 0.05 s when it cannot be told).
    motion_compensation : bool, default True
        Move each partner scan by the robot's motion between its stamp and the
        reference's (when both have a pose).
    max_tilt_deg : float, default 30
        Largest angle between a lidar's scan plane and the base plane.
    skip_bad : bool, default False
        Skip a scan message that cannot be decoded or is invalid instead of raising.
    stats : ReadStats, optional
        Filled while streaming (``lines`` counts scan messages of every
        topic); a :class:`BagReadStats` also counts dropped time steps.
    on_plan : callable, optional
        Called once with the :class:`BagPlan` before the first scan (the CLI prints ``plan.describe()``).

    Yields
    ------
    Scan
        One topic: the lidar's scan, bearings in its frame reduced to the
        base plane (mirrored when upside down), ``sensor_offset`` its planar
        mount. Several topics: a merged scan (:func:`merge_scans`) in the base
        frame, ``coverage`` the union of the fields of view. Ranges in metres
        (``inf`` for no return), intensities when stored, ``pose`` the base
        frame's planar pose at the (reference) stamp, timestamp from the
        header (the bag's record time if the stamp is 0).

    Raises
    ------
    DataFormatError
        Not a readable bag, no laser topic, a malformed scan message, a base
        frame with no transform chain to a lidar frame (naming both), a lidar
        tilted too far.
    InvalidParameterError
        An unknown or ambiguous ``topic`` / ``odom_topic``, or a pose source the bag cannot serve.
    """
    parse_pose_source(pose_source, odom_topic)
    _check_args(max_pose_gap, pair_tolerance, max_tilt_deg)
    p = Path(path)
    st = stats if stats is not None else ReadStats()
    info = bag_info(p)
    topics = _choose_scan_topics(info, topic)
    with _Open(p) as reader:
        plan, poses, fixed = _plan(
            p,
            reader,
            info,
            topics,
            pose_source=pose_source,
            odom_topic=odom_topic,
            base_frame=base_frame,
            max_pose_gap=max_pose_gap,
            pair_tolerance=pair_tolerance,
        )
        if on_plan is not None:
            on_plan(plan)
        base = plan.base_frame
        tree = poses.tree
        mount_cache: dict[str, Transform3] = {}
        counts = dict.fromkeys(topics, 0)

        def decode(conn: Any, ns: int, raw: bytes) -> Scan | None:
            counts[conn.topic] += 1
            k = counts[conn.topic]
            try:
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception as err:
                    raise DataFormatError(f"cannot decode: {err}") from None
                t = _stamp(msg.header, ns)
                scan = _scan_from_msg(msg, t)
                frame = str(msg.header.frame_id).strip("/")
                mount = mount_cache.get(frame)
                if mount is None:
                    mount = _mount_at(tree, base, frame, t, max_pose_gap)
                    if mount is None:
                        if tree is None or tree.common_ancestor(frame, str(base)) is None:
                            raise DataFormatError(
                                f"no transform chain from lidar frame {frame!r} to base frame {base!r} "
                                f"(frames: {_frames_list(tree)})"
                            )
                        if isinstance(st, BagReadStats):
                            st.unmounted += 1
                        return None
                    if tree is None or base is None or tree.static_between(frame, base):
                        mount_cache[frame] = mount
                pose = _pose_at(poses, base, fixed, t, max_pose_gap)
                scan = Scan(
                    ranges=scan.ranges,
                    bearings=scan.bearings,
                    max_range=scan.max_range,
                    intensities=scan.intensities,
                    pose=pose,
                    timestamp=scan.timestamp,
                )
                return reduce_to_plane(scan, mount, max_tilt_deg=max_tilt_deg, frame=frame, base=str(base))
            except DataFormatError as err:
                located = DataFormatError(f"message {k} on {conn.topic}: {err.message}", path=p)
                if skip_bad:
                    st.record_skip(located)
                    return None
                raise located from None

        conns = [c for c in reader.connections if c.topic in topics]
        if len(topics) == 1:
            for conn, ns, raw in messages(reader, conns, p):
                st.lines += 1
                scan = decode(conn, ns, raw)
                if scan is not None:
                    st.scans += 1
                    yield scan
            return
        yield from _paired(
            messages(reader, conns, p),
            decode,
            topics,
            float(plan.pair_tolerance or 0.0),
            motion_compensation,
            st,
        )


def _paired(
    messages: Iterator[tuple[Any, int, bytes]],
    decode: Callable[[Any, int, bytes], Scan | None],
    topics: tuple[str, ...],
    tol: float,
    motion_compensation: bool,
    st: ReadStats,
) -> Iterator[Scan]:
    """Merge streamed scans of several topics by the pairing rule (reference = ``topics[0]``)."""
    ref, others = topics[0], topics[1:]
    pending: deque[Scan] = deque()
    buffers: dict[str, deque[Scan]] = {t: deque() for t in others}
    latest = dict.fromkeys(others, -math.inf)

    def settle(r: Scan) -> Scan | None:
        t = float(r.timestamp or 0.0)
        parts = [r]
        for o in others:
            buf = buffers[o]
            while buf and float(buf[0].timestamp or 0.0) < t - tol:
                buf.popleft()  # too old for this and every later reference scan
            best = min(buf, key=lambda s: abs(float(s.timestamp or 0.0) - t), default=None)
            if best is None or abs(float(best.timestamp or 0.0) - t) > tol:
                if isinstance(st, BagReadStats):
                    st.unpaired += 1
                return None
            parts.append(best)
        if motion_compensation and r.pose is not None:
            inv = invert_planar(r.pose)
            moved = [r]
            for s in parts[1:]:
                if s.pose is None:
                    moved.append(s)
                    continue
                rel = compose_planar(inv, s.pose)  # the partner's base frame in the reference's
                moved.append(
                    Scan(
                        ranges=s.ranges,
                        bearings=s.bearings,
                        max_range=s.max_range,
                        intensities=s.intensities,
                        sensor_offset=compose_planar(rel, s.sensor_offset),
                        timestamp=s.timestamp,
                    )
                )
            parts = moved
        return merge_scans(parts, pose=r.pose, timestamp=r.timestamp)

    def ready(r: Scan) -> bool:
        t = float(r.timestamp or 0.0)
        return len(pending) > _MAX_PENDING or all(latest[o] > t + tol for o in others)

    for conn, ns, raw in messages:
        st.lines += 1
        scan = decode(conn, ns, raw)
        if scan is None:
            continue
        if conn.topic == ref:
            pending.append(scan)
        else:
            buffers[conn.topic].append(scan)
            latest[conn.topic] = max(latest[conn.topic], float(scan.timestamp or 0.0))
        while pending and ready(pending[0]):
            merged = settle(pending.popleft())
            if merged is not None:
                st.scans += 1
                yield merged
    while pending:
        merged = settle(pending.popleft())
        if merged is not None:
            st.scans += 1
            yield merged


def read_bag_scans(path: str | Path, **kwargs: Any) -> list[Scan]:
    """All scans of a bag as a list (see :func:`iter_bag_scans` for the keyword arguments)."""
    return list(iter_bag_scans(path, **kwargs))


def scan_topics(path: str | Path) -> Sequence[str]:
    """The ``sensor_msgs/LaserScan`` topics of a bag, sorted."""
    return bag_info(path).of_type(LASER_SCAN)
