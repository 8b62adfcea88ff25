"""ROS bags (ROS 1 ``.bag``, ROS 2 folders, ``.db3`` and ``.mcap`` files): laser scans with poses.

Built on the `rosbags <https://gitlab.com/ternaris/rosbags>`_ library (the only
module of fingerloc that imports it). Reads ``sensor_msgs/LaserScan`` messages
of any field of view (with intensities) into :class:`~fingerloc.sensors.Scan`.

What the reader resolves, and the rules it follows
--------------------------------------------------
* **Base frame.** The robot's frame, in which bearings are measured. Given
  (``base_frame=`` / ``--base-frame``), or by default the root of the
  ``/tf_static`` tree that the lidar frames hang off (``base_footprint`` on a
  robot whose lidars are mounted on ``base_link`` under ``base_footprint``).
  When the bag has no transform tree at all, the lidar's own frame is the base
  (a zero mount, said so in the plan). A base frame that no chain of
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
  ``nav_msgs/Odometry`` topic (composed with the static transform from its
  ``child_frame_id`` to the base frame when one exists), ``tf`` / ``tf:FRAME``
  the base frame's pose in FRAME (default: the root of its ``/tf`` tree, e.g.
  ``map``), ``none``, or ``auto`` (odometry if there is any, else ``/tf`` if
  the base frame moves in it, else none). Every pose, and every ``/tf`` link,
  is interpolated to the scan's stamp (linear in position, slerp in
  rotation) between the two samples around it when both are within
  ``max_pose_gap`` seconds; else the nearest sample within that gap; else no
  pose. A ``/tf`` link whose value never changes counts as static.
* **Several scan topics** (``topic=["/scan_front", "/scan_back"]``) give one
  scan per time step in the base frame (:func:`merge_scans`): the first topic
  is the reference; each of its scans is merged with, for every other topic,
  the scan whose stamp is nearest, if within ``pair_tolerance`` seconds
  (default: half the reference's scan period, from its ``scan_time`` or the
  spacing of its stamps). A reference scan that lacks a partner is dropped
  and counted (:class:`BagReadStats`). With poses, a partner scan is moved
  by the robot's motion between its stamp and the reference's.

A bag is streamed twice: once for the (small) pose messages, once for the
scans, so a long bag is never held in memory; only the pose time series are.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..angles import TWO_PI, wrap
from ..errors import DataFormatError, InvalidParameterError
from ..sensors import Scan
from .carmen import ReadStats

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
    "read_bag_scans",
    "reduce_to_plane",
    "scan_topics",
]

#: File name endings taken for ROS bags (a folder holding ``metadata.yaml`` is a ROS 2 bag too).
BAG_EXTENSIONS: tuple[str, ...] = (".bag", ".db3", ".mcap")

LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"

#: Pairing tolerance (s) when the reference topic's scan period cannot be told (a single scan, no ``scan_time``).
DEFAULT_PAIR_TOLERANCE = 0.05

#: Reference scans probed to estimate the scan period.
_PROBE_SCANS = 21

#: Reference scans held back waiting for a partner before the oldest is settled anyway.
_MAX_PENDING = 64

PoseSource = Literal["auto", "odom", "tf", "none"]

Planar = tuple[float, float, float]


def is_bag_path(path: str | Path) -> bool:
    """True when ``path`` looks like a ROS bag: a ``.bag``/``.db3``/``.mcap`` file or a folder with ``metadata.yaml``."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").exists()
    return p.suffix.lower() in BAG_EXTENSIONS


# ---------------------------------------------------------------------------
# 3D rigid transforms


def _qmul(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float, float]:
    """Hamilton product of quaternions ``(x, y, z, w)``."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


@dataclass(frozen=True, slots=True)
class Transform3:
    """A rigid 3D transform: rotation ``q`` (unit quaternion ``(x, y, z, w)``) then translation ``t`` (metres).

    ``a.compose(b)`` is ``a * b``: ``b`` expressed in ``a``'s frame, as
    ``T_parent_child`` links compose down a ``/tf`` chain.
    """

    t: tuple[float, float, float] = (0.0, 0.0, 0.0)
    q: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        n = math.sqrt(sum(v * v for v in self.q))
        # a zero quaternion (an unset field in a bag) is taken as no rotation
        q = (0.0, 0.0, 0.0, 1.0) if not (n > 1e-12 and math.isfinite(n)) else tuple(float(v) / n for v in self.q)
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "t", tuple(float(v) for v in self.t))

    @classmethod
    def from_msg(cls, translation: Any, rotation: Any) -> Transform3:
        """From ROS ``Vector3``/``Point`` and ``Quaternion`` message fields."""
        t = (float(translation.x), float(translation.y), float(translation.z))
        return cls(t, (float(rotation.x), float(rotation.y), float(rotation.z), float(rotation.w)))

    @classmethod
    def from_planar(cls, pose: Planar) -> Transform3:
        """A planar pose ``(x, y, yaw)`` as a 3D transform."""
        x, y, yaw = pose
        return cls((x, y, 0.0), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)))

    def matrix(self) -> np.ndarray:
        """The rotation as a (3, 3) matrix."""
        x, y, z, w = self.q
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )

    def compose(self, other: Transform3) -> Transform3:
        """``self * other``."""
        t = np.asarray(self.t) + self.matrix() @ np.asarray(other.t)
        return Transform3((float(t[0]), float(t[1]), float(t[2])), _qmul(self.q, other.q))

    def inverse(self) -> Transform3:
        """The inverse transform."""
        x, y, z, w = self.q
        qi = (-x, -y, -z, w)
        t = -(Transform3((0.0, 0.0, 0.0), qi).matrix() @ np.asarray(self.t))
        return Transform3((float(t[0]), float(t[1]), float(t[2])), qi)

    def planar(self) -> Planar:
        """``(x, y, yaw)``: the translation's x, y and the heading of the rotated x axis in the plane."""
        r = self.matrix()
        return (self.t[0], self.t[1], math.atan2(float(r[1, 0]), float(r[0, 0])))

    def is_close(self, other: Transform3, tol: float = 1e-9) -> bool:
        """Same transform within ``tol`` (translation in metres, quaternion components; ``q`` and ``-q`` agree)."""
        dq = min(
            max(abs(a - b) for a, b in zip(self.q, other.q, strict=True)),
            max(abs(a + b) for a, b in zip(self.q, other.q, strict=True)),
        )
        return dq <= tol and max(abs(a - b) for a, b in zip(self.t, other.t, strict=True)) <= tol


