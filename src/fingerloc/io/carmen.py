"""CARMEN log files: laser scans (``FLASER``, ``RLASER``, ``ROBOTLASER1/2``) and odometry (``ODOM``).

A CARMEN log is a text file (plain or gzip), one message a line, the message
type first. The messages read here::

    FLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta ipc_timestamp hostname logger_timestamp
    RLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta ipc_timestamp hostname logger_timestamp
    ROBOTLASER1 laser_type start_angle fov angular_resolution max_range accuracy remission_mode
                n r_1 .. r_n m e_1 .. e_m laser_x laser_y laser_theta robot_x robot_y robot_theta
                tv rv forward_safety_dist side_safety_dist turn_axis ipc_timestamp hostname logger_timestamp
    ODOM x y theta tv rv accel ipc_timestamp hostname logger_timestamp

(``ROBOTLASER2`` has the layout of ``ROBOTLASER1``.) The ``x y theta`` of an
``FLASER``/``RLASER`` line is CARMEN's laser pose (the robot's pose moved by
the ``robot_frontlaser_offset`` along the heading, 0 in most logs); it becomes
the scan's ``pose`` with a zero ``sensor_offset``, so the end points land
where the log puts them. ``ROBOTLASER`` lines give both poses: the robot's is
the ``pose``, the laser's becomes the ``sensor_offset``. Every other message type
(``PARAM``, ``NEFF``, ``SYNC``, ``TRUEPOS``, ``RAWLASER*``, comments starting
with ``#``) is skipped, except that ``PARAM`` lines may give a laser's maximum
range.

Beam bearings of ``FLASER`` run from -90 deg counter-clockwise in steps of
``180 / (n - 1)`` deg when ``n`` is odd (both ends included) and ``180 / n``
deg when ``n`` is even; ``RLASER`` is the rear laser, the same fan turned by
180 deg (bearings +90 .. +270 deg). ``ROBOTLASER`` lines carry their own start
angle and angular resolution.

**No return.** Lasers write a code at their maximum range when a beam sees
nothing, and the code differs by log (50, 51.x, 80, 81.83, 81.91, 32.76 m have
all been seen); some logs even mix two codes (81.83 and 81.91), and ``PARAM``
lines can disagree with the data. Unless a maximum range is given, the reader
first streams through the log once (:func:`inspect_log`) and, per message type,
takes as the log's no-return threshold the *saturation value*: the largest
reading repeated at least ``min_repeats`` times, lowered to the smallest such
repeated reading within ``saturation_band`` (0.5 %) below it. Failing that, a
largest reading equal to a known code, then the ``ROBOTLASER`` line's own
maximum-range field, then a ``PARAM`` maximum; with none of these, every
reading is kept. Readings at or above the threshold become ``inf``
(:class:`~fingerloc.sensors.Scan`'s convention).

**Reading.** A log is opened once, as a stream: plain or gzip is told from
its first bytes on that one stream, so a pipe or a FIFO works
(``--kind carmen <(zcat log.gz)``). :func:`read_log` reads a log in one pass
(its no-return thresholds and its records together: what ``map``,
``localize`` and ``track`` use); :func:`iter_laser` streams a regular file in
two passes (thresholds first, then the scans: memory does not grow with the
log) and reads anything else in one. A line longer than
:data:`MAX_LINE_BYTES` is an error (a file of NUL bytes, ``/dev/zero``, one
giant line: one line within a second, memory bounded), and runs of blank or
foreign lines are skipped a block at a time (a gzip of a gigabyte of blank
lines is read at the speed of decompression).
"""

from __future__ import annotations

import gzip
import io
import math
import os
import stat
import zlib
from collections import Counter
from collections.abc import Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataFormatError, FingerlocError, InvalidParameterError
from ..sensors import Scan

__all__ = [
    "CARMEN_EXTENSIONS",
    "KNOWN_NO_RETURN_CODES",
    "LASER_MESSAGES",
    "LaserRecord",
    "LogInfo",
    "OdomRecord",
    "ReadStats",
    "default_messages",
    "detect_max_range",
    "flaser_bearings",
    "front_laser_messages",
    "inspect_log",
    "is_carmen_path",
    "iter_laser",
    "iter_records",
    "iter_scans",
    "laser_scans",
    "parse_line",
    "read_log",
    "read_scans",
    "require_laser",
]

#: Longest line a log may have, bytes (a 3600-beam ROBOTLASER line with remissions takes about 60 KB).
MAX_LINE_BYTES = 1 << 20
#: Bytes read at a time.
_BLOCK = 1 << 16
#: Largest |x| or |y| of a pose, metres (the JSON Lines reader's bound).
MAX_COORD_M = 1e9
#: The first bytes of every message this reader reads (a line starting with anything else is skipped).
_KEYWORDS = (b"FLASER", b"RLASER", b"ROBOTLASER", b"ODOM", b"PARAM")
#: What a block must hold to have one of them (three searches instead of five).
_SEARCH = (b"LASER", b"ODOM", b"PARAM")

