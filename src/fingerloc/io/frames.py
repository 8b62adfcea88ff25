"""Frames of a robot: 3D rigid transforms, a ``/tf``-style transform tree, lidar mounts reduced to the plane.

Used by the ROS bag reader (:mod:`fingerloc.io.rosbag`), and by anything that
must put several lidars into one robot frame:

* :class:`Transform3`, a rigid 3D transform (quaternion and translation),
  composed down a chain of ``T_parent_child`` links;
* :class:`TransformSeries`, a time series of one link, interpolated at a
  stamp (linear in translation, slerp in rotation) between the two samples
  around it when they are at most ``2 max_gap`` seconds apart, else the
  nearest sample within ``max_gap``;
* :class:`TransformTree`, links child -> parent, static or timed, with the
  transform between any two frames through their lowest common ancestor;
* :func:`reduce_to_plane`, a lidar's scan seen in the base frame's plane
  (mirrored bearings for a lidar mounted upside down);
* :func:`merge_scans`, several lidars' scans of one time step as one scan in
  the robot frame.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..angles import TWO_PI, wrap
from ..errors import DataFormatError, InvalidParameterError
from ..sensors import Scan

__all__ = [
    "IDENTITY",
    "WORLD_FRAMES",
    "Transform3",
    "TransformSeries",
    "TransformTree",
    "checked_transform",
    "compose_planar",
    "interpolate",
    "invert_planar",
    "merge_scans",
    "mount_tilt",
    "reduce_to_plane",
]

Planar = tuple[float, float, float]

#: Frames a robot moves in (REP 105 names): a ``/tf`` link into one of them is never taken for a fixed mount.
WORLD_FRAMES: tuple[str, ...] = ("odom", "map", "world", "earth")


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

#: Largest translation (metres) of a transform read from a file: a robot's frames are not further apart.
MAX_TRANSLATION_M = 1e9


def checked_transform(translation: Any, rotation: Any) -> Transform3:
    """:meth:`Transform3.from_msg` of message fields, refusing what is not a rigid transform.

    Raises
    ------
    DataFormatError
        A translation that is not finite or farther than :data:`MAX_TRANSLATION_M`
        (naming ``translation``), or a rotation that is not a finite quaternion
        (naming ``rotation``; an all-zero one, an unset field, is no rotation).
    """
    try:
        t = (float(translation.x), float(translation.y), float(translation.z))
        q = (float(rotation.x), float(rotation.y), float(rotation.z), float(rotation.w))
    except (AttributeError, TypeError, ValueError) as err:
        raise DataFormatError(f"malformed transform ({err})") from None
    if not all(math.isfinite(v) and abs(v) <= MAX_TRANSLATION_M for v in t):
        raise DataFormatError(f"translation must be finite and within +-{MAX_TRANSLATION_M:g} m, got {t!r}")
    if not all(math.isfinite(v) for v in q):
        raise DataFormatError(f"rotation must be a finite quaternion, got {q!r}")
    return Transform3(t, q)


def interpolate(a: Transform3, b: Transform3, s: float) -> Transform3:
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


def compose_planar(a: Planar, b: Planar) -> Planar:
    """Planar pose composition ``a * b`` (b expressed in a's frame)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], math.remainder(a[2] + b[2], TWO_PI))


def invert_planar(a: Planar) -> Planar:
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], math.remainder(-a[2], TWO_PI))


@dataclass(slots=True)
class TransformSeries:
    """A time series of one link's transforms, interpolated at a stamp (see the module docstring).

    Attributes
    ----------
    times : list of float
        Seconds, sorted by :meth:`freeze`.
    values : list of Transform3
    constant : bool
        Static: :meth:`at` returns the first value at any time. Set by
        :meth:`freeze` when several samples all hold one value.
    """

    times: list[float] = field(default_factory=list)
    values: list[Transform3] = field(default_factory=list)
    constant: bool = False

    def add(self, t: float, value: Transform3) -> None:
        """Append one sample at ``t`` seconds (call :meth:`freeze` before :meth:`at`)."""
        self.times.append(t)
        self.values.append(value)

    def freeze(self) -> None:
        """Sort by time; a link published several times with one value becomes ``constant``."""
        order = sorted(range(len(self.times)), key=self.times.__getitem__)
        self.times = [self.times[i] for i in order]
        self.values = [self.values[i] for i in order]
        # a link published several times with one value is static (a mount re-sent on /tf)
        self.constant = len(self.values) > 1 and all(v.is_close(self.values[0]) for v in self.values)

    def at(self, t: float, max_gap: float) -> Transform3 | None:
        """The value at ``t``: interpolated between the two samples around it when they are at most
        ``2 max_gap`` seconds apart, else the nearest sample within ``max_gap``, else ``None``."""
        if not self.times:
            return None
        if self.constant:
            return self.values[0]
        i = bisect_left(self.times, t)
        if i < len(self.times) and self.times[i] == t:
            return self.values[i]
        if 0 < i < len(self.times) and self.times[i] - self.times[i - 1] <= 2.0 * max_gap:
            t0, t1 = self.times[i - 1], self.times[i]
            return interpolate(self.values[i - 1], self.values[i], (t - t0) / (t1 - t0))
        lo_ok = i > 0 and t - self.times[i - 1] <= max_gap
        hi_ok = i < len(self.times) and self.times[i] - t <= max_gap
        if lo_ok and hi_ok:
            lo_ok = t - self.times[i - 1] <= self.times[i] - t
        if lo_ok:
            return self.values[i - 1]
        if hi_ok:
            return self.values[i]
        return None