IDENTITY = Transform3()


def _interpolate(a: Transform3, b: Transform3, s: float) -> Transform3:
    """Linear in translation, slerp in rotation; ``s`` in [0, 1]."""
    t = tuple(x + s * (y - x) for x, y in zip(a.t, b.t, strict=True))
    qa, qb = np.asarray(a.q), np.asarray(b.q)
    d = float(qa @ qb)
    if d < 0:  # the shorter way round
        qb, d = -qb, -d
    if d > 0.9995:
        q = qa + s * (qb - qa)
    else:
        th = math.acos(min(d, 1.0))
        q = (math.sin((1 - s) * th) * qa + math.sin(s * th) * qb) / math.sin(th)
    return Transform3((t[0], t[1], t[2]), (float(q[0]), float(q[1]), float(q[2]), float(q[3])))


def _compose_planar(a: Planar, b: Planar) -> Planar:
    """Planar pose composition ``a * b`` (b expressed in a's frame)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], math.remainder(a[2] + b[2], TWO_PI))


def _invert_planar(a: Planar) -> Planar:
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], math.remainder(-a[2], TWO_PI))


@dataclass(slots=True)
class _Series:
    """A time series of transforms, interpolated at a stamp (see the module docstring)."""

    times: list[float] = field(default_factory=list)
    values: list[Transform3] = field(default_factory=list)
    constant: bool = False

    def add(self, t: float, value: Transform3) -> None:
        self.times.append(t)
        self.values.append(value)

    def freeze(self) -> None:
        order = sorted(range(len(self.times)), key=self.times.__getitem__)
        self.times = [self.times[i] for i in order]
        self.values = [self.values[i] for i in order]
        # a link published several times with one value is static (a mount re-sent on /tf)
        self.constant = len(self.values) > 1 and all(v.is_close(self.values[0]) for v in self.values)

    def at(self, t: float, max_gap: float) -> Transform3 | None:
        if not self.times:
            return None
        if self.constant:
            return self.values[0]
        i = bisect_left(self.times, t)
        if i < len(self.times) and self.times[i] == t:
            return self.values[i]
        lo_ok = i > 0 and t - self.times[i - 1] <= max_gap
        hi_ok = i < len(self.times) and self.times[i] - t <= max_gap
        if lo_ok and hi_ok:
            t0, t1 = self.times[i - 1], self.times[i]
            return _interpolate(self.values[i - 1], self.values[i], (t - t0) / (t1 - t0))
        if lo_ok:
            return self.values[i - 1]
        if hi_ok:
            return self.values[i]
        return None


@dataclass(slots=True)
class PoseTrack:
    """A planar pose time series, queried nearest in time (:meth:`nearest`) or interpolated (:meth:`at`).

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

    def at(self, t: float, max_gap: float = math.inf) -> tuple[float, float, float] | None:
        """The pose at ``t``, interpolated by the rule of the module docstring (heading the shorter way)."""
        s = _Series(self.times, [Transform3.from_planar(p) for p in self.poses])
        v = s.at(t, max_gap)
        return None if v is None else v.planar()


