"""Compiled passes of exact retrieval: one call a step of a query, from stored arrays to one value a place.

Every function here gives, for each place asked, the least value over its
views of a per-view quantity (a bound or an exact cost), in one compiled
pass: no per-view temporaries handed back to Python, no packing in Python.
The views of the places are stored in the index's layout order
(:class:`fingerloc.terms.bounds.PlaceLayout`): place ``p`` holds the views
``place_start[p] .. place_start[p] + per_place[p] - 1``.

* :func:`count_place_min`: the letter-count bound of every view (twice the
  bound, integer units of the costs), least a place.
* :func:`l1_place_min`: the L1 distance of rounded range descriptors (steps),
  least a place.
* :func:`semiglobal_place_min`: the semi-global bound of the views of chosen
  groups (:mod:`fingerloc.align._bounds`), least a place.
* :func:`cyclic_place_min`: the exact integer cyclic cost of a query against
  the views of chosen places (the int8 kernel of
  :mod:`fingerloc.align._cyclic_int` on a profile of the query's own letters,
  the views gathered and packed inside the call), least a place.
* :func:`exact_l1_place_min`: the exact float64 L1 distance of range
  descriptors, summed bin after bin from 0 as ``scipy.spatial.distance.cdist``'s
  ``cityblock`` does, least a place.

A place without views gets :data:`NO_VIEW` (integer passes) or ``inf``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

from ..align._bounds import GROUP_LANES, _bounds, _count_bounds
from ..align._cyclic_int import LANES8, _costs_blocks, _profiles

__all__ = [
    "NO_VIEW",
    "QueryRows",
    "count_place_min",
    "count_place_min_narrow",
    "cyclic_place_min",
    "exact_l1_place_min",
    "l1_place_min",
    "letter_counts",
    "place_letter_counts",
    "query_rows",
    "scaled",
    "semiglobal_place_min",
    "unscored_mass",
]

#: The value of a place without views in the integer passes (larger than any bound or cost).
NO_VIEW = np.iinfo(np.int32).max


@njit(cache=True)
def scaled(least: NDArray[np.int64], unit: float) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """``least / unit`` (the integer passes' values in cost units), ``inf`` where ``least`` is :data:`NO_VIEW`."""
    out = np.empty(least.size)
    for i in range(least.size):
        out[i] = np.inf if least[i] == NO_VIEW else least[i] / unit
    return out


@njit(cache=True)
def unscored_mass(ub: NDArray[np.float64], level: NDArray[np.int8], top: float) -> float:  # pragma: no cover - compiled
    """``sum(exp(ub[i] - top))`` over the places not scored (``level[i] < 3``)."""
    total = 0.0
    for i in range(ub.size):
        if level[i] < 3:
            total += np.exp(ub[i] - top)
    return total


@njit(cache=True)
def _place_min(per_view: NDArray[np.integer], place_start: NDArray[np.int64], per_place: NDArray[np.int64]) -> NDArray[np.int64]:  # pragma: no cover - compiled
    out = np.empty(place_start.size, dtype=np.int64)
    for p in range(place_start.size):
        m = NO_VIEW
        a = place_start[p]
        for v in range(a, a + per_place[p]):
            m = min(m, per_view[v])
        out[p] = m
    return out


@njit(cache=True)
def letter_counts(codes: NDArray[np.uint8], off: NDArray[np.int64], n_letters: int) -> NDArray[np.uint16]:  # pragma: no cover - compiled
    """Occurrences of each letter in each string, shape ``(n_letters, n_strings)`` (strings shorter than 65,536 letters)."""
    n = off.size - 1
    out = np.zeros((n_letters, n), dtype=np.uint16)
    for v in range(n):
        for i in range(off[v], off[v + 1]):
            out[codes[i], v] += 1
    return out


@njit(cache=True)
def place_letter_counts(codes: NDArray[np.uint8], off: NDArray[np.int64], per_place: NDArray[np.int64], n_letters: int) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """Occurrences of each letter in the strings of each place (place ``p`` holds the next ``per_place[p]``), shape ``(P, n_letters)``."""
    out = np.zeros((per_place.size, n_letters))
    v = 0
    for p in range(per_place.size):
        for _ in range(per_place[p]):
            for i in range(off[v], off[v + 1]):
                out[p, codes[i]] += 1.0
            v += 1
    return out


@njit(cache=True)
def count_place_min(
    q: NDArray[np.int32],
    counts_t: NDArray[np.int16],
    letters: NDArray[np.int64],
    h2: NDArray[np.int32],
    c2: NDArray[np.int32],
    place_start: NDArray[np.int64],
    per_place: NDArray[np.int64],
) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """Each place's least letter-count bound over its views, shape ``(P,)``.

    ``counts_t[x, v]``: occurrences of letter ``x`` in view ``v`` (layout order); per view the bound is
    ``max(sum h2 |d|, sum c2 max(d, 0), sum c2 max(-d, 0))`` over ``letters``, ``d = q - counts``
    (twice the bound of :mod:`fingerloc.terms.bounds`, integer units of the costs).
    """
    per_view = np.empty(counts_t.shape[1], dtype=np.int32)
    _count_bounds(q, counts_t, letters, h2, c2, per_view)  # the per-view bound of fingerloc.align._bounds
    return _place_min(per_view, place_start, per_place)


@njit(cache=True)
def count_place_min_narrow(
    q: NDArray[np.int16],
    counts_t: NDArray[np.uint8],
    letters: NDArray[np.int64],
    h2: NDArray[np.int16],
    c2: NDArray[np.int16],
    place_start: NDArray[np.int64],
    per_place: NDArray[np.int64],
) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """:func:`count_place_min` in 16-bit lanes (twice as many a vector), for counts below 256.

    The caller checks that no sum can pass 32767: ``sum_x max(h2[x], c2[x]) max(q[x], most[x])``
    over ``letters``, ``most[x]`` the largest count of ``x`` in a view, is at most that.
    """
    nv = counts_t.shape[1]
    acc_h = np.zeros(nv, dtype=np.int16)
    acc_p = np.zeros(nv, dtype=np.int16)
    acc_n = np.zeros(nv, dtype=np.int16)
    zero = np.int16(0)
    for t in range(letters.shape[0]):
        x = letters[t]
        qx = q[x]
        hx = h2[x]
        cx = c2[x]
        row = counts_t[x]
        for i in range(nv):
            d = np.int16(qx - np.int16(row[i]))
            pos = max(d, zero)
            neg = max(np.int16(-d), zero)
            acc_h[i] = np.int16(acc_h[i] + np.int16(hx * np.int16(pos + neg)))
            acc_p[i] = np.int16(acc_p[i] + np.int16(cx * pos))
            acc_n[i] = np.int16(acc_n[i] + np.int16(cx * neg))
    for i in range(nv):
        acc_h[i] = max(acc_h[i], max(acc_p[i], acc_n[i]))  # the bound of each view
    return _place_min(acc_h, place_start, per_place)


@njit(cache=True)
def l1_place_min(
    desc_t: NDArray[np.uint16], q: NDArray[np.uint16], place_start: NDArray[np.int64], per_place: NDArray[np.int64]
) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """Each place's least ``sum_b |desc_t[b, v] - q[b]|`` over its views (layout order), in steps, shape ``(P,)``.

    Summed in 16-bit lanes: every entry at most ``65535 // desc_t.shape[0]`` (the caller's steps), so no sum wraps.
    """
    nv = desc_t.shape[1]
    acc = np.zeros(nv, dtype=np.uint16)
    for b in range(desc_t.shape[0]):
        row = desc_t[b]
        qb = q[b]
        for v in range(nv):
            x = row[v]
            acc[v] = np.uint16(acc[v] + np.uint16(max(x, qb) - min(x, qb)))
    return _place_min(acc, place_start, per_place)


@njit(cache=True)
def semiglobal_place_min(
    rows: NDArray[np.int64],
    gaps: NDArray[np.int32],
    groups: NDArray[np.int64],
    group_blocks: NDArray[np.int64],
    block_start: NDArray[np.int64],
    prof: NDArray[np.int8],
    pstart: NDArray[np.int64],
    block_len: NDArray[np.int64],
    gsum: NDArray[np.int32],
    n_rows: int,
    order: NDArray[np.int64],
    starts: NDArray[np.int64],
    place_start: NDArray[np.int64],
    per_place: NDArray[np.int64],
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:  # pragma: no cover - compiled
    """The places of ``groups`` (group after group, layout order) and each one's least semi-global bound.

    ``rows``/``gaps``: the query written twice, as profile rows and integer indels
    (:func:`fingerloc.align._bounds.semiglobal_bounds`); group ``g`` holds the blocks
    ``group_blocks[g] .. group_blocks[g + 1] - 1`` of the packed views, block ``b`` the views
    ``block_start[b] ..`` (at most ``GROUP_LANES``); ``order``/``starts``: the layout.
    """
    nb = 0
    n_places = 0
    for g in groups:
        nb += group_blocks[g + 1] - group_blocks[g]
        n_places += starts[g + 1] - starts[g]
    blocks = np.empty(nb, dtype=np.int64)
    i = 0
    for g in groups:
        for b in range(group_blocks[g], group_blocks[g + 1]):
            blocks[i] = b
            i += 1
    lanes = np.empty((nb, GROUP_LANES), dtype=np.int32)
    if nb:
        _bounds(rows, gaps, blocks, prof, pstart, block_len, gsum, n_rows, lanes, 0, 1)
    places = np.empty(n_places, dtype=np.int64)
    least = np.empty(n_places, dtype=np.int64)
    first = 0  # row of the group's first block in ``lanes``
    i = 0
    for g in groups:
        b0 = group_blocks[g]
        v0 = block_start[b0]
        for t in range(starts[g], starts[g + 1]):
            p = order[t]
            m = NO_VIEW
            for v in range(place_start[p], place_start[p] + per_place[p]):
                k = (v - v0) // GROUP_LANES
                m = min(m, lanes[first + k, v - block_start[b0 + k]])
            places[i] = p
            least[i] = m
            i += 1
        first += group_blocks[g + 1] - b0
    return places, least


class QueryRows(NamedTuple):
    """A query for :func:`cyclic_place_min`: its letters as rows of a profile of its own distinct letters (:func:`query_rows`)."""

    rows: NDArray[np.uint8]  # (n,): the profile row of each letter of the query
    indel: NDArray[np.int8]  # (n_rows,): the integer indel of each row's letter
    sub_rows: NDArray[np.int8]  # (n_rows, N_LETTERS): row r against every letter, as the profile builder wants it
    gmax: int  # the largest integer indel
    indel8: NDArray[np.int8]  # (N_LETTERS,): the integer indels


def query_rows(query: NDArray[np.uint8], sub8: NDArray[np.int8], indel8: NDArray[np.int8]) -> QueryRows:
    """The profile rows of a query (letter codes) for :func:`cyclic_place_min`; ``sub8``/``indel8`` from ``integer_costs``.

    Row ``r`` stands for the query's ``r``-th distinct letter ``L_r`` (ascending; letter 0 for an empty
    query) and is given ``s(L_r, b) - g(L_r) + g(r)``: the profile builder subtracts the indel of the row
    *index*, and the kernel gets the rows' own indels ``g(L_r)``.
    """
    letters, rows = np.unique(query, return_inverse=True)
    if letters.size == 0:
        letters = np.zeros(1, dtype=np.uint8)
    r = np.arange(letters.size)
    sub_rows = (sub8[letters].astype(np.int16) - indel8[letters][:, None] + indel8[r][:, None]).astype(np.int8)
    return QueryRows(rows.astype(np.uint8), indel8[letters].copy(), sub_rows, int(indel8.max(initial=0)), indel8)


def cyclic_place_min(
    query: QueryRows,
    codes: NDArray[np.uint8],
    off: NDArray[np.int64],
    place_start: NDArray[np.int64],
    per_place: NDArray[np.int64],
    places: NDArray[np.int64],
) -> NDArray[np.int64]:
    """Each of ``places``' least exact integer cyclic cost against ``query`` over its views, shape ``(len(places),)``.

    ``codes``/``off``: the views' letter codes (layout order). The same integers as the term's batch
    kernel (:func:`~fingerloc.align._cyclic_int.cyclic_i8_costs`), on the profile of the query's own
    letters (:func:`query_rows`). Three compiled calls (gather and pack the views, their profile, the
    kernel: those of :mod:`fingerloc.align._cyclic_int` called as they are, not compiled again into
    this module) and a fourth for the least a place.
    """
    blocks, blens, block_len, slot = _gather(codes, off, place_start, per_place, places)
    if slot.size == 0:
        return np.full(places.size, NO_VIEW, dtype=np.int64)
    prof, pstart, prow, gsum, keep, short = _profiles(blocks, blens, block_len, query.sub_rows, query.indel8)
    costs = np.empty((1, block_len.size * LANES8), dtype=np.int32)
    q = query.rows
    qoff = np.array([0, q.size], dtype=np.int64)
    _costs_blocks(q, qoff, q.size, prof, pstart, prow, gsum, keep, short, block_len, query.indel, query.gmax, costs, 0, 1)
    return _slot_min(costs[0], slot, per_place, places)


@njit(cache=True)
def _gather(
    codes: NDArray[np.uint8], off: NDArray[np.int64], place_start: NDArray[np.int64], per_place: NDArray[np.int64], places: NDArray[np.int64]
) -> tuple[NDArray[np.uint8], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:  # pragma: no cover - compiled
    """The views of ``places`` packed ``LANES8`` a block by length, as :func:`~fingerloc.align._kernels.pack_lanes` packs them."""
    nv = 0
    for p in places:
        nv += per_place[p]
    views = np.empty(nv, dtype=np.int64)
    lens = np.empty(nv, dtype=np.int64)
    i = 0
    maxlen = 0
    for p in places:
        for v in range(place_start[p], place_start[p] + per_place[p]):
            views[i] = v
            lens[i] = off[v + 1] - off[v]
            maxlen = max(maxlen, lens[i])
            i += 1
    # by length (a counting sort: lengths are small), so that a block's lanes end close together
    first = np.zeros(maxlen + 2, dtype=np.int64)
    for i in range(nv):
        first[lens[i] + 1] += 1
    for m in range(maxlen + 1):
        first[m + 1] += first[m]
    srt = np.empty(nv, dtype=np.int64)
    for i in range(nv):
        srt[first[lens[i]]] = i
        first[lens[i]] += 1
    nb = (nv + LANES8 - 1) // LANES8
    blocks = np.zeros((nb, maxlen, LANES8), dtype=np.uint8)
    blens = np.zeros((nb, LANES8), dtype=np.int64)
    slot = np.empty(nv, dtype=np.int64)
    for pos in range(nv):
        s = srt[pos]
        k = pos // LANES8
        lane = pos - k * LANES8
        slot[s] = pos
        v = views[s]
        blens[k, lane] = lens[s]
        for j in range(lens[s]):
            blocks[k, j, lane] = codes[off[v] + j]
    block_len = np.zeros(nb, dtype=np.int64)
    for k in range(nb):
        for lane in range(LANES8):
            block_len[k] = max(block_len[k], blens[k, lane])
    return blocks, blens, block_len, slot


@njit(cache=True)
def _slot_min(costs: NDArray[np.int32], slot: NDArray[np.int64], per_place: NDArray[np.int64], places: NDArray[np.int64]) -> NDArray[np.int64]:  # pragma: no cover - compiled
    out = np.empty(places.size, dtype=np.int64)
    i = 0
    for t in range(places.size):
        m = NO_VIEW
        for _ in range(per_place[places[t]]):
            m = min(m, costs[slot[i]])
            i += 1
        out[t] = m
    return out


@njit(cache=True)
def exact_l1_place_min(
    q: NDArray[np.float64], refs: NDArray[np.float64], first: NDArray[np.int64], per_place: NDArray[np.int64], places: NDArray[np.int64]
) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """Each of ``places``' least L1 distance from ``q`` to its rows of ``refs`` (rows ``first[p] ..``), float64.

    Each distance is ``|q[0] - r[0]| + |q[1] - r[1]| + ...`` summed in that order from 0.0, as
    ``cdist(..., metric="cityblock")``; ``inf`` for a place without rows.
    """
    out = np.empty(places.size)
    nb = q.size
    for t in range(places.size):
        p = places[t]
        m = np.inf
        for v in range(first[p], first[p] + per_place[p]):
            s = 0.0
            for b in range(nb):
                s += abs(q[b] - refs[v, b])
            m = min(m, s)
        out[t] = m
    return out
