"""Exact weighted cyclic alignment in 8-bit lanes: difference form, rotations of the query.

The float64 weighted cyclic kernel (:func:`fingerloc.align._kernels.nw_batch_cyclic`)
runs the 32-reference block kernel once per rotation of the references. This
kernel computes the same costs, bit for bit, several times faster:

* **Small integers.** The feature-aware costs are multiples of 1/4 (hue steps
  of 0.25, ``n`` indels of 0.5). When every cost of a
  :class:`~fingerloc.align.CostModel` is a multiple of ``1 / scale`` for a
  power of two ``scale`` (so that ``scale * cost`` is exact), the DP runs on
  the integers ``scale * cost``. Sums of such dyadic costs are exact in
  float64 too, so ``integer_cost / scale`` equals the float64 DP exactly.
* **Differences, in int8.** The DP values grow with the string lengths, but
  the differences between neighbouring cells do not: with
  ``h[i, j] = D[i, j] - D[i, j-1]`` and ``u[i, j] = D[i, j] - D[i-1, j]``,
  ``|h|, |u| <= max indel`` (remove the last letter from an optimal
  alignment), and the recurrence becomes (Suzuki and Kasahara's difference
  form)::

      z       = min( s(a_i, b_j), h[i-1, j] + g(a_i), u[i, j-1] + g(b_j) )   # D[i,j] - D[i-1,j-1]
      u[i, j] = z - h[i-1, j]
      h[i, j] = z - u[i, j-1]

  Shifting both differences by the indel of their own letter,
  ``H = h - g(b_j)`` and ``U = u - g(a_i)`` (both in ``[-2 max indel, 0]``),
  folds the two indel additions into the substitution profile,
  ``s'(a, b) = s(a, b) - g(a) - g(b)``::

      z       = min( s'(a_i, b_j), H[i-1, j], U[i, j-1] )
      U[i, j] = z - H[i-1, j]
      H[i, j] = z - U[i, j-1]

  four operations a cell instead of six (two additions fewer), and rows and
  columns start at ``H = U = 0``. Every intermediate value lies within
  ``2 max indel + max substitution``, so with
  ``scale * (2 max indel + max substitution) <= 127`` the lanes are int8: a
  512-bit register carries 64 cells instead of 8 float64 ones. The cost is
  recovered as ``D[n, m] = D[n, 0] + D[0, m] + sum_j H[n, j]``, with
  ``D[n, 0]`` the indels of the whole query (the same for every rotation)
  and ``D[0, m]`` those of the reference; the sum runs in int16 lanes
  while ``2 max indel * m <= 32767``, else in int32.
* **Two rows a sweep.** Each sweep over a reference computes two query rows,
  the second one column behind the first, so the row of ``H`` goes through
  memory once for both; the ``U`` of both rows stay in registers.
* **Rotate the query, not the references.** The cyclic cost is symmetric
  and invariant under rotating either string (see
  :mod:`fingerloc.align._cyclic`), so ``min over r of NW(a[r:] + a[:r], b)``
  is the same minimum. Every lane of a block then sees the same rotation and
  the substitution profile of a block of references is built once, not once
  per rotation.

:func:`integer_costs` decides whether a cost model qualifies; one that does
not (a cost of 0.1, or costs too far apart) keeps the float64 kernel.
``LANES8`` (256) references run side by side: fewer lanes leave the loop
bound by the latency of one row's dependency chain (measured: 64 lanes 2.8
times slower than 256; 512 no faster).

References
----------
.. [1] H. Suzuki, M. Kasahara, "Introducing difference recurrence relations
   for faster semi-global alignment of long sequences", BMC Bioinformatics
   19 (Suppl 1), 2018.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["LANES8", "ProfileBlocks", "cyclic_i8_costs", "integer_costs", "nw_batch_cyclic_i8", "pack_profiles"]

#: References aligned side by side in the int8 kernel.
LANES8 = 256
#: Largest magnitude an intermediate value of the int8 kernel may reach.
_I8_LIMIT = 127
#: Bytes in a page: the span of address bits that a load and an earlier store must not share.
_PAGE = 4096
#: Scales tried, smallest first: powers of two, so that ``cost * scale`` is exact.
_SCALES = tuple(2**e for e in range(0, 7))


def integer_costs(
    sub: NDArray[np.float64], indel: NDArray[np.float64]
) -> tuple[NDArray[np.int8], NDArray[np.int8], int] | None:
    """Integer versions of a cost model's tables for the int8 kernel, or ``None``.

    Parameters
    ----------
    sub : ndarray of float64, shape (N_LETTERS, N_LETTERS)
        Substitution costs.
    indel : ndarray of float64, shape (N_LETTERS,)
        Insertion/deletion costs.

    Returns
    -------
    (sub8, indel8, scale) or None
        ``sub8 = scale * sub`` and ``indel8 = scale * indel`` as int8, for
        the smallest power of two ``scale`` (1 to 64) that makes every cost
        an integer; ``None`` when there is none or an intermediate value of
        the difference recurrence, up to ``scale * (2 max indel + max
        substitution)``, could pass 127.
    """
    key = (sub.shape, sub.tobytes(), indel.tobytes())
    if key not in _INTEGER_COSTS:  # a cost model is checked once (65 us), not on every call
        if len(_INTEGER_COSTS) >= 64:
            _INTEGER_COSTS.clear()
        _INTEGER_COSTS[key] = _integer_costs(sub, indel)
    hit = _INTEGER_COSTS[key]
    return None if hit is None else (hit[0].copy(), hit[1].copy(), hit[2])


#: Answers of :func:`integer_costs` by cost tables (at most 64 models).
_INTEGER_COSTS: dict[tuple[object, ...], tuple[NDArray[np.int8], NDArray[np.int8], int] | None] = {}


def _integer_costs(
    sub: NDArray[np.float64], indel: NDArray[np.float64]
) -> tuple[NDArray[np.int8], NDArray[np.int8], int] | None:
    bound = 2.0 * float(indel.max(initial=0.0)) + float(sub.max(initial=0.0))
    for scale in _SCALES:
        s_sub = sub * scale
        s_ind = indel * scale
        if np.array_equal(s_sub, np.round(s_sub)) and np.array_equal(s_ind, np.round(s_ind)):
            if bound * scale > _I8_LIMIT:
                return None
            return s_sub.astype(np.int8), s_ind.astype(np.int8), scale
    return None


class ProfileBlocks(NamedTuple):
    """References packed for the int8 kernel: each block's substitution profile and its sums (:func:`pack_profiles`).

    Built once per set of references and cost model (a
    :class:`~fingerloc.align.FingerprintBatch` keeps it), so a query against
    a place database does not encode, pack and profile every reference again.
    ``prof`` takes ``N_LETTERS x ceil(block_len / 16) x 16 x LANES8`` bytes a
    block (34 x 48 = 1,632 bytes a reference in a block of 40-letter
    references), ``keep`` ``max_len x LANES8`` bytes a block: 3.9 MB for the
    3,000 references of 22-49 letters of ``bench speed --only laser``.
    """

    prof: NDArray[np.int8]  # flat, page-aligned; block b at pstart[b]: (n_letters, prow[b], LANES8)
    pstart: NDArray[np.int64]
    prow: NDArray[np.int64]
    gsum: NDArray[np.int32]  # (n_blocks, LANES8): D[0, m_k], the indels of reference k
    keep: NDArray[np.int8]  # (n_blocks, max_len, LANES8): -1 where j < m_k, else 0
    short: NDArray[np.int64]  # (n_blocks,): the shortest reference of the block
    block_len: NDArray[np.int64]  # (n_blocks,): the longest
    slot: NDArray[np.int64]  # (n_references,): position of each reference in the packed layout
    indel: NDArray[np.int8]
    gmax: int

    @property
    def nbytes(self) -> int:
        """Bytes held by the arrays."""
        return int(self.prof.nbytes + self.keep.nbytes + self.gsum.nbytes + 8 * (3 * self.prow.size + self.slot.size))


@njit(cache=True)
def _profiles(
    blocks: NDArray[np.uint8],
    blens: NDArray[np.int64],
    block_len: NDArray[np.int64],
    sub: NDArray[np.int8],
    indel: NDArray[np.int8],
) -> tuple[
    NDArray[np.int8], NDArray[np.int64], NDArray[np.int64], NDArray[np.int32], NDArray[np.int8], NDArray[np.int64]
]:  # pragma: no cover - compiled
    nb = blocks.shape[0]
    maxlen = blocks.shape[1]
    nl = sub.shape[0]
    prow = np.empty(nb, dtype=np.int64)
    pstart = np.empty(nb, dtype=np.int64)
    total = 0
    for blk in range(nb):
        prow[blk] = -(-block_len[blk] // 16) * 16  # nl * prow * LANES8 bytes: a multiple of the page
        pstart[blk] = total
        total += nl * prow[blk] * LANES8
    raw = np.empty(total + _PAGE, dtype=np.int8)
    p0 = (_PAGE - raw.ctypes.data % _PAGE) % _PAGE
    prof = raw[p0 : p0 + total]
    gsum = np.zeros((nb, LANES8), dtype=np.int32)
    keep = np.zeros((nb, maxlen, LANES8), dtype=np.int8)
    short = np.empty(nb, dtype=np.int64)
    for blk in range(nb):
        bc = blocks[blk]
        big = block_len[blk]
        pr = prow[blk]
        # prof[c, j, k] = s(c, b_j) - g(c) - g(b_j) for letter j of reference k: contiguous in the lanes.
        pb = prof[pstart[blk] : pstart[blk] + nl * pr * LANES8].reshape((nl, pr, LANES8))
        for c in range(nl):
            gc = indel[c]
            for j in range(big):
                for k in range(LANES8):
                    b = bc[j, k]
                    pb[c, j, k] = sub[c, b] - gc - indel[b]
        sh = big
        for k in range(LANES8):
            m = blens[blk, k]
            sh = min(sh, m)
            for j in range(m):
                gsum[blk, k] += indel[bc[j, k]]
                keep[blk, j, k] = -1
        short[blk] = sh
    return prof, pstart, prow, gsum, keep, short


def pack_profiles(
    codes: NDArray[np.uint8], off: NDArray[np.int64], sub: NDArray[np.int8], indel: NDArray[np.int8]
) -> ProfileBlocks:
    """Pack encoded references (:func:`~fingerloc.align._encode.encode_many`) for :func:`cyclic_i8_costs`.

    ``sub`` and ``indel`` come from :func:`integer_costs`.
    """
    from ._kernels import pack_lanes

    blocks, blens, block_len, slot = pack_lanes(codes, off, LANES8)
    prof, pstart, prow, gsum, keep, short = _profiles(blocks, blens, block_len, sub, indel)
    gmax = int(indel.max(initial=0))
    return ProfileBlocks(prof, pstart, prow, gsum, keep, short, block_len, slot, indel, gmax)


@njit(cache=True)
def _block_costs(
    qcodes: NDArray[np.uint8],
    qoff: NDArray[np.int64],
    maxq: int,
    blk: int,
    prof: NDArray[np.int8],
    pstart: NDArray[np.int64],
    prow: NDArray[np.int64],
    gsum: NDArray[np.int32],
    keep: NDArray[np.int8],
    short: NDArray[np.int64],
    block_len: NDArray[np.int64],
    indel: NDArray[np.int8],
    gmax: int,
    out: NDArray[np.int32],
) -> None:  # pragma: no cover - compiled
    """Every query against the ``LANES8`` references of block ``blk``: ``out[q, blk * LANES8 + k]``."""
    nq = qoff.shape[0] - 1
    nl = indel.shape[0]
    big = block_len[blk]
    pr = prow[blk]
    pb = prof[pstart[blk] : pstart[blk] + nl * pr * LANES8].reshape((nl, pr, LANES8))
    kp = keep[blk]
    gs = gsum[blk]
    sh = short[blk]
    # The profile is page-aligned, one letter every multiple of 4096 bytes; hv starts half a page off that:
    # a store to hv[j] then shares its address bits 0-11 with no load of prof[., j] or of the next seven
    # columns that follows it. Such "4K aliasing" makes the loads wait for the store: up to 1.9x slower,
    # depending on where the allocator had put the arrays.
    raw = np.empty(max(big, 1) * LANES8 + 2 * _PAGE, dtype=np.int8)
    h0 = (_PAGE // 2 - raw.ctypes.data % _PAGE) % _PAGE
    hv = raw[h0 : h0 + max(big, 1) * LANES8].reshape((max(big, 1), LANES8))  # H[i, j] = D[i, j+1] - D[i, j] - g(b_j)
    # The last row's sum fits int16 when every |H| <= 2 gmax over at most ``big`` columns does.
    narrow = 2 * gmax * big <= 32767
    u1 = np.empty(LANES8, dtype=np.int8)  # U[i, j] = D[i, j] - D[i-1, j] - g(a_i), left of the cell
    u2 = np.empty(LANES8, dtype=np.int8)  # the same on the next row
    s16 = np.empty(LANES8, dtype=np.int16)
    s32 = np.empty(LANES8, dtype=np.int32)
    best = np.empty(LANES8, dtype=np.int32)
    aa = np.empty(2 * maxq, dtype=np.int64)  # the query twice: rotation r reads aa[r : r + n]
    for q in range(nq):
        q0 = qoff[q]
        n = qoff[q + 1] - q0
        base = 0  # D[n, 0]: every query letter deleted, whatever the rotation
        for i in range(n):
            base += indel[qcodes[q0 + i]]
            aa[i] = qcodes[q0 + i]
            aa[i + n] = qcodes[q0 + i]
        for k in range(LANES8):
            best[k] = 2**30
        for r in range(max(n, 1)):
            for j in range(big):
                for k in range(LANES8):
                    hv[j, k] = 0  # row 0: D[0, j+1] - D[0, j] = g(b_j)
            i = 0
            while i + 1 < n:  # two rows per sweep: H goes through memory once for both
                p1 = pb[aa[r + i]]
                p2 = pb[aa[r + i + 1]]
                for k in range(LANES8):
                    u1[k] = 0  # column 0: D[i, 0] - D[i-1, 0] = g(a_i)
                    u2[k] = 0
                for j in range(big):
                    for k in range(LANES8):  # vectorised over the references
                        # z = D[i,j] - D[i-1,j-1] - g(a_i) - g(b_j) = min(s'(a_i, b_j), H[i-1,j], U[i,j-1]);
                        # every result cast back to int8 so that LLVM keeps 8-bit lanes (exact: no overflow)
                        h = hv[j, k]
                        x = u1[k]
                        z = min(min(p1[j, k], h), x)
                        u1[k] = np.int8(z - h)
                        h = np.int8(z - x)
                        x = u2[k]
                        z = min(min(p2[j, k], h), x)
                        u2[k] = np.int8(z - h)
                        hv[j, k] = np.int8(z - x)
                i += 2
            if i < n:  # an odd query: its last row alone
                p1 = pb[aa[r + i]]
                for k in range(LANES8):
                    u1[k] = 0
                for j in range(big):
                    for k in range(LANES8):
                        h = hv[j, k]
                        x = u1[k]
                        z = min(min(p1[j, k], h), x)
                        u1[k] = np.int8(z - h)
                        hv[j, k] = np.int8(z - x)
            # D[n, m_k] = D[n, 0] + D[0, m_k] + sum of H[n, j] over j < m_k
            if narrow:
                for k in range(LANES8):
                    s16[k] = 0
                for j in range(sh):  # columns every lane has
                    for k in range(LANES8):
                        s16[k] = np.int16(s16[k] + hv[j, k])
                for j in range(sh, big):
                    for k in range(LANES8):
                        s16[k] = np.int16(s16[k] + (hv[j, k] & kp[j, k]))
                for k in range(LANES8):
                    best[k] = min(best[k], base + gs[k] + s16[k])
            else:
                for k in range(LANES8):
                    s32[k] = 0
                for j in range(big):
                    for k in range(LANES8):
                        s32[k] += hv[j, k] & kp[j, k]
                for k in range(LANES8):
                    best[k] = min(best[k], base + gs[k] + s32[k])
        for k in range(LANES8):
            out[q, blk * LANES8 + k] = best[k]


def _max_query(qoff: NDArray[np.int64]) -> int:
    return int(np.diff(qoff).max(initial=0))


@njit(nogil=True, cache=True)
def _costs_blocks(qcodes, qoff, maxq, prof, pstart, prow, gsum, keep, short, block_len, indel, gmax, out, first, step):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Blocks ``first, first + step, ...`` into ``out``, without the GIL (so that threads can share the blocks)."""
    for blk in range(first, block_len.shape[0], step):
        _block_costs(qcodes, qoff, maxq, blk, prof, pstart, prow, gsum, keep, short, block_len, indel, gmax, out)


