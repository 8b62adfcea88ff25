"""Raw files -> observations: CARMEN logs, ROS bags and JSON Lines as one kind of *run*.

A :class:`Run` is a recorded sequence in order: per item a name, an optional
pose and timestamp, and (for laser logs) the raw scan from which an
observation is extracted on demand with the preset's feature parameters
(:meth:`Run.observations`). The command line (``map``, ``learn``,
``localize``, ``track``, ``features``) and the real-log benchmark read files
through here.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._types import FArray
from ..errors import DataFormatError, EmptyInputError, InvalidParameterError
from ..observation import Observation
from ..sensors import Scan

__all__ = [
    "RUN_KINDS",
    "Run",
    "detect_kind",
    "iter_bag_observations",
    "iter_carmen_observations",
    "load_log_scans",
    "read_run",
    "read_runs",
]


#: Kinds of run files: CARMEN logs, ROS bags, JSON Lines observations.
RUN_KINDS: tuple[str, ...] = ("carmen", "bag", "jsonl")

#: Called with a note for the user (skipped lines...); default: ignored.
Notify = Callable[[str], None]


def detect_kind(path: str | Path) -> str | None:
    """``"carmen"`` or ``"bag"`` from a path's name (or a ROS 2 bag folder); ``None`` otherwise."""
    from ..io.carmen import is_carmen_path
    from ..io.rosbag import is_bag_path

    if is_bag_path(path):
        return "bag"
    if is_carmen_path(path):
        return "carmen"
    return None


def load_log_scans(path: str | Path, *, skip_bad: bool = False) -> tuple[list[Scan], int]:
    """The front-laser scans of a CARMEN log in file order, and the number of skipped bad lines.

    ``FLASER`` lines when the log has any, else ``ROBOTLASER1``. Every scan
    must carry a pose. The log is read once (a pipe or a FIFO works).
    """
    from ..io.carmen import ReadStats, front_laser_messages, laser_scans, read_log, require_laser

    st = ReadStats()
    info, records = read_log(path, skip_bad=skip_bad, stats=st)
    require_laser(path, info)
    messages = front_laser_messages(info)
    if not messages:
        raise EmptyInputError("no FLASER or ROBOTLASER1 line (no front-laser scan)", path=path)
    scans = [scan for _, scan in laser_scans(path, records, info, messages, skip_bad=skip_bad, stats=st)]
    if not scans:
        raise EmptyInputError("no front-laser scan could be read", path=path)
    if any(s.pose is None for s in scans):
        raise DataFormatError("a scan has no pose", path=path)
    return scans, st.skipped


def iter_carmen_observations(
    path: Path, *, place: str | None = None, skip_bad: bool = False, notify: Notify | None = None, **features: Any
) -> Iterator[tuple[str, Observation]]:
    """One laser-only observation per scan of a CARMEN log, named ``file:line MESSAGE``.

    Reads ``FLASER``/``RLASER`` (or ``ROBOTLASER1/2`` in logs without them);
    ``skip_bad`` skips malformed lines (``notify`` gets their count);
    ``features`` go to :func:`fingerloc.features.laser.observation_from_scan`.
    """
    from ..features.laser import observation_from_scan
    from ..io.carmen import (
        ReadStats,
        default_messages,
        inspect_log,
        is_regular,
        iter_laser,
        laser_scans,
        read_log,
        require_laser,
    )

    st = ReadStats()
    if is_regular(path):  # two passes (thresholds, then scans): memory does not grow with the log
        info = inspect_log(path)
        require_laser(path, info)
        pairs = iter_laser(path, skip_bad=skip_bad, messages=default_messages(info), stats=st, info=info)
    else:  # a pipe or a FIFO: read once
        info, records = read_log(path, skip_bad=skip_bad, stats=st)
        require_laser(path, info)
        pairs = laser_scans(path, records, info, default_messages(info), skip_bad=skip_bad, stats=st)
    n = 0
    for rec, scan in pairs:
        n += 1
        yield f"{path.name}:{rec.line} {rec.message}", observation_from_scan(scan, label=place, **features)
    if not n:
        why = f"; {st.skipped} malformed line(s) skipped, first: {st.first_errors[0]}" if st.skipped else ""
        raise EmptyInputError(f"no usable laser scan{why}", path=path)
    if st.skipped and notify is not None:
        notify(f"{path}: skipped {st.skipped} malformed line(s); first: {st.first_errors[0]}")