@dataclass(slots=True)
class _TfTree:
    """Transforms child -> parent (``T_parent_child``), each a time series (a static one holds one value)."""

    parent: dict[str, str] = field(default_factory=dict)
    links: dict[str, _Series] = field(default_factory=dict)
    from_static: set[str] = field(default_factory=set)

    def add(self, parent: str, child: str, t: float, value: Transform3, *, static: bool) -> None:
        parent, child = parent.lstrip("/"), child.lstrip("/")
        if child == parent or not child:
            return
        if static:
            self.parent[child] = parent
            self.from_static.add(child)
            self.links[child] = _Series([t], [value], constant=True)
        elif child not in self.from_static:
            self.parent[child] = parent
            self.links.setdefault(child, _Series()).add(t, value)

    def freeze(self) -> None:
        for child, s in self.links.items():
            if child not in self.from_static:
                s.freeze()

    def frames(self) -> set[str]:
        return set(self.parent) | set(self.parent.values())

    def ancestors(self, frame: str) -> list[str]:
        """``[frame, parent, grandparent, ..., root]`` (stops at a cycle)."""
        out = [frame]
        seen = {frame}
        while out[-1] in self.parent:
            p = self.parent[out[-1]]
            if p in seen:
                break
            out.append(p)
            seen.add(p)
        return out

    def static_root(self, frame: str) -> str:
        """The frame reached walking up ``/tf_static`` links only."""
        seen = {frame}
        while frame in self.from_static and self.parent[frame] not in seen:
            frame = self.parent[frame]
            seen.add(frame)
        return frame

    def common_ancestor(self, a: str, b: str) -> str | None:
        up_b = set(self.ancestors(b))
        return next((f for f in self.ancestors(a) if f in up_b), None)

    def is_static(self, frame: str, ancestor: str) -> bool:
        """True when every link from ``frame`` up to ``ancestor`` is static or never changes."""
        for f in self.ancestors(frame):
            if f == ancestor:
                return True
            if not self.links[f].constant:
                return False
        return True

    def static_between(self, a: str, b: str) -> bool:
        """True when the chain between frames ``a`` and ``b`` exists and holds only static links."""
        c = self.common_ancestor(a, b)
        return c is not None and self.is_static(a, c) and self.is_static(b, c)

    def moves(self, frame: str) -> bool:
        """True when a ``/tf`` (not ``/tf_static``) link lies above ``frame``."""
        return any(f not in self.from_static for f in self.ancestors(frame)[:-1])

    def _up(self, frame: str, ancestor: str, t: float, max_gap: float) -> Transform3 | None:
        """``T_ancestor_frame`` at ``t``."""
        out = IDENTITY
        for f in self.ancestors(frame):
            if f == ancestor:
                return out
            link = self.links[f].at(t, max_gap)
            if link is None:
                return None
            out = link.compose(out)
        return None

    def transform(self, target: str, source: str, t: float, max_gap: float) -> Transform3 | None:
        """``T_target_source`` at ``t`` through the lowest common ancestor, or ``None``."""
        if target == source:
            return IDENTITY
        c = self.common_ancestor(source, target)
        if c is None:
            return None
        a = self._up(source, c, t, max_gap)
        b = self._up(target, c, t, max_gap)
        if a is None or b is None:
            return None
        return b.inverse().compose(a)


# ---------------------------------------------------------------------------
# bags


@dataclass(frozen=True, slots=True)
class BagInfo:
    """Topics of a bag: ``topics`` maps name to (message type, message count)."""

    path: str
    topics: dict[str, tuple[str, int]]

    def of_type(self, msgtype: str) -> list[str]:
        """Names of the topics carrying ``msgtype`` (e.g. ``"sensor_msgs/msg/LaserScan"``), sorted."""
        return sorted(t for t, (m, _) in self.topics.items() if m == msgtype)


@dataclass(slots=True)
class BagReadStats(ReadStats):
    """:class:`~fingerloc.io.carmen.ReadStats` plus what merging and mounting dropped.

    Attributes
    ----------
    unpaired : int
        Reference scans dropped for lack of a partner scan on another topic within the tolerance.
    unmounted : int
        Scans dropped because a ``/tf`` link of their lidar's mount was missing at their stamp.
    """

    unpaired: int = 0
    unmounted: int = 0


@dataclass(frozen=True, slots=True)
class LidarMount:
    """Where one scan topic's lidar sits in the base frame (at the topic's first scan).

    Attributes
    ----------
    topic, frame : str
        The scan topic and its messages' ``frame_id``.
    xyz : (x, y, z)
        Lidar origin in the base frame, metres.
    yaw : float
        Heading (radians, base frame) of the lidar's bearing 0.
    mirrored : bool
        Mounted upside down: its bearings run clockwise in the base frame.
    tilt : float
        Angle (radians) between the lidar's scan plane and the base's plane.
    static : bool
        The chain is made of static links; else it is resolved at each scan's stamp.
    """

    topic: str
    frame: str
    xyz: tuple[float, float, float]
    yaw: float
    mirrored: bool
    tilt: float
    static: bool


