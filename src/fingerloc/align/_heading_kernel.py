"""The heading of a cyclic alignment in one compiled call (private).

:func:`fingerloc.align.cyclic_alignment` returns the optimal alignment as a
list of pairs, then averages the bearing offsets of its pairs in Python.
Where only the cost and the heading are wanted (a heading at every place
for every view: :meth:`fingerloc.terms.FingerprintTerm.heading_at`), this
kernel does the same steps without building the lists: the costs of every
rotation, for each tied rotation the DP table and the traceback (same tie
order: a pairing, then a deletion, then an insertion), the pairs' tiers
(equal letters other than ``n``, then equal letters, then every pair), the
circular mean of the first non-empty tier and its agreement
``3 - tier + R``. Sums follow numpy's order (its pairwise summation), so the heading equals
:func:`~fingerloc.align.cyclic_alignment`'s to the last bit or to rounding
(tests/test_align_heading.py compares them).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from ._cyclic import cyclic_all_rotations
from ._kernels import nw_matrix

__all__ = ["cyclic_cost_heading", "numpy_sum"]


@njit(cache=True)
def _block(x: NDArray[np.float64], lo: int, n: int) -> float:  # pragma: no cover - compiled
    """numpy's pairwise summation of a block of at most 128: eight partial sums, then the rest in order."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += x[lo + i]
        return res
    r0, r1, r2, r3 = x[lo], x[lo + 1], x[lo + 2], x[lo + 3]
    r4, r5, r6, r7 = x[lo + 4], x[lo + 5], x[lo + 6], x[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += x[lo + i]
        r1 += x[lo + i + 1]
        r2 += x[lo + i + 2]
        r3 += x[lo + i + 3]
        r4 += x[lo + i + 4]
        r5 += x[lo + i + 5]
        r6 += x[lo + i + 6]
        r7 += x[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += x[lo + i]
        i += 1
    return res


@njit(cache=True)
def _pairwise(x: NDArray[np.float64], lo: int, n: int) -> float:  # pragma: no cover - compiled
    """numpy's pairwise summation of ``x[lo:lo + n]``: above 128, the sum of the two halves (the first
    half rounded down to a multiple of 8), each summed the same way. Without recursion (a recursive
    compiled function does not load from numba's cache safely): the halves' tree is walked with a stack."""
    if n <= 128:
        return _block(x, lo, n)
    # post-order walk: a node's value is the sum of its two children's, left + right
    stack_lo = np.empty(128, dtype=np.int64)
    stack_n = np.empty(128, dtype=np.int64)
    stack_state = np.empty(128, dtype=np.int64)  # 0: children not done, 1: left done
    vals = np.empty(128)
    top = 0
    stack_lo[0], stack_n[0], stack_state[0] = lo, n, 0
    result = 0.0
    while top >= 0:
        cl, cn, st = stack_lo[top], stack_n[top], stack_state[top]
        n2 = cn // 2
        n2 -= n2 % 8
        if st == 0:
            stack_state[top] = 1
            if n2 <= 128:
                vals[top] = _block(x, cl, n2)
            else:
                top += 1
                stack_lo[top], stack_n[top], stack_state[top] = cl, n2, 0
            continue
        if st == 1:
            stack_state[top] = 2
            if cn - n2 <= 128:
                v = vals[top] + _block(x, cl + n2, cn - n2)
            else:
                top += 1
                stack_lo[top], stack_n[top], stack_state[top] = cl + n2, cn - n2, 0
                continue
        else:  # st == 2: the right child's value is in vals[top + 1]
            v = vals[top] + vals[top + 1]
        # node done with value v: give it to the parent
        top -= 1
        if top < 0:
            result = v
        elif stack_state[top] == 1:
            vals[top] = v
        else:
            vals[top + 1] = v
    return result


@njit(cache=True)
def numpy_sum(x: NDArray[np.float64], n: int) -> float:  # pragma: no cover - compiled
    """``x[:n].sum()`` as numpy computes it for a contiguous float64 array (0.0 when empty)."""
    return _pairwise(x, 0, n)


@njit(cache=True)
def cyclic_cost_heading(
    ca: NDArray[np.uint8],
    cb: NDArray[np.uint8],
    bear_a: NDArray[np.float64],
    bear_b: NDArray[np.float64],
    sub: NDArray[np.float64],
    indel: NDArray[np.float64],
    n_code: int,
) -> tuple[float, int, float]:  # pragma: no cover - compiled
    """Cyclic cost of ``a`` against ``b``, the chosen rotation, and the heading in radians (NaN: nothing paired).

    The heading is the circular mean of ``bear_a[i] - bear_b[j]`` over the
    chosen tier of the optimal alignment's pairs, in ``(-pi, pi]`` as
    ``atan2`` gives it (the caller turns it into degrees in ``[0, 360)``).
    ``n_code``: the letter code of ``n`` (its pairs rank below other equal
    letters). Both strings must have bearings; ``b`` must not be empty.
    """
    per_rot = cyclic_all_rotations(ca, cb, sub, indel)
    cost = per_rot.min()
    n, m = ca.shape[0], cb.shape[0]
    cap = n + m
    pi = np.empty(cap, dtype=np.int64)
    pj = np.empty(cap, dtype=np.int64)
    sn_buf = np.empty(cap)
    cs_buf = np.empty(cap)
    cbr = np.empty(m, dtype=np.uint8)
    have = False
    best_score = -1.0
    best_rot = 0
    best_heading = np.nan
    for rot in range(per_rot.shape[0]):
        if per_rot[rot] != cost:
            continue
        for k in range(m):
            cbr[k] = cb[(k + rot) % m]
        d = nw_matrix(ca, cbr, sub, indel)
        # traceback from the end; pairs collected backwards, then read forwards
        i, j, npairs = n, m, 0
        while i > 0 or j > 0:
            if i > 0 and j > 0 and d[i, j] == d[i - 1, j - 1] + sub[ca[i - 1], cbr[j - 1]]:
                pi[npairs] = i - 1
                pj[npairs] = (j - 1 + rot) % m
                npairs += 1
                i -= 1
                j -= 1
            elif i > 0 and d[i, j] == d[i - 1, j] + indel[ca[i - 1]]:
                i -= 1
            else:
                j -= 1
        heading = np.nan
        score = -1.0
        for tier in range(3):
            cnt = 0
            for q in range(npairs - 1, -1, -1):  # forwards
                a_code, b_code = ca[pi[q]], cb[pj[q]]
                if tier == 0:
                    keep = a_code == b_code and a_code != n_code
                elif tier == 1:
                    keep = a_code == b_code
                else:
                    keep = True
                if keep:
                    diff = bear_a[pi[q]] - bear_b[pj[q]]
                    sn_buf[cnt] = math.sin(diff)
                    cs_buf[cnt] = math.cos(diff)
                    cnt += 1
            if cnt > 0:
                sn = numpy_sum(sn_buf, cnt)
                cs = numpy_sum(cs_buf, cnt)
                heading = math.atan2(sn, cs)
                score = 3.0 - tier + math.hypot(sn, cs) / cnt
                break
        if not have or score > best_score:
            have = True
            best_score = score
            best_rot = rot
            best_heading = heading
    return float(cost), best_rot, best_heading
