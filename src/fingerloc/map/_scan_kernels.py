"""The likelihood field's per-particle sum, compiled (private; :mod:`fingerloc.map.scan_map`)."""

from __future__ import annotations

import math

from numba import njit

from .._types import FArray

__all__ = ["field_mean"]


@njit(cache=True, nogil=True)
def field_mean(  # pragma: no cover - compiled
    poses: FArray, c: FArray, s: FArray, points: FArray, table: FArray,
    ox: float, oy: float, inv_res: float, outside: float, out: FArray,
) -> None:  # fmt: skip
    """``out[i]``: mean over ``points`` (robot frame) of ``table`` at the cell each falls in seen from ``poses[i]``.

    ``c``, ``s``: cosine and sine of the poses' headings; a point off the grid
    counts ``outside``.
    """
    nx, ny = table.shape
    m = points.shape[0]
    for i in range(poses.shape[0]):
        px = poses[i, 0]
        py = poses[i, 1]
        acc = 0.0
        for k in range(m):
            x = px + c[i] * points[k, 0] - s[i] * points[k, 1]
            y = py + s[i] * points[k, 0] + c[i] * points[k, 1]
            gx = math.floor((x - ox) * inv_res)
            gy = math.floor((y - oy) * inv_res)
            if 0 <= gx < nx and 0 <= gy < ny:
                acc += table[int(gx), int(gy)]
            else:
                acc += outside
        out[i] = acc / m
