"""The robot side of a live localizer, free of any ROS library: sensor messages in, answers out.

:class:`LiveInput` turns the messages a robot publishes into the steps a
streaming tracker takes, with the rules of the bag reader
(:mod:`fingerloc.io.rosbag`):

* **Scans** of one or several ``sensor_msgs/LaserScan`` topics. Several
  topics give one scan per scan of the first (the reference), merged in the
  base frame (:func:`~fingerloc.io.frames.merge_scans`) with, for each other
  topic, its scan nearest in time within ``pair_tolerance`` seconds (default:
  half the reference's ``scan_time``, else 0.05 s); a reference scan without
  partners is dropped (counted). A reference scan is settled once every other
  topic has a scan later than its stamp plus the tolerance.
* **Base frame and mounts**: the given base frame, or the root of the static
  transforms above the lidar frame, chosen at the first scan. A scan whose
  lidar frame ``/tf`` has not named yet waits (at most ``max_wait_s``) for it;
  then a lidar frame still unknown is its own base (a zero mount) by default,
  and a scan without a mount to a given base frame is dropped (counted); each lidar's full 3D mount at the scan's stamp,
  reduced to the plane (:func:`~fingerloc.io.frames.reduce_to_plane`:
  mirrored bearings for a lidar upside down, a lidar tilted more than
  ``max_tilt_deg`` refused).
* **Odometry**: ``nav_msgs/Odometry`` (its pose composed with the link from
  its ``child_frame_id`` to the base frame when ``/tf`` has one), or the base
  frame's pose in a ``/tf`` frame (``odom`` by default), interpolated at the
  scan's stamp between the samples around it (at most ``2 max_pose_gap``
  apart), else the nearest within ``max_pose_gap``. A scan waits until
  odometry at or after its stamp has arrived, at most ``max_wait_s`` seconds
  of wall clock (:meth:`LiveInput.poll`); then it goes with what there is.
* **Rate limit**: with ``rate_hz > 0``, a reference scan less than
  ``1 / rate_hz`` seconds (stamps) after the last step's is dropped; the
  odometry keeps the robot's motion, so the next step's increment covers it.

:class:`LiveLocalizer` feeds the steps to a tracker (``step(item, odometry=,
stamp=)``, :class:`StepTracker`) and calls the transport's publishers: the
current place when it changes, the answer as JSON, the pose with its
covariance when the filter has one. The transports (:mod:`fingerloc.ros.node`
for ROS 1, :mod:`fingerloc.ros.node2` for ROS 2) only subscribe, convert
(:mod:`fingerloc.ros.convert`) and publish.
"""

from __future__ import annotations

import math
import time
from bisect import bisect_right
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from ..errors import DataFormatError, InvalidParameterError
from ..io.frames import (
    IDENTITY,
    Transform3,
    TransformSeries,
    TransformTree,
    compose_planar,
    invert_planar,
    merge_scans,
    reduce_to_plane,
)
from ..sensors import Scan
from .convert import TransformLink

__all__ = [
    "FILTERS",
    "LiveInput",
    "LiveLocalizer",
    "LiveStats",
    "NodeConfig",
    "Step",
    "StepTracker",
    "load_tracker",
]

Planar = tuple[float, float, float]

#: The trackers a node can run.
FILTERS: tuple[str, ...] = ("pose", "places")

#: Pairing tolerance (s) when the reference topic's scan period is not known.
DEFAULT_PAIR_TOLERANCE = 0.05

#: Reference scans held back waiting for partners or odometry before the oldest is settled anyway.
MAX_PENDING = 64

#: Seconds of odometry and ``/tf`` history kept.
HISTORY_S = 30.0


class StepTracker(Protocol):
    """What the node needs of a tracker: one step per scan (see ``fingerloc.pipeline.tracker.Tracker``)."""

    def step(self, item: Any = None, odometry: Any = None, stamp: float | None = None) -> Any: ...


