"""Runs read one line at a time, as they arrive: standard input, or a file that is still growing.

A robot's driver can pipe its log into fingerloc (``driver | fingerloc track
- --db places.sqlite --follow``), or write it to a file that fingerloc follows
(``--follow``, as ``tail -f``). Each line becomes at most one
:class:`StreamItem` the moment it is read; nothing waits for later lines.

Two line formats, told apart by the first line that says something (or given
as ``kind``):

* **CARMEN** (:mod:`fingerloc.io.carmen`; a line starting with ``#`` or a
  message name in capitals): each front-laser line becomes a scan item with
  the line's pose and odometry. Which laser is the front one is fixed by the
  first laser line: ``FLASER`` lines when it is one (``ROBOTLASER1`` lines
  are then ignored), else ``ROBOTLASER1``. ``ODOM`` lines become odometry items
  when asked (``odometry_lines=True``).
* **JSON Lines** (a line starting with ``{``): an observation record of
  docs/FORMATS.md §1 (with ``"features"``), or a raw scan record without
  ``"features"``::

      {"scan": {"bearings": [deg, ...], "ranges": [m or null, ...]}, "max_range": m,
       "pose": [x, y, theta_deg], "odometry": [x, y, theta_deg], "timestamp": s}

  (only ``"scan"`` is required; ``null`` ranges are no return). Either kind of
  record may carry ``"odometry"``, the robot's odometry pose in its odometry
  frame (degrees, as ``"pose"``); a record with only ``"odometry"`` (and a
  timestamp) is an odometry item.

**No return in a stream.** A CARMEN log marks a beam without a return by the
laser's maximum-range code, which :func:`fingerloc.io.carmen.inspect_log`
finds by a pass over the whole file; a stream cannot look ahead. Here a
reading equal to one of :data:`~fingerloc.io.carmen.KNOWN_NO_RETURN_CODES` on
any laser line read so far marks the code: the largest code seen, lowered to
the smallest code seen within 0.5 % below it (as the file reader lowers
81.91 m to 81.83 m), and every reading at or above it is no return. Without
a code seen, a ``ROBOTLASER`` line's own maximum-range field is used, else
every reading is kept (a beam that reads a code never seen before is then a
return). Give ``max_range`` to fix the threshold instead.

**Bad lines.** A malformed line raises :class:`~fingerloc.errors.DataFormatError`
naming the source and the line (``stdin:12: FLASER line has ...``); with
``skip_bad=True`` it is passed to ``on_error`` (the command line prints one
``warning:`` line) and reading goes on.
"""

from __future__ import annotations

import gzip
import math
import os
import stat
import sys
import time
from collections.abc import Callable, Collection, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Protocol

import numpy as np

from ..angles import deg_to_rad
from ..errors import DataFormatError, InvalidParameterError
from ..observation import Observation
from ..sensors import Scan
from .carmen import KNOWN_NO_RETURN_CODES, LASER_MESSAGES, LaserRecord, OdomRecord, ReadStats, parse_line
from .jsonl import MAX_LINE_BYTES, observation_from_record, parse_record

__all__ = [
    "STREAM_KINDS",
    "NoReturnCodes",
    "StreamItem",
    "StreamReader",
    "detect_stream_kind",
    "follow_lines",
    "iter_stream",
    "open_lines",
    "stream_lines",
]

#: Line formats of a stream.
STREAM_KINDS: tuple[str, ...] = ("carmen", "jsonl")

#: Seconds between two looks at a followed file that has no new line.
POLL_S = 0.05

#: Relative band below the largest no-return code seen in which a smaller code seen is taken instead.
SATURATION_BAND = 0.005

#: Distance (metres) within which a reading equals a no-return code.
CODE_TOLERANCE_M = 1e-9

Planar = tuple[float, float, float]
ErrorHandler = Callable[[DataFormatError], None]


class _LineSource(Protocol):
    def readline(self, size: int = -1, /) -> bytes: ...


