"""Exact retrieval: the best places of a :class:`~fingerloc.model.PlaceModel` without scoring every place.

``model.predict_log_proba`` scores an observation against every stored view
of every place: at 100,000 places that is 300,000 cyclic alignments a
query. :class:`PlaceIndex` gives the same best places with the same
joint log-likelihoods, scoring in full only the places that could matter.

How. The places are laid out so that look-alikes sit side by side
(:func:`place_layout`: a recursive split of the places along their most
spread feature, the range descriptor and the letter counts of their views).
For one query, each term gives upper bounds of its log-likelihood at a
place, each tighter and dearer than the last (:mod:`fingerloc.terms.bounds`):
a coarse one at every place, a fine one and a finer one at chosen places;
their weighted sum bounds the joint log-likelihood. The
search is best first: the places whose bound could still reach the ``k``-th
best exact score get their next bound, the highest bounds first, and at the
last level their exact score, until no bound left can reach it (in batches:
a kernel's set-up is paid once a batch). Ties are refined too, so the answer
is that of the linear scan: the same ``k`` places in the same order (ties by
place index, as ``argmax``), with bit-identical joint log-likelihoods (each
term scores the chosen places with the same arithmetic as it scores all of
them).

The posterior. ``P(place | obs)`` is normalised over *every* place, and the
places never scored contribute to the normaliser. The answer says by how
much at most: ``mass_bound`` is the sum of ``exp(bound)`` over the places
not scored, divided by the sum of ``exp(score)`` over those scored, so the
posterior given (normalised over the scored places) is at most a factor
``1 + mass_bound`` too large, and any place not scored has a probability
below ``mass_bound``. With ``tol``, refining goes on until ``mass_bound <=
tol``: the posterior of every place is then within ``tol`` of the linear
scan's (absolute), whatever the place. Where the posterior is broad (many
places within a few tens of nats, as on a campus of similar rooms) that means
scoring most places; the best places alone never do. When more than
:data:`_FULL_FRACTION` of the places would have to be scored, the query is
scored against every place at once instead (the linear scan: its answer is
the linear scan's by construction, and one call is cheaper than scoring
most places in pieces).

Terms without bounds of their own (the mixtures, the appearance terms) are
scored in full for every query and bound by their exact value; terms of
weight 0 are left out (they add nothing to a finite joint). A model whose
mixtures turn with the fingerprint's heading (``rotate_mixtures``) is
scored in full.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._lse import logsumexp
from ._types import FArray, IArray
from .errors import InvalidParameterError
from .observation import Observation
from .terms._bound_kernels import open_places, place_letter_counts, top_places, unscored_mass
from .terms.bounds import DenseBound, PlaceLayout, TermBound, bound_for, has_bound
from .terms.fingerprint import FingerprintTerm
from .terms.range import RangeTerm

__all__ = ["INDEX_MIN_PLACES", "POSTERIOR_TOL", "PlaceIndex", "SearchResult", "index_for", "place_layout"]

#: Most views of a group of the layout (its places side by side; the bound kernels take the views in layout order).
GROUP_VIEWS = 64
#: A bound below the k-th best score by less than this (relative) is refined anyway: rounding of sums.
_MARGIN = 1e-9


@dataclass(frozen=True, slots=True)
class SearchResult:
    """The best places of each query (:meth:`PlaceIndex.search`).

    Attributes
    ----------
    places : ndarray of int, shape (n, k)
        Columns of the ``k`` best places (``model.classes_``), best first; ties by column, as ``argmax``.
    joint : ndarray of float64, shape (n, k)
        Their joint log-likelihoods, the values of ``model.joint_log_likelihood``.
    log_posterior : ndarray of float64, shape (n, k)
        ``joint`` normalised over the places scored (module docstring).
    mass_bound : ndarray of float64, shape (n,)
        Bound on the posterior mass of the places not scored, relative to that of those scored.
    scored : ndarray of int, shape (n,)
        Places scored in full.
    rank_of_truth : ndarray of int, shape (n,)
        Rank of the given true place (1 = best, ties count against, as ``PlaceModel.rank``); 0 without truth.
    """

    places: IArray
    joint: FArray
    log_posterior: FArray
    mass_bound: FArray
    scored: IArray
    rank_of_truth: IArray


def place_layout(features: FArray, views: IArray, *, group_views: int = GROUP_VIEWS) -> PlaceLayout:
    """Groups of look-alike places: an order from a recursive split along the most spread feature, cut into groups.

    Parameters
    ----------
    features : ndarray, shape (P, d)
        A description of each place (distances between rows should track how alike places look).
    views : ndarray of int, shape (P,)
        Views of each place; a group holds at most ``group_views`` of them (a place with more is a group alone).

    Returns
    -------
    PlaceLayout
        The places are ordered by splitting them at the median of their most spread feature,
        recursively (down to a few places), and the order is cut greedily into groups that are as
        full as the places allow: neighbours in the order look alike, and the blocks of the bound
        kernels have few empty lanes.
    """
    n = features.shape[0]
    parts: list[IArray] = []
    stack = [np.arange(n)]
    while stack:
        idx = stack.pop()
        if idx.size <= 4:
            parts.append(idx)
            continue
        f = features[idx]
        dim = int(np.argmax(f.max(axis=0) - f.min(axis=0)))
        order = idx[np.argsort(f[:, dim], kind="stable")]
        half = idx.size // 2
        stack.append(order[half:])
        stack.append(order[:half])
    order = np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)
    starts = [0]
    filled = 0
    for i, v in enumerate(views[order].tolist()):
        if filled and filled + v > group_views:
            starts.append(i)
            filled = 0
        filled += v
    starts.append(order.size)
    return PlaceLayout(order.astype(np.int64), np.asarray(starts if order.size else [0], dtype=np.int64))


def _features(model: Any) -> tuple[FArray, IArray]:
    """Each place's mean range descriptor and mean letter counts, scaled to nats; and its views."""
    from .align._costs import N_LETTERS

    n_places = len(model.classes_)
    cols: list[FArray] = []
    views = np.ones(n_places, dtype=np.int64)
    for name, t in model.terms_.items():
        w = model._weight(name)
        if isinstance(t, RangeTerm) and t.every_place_described():
            cols.append(np.stack([d.mean(axis=0) for d in t.descriptors_]) * (w * t.lambda_))
        elif isinstance(t, FingerprintTerm):
            from .align._encode import encode_many

            per = np.diff(np.append(t._starts, len(t._refs)))
            codes, off = encode_many([fp.letters for fp in t._refs])
            counts = place_letter_counts(codes, off, per.astype(np.int64), N_LETTERS)
            counts /= np.maximum(per, 1)[:, None]
            scale = w * (t.lambda_ if t.likelihood == "exp" else 0.1)
            cols.append(counts * 0.5 * scale)
            views = np.maximum(per, 1).astype(np.int64)
    feats = np.hstack(cols) if cols else np.zeros((n_places, 1))
    return _principal(feats, _COMPONENTS), views


