"""ROS bags (ROS 1 ``.bag``, ROS 2 folders, ``.db3`` and ``.mcap`` files): laser scans with poses.

Built on the `rosbags <https://gitlab.com/ternaris/rosbags>`_ library (the only
module of fingerloc that imports it). Reads ``sensor_msgs/LaserScan`` messages
of any field of view (with intensities) into :class:`~fingerloc.sensors.Scan`,
and gives each scan the robot's pose nearest in time from

* ``nav_msgs/Odometry`` messages (``pose.pose``), or
* ``/tf`` and ``/tf_static`` (``tf2_msgs/TFMessage``): the base frame's pose in
  the root of its transform tree, chaining every transform above it, each
  taken nearest in time.

Poses are planar: ``(x, y, yaw)``; yaw comes from the quaternion. When the
transform tree links the scan's ``frame_id`` to the base frame, the scan's
``sensor_offset`` is that transform.

A bag is streamed twice: once for the (small) pose messages, once for the
scans, so a long bag is never held in memory; only the pose time series are.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..errors import DataFormatError, InvalidParameterError
from ..sensors import Scan
from .carmen import ReadStats

__all__ = [
    "BAG_EXTENSIONS",
    "BagInfo",
    "PoseTrack",
    "bag_info",
    "is_bag_path",
    "iter_bag_scans",
    "read_bag_scans",
    "scan_topics",
]

#: File name endings taken for ROS bags (a folder holding ``metadata.yaml`` is a ROS 2 bag too).
BAG_EXTENSIONS: tuple[str, ...] = (".bag", ".db3", ".mcap")

LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"

#: Base frames tried, in order, when none is given.
DEFAULT_BASE_FRAMES: tuple[str, ...] = ("base_link", "base_footprint", "base")

PoseSource = Literal["auto", "odom", "tf", "none"]


def is_bag_path(path: str | Path) -> bool:
    """True when ``path`` looks like a ROS bag: a ``.bag``/``.db3``/``.mcap`` file or a folder with ``metadata.yaml``."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").exists()
    return p.suffix.lower() in BAG_EXTENSIONS


def _yaw(q: Any) -> float:
    """Yaw (rad) of a quaternion with fields ``x, y, z, w``."""
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _stamp(header: Any, fallback_ns: int) -> float:
    st = header.stamp
    sec = float(st.sec) + 1e-9 * float(st.nanosec)
    return sec if sec > 0 else fallback_ns * 1e-9