@dataclass(frozen=True, slots=True)
class StreamItem:
    """One step of a stream: a scan, an observation, or (``odometry_lines``) an odometry reading alone.

    Attributes
    ----------
    line : int
        1-based line number in the stream.
    name : str
        ``SOURCE:LINE`` and, for a CARMEN line, its message (``stdin:12 FLASER``).
    scan : Scan or None
        A laser scan (robot frame; ``pose`` the line's pose; ``timestamp`` its stamp).
    observation : Observation or None
        A JSON Lines observation.
    pose : (x, y, theta) or None
        The pose recorded with the item (a CARMEN log's corrected pose), metres and radians.
    odometry : (x, y, theta) or None
        The robot's raw odometry pose in its odometry frame, metres and radians.
    stamp : float or None
        Seconds, the input's clock.
    kind : str
        The stream's format: ``"carmen"`` or ``"jsonl"``.
    """

    line: int
    name: str
    scan: Scan | None = None
    observation: Observation | None = None
    pose: Planar | None = None
    odometry: Planar | None = None
    stamp: float | None = None
    kind: str = ""

    @property
    def item(self) -> Scan | Observation | None:
        """What a tracker observes: the scan or the observation (None: odometry only)."""
        return self.scan if self.scan is not None else self.observation


def detect_stream_kind(line: str) -> str | None:
    """``"jsonl"`` for a line starting with ``{``, ``"carmen"`` for a comment or a capitalised message name.

    ``None`` for a blank line (undecided) ; raises for anything else.

    Raises
    ------
    DataFormatError
        A line that is neither (without a location: callers add it).
    """
    s = line.lstrip("\ufeff").strip()
    if not s:
        return None
    if s.startswith("{"):
        return "jsonl"
    if s.startswith("#"):
        return "carmen"
    head = s.split(None, 1)[0]
    if head[:1].isalpha() and head.replace("_", "").isalnum() and head.upper() == head:
        return "carmen"
    shown = s if len(s) <= 40 else s[:37] + "..."
    raise DataFormatError(f"neither a CARMEN line nor a JSON Lines record: {shown!r} (give the kind: --kind)")


@dataclass(slots=True)
class NoReturnCodes:
    """The no-return threshold of a CARMEN stream, learned line by line (see the module docstring).

    Attributes
    ----------
    max_range : float or None
        A fixed threshold (metres) for every laser; ``None``: learned.
    seen : dict of str to set of float
        Per message type, the known no-return codes read so far.
    """

    max_range: float | None = None
    seen: dict[str, set[float]] = field(default_factory=dict)

    def threshold(self, rec: LaserRecord) -> float | None:
        """Take in ``rec``'s readings; the threshold (metres) for its scan, ``None`` to keep every reading."""
        if self.max_range is not None:
            return self.max_range
        codes = self.seen.setdefault(rec.message, set())
        top = float(np.max(rec.ranges)) if rec.ranges.size else 0.0
        for c in KNOWN_NO_RETURN_CODES:
            if c not in codes and c <= top + CODE_TOLERANCE_M and np.any(np.abs(rec.ranges - c) <= CODE_TOLERANCE_M):
                codes.add(c)
        if codes:
            high = max(codes)
            return min(c for c in codes if c >= high * (1.0 - SATURATION_BAND))
        return rec.max_range


def _planar_deg(value: Any, what: str) -> Planar:
    if not isinstance(value, list) or len(value) != 3:
        raise DataFormatError(f'"{what}" must be [x, y, theta_deg], got {value!r}')
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
            raise DataFormatError(f'"{what}" values must be finite numbers, got {value!r}')
        out.append(float(v))
    return (out[0], out[1], float(deg_to_rad(out[2])))


def _stamp(record: dict[str, Any]) -> float | None:
    ts = record.get("timestamp")
    if ts is None:
        return None
    if isinstance(ts, bool) or not isinstance(ts, (int, float)) or not math.isfinite(float(ts)):
        raise DataFormatError(f'"timestamp" must be a finite number of seconds, got {ts!r}')
    return float(ts)


def _scan_record(record: dict[str, Any]) -> Scan:
    scan = record["scan"]
    if (
        not isinstance(scan, dict)
        or not isinstance(scan.get("bearings"), list)
        or not isinstance(scan.get("ranges"), list)
    ):
        raise DataFormatError('"scan" must be {"bearings": [deg, ...], "ranges": [m or null, ...]}')
    bearings, ranges = scan["bearings"], scan["ranges"]
    if len(bearings) != len(ranges):
        raise DataFormatError(f'"scan": {len(bearings)} bearings but {len(ranges)} ranges')
    try:
        b = np.deg2rad(np.array(bearings, dtype=np.float64))
        r = np.array([np.inf if v is None else v for v in ranges], dtype=np.float64)
    except (TypeError, ValueError):
        raise DataFormatError('"scan": bearings and ranges must be numbers (a range may be null)') from None
    if not (np.all(np.isfinite(b)) and not np.any(np.isnan(r))):
        raise DataFormatError('"scan": bearings must be finite and ranges numbers or null')
    mr = record.get("max_range")
    if mr is None:
        finite = r[np.isfinite(r)]
        mr = float(finite.max()) + 1.0 if finite.size else 1.0
    elif isinstance(mr, bool) or not isinstance(mr, (int, float)) or not (math.isfinite(mr) and mr > 0):
        raise DataFormatError(f'"max_range" must be a positive number of metres, got {mr!r}')
    pose = _planar_deg(record["pose"], "pose") if record.get("pose") is not None else None
    try:
        return Scan(ranges=r, bearings=b, max_range=float(mr), pose=pose, timestamp=_stamp(record))
    except InvalidParameterError as err:
        raise DataFormatError(f'"scan": {err}') from None