@dataclass(frozen=True, slots=True)
class BagPlan:
    """What :func:`iter_bag_scans` resolved for a bag; :meth:`describe` says it in one line.

    Attributes
    ----------
    path : str
    topics : tuple of str
        Scan topics, the reference first.
    base_frame : str or None
        ``None`` when the bag has no transform tree: scans stay in the lidar's frame.
    base_frame_origin : str
        Why this base frame: ``"given"``, or the default rule that chose it.
    pose_source : str
        ``"odom:TOPIC"``, ``"tf:FRAME"`` or ``"none"``.
    mounts : tuple of LidarMount
        One per topic (empty without a base frame).
    pair_tolerance : float or None
        Seconds; ``None`` with a single topic.
    """

    path: str
    topics: tuple[str, ...]
    base_frame: str | None
    base_frame_origin: str
    pose_source: str
    mounts: tuple[LidarMount, ...]
    pair_tolerance: float | None

    def describe(self) -> str:
        """One line: base frame and why, pose source, each lidar's mount, the pairing rule."""
        if self.base_frame is None:
            parts = [f"base frame: none ({self.base_frame_origin})"]
        else:
            parts = [f"base frame {self.base_frame!r} ({self.base_frame_origin})"]
        parts.append(f"poses: {self.pose_source}")
        for m in self.mounts:
            x, y, z = m.xyz
            s = f"{m.topic} in {m.frame!r} at ({x:.3f}, {y:.3f}, {z:.3f}) m, yaw {math.degrees(m.yaw):.1f} deg"
            if m.mirrored:
                s += ", upside down (bearings mirrored)"
            if m.tilt > 1e-6 and not (m.mirrored and abs(m.tilt) < 1e-6):
                s += f", tilt {math.degrees(m.tilt):.1f} deg"
            if not m.static:
                s += ", mount moving (/tf)"
            parts.append(s)
        if self.pair_tolerance is not None:
            others = ", ".join(self.topics[1:])
            parts.append(
                f"merged: nearest {others} scan within {self.pair_tolerance:.3f} s of each {self.topics[0]} scan"
            )
        return "; ".join(parts)


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


def _choose_scan_topics(info: BagInfo, topic: str | Sequence[str] | None) -> tuple[str, ...]:
    lasers = info.of_type(LASER_SCAN)
    if topic is not None and not isinstance(topic, str):
        wanted = [str(t) for t in topic]
        if not wanted:
            topic = None
        else:
            dup = next((t for t in wanted if wanted.count(t) > 1), None)
            if dup is not None:
                raise InvalidParameterError(f"topic / --topic {dup!r} given twice")
            return tuple(_choose_scan_topics(info, t)[0] for t in wanted)
    if topic is not None:
        if topic in lasers:
            return (topic,)
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
            f"{info.path} has {len(lasers)} laser topics, choose one with topic= / --topic "
            f"(or several to merge them): {', '.join(lasers)}"
        )
    return (lasers[0],)


def _stamp(header: Any, fallback_ns: int) -> float:
    st = header.stamp
    sec = float(st.sec) + 1e-9 * float(st.nanosec)
    return sec if sec > 0 else fallback_ns * 1e-9


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
    if inc < 0:  # a clockwise scan: keep bearings increasing
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


# ---------------------------------------------------------------------------
# mounts and merging


def _tilt(mount: Transform3) -> tuple[float, bool]:
    """Tilt (rad) of the lidar's scan plane from the base plane, and whether it is upside down."""
    r22 = float(mount.matrix()[2, 2])
    return math.acos(min(1.0, abs(r22))), r22 < 0


def reduce_to_plane(
    scan: Scan, mount: Transform3, *, max_tilt_deg: float = 30.0, frame: str = "lidar", base: str = "base"
) -> Scan:
    """A lidar's scan seen from the base frame's plane: bearings, ranges and ``sensor_offset`` reduced to 2D.

    Each beam's direction ``R @ (cos phi, sin phi, 0)`` (``R`` the mount's
    rotation) is projected onto the base plane: its heading there, minus the
    lidar's planar heading (that of its bearing 0), is the new bearing and the
    range is scaled by the projection's length. An upright lidar keeps its
    bearings; one upside down (roll 180 deg) gets them mirrored (then
    reversed to keep them increasing, ranges and intensities with them).

    Parameters
    ----------
    scan : Scan
        Bearings in the lidar's own frame; its ``pose``, ``timestamp`` kept.
    mount : Transform3
        ``T_base_lidar``.
    max_tilt_deg : float, default 30
        Largest angle between the lidar's scan plane and the base plane.
    frame, base : str
        Frame names for the error message.

    Returns
    -------
    Scan
        ``sensor_offset = (x, y, yaw)`` of the lidar in the base frame.

    Raises
    ------
    DataFormatError
        The lidar is tilted more than ``max_tilt_deg``.
    """
    if mount.is_close(IDENTITY, 1e-12):
        return scan
    tilt, mirrored = _tilt(mount)
    if math.degrees(tilt) > max_tilt_deg + 1e-9:
        raise DataFormatError(
            f"lidar frame {frame!r} is tilted {math.degrees(tilt):.1f} deg from the plane of base frame {base!r} "
            f"(more than max_tilt_deg={max_tilt_deg:g}): not a planar scan"
        )
    r = mount.matrix()
    yaw = math.atan2(float(r[1, 0]), float(r[0, 0]))
    x, y, _ = mount.t
    if tilt < 1e-12 and not mirrored:  # upright: the bearings stay as they are
        return Scan(
            ranges=scan.ranges,
            bearings=scan.bearings,
            max_range=scan.max_range,
            intensities=scan.intensities,
            pose=scan.pose,
            sensor_offset=(x, y, yaw),
            timestamp=scan.timestamp,
        )
    phi = scan.bearings
    d = np.cos(phi)[:, None] * r[:, 0] + np.sin(phi)[:, None] * r[:, 1]  # (n, 3) beam directions in the base frame
    s = np.hypot(d[:, 0], d[:, 1])
    rel = np.unwrap(np.arctan2(d[:, 1], d[:, 0]) - yaw)
    ranges = scan.ranges * s
    inten = scan.intensities
    if mirrored:
        rel, ranges = rel[::-1], ranges[::-1]
        inten = None if inten is None else inten[::-1]
    rel = rel - TWO_PI * math.floor((0.5 * (rel[0] + rel[-1]) + math.pi) / TWO_PI)  # centre in [-pi, pi)
    return Scan(
        ranges=ranges,
        bearings=rel,
        max_range=scan.max_range,
        intensities=inten,
        pose=scan.pose,
        sensor_offset=(x, y, yaw),
        timestamp=scan.timestamp,
    )