#: Laser message types this reader turns into scans.
LASER_MESSAGES: tuple[str, ...] = ("FLASER", "RLASER", "ROBOTLASER1", "ROBOTLASER2")

#: No-return codes seen in real CARMEN logs, metres (used when too few repeats decide).
KNOWN_NO_RETURN_CODES: tuple[float, ...] = (32.76, 50.0, 80.0, 81.83, 81.91)

#: File name endings taken for CARMEN logs.
CARMEN_EXTENSIONS: tuple[str, ...] = (".log", ".log.gz", ".gz", ".clf", ".clf.gz", ".carmen")

#: ``PARAM`` names giving a laser's maximum range, per message type.
_PARAM_MAX_RANGE: dict[str, tuple[str, ...]] = {
    "FLASER": ("robot_front_laser_max", "laser_front_laser_max_range"),
    "RLASER": ("robot_rear_laser_max", "laser_rear_laser_max_range"),
    "ROBOTLASER1": ("robot_front_laser_max", "laser_front_laser_max_range"),
    "ROBOTLASER2": ("robot_rear_laser_max", "laser_rear_laser_max_range"),
}

# Fields after the n readings of FLASER / RLASER: pose (3), odometry (3), timestamp, host, logger timestamp.
_FLASER_TAIL = 9
# ROBOTLASER: 7 header fields, then n, readings, m, remissions, then 14 tail fields.
_ROBOTLASER_HEAD = 7
_ROBOTLASER_TAIL = 14
# ODOM: x y theta tv rv accel timestamp host logger_timestamp.
_ODOM_FIELDS = 10


@dataclass(frozen=True, slots=True)
class LaserRecord:
    """One laser message of a CARMEN log, as written (before no-return handling).

    Attributes
    ----------
    message : str
        ``"FLASER"``, ``"RLASER"``, ``"ROBOTLASER1"`` or ``"ROBOTLASER2"``.
    ranges : ndarray, shape (n,)
        Readings in metres, unchanged.
    bearings : ndarray, shape (n,)
        Beam bearings in radians in the robot frame, increasing.
    pose : (x, y, theta)
        Robot pose, metres and radians.
    sensor_offset : (x, y, theta)
        Sensor pose in the robot frame (``ROBOTLASER`` only; zero otherwise).
    odom : (x, y, theta) or None
        Raw odometry pose (``FLASER`` / ``RLASER``).
    intensities : ndarray, shape (n,), or None
        Remissions (``ROBOTLASER`` lines whose remission count equals ``n``).
    max_range : float or None
        The line's own maximum-range field (``ROBOTLASER`` only).
    timestamp : float
        The ``ipc_timestamp`` field, seconds (unreliable in many logs).
    line : int
        1-based line number in the file.
    """

    message: str
    ranges: np.ndarray
    bearings: np.ndarray
    pose: tuple[float, float, float]
    sensor_offset: tuple[float, float, float]
    odom: tuple[float, float, float] | None
    intensities: np.ndarray | None
    max_range: float | None
    timestamp: float
    line: int


@dataclass(frozen=True, slots=True)
class OdomRecord:
    """One ``ODOM`` message: pose (m, rad), velocities (m/s, rad/s), acceleration (m/s^2)."""

    pose: tuple[float, float, float]
    tv: float
    rv: float
    accel: float
    timestamp: float
    line: int


@dataclass(slots=True)
class ReadStats:
    """Counters a reader fills while it streams (mutable; pass one in to read them after).

    Attributes
    ----------
    lines : int
        Lines (or messages) read.
    scans : int
        Scans yielded.
    skipped : int
        Malformed lines skipped (``skip_bad=True``).
    first_errors : list of str
        The first few skipped lines' error messages (path:line: what).
    """

    lines: int = 0
    scans: int = 0
    skipped: int = 0
    first_errors: list[str] = field(default_factory=list)
    max_errors_kept: int = 5

    def record_skip(self, err: FingerlocError) -> None:
        """Count one skipped line and keep its message if few are kept yet."""
        self.skipped += 1
        if len(self.first_errors) < self.max_errors_kept:
            self.first_errors.append(str(err))