def iter_bag_observations(
    path: Path,
    *,
    place: str | None = None,
    skip_bad: bool = False,
    notify: Notify | None = None,
    bag_options: Mapping[str, Any] | None = None,
    **features: Any,
) -> Iterator[tuple[str, Observation]]:
    """One laser-only observation per ``sensor_msgs/LaserScan`` of a ROS bag.

    ``bag_options`` are keyword options of :func:`fingerloc.io.rosbag.iter_bag_scans`
    (``topic``, ``pose_source``, ``odom_topic``, ``base_frame``...).
    """
    from ..features.laser import observation_from_scan
    from ..io.rosbag import BagPlan, BagReadStats

    st = BagReadStats()
    plans: list[BagPlan] = []  # said once every scan has been read: an error stays the only line

    scans = _bag_scans(path, skip_bad=skip_bad, stats=st, on_plan=plans.append, **dict(bag_options or {}))
    k = 0
    for k, scan in enumerate(scans, start=1):
        t = "" if scan.timestamp is None else f" t={scan.timestamp:.3f}"
        yield f"{path.name}#{k}{t}", observation_from_scan(scan, label=place, **features)
    if k == 0:
        raise EmptyInputError(f"no usable laser scan ({_bag_losses(st) or 'the scan topic has no message'})", path=path)
    if notify is None:
        return
    for plan in plans:
        notify(f"{path}: {plan.describe()}")
    if st.skipped:
        notify(f"{path}: skipped {st.skipped} bad scan message(s); first: {st.first_errors[0]}")
    dropped = [
        f"{st.unpaired} time step(s) without a scan on every topic" if st.unpaired else "",
        f"{st.unmounted} scan(s) whose lidar mount was missing in /tf at their stamp" if st.unmounted else "",
    ]
    if any(dropped):
        notify(f"{path}: dropped {' and '.join(d for d in dropped if d)}")


def _bag_losses(st: Any) -> str:
    """What a bag reader dropped, in words (empty when nothing)."""
    parts = []
    if st.skipped:
        parts.append(f"{st.skipped} bad scan message(s) skipped, first: {st.first_errors[0]}")
    if getattr(st, "unpaired", 0):
        parts.append(f"{st.unpaired} time step(s) without a scan on every topic")
    if getattr(st, "unmounted", 0):
        parts.append(f"{st.unmounted} scan(s) whose lidar mount was missing in /tf")
    return "; ".join(parts)


def _bag_scans(path: Path, **options: Any) -> Iterator[Scan]:
    from ..io.rosbag import iter_bag_scans

    opts = {k: v for k, v in options.items() if v is not None}
    return iter_bag_scans(path, **opts)


@dataclass(slots=True)
class Run:
    """A recorded run: items in order, each a scan (laser logs) or an observation (JSON Lines).

    Attributes
    ----------
    paths : list of Path
        The files, in order (several files are one run, one after the other, in one frame).
    kind : str
        One of :data:`RUN_KINDS` (of the first file).
    names : list of str
        A readable name per item (``file:line MESSAGE``, ``file#k``, ``file:line``).
    scans : list of Scan or None
        The raw scans of a laser log.
    records : list of Observation or None
        The observations of a JSON Lines run.
    key : str
        A content hash of the whole run (SHA-256 hex of every item's pose,
        timestamp and data), to recognise the run a map was made from.
    skipped : int
        Malformed lines or messages skipped (``skip_bad``).
    """

    paths: list[Path]
    kind: str
    names: list[str]
    scans: list[Scan] | None = None
    records: list[Observation] | None = None
    key: str = ""
    skipped: int = 0
    _cache: dict[tuple[Any, ...], Observation] = field(default_factory=dict, repr=False)

    def __len__(self) -> int:
        return len(self.names)

    @property
    def poses(self) -> FArray | None:
        """Poses ``(x, y, theta)`` of every item, shape (n, 3), metres and radians; ``None`` when one is missing."""
        items: Sequence[Any] = self.scans if self.scans is not None else (self.records or [])
        if not items or any(it.pose is None for it in items):
            return None
        return np.array([it.pose for it in items], dtype=np.float64).reshape(-1, 3)

    @property
    def timestamps(self) -> FArray | None:
        """Seconds of every item, shape (n,); ``None`` when one is missing."""
        items: Sequence[Any] = self.scans if self.scans is not None else (self.records or [])
        if not items or any(it.timestamp is None for it in items):
            return None
        return np.array([it.timestamp for it in items], dtype=np.float64)

    def observations(self, idx: Any = None, *, features: Mapping[str, Any] | None = None) -> list[Observation]:
        """Observations of the items ``idx`` (default all), unlabelled for a laser log.

        A laser log's scans go through
        :func:`fingerloc.features.laser.observation_from_scan` with ``features``
        (the preset's extractor parameters).
        """
        sel = range(len(self)) if idx is None else [int(i) for i in np.asarray(idx, dtype=np.int64).reshape(-1)]
        if self.records is not None:
            return [self.records[i] for i in sel]
        from ..features.laser import observation_from_scan

        assert self.scans is not None
        fkey = tuple(sorted((features or {}).items()))
        out = []
        for i in sel:
            k = (i, *fkey)
            if k not in self._cache:
                self._cache[k] = observation_from_scan(self.scans[i], **dict(features or {}))
            out.append(self._cache[k])
        return out

    def field_of_view(self, idx: Any = None) -> float:
        """Median width of the items' fields of view, radians (pi when there are none)."""
        sel = range(len(self)) if idx is None else np.asarray(idx, dtype=np.int64).reshape(-1).tolist()
        items: Sequence[Any] = self.scans if self.scans is not None else (self.records or [])
        fov = [sum(w for _, w in items[i].fov) for i in sel]
        return float(np.median(fov)) if fov else float(np.pi)


