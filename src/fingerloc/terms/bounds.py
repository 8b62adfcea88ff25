"""Upper bounds on each term's log-likelihood at places, from cheap and loose to dear and tight.

Exact retrieval (:mod:`fingerloc.retrieval`) scores a place in full only when
an upper bound on its joint log-likelihood could still change the answer.
Each term gives up to four levels of bound, over a :class:`PlaceLayout`
(the places in an order that keeps look-alikes side by side):

=========  =========================================  ==============================================
level      ``Fp`` (cyclic, integer costs)             ``R``; mixtures and other terms
=========  =========================================  ==============================================
coarse     letter counts (below) with every           ``R``: the L1 distance to each view, its
(every     potential of :func:`count_potentials`,     descriptor rounded to 1/(65535 // bins) (less
place)     one pass over 8-bit counts and one a       bins/steps + 2e-9, both roundings); others:
           potential                                  the exact log-likelihood of every place
fine       the semi-global bound of                   (none finer)
           :mod:`fingerloc.align._bounds`: the view
           whole against any substring of the query
           written twice (its sub-blocks swept once
           a query, 7 % of the cyclic cost's work)
finer      the larger of that and the query whole     (none finer)
           against the view written twice: together
           within a few percent of the cyclic cost
=========  =========================================  ==============================================

Without integer costs the fine bound of ``Fp`` is its exact cost; with a
partial field of view (no cyclic matching) every bound of ``Fp`` is.

The letter-count bound: let ``e_a(x) = max(0, n_a(x) - n_b(x))`` be the letters
``x`` of ``a`` that no equal letter of ``b`` can match (``e_b`` likewise). In any
alignment each of them is left out (cost ``g(x)``) or paired with another
letter (cost ``s(x, y)``), so with ``c(x) = min(g(x), min_{y != x} s(x, y))``
the cost is at least ``sum_x c(x) e_a(x)`` and ``sum_x c(x) e_b(x)``, and,
splitting a pair's cost between its two letters, ``sum_x h(x) |n_a(x) - n_b(x)|``
with ``h(x) = min(g(x), min_{y != x} s(x, y) / 2)``. Counts do not depend on the
rotation, so the bound holds for the cyclic cost too. These are three
feasible points of a linear programme's dual (:func:`count_potentials`); the
coarse bound takes the best of more of them when the letters the views use
fall in few groups of equal potentials (else it keeps these three).

Every bound is a float at most the term's own value, rounding included (the
count and semi-global bounds are exact sums of the costs' dyadic fractions;
the range bound sums whole steps exactly and is lowered by the most both
roundings can move it, plus 2e-9); the likelihood forms ``-lambda d`` and
``-log(1 + d)`` are monotone in floating point too, so a lower bound on
``d`` is an upper bound on the log-likelihood.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .._types import FArray, IArray
from ..align._bounds import query_profile_rows
from ..observation import Observation
from ._bound_kernels import (
    COUNT_GROUPS,
    SweepState,
    count_place_min,
    count_place_min_narrow,
    cyclic_place_min,
    exact_l1_place_min,
    group_count_place_min,
    l1_place_min,
    letter_counts,
    neg_scaled,
    query_rows,
    scaled,
    semiglobal_cover,
    semiglobal_finer_min,
    semiglobal_views_min,
    view_spans,
)
from .base import Term
from .fingerprint import FingerprintTerm
from .range import RangeTerm

__all__ = ["DenseBound", "FingerprintBound", "PlaceLayout", "RangeBound", "TermBound", "bound_for", "count_potentials", "has_bound"]

#: Most steps of a range descriptor entry (in [0, 1]) in the coarse bound, all bins together.
_RANGE_STEPS = 65535
#: Views converted at a time when a bound is built (bounded temporary memory).
_CHUNK_VIEWS = 1 << 15


@dataclass(frozen=True, slots=True)
class PlaceLayout:
    """Places in groups: group ``g`` holds the places ``order[starts[g]:starts[g + 1]]``.

    Attributes
    ----------
    order : ndarray of int, shape (P,)
        Every place once, group after group.
    starts : ndarray of int, shape (G + 1,)
        Start of each group in ``order``.
    """

    order: IArray
    starts: IArray

    @property
    def n_groups(self) -> int:
        return int(self.starts.size - 1)

    def sizes(self) -> IArray:
        """Places of each group, shape ``(G,)``."""
        return np.diff(self.starts)


def _ranges(lo: IArray, hi: IArray) -> IArray:
    """``concatenate([arange(a, b) for a, b in zip(lo, hi)])``."""
    n = hi - lo
    return np.repeat(lo - np.cumsum(n) + n, n) + np.arange(int(n.sum()))


class TermBound:
    """Bounds of one term over a layout: :meth:`prepare` once a query, then :meth:`coarse`, :meth:`cover` and :meth:`fine`, :meth:`finer`, :meth:`exact`."""

    def __init__(self, term: Term, layout: PlaceLayout) -> None:
        self.term = term
        self.layout = layout

    def prepare(self, obs: Observation) -> Any:
        """What the bounds need of one query (its fingerprint, its descriptor...)."""
        return obs

    def coarse(self, query: Any) -> FArray:
        """An upper bound of the term's log-likelihood at every place, shape ``(P,)`` (columns of the model)."""
        raise NotImplementedError

    def cover(self, query: Any, places: IArray) -> IArray:
        """The places whose fine bounds the work for ``places`` makes ready (theirs, unless ready before, and any that come free).

        :meth:`fine` is then asked for those. Default: ``places``.
        """
        return places

    def fine(self, query: Any, places: IArray) -> FArray | None:
        """A tighter bound at ``places`` (distinct, in that order); None: none finer."""
        return None

    def finer(self, query: Any, places: IArray) -> FArray | None:
        """A bound tighter still at ``places`` (distinct, their fine bounds computed); None: none finer."""
        return None

    def exact(self, query: Any, places: IArray) -> FArray:
        """The term's log-likelihood at ``places``: ``term.log_likelihood_at``'s values."""
        raise NotImplementedError


