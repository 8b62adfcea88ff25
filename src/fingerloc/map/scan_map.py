"""A likelihood field of a mapping run's laser end points: where, inside a place, the robot is.

The fingerprint program answers *which place*; a place is a disc of about a
metre, and on a 2D laser its answers are most often wrong by one place along
a corridor. A run recorded with a range sensor also tells *where exactly*:
the end points of its scans, at the run's (corrected) poses, draw the walls
in the mapping frame. :class:`ScanMap` keeps them as an occupancy grid and,
for a query scan, scores any candidate pose of the robot by how close the
scan's end points fall to the mapped ones: the *likelihood field* of
Thrun, Burgard and Fox, *Probabilistic Robotics* (2005, section 6.4). The
pose filter (:class:`~fingerloc.map.pose_filter.PoseFilter`, ``scan_map=``)
weighs each particle by it; the fingerprint program still proposes the
places where particles are drawn (the start, a kidnapping).

The score of a pose is the mean over the scan's end points ``z_k`` (every
``stride``-th beam with a return) of ``log(exp(-d_k^2 / (2 sigma^2)) +
floor)``, ``d_k`` the distance from ``z_k`` (put in the mapping frame by the
pose) to the nearest mapped end point, clipped at ``clip`` metres; an end
point off the grid counts as ``clip`` away. The per-point mixture with a
constant ``floor`` keeps unmapped things (people, moved furniture, glass)
from vetoing a pose. The mean (not the sum) keeps the score's scale
independent of the scanner's beam count; the filter raises it to a
calibrated power (``scan_gamma``, chosen on the mapping part).

Units: metres and radians, mapping frame; end points in the robot frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from .._types import FArray, IArray
from ..errors import InvalidParameterError

if TYPE_CHECKING:
    from ..sensors import Scan

__all__ = [
    "SCAN_CLIP_M",
    "SCAN_FLOOR",
    "SCAN_MAX_CELLS",
    "SCAN_RESOLUTION_M",
    "SCAN_SIGMA_M",
    "SCAN_STRIDE",
    "ScanMap",
    "end_points",
    "scan_points",
]

#: Grid cell, metres.
SCAN_RESOLUTION_M = 0.1
#: Distances to the nearest mapped end point are clipped here, metres.
SCAN_CLIP_M = 1.0
#: Standard deviation of an end point around a mapped one, metres.
SCAN_SIGMA_M = 0.1
#: Constant part of each end point's likelihood (unmapped obstacles, glass, people).
SCAN_FLOOR = 0.05
#: Every ``SCAN_STRIDE``-th beam with a return is scored (neighbouring beams repeat each other).
SCAN_STRIDE = 3
#: Largest grid: beyond it the cell grows (a 400 m square at 0.1 m is 16 million cells, 64 MB).
SCAN_MAX_CELLS = 16_000_000


def scan_points(
    ranges: Any,
    bearings: Any,
    *,
    stride: int = SCAN_STRIDE,
    max_range: float | None = None,
    sensor_offset: Any = None,
) -> FArray:
    """The end points of one scan in the robot frame, shape (m, 2), metres.

    Parameters
    ----------
    ranges : array_like, shape (n,)
        Metres; ``inf``, NaN, zero or negative (no return) are dropped.
    bearings : array_like, shape (n,)
        Radians, in the sensor's frame (the robot's when ``sensor_offset`` is
        ``None``), counter-clockwise.
    stride : int, default SCAN_STRIDE
        Keep every ``stride``-th of the beams with a return.
    max_range : float, optional
        Ranges at or beyond it are dropped (a sensor's "no return" value).
    sensor_offset : (x, y, theta), optional
        The sensor's pose in the robot frame (metres, radians).
    """
    r = np.asarray(ranges, dtype=np.float64).reshape(-1)
    b = np.asarray(bearings, dtype=np.float64).reshape(-1)
    if r.size != b.size:
        raise InvalidParameterError(f"ranges and bearings must have the same length, got {r.size} and {b.size}")
    if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) or stride < 1:
        raise InvalidParameterError(f"stride must be an integer >= 1, got {stride!r}")
    ok = np.isfinite(r) & np.isfinite(b) & (r > 0)
    if max_range is not None:
        ok &= r < float(max_range)
    r, b = r[ok][::stride], b[ok][::stride]
    if sensor_offset is None:
        return np.column_stack([r * np.cos(b), r * np.sin(b)])
    ox, oy, oth = (float(v) for v in np.asarray(sensor_offset, dtype=np.float64).reshape(3))
    return np.column_stack([ox + r * np.cos(b + oth), oy + r * np.sin(b + oth)])


def end_points(scan: Scan, *, stride: int = SCAN_STRIDE) -> FArray:
    """A :class:`~fingerloc.sensors.Scan`'s end points in the robot frame (its sensor's mount applied),
    every ``stride``-th beam with a return, shape (m, 2), metres (:func:`scan_points`)."""
    return scan_points(scan.ranges, scan.bearings, stride=stride, max_range=scan.max_range,
                       sensor_offset=scan.sensor_offset)  # fmt: skip


def _to_frame(points: FArray, pose: FArray) -> FArray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.column_stack([pose[0] + c * points[:, 0] - s * points[:, 1], pose[1] + s * points[:, 0] + c * points[:, 1]])


@dataclass(frozen=True, eq=False)
class ScanMap:
    """An occupancy grid of mapped end points and its likelihood field (module docstring).

    Build it with :meth:`from_scans` (end points and poses of a run) or
    :meth:`from_points`; what is saved is ``origin``, ``resolution``,
    ``shape`` and ``cells``.

    Attributes
    ----------
    origin : ndarray, shape (2,)
        Mapping-frame position of the grid's corner (cell ``(0, 0)`` spans
        ``origin .. origin + resolution``), metres.
    resolution : float
        Cell side, metres.
    shape : (nx, ny)
    cells : ndarray of int, shape (k, 2)
        The occupied cells (at least one end point), unique, sorted.
    sigma, floor, clip : float
        The end-point model (metres, -, metres).
    """

    origin: FArray
    resolution: float
    shape: tuple[int, int]
    cells: IArray
    sigma: float = SCAN_SIGMA_M
    floor: float = SCAN_FLOOR
    clip: float = SCAN_CLIP_M
    _cache: dict[str, Any] = field(default_factory=dict, repr=False, init=False)

    def __post_init__(self) -> None:
        o = np.asarray(self.origin, dtype=np.float64).reshape(-1)
        if o.size != 2 or not np.all(np.isfinite(o)):
            raise InvalidParameterError(f"origin must be 2 finite numbers (metres), got {self.origin!r}")
        object.__setattr__(self, "origin", o)
        for name in ("resolution", "sigma", "clip"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise InvalidParameterError(f"{name} must be a finite number > 0 (metres), got {v!r}")
        if not isinstance(self.floor, (int, float)) or not 0 < self.floor < 1:
            raise InvalidParameterError(f"floor must be in (0, 1), got {self.floor!r}")
        nx, ny = (int(v) for v in self.shape)
        if nx < 1 or ny < 1:
            raise InvalidParameterError(f"shape must be two integers >= 1, got {self.shape!r}")
        object.__setattr__(self, "shape", (nx, ny))
        c = np.asarray(self.cells, dtype=np.int64).reshape(-1, 2)
        if c.size and (c.min() < 0 or c[:, 0].max() >= nx or c[:, 1].max() >= ny):
            raise InvalidParameterError(f"cells must lie in the grid of shape {self.shape}")
        if not c.size:
            c = np.zeros((0, 2), dtype=np.int64)
        elif nx * ny < 2**62:  # unique flat indices: the rows of np.unique(c, axis=0), in its order, 5 times faster
            key = np.unique(c[:, 0] * ny + c[:, 1])
            c = np.column_stack([key // ny, key % ny])
        else:
            c = np.unique(c, axis=0)
        c.setflags(write=False)
        object.__setattr__(self, "cells", c)

    @classmethod
    def from_points(
        cls, points: Any, *, resolution: float = SCAN_RESOLUTION_M, margin: float | None = None, **model: float
    ) -> ScanMap:
        """The grid of end points ``points`` (shape (n, 2), mapping frame, metres).

        ``margin`` (metres, default ``clip + 1``) of free grid around them; the
        cell grows beyond ``resolution`` when the grid would exceed
        :data:`SCAN_MAX_CELLS`. ``model``: ``sigma``, ``floor``, ``clip``.
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if p.shape[0] == 0:
            raise InvalidParameterError("a scan map needs at least one end point")
        if not np.all(np.isfinite(p)):
            raise InvalidParameterError("end points must be finite")
        res = float(resolution)
        if not math.isfinite(res) or res <= 0:
            raise InvalidParameterError(f"resolution must be a finite number > 0 (metres), got {resolution!r}")
        clip = float(model.get("clip", SCAN_CLIP_M))
        pad = clip + 1.0 if margin is None else float(margin)
        lo, hi = p.min(axis=0) - pad, p.max(axis=0) + pad
        while math.prod(math.ceil(float(v) / res) for v in hi - lo) > SCAN_MAX_CELLS:
            res *= 1.25
        shape = tuple(math.ceil(float(v) / res) for v in hi - lo)
        cells = np.clip(np.floor((p - lo) / res).astype(np.int64), 0, np.array(shape) - 1)
        return cls(lo, res, (shape[0], shape[1]), cells, **model)

    @classmethod
    def from_scans(cls, points: Any, poses: Any, **options: Any) -> ScanMap:
        """The grid of a run's end points: ``points[i]`` (robot frame, :func:`scan_points`) seen at ``poses[i]``.

        ``poses``: shape (n, 3), mapping frame (metres, radians); a scan with
        no end point is skipped. ``options``: :meth:`from_points`'s.
        """
        ps = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        pts = list(points)
        if len(pts) != ps.shape[0]:
            raise InvalidParameterError(f"one pose per scan is needed, got {ps.shape[0]} for {len(pts)} scans")
        if not np.all(np.isfinite(ps)):
            raise InvalidParameterError("poses must be finite")
        qs = [np.asarray(q, dtype=np.float64).reshape(-1, 2) for q in pts]
        n = np.array([q.shape[0] for q in qs], dtype=np.int64)
        if not n.sum():
            raise InvalidParameterError("a scan map needs at least one end point")
        # every scan at once, each point through the same operations as _to_frame (math.cos, then the same order)
        q = np.vstack(qs)
        c = np.repeat([math.cos(t) for t in ps[:, 2].tolist()], n)
        s = np.repeat([math.sin(t) for t in ps[:, 2].tolist()], n)
        x, y = np.repeat(ps[:, 0], n), np.repeat(ps[:, 1], n)
        world = np.column_stack([x + c * q[:, 0] - s * q[:, 1], y + s * q[:, 0] + c * q[:, 1]])
        return cls.from_points(world, **options)

    def table(self) -> FArray:
        """Each cell's end-point log-likelihood ``log(exp(-d^2 / 2 sigma^2) + floor)``, shape ``shape`` (float32)."""
        t = self._cache.get("table")
        if t is None:
            from scipy import ndimage

            free = np.ones(self.shape, dtype=bool)
            if self.cells.size:
                free[self.cells[:, 0], self.cells[:, 1]] = False
                d = np.minimum(ndimage.distance_transform_edt(free) * self.resolution, self.clip)
            else:
                d = np.full(self.shape, self.clip)
            t = np.log(np.exp(-0.5 * (d / self.sigma) ** 2) + self.floor)
            t = self._cache.setdefault("table", np.ascontiguousarray(t, dtype=np.float32))
        return t  # type: ignore[no-any-return]

    @property
    def outside(self) -> float:
        """The log-likelihood of an end point off the grid (``clip`` away from every mapped one)."""
        return math.log(math.exp(-0.5 * (self.clip / self.sigma) ** 2) + self.floor)

    def log_likelihood(self, poses: Any, points: Any) -> FArray:
        """Mean end-point log-likelihood of a scan seen from each of ``poses``, shape (N,).

        ``poses``: shape (N, 3), mapping frame; ``points``: the scan's end
        points in the robot frame, shape (m, 2) (:func:`scan_points`). A scan
        with no end point scores 0 everywhere (no evidence).
        """
        p = np.ascontiguousarray(np.asarray(poses, dtype=np.float64).reshape(-1, 3))
        q = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
        if q.shape[0] == 0 or p.shape[0] == 0:
            return np.zeros(p.shape[0])
        if not np.all(np.isfinite(q)):
            raise InvalidParameterError("end points must be finite")
        from ._scan_kernels import field_mean

        table, ox, oy, inv_res, outside = self._field()
        out = np.empty(p.shape[0])
        c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
        field_mean(p, c, s, q, table, ox, oy, inv_res, outside, out)
        return out

    def _field(self) -> tuple[FArray, float, float, float, float]:
        """The kernel's view of the field: ``(table, origin x, origin y, 1 / resolution, outside)``, made once."""
        f = self._cache.get("field")
        if f is None:
            o, inv_res = self.origin, 1.0 / self.resolution
            f = self._cache.setdefault("field", (self.table(), float(o[0]), float(o[1]), inv_res, self.outside))
        return f  # type: ignore[no-any-return]
