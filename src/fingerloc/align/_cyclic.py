"""Exact cyclic alignment kernels: the minimum over all rotations of one string."""

from __future__ import annotations

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from ._kernels import nw_cost

__all__ = ["cyclic_all_rotations", "cyclic_batch_brute"]


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