class StreamReader:
    """Items of a CARMEN or JSON Lines stream, one per useful line, each as soon as its line is read.

    Parameters
    ----------
    lines : iterable of (int, str)
        Numbered lines (1-based), e.g. :func:`open_lines`.
    kind : {"auto", "carmen", "jsonl"}, default "auto"
        ``auto``: from the first non-blank line (:func:`detect_stream_kind`).
    source : str, default "stdin"
        The name used in error messages and item names.
    skip_bad : bool, default False
        Pass malformed lines to ``on_error`` and go on, instead of raising.
    on_error : callable, optional
        Called with each skipped line's error (``skip_bad``).
    messages : collection of str, optional
        CARMEN laser messages to read (default: the front laser, see the module docstring).
    max_range : float, optional
        CARMEN: a fixed no-return threshold, metres (default: learned, :class:`NoReturnCodes`).
    odometry_lines : bool, default False
        Yield odometry items too (CARMEN ``ODOM`` lines, JSON records with only ``"odometry"``).

    Attributes
    ----------
    kind : str or None
        The format, once told.
    stats : ReadStats
        Lines read, scans, skipped lines.
    """

    def __init__(
        self,
        lines: Iterable[tuple[int, str]],
        *,
        kind: str = "auto",
        source: str = "stdin",
        skip_bad: bool = False,
        on_error: ErrorHandler | None = None,
        messages: Collection[str] | None = None,
        max_range: float | None = None,
        odometry_lines: bool = False,
    ) -> None:
        if kind not in ("auto", *STREAM_KINDS):
            raise InvalidParameterError(f"kind must be one of auto, {', '.join(STREAM_KINDS)}, got {kind!r}")
        if messages is not None:
            unknown = set(messages) - set(LASER_MESSAGES)
            if unknown:
                raise InvalidParameterError(
                    f"unknown CARMEN laser message {sorted(unknown)[0]!r} (known: {', '.join(LASER_MESSAGES)})"
                )
        if max_range is not None and not (math.isfinite(max_range) and max_range > 0):
            raise InvalidParameterError(f"max_range must be a positive number of metres, got {max_range!r}")
        self._lines = lines
        self.kind: str | None = None if kind == "auto" else kind
        self.source = source
        self.skip_bad = skip_bad
        self.on_error = on_error
        self._messages: set[str] | None = None if messages is None else set(messages)
        self._codes = NoReturnCodes(max_range)
        self.odometry_lines = odometry_lines
        self.stats = ReadStats()

    def __iter__(self) -> Iterator[StreamItem]:
        for lineno, text in self._lines:
            self.stats.lines += 1
            try:
                if self.kind is None:
                    self.kind = detect_stream_kind(text)
                    if self.kind is None:
                        continue
                item = self._carmen(lineno, text) if self.kind == "carmen" else self._jsonl(lineno, text)
            except DataFormatError as err:
                located = err.at(path=self.source, line=lineno)
                if not self.skip_bad:
                    raise located from None
                self.stats.record_skip(located)
                if self.on_error is not None:
                    self.on_error(located)
                continue
            if item is not None:
                if item.scan is not None or item.observation is not None:
                    self.stats.scans += 1
                yield item

    def _front(self, message: str) -> bool:
        if self._messages is None:
            if message not in ("FLASER", "ROBOTLASER1"):
                return False
            self._messages = {message}  # the first front-laser line fixes the laser
        return message in self._messages

    def _carmen(self, lineno: int, text: str) -> StreamItem | None:
        rec = parse_line(text, line=lineno)
        if isinstance(rec, OdomRecord):
            if not self.odometry_lines:
                return None
            return StreamItem(lineno, f"{self.source}:{lineno} ODOM", odometry=rec.pose, stamp=rec.timestamp,
                              kind="carmen")  # fmt: skip
        if rec is None or not self._front(rec.message):
            return None
        thr = self._codes.threshold(rec)
        if thr is None:
            finite = rec.ranges[np.isfinite(rec.ranges)]
            thr = float(finite.max()) + 1.0 if finite.size else 1.0  # nothing marks no return: keep every reading
        try:
            scan = Scan(
                ranges=rec.ranges,
                bearings=rec.bearings,
                max_range=thr,
                intensities=rec.intensities,
                pose=rec.pose,
                sensor_offset=rec.sensor_offset,
                timestamp=rec.timestamp,
            )
        except InvalidParameterError as err:
            raise DataFormatError(f"{rec.message}: {err}") from None
        return StreamItem(lineno, f"{self.source}:{lineno} {rec.message}", scan=scan, pose=rec.pose, odometry=rec.odom,
                          stamp=rec.timestamp, kind="carmen")  # fmt: skip

    def _jsonl(self, lineno: int, text: str) -> StreamItem | None:
        if not text.strip():
            return None
        record = parse_record(text)
        if not isinstance(record, dict):
            raise DataFormatError(f"a record must be a JSON object, got {type(record).__name__}")
        odom = _planar_deg(record["odometry"], "odometry") if record.get("odometry") is not None else None
        name = f"{self.source}:{lineno}"
        if "features" in record:
            obs = observation_from_record(record)
            return StreamItem(lineno, name, observation=obs, pose=obs.pose, odometry=odom, stamp=obs.timestamp,
                              kind="jsonl")  # fmt: skip
        if "scan" in record:
            scan = _scan_record(record)
            return StreamItem(
                lineno, name, scan=scan, pose=scan.pose, odometry=odom, stamp=scan.timestamp, kind="jsonl"
            )
        if odom is not None:
            if not self.odometry_lines:
                return None
            return StreamItem(lineno, name, odometry=odom, stamp=_stamp(record), kind="jsonl")
        raise DataFormatError('a record needs "features" (an observation), "scan" (a laser scan) or "odometry"')


