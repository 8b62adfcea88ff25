"""The pose filter's per-step array work, compiled (private).

Each kernel does, in one loop, what a short sequence of NumPy operations of
:class:`fingerloc.map.pose_filter.PoseFilter` did, with the same floating
point operations in the same order, so the results are the same bits:

* no transcendental function is evaluated here: NumPy's ``exp``, ``log``,
  ``cos`` and ``sin`` (SIMD, SVML on AVX-512 machines) and a compiled loop's
  libm ones may differ in the last bit, so the filter still calls NumPy for
  them and passes the results in;
* the random numbers are drawn by the filter's NumPy generator, in the same
  calls and order as before, and passed in;
* the sums kept here are those NumPy computes sequentially (``bincount``'s
  weighted counts, ``cumsum``); pairwise sums (``logsumexp``) stay in NumPy;
* ``np.mod`` is ``fmod`` (exact) with NumPy's sign correction
  (``npy_divmod``), as :func:`fingerloc.angles.wrap` uses it.

``tests/test_pose_filter_speed.py`` runs the former NumPy filter (kept there)
and this one side by side and compares every array bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._types import FArray, IArray

__all__ = ["bincount_weights", "gather_rows", "move_particles", "observation_weights_at", "systematic_indices"]

_PI = math.pi
_TWO_PI = 2.0 * np.pi  # fingerloc.angles.TWO_PI


@njit(cache=True, nogil=True)
def move_particles(  # pragma: no cover - compiled
    p: FArray, z1: FArray, z2: FArray, z3: FArray, z4: FArray, z5: FArray, c: FArray, s: FArray,
    dx: float, dy: float, dth: float, tr: float, st: float, sr: float,
    out: FArray,
) -> None:  # fmt: skip
    """``PoseFilter.predict``'s motion: ``out`` the moved particles."""
    for i in range(p.shape[0]):
        ex = dx * (1.0 + tr * z1[i]) + st * z2[i]
        ey = dy * (1.0 + tr * z3[i]) + st * z4[i]
        x = p[i, 0] + (c[i] * ex - s[i] * ey)
        y = p[i, 1] + (s[i] * ex + c[i] * ey)
        a = p[i, 2] + dth + sr * z5[i]
        # wrap(a): np.mod(a + pi, 2 pi) - pi, folded below pi
        m = np.fmod(a + _PI, _TWO_PI)
        if m != 0.0:
            if m < 0.0:
                m += _TWO_PI
        else:
            m = 0.0
        t = m - _PI
        if t >= _PI:
            t = t - _TWO_PI
        out[i, 0] = x
        out[i, 1] = y
        out[i, 2] = t


@njit(cache=True, nogil=True)
def bincount_weights(near: IArray, w: FArray, n_bins: int) -> FArray:  # pragma: no cover - compiled
    """``np.bincount(near, weights=w, minlength=n_bins)`` (same sequential sums; ``near`` in range)."""
    out = np.zeros(n_bins)
    for i in range(near.shape[0]):
        out[near[i]] += w[i]
    return out


@njit(cache=True, nogil=True)
def observation_weights_at(  # pragma: no cover - compiled
    d: FArray, near: IArray, lp: FArray, radius: float, floor: float, log_w: FArray, out: FArray
) -> bool:
    """``out = log_w + np.where(d <= radius, lp[near], floor)``; True when some entry is finite."""
    finite = False
    for i in range(d.shape[0]):
        v = log_w[i] + (lp[near[i]] if d[i] <= radius else floor)
        out[i] = v
        if not finite and math.isfinite(v):
            finite = True
    return finite


@njit(cache=True, nogil=True)
def systematic_indices(p: FArray, u0: float, n: int) -> IArray:  # pragma: no cover - compiled
    """Systematic resampling's picks: ``searchsorted(cumsum(p) with its last entry 1, (u0 + arange(n)) / n)``, clipped.

    The cumulative sum is NumPy's (sequential); the search is a merge (the
    points are increasing and the sums non-decreasing, so the first sum
    ``>= u`` is the binary search's answer).
    """
    m = p.shape[0]
    cum = np.empty(m)
    acc = 0.0
    for i in range(m):
        acc += p[i]
        cum[i] = acc
    cum[m - 1] = 1.0
    idx = np.empty(n, dtype=np.int64)
    k = 0
    for i in range(n):
        u = (u0 + float(i)) / float(n)
        while k < m and cum[k] < u:
            k += 1
        idx[i] = k if k < m - 1 else m - 1
    return idx


@njit(cache=True, nogil=True)
def gather_rows(a: FArray, idx: IArray) -> FArray:  # pragma: no cover - compiled
    """``a[idx]`` (a new C-contiguous array)."""
    out = np.empty((idx.shape[0], a.shape[1]))
    for i in range(idx.shape[0]):
        for k in range(a.shape[1]):
            out[i, k] = a[idx[i], k]
    return out
