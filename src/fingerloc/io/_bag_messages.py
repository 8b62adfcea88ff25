"""ROS bags at the message level: opening a bag, its topics, one ``sensor_msgs/LaserScan`` message as a scan.

The reading layer under :mod:`fingerloc.io.rosbag` (which streams scans) and
:mod:`fingerloc.io.bag_plan` (which resolves frames and poses). Every value
taken from a message is checked: a range, an angle or an increment that is
not a finite number is refused with one line naming the topic and field, and
any error of the rosbags library while a bag is opened or read becomes a
:class:`~fingerloc.errors.DataFormatError`.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..errors import DataFormatError, InvalidParameterError
from ..sensors import Scan
from .carmen import ReadStats

__all__ = [
    "BAG_EXTENSIONS",
    "BagInfo",
    "BagReadStats",
    "bag_info",
    "is_bag_path",
    "messages",
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
        try:
            topics = {str(name): (str(info.msgtype), int(info.msgcount)) for name, info in reader.topics.items()}
        except Exception as err:  # rosbags' ReaderError, a UnicodeDecodeError of a damaged header...
            raise DataFormatError(f"not a readable ROS bag: {type(err).__name__}: {err}", path=p) from None
    return BagInfo(path=str(p), topics=topics)


def messages(reader: Any, connections: Sequence[Any], path: Path) -> Iterator[tuple[Any, int, bytes]]:
    """``reader.messages(connections=...)`` with any error of the reading itself (a damaged chunk or
    index, an undecodable header) turned into one :class:`DataFormatError` line."""
    if not connections:
        return
    n = 0
    it = iter(reader.messages(connections=list(connections)))
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except Exception as err:  # rosbags raises several unrelated types here
            raise DataFormatError(
                f"damaged bag: cannot read past message {n} ({type(err).__name__}: {err})", path=path
            ) from None
        n += 1
        yield item


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
    if not math.isfinite(a0) or abs(a0) > 8 * math.pi:
        raise DataFormatError(f"LaserScan angle_min must be a finite angle (radians), got {msg.angle_min!r}")
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
    if not (math.isfinite(rmin) and rmin >= 0):
        raise DataFormatError(f"LaserScan range_min must be a finite number of metres >= 0, got {msg.range_min!r}")
    ranges = np.where(np.isfinite(ranges) & (ranges >= max(rmin, 0.0)), ranges, np.inf)
    if not (math.isfinite(rmax) and rmax > 0):
        finite = ranges[np.isfinite(ranges)]
        rmax = float(finite.max()) + 1.0 if finite.size else 1.0
    try:
        return Scan(ranges=ranges, bearings=bearings, max_range=rmax, intensities=intensities, timestamp=t)
    except InvalidParameterError as err:
        raise DataFormatError(f"LaserScan: {err}") from None


