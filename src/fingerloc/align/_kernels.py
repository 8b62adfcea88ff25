"""Compiled Needleman-Wunsch kernels (numba) for weighted costs.

Letters are ``uint8`` codes (positions in the alphabet); ``sub`` is the
``(N_LETTERS, N_LETTERS)`` substitution table and ``indel`` the ``(N_LETTERS,)`` insertion/deletion
costs of a :class:`~fingerloc.align.CostModel`.

The batch kernel runs ``LANES`` (32) references side by side: the innermost
loop runs over the lanes, which breaks the dependency chain of one DP row
(each cell needs its left neighbour) and lets LLVM vectorise it (AVX2). The
substitution costs of each block are laid out once per block as a profile
``prof[letter, j, lane]``, so the inner loop reads them contiguously instead
of gathering. With 8 or 16 lanes LLVM kept the loop scalar (about 1e9 cells/s
per core); from 24 lanes on it vectorises (about 3.5e9 cells/s per core).
The block body :func:`_block_costs` must stay inlined into the parallel
kernels: called as a function its work arrays may alias for all LLVM knows,
and the loop falls back to scalar code (measured: 2.5 times slower).

:func:`nw_batch_cyclic` runs the same block body for every rotation of the
references: the exact weighted cyclic cost.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

__all__ = ["LANES", "nw_batch", "nw_batch_cyclic", "nw_cost", "nw_matrix", "pack_lanes", "traceback"]

#: References aligned side by side in the batch kernel.
LANES = 32


@njit(cache=True)
def nw_matrix(
    a: NDArray[np.uint8], b: NDArray[np.uint8], sub: NDArray[np.float64], indel: NDArray[np.float64]
) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """Full DP table ``D`` of shape ``(len(a) + 1, len(b) + 1)``; ``D[i, j]`` aligns ``a[:i]`` with ``b[:j]``."""
    n, m = a.shape[0], b.shape[0]
    d = np.empty((n + 1, m + 1))
    d[0, 0] = 0.0
    for j in range(1, m + 1):
        d[0, j] = d[0, j - 1] + indel[b[j - 1]]
    for i in range(1, n + 1):
        ca = a[i - 1]
        da = indel[ca]
        d[i, 0] = d[i - 1, 0] + da
        for j in range(1, m + 1):
            cb = b[j - 1]
            # D[i,j] = min(D[i-1,j-1] + s(a_i, b_j), D[i-1,j] + g(a_i), D[i,j-1] + g(b_j))
            v = d[i - 1, j - 1] + sub[ca, cb]
            w = d[i - 1, j] + da
            if w < v:
                v = w
            w = d[i, j - 1] + indel[cb]
            if w < v:
                v = w
            d[i, j] = v
    return d


@njit(cache=True)
def nw_cost(
    a: NDArray[np.uint8], b: NDArray[np.uint8], sub: NDArray[np.float64], indel: NDArray[np.float64]
) -> float:  # pragma: no cover - compiled
    """Minimal global alignment cost of ``a`` and ``b`` (one DP row, ``O(len(b))`` memory)."""
    m = b.shape[0]
    row = np.empty(m + 1)
    row[0] = 0.0
    for j in range(1, m + 1):
        row[j] = row[j - 1] + indel[b[j - 1]]
    for i in range(a.shape[0]):
        ca = a[i]
        da = indel[ca]
        diag = row[0]
        row[0] = diag + da
        for j in range(1, m + 1):
            cb = b[j - 1]
            v = diag + sub[ca, cb]
            up = row[j]
            w = up + da
            if w < v:
                v = w
            w = row[j - 1] + indel[cb]
            if w < v:
                v = w
            diag = up
            row[j] = v
    return float(row[m])


def traceback(
    d: NDArray[np.float64],
    a: NDArray[np.uint8],
    b: NDArray[np.uint8],
    sub: NDArray[np.float64],
    indel: NDArray[np.float64],
) -> list[tuple[int | None, int | None]]:
    """One optimal alignment from the DP table ``d``, as index pairs from first to last.

    Ties prefer a pairing, then a deletion (``a[i]`` unpaired), then an
    insertion (``b[j]`` unpaired).
    """
    i, j = a.shape[0], b.shape[0]
    out: list[tuple[int | None, int | None]] = []
    while i > 0 or j > 0:
        if i > 0 and j > 0 and d[i, j] == d[i - 1, j - 1] + sub[a[i - 1], b[j - 1]]:
            out.append((i - 1, j - 1))
            i, j = i - 1, j - 1
        elif i > 0 and d[i, j] == d[i - 1, j] + indel[a[i - 1]]:
            out.append((i - 1, None))
            i -= 1
        else:
            out.append((None, j - 1))
            j -= 1
    out.reverse()
    return out


def pack_lanes(
    codes: NDArray[np.uint8], off: NDArray[np.int64], lanes: int = LANES
) -> tuple[NDArray[np.uint8], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Pack strings into blocks of ``lanes`` strings of similar length, side by side.

    The batch kernels need ``lanes == LANES``; other values are for tests.

    Returns
    -------
    blocks : ndarray of uint8, shape (n_blocks, max_len, lanes)
        ``blocks[k, j, l]`` is letter ``j`` of the ``l``-th string of block ``k`` (0 past its end).
    lens : ndarray of int64, shape (n_blocks, lanes)
        Length of each packed string (0 for padding lanes).
    block_len : ndarray of int64, shape (n_blocks,)
        Longest string of each block.
    slot : ndarray of int64, shape (n_strings,)
        Position ``k * lanes + l`` of each input string in the packed layout.
    """
    n = off.shape[0] - 1
    lens = np.diff(off)
    order = np.argsort(lens, kind="stable")
    nb = max(1, -(-n // lanes))
    maxlen = int(lens.max()) if n else 0
    blocks = np.zeros((nb, maxlen, lanes), dtype=np.uint8)
    blens = np.zeros(nb * lanes, dtype=np.int64)
    blens[:n] = lens[order]
    slot = np.empty(n, dtype=np.int64)
    slot[order] = np.arange(n)
    _fill_blocks(codes, off, order, blocks)
    blens2 = blens.reshape(nb, lanes)
    return blocks, blens2, blens2.max(axis=1), slot


@njit(cache=True)
def _fill_blocks(
    codes: NDArray[np.uint8], off: NDArray[np.int64], order: NDArray[np.int64], blocks: NDArray[np.uint8]
) -> None:  # pragma: no cover - compiled
    lanes = blocks.shape[2]
    for pos in range(order.shape[0]):
        s = order[pos]
        k = pos // lanes
        lane = pos - k * lanes
        for j in range(off[s + 1] - off[s]):
            blocks[k, j, lane] = codes[off[s] + j]


@njit(cache=True, inline="always")
def _block_costs(
    qcodes: NDArray[np.uint8],
    qoff: NDArray[np.int64],
    bc: NDArray[np.uint8],
    big: int,
    lens: NDArray[np.int64],
    sub: NDArray[np.float64],
    indel: NDArray[np.float64],
    prof: NDArray[np.float64],
    indb: NDArray[np.float64],
    row: NDArray[np.float64],
    diag: NDArray[np.float64],
    res: NDArray[np.float64],
) -> None:  # pragma: no cover - compiled
    """Costs of every query against the ``LANES`` references of one block: ``res[q, lane]``.

    ``bc[j, lane]`` is letter ``j`` of the lane's reference, ``lens[lane]`` its
    length and ``big`` the longest; the other arrays are work buffers.
    """
    # prof[c, j, k] = sub[c, letter j of reference k]: contiguous in the lanes
    for c in range(sub.shape[0]):
        for j in range(big):
            for k in range(LANES):
                prof[c, j, k] = sub[c, bc[j, k]]
    for j in range(big):
        for k in range(LANES):
            indb[j, k] = indel[bc[j, k]]
    for q in range(qoff.shape[0] - 1):
        for k in range(LANES):
            row[0, k] = 0.0
        for j in range(1, big + 1):
            for k in range(LANES):
                row[j, k] = row[j - 1, k] + indb[j - 1, k]
        for i in range(qoff[q], qoff[q + 1]):
            ca = qcodes[i]
            da = indel[ca]
            pr = prof[ca]
            for k in range(LANES):
                diag[k] = row[0, k]
                row[0, k] = diag[k] + da
            for j in range(1, big + 1):
                for k in range(LANES):  # vectorised over the references
                    # D[i,j] = min(D[i-1,j-1] + s(a_i, b_j), D[i-1,j] + g(a_i), D[i,j-1] + g(b_j))
                    v = diag[k] + pr[j - 1, k]
                    up = row[j, k]
                    v = min(v, up + da)
                    v = min(v, row[j - 1, k] + indb[j - 1, k])
                    diag[k] = up
                    row[j, k] = v
        for k in range(LANES):
            res[q, k] = row[lens[k], k]


@njit(parallel=True, cache=True)
def nw_batch(
    qcodes: NDArray[np.uint8],
    qoff: NDArray[np.int64],
    blocks: NDArray[np.uint8],
    blens: NDArray[np.int64],
    block_len: NDArray[np.int64],
    sub: NDArray[np.float64],
    indel: NDArray[np.float64],
) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """Costs of every query against every packed reference, shape ``(n_queries, n_blocks * LANES)``."""
    nq = qoff.shape[0] - 1
    nb = blocks.shape[0]
    maxlen = blocks.shape[1]
    out = np.empty((nq, nb * LANES))
    for blk in prange(nb):
        prof = np.empty((sub.shape[0], maxlen, LANES))
        indb = np.empty((maxlen + 1, LANES))
        row = np.empty((maxlen + 1, LANES))
        diag = np.empty(LANES)
        res = np.empty((nq, LANES))
        _block_costs(qcodes, qoff, blocks[blk], block_len[blk], blens[blk], sub, indel, prof, indb, row, diag, res)
        out[:, blk * LANES : (blk + 1) * LANES] = res
    return out


@njit(parallel=True, cache=True)
def nw_batch_cyclic(
    qcodes: NDArray[np.uint8],
    qoff: NDArray[np.int64],
    blocks: NDArray[np.uint8],
    blens: NDArray[np.int64],
    block_len: NDArray[np.int64],
    sub: NDArray[np.float64],
    indel: NDArray[np.float64],
) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """Cyclic costs (minimum over every rotation of each reference), shape ``(n_queries, n_blocks * LANES)``.

    Every rotation ``r`` of the longest reference of a block is aligned with
    the block kernel; a shorter reference of length ``m`` reads rotation
    ``r mod m`` (repeats are harmless for a minimum).
    """
    nq = qoff.shape[0] - 1
    nb = blocks.shape[0]
    maxlen = blocks.shape[1]
    out = np.empty((nq, nb * LANES))
    for blk in prange(nb):
        bc = blocks[blk]
        lens = blens[blk]
        big = block_len[blk]
        prof = np.empty((sub.shape[0], maxlen, LANES))
        indb = np.empty((maxlen + 1, LANES))
        row = np.empty((maxlen + 1, LANES))
        diag = np.empty(LANES)
        res = np.empty((nq, LANES))
        best = np.full((nq, LANES), np.inf)
        rot = np.zeros((maxlen, LANES), dtype=np.uint8)
        for r in range(max(big, 1)):
            for k in range(LANES):
                m = lens[k]
                if m == 0:
                    continue
                jj = r % m
                for j in range(m):
                    rot[j, k] = bc[jj, k]
                    jj += 1
                    if jj == m:
                        jj = 0
            _block_costs(qcodes, qoff, rot, big, lens, sub, indel, prof, indb, row, diag, res)
            for q in range(nq):
                for k in range(LANES):
                    best[q, k] = min(best[q, k], res[q, k])
        out[:, blk * LANES : (blk + 1) * LANES] = best
    return out
