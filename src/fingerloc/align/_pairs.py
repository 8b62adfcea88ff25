"""Cyclic alignment of given pairs of strings, the lanes running over the rotations.

The batch kernels (:mod:`fingerloc.align._cyclic_int`) align one query
against many references side by side, which pays when the references are
many. The views of one place (a medoid needs their pairwise costs) are a
handful: there the lanes are better spent on the rotations of one pair.

For a pair ``(a, b)`` with integer costs (:func:`~fingerloc.align._cyclic_int.integer_costs`),
lane ``r`` runs the global alignment of ``a`` rotated by ``r`` against ``b``
in the difference form of :mod:`fingerloc.align._cyclic_int` (``z = min(s'(a_i, b_j), H, U)``,
``s'(x, y) = s(x, y) - g(x) - g(y)``). Row ``i`` of lane ``r`` holds letter
``a[(i + r) mod n]``, so with the substitution profile of the doubled ``a``
against ``b`` stored column by column, ``P[j, t] = s'(aa[t], b_j)``, the
lanes of one cell read the contiguous ``P[j, i : i + n]`` and the loop over
the lanes compiles to vector instructions (16 lanes of int16 a register).
The cost of rotation ``r`` is ``sum g(a) + sum g(b) + sum_j H_r[n, j]``; the
minimum over ``r`` is the cyclic cost, exactly (integers).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["paired_cyclic_int"]


@njit(cache=True)
def _pair(
    a: NDArray[np.uint8], b: NDArray[np.uint8], sub: NDArray[np.int16], indel: NDArray[np.int16], prof: NDArray[np.int16],
    hv: NDArray[np.int16], uv: NDArray[np.int16],
) -> int:  # pragma: no cover - compiled
    n = a.shape[0]
    m = b.shape[0]
    base = 0
    for i in range(n):
        base += indel[a[i]]
    gb = 0
    for j in range(m):
        gb += indel[b[j]]
    if n == 0 or m == 0:
        return base + gb
    for j in range(m):
        bj = b[j]
        for t in range(2 * n):
            x = a[t % n]
            prof[j, t] = sub[x, bj] - indel[x] - indel[bj]
    for j in range(m):
        for r in range(n):
            hv[j, r] = 0
    for i in range(n):
        for r in range(n):
            uv[r] = 0
        for j in range(m):
            p = prof[j, i : i + n]
            h = hv[j]
            for r in range(n):
                z = min(min(p[r], h[r]), uv[r])
                hr = h[r]
                h[r] = z - uv[r]
                uv[r] = z - hr
    best = 2**30
    for r in range(n):
        s = 0
        for j in range(m):
            s += hv[j, r]
        best = min(best, s)
    return base + gb + best


@njit(cache=True)
def _pairs(
    codes: NDArray[np.uint8], off: NDArray[np.int64], left: NDArray[np.int64], right: NDArray[np.int64],
    sub: NDArray[np.int16], indel: NDArray[np.int16],
) -> NDArray[np.int64]:  # pragma: no cover - compiled
    longest = 1
    for k in range(off.shape[0] - 1):
        longest = max(longest, off[k + 1] - off[k])
    prof = np.empty((longest, 2 * longest), dtype=np.int16)
    hv = np.empty((longest, longest), dtype=np.int16)
    uv = np.empty(longest, dtype=np.int16)
    out = np.empty(left.shape[0], dtype=np.int64)
    for k in range(left.shape[0]):
        a = codes[off[left[k]] : off[left[k] + 1]]
        b = codes[off[right[k]] : off[right[k] + 1]]
        out[k] = _pair(a, b, sub, indel, prof, hv, uv)
    return out


def paired_cyclic_int(
    codes: NDArray[np.uint8],
    off: NDArray[np.int64],
    left: NDArray[np.int64],
    right: NDArray[np.int64],
    sub8: NDArray[np.int8],
    indel8: NDArray[np.int8],
) -> NDArray[np.int64]:
    """Integer cyclic costs of the pairs ``(string left[k], string right[k])``, shape ``(len(left),)``.

    ``codes``/``off`` from :func:`~fingerloc.align._encode.encode_many`; ``sub8``/``indel8``
    from :func:`~fingerloc.align._cyclic_int.integer_costs` (the costs times their ``scale``).
    """
    return _pairs(
        codes, off, np.ascontiguousarray(left, dtype=np.int64), np.ascontiguousarray(right, dtype=np.int64),
        sub8.astype(np.int16), indel8.astype(np.int16),
    )  # fmt: skip
