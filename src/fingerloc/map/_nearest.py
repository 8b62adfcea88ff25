"""Nearest place centre of many points, compiled (private; the pose filter's hot loop).

:func:`nearest_centres` gives what ``scipy.spatial.cKDTree(centres).query(points)``
gives (the distance to the nearest centre, bit for bit: ``sqrt(dx * dx + dy * dy)``,
and its index) for the pose filter's sizes (thousands of particles, tens to
a few hundred places) in a brute-force loop, 5-9x faster than the tree's
query there. A point exactly as far from two centres (never seen with
particles drawn from continuous noise) gets the lower index; the tree may
give the other. ``tests/test_pose_filter_speed.py`` compares the two.
:class:`CentreGrid` gives the same answer for many places (hundreds to
thousands), looking only at a grid cell's candidate centres.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from .._types import FArray, IArray

__all__ = ["CentreGrid", "nearest_centres"]


@njit(cache=True, nogil=True)
def _nearest_kernel(x: FArray, y: FArray, c: FArray, d: FArray, j: IArray) -> None:  # pragma: no cover - compiled
    # centres outside, points inside: the inner loop runs over contiguous arrays (SIMD lanes)
    n = x.shape[0]
    for i in range(n):
        d[i] = np.inf
        j[i] = 0
    for k in range(c.shape[0]):
        cx = c[k, 0]
        cy = c[k, 1]
        for i in range(n):
            dx = x[i] - cx
            dy = y[i] - cy
            s = dx * dx + dy * dy
            better = s < d[i]  # strictly: ties keep the lower index
            d[i] = s if better else d[i]
            j[i] = k if better else j[i]
    for i in range(n):
        d[i] = math.sqrt(d[i])


def nearest_centres(points: FArray, centres: FArray) -> tuple[FArray, IArray]:
    """Distance to and index of the nearest of ``centres`` (shape (P, 2)) for each of ``points`` (shape (n, 2))."""
    xy = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    c = np.ascontiguousarray(centres, dtype=np.float64)
    d = np.empty(xy.shape[0], dtype=np.float64)
    j = np.zeros(xy.shape[0], dtype=np.int64)
    if c.shape[0]:
        _nearest_kernel(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]), c, d, j)
    else:
        d.fill(np.inf)
    return d, j


#: Cells per place of :class:`CentreGrid` (a few candidates per cell where places are dense).
GRID_CELLS_PER_PLACE = 4
#: At most this many cells in a :class:`CentreGrid`.
GRID_MAX_CELLS = 1 << 20


@njit(cache=True, nogil=True)
def _grid_candidates(c: FArray, x0: float, y0: float, side: float, nx: int, ny: int) -> tuple[IArray, IArray]:  # pragma: no cover - compiled
    # per cell: every centre whose least distance to the cell is at most the least farthest distance to it
    n_cells = nx * ny
    start = np.zeros(n_cells + 1, dtype=np.int64)
    bound = np.empty(n_cells)
    for ix in range(nx):
        ax = x0 + ix * side
        bx = ax + side
        for iy in range(ny):
            ay = y0 + iy * side
            by = ay + side
            u = np.inf
            for k in range(c.shape[0]):
                fx = max(abs(c[k, 0] - ax), abs(c[k, 0] - bx))
                fy = max(abs(c[k, 1] - ay), abs(c[k, 1] - by))
                u = min(u, fx * fx + fy * fy)
            u = u * (1.0 + 1e-9) + 1e-12  # rounding slack: more candidates never change the answer
            bound[ix * ny + iy] = u
            m = 0
            for k in range(c.shape[0]):
                gx = max(ax - c[k, 0], 0.0, c[k, 0] - bx)
                gy = max(ay - c[k, 1], 0.0, c[k, 1] - by)
                if gx * gx + gy * gy <= u:
                    m += 1
            start[ix * ny + iy + 1] = m
    for i in range(n_cells):
        start[i + 1] += start[i]
    cand = np.empty(start[n_cells], dtype=np.int64)
    for ix in range(nx):
        ax = x0 + ix * side
        bx = ax + side
        for iy in range(ny):
            ay = y0 + iy * side
            by = ay + side
            u = bound[ix * ny + iy]
            m = start[ix * ny + iy]
            for k in range(c.shape[0]):  # ascending: ties keep the lower index, as the brute force
                gx = max(ax - c[k, 0], 0.0, c[k, 0] - bx)
                gy = max(ay - c[k, 1], 0.0, c[k, 1] - by)
                if gx * gx + gy * gy <= u:
                    cand[m] = k
                    m += 1
    return start, cand


@njit(cache=True, nogil=True)
def _grid_nearest_kernel(
    xy: FArray, c: FArray, x0: float, y0: float, side: float, nx: int, ny: int,
    start: IArray, cand: IArray, d: FArray, j: IArray,
) -> None:  # pragma: no cover - compiled
    for i in range(xy.shape[0]):
        x = xy[i, 0]
        y = xy[i, 1]
        fx = (x - x0) / side
        fy = (y - y0) / side
        best = np.inf
        at = 0
        if 0.0 <= fx < nx and 0.0 <= fy < ny:
            cell = int(fx) * ny + int(fy)
            for m in range(start[cell], start[cell + 1]):
                k = cand[m]
                dx = x - c[k, 0]
                dy = y - c[k, 1]
                s = dx * dx + dy * dy
                if s < best:  # candidates ascend: ties keep the lower index
                    best = s
                    at = k
        else:  # off the grid: every centre
            for k in range(c.shape[0]):
                dx = x - c[k, 0]
                dy = y - c[k, 1]
                s = dx * dx + dy * dy
                if s < best:
                    best = s
                    at = k
        d[i] = math.sqrt(best)
        j[i] = at


class CentreGrid:
    """:func:`nearest_centres` for many places: each point looks only at its grid cell's candidate centres.

    A square grid over the centres' bounding box (about
    :data:`GRID_CELLS_PER_PLACE` cells per place, at most
    :data:`GRID_MAX_CELLS`) lists, per cell, every centre that can be the
    nearest to a point of the cell (its least distance to the cell is at most
    the least farthest distance of any centre to the cell). A point off the
    grid looks at every centre. The answer is :func:`nearest_centres`' bit for bit
    (the same ``sqrt(dx * dx + dy * dy)``, ties to the lower index).

    Parameters
    ----------
    centres : array_like, shape (P, 2)
        Place centres, metres (P >= 1).
    """

    def __init__(self, centres: Any) -> None:
        c = np.ascontiguousarray(centres, dtype=np.float64).reshape(-1, 2)
        if c.shape[0] == 0 or not np.all(np.isfinite(c)):
            raise ValueError("CentreGrid needs at least one centre, all finite")
        self.centres = c
        lo, hi = c.min(axis=0), c.max(axis=0)
        extent = np.maximum(hi - lo, 1e-6)
        n_cells = min(GRID_CELLS_PER_PLACE * c.shape[0], GRID_MAX_CELLS)
        side = float(math.sqrt(extent[0] * extent[1] / n_cells)) if extent.min() > 1e-6 else float(extent.max() / n_cells)
        side = max(side, float(extent.max()) / math.sqrt(GRID_MAX_CELLS), 1e-6)
        self.origin = (float(lo[0]), float(lo[1]))
        self.side = side
        self.shape = (int(extent[0] // side) + 1, int(extent[1] // side) + 1)
        self.start, self.cand = _grid_candidates(c, self.origin[0], self.origin[1], side, *self.shape)
        self._members: tuple[IArray, IArray] | None = None

    def nearest(self, points: Any) -> tuple[FArray, IArray]:
        """Distance to and index of the nearest centre for each of ``points`` (shape (n, 2)); shapes (n,), (n,)."""
        xy = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
        d = np.empty(xy.shape[0], dtype=np.float64)
        j = np.zeros(xy.shape[0], dtype=np.int64)
        _grid_nearest_kernel(xy, self.centres, self.origin[0], self.origin[1], self.side, *self.shape,
                             self.start, self.cand, d, j)  # fmt: skip
        return d, j

    def mass_within(self, points: Any, weights: Any, reach: float) -> FArray:
        """Each centre's sum of the ``weights`` (shape (n,)) of ``points`` (shape (n, 2)) within ``reach`` metres, shape (P,).

        A centre is within reach of a point when ``dx * dx + dy * dy <= reach * reach``
        (what ``scipy.spatial.cKDTree.query_ball_point`` counts, but for a
        point exactly on the circle's edge). Whole-number weights give exact sums.
        """
        xy = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
        w = np.ascontiguousarray(np.asarray(weights, dtype=np.float64).reshape(-1))
        if w.shape[0] != xy.shape[0]:
            raise ValueError(f"{w.shape[0]} weights for {xy.shape[0]} points")
        if self._members is None:
            self._members = _grid_members(self.centres, self.origin[0], self.origin[1], self.side, *self.shape)
        out = np.zeros(self.centres.shape[0])
        if xy.shape[0] and math.isfinite(reach) and reach >= 0:
            start, members = self._members
            _mass_within_kernel(xy, w, float(reach), self.centres, self.origin[0], self.origin[1], self.side,
                                *self.shape, start, members, out)  # fmt: skip
        return out


@njit(cache=True, nogil=True)
def _grid_members(c: FArray, x0: float, y0: float, side: float, nx: int, ny: int) -> tuple[IArray, IArray]:  # pragma: no cover - compiled
    # the centres lying in each cell (CSR, ascending index)
    n_cells = nx * ny
    cell = np.empty(c.shape[0], dtype=np.int64)
    start = np.zeros(n_cells + 1, dtype=np.int64)
    for k in range(c.shape[0]):
        ix = min(max(int((c[k, 0] - x0) / side), 0), nx - 1)
        iy = min(max(int((c[k, 1] - y0) / side), 0), ny - 1)
        cell[k] = ix * ny + iy
        start[cell[k] + 1] += 1
    for i in range(n_cells):
        start[i + 1] += start[i]
    fill = start[:-1].copy()
    members = np.empty(c.shape[0], dtype=np.int64)
    for k in range(c.shape[0]):
        members[fill[cell[k]]] = k
        fill[cell[k]] += 1
    return start, members


@njit(cache=True, nogil=True)
def _mass_within_kernel(
    xy: FArray, weights: FArray, reach: float, c: FArray, x0: float, y0: float, side: float, nx: int, ny: int,
    start: IArray, members: IArray, out: FArray,
) -> None:  # pragma: no cover - compiled
    r2 = reach * reach
    for i in range(xy.shape[0]):
        x = xy[i, 0]
        y = xy[i, 1]
        if not (math.isfinite(x) and math.isfinite(y)):
            continue
        # one cell more on each side: a centre on the edge of the reach, in the cell beyond by rounding
        ax = max(math.floor((x - reach - x0) / side) - 1, 0)
        bx = min(math.floor((x + reach - x0) / side) + 1, nx - 1)
        ay = max(math.floor((y - reach - y0) / side) - 1, 0)
        by = min(math.floor((y + reach - y0) / side) + 1, ny - 1)
        for ix in range(ax, bx + 1):
            for iy in range(ay, by + 1):
                cell = ix * ny + iy
                for m in range(start[cell], start[cell + 1]):
                    k = members[m]
                    dx = x - c[k, 0]
                    dy = y - c[k, 1]
                    if dx * dx + dy * dy <= r2:
                        out[k] += weights[i]
