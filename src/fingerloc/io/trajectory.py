"""Trajectories in the text formats that trajectory tools read: TUM and KITTI.

fingerloc's poses are planar, ``(x, y, theta)`` in metres and radians. They
are written as 3D poses in the plane ``z = 0``, turned by ``theta`` about the
``z`` axis:

* **TUM** (the format of the TUM RGB-D benchmark, read by ``evo``): one pose a
  line, ``timestamp tx ty tz qx qy qz qw`` (seconds, metres, a unit
  quaternion, ``w`` last), separated by single spaces; lines starting with
  ``#`` are comments. Timestamps must increase strictly (``evo`` refuses
  duplicates).
* **KITTI** (the KITTI odometry benchmark's poses): one pose a line, the
  twelve numbers of the 3x4 matrix ``[R | t]`` row by row, no timestamp (the
  rows line up with another file's rows by their order).

Readers give the planar pose back: ``x``, ``y`` and the heading of the
rotated ``x`` axis in the plane (a pose that is not planar is projected;
``z`` is dropped). Writers write atomically: a temporary file next to the
target, renamed over it when every line is written, so a failed write leaves
an existing file as it was. :class:`TrajectoryWriter` writes one pose at a
time (a stream of steps) with the same guarantee.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import numpy as np

from .._types import FArray
from ..atomic import check_target, replace, temporary_name, umask
from ..errors import DataFormatError, EmptyInputError, InvalidParameterError

__all__ = [
    "STAMP_NUDGE_S",
    "TRAJECTORY_FORMATS",
    "TrajectoryWriter",
    "kitti_line",
    "quaternion_yaw",
    "read_kitti",
    "read_tum",
    "tum_line",
    "write_kitti",
    "write_tum",
    "yaw_quaternion",
]

#: The formats :class:`TrajectoryWriter` writes.
TRAJECTORY_FORMATS: tuple[str, ...] = ("tum", "kitti")

#: Seconds after the previous pose at which a TUM pose whose stamp does not increase is written (``strict=False``).
STAMP_NUDGE_S = 1e-6

Pose = tuple[float, float, float]


def yaw_quaternion(theta: float) -> tuple[float, float, float, float]:
    """The unit quaternion ``(x, y, z, w)`` of a turn by ``theta`` radians about the ``z`` axis."""
    return (0.0, 0.0, math.sin(theta / 2.0), math.cos(theta / 2.0))


def quaternion_yaw(qx: float, qy: float, qz: float, qw: float) -> float:
    """Heading (radians, in ``[-pi, pi]``) of the ``x`` axis turned by the quaternion ``(x, y, z, w)``, in the plane.

    The quaternion need not be normalised (its norm cancels).
    """
    # R[1,0] = 2(xy + zw), R[0,0] = 1 - 2(y^2 + z^2) of the normalised quaternion; both scale with |q|^2
    n2 = qx * qx + qy * qy + qz * qz + qw * qw
    return math.atan2(2.0 * (qx * qy + qz * qw), n2 - 2.0 * (qy * qy + qz * qz))


def _num(x: float) -> str:
    return repr(float(x))  # the shortest text that reads back to the same double


def _pose(pose: Any, what: str) -> Pose:
    try:
        x, y, th = (float(v) for v in pose)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"{what}: a pose must be (x, y, theta), got {pose!r}") from None
    if not all(math.isfinite(v) for v in (x, y, th)):
        raise InvalidParameterError(f"{what}: a pose must be finite, got {(x, y, th)!r}")
    return (x, y, th)


def tum_line(stamp: float, pose: Any) -> str:
    """One TUM line (no newline) for a planar pose ``(x, y, theta)`` at ``stamp`` seconds."""
    x, y, th = _pose(pose, "TUM")
    t = float(stamp)
    if not math.isfinite(t):
        raise InvalidParameterError(f"TUM: a timestamp must be finite, got {stamp!r}")
    qx, qy, qz, qw = yaw_quaternion(th)
    return " ".join(_num(v) for v in (t, x, y, 0.0, qx, qy, qz, qw))


def kitti_line(pose: Any) -> str:
    """One KITTI line (no newline): the 3x4 matrix ``[R | t]`` of a planar pose, row by row."""
    x, y, th = _pose(pose, "KITTI")
    c, s = math.cos(th), math.sin(th)
    rows = ((c, -s, 0.0, x), (s, c, 0.0, y), (0.0, 0.0, 1.0, 0.0))
    return " ".join(_num(v) for row in rows for v in row)


class TrajectoryWriter:
    """Write a trajectory one pose at a time; the file appears (atomically) at :meth:`close`.

    Inside a :class:`fingerloc.atomic.OutputGroup` the file appears with the
    group's other outputs (or not at all when the group fails).

    Lines go to a temporary file next to ``path`` (flushed after each pose
    when ``flush=True``, so a crash loses nothing already written there);
    :meth:`close` renames it over ``path``, :meth:`discard` (or leaving a
    ``with`` block by an exception) removes it and leaves ``path`` untouched.

    Parameters
    ----------
    path : str or Path
        The trajectory file. A symbolic link stays a link (its target is replaced).
    fmt : {"tum", "kitti"}
    flush : bool, default False
        Flush the temporary file after every pose.
    strict : bool, default True
        TUM: refuse a stamp that is not after the previous one. False: write
        it :data:`STAMP_NUDGE_S` after the previous one instead (counted in
        :attr:`nudged`); some logs repeat stamps or write them with too few digits.

    Raises
    ------
    InvalidParameterError
        An unknown format, a path that is not a regular file (a device, a FIFO, a link loop), or a directory
        that cannot hold the file.
    """

    def __init__(self, path: str | Path, fmt: str = "tum", *, flush: bool = False, strict: bool = True) -> None:
        if fmt not in TRAJECTORY_FORMATS:
            raise InvalidParameterError(
                f"trajectory format must be one of {', '.join(TRAJECTORY_FORMATS)}, got {fmt!r}"
            )
        p = Path(path)
        self.path = p
        self.fmt = fmt
        self.count = 0
        self.nudged = 0
        self._strict = strict
        self._flush = flush
        self._last: float | None = None
        target = check_target(p, fmt.upper())  # a regular file or none: a device, a FIFO, a link loop are refused
        self._target = target
        directory = target.parent if str(target.parent) else Path(".")
        self._mode = target.stat().st_mode & 0o7777 if target.is_file() else 0o666 & ~umask()
        prefix, suffix = temporary_name(target)
        try:
            fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=directory)
        except OSError as err:
            raise InvalidParameterError(f"cannot write {p}: {err.strerror or err}") from None
        self._tmp = Path(tmp)
        self._fh: IO[str] | None = os.fdopen(fd, "w", encoding="utf-8")

    def add(self, pose: Any, stamp: float | None = None) -> None:
        """Append one pose ``(x, y, theta)``; TUM needs its ``stamp`` (seconds, after the previous one's).

        Raises
        ------
        InvalidParameterError
            A pose that is not three finite numbers, a TUM pose without a
            finite stamp or with a stamp not after the previous one, or a
            writer already closed.
        """
        if self._fh is None:
            raise InvalidParameterError(f"{self.path}: the trajectory writer is closed")
        if self.fmt == "tum":
            if stamp is None:
                raise InvalidParameterError(f"TUM: pose {self.count + 1} has no timestamp")
            if self._last is not None and not float(stamp) > self._last and not self._strict:
                stamp = self._last + STAMP_NUDGE_S
                self.nudged += 1
            if self._last is not None and not float(stamp) > self._last:
                raise InvalidParameterError(
                    f"TUM: timestamps must increase, pose {self.count + 1} at {float(stamp)!r} s "
                    f"follows one at {self._last!r} s"
                )
            line = tum_line(stamp, pose)
            self._last = float(stamp)
        else:
            line = kitti_line(pose)
        self._fh.write(line + "\n")
        if self._flush:
            self._fh.flush()
        self.count += 1

    def close(self) -> int:
        """Put the file in place; returns the number of poses written (idempotent)."""
        if self._fh is None:
            return self.count
        fh, self._fh = self._fh, None
        try:
            fh.flush()
            os.fsync(fh.fileno())
            fh.close()
            os.chmod(self._tmp, self._mode)
            replace(self._tmp, self._target)  # inside an OutputGroup: with the command's other outputs
        except BaseException:
            self._tmp.unlink(missing_ok=True)
            raise
        return self.count

    def discard(self) -> None:
        """Drop what was written; ``path`` stays as it was."""
        if self._fh is not None:
            fh, self._fh = self._fh, None
            fh.close()
        self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> TrajectoryWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.discard()


def _rows(poses: Any, what: str) -> FArray:
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InvalidParameterError(f"{what}: poses must have shape (n, 3), got {p.shape}")
    return p


def write_tum(path: str | Path, stamps: Sequence[float] | FArray, poses: Any) -> int:
    """Write planar poses ``(n, 3)`` (metres, radians) at ``stamps`` ``(n,)`` (seconds, increasing) as TUM.

    Returns
    -------
    int
        Poses written.
    """
    p = _rows(poses, "TUM")
    t = np.asarray(stamps, dtype=np.float64).reshape(-1)
    if t.size != p.shape[0]:
        raise InvalidParameterError(f"TUM: {t.size} timestamps for {p.shape[0]} poses")
    with TrajectoryWriter(path, "tum") as w:
        for ti, pi in zip(t.tolist(), p.tolist(), strict=True):
            w.add(pi, ti)
    return w.count


def write_kitti(path: str | Path, poses: Any) -> int:
    """Write planar poses ``(n, 3)`` (metres, radians) as KITTI 3x4 matrices; returns the number written."""
    p = _rows(poses, "KITTI")
    with TrajectoryWriter(path, "kitti") as w:
        for pi in p.tolist():
            w.add(pi)
    return w.count


def _numbers(path: Path, expected: int, what: str) -> Iterable[tuple[int, list[float]]]:
    try:
        fh = open(path, encoding="utf-8")
    except OSError as err:
        raise DataFormatError(f"cannot read: {err.strerror or err}", path=path) from None
    with fh:
        lineno = 0
        try:
            for lineno, text in enumerate(fh, start=1):
                s = text.strip()
                if not s or s.startswith("#"):
                    continue
                parts = s.split()
                if len(parts) != expected:
                    raise DataFormatError(f"{what} line has {len(parts)} numbers, expected {expected}", path=path,
                                          line=lineno)  # fmt: skip
                try:
                    vals = [float(v) for v in parts]
                except ValueError:
                    bad = next(v for v in parts if not _is_float(v))
                    raise DataFormatError(
                        f"{what} value must be a number, got {bad!r}", path=path, line=lineno
                    ) from None
                if not all(math.isfinite(v) for v in vals):
                    raise DataFormatError(f"{what} values must be finite", path=path, line=lineno)
                yield lineno, vals
        except UnicodeDecodeError as err:
            raise DataFormatError("not a UTF-8 text file", path=path, line=lineno + 1) from err


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_tum(path: str | Path) -> tuple[FArray, FArray]:
    """Read a TUM trajectory as timestamps and planar poses.

    Returns
    -------
    stamps : ndarray, shape (n,)
        Seconds, as written.
    poses : ndarray, shape (n, 3)
        ``(x, y, theta)``, metres and radians (``z`` dropped, the rotation
        reduced to its heading in the plane).

    Raises
    ------
    DataFormatError
        A line without 8 numbers, a non-finite value, or a zero quaternion
        (naming the path and line).
    EmptyInputError
        No pose in the file.
    """
    p = Path(path)
    stamps: list[float] = []
    poses: list[Pose] = []
    for lineno, v in _numbers(p, 8, "TUM"):
        qx, qy, qz, qw = v[4:8]
        if qx * qx + qy * qy + qz * qz + qw * qw < 1e-12:
            raise DataFormatError("TUM quaternion is zero", path=p, line=lineno)
        stamps.append(v[0])
        poses.append((v[1], v[2], quaternion_yaw(qx, qy, qz, qw)))
    if not poses:
        raise EmptyInputError("no pose in the TUM file", path=p)
    return np.array(stamps, dtype=np.float64), np.array(poses, dtype=np.float64).reshape(-1, 3)


def read_kitti(path: str | Path) -> FArray:
    """Read a KITTI pose file as planar poses ``(n, 3)`` (``x``, ``y`` of ``t``; heading of ``R``'s first column).

    Raises
    ------
    DataFormatError
        A line without 12 numbers or a non-finite value (naming the path and line).
    EmptyInputError
        No pose in the file.
    """
    p = Path(path)
    poses = [(v[3], v[7], math.atan2(v[4], v[0])) for _, v in _numbers(p, 12, "KITTI")]
    if not poses:
        raise EmptyInputError("no pose in the KITTI file", path=p)
    return np.array(poses, dtype=np.float64).reshape(-1, 3)