#: Principal components of the place features the layout splits along.
_COMPONENTS = 4


def _principal(feats: FArray, k: int) -> FArray:
    """``feats`` projected on its ``k`` principal axes (found on a seeded sample of at most 5,000 rows).

    Splitting along these rather than along single features puts more of the places a query keeps in
    fewer groups (on the campus, 24 % of the groups hold them instead of 34 %).
    """
    n = feats.shape[0]
    if n <= k or feats.shape[1] <= k:
        return feats
    sample = feats[np.sort(np.random.default_rng(0).choice(n, min(n, 5000), replace=False))]
    centre = sample.mean(axis=0)
    _, _, vt = np.linalg.svd(sample - centre, full_matrices=False)
    return np.asarray((feats - centre) @ vt[:k].T, dtype=np.float64)


class PlaceIndex:
    """Exact best places of a fitted :class:`~fingerloc.model.PlaceModel` (module docstring).

    Parameters
    ----------
    model : PlaceModel
        A fitted model; the index is built once (its groups and bounds) and is valid until the model changes.
    group_views : int, default 64
        Most views of a group.

    Attributes
    ----------
    layout : PlaceLayout
    bounds : dict
        Term name -> its bound (:mod:`fingerloc.terms.bounds`); terms of weight 0 are absent.
    dense : bool
        True when the model is scored in full (``rotate_mixtures``).
    """

    def __init__(self, model: Any, *, group_views: int = GROUP_VIEWS) -> None:
        model._check_fitted()
        self.model = model
        self.n_places = len(model.classes_)
        self.dense = bool(model.rotate_mixtures)
        feats, views = _features(model)
        self.layout = place_layout(feats, views, group_views=group_views)
        self.weights = {name: model._weight(name) for name in model.terms_}
        self.bounds: dict[str, TermBound] = {}
        if not self.dense:
            for name, t in model.terms_.items():
                if self.weights[name] != 0.0:
                    self.bounds[name] = bound_for(t, self.layout)

    # -- scoring ---------------------------------------------------------------------
    def _exact(self, prep: dict[str, Any], places: IArray) -> FArray:
        """Joint log-likelihoods at ``places``, the model's arithmetic (weighted sum in term order)."""
        terms = {name: b.exact(prep[name], places) for name, b in self.bounds.items()}
        return np.asarray(sum(self.weights[t] * ll for t, ll in terms.items()), dtype=np.float64)

    def search(
        self,
        observations: Sequence[Observation],
        *,
        k: int = 5,
        tol: float | None = None,
        truth: Sequence[Hashable] | None = None,
    ) -> SearchResult:
        """The ``k`` best places of each observation, exactly (module docstring).

        Parameters
        ----------
        observations : sequence of Observation
        k : int, default 5
            Best places wanted (at most the number of places).
        tol : float, optional
            Refine until the posterior mass of the places not scored is at most ``tol`` times that of
            those scored: every probability then within ``tol`` of the linear scan's.
        truth : sequence of labels, optional
            The true place of each observation: its exact rank is computed too (scoring every place
            that might rank above it). An entry that is None or no learned place gets rank 0.
        """
        obs = list(observations)
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
            raise InvalidParameterError(f"k must be an integer >= 1, got {k!r}")
        if tol is not None and not (tol >= 0.0 and math.isfinite(tol)):
            raise InvalidParameterError(f"tol must be a number >= 0 or None, got {tol!r}")
        if truth is not None and len(truth) != len(obs):
            raise InvalidParameterError(f"truth: one label per observation is needed, got {len(truth)} for {len(obs)}")
        kk = min(int(k), self.n_places)
        n = len(obs)
        res = SearchResult(
            places=np.zeros((n, kk), dtype=np.int64),
            joint=np.zeros((n, kk)),
            log_posterior=np.zeros((n, kk)),
            mass_bound=np.zeros(n),
            scored=np.zeros(n, dtype=np.int64),
            rank_of_truth=np.zeros(n, dtype=np.int64),
        )
        for i, o in enumerate(obs):
            if not isinstance(o, Observation):
                raise InvalidParameterError(f"observations[{i}] must be an Observation, got {type(o).__name__}")
        cols = [None if truth is None else self._column(t) for t in (truth or [None] * n)]
        full: list[int] = []  # queries scored against every place, together (one batched call is cheaper)
        for i, o in enumerate(obs):
            one = None if (self.dense or not self.bounds) else _Search(self, o, kk, tol, cols[i]).run()
            if one is None:
                full.append(i)
            else:
                _put(res, i, one)
        for s in range(0, len(full), _FULL_BATCH):
            part = full[s : s + _FULL_BATCH]
            joint = np.asarray(self.model.joint_log_likelihood([obs[i] for i in part]), dtype=np.float64)
            for row, i in enumerate(part):
                _put(res, i, _finish(np.arange(self.n_places), joint[row], kk, 0.0, cols[i]))
        return res

    def _column(self, label: Hashable | None) -> int | None:
        if label is None:
            return None
        try:
            return self.model.column_of(label)
        except InvalidParameterError:
            return None

    @property
    def bounded(self) -> bool:
        """True when every term of non-zero weight has bounds of its own (none is scored in full for every query)."""
        return not self.dense and bool(self.bounds) and not any(isinstance(b, DenseBound) for b in self.bounds.values())