_POOL: list[tuple[int, ThreadPoolExecutor]] = []  # (pid, pool): a pool made before a fork has no threads after it
_POOL_LOCK = threading.Lock()


def _pool() -> ThreadPoolExecutor:
    with _POOL_LOCK:
        if not _POOL or _POOL[0][0] != os.getpid():
            _POOL[:] = [
                (
                    os.getpid(),
                    ThreadPoolExecutor(
                        max_workers=max(1, (os.cpu_count() or 1) - 1), thread_name_prefix="fingerloc-i8"
                    ),
                )
            ]
        return _POOL[0][1]


def cyclic_i8_costs(
    qcodes: NDArray[np.uint8], qoff: NDArray[np.int64], pk: ProfileBlocks, *, workers: int = 1
) -> NDArray[np.int32]:
    """Integer cyclic costs of every query against the packed references, shape ``(n_queries, n_blocks * LANES8)``.

    Entry ``[q, k * LANES8 + l]`` is ``scale`` times the cyclic cost of query
    ``q`` against reference ``l`` of block ``k`` (minimum over every rotation
    of the query); ``pk.slot`` maps the references to their entries.
    ``workers`` threads share the blocks (every ``workers``-th block each):
    the calling thread and ``workers - 1`` threads of a pool, which wait on a
    queue, not spinning, when idle (numba's own threads spin for a while
    after each parallel region: on a loaded machine a single query cost
    several times the CPU of one thread).
    """
    nb = pk.block_len.shape[0]
    out = np.empty((qoff.shape[0] - 1, nb * LANES8), dtype=np.int32)
    args = (
        qcodes,
        qoff,
        _max_query(qoff),
        pk.prof,
        pk.pstart,
        pk.prow,
        pk.gsum,
        pk.keep,
        pk.short,
        pk.block_len,
        pk.indel,
        pk.gmax,
        out,
    )
    n = max(1, min(int(workers), nb))
    if n == 1:
        _costs_blocks(*args, 0, 1)
        return out
    pool = _pool()
    futures = [pool.submit(_costs_blocks, *args, t, n) for t in range(1, n)]
    _costs_blocks(*args, 0, n)
    for f in futures:
        f.result()
    return out