@dataclass(frozen=True, slots=True)
class NodeConfig:
    """A node's parameters (ROS parameter names in brackets, private: ``~name``).

    Attributes
    ----------
    database : str
        The place database made by ``fingerloc map`` [``database``, required].
    scan_topics : tuple of str
        ``sensor_msgs/LaserScan`` topics, the reference first [``scan_topics``: a list, or names separated by commas].
    pose_source : str
        ``odom`` (a ``nav_msgs/Odometry`` topic, ``odom_topic``), ``tf`` / ``tf:FRAME`` (the base frame's pose
        in FRAME, default ``odom``, from ``/tf``) or ``none`` [``pose_source``].
    odom_topic : str
        [``odom_topic``].
    base_frame : str
        The robot's frame; empty: the root of the static transforms above the lidar frame [``base_frame``].
    map_frame : str
        The ``frame_id`` of the published pose: the frame of the map's poses [``map_frame``].
    filter : str
        ``pose`` (the particle filter, gives a pose) or ``places`` [``filter``].
    seed : int
        [``seed``].
    rate_hz : float
        Most steps a second (stamps), 0: every scan [``rate``].
    pair_tolerance : float or None
        Seconds; None: half the reference's scan period [``pair_tolerance``, <= 0: default].
    max_pose_gap : float
        Seconds [``max_pose_gap``].
    max_wait_s : float
        Wall-clock seconds a scan waits for odometry [``max_wait``].
    max_tilt_deg : float
        [``max_tilt_deg``].
    scan, heading : bool
        The pose filter's scan and heading evidence [``scan_evidence``, ``heading_evidence``].
    queue_size : int
        Messages queued per scan topic [``queue_size``].
    """

    database: str
    scan_topics: tuple[str, ...] = ("scan",)
    pose_source: str = "odom"
    odom_topic: str = "odom"
    base_frame: str = ""
    map_frame: str = "map"
    filter: str = "pose"
    seed: int = 0
    rate_hz: float = 0.0
    pair_tolerance: float | None = None
    max_pose_gap: float = 0.5
    max_wait_s: float = 0.5
    max_tilt_deg: float = 30.0
    scan: bool = True
    heading: bool = True
    queue_size: int = 10

    def __post_init__(self) -> None:
        if not self.database:
            raise InvalidParameterError("~database: give the place database made by 'fingerloc map'")
        if not self.scan_topics or any(not t for t in self.scan_topics):
            raise InvalidParameterError(f"~scan_topics: give one or more topic names, got {list(self.scan_topics)!r}")
        if len(set(self.scan_topics)) != len(self.scan_topics):
            raise InvalidParameterError(f"~scan_topics: a topic is given twice: {list(self.scan_topics)!r}")
        kind, _, arg = self.pose_source.partition(":")
        if kind not in ("odom", "tf", "none") or (arg and kind != "tf"):
            raise InvalidParameterError(f"~pose_source must be odom, tf, tf:FRAME or none, got {self.pose_source!r}")
        if kind == "odom" and not self.odom_topic:
            raise InvalidParameterError("~odom_topic: give the nav_msgs/Odometry topic (or ~pose_source tf / none)")
        if self.filter not in FILTERS:
            raise InvalidParameterError(f"~filter must be one of {', '.join(FILTERS)}, got {self.filter!r}")
        for name, v, low in (("rate", self.rate_hz, 0.0), ("max_pose_gap", self.max_pose_gap, 0.0),
                             ("max_wait", self.max_wait_s, 0.0)):  # fmt: skip
            if not (math.isfinite(v) and v >= low):
                raise InvalidParameterError(f"~{name} must be a finite number >= {low:g}, got {v!r}")
        if self.pair_tolerance is not None and not (math.isfinite(self.pair_tolerance) and self.pair_tolerance > 0):
            raise InvalidParameterError(
                f"~pair_tolerance must be a positive number of seconds, got {self.pair_tolerance!r}"
            )
        if not (0 <= self.max_tilt_deg < 90):
            raise InvalidParameterError(f"~max_tilt_deg must be in [0, 90), got {self.max_tilt_deg!r}")
        if self.queue_size < 1:
            raise InvalidParameterError(f"~queue_size must be >= 1, got {self.queue_size!r}")

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> NodeConfig:
        """From ROS parameters by their names (see the attributes); a missing one takes its default.

        Raises
        ------
        InvalidParameterError
            Naming the parameter: a wrong type or value, or an unknown name.
        """
        known = {"database", "scan_topics", "pose_source", "odom_topic", "base_frame", "map_frame", "filter", "seed",
                 "rate", "pair_tolerance", "max_pose_gap", "max_wait", "max_tilt_deg", "scan_evidence",
                 "heading_evidence", "queue_size"}  # fmt: skip
        unknown = sorted(set(params) - known)
        if unknown:
            raise InvalidParameterError(f"~{unknown[0]}: unknown parameter (known: {', '.join(sorted(known))})")
        out: dict[str, Any] = {}

        def text(name: str, attr: str) -> None:
            if name in params:
                v = params[name]
                if not isinstance(v, str):
                    raise InvalidParameterError(f"~{name} must be a string, got {v!r}")
                out[attr] = v.strip()

        def number(name: str, attr: str, kind: type) -> None:
            if name in params:
                v = params[name]
                if (
                    isinstance(v, bool)
                    or not isinstance(v, (int, float))
                    or (kind is int and not float(v).is_integer())
                ):
                    raise InvalidParameterError(
                        f"~{name} must be {'an integer' if kind is int else 'a number'}, got {v!r}"
                    )
                out[attr] = kind(v)

        def flag(name: str, attr: str) -> None:
            if name in params:
                v = params[name]
                if not isinstance(v, bool):
                    raise InvalidParameterError(f"~{name} must be true or false, got {v!r}")
                out[attr] = v

        for name in ("database", "pose_source", "odom_topic", "base_frame", "map_frame", "filter"):
            text(name, name)
        if "scan_topics" in params:
            v = params["scan_topics"]
            items = v.split(",") if isinstance(v, str) else v
            if not isinstance(items, (list, tuple)) or not all(isinstance(t, str) for t in items):
                raise InvalidParameterError(f"~scan_topics must be a list of topic names, got {v!r}")
            out["scan_topics"] = tuple(t.strip() for t in items)
        number("seed", "seed", int)
        number("rate", "rate_hz", float)
        number("max_pose_gap", "max_pose_gap", float)
        number("max_wait", "max_wait_s", float)
        number("max_tilt_deg", "max_tilt_deg", float)
        number("queue_size", "queue_size", int)
        number("pair_tolerance", "pair_tolerance", float)
        if out.get("pair_tolerance") is not None and out["pair_tolerance"] <= 0:
            out["pair_tolerance"] = None
        flag("scan_evidence", "scan")
        flag("heading_evidence", "heading")
        if "database" not in out:
            raise InvalidParameterError("~database: give the place database made by 'fingerloc map'")
        return cls(**out)

    @property
    def fixed_frame(self) -> str:
        """The frame of the ``tf`` pose source (``odom`` unless ``tf:FRAME`` names one)."""
        return self.pose_source.partition(":")[2] or "odom"