class DenseBound(TermBound):
    """Any term: its exact log-likelihood at every place (no saving; the bound is the value)."""

    def prepare(self, obs: Observation) -> FArray:
        return np.asarray(self.term.log_likelihood([obs])[0], dtype=np.float64)

    def coarse(self, query: FArray) -> FArray:
        return query

    def exact(self, query: FArray, places: IArray) -> FArray:
        return query[places]


class _Views:
    """A term's views in layout order: where each place's views start."""

    def __init__(self, layout: PlaceLayout, per_place: IArray) -> None:
        self.layout = layout
        self.per_place = per_place
        n = per_place[layout.order]
        first = np.cumsum(per_place) - per_place
        #: views (index in place order) in layout order
        self.order = _ranges(first[layout.order], first[layout.order] + n)
        pos = np.cumsum(n) - n
        self.place_start = np.empty_like(per_place)
        self.place_start[layout.order] = pos
        self.has = per_place[layout.order] > 0


class FingerprintBound(TermBound):
    """Bounds of :class:`~fingerloc.terms.FingerprintTerm` (module docstring)."""

    def __init__(self, term: FingerprintTerm, layout: PlaceLayout) -> None:
        from ..align import CostModel
        from ..align._bounds import pack_subblocks
        from ..align._costs import N_LETTERS
        from ..align._cyclic_int import integer_costs
        from ..align._encode import encode_many

        super().__init__(term, layout)
        cm = term.costs if term.costs is not None else CostModel()
        per_place = np.diff(np.append(term._starts, len(term._refs))).astype(np.int64)
        self.views = views = _Views(layout, per_place)
        codes, off = encode_many([term._refs[int(r)].letters for r in views.order])
        n_views = off.size - 1
        counts_t = letter_counts(codes, off, N_LETTERS)  # (letters, views)
        most = counts_t.max(axis=1, initial=0).astype(np.int64)  # the largest count of each letter in a view
        other = np.where(np.eye(N_LETTERS, dtype=bool), np.inf, cm.substitution).min(axis=1)
        c_weight = np.minimum(cm.indel, other)
        h_weight = np.minimum(cm.indel, other / 2.0)
        self.used = most > 0
        self.partial_fov_exact = not term.cyclic  # cropped references: no count bound for a partial field of view
        ints = integer_costs(cm.substitution, cm.indel)
        self.counts_t: Any = None  # (letters, views): uint8, or int16 for larger counts or costs
        self.grouped: Any = None  # the letters in groups for every potential (:meth:`_group_letters`); None: three potentials
        if ints is not None and most.max(initial=0) < np.iinfo(np.int16).max:
            sc = ints[2]
            h2, c2 = 2 * sc * h_weight, 2 * sc * c_weight
            if np.array_equal(h2, np.round(h2)) and np.array_equal(c2, np.round(c2)):
                narrow = most.max(initial=0) < 256 and max(h2.max(initial=0), c2.max(initial=0)) < 256
                self.counts_t = counts_t.astype(np.uint8 if narrow else np.int16)
                self.weights2 = (h2.astype(np.int32), c2.astype(np.int32), float(2 * sc))
                self.most = most
                if narrow:
                    self._group_letters(cm, sc, counts_t)
        del counts_t
        # the semi-global bound: cyclic matching with integer costs, the views in sub-blocks in layout order
        self.sb = None
        self.codes, self.off = codes, off
        if term.cyclic and ints is not None and n_views:
            sub8, indel8, scale = ints
            self.ints = ints
            self.sb = pack_subblocks(codes, off, sub8, indel8)
            self.scale = scale
            self.place_of_view = np.repeat(layout.order, per_place[layout.order]).astype(np.int32)
            self.view_span = view_spans(views.place_start, per_place, n_views)

    def _group_letters(self, cm: Any, sc: float, counts_t: Any) -> None:
        """The coarse bound with every potential of :func:`count_potentials`, the letters the views use in groups.

        Letters whose potentials all agree share a group; with at most
        :data:`~fingerloc.terms._bound_kernels.COUNT_GROUPS` groups the bound of every potential costs
        one pass over the counts and one a potential (:func:`~fingerloc.terms._bound_kernels.group_count_place_min`),
        else the coarse bound keeps the three potentials of the module docstring.
        """
        pots = [(2 * sc * u, 2 * sc * w) for u, w in count_potentials(cm.substitution, cm.indel)]
        pots = [(u, w) for u, w in pots if np.array_equal(u, np.round(u)) and np.array_equal(w, np.round(w))]
        if not pots:
            return
        u_all = np.array([u for u, _ in pots], dtype=np.int64)
        w_all = np.array([w for _, w in pots], dtype=np.int64)
        letters = np.flatnonzero(self.used)
        keys: dict[bytes, int] = {}
        group = np.array([keys.setdefault(u_all[:, x].tobytes() + w_all[:, x].tobytes(), len(keys)) for x in letters], dtype=np.int64)
        if len(keys) > COUNT_GROUPS:
            return
        ca = np.zeros((len(pots), COUNT_GROUPS), dtype=np.int64)
        cb = np.zeros((len(pots), COUNT_GROUPS), dtype=np.int64)
        vsum = np.zeros((COUNT_GROUPS, counts_t.shape[1]), dtype=np.int64)
        for x, g in zip(letters.tolist(), group.tolist(), strict=True):
            ca[:, g] = u_all[:, x] + w_all[:, x]
            cb[:, g] = u_all[:, x] - w_all[:, x]
            vsum[g] += counts_t[x]
        vmax = vsum.max(axis=1)
        if int(vmax.max(initial=0)) > np.iinfo(np.int16).max:
            return
        self.grouped = (letters, group, vsum.astype(np.int16), vmax, ca, cb, u_all)

    def _grouped_least(self, q: IArray) -> IArray | None:
        """:func:`~fingerloc.terms._bound_kernels.group_count_place_min` of a query's counts ``q``; None when a sum could pass 16 bits."""
        letters, group, vsum, vmax, ca, cb, u_all = self.grouped
        qsum = np.bincount(group, weights=q[letters], minlength=COUNT_GROUPS).astype(np.int64)
        only = (q > 0) & ~self.used  # letters no view has: in excess in the query, whatever the view
        const2 = 2 * (u_all[:, only] @ q[only].astype(np.int64))
        worst = np.abs(const2) + np.abs(cb) @ np.maximum(qsum, vmax) + np.abs(ca) @ (qsum + vmax) + np.abs(cb) @ qsum
        if int(worst.max(initial=0)) > np.iinfo(np.int16).max or int((qsum + vmax).max(initial=0)) > np.iinfo(np.int16).max:
            return None
        v = self.views
        return group_count_place_min(
            q.astype(np.int16), self.counts_t, letters, group, vsum, qsum.astype(np.int16), ca.astype(np.int16), cb.astype(np.int16),
            const2.astype(np.int16), v.place_start, v.per_place,
        )

    def prepare(self, obs: Observation) -> Any:
        from ..align._costs import N_LETTERS
        from ..align._encode import encode

        fp = self.term.query_fingerprint(obs)  # type: ignore[attr-defined]
        codes = encode(fp.letters)
        q = np.bincount(codes, minlength=N_LETTERS).astype(np.int32)
        partial = self.partial_fov_exact and not any(w >= 2 * np.pi - 1e-12 for _, w in obs.fov)
        rows = None if self.sb is None else query_rows(codes, self.ints[0], self.ints[1])
        sg = None if self.sb is None else query_profile_rows(codes, self.sb)
        state = None if self.sb is None else SweepState(int(self.sb.length.size))
        return obs, codes, q, partial, fp, rows, sg, state

    def _bound_of(self, least: IArray, unit: float) -> FArray:
        """The term's likelihood of the integer least costs ``least`` (units of ``1 / unit``): an upper bound where they bound the cost."""
        if self.term.likelihood == "exp":  # type: ignore[attr-defined]
            return neg_scaled(least, float(unit), float(self.term.lambda_), 0.0)  # type: ignore[attr-defined]
        return self._likelihood(_scaled(least, unit))

    def _likelihood(self, d: FArray) -> FArray:
        return np.asarray(self.term._likelihood_of(d), dtype=np.float64)  # type: ignore[attr-defined]

    def exact(self, query: Any, places: IArray) -> FArray:
        term: FingerprintTerm = self.term  # type: ignore[assignment]
        if self.sb is None:
            return self._likelihood(term.distances_at([query[0]], places, fingerprints=[query[4]])[0])
        # cyclic, integer costs: the same exact integers as the term's batch kernel, for these views only
        v = self.views
        least = cyclic_place_min(query[5], self.codes, self.off, v.place_start, v.per_place, np.asarray(places, dtype=np.int64))
        return self._likelihood(_scaled(least, self.ints[2]))

    def coarse(self, query: Any) -> FArray:
        q, partial = query[2], query[3]
        n = self.views.per_place.size
        if partial or self.counts_t is None:  # -lambda * 0 and -log(1 + 0): the largest there is
            return self._likelihood(np.where(self.views.per_place > 0, 0.0, np.inf))
        h2, c2, unit = self.weights2
        if self.grouped is not None:
            least = self._grouped_least(q)
            if least is not None:
                return self._bound_of(least, 2.0 * unit)
        letters = np.flatnonzero((q > 0) | self.used)
        wide = np.maximum(h2, c2)[letters].astype(np.int64) @ np.maximum(q[letters], self.most[letters])
        if self.counts_t.dtype == np.uint8 and wide <= np.iinfo(np.int16).max:  # no sum can pass 16 bits
            least = count_place_min_narrow(
                q.astype(np.int16), self.counts_t, letters, h2.astype(np.int16), c2.astype(np.int16), self.views.place_start, self.views.per_place
            )
        else:
            least = count_place_min(q, self.counts_t, letters, h2, c2, self.views.place_start, self.views.per_place)
        out = _scaled(least, unit)
        return self._likelihood(out) if n else out

    def cover(self, query: Any, places: IArray) -> IArray:
        """Sweep the semi-global bound of ``places``' views: the places whose fine bounds that completed (theirs among them)."""
        if self.sb is None or query[3]:
            return places
        v = self.views
        return semiglobal_cover(query[6], self.sb, query[7], places, v.place_start, v.per_place, self.place_of_view, self.view_span)

    def fine(self, query: Any, places: IArray) -> FArray | None:
        places = np.asarray(places, dtype=np.int64)
        if self.sb is None or query[3]:
            return self.exact(query, places)
        v = self.views
        least = semiglobal_views_min(query[6], self.sb, query[7], places, v.place_start, v.per_place, self.place_of_view, self.view_span)
        return self._bound_of(least, self.scale)

    def finer(self, query: Any, places: IArray) -> FArray | None:
        if self.sb is None or query[3]:
            return None  # the fine bound is the exact cost already
        v = self.views
        least = semiglobal_finer_min(
            query[6], self.sb, query[7], self.codes, self.off, np.asarray(places, dtype=np.int64), v.place_start, v.per_place,
            self.place_of_view, self.view_span,
        )
        return self._bound_of(least, self.scale)


