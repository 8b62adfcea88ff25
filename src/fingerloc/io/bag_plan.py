"""How a ROS bag's scans are put in the robot's frame: base frame, lidar mounts, pose source, pairing.

The rules are in :mod:`fingerloc.io.rosbag`'s docstring; this module
resolves them for one bag (:func:`bag_plan`, :class:`BagPlan`) from its
``/tf_static`` and ``/tf`` trees, its odometry and a look at its first scans.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..errors import DataFormatError, InvalidParameterError
from ._bag_messages import ODOMETRY, TF_MESSAGES, BagInfo, _choose_scan_topics, _Open, _stamp, bag_info, messages
from .frames import IDENTITY, Transform3, TransformSeries, TransformTree, mount_tilt

__all__ = ["BagPlan", "LidarMount", "PoseTrack", "bag_plan", "parse_pose_source"]

#: Pairing tolerance (s) when the reference topic's scan period cannot be told (a single scan, no ``scan_time``).
DEFAULT_PAIR_TOLERANCE = 0.05

#: Reference scans probed to estimate the scan period.
_PROBE_SCANS = 21

#: Reference scans held back waiting for a partner before the oldest is settled anyway.
_MAX_PENDING = 64

PoseSource = Literal["auto", "odom", "tf", "none"]

Planar = tuple[float, float, float]



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


def _transform(where: str, translation: Any, rotation: Any, path: str) -> Transform3:
    """A transform of a message, its numbers checked (one line naming the topic and the field)."""
    from .frames import checked_transform

    try:
        return checked_transform(translation, rotation)
    except DataFormatError as err:
        raise DataFormatError(f"{where}: {err.message}", path=path) from None


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
    for conn, ns, raw in messages(reader, conns, Path(info.path)):
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception:
            continue  # a broken pose message is as good as a missing one
        if conn.msgtype == ODOMETRY and odom is not None:
            p = msg.pose.pose
            odom.add(_stamp(msg.header, ns), _transform(f"{conn.topic}: pose.pose", p.position, p.orientation, info.path))
            if child is None and str(msg.child_frame_id).strip("/"):
                child = str(msg.child_frame_id).strip("/")
        elif conn.msgtype in TF_MESSAGES and tree is not None:
            static = conn.topic.rstrip("/").endswith("tf_static")
            for tf in msg.transforms:
                link = f"{conn.topic}: transform {str(tf.header.frame_id)!r} -> {str(tf.child_frame_id)!r}"
                value = _transform(link, tf.transform.translation, tf.transform.rotation, info.path)
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

    for conn, ns, raw in messages(reader, conns if not done() else [], Path(info.path)):
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