@dataclass(frozen=True, slots=True)
class LogInfo:
    """What one pass over a CARMEN log found (see :func:`inspect_log`).

    Attributes
    ----------
    counts : dict of str to int
        Number of well-formed lines per laser message type (and ``ODOM``).
    max_range : dict of str to float or None
        Detected no-return threshold per laser message type, metres; ``None``
        when nothing marks no-return (every reading is then kept).
    params : dict of str to str
        The ``PARAM`` lines (last value wins).
    """

    counts: dict[str, int]
    max_range: dict[str, float | None]
    params: dict[str, str]
    head: bytes = b""
    compressed: bool = False


def is_carmen_path(path: str | Path) -> bool:
    """True when ``path``'s name ends like a CARMEN log (:data:`CARMEN_EXTENSIONS`)."""
    name = Path(path).name.lower()
    return any(name.endswith(ext) for ext in CARMEN_EXTENSIONS)


def flaser_bearings(n: int, *, rear: bool = False) -> np.ndarray:
    """Beam bearings of an ``FLASER`` (or ``RLASER``) line with ``n`` beams, radians.

    From -90 deg, counter-clockwise, step ``180 / (n - 1)`` deg for odd ``n``
    (both ends included) and ``180 / n`` deg for even ``n``. The rear laser's
    fan is turned by 180 deg (from +90 deg).

    Returns
    -------
    ndarray, shape (n,)
    """
    if n < 2:
        raise InvalidParameterError(f"a laser line needs at least 2 beams, got n={n}")
    step = math.pi / (n - 1) if n % 2 == 1 else math.pi / n
    start = math.pi / 2 if rear else -math.pi / 2
    return start + step * np.arange(n, dtype=np.float64)