def _decode(raw: bytes) -> str:
    return raw.decode("utf-8", errors="replace")


def _too_long(lineno: int, where: str | Path) -> DataFormatError:
    return DataFormatError(f"line {lineno} is longer than {MAX_LINE_BYTES:,} bytes: not a log or JSON Lines line",
                           path=where)  # fmt: skip


def stream_lines(fh: _LineSource, where: str | Path = "stdin") -> Iterator[tuple[int, str]]:
    """Numbered lines (1-based) of a binary stream, each returned as soon as its newline arrives.

    Bytes that are not UTF-8 become U+FFFD (the line then fails to parse, by its number).

    Raises
    ------
    DataFormatError
        A line longer than :data:`MAX_LINE_BYTES` (binary data, ``/dev/zero``): memory stays bounded.
    """
    lineno = 0
    while True:
        raw = fh.readline(MAX_LINE_BYTES + 1)
        if not raw:
            return
        lineno += 1
        if len(raw) > MAX_LINE_BYTES:
            raise _too_long(lineno, where)
        yield lineno, _decode(raw)


def follow_lines(
    path: str | Path,
    *,
    poll_s: float = POLL_S,
    idle_timeout_s: float | None = None,
    stop: Callable[[], bool] | None = None,
    fh: IO[bytes] | None = None,
) -> Iterator[tuple[int, str]]:
    """Numbered lines of a file that is still being written (as ``tail -f`` from its start).

    A line is returned once its newline is written; at the end of the file
    the reader waits (``poll_s`` seconds between looks) for more.

    Parameters
    ----------
    path : str or Path
    poll_s : float
        Seconds between two looks at the end of the file.
    idle_timeout_s : float, optional
        Stop after this many seconds without a new line (a last line without
        a newline is then returned); ``None``: never (until ``stop``).
    stop : callable, optional
        Checked while waiting; True ends the stream.
    fh : binary file, optional
        ``path`` already open (it is closed at the end).

    Raises
    ------
    DataFormatError
        The file cannot be opened, or shrinks while followed.
    """
    p = Path(path)
    if fh is None:
        try:
            fh = open(p, "rb")
        except OSError as err:
            raise DataFormatError(f"cannot read: {err.strerror or err}", path=p) from None
    lineno = 0
    partial = b""
    idle_since = time.monotonic()
    with fh:
        while True:
            raw = fh.readline(MAX_LINE_BYTES + 1)
            if raw:
                partial += raw
                if len(partial) > MAX_LINE_BYTES:
                    raise _too_long(lineno + 1, p)
                if partial.endswith(b"\n"):
                    lineno += 1
                    yield lineno, _decode(partial)
                    partial = b""
                    idle_since = time.monotonic()
                continue
            try:
                size = p.stat().st_size
            except OSError:
                size = fh.tell()
            if size < fh.tell():
                raise DataFormatError(f"the file shrank while followed (after line {lineno})", path=p)
            if (stop is not None and stop()) or (
                idle_timeout_s is not None and time.monotonic() - idle_since >= idle_timeout_s
            ):
                if partial:
                    yield lineno + 1, _decode(partial)
                return
            time.sleep(poll_s)


