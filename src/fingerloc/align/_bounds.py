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
the four: a pass about 20 % faster than with two). With a free start the
first column is ``D[i, 0] = 0``, so each row starts with ``U[i, 0] = -g(a_i)``.
The free end needs ``D[i, m_k]`` of every row: every reference of a sweep is
padded to the sweep's longest with a *wildcard* that costs nothing to pair or
to leave out. Wildcards at the end of ``b`` can only swallow a suffix of the
substring of ``aa``, which the free end drops anyway, so the padded
reference has the same bound, and every lane ends at the same column:
``D[i, M] = D[i-1, M] + U[i, M] + g(a_i)``, summed down the rows from
``D[0, M] = sum g(b)``. The bound is ``min_i D[i, M]``, in the integer
units of :func:`~fingerloc.align._cyclic_int.integer_costs`.

**Sub-blocks, gathered.** The references are stored in the caller's order
(an index keeps places that look alike side by side) in *sub-blocks* of
``SUB_LANES`` (8) references: their letter codes column after column, one
64-bit word a column, padded with the wildcard to the sub-block's longest.
A sweep gathers any ``SUBS`` (8) sub-blocks, so that only the references a
search needs are bounded, and builds their substitution profile
``s'(c, b) = s(c, b) - g(c) - g(b)`` for the rows of the query's letters
(each bound runs many query rows of one letter, so the profile is built
once a letter and a sweep, not stored: 64 bytes a letter where the codes
take one). The profile is computed, not looked up: ``s'(c, b) = alpha(c) + sum_e
delta_e(c) [b == x_e(c)]``, the row's most common value and the few letters
``x_e(c)`` (and the wildcard) that differ from it (the letter itself, ``n``
whose indel is half, and with feature-aware costs the letter's neighbours),
so that the build is a few compare-and-add passes over the lanes. Query letters
alike against every letter the references use (the same costs, the same
indel) share one row: a laser-only map needs about 19 rows of the
alphabet's 34.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["GROUP_LANES", "SUBS", "SUB_LANES", "SubBlocks", "pack_subblocks", "query_profile_rows", "reversed_bound", "semiglobal_bounds"]

#: References side by side in a sweep of the kernel (two AVX-512 registers of int8: at 64 the sweep waits on its dependency chains).
GROUP_LANES = 128
#: References of a sub-block: the unit in which references are stored and gathered (one 64-bit word a column).
SUB_LANES = 8
#: Sub-blocks a sweep.
SUBS = GROUP_LANES // SUB_LANES


class SubBlocks(NamedTuple):
    """References packed in sub-blocks for :func:`sweep_subblocks` (:func:`pack_subblocks`).

    The profile of row ``r`` against letter code ``b`` (the wildcard: code ``wild_code``) is
    ``alpha[r] + sum_e exc_delta[r, e] * (b == exc_code[r, e])`` over ``e < n_exc[r]``.
    """

    codes: NDArray[np.uint8]  # flat; sub-block s at start[s]: (length[s], SUB_LANES), column after column
    start: NDArray[np.int64]  # (n_sub + 1,): multiples of SUB_LANES
    length: NDArray[np.int64]  # (n_sub,): the longest reference of each sub-block
    gsum: NDArray[np.int32]  # (n_sub, SUB_LANES): sum of the indels of each reference, D[0, m_k]
    row_of: NDArray[np.int64]  # (N_LETTERS,): the profile row of each query letter
    indel: NDArray[np.int8]  # (N_LETTERS,): the integer indels
    alpha: NDArray[np.int8]  # (n_rows,)
    exc_code: NDArray[np.uint8]  # (n_rows, most exceptions)
    exc_delta: NDArray[np.int8]  # (n_rows, most exceptions)
    n_exc: NDArray[np.int64]  # (n_rows,)
    n_rows: int
    wild_code: int


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


def _mode(values: NDArray[np.int64]) -> int:
    """The most frequent value (the least of the tied), 0 of none."""
    if values.size == 0:
        return 0
    vals, counts = np.unique(values, return_counts=True)
    return int(vals[int(np.argmax(counts))])


def _decompose(
    rep: NDArray[np.int64], used: NDArray[np.int64], sub: NDArray[np.int8], indel: NDArray[np.int8]
) -> tuple[NDArray[np.int8], NDArray[np.uint8], NDArray[np.int8], NDArray[np.int64]]:
    """``s'(c, b) = alpha[row] + exceptions`` for the rows' letters ``rep`` against the ``used`` letters and the wildcard.

    ``alpha``: a row's most common value over those letters (the wildcard's ``-g(c)`` among them).
    Returns alpha and each row's exceptions (codes, deltas, count); the wildcard's code is ``len(indel)``.
    """
    wild = sub.shape[0]
    vals = sub[np.ix_(rep, used)].astype(np.int64) - indel[rep].astype(np.int64)[:, None] - indel[used].astype(np.int64)[None, :]
    vals = np.hstack([vals, -indel[rep].astype(np.int64)[:, None]])  # the wildcard costs nothing: s' = -g(c)
    codes_all = [*used.tolist(), wild]
    alpha = np.array([_mode(v) for v in vals], dtype=np.int64)
    codes = [[b for b, v in zip(codes_all, row.tolist(), strict=True) if v != a] for row, a in zip(vals, alpha.tolist(), strict=True)]
    deltas = [[v - a for v in row.tolist() if v != a] for row, a in zip(vals, alpha.tolist(), strict=True)]
    most = max((len(c) for c in codes), default=0)
    exc_code = np.zeros((len(codes), max(most, 1)), dtype=np.uint8)
    exc_delta = np.zeros((len(codes), max(most, 1)), dtype=np.int8)
    for r, (cs, ds) in enumerate(zip(codes, deltas, strict=True)):
        exc_code[r, : len(cs)] = cs
        exc_delta[r, : len(ds)] = ds
    n_exc = np.array([len(c) for c in codes], dtype=np.int64)
    return alpha.astype(np.int8), exc_code, exc_delta, n_exc


@njit(cache=True)
def _pack(
    codes: NDArray[np.uint8], off: NDArray[np.int64], indel: NDArray[np.int8], wild: int
) -> tuple[NDArray[np.uint8], NDArray[np.int64], NDArray[np.int64], NDArray[np.int32]]:  # pragma: no cover - compiled
    n_refs = off.size - 1
    n_sub = (n_refs + SUB_LANES - 1) // SUB_LANES
    length = np.zeros(n_sub, dtype=np.int64)
    start = np.zeros(n_sub + 1, dtype=np.int64)
    for s in range(n_sub):
        for r in range(s * SUB_LANES, min(n_refs, (s + 1) * SUB_LANES)):
            length[s] = max(length[s], off[r + 1] - off[r])
        start[s + 1] = start[s] + length[s] * SUB_LANES
    out = np.full(start[n_sub], wild, dtype=np.uint8)
    gsum = np.zeros((n_sub, SUB_LANES), dtype=np.int32)
    for r in range(n_refs):
        s, lane = r // SUB_LANES, r % SUB_LANES
        for j in range(off[r + 1] - off[r]):
            b = codes[off[r] + j]
            out[start[s] + j * SUB_LANES + lane] = b
            gsum[s, lane] += indel[b]
    return out, start, length, gsum


def pack_subblocks(
    codes: NDArray[np.uint8], off: NDArray[np.int64], sub8: NDArray[np.int8], indel8: NDArray[np.int8]
) -> SubBlocks:
    """Pack references for :func:`sweep_subblocks`: sub-block ``s`` holds references ``8 s .. 8 s + 7`` in order.

    ``codes``/``off`` from :func:`~fingerloc.align._encode.encode_many`; ``sub8``/``indel8`` from
    :func:`~fingerloc.align._cyclic_int.integer_costs`.
    """
    row_of, rep = _letter_rows(codes, sub8, indel8)
    used = (np.unique(codes) if codes.size else np.zeros(0, dtype=np.uint8)).astype(np.int64)
    alpha, exc_code, exc_delta, n_exc = _decompose(rep, used, sub8, indel8)
    wild = int(sub8.shape[0])
    packed, start, length, gsum = _pack(codes, np.ascontiguousarray(off, dtype=np.int64), indel8, wild)
    return SubBlocks(packed, start, length, gsum, row_of, indel8.copy(), alpha, exc_code, exc_delta, n_exc, int(rep.size), wild)


@njit(cache=True, nogil=True)
def _sweep(
    rows: NDArray[np.int64],
    gaps: NDArray[np.int32],
    pb: NDArray[np.int8],
    big: int,
    gs: NDArray[np.int32],
    out: NDArray[np.int32],
    hv: NDArray[np.int8],
    u1: NDArray[np.int8],
    u2: NDArray[np.int8],
    u3: NDArray[np.int8],
    u4: NDArray[np.int8],
    dl: NDArray[np.int32],
    best: NDArray[np.int32],
) -> None:  # pragma: no cover - compiled
    """One block: the bound of each of its ``GROUP_LANES`` references into ``out``.

    ``pb``: the block's profile, shape ``(profile rows, big, GROUP_LANES)``; ``rows`` index its first axis;
    ``gs``: each lane's sum of indels, ``D[0, M]``. ``hv`` (at least ``big`` rows) and the lane vectors are
    scratch space of the caller.
    """
    nrow = rows.shape[0]
    for k in range(GROUP_LANES):
        dl[k] = gs[k]  # D[0, M]: the whole reference deleted
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
        out[k] = best[k]


@njit(cache=True)
def _build(
    cc: NDArray[np.uint8],
    big: int,
    used: NDArray[np.int64],
    alpha: NDArray[np.int8],
    exc_code: NDArray[np.uint8],
    exc_delta: NDArray[np.int8],
    n_exc: NDArray[np.int64],
    pb: NDArray[np.int8],
) -> None:  # pragma: no cover - compiled
    """The profile rows ``used`` of a sweep's codes ``cc`` (its first ``big`` columns) into ``pb``, shape ``(len(used), big, GROUP_LANES)``."""
    for r in range(used.size):
        row = used[r]
        a = alpha[row]
        p = pb[r]
        for j in range(big):
            for k in range(GROUP_LANES):
                p[j, k] = a
        for e in range(n_exc[row]):
            x = exc_code[row, e]
            d = exc_delta[row, e]
            for j in range(big):
                for k in range(GROUP_LANES):
                    p[j, k] = np.int8(p[j, k] + (d if cc[j, k] == x else np.int8(0)))


@njit(cache=True)
def sweep_subblocks(
    rows: NDArray[np.int64],
    gaps: NDArray[np.int32],
    used: NDArray[np.int64],
    subs: NDArray[np.int64],
    codes: NDArray[np.uint8],
    start: NDArray[np.int64],
    length: NDArray[np.int64],
    gsum: NDArray[np.int32],
    alpha: NDArray[np.int8],
    exc_code: NDArray[np.uint8],
    exc_delta: NDArray[np.int8],
    n_exc: NDArray[np.int64],
    wild_code: int,
) -> NDArray[np.int32]:  # pragma: no cover - compiled
    """The bounds of the references of sub-blocks ``subs``, ``SUBS`` sub-blocks a sweep, shape ``(ceil(len(subs) / SUBS), GROUP_LANES)``.

    Row ``c`` of the result holds ``subs[c * SUBS : (c + 1) * SUBS]`` side by side (lane
    ``w * SUB_LANES + l``: reference ``l`` of the ``w``-th); lanes of a missing sub-block (past the
    end of ``subs``) or an empty lane are not meaningful. ``rows`` index ``used``, the profile rows of
    the query's letters (:func:`query_profile_rows`); the other arrays are those of :class:`SubBlocks`.
    """
    n_sub = subs.size
    n_chunks = (n_sub + SUBS - 1) // SUBS
    out = np.empty((n_chunks, GROUP_LANES), dtype=np.int32)
    maxlen = 1
    for t in range(n_sub):
        maxlen = max(maxlen, length[subs[t]])
    nu = used.size
    cc = np.empty(maxlen * GROUP_LANES, dtype=np.uint8)
    cc64 = cc.view(np.int64)
    codes64 = codes.view(np.int64)
    fill = np.full(SUB_LANES, wild_code, dtype=np.uint8)
    wild_c = fill.view(np.int64)[0]
    scratch = np.empty(max(nu, 1) * maxlen * GROUP_LANES, dtype=np.int8)
    gs = np.zeros(GROUP_LANES, dtype=np.int32)
    hv = np.empty((maxlen, GROUP_LANES), dtype=np.int8)
    u1 = np.empty(GROUP_LANES, dtype=np.int8)
    u2 = np.empty(GROUP_LANES, dtype=np.int8)
    u3 = np.empty(GROUP_LANES, dtype=np.int8)
    u4 = np.empty(GROUP_LANES, dtype=np.int8)
    dl = np.empty(GROUP_LANES, dtype=np.int32)
    best = np.empty(GROUP_LANES, dtype=np.int32)
    for c in range(n_chunks):
        lo = c * SUBS
        hi = min(lo + SUBS, n_sub)
        big = 1
        for t in range(lo, hi):
            big = max(big, length[subs[t]])
        for w in range(SUBS):  # the codes of the sweep, column j at words j * SUBS ..
            m = 0
            if lo + w < hi:
                s = subs[lo + w]
                m = length[s]
                a = start[s] // SUB_LANES
                for j in range(m):
                    cc64[j * SUBS + w] = codes64[a + j]
                for k in range(SUB_LANES):
                    gs[w * SUB_LANES + k] = gsum[s, k]
            else:
                for k in range(SUB_LANES):
                    gs[w * SUB_LANES + k] = 0
            for j in range(m, big):
                cc64[j * SUBS + w] = wild_c
        pb = scratch[: nu * big * GROUP_LANES].reshape((nu, big, GROUP_LANES))
        _build(cc[: big * GROUP_LANES].reshape((big, GROUP_LANES)), big, used, alpha, exc_code, exc_delta, n_exc, pb)
        _sweep(rows, gaps, pb, big, gs, out[c], hv, u1, u2, u3, u4, dl, best)
    return out


@njit(cache=True, nogil=True)
def _sweep_rev(
    cls: NDArray[np.int64],
    pb: NDArray[np.int8],
    nrows: int,
    rowgap: NDArray[np.int8],
    valid: NDArray[np.int64],
    gs0: int,
    out: NDArray[np.int32],
    hv: NDArray[np.int8],
    u1: NDArray[np.int8],
    u2: NDArray[np.int8],
    u3: NDArray[np.int8],
    u4: NDArray[np.int8],
    dl: NDArray[np.int32],
    best: NDArray[np.int32],
) -> None:  # pragma: no cover - compiled
    """The reversed bound of one sweep: the query whole (columns) against any substring of each reference written twice (rows).

    ``pb``: the profile ``s'(y, a)`` of the rows' letters ``y`` (per lane, shape ``(profile rows, nrows,
    GROUP_LANES)``) for each of the query's letter classes; ``cls``: the class of each query letter;
    ``rowgap[i, k]``: ``g`` of lane ``k``'s row ``i``; ``valid[k]``: the rows of lane ``k`` (its
    reference twice, less one); ``gs0``: ``D[0, n]``, every query letter deleted.
    """
    n = cls.shape[0]
    for k in range(GROUP_LANES):
        dl[k] = gs0
        best[k] = gs0  # the empty substring
    for j in range(n):
        for k in range(GROUP_LANES):
            hv[j, k] = 0  # row 0: D[0, j+1] - D[0, j] = g(a_j)
    i = 0
    while i + 4 <= nrows:
        g1 = rowgap[i]
        g2 = rowgap[i + 1]
        g3 = rowgap[i + 2]
        g4 = rowgap[i + 3]
        for k in range(GROUP_LANES):
            u1[k] = -g1[k]  # free start: D[i, 0] = 0, so U[i, 0] = -g(y_i)
            u2[k] = -g2[k]
            u3[k] = -g3[k]
            u4[k] = -g4[k]
        for j in range(n):
            c = cls[j]
            p1 = pb[c, i]
            p2 = pb[c, i + 1]
            p3 = pb[c, i + 2]
            p4 = pb[c, i + 3]
            for k in range(GROUP_LANES):
                h = hv[j, k]
                x = u1[k]
                z = min(min(p1[k], h), x)
                u1[k] = np.int8(z - h)
                h = np.int8(z - x)
                x = u2[k]
                z = min(min(p2[k], h), x)
                u2[k] = np.int8(z - h)
                h = np.int8(z - x)
                x = u3[k]
                z = min(min(p3[k], h), x)
                u3[k] = np.int8(z - h)
                h = np.int8(z - x)
                x = u4[k]
                z = min(min(p4[k], h), x)
                u4[k] = np.int8(z - h)
                hv[j, k] = np.int8(z - x)
        for k in range(GROUP_LANES):  # D[i, n] = D[i-1, n] + U[i, n] + g(y_i), the least over the lane's rows
            dl[k] += u1[k] + g1[k]
            if i < valid[k]:
                best[k] = min(best[k], dl[k])
            dl[k] += u2[k] + g2[k]
            if i + 1 < valid[k]:
                best[k] = min(best[k], dl[k])
            dl[k] += u3[k] + g3[k]
            if i + 2 < valid[k]:
                best[k] = min(best[k], dl[k])
            dl[k] += u4[k] + g4[k]
            if i + 3 < valid[k]:
                best[k] = min(best[k], dl[k])
        i += 4
    while i < nrows:
        g1 = rowgap[i]
        for k in range(GROUP_LANES):
            u1[k] = -g1[k]
        for j in range(n):
            p1 = pb[cls[j], i]
            for k in range(GROUP_LANES):
                h = hv[j, k]
                x = u1[k]
                z = min(min(p1[k], h), x)
                u1[k] = np.int8(z - h)
                hv[j, k] = np.int8(z - x)
        for k in range(GROUP_LANES):
            dl[k] += u1[k] + g1[k]
            if i < valid[k]:
                best[k] = min(best[k], dl[k])
        i += 1
    for k in range(GROUP_LANES):
        out[k] = best[k]


@njit(cache=True)
def reversed_bounds(
    rows: NDArray[np.int64],
    gaps: NDArray[np.int32],
    used: NDArray[np.int64],
    codes: NDArray[np.uint8],
    off: NDArray[np.int64],
    views: NDArray[np.int64],
    indel: NDArray[np.int8],
    alpha: NDArray[np.int8],
    exc_code: NDArray[np.uint8],
    exc_delta: NDArray[np.int8],
    n_exc: NDArray[np.int64],
    wild_code: int,
) -> NDArray[np.int32]:  # pragma: no cover - compiled
    """The reversed semi-global bound of the query against each of ``views``, shape ``(len(views),)``, integer units.

    The query (its rows, indels and used profile rows from :func:`query_profile_rows`: the first
    ``n`` of the rows are the query itself) aligned whole against any substring of the view written
    twice: at most the cyclic cost too (a rotation of the view is such a substring), and large where
    the view has letters the query has not, where :func:`sweep_subblocks`' bound (the view whole
    against the query twice) lets the query's surplus go free. ``codes``/``off``: the views' letter
    codes; ``indel``: the integer indel of each letter; the profile
    arrays are those of :class:`SubBlocks`. The views are swept ``GROUP_LANES`` at a time, by length.
    """
    n = (rows.size + 1) // 2
    cls = rows[:n].copy()
    gs0 = 0
    for j in range(n):
        gs0 += gaps[j]
    nv = views.size
    lens = np.empty(nv, dtype=np.int64)
    maxlen = 1
    for t in range(nv):
        lens[t] = off[views[t] + 1] - off[views[t]]
        maxlen = max(maxlen, lens[t])
    order = np.argsort(lens, kind="mergesort")
    out = np.empty(nv, dtype=np.int32)
    nr_max = 2 * maxlen - 1
    nu = used.size
    cc = np.empty((nr_max, GROUP_LANES), dtype=np.uint8)
    rowgap = np.empty((nr_max, GROUP_LANES), dtype=np.int8)
    scratch = np.empty(max(nu, 1) * nr_max * GROUP_LANES, dtype=np.int8)
    valid = np.empty(GROUP_LANES, dtype=np.int64)
    lanes = np.empty(GROUP_LANES, dtype=np.int32)
    hv = np.empty((max(n, 1), GROUP_LANES), dtype=np.int8)
    u1 = np.empty(GROUP_LANES, dtype=np.int8)
    u2 = np.empty(GROUP_LANES, dtype=np.int8)
    u3 = np.empty(GROUP_LANES, dtype=np.int8)
    u4 = np.empty(GROUP_LANES, dtype=np.int8)
    dl = np.empty(GROUP_LANES, dtype=np.int32)
    best = np.empty(GROUP_LANES, dtype=np.int32)
    for lo in range(0, nv, GROUP_LANES):
        hi = min(nv, lo + GROUP_LANES)
        big = 1
        for t in range(lo, hi):
            big = max(big, lens[order[t]])
        nr = 2 * big - 1
        for i in range(nr):
            for k in range(GROUP_LANES):
                cc[i, k] = wild_code
                rowgap[i, k] = 0
        for k in range(GROUP_LANES):
            m = lens[order[lo + k]] if lo + k < hi else 0
            valid[k] = 2 * m - 1
            if m == 0:
                continue
            a = off[views[order[lo + k]]]
            for i in range(2 * m - 1):  # the view, then the view again less its last letter
                b = codes[a + i if i < m else a + i - m]
                cc[i, k] = b
                rowgap[i, k] = indel[b]
        pb = scratch[: nu * nr * GROUP_LANES].reshape((nu, nr, GROUP_LANES))
        _build(cc[:nr], nr, used, alpha, exc_code, exc_delta, n_exc, pb)
        _sweep_rev(cls, pb, nr, rowgap, valid, gs0, lanes, hv, u1, u2, u3, u4, dl, best)
        for t in range(lo, hi):
            out[order[t]] = lanes[t - lo]
    return out


def query_profile_rows(query: NDArray[np.uint8], sb: SubBlocks) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.int64]]:
    """The query written twice as :func:`sweep_subblocks` wants it: each row's index into ``used``, its integer indel, and ``used``.

    ``used``: the profile rows (:attr:`SubBlocks.row_of`) of the query's letters, ascending.
    """
    n = int(query.size)
    aa = np.concatenate([query, query[: max(n - 1, 0)]]).astype(np.int64)
    used, rows = np.unique(sb.row_of[aa], return_inverse=True)
    return rows.astype(np.int64).reshape(-1), sb.indel[aa].astype(np.int32), used.astype(np.int64)