#: A place's bound: its coarse bound, its fine bound, its finer bound, its exact score (:class:`_Search`).
COARSE, FINE, FINER, SCORED = 1, 2, 3, 4


class _Search:
    """One query's search (module docstring): coarse bounds of every place, then finer ones and scores, best bound first."""

    def __init__(self, index: PlaceIndex, o: Observation, k: int, tol: float | None, true_col: int | None) -> None:
        self.ix = index
        self.o = o
        self.k, self.tol, self.true_col = k, tol, true_col
        self.prep = {name: b.prepare(o) for name, b in index.bounds.items()}
        #: each term's best bound known of each place (its coarse bound until a finer one is computed)
        self.bound = {name: b.coarse(self.prep[name]) for name, b in index.bounds.items()}
        self.ub = _weighted(index.weights, self.bound)  # the best bound known of each place's joint
        self.level = np.full(index.n_places, COARSE, dtype=np.int8)
        self.scored_p: list[IArray] = []
        self.scored_j: list[FArray] = []
        self.joint = np.zeros(0)

    def theta(self) -> float:
        """The score a place must reach to matter: the k-th best scored (and the truth's, when ranked)."""
        j = self.joint
        th = -math.inf if j.size < self.k else float(np.partition(j, j.size - self.k)[j.size - self.k])
        if self.true_col is not None:
            th = min(th, float(self.scored_j[0][0]))
        return th

    def _tighten(self, p: IArray, level: int, per: dict[str, FArray | None]) -> None:
        """New bounds of the terms at ``p`` (None: the term's bound stays; each the least of its bounds), and ``p``'s joint bound."""
        for name, f in per.items():
            if f is not None:
                self.bound[name][p] = np.minimum(self.bound[name][p], f)
        self.ub[p] = np.minimum(self.ub[p], _weighted(self.ix.weights, {name: b[p] for name, b in self.bound.items()}))
        self.level[p] = level

    def refine(self, places: IArray) -> None:
        """The fine bounds of ``places`` (distinct), and of the places they come with."""
        p = places[self.level[places] < FINE]
        if p.size == 0:
            return
        for name, b in self.ix.bounds.items():  # the places whose fine bounds come with those of p (p among them)
            p = b.cover(self.prep[name], p)
        p = p[self.level[p] < FINE]
        if p.size:
            self._tighten(p, FINE, {name: b.fine(self.prep[name], p) for name, b in self.ix.bounds.items()})

    def refine_more(self, places: IArray) -> None:
        """The finer bounds of ``places`` (distinct, fine already)."""
        p = places[self.level[places] == FINE]
        if p.size:
            self._tighten(p, FINER, {name: b.finer(self.prep[name], p) for name, b in self.ix.bounds.items()})

    def score(self, places: IArray) -> None:
        places = places[self.level[places] < SCORED]
        if places.size == 0:
            return
        j = self.ix._exact(self.prep, places)
        self.scored_p.append(places)
        self.scored_j.append(j)
        self.joint = np.concatenate([self.joint, j])
        self.level[places] = SCORED

    def cut(self) -> float:
        th = self.theta()
        return th - _MARGIN * (1.0 + abs(th)) if math.isfinite(th) else -math.inf

    def run(self) -> tuple[IArray, FArray, FArray, float, int, int] | None:
        ix, k = self.ix, self.k
        if self.tol is not None and self._broad():  # the posterior to tol: most places, as far as the bounds tell
            return None  # every place to be scored: search() does it for such queries together
        if self.true_col is not None:  # the truth first: its score bounds what must be scored
            self.score(np.array([self.true_col]))
        # 1. a first threshold: the places with the best coarse bounds refined, the best of them scored
        m = min(max(_FIRST_REFINED, _FIRST_SCORED), ix.n_places)
        top = top_places(self.ub, m)
        self.refine(top)
        first = top[np.argsort(-self.ub[top], kind="stable")][: 4 * max(2 * k, _FIRST_SCORED)]
        self.refine_more(first)
        self.score(first[np.argsort(-self.ub[first], kind="stable")][: max(2 * k, _FIRST_SCORED)])
        if self.tol is not None and self._needs_most():  # the posterior to tol would score most places anyway
            return None  # every place to be scored: search() does it for such queries together
        # 2. best first: of the places whose bound can still reach the k-th best score, those of the highest bounds
        # get their next bound (or, at the last, their score); in batches (a kernel's set-up is paid once a batch)
        cand = open_places(self.ub, self.level, self.cut(), SCORED)
        batch = _SCORE_FIRST
        while True:
            cand = cand[(self.level[cand] < SCORED) & (self.ub[cand] >= self.cut())]
            if cand.size == 0:
                if self.tol is None or self._mass() <= self.tol:
                    break
                if self._refine_mass():  # most places would be scored: the linear scan, at once
                    return None  # every place to be scored: search() does it for such queries together
                cand = np.flatnonzero(self.level < SCORED)
                continue
            ub = self.ub[cand]
            lev = self.level[cand]
            at = int(lev[int(np.argmax(ub))])  # the level of the highest bound
            if at == FINER:
                sel = np.flatnonzero(lev == FINER)
                if sel.size > batch:
                    sel = sel[np.argpartition(-ub[sel], batch - 1)[:batch]]
                self.score(cand[sel])
                batch = min(2 * batch, _SCORE_BATCH)
                continue
            above = lev > at
            top_above = float(ub[above].max()) if above.any() else -math.inf
            sel = np.flatnonzero((lev == at) & (ub >= top_above))  # above every bound of a later level
            cap = _REFINE_BATCH if at == COARSE else _FINER_BATCH
            if sel.size > cap:
                sel = sel[np.argpartition(-ub[sel], cap - 1)[:cap]]
            elif at == COARSE:
                sel = np.flatnonzero(lev == COARSE)  # a sweep's set-up once for all of them
            chosen = cand[sel]
            if at == COARSE:
                self.refine(chosen)
            else:
                self.refine_more(chosen)
            stuck = chosen[self.level[chosen] == at]
            if stuck.size:  # a bound that could not go further (no term refines it): the score, which always can
                self.score(stuck)
        all_p = np.concatenate(self.scored_p)
        return _finish(all_p, self.joint, k, self._mass(), self.true_col)

    def _mass(self) -> float:
        """:func:`_mass` of the scored places and the bounds of the others (their sum in one compiled pass)."""
        j = self.joint
        if j.size == 0:
            return math.inf
        top = float(np.max(j))
        if not math.isfinite(top):
            return _mass(j, self.ub[self.level < SCORED])
        return unscored_mass(self.ub, self.level, top, SCORED) / float(np.exp(j - top).sum())

    def _needed(self) -> tuple[IArray, int]:
        """Places not scored, most mass first, and how many of them hold more than ``tol`` of the posterior (bounds)."""
        unscored = np.flatnonzero(self.level < SCORED)
        top = float(np.max(self.joint)) if self.joint.size else -math.inf
        if not math.isfinite(top):
            return unscored, unscored.size
        ub = self.ub[unscored]
        order = np.argsort(-ub, kind="stable")
        z = float(np.exp(self.joint - top).sum())
        tail = np.cumsum(np.exp(ub[order] - top)[::-1])[::-1]  # tail[i]: bound on the mass of order[i:]
        return unscored[order], max(1, int(np.searchsorted(-tail, -float(self.tol or 0.0) * z, side="left")))

    def _broad(self) -> bool:
        """A first guess, from the coarse bounds alone, that the posterior to ``tol`` needs most places.

        True when more than :data:`_FULL_FRACTION` of the places have a bound within ``-log(tol)``
        nats of the best bound: on a map of look-alike places, the full scan at once is then
        cheaper than refining. A guess only: the answer is exact either way.
        """
        finite = self.ub[np.isfinite(self.ub)]
        if finite.size == 0:
            return True
        lim = float(finite.max()) + math.log(max(float(self.tol or 0.0), 1e-300))
        return int(np.count_nonzero(finite >= lim)) > _FULL_FRACTION * self.ix.n_places

    def _needs_most(self) -> bool:
        """True when, by the bounds known, more than :data:`_FULL_FRACTION` of the places are to be scored."""
        _, need = self._needed()
        return self.joint.size + need > _FULL_FRACTION * self.ix.n_places

    def _refine_mass(self) -> bool:
        """Refine or score, at once, the fewest places whose bounds hold more unscored posterior mass than ``tol``.

        True when that would score more than :data:`_FULL_FRACTION` of the places: score every
        place instead (the linear scan, in one call, is cheaper than scoring most places in pieces).
        """
        ordered, need = self._needed()
        if self.joint.size + need > _FULL_FRACTION * self.ix.n_places:
            return True
        chosen = ordered[:need]
        coarse = chosen[self.level[chosen] < FINE]
        if coarse.size:
            self.refine(coarse)
        else:
            self.score(chosen)
        return False


