"""Compiled passes of exact retrieval: one call a step of a query, from stored arrays to one value a place.

Every function here gives, for each place asked, the least value over its
views of a per-view quantity (a bound or an exact cost), in one compiled
pass: no per-view temporaries handed back to Python, no packing in Python.
The views of the places are stored in the index's layout order
(:class:`fingerloc.terms.bounds.PlaceLayout`): place ``p`` holds the views
``place_start[p] .. place_start[p] + per_place[p] - 1``.

* :func:`group_count_place_min`: the letter-count bound of every view with
  every potential of the letters' transport (twice the bound, integer units
  of the costs), least a place; :func:`count_place_min` (and its 16-bit
  :func:`count_place_min_narrow`) with three potentials, where the letters
  fall in too many groups.
* :func:`l1_place_min`: the L1 distance of rounded range descriptors (steps),
  least a place.
* :func:`semiglobal_cover` / :func:`semiglobal_views_min`: the semi-global
  bound of chosen places' views (:mod:`fingerloc.align._bounds`), their
  sub-blocks swept once a query (:class:`SweepState`), least a place;
  :func:`semiglobal_finer_min`: the larger of it and the reversed bound.
* :func:`cyclic_place_min`: the exact integer cyclic cost of a query against
  the views of chosen places (the int8 kernel of
  :mod:`fingerloc.align._cyclic_int` on a profile of the query's own letters,
  the views gathered and packed inside the call), least a place.
* :func:`exact_l1_place_min`: the exact float64 L1 distance of range
  descriptors, summed bin after bin from 0 as ``scipy.spatial.distance.cdist``'s
  ``cityblock`` does, least a place.

A place without views gets :data:`NO_VIEW` (integer passes) or ``inf``.
:func:`top_places`, :func:`open_places` and :func:`unscored_mass` are the
search's passes over every place's bound.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

from ..align._bounds import SUB_LANES, SubBlocks, _count_bounds, reversed_bound, sweep
from ..align._cyclic_int import LANES8, _costs_blocks, _profiles

__all__ = [
    "COUNT_GROUPS",
    "NO_VIEW",
    "QueryRows",
    "SweepState",
    "count_place_min",
    "count_place_min_narrow",
    "cyclic_place_min",
    "exact_l1_place_min",
    "group_count_place_min",
    "l1_place_min",
    "letter_counts",
    "neg_scaled",
    "open_places",
    "place_letter_counts",
    "query_rows",
    "scaled",
    "semiglobal_cover",
    "semiglobal_finer_min",
    "semiglobal_views_min",
    "top_places",
    "unscored_mass",
    "view_spans",
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
def neg_scaled(least: NDArray[np.int64], unit: float, lam: float, slack: float) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """``-lam * max(least / unit - slack, 0)`` (the ``exp`` likelihood of a lower bound on a distance), ``-inf`` at :data:`NO_VIEW`."""
    out = np.empty(least.size)
    for i in range(least.size):
        out[i] = -np.inf if least[i] == NO_VIEW else -lam * max(least[i] / unit - slack, 0.0)
    return out


#: Below the best score by more than this (nats), a place's bound counts as exp(-_FAR) in :func:`unscored_mass`.
_FAR = 60.0
#: Steps a nat of the table of :func:`unscored_mass`.
_STEPS = 64
#: ``exp(-k / _STEPS)`` for k = 0 .. _FAR * _STEPS.
_EXP_TABLE = np.exp(-np.arange(int(_FAR * _STEPS) + 1) / _STEPS)


@njit(cache=True)
def _unscored_mass(ub: NDArray[np.float64], level: NDArray[np.int8], top: float, scored: int, table: NDArray[np.float64]) -> float:  # pragma: no cover - compiled
    total = 0.0
    far = 0
    last = table.size - 1
    for i in range(ub.size):
        if level[i] < scored:
            d = ub[i] - top
            if d > 0.0:
                total += np.exp(d)
            else:
                k = int(-d * _STEPS)  # d in [-(k + 1) / steps, -k / steps]: exp(d) <= table[k]
                if k < last:
                    total += table[k]
                else:
                    far += 1
    return total + far * table[last]


def unscored_mass(ub: NDArray[np.float64], level: NDArray[np.int8], top: float, scored: int) -> float:
    """A bound on ``sum(exp(ub[i] - top))`` over the places not scored (``level[i] < scored``).

    Each term is bounded by ``exp`` of its exponent rounded up to a 64th (at most 1.6 % above it;
    a table, not an exponential a place), and bounds more than ``_FAR`` (60) nats below ``top``
    count ``exp(-60)`` each (less than 1e-26).
    """
    return float(_unscored_mass(ub, level, float(top), int(scored), _EXP_TABLE))


@njit(cache=True)
def top_places(ub: NDArray[np.float64], m: int) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """The ``m`` places of largest ``ub`` (a heap of ``m``: one pass, most places rejected by a comparison), best first."""
    n = ub.size
    m = min(m, n)
    if m <= 0:
        return np.zeros(0, dtype=np.int64)
    heap_v = np.empty(m)  # a min-heap of the m best values so far
    heap_i = np.empty(m, dtype=np.int64)
    size = 0
    for i in range(n):
        x = ub[i]
        if size < m:
            j = size
            size += 1
        elif x > heap_v[0]:
            j = 0  # replace the root, sift down
            while True:
                c = 2 * j + 1
                if c >= m:
                    break
                if c + 1 < m and heap_v[c + 1] < heap_v[c]:
                    c += 1
                if heap_v[c] >= x:
                    break
                heap_v[j] = heap_v[c]
                heap_i[j] = heap_i[c]
                j = c
            heap_v[j] = x
            heap_i[j] = i
            continue
        else:
            continue
        while j > 0:  # sift up the new leaf
            parent = (j - 1) // 2
            if heap_v[parent] <= x:
                break
            heap_v[j] = heap_v[parent]
            heap_i[j] = heap_i[parent]
            j = parent
        heap_v[j] = x
        heap_i[j] = i
    order = np.argsort(-heap_v[:size], kind="mergesort")
    return heap_i[:size][order]


@njit(cache=True)
def open_places(ub: NDArray[np.float64], level: NDArray[np.int8], cut: float, scored: int) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """``flatnonzero((level < scored) & (ub >= cut))``."""
    out = np.empty(ub.size, dtype=np.int64)
    n = 0
    for i in range(ub.size):
        if level[i] < scored and ub[i] >= cut:
            out[n] = i
            n += 1
    return out[:n].copy()


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


#: Most letter groups of :func:`group_count_place_min` (letters whose potentials all agree share a group).
COUNT_GROUPS = 4


@njit(cache=True)
def group_count_place_min(
    q: NDArray[np.int16],
    counts_t: NDArray[np.uint8],
    letters: NDArray[np.int64],
    group: NDArray[np.int64],
    vsum: NDArray[np.int16],
    qsum: NDArray[np.int16],
    ca: NDArray[np.int16],
    cb: NDArray[np.int16],
    const2: NDArray[np.int16],
    place_start: NDArray[np.int64],
    per_place: NDArray[np.int64],
) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """Each place's least letter-count bound over its views with ``K`` potentials, twice the bound, shape ``(P,)``.

    The potentials (:func:`fingerloc.terms.bounds.count_potentials`, integer units ``u``, ``w``) are
    the same for the letters of a group (``group[t]`` of ``letters[t]``, the letters the views use;
    at most :data:`COUNT_GROUPS`). With ``A_g = sum |q_x - v_x|`` and ``D_g = sum (q_x - v_x)`` over
    the letters of group ``g``, the letters in excess sum to ``(A_g + D_g) / 2`` in the query and
    ``(A_g - D_g) / 2`` in the view, so twice potential ``k``'s bound is ``const2[k] + sum_g
    ca[k, g] A_g + cb[k, g] D_g`` (``ca = u + w``, ``cb = u - w`` of the group; ``const2``: twice
    ``sum u q_x`` over the query's letters no view has): one pass over the counts for every ``A_g``,
    one pass a potential. ``vsum[g, v]``: the letters of group ``g`` in view ``v``; ``qsum[g]``: in
    the query. In 16-bit lanes: the caller checks that no sum can pass 32767. The bound of a view
    is the largest of its potentials' and 0.
    """
    nv = counts_t.shape[1]
    acc = np.zeros((COUNT_GROUPS, nv), dtype=np.int16)
    for t in range(letters.size):
        x = letters[t]
        qx = q[x]
        row = counts_t[x]
        ag = acc[group[t]]
        for i in range(nv):
            c = np.int16(row[i])
            ag[i] = np.int16(ag[i] + np.int16(max(qx, c) - min(qx, c)))
    a0, a1, a2, a3 = acc[0], acc[1], acc[2], acc[3]
    v0, v1, v2, v3 = vsum[0], vsum[1], vsum[2], vsum[3]
    best = np.zeros(nv, dtype=np.int16)
    for k in range(ca.shape[0]):  # D_g = qsum[g] - vsum[g, v]: the query's part is one number a potential
        p0, p1, p2, p3 = ca[k, 0], ca[k, 1], ca[k, 2], ca[k, 3]
        m0, m1, m2, m3 = cb[k, 0], cb[k, 1], cb[k, 2], cb[k, 3]
        base = np.int16(const2[k] + m0 * qsum[0] + m1 * qsum[1] + m2 * qsum[2] + m3 * qsum[3])
        for i in range(nv):
            b = np.int16(base + np.int16(p0 * a0[i]) + np.int16(p1 * a1[i]) + np.int16(p2 * a2[i]) + np.int16(p3 * a3[i]))
            b = np.int16(b - np.int16(m0 * v0[i]) - np.int16(m1 * v1[i]) - np.int16(m2 * v2[i]) - np.int16(m3 * v3[i]))
            best[i] = max(best[i], b)
    return _place_min(best, place_start, per_place)


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


class SweepState:
    """What one query's search has swept of the semi-global bound (:func:`semiglobal_cover`): the lanes of each sub-block."""

    def __init__(self, n_sub: int) -> None:
        self.lanes = np.empty(n_sub * SUB_LANES, dtype=np.int32)  # valid where swept_at > 0
        self.swept_at = np.zeros(n_sub, dtype=np.int32)  # the call that swept each sub-block; 0: not swept
        self.calls = 0
        #: the places the latest call covered and their least bounds (what :func:`semiglobal_views_min` reads first)
        self.covered: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None


@njit(cache=True)
def _new_subblocks(
    places: NDArray[np.int64], place_start: NDArray[np.int64], per_place: NDArray[np.int64], length: NDArray[np.int64],
    swept_at: NDArray[np.int32], call: int,
) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """The sub-blocks holding a view of ``places`` not swept yet, each once, shortest first; marked swept by ``call``."""
    nv = 0
    for p in places:
        nv += per_place[p]
    subs = np.empty(nv, dtype=np.int64)
    n = 0
    maxlen = 0
    for p in places:
        a = place_start[p]
        if per_place[p] == 0:
            continue
        for s in range(a // SUB_LANES, (a + per_place[p] - 1) // SUB_LANES + 1):
            if swept_at[s] == 0:
                swept_at[s] = call
                subs[n] = s
                n += 1
                maxlen = max(maxlen, length[s])
    first = np.zeros(maxlen + 2, dtype=np.int64)  # a counting sort on the lengths: sweeps of alike lengths
    for t in range(n):
        first[length[subs[t]] + 1] += 1
    for m in range(maxlen + 1):
        first[m + 1] += first[m]
    order = np.empty(n, dtype=np.int64)
    for t in range(n):
        m = length[subs[t]]
        order[first[m]] = subs[t]
        first[m] += 1
    return order


@njit(cache=True)
def _store(lanes: NDArray[np.int32], subs: NDArray[np.int64], out: NDArray[np.int32]) -> None:  # pragma: no cover - compiled
    flat = lanes.reshape(lanes.size)
    for t in range(subs.size):
        for k in range(SUB_LANES):
            out[subs[t] * SUB_LANES + k] = flat[t * SUB_LANES + k]


@njit(cache=True)
def _newly_covered(
    subs: NDArray[np.int64], view_place: NDArray[np.int32], view_span: NDArray[np.int32], swept_at: NDArray[np.int32], call: int,
    lanes: NDArray[np.int32],
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:  # pragma: no cover - compiled
    """The places whose views all lie in swept sub-blocks, one of them swept by ``call`` (``subs``: those), and their least lane.

    ``view_place``: the place of each view; ``view_span[v] = (first view, views)`` of its place,
    the first negated (-1 -) at the place's first view in each sub-block (the only view looked at).
    """
    nv = view_place.size
    out = np.empty(subs.size * SUB_LANES, dtype=np.int64)
    least = np.empty(subs.size * SUB_LANES, dtype=np.int64)
    n = 0
    for s in subs:
        lo = s * SUB_LANES
        for v in range(lo, min(nv, lo + SUB_LANES)):
            a = view_span[2 * v]
            if a >= 0:  # not the place's first view in this sub-block
                continue
            a = -1 - a
            m = view_span[2 * v + 1]
            whole = True
            for u in range(a // SUB_LANES, (a + m - 1) // SUB_LANES + 1):  # every sub-block swept, s the last this call swept
                x = swept_at[u]
                whole = whole and x > 0 and not (u > s and x == call)
            if whole:
                best = NO_VIEW
                for w in range(a, a + m):
                    best = min(best, int(lanes[w]))
                out[n] = view_place[v]
                least[n] = best
                n += 1
    return out[:n], least[:n]


def view_spans(place_start: NDArray[np.int64], per_place: NDArray[np.int64], n_views: int) -> NDArray[np.int32]:
    """:func:`_newly_covered`'s ``view_span`` (2 entries a view) for views in layout order (place ``p``: ``place_start[p] ..``)."""
    has = per_place > 0
    a, m = place_start[has], per_place[has]
    span = np.empty((n_views, 2), dtype=np.int64)
    order = np.argsort(a, kind="stable")  # the views of the places in layout order
    span[:, 0] = np.repeat(a[order], m[order])
    span[:, 1] = np.repeat(m[order], m[order])
    v = np.arange(n_views)
    head = v == np.maximum(span[:, 0], (v // SUB_LANES) * SUB_LANES)
    span[head, 0] = -1 - span[head, 0]
    return span.reshape(-1).astype(np.int32)


@njit(cache=True)
def _cached_place_min(
    lanes: NDArray[np.int32], swept_at: NDArray[np.int32], places: NDArray[np.int64], place_start: NDArray[np.int64], per_place: NDArray[np.int64]
) -> tuple[NDArray[np.int64], bool]:  # pragma: no cover - compiled
    """Each place's least lane over its views, and whether every view was swept (else the values are not all valid)."""
    out = np.empty(places.size, dtype=np.int64)
    ok = True
    for i in range(places.size):
        p = places[i]
        m = NO_VIEW
        for v in range(place_start[p], place_start[p] + per_place[p]):
            ok = ok and swept_at[v // SUB_LANES] > 0
            m = min(m, int(lanes[v]))
        out[i] = m
    return out, ok


def semiglobal_cover(
    query: tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.int64]],
    sb: SubBlocks,
    state: SweepState,
    places: NDArray[np.int64],
    place_start: NDArray[np.int64],
    per_place: NDArray[np.int64],
    place_of_view: NDArray[np.int32],
    view_span: NDArray[np.int32],
) -> NDArray[np.int64]:
    """Sweep the sub-blocks of ``places``' views not swept yet; the places whose bounds that completed.

    ``query``: :func:`~fingerloc.align._bounds.query_profile_rows`; ``sb``: the views packed in
    sub-blocks in layout order (place ``p`` holds the views ``place_start[p] ..``,
    ``place_of_view`` the place of each view, ``view_span`` from :func:`view_spans`). Only the sub-blocks
    (:data:`~fingerloc.align._bounds.SUB_LANES` views) holding a view of ``places`` are swept,
    shortest together (:func:`~fingerloc.align._bounds.sweep_subblocks`), each once a query: their
    lanes are kept in ``state``. The places returned are those whose every view is now swept and
    was not before (``places`` among them, unless swept before): :func:`semiglobal_views_min` reads
    their bounds.
    """
    state.calls += 1
    subs = _new_subblocks(np.ascontiguousarray(places, dtype=np.int64), place_start, per_place, sb.length, state.swept_at, state.calls)
    if subs.size == 0:
        state.covered = None
        return np.zeros(0, dtype=np.int64)
    _store(sweep(query, sb, subs), subs, state.lanes)
    covered, least = _newly_covered(np.sort(subs), place_of_view, view_span, state.swept_at, state.calls, state.lanes)  # memory in order
    state.covered = (covered, least)
    return covered


def semiglobal_views_min(
    query: tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.int64]],
    sb: SubBlocks,
    state: SweepState,
    places: NDArray[np.int64],
    place_start: NDArray[np.int64],
    per_place: NDArray[np.int64],
    place_of_view: NDArray[np.int32],
    view_span: NDArray[np.int32],
) -> NDArray[np.int64]:
    """Each of ``places``' least semi-global bound over its views, shape ``(len(places),)`` (:data:`NO_VIEW`: no view).

    Sweeps what :func:`semiglobal_cover` has not swept yet (``state``), then reads the lanes.
    """
    places = np.ascontiguousarray(places, dtype=np.int64)
    if state.covered is not None and np.array_equal(state.covered[0], places):  # those the latest sweep covered
        return state.covered[1]
    least, ok = _cached_place_min(state.lanes, state.swept_at, places, place_start, per_place)
    if ok:
        return least
    semiglobal_cover(query, sb, state, places, place_start, per_place, place_of_view, view_span)
    return _cached_place_min(state.lanes, state.swept_at, places, place_start, per_place)[0]


@njit(cache=True)
def _views_of(places: NDArray[np.int64], place_start: NDArray[np.int64], per_place: NDArray[np.int64]) -> NDArray[np.int64]:  # pragma: no cover - compiled
    n = 0
    for p in places:
        n += per_place[p]
    out = np.empty(n, dtype=np.int64)
    i = 0
    for p in places:
        for v in range(place_start[p], place_start[p] + per_place[p]):
            out[i] = v
            i += 1
    return out


@njit(cache=True)
def _max_place_min(
    lanes: NDArray[np.int32], rev: NDArray[np.int32], places: NDArray[np.int64], place_start: NDArray[np.int64], per_place: NDArray[np.int64]
) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """Each place's least ``max(lanes[v], rev[i])`` over its views (``rev`` in the order of :func:`_views_of`)."""
    out = np.empty(places.size, dtype=np.int64)
    i = 0
    for t in range(places.size):
        p = places[t]
        m = NO_VIEW
        for v in range(place_start[p], place_start[p] + per_place[p]):
            m = min(m, int(max(lanes[v], rev[i])))
            i += 1
        out[t] = m
    return out


def semiglobal_finer_min(
    query: tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.int64]],
    sb: SubBlocks,
    state: SweepState,
    codes: NDArray[np.uint8],
    off: NDArray[np.int64],
    places: NDArray[np.int64],
    place_start: NDArray[np.int64],
    per_place: NDArray[np.int64],
    place_of_view: NDArray[np.int32],
    view_span: NDArray[np.int32],
) -> NDArray[np.int64]:
    """Each of ``places``' least, over its views, of the larger of the two semi-global bounds, shape ``(len(places),)``.

    The view whole against the query twice (:func:`semiglobal_views_min`, swept as needed) and the
    query whole against the view twice (:func:`~fingerloc.align._bounds.reversed_bound`): each lets
    the other string's surplus letters go free, both are at most the cyclic cost, and together they
    come close to it.
    """
    places = np.ascontiguousarray(places, dtype=np.int64)
    if not _cached_place_min(state.lanes, state.swept_at, places, place_start, per_place)[1]:
        semiglobal_cover(query, sb, state, places, place_start, per_place, place_of_view, view_span)
    views = _views_of(places, place_start, per_place)
    rev = reversed_bound(query, sb, codes, off, views) if views.size else np.zeros(0, dtype=np.int32)
    return _max_place_min(state.lanes, rev, places, place_start, per_place)


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
