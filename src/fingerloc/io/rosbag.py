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
from bisect import bisect_left
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..errors import DataFormatError, InvalidParameterError
from ..sensors import Scan
from .carmen import ReadStats
from .frames import (
    IDENTITY,
    Transform3,
    TransformSeries,
    TransformTree,
    compose_planar,
    invert_planar,
    merge_scans,
    mount_tilt,
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

#: File name endings taken for ROS bags (a folder holding ``metadata.yaml`` is a ROS 2 bag too).
BAG_EXTENSIONS: tuple[str, ...] = (".bag", ".db3", ".mcap")

LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
#: Transform message types: tf2's, and tf's of older ROS 1 bags (same fields).
TF_MESSAGES: tuple[str, ...] = (TF_MESSAGE, "tf/msg/tfMessage")

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
        s = TransformSeries(self.times, [Transform3.from_planar(p) for p in self.poses])
        v = s.at(t, max_gap)
        return None if v is None else v.planar()


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
            if m.tilt > 1e-6:
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
# resolving a bag: pose source, base frame, mounts


def parse_pose_source(pose_source: str, odom_topic: str | None = None) -> tuple[str, str | None]:
    """Split a pose source into its kind (``auto``, ``none``, ``tf``, ``odom``) and argument (frame or topic).

    Raises
    ------
    InvalidParameterError
        Not one of ``auto``, ``none``, ``tf``, ``tf:FRAME``, ``odom``, ``odom:TOPIC``, or a topic that
        disagrees with ``odom_topic``.
    """
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
    odom: TransformSeries | None
    odom_topic: str | None
    odom_child: str | None
    tree: TransformTree | None


def _collect_poses(reader: Any, info: BagInfo, pose_source: str, odom_topic: str | None) -> _Poses:
    """Read the pose messages: an odometry series (when asked or auto) and the transform tree."""
    kind, arg = parse_pose_source(pose_source, odom_topic)
    odoms = info.of_type(ODOMETRY)
    tfs = sorted(t for m in TF_MESSAGES for t in info.of_type(m) if t.rstrip("/").split("/")[-1] in ("tf", "tf_static"))
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
    odom = TransformSeries() if use_odom else None
    child: str | None = None
    tree = TransformTree() if tfs else None
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
        elif conn.msgtype in TF_MESSAGES and tree is not None:
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


def _frames_list(tree: TransformTree | None) -> str:
    return ", ".join(sorted(tree.frames())) if tree is not None and tree.frames() else "none"


def _resolve_base(
    path: Path, tree: TransformTree | None, frames: dict[str, str], base_frame: str | None
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
            f"the lidar frames hang off different static trees ({hang}); choose one with base_frame= / --base-frame",
            path=path,
        )
    (root,) = set(roots.values())
    return root, "root of the static transforms above the lidar frame" + ("s" if len(lidar) > 1 else "")


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


def _mount_at(tree: TransformTree | None, base: str | None, frame: str, t: float, max_gap: float) -> Transform3 | None:
    if base is None or frame == base or tree is None:
        return IDENTITY
    return tree.transform(base, frame, t, max_gap)


def _lidar_mount(
    tree: TransformTree | None, base: str | None, topic: str, frame: str, t: float, max_gap: float
) -> LidarMount | None:
    if base is None:
        return None
    m = _mount_at(tree, base, frame, t, max_gap)
    if m is None:
        return None
    tilt, mirrored = mount_tilt(m)
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
    kind, arg = parse_pose_source(pose_source, odom_topic)
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