#: The first threshold: the places of the best coarse bounds refined, and of them the best scored (at least 2 k).
_FIRST_REFINED = 256
_FIRST_SCORED = 8
#: Places scored a step afterwards, best bound first: the first batch, doubled each step up to the last.
_SCORE_FIRST = 16
_SCORE_BATCH = 64
#: Most places refined a step (their fine bounds in one call), best coarse bound first.
_REFINE_BATCH = 2048
#: Most places given their finer bound a step, best bound first.
_FINER_BATCH = 256

#: Places to score for ``tol`` beyond which the linear scan is run instead (a fraction of all places).
_FULL_FRACTION = 0.4


#: Places from which :func:`index_for` gives an index, or None: never (``localize`` then scores every place).
#: None by default: on a campus of 10,000 look-alike laser places (``bench scale``) the exact top 5 through the
#: index cost 1.7 CPU ms a query against 9.7 for the full scan, but ``localize`` also prints the posterior of its
#: top places, and the posterior within :data:`POSTERIOR_TOL` needs nearly every place scored there (a broad
#: posterior: such a query is handed to the full scan). Set a number of places to have ``localize`` use it.
INDEX_MIN_PLACES: int | None = None
#: The posterior tolerance ``localize`` asks of the index: every probability within this of the linear scan's.
POSTERIOR_TOL = 1e-9

