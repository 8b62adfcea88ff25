"""Exact cyclic alignment kernels: the minimum over all rotations of one string.

The cyclic cost of ``a`` and ``b`` is ``min over r of NW(a, b[r:] + b[:r])``.
Rotating one string suffices: an optimal alignment of any rotation of ``a``
with any rotation of ``b`` is a cyclic sequence of columns, which can be cut
where ``a`` starts; the cost is therefore symmetric and invariant under
rotating either string, and the roles of ``a`` and ``b`` may be swapped.

Three kernels, all exact:

* :func:`cyclic_batch_unit` (unit costs): the bit-parallel edit distance of
  Myers (1999) in Hyyrö's global form, one 64-bit word per column, run for
  every rotation at once. Rotation ``k`` reads text column ``t`` from the
  doubled string at ``k + t``, so the words of all rotations at one step are
  contiguous in memory and the loop over rotations compiles to AVX2 vector
  instructions. The score is read from the last column's vertical deltas
  (``D[n, m] = m + popcount(VP) - popcount(VN)``), so the inner loop carries
  no score bookkeeping. A pair whose shorter string is longer than 64 letters
  falls back to the plain DP.
* :func:`fingerloc.align._kernels.nw_batch_cyclic` (any
  :class:`CostModel`): every rotation, with the vectorised 32-reference
  block kernel of the plain weighted alignment. (Lower-bound pruning, with
  free-start and free-end DP passes over the doubled string bounding each
  rotation, was tried first: on random fingerprints the bounds sit about 1.8
  below the optimum while the rotations lie within about 2 of each other, so
  half the rotations still needed the exact DP and it ran 2.7 times slower.)
* :func:`cyclic_batch_brute`: every rotation with the plain DP (the oracle of
  the tests and the baseline of the speed benchmark).

References
----------
.. [1] G. Myers, "A fast bit-vector algorithm for approximate string matching
   based on dynamic programming", J. ACM 46(3), 1999.
.. [2] H. Hyyrö, "A bit-vector algorithm for computing Levenshtein and
   Damerau edit distances", Nordic J. Computing 10, 2003.
.. [3] M. Maes, "On a cyclic string-to-string correction problem", Inf.
   Process. Lett. 35, 1990.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from ._costs import N_LETTERS
from ._kernels import nw_cost

__all__ = [
    "cyclic_all_rotations",
    "cyclic_batch_brute",
    "cyclic_batch_unit",
]

#: Longest pattern of the one-word bit-parallel kernel.
WORD = 64
# References per parallel task.
_CHUNK = 64


@njit(cache=True)
def cyclic_all_rotations(
    a: NDArray[np.uint8], b: NDArray[np.uint8], sub: NDArray[np.float64], indel: NDArray[np.float64]
) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """Cost of ``a`` against every rotation ``b[r:] + b[:r]``, shape ``(max(len(b), 1),)``."""
    m = b.shape[0]
    if m == 0:
        out = np.empty(1)
        out[0] = nw_cost(a, b, sub, indel)
        return out
    bb = np.empty(2 * m, dtype=np.uint8)
    bb[:m] = b
    bb[m:] = b
    out = np.empty(m)
    for r in range(m):
        out[r] = nw_cost(a, bb[r : r + m], sub, indel)
    return out


@njit(parallel=True, cache=True)
def cyclic_batch_brute(
    qcodes: NDArray[np.uint8],
    qoff: NDArray[np.int64],
    rcodes: NDArray[np.uint8],
    roff: NDArray[np.int64],
    sub: NDArray[np.float64],
    indel: NDArray[np.float64],
) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """Cyclic costs by trying every rotation with the plain DP, shape ``(n_queries, n_references)``."""
    nq = qoff.shape[0] - 1
    nr = roff.shape[0] - 1
    out = np.empty((nq, nr))
    for r in prange(nr):
        b = rcodes[roff[r] : roff[r + 1]]
        for q in range(nq):
            out[q, r] = cyclic_all_rotations(qcodes[qoff[q] : qoff[q + 1]], b, sub, indel).min()
    return out


# -- unit costs: bit-parallel -------------------------------------------------------


@njit(cache=True, inline="always")
def _popcount(x: np.uint64) -> int:  # pragma: no cover - compiled
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@njit(cache=True)
def _myers_all_rotations(
    p: NDArray[np.uint8],
    t: NDArray[np.uint8],
    peq: NDArray[np.uint64],
    pb: NDArray[np.uint64],
    vps: NDArray[np.uint64],
    vns: NDArray[np.uint64],
) -> int:  # pragma: no cover - compiled
    """Minimal Levenshtein distance of ``p`` (1..64 letters) against every rotation of ``t`` (>= 1 letter).

    ``peq`` (N_LETTERS,), ``pb`` (>= 2 len(t)), ``vps`` and ``vns`` (>= len(t)) are work buffers.
    """
    n = p.shape[0]
    m = t.shape[0]
    one = np.uint64(1)
    zero = np.uint64(0)
    peq[:] = zero
    for i in range(n):
        peq[p[i]] |= one << np.uint64(i)
    # Match masks of the doubled text: rotation k reads column j at pb[k + j].
    for j in range(m):
        w = peq[t[j]]
        pb[j] = w
        pb[j + m] = w
    mask = ~zero if n == WORD else (one << np.uint64(n)) - one
    for k in range(m):
        vps[k] = mask
        vns[k] = zero
    for j in range(m):
        for k in range(m):  # vectorised over rotations
            vp = vps[k]
            vn = vns[k]
            x = pb[k + j] | vn
            d0 = (((x & vp) + vp) ^ vp) | x
            hp = vn | ~(d0 | vp)
            hn = vp & d0
            x = (hp << one) | one  # global alignment: the top row grows by 1 per column
            vns[k] = x & d0
            vps[k] = (hn << one) | ~(x | d0)
    best = n + m
    for k in range(m):
        # D[n, m] = D[0, m] + sum of the last column's vertical deltas
        s = m + _popcount(vps[k] & mask) - _popcount(vns[k] & mask)
        if s < best:
            best = s
    return best


@njit(parallel=True, cache=True)
def cyclic_batch_unit(
    qcodes: NDArray[np.uint8],
    qoff: NDArray[np.int64],
    rcodes: NDArray[np.uint8],
    roff: NDArray[np.int64],
    sub: NDArray[np.float64],
    indel: NDArray[np.float64],
) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """Exact cyclic Levenshtein distances, shape ``(n_queries, n_references)`` (``sub``/``indel`` must be unit)."""
    nq = qoff.shape[0] - 1
    nr = roff.shape[0] - 1
    out = np.empty((nq, nr))
    maxlen = 1
    for r in range(nr):
        maxlen = max(maxlen, roff[r + 1] - roff[r])
    for q in range(nq):
        maxlen = max(maxlen, qoff[q + 1] - qoff[q])
    nchunks = (nr + _CHUNK - 1) // _CHUNK
    for c in prange(nchunks):
        peq = np.empty(N_LETTERS, dtype=np.uint64)
        pb = np.empty(2 * maxlen, dtype=np.uint64)
        vps = np.empty(maxlen, dtype=np.uint64)
        vns = np.empty(maxlen, dtype=np.uint64)
        for r in range(c * _CHUNK, min(nr, (c + 1) * _CHUNK)):
            b = rcodes[roff[r] : roff[r + 1]]
            for q in range(nq):
                a = qcodes[qoff[q] : qoff[q + 1]]
                n, m = a.shape[0], b.shape[0]
                if n == 0 or m == 0:
                    out[q, r] = n + m
                elif n <= WORD:
                    out[q, r] = _myers_all_rotations(a, b, peq, pb, vps, vns)
                elif m <= WORD:  # symmetric: let the shorter string be the pattern
                    out[q, r] = _myers_all_rotations(b, a, peq, pb, vps, vns)
                else:
                    out[q, r] = cyclic_all_rotations(a, b, sub, indel).min()
    return out
