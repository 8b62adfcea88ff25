"""The laser feature extractor's iterative-end-point split, compiled (private; :mod:`fingerloc.features.laser`).

:func:`split_pieces` is the recursive iterative-end-point split of a scan
segment into line pieces, run with an explicit stack (pieces in the order
of the recursion). It replaced a NumPy recursion whose point-to-chord
distance was ``|(seg - a) @ normal|``; the product here,
``|dx * n_x + dy * n_y|``, may differ from NumPy's in the last bit, which
changes a split only where a point lies within that bit of its tolerance
(``tests/test_laser_split.py`` compares the two; the features of every scan of
the four CARMEN logs of the benchmarks came out the same).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._types import FArray, IArray

__all__ = ["split_pieces"]


@njit(cache=True, nogil=True)
def split_pieces(pts: FArray, tol: FArray) -> IArray:  # pragma: no cover - compiled
    """Pieces ``(lo, hi)`` of the split of ``pts`` (shape (n, 2)) with per-point tolerances ``tol`` (shape (n,), > 0).

    A piece of at least 3 points whose point farthest from its chord,
    relative to that point's tolerance, lies beyond its tolerance (and is not
    an end point) splits there: the point ends the left piece and starts the
    right one. Returns shape (k, 2), in order along the points.
    """
    n = pts.shape[0]
    out = np.empty((max(2 * n, 2), 2), dtype=np.int64)
    n_out = 0
    stack = np.empty((max(2 * n, 2), 2), dtype=np.int64)
    stack[0, 0] = 0
    stack[0, 1] = n
    top = 1  # pieces still to look at, the next on top
    while top > 0:
        top -= 1
        lo = stack[top, 0]
        hi = stack[top, 1]
        if hi - lo < 3:
            out[n_out, 0] = lo
            out[n_out, 1] = hi
            n_out += 1
            continue
        ax = pts[lo, 0]
        ay = pts[lo, 1]
        cx = pts[hi - 1, 0] - ax
        cy = pts[hi - 1, 1] - ay
        length = np.hypot(cx, cy)
        nx = ny = 0.0
        if length >= 1e-9:
            nx = -cy / length
            ny = cx / length
        best = -1.0
        k = 0
        for i in range(lo, hi):
            dx = pts[i, 0] - ax
            dy = pts[i, 1] - ay
            if length < 1e-9:
                d = math.sqrt(dx * dx + dy * dy)
            else:
                d = abs(dx * nx + dy * ny)
            r = d / tol[i]
            if r > best:  # the first largest (np.argmax)
                best = r
                k = i
        dx = pts[k, 0] - ax
        dy = pts[k, 1] - ay
        d = math.sqrt(dx * dx + dy * dy) if length < 1e-9 else abs(dx * nx + dy * ny)
        if d - tol[k] > 0 and lo < k < hi - 1:
            stack[top, 0] = k  # the right piece, split after the left one
            stack[top, 1] = hi
            stack[top + 1, 0] = lo  # the split point ends the left piece...
            stack[top + 1, 1] = k + 1  # ...and starts the right one
            top += 2
        else:
            out[n_out, 0] = lo
            out[n_out, 1] = hi
            n_out += 1
    return out[:n_out]