def _run_key(items: Sequence[Any], data: Callable[[Any], bytes]) -> str:
    h = hashlib.sha256()
    h.update(str(len(items)).encode())
    for it in items:
        pose = np.asarray(it.pose if it.pose is not None else (np.nan,) * 3, dtype="<f8")
        ts = np.asarray([np.nan if it.timestamp is None else it.timestamp], dtype="<f8")
        h.update(pose.tobytes())
        h.update(ts.tobytes())
        h.update(data(it))
    return h.hexdigest()


def _scan_bytes(s: Scan) -> bytes:
    return np.ascontiguousarray(s.ranges, dtype="<f8").tobytes() + np.ascontiguousarray(s.bearings, dtype="<f8").tobytes()


def _record_bytes(o: Observation) -> bytes:
    from ..map.database import observation_hash

    return observation_hash(o).encode()


def read_run(
    path: str | Path,
    *,
    kind: str = "auto",
    skip_bad: bool = False,
    bag_options: Mapping[str, Any] | None = None,
) -> Run:
    """Read one run file.

    Parameters
    ----------
    path : path
        A CARMEN log (its front laser: ``FLASER``, else ``ROBOTLASER1``, as
        the benchmark), a ROS bag, or JSON Lines observations.
    kind : {"auto", "carmen", "bag", "jsonl"}
        ``auto``: from the name (:func:`detect_kind`), JSON Lines otherwise.
    skip_bad : bool, default False
        Skip malformed log lines / bag messages (counted in ``Run.skipped``).
    bag_options : mapping, optional
        Keyword options of :func:`fingerloc.io.rosbag.iter_bag_scans`.

    Returns
    -------
    Run
    """
    p = Path(path)
    if kind not in ("auto", *RUN_KINDS):
        raise InvalidParameterError(f"kind must be one of auto, {', '.join(RUN_KINDS)}, got {kind!r}")
    k = (detect_kind(p) or "jsonl") if kind == "auto" else kind
    if k == "carmen":
        scans, skipped = load_log_scans(p, skip_bad=skip_bad)
        names = [f"{p.name}#{i}" for i in range(len(scans))]
        return Run([p], k, names, scans=scans, key=_run_key(scans, _scan_bytes), skipped=skipped)
    if k == "bag":

        from ..io.rosbag import BagReadStats

        st = BagReadStats()
        scans = list(_bag_scans(p, skip_bad=skip_bad, stats=st, **dict(bag_options or {})))
        if not scans:
            raise EmptyInputError(f"no laser scan could be read ({_bag_losses(st) or 'no scan message'})", path=p)
        names = [f"{p.name}#{i}" for i in range(len(scans))]
        return Run([p], k, names, scans=scans, key=_run_key(scans, _scan_bytes), skipped=st.skipped)
    from ..io.jsonl import read_observations

    obs = read_observations(p)
    if not obs:
        raise EmptyInputError("no observation", path=p)
    names = [f"{p.name}:{i + 1}" for i in range(len(obs))]
    return Run([p], "jsonl", names, records=obs, key=_run_key(obs, _record_bytes))


def read_runs(
    paths: Sequence[str | Path],
    *,
    kind: str = "auto",
    skip_bad: bool = False,
    bag_options: Mapping[str, Any] | None = None,
) -> Run:
    """Several files as one run, one after the other (one frame: the poses are not shifted)."""
    if not paths:
        raise InvalidParameterError("at least one run file is needed")
    runs = [read_run(p, kind=kind, skip_bad=skip_bad, bag_options=bag_options) for p in paths]
    if len(runs) == 1:
        return runs[0]
    laser = [r.scans is not None for r in runs]
    if any(laser) and not all(laser):
        raise InvalidParameterError("the run files must be all laser logs / bags or all JSON Lines, not a mix")
    names = [n for r in runs for n in r.names]
    if all(laser):
        scans = [s for r in runs for s in (r.scans or [])]
        return Run([p for r in runs for p in r.paths], runs[0].kind, names, scans=scans,
                   key=_run_key(scans, _scan_bytes), skipped=sum(r.skipped for r in runs))  # fmt: skip
    obs = [o for r in runs for o in (r.records or [])]
    return Run([p for r in runs for p in r.paths], "jsonl", names, records=obs, key=_run_key(obs, _record_bytes))
