"""Lower bounds on the cyclic alignment cost, for exact retrieval without aligning every reference.

**Semi-global bound.** A rotation of the query ``a`` (length ``n``) is a
substring of ``aa = a + a[:n-1]``; so the least global alignment cost of a
reference ``b`` against *any* substring of ``aa`` (free start and free end
in ``aa``, ``b`` aligned whole) is at most the cyclic cost
``min_r NW(rot_r(a), b)``. One such semi-global alignment costs
``(2n - 1) m`` cells where the cyclic cost costs ``n^2 m``: 7 % of it for
strings of 28 letters, and on the campus of :mod:`fingerloc.sim.campus` it
reaches 86 % of the cyclic cost on average (the letter counts alone reach
about 40 %).

It runs in the difference form of :mod:`fingerloc.align._cyclic_int` on
``GROUP_LANES`` (64) references side by side, the query's letters down the
rows, four rows a sweep (the difference row H goes through memory once for
the four: a pass about 20 % faster than with two on the campus index). With
a free start the first column is ``D[i, 0] = 0``, so
each row starts with ``U[i, 0] = -g(a_i)``. The free end needs
``D[i, m_k]`` of every row: every reference of a block is padded to the
block's longest with a *wildcard* that costs nothing to pair or to leave
out. Wildcards at the end of ``b`` can only swallow a suffix of the
substring of ``aa``, which the free end drops anyway, so the padded
reference has the same bound, and every lane ends at the same column:
``D[i, M] = D[i-1, M] + U[i, M] + g(a_i)``, summed down the rows from
``D[0, M] = sum g(b)``. The bound is ``min_i D[i, M]``, in the integer
units of :func:`~fingerloc.align._cyclic_int.integer_costs`.

**Blocks in a given order.** The exact batch kernel packs references sorted
by length; an index packs them in its own order (places that look alike
side by side), one block a group, so that a group it cannot rule out is
one block to bound. The substitution profile keeps one row per *class* of
query letters: letters whose costs against every letter the references
use, and whose own indel, are the same share a row (a laser-only map's
profile needs about 19 rows of the alphabet's 34).
"""

from __future__ import annotations

import os
from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["GROUP_LANES", "GroupProfiles", "pack_groups", "semiglobal_bounds"]

#: References side by side in a block of :func:`pack_groups` (two AVX2 registers of int8).
GROUP_LANES = 64


class GroupProfiles(NamedTuple):
    """References packed one block a group for :func:`semiglobal_bounds` (:func:`pack_groups`)."""

    prof: NDArray[np.int8]  # flat; block b at pstart[b]: (n_rows, block_len[b], GROUP_LANES)
    pstart: NDArray[np.int64]
    block_len: NDArray[np.int64]  # (n_blocks,): the longest reference of each block
    short: NDArray[np.int64]  # (n_blocks,): the shortest
    gsum: NDArray[np.int32]  # (n_blocks, GROUP_LANES): sum of the indels of each reference, D[0, m_k]
    row_of: NDArray[np.int64]  # (N_LETTERS,): the profile row of each query letter
    indel: NDArray[np.int8]  # (N_LETTERS,): the integer indels
    n_rows: int

    @property
    def nbytes(self) -> int:
        """Bytes held by the arrays."""
        return int(self.prof.nbytes + self.gsum.nbytes + 8 * 3 * self.pstart.size)