@dataclass(frozen=True, slots=True)
class Step:
    """A scan ready for the tracker: in the robot frame, with the odometry pose at its stamp (or None)."""

    scan: Scan
    odometry: Planar | None
    stamp: float


@dataclass(slots=True)
class LiveStats:
    """What the input dropped, by reason (counters)."""

    scans: int = 0
    steps: int = 0
    rate_limited: int = 0
    unpaired: int = 0
    unmounted: int = 0
    bad: int = 0
    stale: int = 0
    notes: list[str] = field(default_factory=list)

    def note(self, text: str) -> None:
        """Keep one note (the first few)."""
        if len(self.notes) < 20:
            self.notes.append(text)


def _add_sample(series: TransformSeries, t: float, value: Transform3, history_s: float) -> None:
    """Add a sample keeping the series sorted, ``constant`` up to date and at most ``history_s`` seconds long.

    ``constant`` (a link that never changed: a mount re-sent on ``/tf``) stays
    true while every new value equals the first one.
    """
    was_constant = series.constant or len(series.values) == 1
    first = series.values[0] if series.values else value
    k = bisect_right(series.times, t)
    if k and series.times[k - 1] == t:
        series.values[k - 1] = value  # a repeated stamp: the newer value
    else:
        series.times.insert(k, t)
        series.values.insert(k, value)
    series.constant = len(series.values) > 1 and was_constant and value.is_close(first)
    cut = series.times[-1] - history_s
    n = 0
    while n < len(series.times) - 2 and series.times[n] < cut:
        n += 1
    if n:
        del series.times[:n], series.values[:n]