def sweep(query: tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.int64]], sb: SubBlocks, subs: NDArray[np.int64]) -> NDArray[np.int32]:
    """:func:`sweep_subblocks` of a query (:func:`query_profile_rows`) on the sub-blocks ``subs`` of ``sb``."""
    rows, gaps, used = query
    return sweep_subblocks(
        rows, gaps, used, np.ascontiguousarray(subs, dtype=np.int64), sb.codes, sb.start, sb.length, sb.gsum,
        sb.alpha, sb.exc_code, sb.exc_delta, sb.n_exc, sb.wild_code,
    )


def reversed_bound(
    query: tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.int64]],
    sb: SubBlocks,
    codes: NDArray[np.uint8],
    off: NDArray[np.int64],
    views: NDArray[np.int64],
) -> NDArray[np.int32]:
    """:func:`reversed_bounds` of a query (:func:`query_profile_rows`) against ``views`` of ``codes``/``off``, the profile of ``sb``."""
    rows, gaps, used = query
    return reversed_bounds(
        rows, gaps, used, codes, off, np.ascontiguousarray(views, dtype=np.int64), sb.indel, sb.alpha, sb.exc_code, sb.exc_delta,
        sb.n_exc, sb.wild_code,
    )


def semiglobal_bounds(query: NDArray[np.uint8], sb: SubBlocks) -> NDArray[np.int32]:
    """Lower bounds (integer units) on the cyclic cost of ``query`` against every reference of ``sb``, shape ``(n_refs,)``.

    ``query``: letter codes (:func:`~fingerloc.align._encode.encode`); references in the order packed
    (empty lanes of the last sub-block at the end).
    """
    n_sub = sb.gsum.shape[0]
    if n_sub == 0:
        return np.empty(0, dtype=np.int32)
    lanes = sweep(query_profile_rows(query, sb), sb, np.arange(n_sub, dtype=np.int64))
    return lanes.reshape(-1)[: n_sub * SUB_LANES]


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
