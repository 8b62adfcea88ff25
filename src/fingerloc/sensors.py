"""Raw sensor data types: a laser :class:`Scan` and a :class:`Panorama` image.

Readers (CARMEN logs, ROS bags, image files) and the simulator produce these;
feature extractors consume them. Angles in radians; bearings are relative to
the robot's heading, counter-clockwise positive.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ._types import FArray
from .angles import TWO_PI, wrap
from .errors import InvalidParameterError

__all__ = ["Panorama", "Scan"]



def _ro(a: object) -> FArray:
    arr: FArray = np.array(a, dtype=np.float64, copy=True)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, slots=True, eq=False)
class Scan:
    """One 2D laser scan.

    Parameters
    ----------
    ranges : array_like of float, shape (n,)
        Range of each beam in metres. A beam with no return is ``inf``
        (readers turn readings at or above ``max_range`` into ``inf``).
    bearings : array_like of float, shape (n,)
        Bearing of each beam in radians relative to the robot's heading,
        counter-clockwise, increasing (not wrapped: a scan from -135 deg to
        +135 deg keeps that order).
    max_range : float
        Largest range the sensor reports, metres.
    intensities : array_like of float, shape (n,), optional
        Remission / intensity per beam in the sensor's own unit and scale.
    pose : (x, y, theta), optional
        Pose of the robot (metres, radians) when the scan was taken.
    sensor_offset : (x, y, theta), optional
        Pose of the sensor in the robot frame; default at the robot's origin.
    timestamp : float, optional
        Seconds.
    coverage : tuple of (start, width), optional
        The covered bearings (radians, robot frame) when they are not the
        span of the beams: a scan merged from several lidars covers the union
        of theirs (see :func:`fingerloc.io.frames.merge_scans`). ``None``:
        the beams' own span (:attr:`fov`).
    """

    ranges: FArray
    bearings: FArray
    max_range: float = 80.0
    intensities: FArray | None = None
    pose: tuple[float, float, float] | None = None
    sensor_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    timestamp: float | None = None
    coverage: tuple[tuple[float, float], ...] | None = None

    def __post_init__(self) -> None:
        r = np.array(self.ranges, dtype=np.float64).reshape(-1)
        b = np.array(self.bearings, dtype=np.float64).reshape(-1)
        if r.shape != b.shape:
            raise InvalidParameterError(f"ranges and bearings must have the same length, got {r.size} and {b.size}")
        if r.size < 2:
            raise InvalidParameterError(f"a scan needs at least 2 beams, got {r.size}")
        if not np.all(np.isfinite(b)):
            raise InvalidParameterError("bearings must be finite")
        if np.any(np.diff(b) <= 0):
            raise InvalidParameterError("bearings must increase strictly")
        if b[-1] - b[0] > TWO_PI + 1e-9:
            raise InvalidParameterError("a scan covers at most one turn")
        if not (np.isfinite(self.max_range) and self.max_range > 0):
            raise InvalidParameterError(f"max_range must be a positive number of metres, got {self.max_range!r}")
        r = np.where(np.isnan(r) | (r >= self.max_range), np.inf, r)
        if np.any(r < 0):
            raise InvalidParameterError(f"ranges must be >= 0, got {float(r[r < 0][0])!r}")
        object.__setattr__(self, "ranges", _ro(r))
        object.__setattr__(self, "bearings", _ro(b))
        object.__setattr__(self, "max_range", float(self.max_range))
        if self.intensities is not None:
            i = np.array(self.intensities, dtype=np.float64).reshape(-1)
            if i.shape != r.shape:
                raise InvalidParameterError(f"one intensity per beam is needed, got {i.size} for {r.size} beams")
            object.__setattr__(self, "intensities", _ro(i))
        if self.pose is not None:
            object.__setattr__(self, "pose", tuple(float(v) for v in self.pose))
        object.__setattr__(self, "sensor_offset", tuple(float(v) for v in self.sensor_offset))
        if self.coverage is not None:
            cov = tuple((float(s), float(w)) for s, w in self.coverage)
            if not cov or not all(np.isfinite(s) and 0 < w <= TWO_PI + 1e-9 for s, w in cov):
                raise InvalidParameterError(f"coverage: (start, width) ranges with 0 < width <= 2 pi, got {cov!r}")
            object.__setattr__(self, "coverage", cov)

    @property
    def valid(self) -> NDArray[np.bool_]:
        """Mask of beams with a return, shape (n,)."""
        return np.isfinite(self.ranges)

    @property
    def angular_step(self) -> float:
        """Median angle between consecutive beams, radians."""
        return float(np.median(np.diff(self.bearings)))

    @property
    def fov(self) -> tuple[tuple[float, float], ...]:
        """The covered bearings as ``(start, width)`` ranges in radians (robot frame).

        Half a beam step is added on each side; a scan whose beams close the
        circle covers the full circle. A scan with an explicit ``coverage``
        (a merged scan) returns it instead, possibly several ranges.
        """
        if self.coverage is not None:
            return self.coverage
        step = self.angular_step
        width = float(self.bearings[-1] - self.bearings[0] + step)
        start = float(self.bearings[0] - step / 2 + self.sensor_offset[2])
        if width >= TWO_PI - 1e-9:
            return ((-np.pi, TWO_PI),)
        return ((float(wrap(start)), width),)

    def points(self) -> FArray:
        """Cartesian end points of the beams with a return, in the robot frame, shape (m, 2), metres."""
        ok = self.valid
        ox, oy, oth = self.sensor_offset
        a = self.bearings[ok] + oth
        r = self.ranges[ok]
        return np.column_stack([ox + r * np.cos(a), oy + r * np.sin(a)])


@dataclass(frozen=True, slots=True, eq=False)
class Panorama:
    """A 360 deg cylindrical panorama: columns are bearings, rows elevations.

    Parameters
    ----------
    image : array_like, shape (h, w, 3)
        RGB, ``uint8`` or float in ``[0, 1]`` (stored as float32 in ``[0, 1]``).
    bearing_offset : float, default 0
        Bearing (radians) of the left edge of column 0.
    clockwise : bool, default True
        True when bearing decreases as the column index grows, as in a
        photograph taken by a camera turning to its right (the usual
        equirectangular panorama). Column ``j`` covers bearings from
        ``offset -/+ 2 pi j / w`` to ``offset -/+ 2 pi (j+1) / w``.
    """

    image: NDArray[np.float32]
    bearing_offset: float = 0.0
    clockwise: bool = True
    meta: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        img = np.asarray(self.image)
        if img.ndim != 3 or img.shape[2] != 3:
            raise InvalidParameterError(f"a panorama must be an (h, w, 3) RGB array, got shape {img.shape}")
        if img.shape[0] < 2 or img.shape[1] < 8:
            raise InvalidParameterError(f"panorama too small: {img.shape[1]}x{img.shape[0]} pixels")
        if img.dtype == np.uint8:
            f = img.astype(np.float32) / 255.0
        else:
            f = img.astype(np.float32)
            if not np.all(np.isfinite(f)) or f.min() < 0 or f.max() > 1:
                raise InvalidParameterError("a float panorama must hold values in [0, 1]")
        f.setflags(write=False)
        object.__setattr__(self, "image", f)
        object.__setattr__(self, "bearing_offset", float(self.bearing_offset))

    @property
    def width(self) -> int:
        """Number of columns."""
        return int(self.image.shape[1])

    def column_bearing(self, col: NDArray[np.float64] | float) -> FArray:
        """Bearing (radians, wrapped) of fractional column coordinates (``j + 0.5`` is column ``j``'s centre)."""
        sign = -1.0 if self.clockwise else 1.0
        return wrap(self.bearing_offset + sign * TWO_PI * np.asarray(col, dtype=np.float64) / self.width)

    def bearing_column(self, bearing: NDArray[np.float64] | float) -> FArray:
        """Fractional column coordinate, in ``[0, w)``, of bearings in radians."""
        sign = -1.0 if self.clockwise else 1.0
        frac = np.mod(sign * (np.asarray(bearing, dtype=np.float64) - self.bearing_offset), TWO_PI) / TWO_PI
        return np.mod(frac * self.width, self.width)