class _Source:
    """One open log: its binary stream (gunzipped when it starts with gzip's magic) and its first bytes."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            raw = open(path, "rb")
        except FileNotFoundError:
            raise DataFormatError("no such file", path=path) from None
        except IsADirectoryError:
            raise DataFormatError("is a directory, not a CARMEN log", path=path) from None
        except OSError as err:
            raise DataFormatError(f"cannot read: {err.strerror or err}", path=path) from None
        self.raw = raw
        buffered = raw if isinstance(raw, io.BufferedReader) else io.BufferedReader(raw)  # type: ignore[arg-type]
        try:
            magic = buffered.peek(2)[:2]
        except OSError as err:
            raw.close()
            raise DataFormatError(f"cannot read: {err.strerror or err}", path=path) from None
        self.compressed = magic == b"\x1f\x8b"
        self.stream: Any = gzip.GzipFile(fileobj=buffered, mode="rb") if self.compressed else buffered
        self.head = b""
        self.lines = 0  # lines read so far (blank and foreign ones included)

    def close(self) -> None:
        try:
            self.stream.close()
        finally:
            self.raw.close()


def is_regular(path: str | Path) -> bool:
    """True when ``path`` is a regular file (it can be read twice); a pipe, a FIFO or a device cannot."""
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except OSError:
        return False


def _blocks(src: _Source) -> Iterator[bytes]:
    while True:
        try:
            block = src.stream.read(_BLOCK)
        except (EOFError, zlib.error, gzip.BadGzipFile, OSError) as err:
            raise DataFormatError(f"corrupt or truncated file after line {src.lines}: {err}", path=src.path) from None
        if not block:
            return
        if len(src.head) < 4096:
            src.head += block[: 4096 - len(src.head)]
        yield block


def _too_long(src: _Source, lineno: int) -> DataFormatError:
    if b"\x00" in src.head:
        return DataFormatError("not a CARMEN log: binary data, not text", path=src.path)
    return DataFormatError(
        f"line {lineno} is longer than {MAX_LINE_BYTES:,} bytes: not a CARMEN log line", path=src.path
    )


def _source_lines(src: _Source) -> Iterator[tuple[int, str]]:
    """Numbered lines (1-based) that may hold a message; blank and foreign lines are skipped (still counted)."""
    lineno = 0
    carry = b""
    for block in _blocks(src):
        data = carry + block if carry else block
        cut = data.rfind(b"\n")
        if cut < 0:
            if len(data) > MAX_LINE_BYTES:
                raise _too_long(src, lineno + 1)
            carry = data
            continue
        carry = data[cut + 1 :]
        if len(carry) > MAX_LINE_BYTES:
            raise _too_long(src, lineno + data.count(b"\n") + 1)
        body = data[:cut]
        if not body.strip() or not any(k in body for k in _SEARCH):  # nothing to read in the block: count its lines
            if len(body) > MAX_LINE_BYTES and max(map(len, body.split(b"\n"))) > MAX_LINE_BYTES:
                raise _too_long(src, lineno + 1)
            lineno += body.count(b"\n") + 1
            src.lines = lineno
            continue
        for line in body.split(b"\n"):
            lineno += 1
            if len(line) > MAX_LINE_BYTES:
                raise _too_long(src, lineno)
            head = line.lstrip()[:10]
            if head.startswith(_KEYWORDS):
                src.lines = lineno
                yield lineno, line.decode("utf-8", "replace")
        src.lines = lineno
    if carry:
        lineno += 1
        src.lines = lineno
        if carry.lstrip()[:10].startswith(_KEYWORDS):
            yield lineno, carry.decode("utf-8", "replace")


def _lines(path: Path) -> Iterator[tuple[int, str]]:
    """Numbered lines (1-based) of a plain or gzip file, opened once; read errors become :class:`DataFormatError`."""
    src = _Source(path)
    try:
        yield from _source_lines(src)
    finally:
        src.close()


def _float(tok: str, what: str) -> float:
    try:
        return float(tok)
    except ValueError:
        raise DataFormatError(f"{what} must be a number, got {tok!r}") from None


def _int(tok: str, what: str) -> int:
    try:
        v = int(tok)
    except ValueError:
        raise DataFormatError(f"{what} must be an integer, got {tok!r}") from None
    if v < 0:
        raise DataFormatError(f"{what} must be >= 0, got {v}")
    return v


def _floats(toks: list[str], what: str) -> np.ndarray:
    try:
        arr = np.array([float(t) for t in toks], dtype=np.float64)
    except ValueError:
        bad = next(t for t in toks if not _is_number(t))
        raise DataFormatError(f"{what} must be numbers, got {bad!r}") from None
    return arr


def _is_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def _pose(toks: list[str], what: str) -> tuple[float, float, float]:
    x, y, th = (_float(t, what) for t in toks)
    if not all(math.isfinite(v) for v in (x, y, th)):
        raise DataFormatError(f"{what} must be finite, got {' '.join(toks)}")
    if abs(x) > MAX_COORD_M or abs(y) > MAX_COORD_M:
        raise DataFormatError(f"{what} must lie within +-{MAX_COORD_M:g} m, got {' '.join(toks)}")
    return (x, y, th)


def _check_count(parts: list[str], expected: int, msg: str) -> None:
    if len(parts) != expected:
        raise DataFormatError(f"{msg} line has {len(parts)} fields, expected {expected}")


def _check_ranges(ranges: np.ndarray, msg: str) -> None:
    if np.any(ranges < 0):
        raise DataFormatError(f"{msg} reading must be >= 0, got {float(ranges[ranges < 0][0])!r}")


def parse_line(text: str, *, line: int = 0) -> LaserRecord | OdomRecord | None:
    """Parse one CARMEN line; ``None`` for a line of another type, a comment or a blank.

    Parameters
    ----------
    text : str
        The line.
    line : int
        Its 1-based number (stored in the record).

    Raises
    ------
    DataFormatError
        A ``FLASER``, ``RLASER``, ``ROBOTLASER1/2`` or ``ODOM`` line with a wrong
        number of fields or a non-numeric value (without path and line: the
        caller adds them).
    """
    parts = text.split()
    if not parts or parts[0].startswith("#"):
        return None
    msg = parts[0]
    if msg in ("FLASER", "RLASER"):
        if len(parts) < 2:
            raise DataFormatError(f"{msg} line has no beam count")
        n = _int(parts[1], f"{msg} beam count")
        if n < 2:
            raise DataFormatError(f"{msg} line needs at least 2 beams, got {n}")
        _check_count(parts, 2 + n + _FLASER_TAIL, msg)
        ranges = _floats(parts[2 : 2 + n], f"{msg} readings")
        _check_ranges(ranges, msg)
        t = 2 + n
        pose = _pose(parts[t : t + 3], f"{msg} pose")
        odom = _pose(parts[t + 3 : t + 6], f"{msg} odometry")
        ts = _float(parts[t + 6], f"{msg} timestamp")
        return LaserRecord(
            message=msg,
            ranges=ranges,
            bearings=flaser_bearings(n, rear=msg == "RLASER"),
            pose=pose,
            sensor_offset=(0.0, 0.0, 0.0),
            odom=odom,
            intensities=None,
            max_range=None,
            timestamp=ts,
            line=line,
        )
    if msg in ("ROBOTLASER1", "ROBOTLASER2"):
        if len(parts) < 1 + _ROBOTLASER_HEAD + 1:
            raise DataFormatError(f"{msg} line has {len(parts)} fields, too few for its header")
        start = _float(parts[2], f"{msg} start angle")
        fov = _float(parts[3], f"{msg} field of view")
        res = _float(parts[4], f"{msg} angular resolution")
        max_range = _float(parts[5], f"{msg} maximum range")
        n = _int(parts[8], f"{msg} beam count")
        if n < 2:
            raise DataFormatError(f"{msg} line needs at least 2 beams, got {n}")
        m_at = 9 + n
        if len(parts) <= m_at:
            raise DataFormatError(f"{msg} line has {len(parts)} fields, too few for {n} readings")
        m = _int(parts[m_at], f"{msg} remission count")
        _check_count(parts, m_at + 1 + m + _ROBOTLASER_TAIL, msg)
        if not (math.isfinite(start) and math.isfinite(fov) and math.isfinite(res)):
            raise DataFormatError(f"{msg} angles must be finite")
        if res <= 0:
            # Fall back on the field of view when the resolution field is unusable.
            if fov <= 0:
                raise DataFormatError(f"{msg} angular resolution must be > 0, got {res!r}")
            res = fov / (n - 1)
        if res * (n - 1) > 2 * math.pi + 1e-6:
            raise DataFormatError(f"{msg} beams cover more than one turn: {n} x {res!r} rad")
        if not (math.isfinite(max_range) and max_range > 0):
            raise DataFormatError(f"{msg} maximum range must be a positive number, got {parts[5]!r}")
        ranges = _floats(parts[9 : 9 + n], f"{msg} readings")
        _check_ranges(ranges, msg)
        remissions = _floats(parts[m_at + 1 : m_at + 1 + m], f"{msg} remissions") if m else None
        if remissions is not None and m != n:
            remissions = None  # remissions that do not match the beams one-to-one are not usable
        t = m_at + 1 + m
        laser = _pose(parts[t : t + 3], f"{msg} laser pose")
        robot = _pose(parts[t + 3 : t + 6], f"{msg} robot pose")
        ts = _float(parts[t + 11], f"{msg} timestamp")
        # Sensor pose in the robot frame: rotate the world offset by -robot_theta.
        dx, dy = laser[0] - robot[0], laser[1] - robot[1]
        c, s = math.cos(robot[2]), math.sin(robot[2])
        dth = math.remainder(laser[2] - robot[2], 2 * math.pi)
        offset = (c * dx + s * dy, -s * dx + c * dy, dth)
        return LaserRecord(
            message=msg,
            ranges=ranges,
            bearings=start + res * np.arange(n, dtype=np.float64),
            pose=robot,
            sensor_offset=offset,
            odom=None,
            intensities=remissions,
            max_range=max_range,
            timestamp=ts,
            line=line,
        )
    if msg == "ODOM":
        _check_count(parts, _ODOM_FIELDS, msg)
        pose = _pose(parts[1:4], "ODOM pose")
        tv, rv, acc = (_float(parts[i], f"ODOM field {i}") for i in (4, 5, 6))
        ts = _float(parts[7], "ODOM timestamp")
        return OdomRecord(pose=pose, tv=tv, rv=rv, accel=acc, timestamp=ts, line=line)
    return None


def iter_records(
    path: str | Path,
    *,
    skip_bad: bool = False,
    stats: ReadStats | None = None,
) -> Iterator[LaserRecord | OdomRecord]:
    """Stream the laser and odometry records of a CARMEN log, in file order.

    Parameters
    ----------
    path : str or Path
        Plain or gzip log (gzip is recognised by its magic bytes).
    skip_bad : bool, default False
        Skip malformed lines instead of raising; ``stats.skipped`` counts them.
    stats : ReadStats, optional
        Filled while streaming.

    Raises
    ------
    DataFormatError
        A malformed line (message names the path and the 1-based line number),
        or an unreadable / corrupt file.
    """
    p = Path(path)
    st = stats if stats is not None else ReadStats()
    src = _Source(p)
    start = st.lines
    try:
        for lineno, text in _source_lines(src):
            st.lines = start + lineno
            try:
                rec = parse_line(text, line=lineno)
            except DataFormatError as err:
                located = err.at(path=p, line=lineno)
                if skip_bad:
                    st.record_skip(located)
                    continue
                raise located from None
            if rec is not None:
                yield rec
        st.lines = start + src.lines
    finally:
        src.close()


def _saturation_value(counts: Counter[float], *, min_repeats: int, saturation_band: float) -> float | None:
    repeated = sorted(v for v, c in counts.items() if c >= min_repeats and v > 0)
    if repeated:
        top = repeated[-1]
        lo = top * (1.0 - saturation_band)
        return min(v for v in repeated if v >= lo)
    if counts:
        top = max(counts)
        if any(math.isclose(top, code, abs_tol=1e-9) for code in KNOWN_NO_RETURN_CODES):
            return top
    return None


class _Inspector:
    """What :func:`inspect_log` counts, fed line by line (one pass may also keep the records)."""

    def __init__(self, min_repeats: int, saturation_band: float, top_values: int) -> None:
        if min_repeats < 1:
            raise InvalidParameterError(f"min_repeats must be >= 1, got {min_repeats}")
        if not (0 <= saturation_band < 1):
            raise InvalidParameterError(f"saturation_band must be in [0, 1), got {saturation_band!r}")
        self.min_repeats, self.saturation_band, self.top_values = min_repeats, saturation_band, top_values
        self.counts: Counter[str] = Counter()
        self.tops: dict[str, Counter[float]] = {}
        self.line_max: dict[str, float] = {}
        self.params: dict[str, str] = {}

    def param(self, text: str) -> None:
        parts = text.split()
        if len(parts) >= 3:
            self.params[parts[1]] = parts[2]

    def laser(self, rec: LaserRecord) -> None:
        self.counts[rec.message] += 1
        c = self.tops.setdefault(rec.message, Counter())
        vals, reps = np.unique(rec.ranges, return_counts=True)
        # Keep the top values only: a cheap bound on memory for huge logs.
        k = self.top_values
        for v, n in zip(vals[-k:].tolist(), reps[-k:].tolist(), strict=True):
            c[v] += n
        if len(c) > 4 * k:
            for v in sorted(c)[: len(c) - k]:
                del c[v]
        if rec.max_range is not None:
            self.line_max[rec.message] = rec.max_range

    def info(self, src: _Source | None) -> LogInfo:
        max_range: dict[str, float | None] = {}
        for msg in self.tops:
            found = _saturation_value(self.tops[msg], min_repeats=self.min_repeats, saturation_band=self.saturation_band)
            if found is None and msg in self.line_max:
                found = self.line_max[msg]
            if found is None:
                for name in _PARAM_MAX_RANGE.get(msg, ()):
                    if name in self.params and _is_number(self.params[name]) and 0 < float(self.params[name]) < math.inf:
                        found = float(self.params[name])
                        break
            max_range[msg] = found
        head, gz = (src.head, src.compressed) if src is not None else (b"", False)
        return LogInfo(counts=dict(self.counts), max_range=max_range, params=self.params, head=head, compressed=gz)


def _odom_valid(text: str) -> bool:
    """True when :func:`parse_line` would read ``text`` as an ``ODOM`` record without error (a quicker check)."""
    parts = text.split()
    if len(parts) != _ODOM_FIELDS or parts[0] != "ODOM":
        return False
    try:
        x, y, th, *_ = (float(t) for t in parts[1:8])
    except ValueError:
        return False
    return math.isfinite(x) and math.isfinite(y) and math.isfinite(th) and abs(x) <= MAX_COORD_M and abs(y) <= MAX_COORD_M


def _is_message(text: str) -> str:
    head = text.lstrip()[:12]
    if head.startswith("PARAM"):
        return "PARAM"
    if head.startswith(("FLASER", "RLASER", "ROBOTLASER")):
        return "LASER"
    if head.startswith("ODOM"):
        return "ODOM"
    return ""


def inspect_log(
    path: str | Path,
    *,
    min_repeats: int = 3,
    saturation_band: float = 0.005,
    top_values: int = 64,
) -> LogInfo:
    """Stream once through a log: message counts, ``PARAM`` values and each laser's no-return threshold.

    Malformed lines are ignored here (the reading pass reports them).

    Parameters
    ----------
    path : str or Path
    min_repeats : int, default 3
        How many times a reading must occur to count as a saturation code.
    saturation_band : float, default 0.005
        Relative band below the largest repeated reading in which a smaller
        repeated reading is taken as a second no-return code.
    top_values : int, default 64
        Only the largest distinct readings per message type are counted
        (bounded memory).

    Returns
    -------
    LogInfo
    """
    acc = _Inspector(min_repeats, saturation_band, top_values)
    src = _Source(Path(path))
    try:
        for lineno, text in _source_lines(src):
            kind = _is_message(text)
            if kind == "PARAM":
                acc.param(text)
            elif kind == "ODOM":
                acc.counts["ODOM"] += 1
            elif kind == "LASER":
                try:
                    rec = parse_line(text, line=lineno)
                except DataFormatError:
                    continue
                if isinstance(rec, LaserRecord):
                    acc.laser(rec)
    finally:
        src.close()
    return acc.info(src)


def read_log(
    path: str | Path,
    *,
    skip_bad: bool = False,
    stats: ReadStats | None = None,
    min_repeats: int = 3,
    saturation_band: float = 0.005,
    top_values: int = 64,
) -> tuple[LogInfo, list[LaserRecord]]:
    """Read a log once: what :func:`inspect_log` finds, and every laser record in file order.

    For a stream that cannot be read twice (a pipe, a FIFO), and for callers
    that keep every scan anyway (``map``, ``localize``, ``track``).

    Raises
    ------
    DataFormatError
        A malformed line (unless ``skip_bad``), a line too long, an unreadable file.
    """
    acc = _Inspector(min_repeats, saturation_band, top_values)
    st = stats if stats is not None else ReadStats()
    p = Path(path)
    records: list[LaserRecord] = []
    src = _Source(p)
    try:
        start = st.lines
        for lineno, text in _source_lines(src):
            st.lines = start + lineno
            kind = _is_message(text)
            if kind == "PARAM":
                acc.param(text)
                continue
            if kind == "ODOM" and _odom_valid(text):  # only counted here: checked without building a record
                acc.counts["ODOM"] += 1
                continue
            try:
                rec = parse_line(text, line=lineno)
            except DataFormatError as err:
                located = err.at(path=p, line=lineno)
                if skip_bad:
                    st.record_skip(located)
                    continue
                raise located from None
            if isinstance(rec, LaserRecord):
                acc.laser(rec)
                records.append(rec)
            elif isinstance(rec, OdomRecord):
                acc.counts["ODOM"] += 1
        st.lines = start + src.lines
    finally:
        src.close()
    return acc.info(src), records


def detect_max_range(path: str | Path, message: str = "FLASER") -> float | None:
    """The no-return threshold (metres) of ``message`` lines in a log, or ``None`` (see :func:`inspect_log`)."""
    return inspect_log(path).max_range.get(message)


def _to_scan(rec: LaserRecord, max_range: float | None, path: Path) -> Scan:
    if max_range is None:
        finite = rec.ranges[np.isfinite(rec.ranges)]
        # Nothing marks no-return: keep every reading (the threshold sits above the largest).
        max_range = float(finite.max()) + 1.0 if finite.size else 1.0
    try:
        return Scan(
            ranges=rec.ranges,
            bearings=rec.bearings,
            max_range=max_range,
            intensities=rec.intensities,
            pose=rec.pose,
            sensor_offset=rec.sensor_offset,
            timestamp=rec.timestamp,
        )
    except InvalidParameterError as err:
        raise DataFormatError(f"{rec.message}: {err}", path=path, line=rec.line) from None


def iter_laser(
    path: str | Path,
    *,
    skip_bad: bool = False,
    messages: Collection[str] | None = None,
    max_range: float | None = None,
    stats: ReadStats | None = None,
    info: LogInfo | None = None,
) -> Iterator[tuple[LaserRecord, Scan]]:
    """Like :func:`iter_scans`, but yield each scan with its raw record (message type, line number).

    ``info``: the log's :func:`inspect_log` when the caller has it (its
    thresholds are used; the log is then read once more). Without it, a
    regular file is inspected first, and a stream that cannot be read twice
    (a pipe, a FIFO) is read once by :func:`read_log`.
    """
    p = Path(path)
    wanted = set(LASER_MESSAGES if messages is None else messages)
    unknown = wanted - set(LASER_MESSAGES)
    if unknown:
        raise InvalidParameterError(
            f"unknown CARMEN laser message {sorted(unknown)[0]!r} (known: {', '.join(LASER_MESSAGES)})"
        )
    if max_range is not None and not (math.isfinite(max_range) and max_range > 0):
        raise InvalidParameterError(f"max_range must be a positive number of metres, got {max_range!r}")
    thresholds: dict[str, float | None] = {}
    st = stats if stats is not None else ReadStats()
    source: Iterator[LaserRecord | OdomRecord]
    if max_range is None and info is None and not is_regular(p):
        found, recs = read_log(p, skip_bad=skip_bad, stats=st)
        thresholds, source = found.max_range, iter(recs)
    else:
        if max_range is None:
            thresholds = (info if info is not None else inspect_log(p)).max_range
        source = iter_records(p, skip_bad=skip_bad, stats=st)
    for rec in source:
        if not isinstance(rec, LaserRecord) or rec.message not in wanted:
            continue
        thr = max_range if max_range is not None else thresholds.get(rec.message)
        try:
            scan = _to_scan(rec, thr, p)
        except DataFormatError as err:
            if skip_bad:
                st.record_skip(err)
                continue
            raise
        st.scans += 1
        yield rec, scan


def laser_scans(
    path: str | Path,
    records: Collection[LaserRecord],
    info: LogInfo,
    messages: Collection[str],
    *,
    skip_bad: bool = False,
    stats: ReadStats | None = None,
) -> Iterator[tuple[LaserRecord, Scan]]:
    """The scans of records :func:`read_log` kept, of the message types ``messages``, with the log's thresholds."""
    p = Path(path)
    st = stats if stats is not None else ReadStats()
    wanted = set(messages)
    for rec in records:
        if rec.message not in wanted:
            continue
        try:
            scan = _to_scan(rec, info.max_range.get(rec.message), p)
        except DataFormatError as err:
            if skip_bad:
                st.record_skip(err)
                continue
            raise
        st.scans += 1
        yield rec, scan