@dataclass(slots=True)
class TransformTree:
    """Transforms child -> parent (``T_parent_child``), each a time series (a static one holds one value)."""

    parent: dict[str, str] = field(default_factory=dict)
    links: dict[str, TransformSeries] = field(default_factory=dict)
    from_static: set[str] = field(default_factory=set)

    def add(self, parent: str, child: str, t: float, value: Transform3, *, static: bool) -> None:
        """Record ``T_parent_child`` at ``t``; a static link replaces the child's link, a timed one is ignored
        for a child that already has a static link (leading ``/`` of frame names dropped)."""
        parent, child = parent.lstrip("/"), child.lstrip("/")
        if child == parent or not child:
            return
        if static:
            self.parent[child] = parent
            self.from_static.add(child)
            self.links[child] = TransformSeries([t], [value], constant=True)
        elif child not in self.from_static:
            self.parent[child] = parent
            self.links.setdefault(child, TransformSeries()).add(t, value)

    def freeze(self) -> None:
        """Sort every timed link (see :meth:`TransformSeries.freeze`)."""
        for child, s in self.links.items():
            if child not in self.from_static:
                s.freeze()

    def frames(self) -> set[str]:
        """Every frame named in the tree."""
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

    def static_root(self, frame: str, *, fixed_frames: Sequence[str] = WORLD_FRAMES) -> str:
        """The frame reached walking up static links from ``frame``.

        Static links are those of ``/tf_static``, and ``/tf`` links that never
        change (older bags publish a robot's fixed joints on ``/tf``), except a
        ``/tf`` link into one of ``fixed_frames``: a robot that stands still
        for a whole bag is still not part of its ``odom`` frame.
        """
        seen = {frame}
        while frame in self.links and self.parent[frame] not in seen:
            link = self.links[frame]
            if not (frame in self.from_static or (link.constant and self.parent[frame] not in fixed_frames)):
                break
            frame = self.parent[frame]
            seen.add(frame)
        return frame

    def common_ancestor(self, a: str, b: str) -> str | None:
        """The lowest frame above (or equal to) both ``a`` and ``b``; ``None`` when they are in different trees."""
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
# mounts and merging


def mount_tilt(mount: Transform3) -> tuple[float, bool]:
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
    tilt, mirrored = mount_tilt(mount)
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


def _relative(intensities: np.ndarray) -> np.ndarray:
    """A lidar's intensities over their median positive finite value (unchanged when it has none)."""
    v = np.asarray(intensities, dtype=np.float64)
    pos = v[np.isfinite(v) & (v > 0)]
    if pos.size == 0:
        return v
    return v / float(np.median(pos))


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
    a bearing is served by the lidar whose field of view's centre (its mean
    beam direction) is nearest to it (no interleaving of two lidars' beams).
    The beams are sorted by bearing, in ``[-pi, pi)`` when the fields of view
    close the circle, else starting after the widest gap; the result's
    ``coverage`` is the union of the scans' fields of view.

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
        ``sensor_offset`` zero; ``max_range`` the largest reach from the
        robot's origin; intensities when any scan has them, each lidar's
        divided by its own median (lidars of different makes report on
        different scales: so that a beacon one lidar alone sees stands out of
        the merged scan as it stood out of its own; ``NaN`` for the beams of a
        lidar without intensities, which the beacon detector skips).
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
        inten.append(None if s.intensities is None else _relative(s.intensities)[keep])
    b = np.concatenate(bear)
    r = np.concatenate(rng)
    order = np.argsort(b, kind="stable")
    b, r = b[order], r[order]
    has_int = any(i is not None for i in inten)
    it = None
    if has_int:
        it = np.concatenate([np.full(x.shape, np.nan) if i is None else i for x, i in zip(rng, inten, strict=True)])
        it = it[order]
    uniq = np.concatenate([[True], np.diff(b) > 1e-12])
    b, r = b[uniq], r[uniq]
    it = None if it is None else it[uniq]
    if b.size < 2:
        raise DataFormatError(f"merged scan has {b.size} beam(s); at least 2 are needed")
    coverage = _union_fov([f for fov in fovs for f in fov])
    if coverage[0][1] < TWO_PI:
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
        coverage=coverage,
    )