_CACHE: weakref.WeakKeyDictionary[Any, tuple[tuple[Any, ...], PlaceIndex]] = weakref.WeakKeyDictionary()


def _model_key(model: Any) -> tuple[Any, ...]:
    """What an index depends on: the model's places, their views, its terms and their weights."""
    views = sum(len(p.observations) for p in model.places_.values())
    return (len(model.classes_), views, id(model.terms_), tuple(id(t) for t in model.terms_.values()), tuple(sorted(model.weights_.items())))


def index_for(model: Any, *, min_places: int | None = None) -> PlaceIndex | None:
    """The exact index of a fitted model when it pays, else None (score every place).

    An index is given when the model has at least ``min_places`` places (default
    :data:`INDEX_MIN_PLACES`; None: never) and every term of non-zero
    weight has bounds of its own (:attr:`PlaceIndex.bounded`: the ``laser2d`` preset's fingerprint
    and range terms; mixture and appearance terms are not bounded, so the ``paper`` and
    ``panorama`` presets are scored in full). It is built once a model and kept while the model's
    places, views, terms and weights stay the same (``add_places`` builds a new one).
    """
    model._check_fitted()
    threshold = INDEX_MIN_PLACES if min_places is None else min_places
    if threshold is None or len(model.classes_) < threshold or model.rotate_mixtures:
        return None
    if not all(has_bound(t) for name, t in model.terms_.items() if model._weight(name) != 0.0):
        return None
    key = _model_key(model)
    hit = _CACHE.get(model)
    if hit is not None and hit[0] == key:
        return hit[1]
    index = PlaceIndex(model)
    _CACHE[model] = (key, index)
    return index