def _letter_rows(codes: NDArray[np.uint8], sub: NDArray[np.int8], indel: NDArray[np.int8]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The profile row of each letter and one letter standing for each row (letters alike against the references share one)."""
    used = np.unique(codes) if codes.size else np.zeros(0, dtype=np.uint8)
    keys: dict[bytes, int] = {}
    row_of = np.empty(sub.shape[0], dtype=np.int64)
    rep: list[int] = []
    for c in range(sub.shape[0]):
        key = sub[c, used].tobytes() + indel[c : c + 1].tobytes()
        if key not in keys:
            keys[key] = len(rep)
            rep.append(c)
        row_of[c] = keys[key]
    return row_of, np.asarray(rep, dtype=np.int64)


@njit(cache=True)
def _pack(
    codes: NDArray[np.uint8],
    off: NDArray[np.int64],
    starts: NDArray[np.int64],
    rep: NDArray[np.int64],
    sub: NDArray[np.int8],
    indel: NDArray[np.int8],
) -> tuple[NDArray[np.int8], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int32]]:  # pragma: no cover - compiled
    nb = starts.shape[0] - 1
    nr = rep.shape[0]
    block_len = np.zeros(nb, dtype=np.int64)
    short = np.zeros(nb, dtype=np.int64)
    pstart = np.zeros(nb + 1, dtype=np.int64)
    maxlen = 1
    for blk in range(nb):
        big = 0
        sh = 1 << 30
        for r in range(starts[blk], starts[blk + 1]):
            m = off[r + 1] - off[r]
            big = max(big, m)
            sh = min(sh, m)
        block_len[blk] = big
        short[blk] = sh if starts[blk + 1] - starts[blk] == GROUP_LANES else 0  # empty lanes are references of length 0
        pstart[blk + 1] = pstart[blk] + nr * big * GROUP_LANES
        maxlen = max(maxlen, big)
    prof = np.empty(pstart[nb], dtype=np.int8)
    gsum = np.zeros((nb, GROUP_LANES), dtype=np.int32)
    for blk in range(nb):
        big = block_len[blk]
        pb = prof[pstart[blk] : pstart[blk + 1]].reshape((nr, big, GROUP_LANES))
        for row in range(nr):  # the wildcard: s'(c, *) = 0 - g(c) - 0
            pb[row] = -indel[rep[row]]
        for k in range(starts[blk + 1] - starts[blk]):
            r = starts[blk] + k
            for j in range(off[r + 1] - off[r]):
                b = codes[off[r] + j]
                gsum[blk, k] += indel[b]
                for row in range(nr):
                    c = rep[row]
                    pb[row, j, k] = sub[c, b] - indel[c] - indel[b]
    return prof, pstart, block_len, short, gsum


def pack_groups(
    codes: NDArray[np.uint8], off: NDArray[np.int64], starts: NDArray[np.int64], sub8: NDArray[np.int8], indel8: NDArray[np.int8]
) -> GroupProfiles:
    """Pack references for :func:`semiglobal_bounds`, block ``b`` holding references ``starts[b] .. starts[b+1] - 1`` in order.

    ``codes``/``off`` from :func:`~fingerloc.align._encode.encode_many`; ``starts`` ascending from 0 to the number of
    references, at most ``GROUP_LANES`` apart; ``sub8``/``indel8`` from :func:`~fingerloc.align._cyclic_int.integer_costs`.
    """
    starts = np.ascontiguousarray(starts, dtype=np.int64)
    if starts.size < 1 or starts[0] != 0 or starts[-1] != off.size - 1 or np.any(np.diff(starts) > GROUP_LANES) or np.any(np.diff(starts) < 0):
        raise ValueError("pack_groups: starts must run from 0 to the number of references, at most GROUP_LANES apart")
    row_of, rep = _letter_rows(codes, sub8, indel8)
    prof, pstart, block_len, short, gsum = _pack(codes, off, starts, rep, sub8, indel8)
    return GroupProfiles(prof, pstart, block_len, short, gsum, row_of, indel8.copy(), int(rep.size))


@njit(cache=True, nogil=True)
def _bounds(
    rows: NDArray[np.int64],
    gaps: NDArray[np.int32],
    blocks: NDArray[np.int64],
    prof: NDArray[np.int8],
    pstart: NDArray[np.int64],
    block_len: NDArray[np.int64],
    gsum: NDArray[np.int32],
    n_rows: int,
    out: NDArray[np.int32],
    first: int,
    step: int,
) -> None:  # pragma: no cover - compiled
    """Blocks ``blocks[first::step]`` into the same rows of ``out`` (threads share the blocks)."""
    nrow = rows.shape[0]
    hv = np.empty((max(1, int(block_len.max())), GROUP_LANES), dtype=np.int8)
    u1 = np.empty(GROUP_LANES, dtype=np.int8)
    u2 = np.empty(GROUP_LANES, dtype=np.int8)
    u3 = np.empty(GROUP_LANES, dtype=np.int8)
    u4 = np.empty(GROUP_LANES, dtype=np.int8)
    dl = np.empty(GROUP_LANES, dtype=np.int32)
    best = np.empty(GROUP_LANES, dtype=np.int32)
    for q in range(first, blocks.shape[0], step):
        blk = blocks[q]
        big = block_len[blk]
        pb = prof[pstart[blk] : pstart[blk + 1]].reshape((n_rows, big, GROUP_LANES))
        for k in range(GROUP_LANES):
            dl[k] = gsum[blk, k]  # D[0, M]: the whole reference deleted
            best[k] = dl[k]
        for j in range(big):
            for k in range(GROUP_LANES):
                hv[j, k] = 0  # row 0: D[0, j+1] - D[0, j] = g(b_j)
        i = 0
        while i + 4 <= nrow:  # four rows a sweep: H goes through memory once for the four
            p1 = pb[rows[i]]
            p2 = pb[rows[i + 1]]
            p3 = pb[rows[i + 2]]
            p4 = pb[rows[i + 3]]
            g1 = np.int8(-gaps[i])
            g2 = np.int8(-gaps[i + 1])
            g3 = np.int8(-gaps[i + 2])
            g4 = np.int8(-gaps[i + 3])
            for k in range(GROUP_LANES):
                u1[k] = g1  # free start: D[i, 0] = 0, so U[i, 0] = -g(a_i)
                u2[k] = g2
                u3[k] = g3
                u4[k] = g4
            for j in range(big):
                # the four rows written out: a loop over them here keeps LLVM from vectorising over the lanes (~70x slower)
                for k in range(GROUP_LANES):
                    h = hv[j, k]
                    x = u1[k]
                    z = min(min(p1[j, k], h), x)
                    u1[k] = np.int8(z - h)
                    h = np.int8(z - x)
                    x = u2[k]
                    z = min(min(p2[j, k], h), x)
                    u2[k] = np.int8(z - h)
                    h = np.int8(z - x)
                    x = u3[k]
                    z = min(min(p3[j, k], h), x)
                    u3[k] = np.int8(z - h)
                    h = np.int8(z - x)
                    x = u4[k]
                    z = min(min(p4[j, k], h), x)
                    u4[k] = np.int8(z - h)
                    hv[j, k] = np.int8(z - x)
            for k in range(GROUP_LANES):
                dl[k] += u1[k] + gaps[i]  # D[i, M] = D[i-1, M] + U[i, M] + g(a_i)
                best[k] = min(best[k], dl[k])
                dl[k] += u2[k] + gaps[i + 1]
                best[k] = min(best[k], dl[k])
                dl[k] += u3[k] + gaps[i + 2]
                best[k] = min(best[k], dl[k])
                dl[k] += u4[k] + gaps[i + 3]
                best[k] = min(best[k], dl[k])
            i += 4
        while i < nrow:  # the last rows one at a time
            p1 = pb[rows[i]]
            g1 = np.int8(-gaps[i])
            for k in range(GROUP_LANES):
                u1[k] = g1
            for j in range(big):
                for k in range(GROUP_LANES):
                    h = hv[j, k]
                    x = u1[k]
                    z = min(min(p1[j, k], h), x)
                    u1[k] = np.int8(z - h)
                    hv[j, k] = np.int8(z - x)
            for k in range(GROUP_LANES):
                dl[k] += u1[k] + gaps[i]
                best[k] = min(best[k], dl[k])
            i += 1
        for k in range(GROUP_LANES):
            out[q, k] = best[k]


#: Fewest blocks a call splits between two threads.
_THREAD_MIN_BLOCKS = 64


def semiglobal_bounds(
    query: NDArray[np.uint8], gp: GroupProfiles, blocks: NDArray[np.int64], *, workers: int = 2
) -> NDArray[np.int32]:
    """Lower bounds (integer units) on the cyclic cost of ``query`` against every lane of ``blocks``, shape ``(len(blocks), GROUP_LANES)``.

    ``query``: letter codes (:func:`~fingerloc.align._encode.encode`). Lanes past a block's references hold 0.
    ``workers`` threads share the blocks when there are many (the pool of
    :func:`~fingerloc.align._cyclic_int.cyclic_i8_costs`, whose idle threads wait without spinning).
    """
    from ._cyclic_int import _pool

    n = int(query.size)
    aa = np.concatenate([query, query[: max(n - 1, 0)]]).astype(np.int64)
    blocks = np.ascontiguousarray(blocks, dtype=np.int64)
    out = np.empty((blocks.size, GROUP_LANES), dtype=np.int32)
    if not blocks.size:
        return out
    args = (gp.row_of[aa], gp.indel[aa].astype(np.int32), blocks, gp.prof, gp.pstart, gp.block_len, gp.gsum, gp.n_rows, out)
    nw = max(1, min(int(workers), os.cpu_count() or 1, blocks.size // _THREAD_MIN_BLOCKS + 1))
    if nw == 1:
        _bounds(*args, 0, 1)
        return out
    futures = [_pool().submit(_bounds, *args, t, nw) for t in range(1, nw)]
    _bounds(*args, 0, nw)
    for f in futures:
        f.result()
    return out


@njit(cache=True)
def _count_bounds(
    q: NDArray[np.int32], counts_t: NDArray[np.int16], letters: NDArray[np.int64], h2: NDArray[np.int32], c2: NDArray[np.int32],
    out: NDArray[np.int32],
) -> None:  # pragma: no cover - compiled
    nv = counts_t.shape[1]
    acc_h = np.zeros(nv, dtype=np.int32)
    acc_p = np.zeros(nv, dtype=np.int32)
    acc_n = np.zeros(nv, dtype=np.int32)
    for t in range(letters.shape[0]):
        x = letters[t]
        qx = q[x]
        hx = h2[x]
        cx = c2[x]
        row = counts_t[x]
        for i in range(nv):
            d = qx - np.int32(row[i])
            pos = max(d, 0)
            neg = max(-d, 0)
            acc_h[i] += hx * (pos + neg)
            acc_p[i] += cx * pos
            acc_n[i] += cx * neg
    for i in range(nv):
        out[i] = max(acc_h[i], max(acc_p[i], acc_n[i]))