def iter_scans(
    path: str | Path,
    *,
    skip_bad: bool = False,
    messages: Collection[str] | None = None,
    max_range: float | None = None,
    stats: ReadStats | None = None,
) -> Iterator[Scan]:
    """Stream the laser scans of a CARMEN log as :class:`~fingerloc.sensors.Scan`, in file order.

    Parameters
    ----------
    path : str or Path
        Plain or gzip CARMEN log.
    skip_bad : bool, default False
        Skip malformed lines instead of raising; their number is in
        ``stats.skipped`` when the generator is exhausted.
    messages : collection of str, optional
        Laser message types to read (default all of :data:`LASER_MESSAGES`).
        A log holding both ``FLASER`` and ``ROBOTLASER1`` usually records the
        same laser twice: pick one (:func:`default_messages`).
    max_range : float, optional
        No-return threshold in metres for every laser; by default detected
        per message type by a first streaming pass (:func:`inspect_log`).
    stats : ReadStats, optional
        Filled while streaming (lines, scans, skipped lines).

    Yields
    ------
    Scan
        Ranges in metres with ``inf`` for no return; bearings in the robot
        frame; ``pose`` the robot's (corrected) pose; ``timestamp`` the IPC
        timestamp; ``intensities`` the remissions when present.

    Raises
    ------
    DataFormatError
        A malformed line, named by path and line number (unless ``skip_bad``).
    """
    for _, scan in iter_laser(path, skip_bad=skip_bad, messages=messages, max_range=max_range, stats=stats):
        yield scan