def open_lines(
    path: str | Path,
    *,
    follow: bool = False,
    poll_s: float = POLL_S,
    idle_timeout_s: float | None = None,
    stdin: IO[bytes] | None = None,
) -> Iterator[tuple[int, str]]:
    """Numbered lines of ``path`` (``"-"``: standard input), plain or gzip, streamed.

    ``follow``: keep reading a plain file as it grows (:func:`follow_lines`);
    standard input is always read as it arrives, until it closes. A gzip
    stream (recognised by its first bytes) is decompressed block by block.
    """
    if str(path) == "-":
        if stdin is None and (sys.stdin is None or sys.stdin.closed):
            raise InvalidParameterError("standard input ('-') is closed: nothing to read")
        fh = stdin if stdin is not None else sys.stdin.buffer
        peek = getattr(fh, "peek", None)
        head = peek(2)[:2] if callable(peek) else b""
        if head == b"\x1f\x8b":
            return _gzip_lines(gzip.GzipFile(fileobj=fh, mode="rb"), "stdin")
        return stream_lines(fh)
    p = Path(path)
    try:
        fh = open(p, "rb")  # opened once: a FIFO or a process substitution is read as it comes
    except IsADirectoryError:
        raise DataFormatError("is a directory, not a log", path=p) from None
    except OSError as err:
        raise DataFormatError(f"cannot read: {err.strerror or err}", path=p) from None
    try:
        regular = stat.S_ISREG(os.fstat(fh.fileno()).st_mode)
        magic = fh.peek(2)[:2]
    except OSError as err:
        fh.close()
        raise DataFormatError(f"cannot read: {err.strerror or err}", path=p) from None
    if magic == b"\x1f\x8b":
        if follow and regular:
            fh.close()
            raise InvalidParameterError(f"{p}: a gzip file cannot be followed while it grows (give a plain text log)")
        return _gzip_lines(gzip.GzipFile(fileobj=fh, mode="rb"), p)
    if follow and regular:  # a FIFO or a device is read as it comes, to its end, as standard input is
        return follow_lines(p, poll_s=poll_s, idle_timeout_s=idle_timeout_s, fh=fh)
    return _file_lines(fh, p)


def _file_lines(fh: IO[bytes], p: Path) -> Iterator[tuple[int, str]]:
    with fh:
        yield from stream_lines(fh, p)


def _gzip_lines(fh: gzip.GzipFile, where: str | Path) -> Iterator[tuple[int, str]]:
    import zlib

    lineno = 0
    with fh:
        try:
            for item in stream_lines(fh):
                lineno = item[0]  # reported when the stream turns out corrupt
                yield item
        except (EOFError, zlib.error, gzip.BadGzipFile, OSError) as err:
            raise DataFormatError(f"corrupt or truncated gzip data after line {lineno}: {err}", path=where) from None


def iter_stream(
    path: str | Path,
    *,
    kind: str = "auto",
    follow: bool = False,
    skip_bad: bool = False,
    on_error: ErrorHandler | None = None,
    idle_timeout_s: float | None = None,
    **options: Any,
) -> StreamReader:
    """A :class:`StreamReader` over ``path`` (``"-"``: standard input); ``options``: the reader's.

    Raises
    ------
    FingerlocError
        An unreadable path, a gzip file with ``follow``, or a bad option.
    """
    lines = open_lines(path, follow=follow, idle_timeout_s=idle_timeout_s)
    source = "stdin" if str(path) == "-" else str(path)
    return StreamReader(lines, kind=kind, source=source, skip_bad=skip_bad, on_error=on_error, **options)