#: Queries scored against every place in one call of ``model.joint_log_likelihood``.
_FULL_BATCH = 16


def _put(res: SearchResult, i: int, one: tuple[IArray, FArray, FArray, float, int, int]) -> None:
    places, joint, lp, mass, scored, rank = one
    res.places[i], res.joint[i], res.log_posterior[i] = places, joint, lp
    res.mass_bound[i], res.scored[i], res.rank_of_truth[i] = mass, scored, rank


def _weighted(weights: dict[str, float], per_term: dict[str, FArray]) -> FArray:
    """``sum_t w_t * x_t`` in the order of the terms (the model's arithmetic)."""
    total = sum(weights[t] * x for t, x in per_term.items())
    return np.asarray(total, dtype=np.float64)


def _mass(scored: FArray, bounds: FArray) -> float:
    """Posterior mass of the places not scored (by their bounds) relative to that of the scored places."""
    if scored.size == 0:
        return math.inf
    top = float(np.max(scored))
    if not math.isfinite(top):
        return math.inf if bounds.size and np.isfinite(bounds).any() else 0.0
    z = float(np.exp(scored - top).sum())
    return float(np.exp(bounds - top).sum()) / z


def _finish(places: IArray, joint: FArray, k: int, mass: float, true_col: int | None) -> tuple[IArray, FArray, FArray, float, int, int]:
    """The k best of the scored places (ties by column), their normalised scores, and the rank of the truth."""
    order = np.lexsort((places, -joint))[:k]
    top_p, top_j = places[order], joint[order]
    finite = joint[np.isfinite(joint)]
    lse = float(logsumexp(finite)) if finite.size else 0.0
    lp = top_j - lse if finite.size else np.full(top_j.size, -math.log(max(len(places), 1)))
    rank = 0
    if true_col is not None:
        t = float(joint[places == true_col][0])
        rank = 1 + int(np.sum(joint > t)) + int(np.sum((joint == t) & (places != true_col)))
    if top_p.size < k:  # fewer places than k: pad (cannot happen: k <= number of places and all are scored then)
        raise AssertionError("fewer scored places than k")
    return top_p, top_j, lp, float(mass), int(places.size), rank