def _arcs(fov: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """Covered ``(start, width)`` ranges as sorted disjoint ``[lo, hi)`` pieces of ``[-pi, pi)``."""
    pieces = []
    for start, width in fov:
        if width >= TWO_PI - 1e-9:
            return [(-math.pi, math.pi)]
        lo = float(wrap(start))
        hi = lo + width
        if hi > math.pi:
            pieces += [(lo, math.pi), (-math.pi, hi - TWO_PI)]
        else:
            pieces.append((lo, hi))
    pieces.sort()
    out: list[tuple[float, float]] = []
    for lo, hi in pieces:
        if out and lo <= out[-1][1] + 1e-9:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out


def _union_fov(fov: Sequence[tuple[float, float]]) -> tuple[tuple[float, float], ...]:
    arcs = _arcs(fov)
    if sum(hi - lo for lo, hi in arcs) >= TWO_PI - 1e-9:
        return ((-math.pi, TWO_PI),)
    if len(arcs) > 1 and arcs[0][0] <= -math.pi + 1e-9 and arcs[-1][1] >= math.pi - 1e-9:
        first = arcs.pop(0)  # one arc across the +-pi seam
        lo, hi = arcs.pop()
        arcs.append((lo, hi + (first[1] - first[0])))
    return tuple((lo, hi - lo) for lo, hi in arcs)


def _covers(fov: Sequence[tuple[float, float]], a: np.ndarray) -> np.ndarray:
    out = np.zeros(a.shape, dtype=bool)
    for start, width in fov:
        out |= np.mod(a - start, TWO_PI) < width + 1e-12
    return out


def merge_scans(
    scans: Sequence[Scan],
    *,
    pose: Planar | None = None,
    timestamp: float | None = None,
) -> Scan:
    """One scan in the robot frame from several lidars' scans of one time step.

    Every beam is moved to the robot frame through its scan's
    ``sensor_offset``: a return becomes the bearing and range of its end point
    seen from the robot's origin; a beam without a return keeps its direction
    (a point at infinity) with range ``inf``. Where fields of view overlap,
    a bearing is served by the lidar whose field of view's centre is nearest
    to it (no interleaving of two lidars' beams). The beams are sorted by
    bearing, starting after the widest gap, and the result's ``coverage`` is
    the union of the scans' fields of view.

    Parameters
    ----------
    scans : sequence of Scan
        At least one; each with its lidar's ``sensor_offset`` (metres, radians).
    pose : (x, y, theta), optional
        The robot's pose (default: the first scan's).
    timestamp : float, optional
        Seconds (default: the first scan's).

    Returns
    -------
    Scan
        ``sensor_offset`` zero; intensities when every scan has them;
        ``max_range`` the largest reach from the robot's origin.
    """
    if not scans:
        raise InvalidParameterError("merge_scans needs at least one scan")
    fovs = [s.fov for s in scans]
    centres = []
    for s in scans:
        a = s.bearings + s.sensor_offset[2]
        centres.append(math.atan2(float(np.sin(a).mean()), float(np.cos(a).mean())))
    bear, rng, inten = [], [], []
    for k, s in enumerate(scans):
        ox, oy, oth = s.sensor_offset
        a = s.bearings + oth
        ok = s.valid
        with np.errstate(invalid="ignore"):
            px = np.where(ok, ox + s.ranges * np.cos(a), np.nan)
            py = np.where(ok, oy + s.ranges * np.sin(a), np.nan)
        b = np.where(ok, np.arctan2(py, px), a)
        r = np.where(ok, np.hypot(px, py), np.inf)
        # owner of each bearing: the covering lidar with the nearest field-of-view centre
        dist = np.abs(wrap(b - centres[k]))
        keep = np.ones(b.shape, dtype=bool)
        for j in range(len(scans)):
            if j != k:
                dj = np.abs(wrap(b - centres[j]))
                keep &= ~(_covers(fovs[j], b) & ((dj < dist) | ((dj == dist) & (j < k))))
        bear.append(wrap(b[keep]))
        rng.append(r[keep])
        inten.append(None if s.intensities is None else s.intensities[keep])
    b = np.concatenate(bear)
    r = np.concatenate(rng)
    order = np.argsort(b, kind="stable")
    b, r = b[order], r[order]
    has_int = all(i is not None for i in inten)
    it = np.concatenate([i for i in inten if i is not None])[order] if has_int else None
    uniq = np.concatenate([[True], np.diff(b) > 1e-12])
    b, r = b[uniq], r[uniq]
    it = None if it is None else it[uniq]
    if b.size < 2:
        raise DataFormatError(f"merged scan has {b.size} beam(s); at least 2 are needed")
    # start after the widest gap (the circular one included) so that bearings increase without a seam
    gaps = np.diff(np.concatenate([b, [b[0] + TWO_PI]]))
    cut = (int(np.argmax(gaps)) + 1) % b.size
    b = np.concatenate([b[cut:], b[:cut] + TWO_PI])
    r = np.concatenate([r[cut:], r[:cut]])
    it = None if it is None else np.concatenate([it[cut:], it[:cut]])
    b = b - TWO_PI * math.floor((0.5 * (b[0] + b[-1]) + math.pi) / TWO_PI)
    reach = max(s.max_range + math.hypot(s.sensor_offset[0], s.sensor_offset[1]) for s in scans)
    return Scan(
        ranges=r,
        bearings=b,
        max_range=reach,
        intensities=it,
        pose=scans[0].pose if pose is None else pose,
        timestamp=scans[0].timestamp if timestamp is None else timestamp,
        coverage=_union_fov([f for fov in fovs for f in fov]),
    )


# ---------------------------------------------------------------------------
# resolving a bag: pose source, base frame, mounts


def _parse_pose_source(pose_source: str, odom_topic: str | None) -> tuple[str, str | None]:
    kind, _, arg = str(pose_source).partition(":")
    if kind not in ("auto", "odom", "tf", "none") or (arg and kind not in ("odom", "tf")):
        raise InvalidParameterError(
            f"pose_source / --pose-source must be auto, none, tf, tf:FRAME, odom or odom:TOPIC, got {pose_source!r}"
        )
    if kind == "odom" and arg and odom_topic is not None and odom_topic != arg:
        raise InvalidParameterError(f"pose_source {pose_source!r} and odom_topic {odom_topic!r} disagree")
    if kind == "odom":
        return kind, arg or odom_topic
    if kind == "tf":
        return kind, arg.lstrip("/") or None
    return kind, None


@dataclass(slots=True)
class _Poses:
    kind: str  # "odom", "tf" or "none"
    odom: _Series | None
    odom_topic: str | None
    odom_child: str | None
    tree: _TfTree | None


def _collect_poses(reader: Any, info: BagInfo, pose_source: str, odom_topic: str | None) -> _Poses:
    """Read the pose messages: an odometry series (when asked or auto) and the transform tree."""
    kind, arg = _parse_pose_source(pose_source, odom_topic)
    odoms = info.of_type(ODOMETRY)
    tfs = [t for t in info.of_type(TF_MESSAGE) if t.rstrip("/").split("/")[-1] in ("tf", "tf_static")]
    dynamic_tf = [t for t in tfs if not t.rstrip("/").endswith("tf_static")]
    if kind == "odom" and arg is not None and arg not in odoms:
        raise InvalidParameterError(
            f"no {ODOMETRY} topic {arg!r} in {info.path} (odometry topics: {', '.join(odoms) or 'none'})"
        )
    if odom_topic is not None and odom_topic not in odoms:
        raise InvalidParameterError(
            f"no {ODOMETRY} topic {odom_topic!r} in {info.path} (odometry topics: {', '.join(odoms) or 'none'})"
        )
    if kind == "auto" and (odoms or odom_topic is not None):
        kind = "odom"
    if kind == "odom" and not odoms:
        raise InvalidParameterError(f"pose source 'odom': {info.path} has no {ODOMETRY} topic")
    if kind == "tf" and not dynamic_tf:
        raise InvalidParameterError(f"pose source 'tf': {info.path} has no /tf topic")
    use_odom = arg if (kind == "odom" and arg) else (odom_topic or (odoms[0] if kind == "odom" else None))
    wanted = ([use_odom] if use_odom else []) + tfs  # the tree is read whenever it exists: it gives the mounts
    conns = [c for c in reader.connections if c.topic in wanted]
    odom = _Series() if use_odom else None
    child: str | None = None
    tree = _TfTree() if tfs else None
    for conn, ns, raw in reader.messages(connections=conns) if conns else ():
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception:
            continue  # a broken pose message is as good as a missing one
        if conn.msgtype == ODOMETRY and odom is not None:
            p = msg.pose.pose
            odom.add(_stamp(msg.header, ns), Transform3.from_msg(p.position, p.orientation))
            if child is None and str(msg.child_frame_id).strip("/"):
                child = str(msg.child_frame_id).strip("/")
        elif conn.msgtype == TF_MESSAGE and tree is not None:
            static = conn.topic.rstrip("/").endswith("tf_static")
            for tf in msg.transforms:
                value = Transform3.from_msg(tf.transform.translation, tf.transform.rotation)
                tree.add(str(tf.header.frame_id), str(tf.child_frame_id), _stamp(tf.header, ns), value, static=static)
    if odom is not None:
        odom.freeze()
    if tree is not None:
        tree.freeze()
    return _Poses(kind, odom, use_odom, child, tree)


@dataclass(slots=True)
class _Probe:
    frames: dict[str, str]
    first_stamp: dict[str, float]
    period: float | None


def _probe(reader: Any, info: BagInfo, topics: Sequence[str]) -> _Probe:
    """Frame of each topic's first scan, and the reference topic's scan period (from its first scans)."""
    conns = [c for c in reader.connections if c.topic in topics]
    frames: dict[str, str] = {}
    first: dict[str, float] = {}
    ref_stamps: list[float] = []
    scan_times: list[float] = []
    present = {t for t in topics if info.topics[t][1] > 0}
    n_ref = min(_PROBE_SCANS, info.topics[topics[0]][1])

    def done() -> bool:
        return present <= set(frames) and len(ref_stamps) >= n_ref

    for conn, ns, raw in reader.messages(connections=conns) if conns and not done() else ():
        if conn.topic in frames and not (conn.topic == topics[0] and len(ref_stamps) < n_ref):
            continue
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception:
            continue
        t = _stamp(msg.header, ns)
        if conn.topic not in frames:
            frames[conn.topic] = str(msg.header.frame_id).strip("/")
            first[conn.topic] = t
        if conn.topic == topics[0]:
            ref_stamps.append(t)
            st = float(msg.scan_time)
            if math.isfinite(st) and st > 0:
                scan_times.append(st)
        if done():
            break
    period = None
    if scan_times:
        period = float(np.median(scan_times))
    elif len(ref_stamps) > 1:
        d = np.diff(np.sort(ref_stamps))
        d = d[d > 0]
        period = float(np.median(d)) if d.size else None
    return _Probe(frames, first, period)


def _frames_list(tree: _TfTree | None) -> str:
    return ", ".join(sorted(tree.frames())) if tree is not None and tree.frames() else "none"


def _resolve_base(
    path: Path, tree: _TfTree | None, frames: dict[str, str], base_frame: str | None
) -> tuple[str | None, str]:
    lidar = sorted(set(frames.values()))
    known = tree.frames() if tree is not None else set()
    if base_frame is not None:
        base = base_frame.strip("/")
        if not base:
            raise InvalidParameterError(f"base_frame / --base-frame must name a frame, got {base_frame!r}")
        for topic, fr in frames.items():
            if fr == base:
                continue
            if not fr:
                raise DataFormatError(
                    f"scans on {topic} have no frame_id: cannot place them in base frame {base!r}", path=path
                )
            if base not in known:
                raise DataFormatError(
                    f"base frame {base!r} is not in the /tf_static or /tf tree (frames: {_frames_list(tree)})",
                    path=path,
                )
            assert tree is not None
            if tree.common_ancestor(fr, base) is None:
                raise DataFormatError(
                    f"no transform chain from lidar frame {fr!r} ({topic}) to base frame {base!r} "
                    f"in /tf_static or /tf (frames: {_frames_list(tree)})",
                    path=path,
                )
        return base, "given"
    if not lidar:
        return None, "no scan messages"
    if tree is None or not any(f in known for f in lidar):
        if len(lidar) == 1:
            return None, f"no /tf_static mount for lidar frame {lidar[0]!r}: bearings stay in its frame"
        raise DataFormatError(
            f"the lidar frames {', '.join(map(repr, lidar))} are not linked by /tf_static or /tf "
            f"(frames: {_frames_list(tree)}); cannot merge them",
            path=path,
        )
    roots = {fr: tree.static_root(fr) for fr in lidar}
    if len(set(roots.values())) > 1:
        hang = ", ".join(f"{fr!r} -> {rt!r}" for fr, rt in roots.items())
        raise DataFormatError(
            f"the lidar frames hang off different /tf_static trees ({hang}); choose one with base_frame= / --base-frame",
            path=path,
        )
    (root,) = set(roots.values())
    return root, "root of the /tf_static tree of the lidar frame" + ("s" if len(lidar) > 1 else "")


def _fixed_frame(path: Path, poses: _Poses, base: str | None, fixed: str | None) -> str | None:
    """The frame poses are taken in for ``tf``: the given one, or the root above the base frame."""
    tree = poses.tree
    if base is None:
        raise DataFormatError(
            "pose source 'tf' needs a base frame in the /tf tree: pass base_frame= / --base-frame", path=path
        )
    assert tree is not None
    if fixed is not None:
        if fixed not in tree.frames():
            raise DataFormatError(
                f"pose frame {fixed!r} is not in the /tf tree (frames: {_frames_list(tree)})", path=path
            )
        if tree.common_ancestor(base, fixed) is None:
            raise DataFormatError(
                f"no transform chain from base frame {base!r} to pose frame {fixed!r} in /tf "
                f"(frames: {_frames_list(tree)})",
                path=path,
            )
        return fixed
    if not tree.moves(base):
        raise DataFormatError(
            f"pose source 'tf': base frame {base!r} does not move in /tf (no /tf link above it; "
            f"frames: {_frames_list(tree)}); use another pose source or base frame",
            path=path,
        )
    return tree.ancestors(base)[-1]


def _mount_at(tree: _TfTree | None, base: str | None, frame: str, t: float, max_gap: float) -> Transform3 | None:
    if base is None or frame == base or tree is None:
        return IDENTITY
    return tree.transform(base, frame, t, max_gap)


def _lidar_mount(
    tree: _TfTree | None, base: str | None, topic: str, frame: str, t: float, max_gap: float
) -> LidarMount | None:
    if base is None:
        return None
    m = _mount_at(tree, base, frame, t, max_gap)
    if m is None:
        return None
    tilt, mirrored = _tilt(m)
    r = m.matrix()
    static = tree is None or frame == base or tree.static_between(frame, base)
    return LidarMount(
        topic=topic,
        frame=frame,
        xyz=m.t,
        yaw=math.atan2(float(r[1, 0]), float(r[0, 0])),
        mirrored=mirrored,
        tilt=tilt,
        static=bool(static),
    )


def _check_args(max_pose_gap: float, pair_tolerance: float | None, max_tilt_deg: float) -> None:
    if not (max_pose_gap >= 0):
        raise InvalidParameterError(f"max_pose_gap must be >= 0 seconds, got {max_pose_gap!r}")
    if pair_tolerance is not None and not (pair_tolerance >= 0 and math.isfinite(pair_tolerance)):
        raise InvalidParameterError(f"pair_tolerance must be >= 0 seconds, got {pair_tolerance!r}")
    if not (0 <= max_tilt_deg < 90):
        raise InvalidParameterError(f"max_tilt_deg must be in [0, 90), got {max_tilt_deg!r}")


def _plan(
    p: Path,
    reader: Any,
    info: BagInfo,
    topics: tuple[str, ...],
    *,
    pose_source: str,
    odom_topic: str | None,
    base_frame: str | None,
    max_pose_gap: float,
    pair_tolerance: float | None,
) -> tuple[BagPlan, _Poses, str | None]:
    if len(topics) > 1:
        empty = [t for t in topics if info.topics[t][1] == 0]
        if empty:
            raise DataFormatError(f"scan topic {empty[0]} has no messages: nothing to merge", path=p)
    poses = _collect_poses(reader, info, pose_source, odom_topic)
    probe = _probe(reader, info, topics)
    frames = {t: probe.frames[t] for t in topics if t in probe.frames}
    base, origin = _resolve_base(p, poses.tree, frames, base_frame)
    fixed: str | None = None
    kind, arg = _parse_pose_source(pose_source, odom_topic)
    if poses.kind == "auto":
        moving = poses.tree is not None and base is not None and poses.tree.moves(base)
        poses.kind = "tf" if moving else "none"
    if poses.kind == "tf":
        fixed = _fixed_frame(p, poses, base, arg if kind == "tf" else None)
    if poses.kind == "odom":
        source = f"odom:{poses.odom_topic}"
    elif poses.kind == "tf":
        source = f"tf:{fixed}"
    else:
        source = "none"
    mounts = []
    for t in frames:
        m = _lidar_mount(poses.tree, base, t, frames[t], probe.first_stamp[t], max_pose_gap)
        if m is not None:
            mounts.append(m)
    tol = None
    if len(topics) > 1:
        tol = pair_tolerance
        if tol is None:
            tol = 0.5 * probe.period if probe.period else DEFAULT_PAIR_TOLERANCE
    plan = BagPlan(
        path=str(p),
        topics=topics,
        base_frame=base,
        base_frame_origin=origin,
        pose_source=source,
        mounts=tuple(mounts),
        pair_tolerance=tol,
    )
    return plan, poses, fixed


def _pose_at(poses: _Poses, base: str | None, fixed: str | None, t: float, max_gap: float) -> Planar | None:
    tree = poses.tree
    if poses.kind == "odom" and poses.odom is not None:
        v = poses.odom.at(t, max_gap)
        if v is None:
            return None
        child = poses.odom_child
        if tree is not None and base is not None and child and child != base and tree.common_ancestor(child, base):
            link = tree.transform(child, base, t, max_gap)  # the odometry's frame to the base frame
            if link is not None:
                v = v.compose(link)
        return v.planar()
    if poses.kind == "tf" and tree is not None and base is not None and fixed is not None:
        v = tree.transform(fixed, base, t, max_gap)
        return None if v is None else v.planar()
    return None


def bag_plan(
    path: str | Path,
    *,
    topic: str | Sequence[str] | None = None,
    pose_source: str = "auto",
    odom_topic: str | None = None,
    base_frame: str | None = None,
    max_pose_gap: float = 0.5,
    pair_tolerance: float | None = None,
) -> BagPlan:
    """What :func:`iter_bag_scans` would resolve for this bag and these options (reads the poses, not the scans)."""
    _check_args(max_pose_gap, pair_tolerance, 30.0)
    p = Path(path)
    info = bag_info(p)
    topics = _choose_scan_topics(info, topic)
    with _Open(p) as reader:
        plan, _, _ = _plan(
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
    return plan


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
        Seconds: poses and ``/tf`` links are interpolated between samples
        within this gap of the stamp (else the nearest within it, else none).
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
    _parse_pose_source(pose_source, odom_topic)
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
            for conn, ns, raw in reader.messages(connections=conns):
                st.lines += 1
                scan = decode(conn, ns, raw)
                if scan is not None:
                    st.scans += 1
                    yield scan
            return
        yield from _paired(
            reader.messages(connections=conns),
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
            inv = _invert_planar(r.pose)
            moved = [r]
            for s in parts[1:]:
                if s.pose is None:
                    moved.append(s)
                    continue
                rel = _compose_planar(inv, s.pose)  # the partner's base frame in the reference's
                moved.append(
                    Scan(
                        ranges=s.ranges,
                        bearings=s.bearings,
                        max_range=s.max_range,
                        intensities=s.intensities,
                        sensor_offset=_compose_planar(rel, s.sensor_offset),
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
