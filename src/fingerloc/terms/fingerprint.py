"""The fingerprint term ``P(Fp | Loc)`` (docs/METHOD.md §4): string alignment against a place's stored fingerprints.

``likelihood="paper"``: ``P(Fp | loc) = 1 / (cost + 1)``; ``"exp"``:
``exp(-lambda cost)``, ``lambda`` fit leave-one-out (:mod:`.distance`). The
cost is the least alignment cost over the place's references
(``reference``: every training fingerprint, the medoid, or a consensus
string). With a field of view narrower than the circle and ``cyclic=False``,
the references' letters outside the query's field of view are dropped before
aligning, so empty space the query did not see costs nothing. With
``cyclic=True`` every rotation of a reference is tried (heading unknown), and
the term estimates the heading of a view at each place (:meth:`FingerprintTerm.headings`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..angles import TWO_PI
from ..errors import DatabaseError, InvalidParameterError
from ..fingerprint import Fingerprint, make_fingerprint
from ..metrics import min_per_place_groups
from ..observation import FULL_FOV, Observation
from .base import FArray
from .distance import DistanceTerm

__all__ = ["FingerprintTerm", "consensus_fingerprint", "crop_fingerprint"]

#: The latest batch of :meth:`FingerprintTerm.distances`: id -> (query, fingerprint, row of the costs), costs.
_Recent = tuple[dict[int, tuple[Observation, Fingerprint, int]], FArray | None]
#: Most costs (queries x references) of the latest batch kept for the headings (64 MB of float64).
_KEEP_COSTS = 1 << 23
#: Most views of a place whose heading is found by aligning each view once (more: their costs in one batch first).
_ALIGN_EACH = 8


class FingerprintTerm(DistanceTerm):
    """``P(Fp | Loc)`` from alignment costs to each place's stored fingerprints.

    Parameters
    ----------
    likelihood : {"paper", "exp"}
    reference : {"all", "medoid", "consensus"}
    cyclic : bool
        Align over every rotation of the references (heading unknown).
    costs : fingerloc.align.CostModel or None
        Edit costs (unit costs by default).
    empty_step_deg, merge_tol_deg, laser_letters
        Fingerprint generation (:func:`fingerloc.make_fingerprint`).
    need_unknown : bool
        Calibrate ``unknown_cost_`` even with the paper's likelihood.

    Attributes
    ----------
    fingerprints_ : list of list of Fingerprint
        Per place, the fingerprint of each training view.
    medoids_ : list of int
        Per place, the index of the training fingerprint with the least summed cost to the others.
    consensus_ : list of Fingerprint or None
        Per place, its average fingerprint (``reference="consensus"``).
    """

    name = "Fp"
    heading_free = True

    def __init__(
        self,
        *,
        likelihood: str = "paper",
        reference: str = "all",
        cyclic: bool = False,
        costs: Any = None,
        empty_step_deg: float = 20.0,
        merge_tol_deg: float = 5.0,
        laser_letters: bool = False,
        need_unknown: bool = False,
    ) -> None:
        self.likelihood = likelihood
        self.reference = reference
        self.cyclic = cyclic
        self.costs = costs
        self.empty_step_deg = empty_step_deg
        self.merge_tol_deg = merge_tol_deg
        self.laser_letters = laser_letters
        self.need_unknown = need_unknown
        self.heading_free = bool(cyclic)

    def fingerprint(self, obs: Observation) -> Fingerprint:
        """The fingerprint of one observation with this term's generation parameters."""
        return make_fingerprint(
            obs, empty_step_deg=self.empty_step_deg, merge_tol_deg=self.merge_tol_deg, laser_letters=self.laser_letters
        )

    def fingerprints(self, observations: Sequence[Observation]) -> list[Fingerprint]:
        """:meth:`fingerprint` of each observation, computed as one batch (the same strings and bearings)."""
        from .._fingerprints import make_fingerprints

        if len(observations) < 4:  # the batch's set-up costs more than a few single ones
            return [self.fingerprint(o) for o in observations]
        return make_fingerprints(
            observations, empty_step_deg=self.empty_step_deg, merge_tol_deg=self.merge_tol_deg, laser_letters=self.laser_letters
        )

    # -- learning --------------------------------------------------------------
    def fit(self, groups: Sequence[Sequence[Observation]]) -> FingerprintTerm:
        self.fingerprints_: list[list[Fingerprint]] = []
        self.medoids_: list[int] = []
        self.consensus_: list[Fingerprint | None] = []
        self._refit(groups, range(len(groups)))
        self.calibrate(groups)
        return self

    def update(self, groups: Sequence[Sequence[Observation]], changed: Sequence[int]) -> FingerprintTerm:
        self._refit(groups, changed)
        return self

    def _refit(self, groups: Sequence[Sequence[Observation]], changed: Sequence[int] | range) -> None:
        n = len(groups)
        grow = n - len(self.fingerprints_)
        self.fingerprints_ += [[] for _ in range(grow)]
        self.medoids_ += [0] * grow
        self.consensus_ += [None] * grow
        changed = list(changed)
        fps = self.fingerprints([o for j in changed for o in groups[j]])
        k = 0
        for j in changed:
            self.fingerprints_[j] = fps[k : k + len(groups[j])]
            k += len(groups[j])
        self._medoids(changed)
        if self.reference == "consensus":
            for j in changed:
                fps = self.fingerprints_[j]
                self.consensus_[j] = consensus_fingerprint(fps, costs=self.costs, cyclic=self.cyclic) if fps else None
        self._index()

    def _medoids(self, changed: Sequence[int] | range) -> None:
        """``medoids_[j]`` of the places ``changed``: the view with the least summed cost to the place's others.

        Every pair of views of every place in one call of
        :func:`~fingerloc.align.paired_alignment_costs` (the pairs of one place are few); the
        cost of ``(a, b)`` is that of ``(b, a)`` (the substitution costs are symmetric).
        """
        from ..align import paired_alignment_costs

        left: list[Fingerprint] = []
        right: list[Fingerprint] = []
        spans: list[tuple[int, int, int]] = []  # place, first pair, views
        for j in changed:
            fps = self.fingerprints_[j]
            self.medoids_[j] = 0
            if len(fps) > 1:
                spans.append((j, len(left), len(fps)))
                for a in range(len(fps)):
                    for b in range(a + 1, len(fps)):
                        left.append(fps[a])
                        right.append(fps[b])
        if not spans:
            return
        pair = paired_alignment_costs(left, right, cyclic=self.cyclic, costs=self.costs)
        for j, start, v in spans:
            d = np.zeros((v, v))
            upper = np.triu_indices(v, 1)
            d[upper] = pair[start : start + v * (v - 1) // 2]
            d.T[upper] = d[upper]
            self.medoids_[j] = int(np.argmin(d.sum(axis=1)))

    def _index(self) -> None:
        """Flatten the references: ``_refs`` and the first column of each place (``_starts``)."""
        refs: list[Fingerprint] = []
        owner: list[int] = []
        for j, fps in enumerate(self.fingerprints_):
            if self.reference == "all":
                chosen = fps
            elif self.reference == "medoid":
                chosen = [fps[self.medoids_[j]]]
            else:
                cons = self.consensus_[j]
                chosen = [cons if cons is not None else fps[self.medoids_[j]]]
            refs += chosen
            owner += [j] * len(chosen)
        self._refs = refs
        self._owner = np.asarray(owner, dtype=np.int64)
        self._starts = np.searchsorted(self._owner, np.arange(len(self.fingerprints_)))
        self._crop_cache: dict[Any, Any] = {}
        self._recent: _Recent = ({}, None)  # the latest batch's queries and costs (distances)
        self._last_query: tuple[Observation, Fingerprint] | None = None  # the latest single query's fingerprint

    def _loo_matrix(self, rows: NDArray[np.int64], cols: NDArray[np.int64] | None = None) -> FArray | None:
        from ..align import alignment_costs

        fps = [fp for g in self.fingerprints_ for fp in g]
        refs = fps if cols is None else [fps[i] for i in cols]
        return alignment_costs([fps[i] for i in rows], refs, cyclic=self.cyclic, costs=self.costs)

    # -- inference -------------------------------------------------------------
    def _references_for(self, fov: tuple[tuple[float, float], ...]) -> Any:
        """The references as a validated batch, cropped to a partial query ``fov`` (cached)."""
        from ..align import FingerprintBatch

        if self.cyclic or any(width >= TWO_PI - 1e-12 for _, width in fov):
            fov = FULL_FOV
        if fov not in self._crop_cache:
            refs = self._refs if fov == FULL_FOV else [crop_fingerprint(fp, fov) for fp in self._refs]
            self._crop_cache[fov] = FingerprintBatch(refs)
        return self._crop_cache[fov]

    def distances(self, observations: Sequence[Observation]) -> FArray:
        """Alignment cost of each observation to each place, shape ``(n, P)`` (per ``reference``).

        With ``cyclic`` every query is aligned against the same references
        (the field of view does not crop them), in one batch. The costs to
        every reference of the latest batch are kept (when not too many) for
        :meth:`heading_at`, with the queries' fingerprints.
        """
        from ..align import alignment_costs

        obs = list(observations)
        qfps = self.fingerprints(obs)
        out = np.full((len(obs), len(self.fingerprints_)), np.inf)
        groups: dict[Any, list[int]] = {}
        for i, o in enumerate(obs):
            groups.setdefault(FULL_FOV if self.cyclic else o.fov, []).append(i)
        recent: dict[int, tuple[Observation, Fingerprint, int]] = {}
        for fov, idx in groups.items():
            d = alignment_costs([qfps[i] for i in idx], self._references_for(fov), cyclic=self.cyclic, costs=self.costs)
            out[idx] = min_per_place_groups(d, self._starts)
            if self.cyclic and self.reference == "all" and d.size <= _KEEP_COSTS:
                recent = {id(obs[i]): (obs[i], qfps[i], r) for r, i in enumerate(idx)}
                self._recent = (recent, d)
        if not recent:
            self._recent = ({id(o): (o, f, -1) for o, f in zip(obs, qfps, strict=True)}, None)
        return out

    def place_references(self, places: Sequence[int] | np.ndarray) -> NDArray[np.int64]:
        """Indices into the references (``_refs``) of the given places, place after place."""
        counts = np.diff(np.append(self._starts, len(self._refs)))
        pl = np.asarray(places, dtype=np.int64)
        if pl.size == 0:
            return np.zeros(0, dtype=np.int64)
        first = self._starts[pl]
        n = counts[pl]
        return np.repeat(first - np.cumsum(n) + n, n) + np.arange(int(n.sum()))

    def distances_at(
        self,
        observations: Sequence[Observation],
        places: Sequence[int] | np.ndarray,
        *,
        fingerprints: Sequence[Fingerprint] | None = None,
    ) -> FArray:
        """:meth:`distances` at the given places only, shape ``(n, len(places))``: the same values.

        ``fingerprints``: those of the observations, when already at hand.
        """
        from ..align import alignment_costs

        obs = list(observations)
        pl = np.asarray(places, dtype=np.int64)
        out = np.full((len(obs), pl.size), np.inf)
        refs_idx = self.place_references(pl)
        counts = np.diff(np.append(self._starts, len(self._refs)))[pl]
        has = counts > 0
        if not obs or refs_idx.size == 0:
            return out
        starts = (np.cumsum(counts) - counts)[has]
        qfps = self.fingerprints(obs) if fingerprints is None else list(fingerprints)
        groups: dict[Any, list[int]] = {}
        for i, o in enumerate(obs):
            groups.setdefault(FULL_FOV if self.cyclic else o.fov, []).append(i)
        for fov, idx in groups.items():
            full = self.cyclic or any(width >= TWO_PI - 1e-12 for _, width in fov)
            refs = [self._refs[int(r)] for r in refs_idx]
            if not full:
                refs = [crop_fingerprint(fp, fov) for fp in refs]
            d = alignment_costs([qfps[i] for i in idx], refs, cyclic=self.cyclic, costs=self.costs)
            sub = out[idx]
            sub[:, has] = min_per_place_groups(d, starts)
            out[idx] = sub
        return out

    def log_likelihood_at(self, observations: Sequence[Observation], places: Sequence[int] | np.ndarray) -> FArray:
        return self._likelihood_of(self.distances_at(observations, places))

    def remember(self, observations: Sequence[Observation]) -> None:
        """Align the observations against every training view in one batch, for the next :meth:`heading_at` calls.

        :meth:`heading_at` then reuses each observation's fingerprint and
        its cyclic costs to every view (the same numbers it would compute
        one place at a time). Nothing is kept when the batch would be too
        large; observations already held by the latest batch are not
        aligned again.
        """
        from ..align import alignment_costs

        obs = list(observations)
        recent, d = self.__dict__.get("_recent", ({}, None))
        if self.reference != "all" or not obs or not self._refs or len(obs) * len(self._refs) > _KEEP_COSTS:
            return  # (with medoid or consensus references the batch does not hold every view)
        if d is not None and all((hit := recent.get(id(o))) is not None and hit[0] is o and hit[2] >= 0 for o in obs):
            return
        qfps = self.fingerprints(obs)
        d = alignment_costs(qfps, self._references_for(FULL_FOV), cyclic=True, costs=self.costs)
        self._recent = ({id(o): (o, f, r) for r, (o, f) in enumerate(zip(obs, qfps, strict=True))}, d)

    def _query(self, obs: Observation) -> tuple[Fingerprint, FArray | None]:
        """The fingerprint of a query and its costs to every reference, from the latest batch when it held it."""
        recent, d = self.__dict__.get("_recent", ({}, None))
        hit = recent.get(id(obs))
        if hit is not None and hit[0] is obs:
            return hit[1], (None if d is None or hit[2] < 0 else d[hit[2]])
        return self.query_fingerprint(obs), None

    def query_fingerprint(self, obs: Observation) -> Fingerprint:
        """:meth:`fingerprint` of one query, kept for the next call of the same observation (a search, then its heading)."""
        last = self.__dict__.get("_last_query")
        if last is not None and last[0] is obs:
            return last[1]
        fp = self.fingerprint(obs)
        self._last_query = (obs, fp)
        return fp

    def headings(self, observations: Sequence[Observation]) -> FArray | None:
        """Heading of each observation at each place, radians, shape ``(n, P)`` (NaN where none).

        The best cyclic alignment against the place's best-matching reference
        gives the angle to add to the reference's bearings to bring them onto
        the observation's (:class:`fingerloc.align.CyclicAlignment`).
        """
        from ..align import alignment_costs, cyclic_alignment

        obs = list(observations)
        qfps = self.fingerprints(obs)
        out = np.full((len(obs), len(self.fingerprints_)), np.nan)
        if not obs or not self._refs:
            return out
        d = alignment_costs(qfps, self._references_for(FULL_FOV), cyclic=True, costs=self.costs)
        bounds = [*self._starts.tolist(), len(self._refs)]
        for j in range(len(self.fingerprints_)):
            lo, hi = bounds[j], bounds[j + 1]
            if hi <= lo:
                continue
            best = lo + np.argmin(d[:, lo:hi], axis=1)
            for i, r in enumerate(best):
                h = cyclic_alignment(qfps[i], self._refs[int(r)], costs=self.costs).heading_deg
                if h is not None:
                    out[i, j] = math.radians(h)
        return out

    def heading_at(self, obs: Observation, place: int) -> tuple[float | None, int]:
        """Heading (degrees) of one view at one place, and the index of the training view it is measured against.

        The view is the first of the place's training views with the least
        cyclic cost. Only the views whose batch cost (:func:`fingerloc.align.alignment_costs`,
        from the latest :meth:`distances` call when it holds this query) is
        within 1e-9 of the least are aligned again with their alignment, so
        the answer is that of aligning every view; without the latest batch's
        costs, a place of at most :data:`_ALIGN_EACH` views has each view
        aligned once instead.
        """
        from ..align import alignment_costs, cyclic_heading

        q, row = self._query(obs)
        fps = self.fingerprints_[place]
        candidates: Sequence[int] = range(len(fps))
        if len(fps) > 1 and (row is not None or len(fps) > _ALIGN_EACH):  # else each view aligned once, below
            if row is not None:
                lo = int(self._starts[place])
                costs = row[lo : lo + len(fps)]
            else:
                costs = alignment_costs([q], fps, cyclic=True, costs=self.costs, workers=1)[0]  # a few views: no threads
            least = float(costs.min())
            candidates = np.flatnonzero(costs <= least + 1e-9 * max(1.0, abs(least))).tolist()
        best: tuple[float, float | None, int] | None = None
        for v in candidates:
            cost, heading = cyclic_heading(q, fps[v], costs=self.costs)
            if best is None or cost < best[0]:
                best = (cost, heading, v)
        return (None, -1) if best is None else (best[1], best[2])

    # -- state -----------------------------------------------------------------
    def to_state(self) -> dict[str, Any]:
        return {
            "fingerprints": [[(fp.letters, np.asarray(fp.bearings)) for fp in g] for g in self.fingerprints_],
            "medoids": list(self.medoids_),
            "consensus": [None if c is None else (c.letters, np.asarray(c.bearings)) for c in self.consensus_],
            **self._calibration_state(),
        }

    def set_state(self, state: dict[str, Any], groups: Sequence[Sequence[Observation]]) -> FingerprintTerm:
        try:
            fps = state.get("fingerprints")
            if fps is None:  # recompute from the observations
                fps = [[None] * len(g) for g in groups]
            # a view without a stored fingerprint: from the observation (all such views in one batch)
            missing = [o for fg, g in zip(fps, groups, strict=True) for f, o in zip(fg, g, strict=True) if f is None]
            fresh = iter(self.fingerprints(missing))
            self.fingerprints_ = [
                [next(fresh) if f is None else Fingerprint(f[0], np.asarray(f[1], dtype=np.float64)) for f in fg]
                for fg in fps
            ]
            self.medoids_ = [int(m) for m in state.get("medoids", [0] * len(groups))]
            cons = state.get("consensus") or [None] * len(groups)
            self.consensus_ = [None if c is None else Fingerprint(c[0], np.asarray(c[1], dtype=np.float64)) for c in cons]
        except (TypeError, ValueError, IndexError, InvalidParameterError) as err:
            raise DatabaseError(f"stored fingerprint term is malformed: {err}") from err
        n = len(groups)
        if not (len(self.fingerprints_) == len(self.medoids_) == len(self.consensus_) == n):
            raise DatabaseError(f"stored fingerprint term holds {len(self.fingerprints_)} places for {n}")
        for j, (g, m) in enumerate(zip(self.fingerprints_, self.medoids_, strict=True)):
            if g and not (0 <= m < len(g)):
                raise DatabaseError(f"place {j}: medoid {m} out of range 0..{len(g) - 1}")
        self._set_calibration_state(state)
        self._index()
        return self


def crop_fingerprint(fp: Fingerprint, fov: tuple[tuple[float, float], ...]) -> Fingerprint:
    """The letters of ``fp`` whose bearing lies inside ``fov`` (ranges of (start, width) radians)."""
    keep = np.zeros(len(fp), dtype=bool)
    for start, width in fov:
        keep = keep | np.asarray(np.mod(fp.bearings - start, TWO_PI) <= width)
    if keep.all():
        return fp
    letters = "".join(ch for ch, k in zip(fp.letters, keep, strict=True) if k)
    return Fingerprint(letters, fp.bearings[keep])


def consensus_fingerprint(
    fingerprints: Sequence[Fingerprint],
    *,
    costs: Any = None,
    cyclic: bool = False,
    max_rounds: int = 3,
) -> Fingerprint:
    """An average fingerprint of a place: an approximate median string.

    The median string minimises the summed alignment cost to the place's
    fingerprints. Finding it exactly is NP-hard, so we start from the medoid
    (the best of the given strings) and improve it greedily: for ``max_rounds``
    rounds, try deleting each letter, substituting it, and inserting a letter
    of the alphabet at each position, keeping any edit that lowers the summed
    cost. The result is never worse than the medoid. Letter bearings come from
    the medoid (inserted letters take their neighbour's bearing).
    """
    from ..align import alignment_costs
    from ..fingerprint import ALPHABET

    fps = list(fingerprints)
    if not fps:
        raise InvalidParameterError("consensus_fingerprint needs at least one fingerprint")
    if len(fps) == 1:
        return fps[0]
    d = alignment_costs(fps, fps, cyclic=cyclic, costs=costs)
    medoid = fps[int(np.argmin(d.sum(axis=1)))]
    best_s = medoid.letters
    best_b = list(medoid.bearings)

    def total(strings: list[str]) -> FArray:
        return alignment_costs(strings, fps, cyclic=cyclic, costs=costs).sum(axis=1)

    best_cost = float(total([best_s])[0])
    used = sorted(set("".join(fp.letters for fp in fps)) | {"n"}, key=ALPHABET.index)
    for _ in range(max_rounds):
        cands: list[tuple[str, list[float]]] = []
        s, b = best_s, best_b
        for i in range(len(s)):
            cands.append((s[:i] + s[i + 1 :], b[:i] + b[i + 1 :]))
            for ch in used:
                if ch != s[i]:
                    cands.append((s[:i] + ch + s[i + 1 :], b))
        for i in range(len(s) + 1):
            bb = b[i - 1] if i > 0 else (b[0] if b else 0.0)
            for ch in used:
                cands.append((s[:i] + ch + s[i:], [*b[:i], bb, *b[i:]]))
        if not cands:
            break
        tot = total([c[0] for c in cands])
        j = int(np.argmin(tot))
        if tot[j] >= best_cost - 1e-12:
            break
        best_cost = float(tot[j])
        best_s, best_b = cands[j]
    return Fingerprint(best_s, np.asarray(best_b, dtype=np.float64))