class RangeBound(TermBound):
    """Bounds of :class:`~fingerloc.terms.RangeTerm` (module docstring)."""

    def __init__(self, term: RangeTerm, layout: PlaceLayout) -> None:
        super().__init__(term, layout)
        per_place = np.array([d.shape[0] for d in term.descriptors_], dtype=np.int64)
        self.views = _Views(layout, per_place)
        refs = term._refs  # every view's descriptor, place after place
        n_views, width = int(self.views.order.size), int(refs.shape[1])
        # each entry rounded to 1/steps: an L1 distance moves by at most half a step a bin; steps such that a whole
        # L1 distance fits 16 bits (the pass sums in 16-bit lanes): 1/1598 for 41 bins
        self.steps = max(1, _RANGE_STEPS // max(width, 1))
        self.desc_t = np.empty((width, n_views), dtype=np.uint16)
        for a in range(0, n_views, _CHUNK_VIEWS):  # in chunks: no float64 copy of every descriptor at once
            part = refs[self.views.order[a : a + _CHUNK_VIEWS]]
            self.desc_t[:, a : a + part.shape[0]] = np.round(np.clip(part, 0.0, 1.0) * self.steps).T
        self.slack = width * 0.5 / self.steps + 1e-9
        self.first = (np.cumsum(per_place) - per_place).astype(np.int64)  # first row of each place in ``term._refs``

    def prepare(self, obs: Observation) -> tuple[Observation, FArray | None]:
        return obs, (None if obs.ranges is None else self.term.descriptor(obs))  # type: ignore[attr-defined]

    def exact(self, query: tuple[Observation, FArray | None], places: IArray) -> FArray:
        term: RangeTerm = self.term  # type: ignore[assignment]
        obs, q = query
        if q is None:
            d = term.distances_at([obs], places)[0]
        else:  # cdist's L1, bin after bin, for these places' views only
            d = exact_l1_place_min(q, term._refs, self.first, self.views.per_place, np.asarray(places, dtype=np.int64))
        return np.asarray(term._likelihood_of(d))

    def coarse(self, query: tuple[Observation, FArray | None]) -> FArray:
        q = query[1]
        if q is None:
            return np.zeros(self.views.per_place.size)
        q16 = np.round(np.clip(q, 0.0, 1.0) * self.steps).astype(np.uint16)
        least = l1_place_min(self.desc_t, q16, self.views.place_start, self.views.per_place)
        # less the most both roundings (the view's and the query's) can move the distance
        return neg_scaled(least, float(self.steps), float(self.term.lambda_), 2.0 * self.slack)  # type: ignore[attr-defined]


def count_potentials(substitution: FArray, indel: FArray) -> list[tuple[FArray, FArray]]:
    """Letter weights ``(u, w)`` of letter-count bounds: the cost is at least ``sum_x u(x) e_a(x) + w(x) e_b(x)``.

    ``e_a(x)``: the letters ``x`` of ``a`` in excess of those of ``b`` (``e_b`` likewise). Such a
    letter is left out (cost ``g``) or paired with another (cost ``s``), so charging ``u`` to the
    letters of ``a`` that no equal letter pairs with and ``w`` to those of ``b`` bounds the cost when
    ``u <= g``, ``w <= g``, ``u(x) + w(y) <= min(s(x, y), g(x) + g(y))`` for ``x != y`` (a pair or two
    indels), and ``u(x) + w(x) >= 0`` (beyond the excess, letters left unpaired by equal ones come a
    pair at a time, one in each string). That is the dual of the transport of the excess letters,
    order left out; each pair here is one of its feasible points: ``(h, h)``, ``(c, 0)``, ``(0, c)``
    (module docstring), and for each indel value ``t`` the weights ``u = min(g, t)`` with the best
    ``w`` for them, and the same swapped. Pairs breaking a condition are left out.
    """
    sub = np.asarray(substitution, dtype=np.float64)
    g = np.asarray(indel, dtype=np.float64)
    n = g.size
    pair = np.minimum(sub, g[:, None] + g[None, :])
    pair[np.eye(n, dtype=bool)] = np.inf
    other = pair.min(axis=1) if n > 1 else np.full(n, np.inf)
    c = np.minimum(g, other)
    h = np.minimum(g, other / 2.0)
    zero = np.zeros(n)
    cands = [(h, h), (c, zero), (zero, c)]
    for t in sorted(set(g.tolist())):
        u = np.minimum(g, t)
        w = np.minimum(g, (pair - u[:, None]).min(axis=0)) if n > 1 else g.copy()
        cands += [(u, w), (w, u)]
    out: list[tuple[FArray, FArray]] = []
    for u, w in cands:
        ok = bool(np.all(u <= g + 1e-12) and np.all(w <= g + 1e-12) and np.all(u + w >= -1e-12))
        ok = ok and bool(np.all(u[:, None] + w[None, :] <= pair + 1e-12))
        if ok and not any(np.array_equal(u, a) and np.array_equal(w, b) for a, b in out):
            out.append((u, w))
    return out


def _scaled(least: IArray, unit: float) -> FArray:
    """Integer least values a place (:mod:`._bound_kernels`) divided by ``unit``; inf for a place without views."""
    return scaled(least, float(unit))


def has_bound(term: Term) -> bool:
    """True when this module has bounds of the term's own (not :class:`DenseBound`'s full scoring)."""
    if isinstance(term, FingerprintTerm):
        return term.reference == "all" and len(term._refs) > 0
    return isinstance(term, RangeTerm) and term.every_place_described()


def bound_for(term: Term, layout: PlaceLayout) -> TermBound:
    """The best bound this module has for ``term``: its own, or :class:`DenseBound`."""
    if not has_bound(term):
        return DenseBound(term, layout)
    if isinstance(term, FingerprintTerm):
        return FingerprintBound(term, layout)
    return RangeBound(term, layout)  # type: ignore[arg-type]