def nw_batch_cyclic_i8(
    qcodes: NDArray[np.uint8],
    qoff: NDArray[np.int64],
    blocks: NDArray[np.uint8],
    blens: NDArray[np.int64],
    block_len: NDArray[np.int64],
    sub: NDArray[np.int8],
    indel: NDArray[np.int8],
) -> NDArray[np.int32]:
    """Integer cyclic costs of every query against every packed reference, shape ``(n_queries, n_blocks * LANES8)``.

    ``blocks``, ``blens`` and ``block_len`` come from
    :func:`fingerloc.align._kernels.pack_lanes` with ``lanes=LANES8``;
    ``sub`` and ``indel`` from :func:`integer_costs`. Entry
    ``[q, k * LANES8 + l]`` is ``scale`` times the cyclic cost of query ``q``
    against reference ``l`` of block ``k`` (minimum over every rotation of
    the query). The profiles are built for this call (:func:`pack_profiles`
    keeps them for repeated calls).
    """
    prof, pstart, prow, gsum, keep, short = _profiles(blocks, blens, block_len, sub, indel)
    pk = ProfileBlocks(prof, pstart, prow, gsum, keep, short, block_len, np.arange(0), indel, int(indel.max(initial=0)))
    return cyclic_i8_costs(qcodes, qoff, pk, workers=os.cpu_count() or 1)