class LiveInput:
    """Messages in, :class:`Step` out (see the module docstring for the rules).

    Parameters
    ----------
    config : NodeConfig
    clock : callable, optional
        Wall clock in seconds (default :func:`time.monotonic`), for ``max_wait_s``.
    """

    def __init__(self, config: NodeConfig, *, clock: Callable[[], float] = time.monotonic) -> None:
        self.config = config
        self.clock = clock
        self.tree = TransformTree()
        self.odom = TransformSeries()
        self.odom_child: str | None = None
        self.stats = LiveStats()
        self.base: str | None = config.base_frame.strip("/") or None
        self._pose_kind = config.pose_source.partition(":")[0]
        self._tf_latest = -math.inf
        self._pending: deque[tuple[Scan, str, float]] = deque()  # reference scans (lidar frame), frame, arrival
        self._partners: dict[str, deque[tuple[Scan, str]]] = {t: deque() for t in config.scan_topics[1:]}
        self._latest: dict[str, float] = dict.fromkeys(config.scan_topics[1:], -math.inf)
        self._periods: list[float] = []
        self._last_ref: float | None = None
        self._last_step: float | None = None

    # -- messages in

    def add_transforms(self, links: Sequence[TransformLink], *, static: bool) -> None:
        """Take in the links of a ``/tf`` (``static=False``) or ``/tf_static`` message."""
        for ln in links:
            if not ln.child or ln.child == ln.parent:
                continue
            if static or ln.child in self.tree.from_static:
                self.tree.add(ln.parent, ln.child, ln.stamp, ln.transform, static=static)
                continue
            self.tree.parent[ln.child] = ln.parent
            _add_sample(self.tree.links.setdefault(ln.child, TransformSeries()), ln.stamp, ln.transform, HISTORY_S)
            self._tf_latest = max(self._tf_latest, ln.stamp)

    def add_odometry(self, stamp: float, pose: Transform3, child_frame: str = "") -> None:
        """Take in one ``nav_msgs/Odometry`` reading (``pose`` = ``T_odom_child``)."""
        _add_sample(self.odom, stamp, pose, HISTORY_S)
        if child_frame and self.odom_child is None:
            self.odom_child = child_frame

    def add_scan(self, topic: str, scan: Scan, frame: str) -> list[Step]:
        """Take in one scan (lidar frame, ``timestamp`` its stamp) of ``topic``; returns the steps now ready."""
        t = float(scan.timestamp or 0.0)
        self.stats.scans += 1
        if topic == self.config.scan_topics[0]:
            if self._last_ref is not None and t > self._last_ref and len(self._periods) < 21:
                self._periods.append(t - self._last_ref)
            self._last_ref = t
            if (
                self.config.rate_hz > 0
                and self._last_step is not None
                and t < self._last_step + 1.0 / self.config.rate_hz
            ):
                self.stats.rate_limited += 1
                return self.ready()
            self._pending.append((scan, frame, self.clock()))
        elif topic in self._partners:
            self._partners[topic].append((scan, frame))
            self._latest[topic] = max(self._latest[topic], t)
        else:
            raise InvalidParameterError(f"scan topic {topic!r} is not one of {', '.join(self.config.scan_topics)}")
        return self.ready()

    # -- steps out

    @property
    def pair_tolerance(self) -> float:
        """Seconds between a reference scan and its partners."""
        if self.config.pair_tolerance is not None:
            return self.config.pair_tolerance
        if self._periods:
            return 0.5 * sorted(self._periods)[len(self._periods) // 2]
        return DEFAULT_PAIR_TOLERANCE

    def _pose_clock(self) -> float:
        if self._pose_kind == "odom":
            return self.odom.times[-1] if self.odom.times else -math.inf
        if self._pose_kind == "tf":
            return self._tf_latest
        return math.inf

    def _is_ready(self, scan: Scan, frame: str, arrived: float, now: float) -> bool:
        t = float(scan.timestamp or 0.0)
        if len(self._pending) > MAX_PENDING or now - arrived >= self.config.max_wait_s:
            return True
        if frame and frame != self.base and frame not in self.tree.frames():
            return False  # the lidar's mount (and the default base frame) come from /tf_static: wait for it
        tol = self.pair_tolerance
        if any(self._latest[o] <= t + tol for o in self._partners):
            return False
        return self._pose_clock() >= t + (tol if self._partners else 0.0)

    def ready(self) -> list[Step]:
        """Settle every pending reference scan whose partners and odometry have arrived (or waited long enough)."""
        out: list[Step] = []
        now = self.clock()
        while self._pending and self._is_ready(*self._pending[0], now):
            scan, frame, arrived = self._pending.popleft()
            if now - arrived >= self.config.max_wait_s and self._pose_clock() < float(scan.timestamp or 0.0):
                self.stats.stale += 1
            step = self._settle(scan, frame)
            if step is not None:
                self._last_step = step.stamp
                self.stats.steps += 1
                out.append(step)
        return out

    def poll(self) -> list[Step]:
        """The steps whose wait is over by the wall clock (call it from a timer)."""
        return self.ready()

    def pose_at(self, t: float) -> Planar | None:
        """The base frame's odometry pose at ``t`` (see the module docstring), or None."""
        gap = self.config.max_pose_gap
        if self._pose_kind == "odom":
            v = self.odom.at(t, gap)
            if v is None:
                return None
            child, base = self.odom_child, self.base
            if child and base and child != base and self.tree.common_ancestor(child, base) is not None:
                link = self.tree.transform(child, base, t, gap)
                if link is not None:
                    v = v.compose(link)
            return v.planar()
        if self._pose_kind == "tf" and self.base is not None:
            w = self.tree.transform(self.config.fixed_frame, self.base, t, gap)
            return None if w is None else w.planar()
        return None

    def _mount(self, frame: str, t: float) -> Transform3 | None:
        if self.base is None:  # the first scan fixes the base frame
            if frame in self.tree.frames():
                self.base = self.tree.static_root(frame)
                self.stats.note(f"base frame {self.base!r}: the root of the static transforms above {frame!r}")
            else:
                self.base = frame
                self.stats.note(f"base frame {frame!r}: no /tf mount for the lidar frame, bearings stay in its frame")
        if frame == self.base or not frame:
            return IDENTITY
        return self.tree.transform(self.base, frame, t, self.config.max_pose_gap)

    def _in_base(self, scan: Scan, frame: str) -> Scan | None:
        t = float(scan.timestamp or 0.0)
        mount = self._mount(frame, t)
        if mount is None:
            self.stats.unmounted += 1
            self.stats.note(f"no transform from lidar frame {frame!r} to base frame {self.base!r} at {t:.3f} s")
            return None
        placed = Scan(ranges=scan.ranges, bearings=scan.bearings, max_range=scan.max_range,
                      intensities=scan.intensities, pose=self.pose_at(t), timestamp=scan.timestamp)  # fmt: skip
        try:
            return reduce_to_plane(
                placed, mount, max_tilt_deg=self.config.max_tilt_deg, frame=frame, base=str(self.base)
            )
        except DataFormatError as err:
            self.stats.bad += 1
            self.stats.note(str(err))
            return None

    def _settle(self, ref: Scan, frame: str) -> Step | None:
        t = float(ref.timestamp or 0.0)
        r = self._in_base(ref, frame)
        if r is None:
            return None
        if not self._partners:
            return Step(r, r.pose, t)
        tol = self.pair_tolerance
        parts = [r]
        for topic, buf in self._partners.items():
            while buf and float(buf[0][0].timestamp or 0.0) < t - tol:
                buf.popleft()  # too old for this and every later reference scan
            best = min(buf, key=lambda s: abs(float(s[0].timestamp or 0.0) - t), default=None)
            if best is None or abs(float(best[0].timestamp or 0.0) - t) > tol:
                self.stats.unpaired += 1
                self.stats.note(
                    f"no {topic} scan within {tol:.3f} s of the {self.config.scan_topics[0]} scan at {t:.3f} s"
                )
                return None
            s = self._in_base(*best)
            if s is None:
                return None
            parts.append(s)
        if r.pose is not None:
            inv = invert_planar(r.pose)
            moved = [r]
            for s in parts[1:]:
                if s.pose is None:
                    moved.append(s)
                    continue
                rel = compose_planar(inv, s.pose)  # the partner's base frame in the reference's
                moved.append(Scan(ranges=s.ranges, bearings=s.bearings, max_range=s.max_range, intensities=s.intensities,
                                  sensor_offset=compose_planar(rel, s.sensor_offset), timestamp=s.timestamp))  # fmt: skip
            parts = moved
        try:
            merged = merge_scans(parts, pose=r.pose, timestamp=r.timestamp)
        except DataFormatError as err:
            self.stats.bad += 1
            self.stats.note(str(err))
            return None
        return Step(merged, r.pose, t)


def load_tracker(config: NodeConfig) -> StepTracker:
    """The streaming tracker of ``config.database`` with the node's filter, seed and evidence options."""
    import fingerloc as fl

    place_map = fl.load_map(config.database)
    tracker: StepTracker = place_map.tracker(filter=config.filter, seed=config.seed, scan=config.scan,
                                             heading=config.heading)  # fmt: skip
    return tracker


Publish = Callable[[Any], None]


class LiveLocalizer:
    """A tracker fed by a :class:`LiveInput`, its answers handed to the transport's publishers.

    Parameters
    ----------
    tracker : StepTracker
    config : NodeConfig
    on_place : callable
        Called with the best place label (str) at the first answer and whenever it changes.
    on_answer : callable
        Called with every answer.
    on_pose : callable, optional
        Called with every answer that has a pose.
    clock : callable, optional
        Wall clock for the input's waits.
    """

    def __init__(
        self,
        tracker: StepTracker,
        config: NodeConfig,
        *,
        on_place: Publish,
        on_answer: Publish,
        on_pose: Publish | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.tracker = tracker
        self.config = config
        self.input = LiveInput(config, clock=clock)
        self.on_place = on_place
        self.on_answer = on_answer
        self.on_pose = on_pose
        self.place: str | None = None
        self.answers = 0

    def _run(self, steps: list[Step]) -> list[Any]:
        out = []
        for s in steps:
            ans = self.tracker.step(s.scan, odometry=s.odometry, stamp=s.stamp)
            self.answers += 1
            if ans.place != self.place:
                self.place = ans.place
                self.on_place(ans.place)
            self.on_answer(ans)
            if self.on_pose is not None and getattr(ans, "pose", None) is not None:
                self.on_pose(ans)
            out.append(ans)
        return out

    def scan(self, topic: str, scan: Scan, frame: str) -> list[Any]:
        """One scan message in; the answers it completed."""
        return self._run(self.input.add_scan(topic, scan, frame))

    def odometry(self, stamp: float, pose: Transform3, child_frame: str = "") -> list[Any]:
        """One odometry message in; the answers it completed (scans that waited for it)."""
        self.input.add_odometry(stamp, pose, child_frame)
        return self._run(self.input.ready())

    def transforms(self, links: Sequence[TransformLink], *, static: bool) -> list[Any]:
        """One ``/tf`` or ``/tf_static`` message in; the answers it completed."""
        self.input.add_transforms(links, static=static)
        return self._run(self.input.ready())

    def poll(self) -> list[Any]:
        """The answers of scans whose wait is over (call it from a timer)."""
        return self._run(self.input.poll())
