"""Nearest place centre of many points, compiled (private; the pose filter's hot loop).

:func:`nearest_centres` gives what ``scipy.spatial.cKDTree(centres).query(points)``
gives (the distance to the nearest centre, bit for bit: ``sqrt(dx * dx + dy * dy)``,
and its index) for the pose filter's sizes (thousands of particles, tens to
a few hundred places) in a brute-force loop, 5-9x faster than the tree's
query there. A point exactly as far from two centres (never seen with
particles drawn from continuous noise) gets the lower index; the tree may
give the other. ``tests/test_pose_filter_speed.py`` compares the two.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._types import FArray, IArray

__all__ = ["nearest_centres"]


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