def _compose(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """Planar pose composition ``a * b`` (b expressed in a's frame)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], math.remainder(a[2] + b[2], 2 * math.pi))


@dataclass(slots=True)
class PoseTrack:
    """A planar pose time series, queried nearest in time.

    Attributes
    ----------
    times : list of float
        Seconds, sorted on :meth:`freeze`.
    poses : list of (x, y, theta)
        Metres and radians.
    """

    times: list[float] = field(default_factory=list)
    poses: list[tuple[float, float, float]] = field(default_factory=list)
    _sorted: bool = True

    def add(self, t: float, pose: tuple[float, float, float]) -> None:
        """Append one pose at time ``t`` (seconds)."""
        if self.times and t < self.times[-1]:
            self._sorted = False
        self.times.append(t)
        self.poses.append(pose)

    def freeze(self) -> None:
        """Sort by time (stable)."""
        if not self._sorted:
            order = sorted(range(len(self.times)), key=self.times.__getitem__)
            self.times = [self.times[i] for i in order]
            self.poses = [self.poses[i] for i in order]
            self._sorted = True

    def nearest(self, t: float, max_gap: float = math.inf) -> tuple[float, float, float] | None:
        """The pose nearest in time to ``t``, or ``None`` when none is within ``max_gap`` seconds."""
        if not self.times:
            return None
        i = bisect_left(self.times, t)
        best = None
        best_dt = math.inf
        for j in (i - 1, i):
            if 0 <= j < len(self.times):
                dt = abs(self.times[j] - t)
                if dt < best_dt:
                    best, best_dt = j, dt
        if best is None or best_dt > max_gap:
            return None
        return self.poses[best]


@dataclass(slots=True)
class _TfTree:
    """Transforms child -> parent, each a :class:`PoseTrack` (static ones hold one pose)."""

    parent: dict[str, str] = field(default_factory=dict)
    tracks: dict[str, PoseTrack] = field(default_factory=dict)
    static: set[str] = field(default_factory=set)

    def add(self, parent: str, child: str, t: float, pose: tuple[float, float, float], *, static: bool) -> None:
        parent, child = parent.lstrip("/"), child.lstrip("/")
        if child == parent:
            return
        self.parent[child] = parent
        if static:
            self.static.add(child)
            self.tracks[child] = PoseTrack([t], [pose])
        else:
            self.tracks.setdefault(child, PoseTrack()).add(t, pose)

    def freeze(self) -> None:
        for tr in self.tracks.values():
            tr.freeze()

    def chain(self, frame: str, t: float, *, until: str | None, max_gap: float) -> tuple[float, float, float] | None:
        """Pose of ``frame`` in ``until`` (or in the tree's root), or ``None`` if a link is missing in time."""
        frame = frame.lstrip("/")
        pose = (0.0, 0.0, 0.0)
        seen = set()
        while frame != until and frame in self.parent:
            if frame in seen:
                return None  # a cycle: not a tree
            seen.add(frame)
            gap = math.inf if frame in self.static else max_gap
            link = self.tracks[frame].nearest(t, gap)
            if link is None:
                return None
            pose = _compose(link, pose)
            frame = self.parent[frame]
        if until is not None and frame != until:
            return None
        return pose


@dataclass(frozen=True, slots=True)
class BagInfo:
    """Topics of a bag: ``topics`` maps name to (message type, message count)."""

    path: str
    topics: dict[str, tuple[str, int]]

    def of_type(self, msgtype: str) -> list[str]:
        """Names of the topics carrying ``msgtype`` (e.g. ``"sensor_msgs/msg/LaserScan"``), sorted."""
        return sorted(t for t, (m, _) in self.topics.items() if m == msgtype)


def _reader(path: Path) -> Any:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise DataFormatError("no such file or folder", path=path)
    try:
        return AnyReader([path], default_typestore=get_typestore(Stores.LATEST))
    except Exception as err:  # rosbags raises several unrelated types here
        raise DataFormatError(f"not a readable ROS bag: {err}", path=path) from None


class _Open:
    """Open an AnyReader, turning rosbags' errors into :class:`DataFormatError`."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.reader = _reader(path)

    def __enter__(self) -> Any:
        try:
            self.reader.open()
        except Exception as err:
            raise DataFormatError(f"not a readable ROS bag: {err}", path=self.path) from None
        return self.reader

    def __exit__(self, *exc: object) -> None:
        self.reader.close()


def bag_info(path: str | Path) -> BagInfo:
    """List the topics of a bag with their message types and counts."""
    p = Path(path)
    with _Open(p) as reader:
        topics = {name: (str(info.msgtype), int(info.msgcount)) for name, info in reader.topics.items()}
    return BagInfo(path=str(p), topics=topics)


def _choose_scan_topic(info: BagInfo, topic: str | None) -> str:
    lasers = info.of_type(LASER_SCAN)
    if topic is not None:
        if topic in lasers:
            return topic
        if topic in info.topics:
            raise InvalidParameterError(
                f"topic {topic!r} of {info.path} carries {info.topics[topic][0]}, not {LASER_SCAN} "
                f"(laser topics: {', '.join(lasers) or 'none'})"
            )
        raise InvalidParameterError(
            f"no topic {topic!r} in {info.path} (laser topics: {', '.join(lasers) or 'none'}; "
            f"all topics: {', '.join(sorted(info.topics)) or 'none'})"
        )
    if not lasers:
        raise DataFormatError(
            f"no {LASER_SCAN} topic (topics: {', '.join(sorted(info.topics)) or 'none'})", path=info.path
        )
    if len(lasers) > 1:
        raise InvalidParameterError(
            f"{info.path} has {len(lasers)} laser topics, choose one with topic= / --topic: {', '.join(lasers)}"
        )
    return lasers[0]


def _scan_from_msg(msg: Any, t: float) -> Scan:
    ranges = np.asarray(msg.ranges, dtype=np.float64).reshape(-1)
    n = ranges.size
    if n < 2:
        raise DataFormatError(f"a LaserScan needs at least 2 beams, got {n}")
    inc = float(msg.angle_increment)
    a0 = float(msg.angle_min)
    if not (math.isfinite(inc) and math.isfinite(a0)) or inc == 0:
        if math.isfinite(float(msg.angle_max)) and math.isfinite(a0) and float(msg.angle_max) != a0:
            inc = (float(msg.angle_max) - a0) / (n - 1)
        else:
            raise DataFormatError(f"LaserScan angle_increment must be a non-zero number, got {msg.angle_increment!r}")
    bearings = a0 + inc * np.arange(n, dtype=np.float64)
    inten = np.asarray(msg.intensities, dtype=np.float64).reshape(-1)
    intensities = inten if inten.size == n else None
    if inc < 0:  # a laser mounted upside down: keep bearings increasing
        bearings, ranges = bearings[::-1], ranges[::-1]
        intensities = None if intensities is None else intensities[::-1]
    # A scan covers at most one turn: drop beams that repeat the first ones.
    keep = bearings - bearings[0] <= 2 * math.pi + 1e-9 - abs(inc) * 1e-6
    if not keep.all():
        bearings, ranges = bearings[keep], ranges[keep]
        intensities = None if intensities is None else intensities[keep]
    rmin, rmax = float(msg.range_min), float(msg.range_max)
    ranges = np.where(np.isfinite(ranges) & (ranges >= max(rmin, 0.0)), ranges, np.inf)
    if not (math.isfinite(rmax) and rmax > 0):
        finite = ranges[np.isfinite(ranges)]
        rmax = float(finite.max()) + 1.0 if finite.size else 1.0
    try:
        return Scan(ranges=ranges, bearings=bearings, max_range=rmax, intensities=intensities, timestamp=t)
    except InvalidParameterError as err:
        raise DataFormatError(f"LaserScan: {err}") from None


def _collect_poses(
    reader: Any, info: BagInfo, source: PoseSource, odom_topic: str | None
) -> tuple[str, PoseTrack | None, _TfTree | None]:
    """Read the pose messages. Returns the source used, an odometry track and a transform tree."""
    odoms = info.of_type(ODOMETRY)
    tfs = [t for t in info.of_type(TF_MESSAGE) if t.rstrip("/").split("/")[-1] in ("tf", "tf_static")]
    if odom_topic is not None and odom_topic not in odoms:
        raise InvalidParameterError(
            f"no {ODOMETRY} topic {odom_topic!r} in {info.path} (odometry topics: {', '.join(odoms) or 'none'})"
        )
    use = source
    if source == "auto":
        use = "odom" if odoms else ("tf" if tfs else "none")
    if use == "odom" and not odoms:
        raise InvalidParameterError(f"pose source 'odom': {info.path} has no {ODOMETRY} topic")
    if use == "tf" and not tfs:
        raise InvalidParameterError(f"pose source 'tf': {info.path} has no /tf topic")
    wanted = []
    if use == "odom":
        wanted.append(odom_topic or odoms[0])
    # The transform tree is read whenever it exists: it gives the laser's offset too.
    wanted += tfs
    conns = [c for c in reader.connections if c.topic in wanted]
    track = PoseTrack() if use == "odom" else None
    tree = _TfTree() if tfs else None
    for conn, ns, raw in reader.messages(connections=conns) if conns else ():
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception:
            continue  # a broken pose message is as good as a missing one
        if conn.msgtype == ODOMETRY and track is not None:
            p = msg.pose.pose
            track.add(_stamp(msg.header, ns), (float(p.position.x), float(p.position.y), _yaw(p.orientation)))
        elif conn.msgtype == TF_MESSAGE and tree is not None:
            static = conn.topic.rstrip("/").endswith("tf_static")
            for tf in msg.transforms:
                tr = tf.transform
                pose = (float(tr.translation.x), float(tr.translation.y), _yaw(tr.rotation))
                tree.add(tf.header.frame_id, tf.child_frame_id, _stamp(tf.header, ns), pose, static=static)
    if track is not None:
        track.freeze()
    if tree is not None:
        tree.freeze()
    return str(use), track, tree


def iter_bag_scans(
    path: str | Path,
    *,
    topic: str | None = None,
    pose_source: PoseSource = "auto",
    odom_topic: str | None = None,
    base_frame: str | None = None,
    max_pose_gap: float = 0.5,
    skip_bad: bool = False,
    stats: ReadStats | None = None,
) -> Iterator[Scan]:
    """Stream the ``sensor_msgs/LaserScan`` messages of a ROS 1 or ROS 2 bag as scans, in time order.

    Parameters
    ----------
    path : str or Path
        A ROS 1 ``.bag`` file, a ROS 2 bag folder, or a ``.db3`` / ``.mcap`` file.
    topic : str, optional
        The scan topic; required when the bag has several laser topics
        (the error lists them).
    pose_source : {"auto", "odom", "tf", "none"}, default "auto"
        Where poses come from: ``nav_msgs/Odometry`` (``auto`` prefers it),
        the ``/tf`` tree, or nowhere (``pose`` stays ``None``).
    odom_topic : str, optional
        The odometry topic when there are several (default: the first by name).
    base_frame : str, optional
        The robot's frame in the transform tree (default: the first of
        ``base_link``, ``base_footprint``, ``base`` present).
    max_pose_gap : float, default 0.5
        A scan whose nearest pose is farther than this many seconds gets no pose.
    skip_bad : bool, default False
        Skip a scan message that cannot be decoded or is invalid instead of raising.
    stats : ReadStats, optional
        Filled while streaming (``lines`` counts scan messages).

    Yields
    ------
    Scan
        Ranges in metres (``inf`` for no return: readings outside
        ``[range_min, range_max]``, NaN, inf); bearings from ``angle_min``
        by ``angle_increment``; intensities when one per beam is stored;
        timestamp from the header (the bag's record time if the stamp is 0).

    Raises
    ------
    DataFormatError
        Not a readable bag, no laser topic, or a malformed scan message.
    InvalidParameterError
        An unknown or ambiguous ``topic`` / ``odom_topic``, or a pose source the bag cannot serve.
    """
    if pose_source not in ("auto", "odom", "tf", "none"):
        raise InvalidParameterError(f"pose_source must be auto, odom, tf or none, got {pose_source!r}")
    if not (max_pose_gap >= 0):
        raise InvalidParameterError(f"max_pose_gap must be >= 0 seconds, got {max_pose_gap!r}")
    p = Path(path)
    st = stats if stats is not None else ReadStats()
    info = bag_info(p)
    scan_topic = _choose_scan_topic(info, topic)
    with _Open(p) as reader:
        use, track, tree = _collect_poses(reader, info, pose_source, odom_topic)
        base = base_frame
        if tree is not None and base is None:
            base = next((f for f in DEFAULT_BASE_FRAMES if f in tree.parent or f in tree.parent.values()), None)
        if use == "tf" and base is None:
            raise InvalidParameterError(
                f"cannot tell the robot's frame in the /tf tree of {p}: pass base_frame= "
                f"(frames: {', '.join(sorted(tree.parent)) if tree else 'none'})"
            )
        conns = [c for c in reader.connections if c.topic == scan_topic]
        for k, (conn, ns, raw) in enumerate(reader.messages(connections=conns), start=1):
            st.lines += 1
            try:
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception as err:
                    raise DataFormatError(f"cannot decode: {err}") from None
                t = _stamp(msg.header, ns)
                scan = _scan_from_msg(msg, t)
            except DataFormatError as err:
                located = DataFormatError(f"message {k} on {scan_topic}: {err.message}", path=p)
                if skip_bad:
                    st.record_skip(located)
                    continue
                raise located from None
            pose: tuple[float, float, float] | None = None
            offset = (0.0, 0.0, 0.0)
            if use == "odom" and track is not None:
                pose = track.nearest(t, max_pose_gap)
            elif use == "tf" and tree is not None:
                pose = tree.chain(str(base), t, until=None, max_gap=max_pose_gap) if base in tree.parent else None
            frame = str(msg.header.frame_id).lstrip("/")
            if tree is not None and base is not None and frame and frame != base:
                off = tree.chain(frame, t, until=base, max_gap=max_pose_gap)
                if off is not None:
                    offset = off
            if pose is not None or offset != (0.0, 0.0, 0.0):
                scan = Scan(
                    ranges=scan.ranges,
                    bearings=scan.bearings,
                    max_range=scan.max_range,
                    intensities=scan.intensities,
                    pose=pose,
                    sensor_offset=offset,
                    timestamp=scan.timestamp,
                )
            st.scans += 1
            yield scan


def read_bag_scans(path: str | Path, **kwargs: Any) -> list[Scan]:
    """All scans of a bag as a list (see :func:`iter_bag_scans` for the keyword arguments)."""
    return list(iter_bag_scans(path, **kwargs))


def scan_topics(path: str | Path) -> Sequence[str]:
    """The ``sensor_msgs/LaserScan`` topics of a bag, sorted."""
    return bag_info(path).of_type(LASER_SCAN)