def require_laser(path: str | Path, info: LogInfo) -> None:
    """Raise unless the log holds a laser line; the message says what the file is instead.

    Raises
    ------
    DataFormatError
        Naming the path: an empty file, binary data (not a text log, or a
        ``.gz`` that is not gzip), or a text log without any laser message.
    """
    if any(info.counts.get(m, 0) for m in LASER_MESSAGES):
        return
    p = Path(path)
    head, compressed = info.head, info.compressed
    if not head and is_regular(p):  # a LogInfo made elsewhere: look at the file (a regular file reads again)
        try:
            with open(p, "rb") as fh:
                head = fh.read(4096)
        except OSError as err:
            raise DataFormatError(f"cannot read: {err.strerror or err}", path=p) from None
        if head[:2] == b"\x1f\x8b":
            compressed = True
            with gzip.open(p, "rb") as zfh:
                try:
                    head = zfh.read(4096)
                except (EOFError, zlib.error, gzip.BadGzipFile, OSError) as err:
                    raise DataFormatError(f"corrupt gzip file ({err})", path=p) from None
    if not head:
        raise DataFormatError("empty file: no laser scan", path=p)
    try:
        head.decode("utf-8")
        binary = b"\x00" in head
    except UnicodeDecodeError as err:
        binary = err.start < len(head) - 4  # not only a character cut at the end of the block
    if binary:
        gz = " (and not gzip)" if p.name.lower().endswith(".gz") and not compressed else ""
        raise DataFormatError(f"not a CARMEN log: binary data, not text{gz}", path=p)
    raise DataFormatError(f"no laser scan: not one {', '.join(LASER_MESSAGES)} line in this log", path=p)


