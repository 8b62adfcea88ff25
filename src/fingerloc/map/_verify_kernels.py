"""Compiled kernels of the scan-to-place verification (private; :mod:`fingerloc.map.scan_verify`).

* :func:`grid_fits`: the mean table value of a scan's end points at every
  pose of a grid (place centre cells plus integer cell offsets, times a set
  of headings); each end point's cell offset is rounded once per heading,
  so a pose costs one addition per point.
* :func:`refine`: a hill climb of poses on a (sharper) table, the position
  kept within a disc.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._types import FArray, IArray

__all__ = ["grid_fits", "refine"]


@njit(cache=True, nogil=True)
def grid_fits(
    qx: FArray, qy: FArray, ch: FArray, sh: FArray, ci: IArray, cj: IArray, oi: IArray, oj: IArray,
    table: FArray, inv_res: float, outside: float, out: FArray,
) -> None:  # pragma: no cover - compiled  # fmt: skip
    """``out[p, k, h]``: mean of ``table`` over the points ``(qx, qy)`` (robot frame, metres) turned by heading
    ``h`` (cosine ``ch[h]``, sine ``sh[h]``) and put at cell ``(ci[p] + oi[k], cj[p] + oj[k])``; a point off the
    table counts ``outside``. ``inv_res``: cells per metre."""
    nx, ny = table.shape
    flat = table.ravel()
    m = qx.shape[0]
    n_h = ch.shape[0]
    di = np.empty((n_h, m), dtype=np.int64)
    dj = np.empty((n_h, m), dtype=np.int64)
    for h in range(n_h):
        for i in range(m):
            di[h, i] = np.int64(math.floor((ch[h] * qx[i] - sh[h] * qy[i]) * inv_res + 0.5))
            dj[h, i] = np.int64(math.floor((sh[h] * qx[i] + ch[h] * qy[i]) * inv_res + 0.5))
    for p in range(ci.shape[0]):
        for k in range(oi.shape[0]):
            bi = ci[p] + oi[k]
            bj = cj[p] + oj[k]
            for h in range(n_h):
                s = 0.0
                for i in range(m):
                    a = bi + di[h, i]
                    b = bj + dj[h, i]
                    if a >= 0 and a < nx and b >= 0 and b < ny:
                        s += flat[a * ny + b]
                    else:
                        s += outside
                out[p, k, h] = s / m


@njit(cache=True, nogil=True, inline="always")
def _pose_fit(
    qx: FArray, qy: FArray, x: float, y: float, t: float, flat: FArray, fnx: float, fny: float, ny: int,
    ox: float, oy: float, inv_res: float, outside: float,
) -> float:  # pragma: no cover - compiled  # fmt: skip
    c = math.cos(t)
    s = math.sin(t)
    m = qx.shape[0]
    acc = 0.0
    for i in range(m):
        fx = math.floor((x + c * qx[i] - s * qy[i] - ox) * inv_res)
        fy = math.floor((y + s * qx[i] + c * qy[i] - oy) * inv_res)
        if fx >= 0.0 and fx < fnx and fy >= 0.0 and fy < fny:
            acc += flat[np.int64(fx) * ny + np.int64(fy)]
        else:
            acc += outside
    return acc / m


@njit(cache=True, nogil=True)
def refine(
    qx: FArray, qy: FArray, starts: FArray, cx: FArray, cy: FArray, limit: float, steps: FArray, turns: FArray,
    table: FArray, ox: float, oy: float, inv_res: float, outside: float, best: FArray, pose: FArray,
) -> None:  # pragma: no cover - compiled  # fmt: skip
    """Hill-climb each start pose ``starts[s]`` (x, y, theta) on ``table``: at each level (step ``steps[l]``
    metres, turn ``turns[l]`` radians) move to the best of the 26 neighbours while it improves (20 moves at
    most), the position kept within ``limit`` metres of ``(cx[s], cy[s])``. ``best[s]``: the mean table value
    of the points there (as :meth:`~fingerloc.map.scan_map.ScanMap.log_likelihood`), ``pose[s]``: the pose."""
    nx, ny = table.shape
    flat = table.ravel()
    fnx = float(nx)
    fny = float(ny)
    lim2 = limit * limit
    for s in range(starts.shape[0]):
        x = starts[s, 0]
        y = starts[s, 1]
        t = starts[s, 2]
        v = _pose_fit(qx, qy, x, y, t, flat, fnx, fny, ny, ox, oy, inv_res, outside)
        for level in range(steps.shape[0]):
            st = steps[level]
            an = turns[level]
            for _ in range(20):
                bv = v
                bx = x
                by = y
                bt = t
                for i in range(-1, 2):
                    for j in range(-1, 2):
                        xx = x + i * st
                        yy = y + j * st
                        if (xx - cx[s]) ** 2 + (yy - cy[s]) ** 2 > lim2:
                            continue
                        for k in range(-1, 2):
                            if i == 0 and j == 0 and k == 0:
                                continue
                            tt = t + k * an
                            w = _pose_fit(qx, qy, xx, yy, tt, flat, fnx, fny, ny, ox, oy, inv_res, outside)
                            if w > bv:
                                bv = w
                                bx = xx
                                by = yy
                                bt = tt
                if bv <= v:
                    break
                v = bv
                x = bx
                y = by
                t = bt
        best[s] = v
        pose[s, 0] = x
        pose[s, 1] = y
        pose[s, 2] = math.atan2(math.sin(t), math.cos(t))