def front_laser_messages(info: LogInfo) -> tuple[str, ...]:
    """The front laser only: ``FLASER`` when the log has it, else ``ROBOTLASER1`` (empty: neither).

    What the real-log benchmark and ``fingerloc map`` / ``localize`` / ``track``
    read (one scan per time step, one sensor); :func:`default_messages` adds
    the rear laser for ``fingerloc features``.
    """
    for m in ("FLASER", "ROBOTLASER1"):
        if info.counts.get(m, 0):
            return (m,)
    return ()


def default_messages(info: LogInfo) -> tuple[str, ...]:
    """The laser messages to read from a log without duplicates.

    ``FLASER`` and ``RLASER`` when the log has either, else ``ROBOTLASER1`` and
    ``ROBOTLASER2`` (logs that hold both kinds record the same lasers twice).
    """
    old = tuple(m for m in ("FLASER", "RLASER") if info.counts.get(m, 0))
    return old or tuple(m for m in ("ROBOTLASER1", "ROBOTLASER2") if info.counts.get(m, 0))


def read_scans(
    path: str | Path,
    *,
    skip_bad: bool = False,
    messages: Collection[str] | None = None,
    max_range: float | None = None,
    stats: ReadStats | None = None,
) -> list[Scan]:
    """All scans of a log as a list (see :func:`iter_scans`)."""
    return list(iter_scans(path, skip_bad=skip_bad, messages=messages, max_range=max_range, stats=stats))
