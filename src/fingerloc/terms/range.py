"""The range term ``R`` (our extension for 2D lasers): a heading-free distance between range distributions.

``P(R | loc) ∝ exp(-lambda_R d(R, R_loc))``, ``d`` the L1 distance between
cumulative range histograms (an earth mover's distance between the
distributions of beam ranges, in bins) to the nearest training scan of
``loc``, ``lambda_R`` fit leave-one-out on the training scans
(:mod:`.distance`). Observations need their raw ranges (``Observation.ranges``);
the term keeps only each training scan's descriptor (``len(bins) + 1``
floats), not the scan.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DatabaseError, InvalidParameterError
from ..observation import Observation
from .base import FArray
from .distance import DistanceTerm

__all__ = [
    "RangeTerm",
    "cumulative_range_histogram",
    "descriptors_from_counts",
    "range_counts",
    "range_counts_many",
    "range_descriptor",
]


class RangeTerm(DistanceTerm):
    """``P(R | Loc)`` from range histograms.

    Parameters
    ----------
    bin_m, max_m : float
        Bin width and last bin edge (metres); ranges beyond ``max_m`` and
        beams without return share one last bin.

    Attributes
    ----------
    descriptors_ : list of ndarray, each (v_j, len(bins) + 1)
        Per place, the descriptor of each training view that carries ranges.
    counts_ : list of (ndarray of int64, each (v_j, len(bins) + 1), or None)
        Per place, the beam counts per bin the descriptors come from
        (:func:`descriptors_from_counts`); ``None`` for a place read from a
        database that stored only the descriptors. The place database keeps
        these small integers instead of the float64 descriptors.
    """

    name = "R"
    heading_free = True
    likelihood = "exp"

    def __init__(self, *, bin_m: float = 0.25, max_m: float = 10.0) -> None:
        self.bin_m = bin_m
        self.max_m = max_m

    def bins(self) -> FArray:
        """Upper bin edges, metres."""
        return np.arange(self.bin_m, self.max_m + 1e-9, self.bin_m)

    def _descriptors(self, group: Sequence[Observation]) -> FArray:
        return descriptors_from_counts(self._counts(group))

    def descriptor(self, obs: Observation) -> FArray:
        """The cumulative range histogram of one observation (:func:`range_descriptor`)."""
        return range_descriptor(obs, self.bins())

    def _counts(self, group: Sequence[Observation]) -> NDArray[np.int64]:
        width = self.bins().size + 1
        rows = [range_counts(o.ranges, self.bins()) for o in group if o.ranges is not None]
        return np.stack(rows) if rows else np.zeros((0, width), dtype=np.int64)

    def _counts_by_place(self, groups: Sequence[Sequence[Observation]]) -> list[NDArray[np.int64]]:
        """:meth:`_counts` of each group, the beams of every view binned in one call."""
        bins = self.bins()
        views = [o for g in groups for o in g if o.ranges is not None]
        per = [sum(1 for o in g if o.ranges is not None) for g in groups]
        counts = range_counts_many([o.ranges for o in views], bins)  # type: ignore[misc]
        starts = np.concatenate([[0], np.cumsum(per)]).astype(np.int64)
        return [counts[starts[j] : starts[j + 1]] for j in range(len(groups))]

    def fit(self, groups: Sequence[Sequence[Observation]]) -> RangeTerm:
        self.counts_: list[NDArray[np.int64] | None] = list(self._counts_by_place(groups))
        self.descriptors_ = [descriptors_from_counts(c) for c in self.counts_ if c is not None]
        self._n_seen = [len(g) for g in groups]
        self._index()
        self.calibrate(groups)
        return self

    def update(self, groups: Sequence[Sequence[Observation]], changed: Sequence[int]) -> RangeTerm:
        """Describe the views appended to the places ``changed`` since the last fit or update.

        Views already described keep their descriptors, so a place database
        that stores descriptors instead of scans can still grow.
        """
        width = self.bins().size + 1
        grow = len(groups) - len(self.descriptors_)
        self.descriptors_ += [np.zeros((0, width)) for _ in range(grow)]
        self.counts_ += [np.zeros((0, width), dtype=np.int64) for _ in range(grow)]
        self._n_seen += [0] * grow
        for j in changed:
            fresh = self._counts(groups[j][self._n_seen[j] :])
            self.descriptors_[j] = np.vstack([self.descriptors_[j], descriptors_from_counts(fresh)])
            old = self.counts_[j]
            self.counts_[j] = None if old is None else np.vstack([old, fresh])
            self._n_seen[j] = len(groups[j])
        self._index()
        return self

    def _index(self) -> None:
        self._starts: NDArray[np.int64] | None = None
        self._described: bool | None = None
        width = self.bins().size + 1
        self._refs = np.vstack(self.descriptors_) if self.descriptors_ else np.zeros((0, width))
        self._owner = np.repeat(np.arange(len(self.descriptors_)), [d.shape[0] for d in self.descriptors_])

    def _loo_matrix(self, rows: NDArray[np.int64], cols: NDArray[np.int64] | None = None) -> FArray | None:
        """Distances between training views; the views without ranges are never anyone's neighbour."""
        from scipy.spatial.distance import cdist

        if self._refs.shape[0] == 0:
            return None
        # one row per training view: views without ranges have none, so index the views that carry one
        has = self._has_ranges
        desc = np.zeros((has.size, self._refs.shape[1]))
        desc[has] = self._refs
        if cols is None:
            d = cdist(desc[rows], desc, metric="cityblock")
            d[:, ~has] = np.inf
        else:
            d = cdist(desc[rows], desc[cols], metric="cityblock")
            d[:, ~has[cols]] = np.inf
        d[~has[rows]] = np.inf
        return d

    def calibrate(self, groups: Sequence[Sequence[Observation]]) -> None:
        self._has_ranges = np.array([o.ranges is not None for g in groups for o in g], dtype=bool)
        super().calibrate(groups)

    def distances(self, observations: Sequence[Observation]) -> FArray:
        """Range distance of each observation to each place, shape ``(n, P)``.

        Rows of observations without ranges are 0 (the term says nothing); a
        place without any training ranges gets the row's largest finite distance.
        """
        from scipy.spatial.distance import cdist

        obs = list(observations)
        n_places = len(self.descriptors_)
        out = np.zeros((len(obs), n_places))
        idx = [i for i, o in enumerate(obs) if o.ranges is not None]
        if not idx or self._refs.shape[0] == 0:
            return out
        q = np.stack([self.descriptor(obs[i]) for i in idx])
        d = cdist(q, self._refs, metric="cityblock")
        per = np.full((len(idx), n_places), np.inf)
        has = np.bincount(self._owner, minlength=n_places) > 0
        starts = np.searchsorted(self._owner, np.arange(n_places))
        per[:, has] = np.minimum.reduceat(d, starts[has], axis=1)
        worst = np.max(np.where(np.isfinite(per), per, -np.inf), axis=1, keepdims=True)
        out[idx] = np.where(np.isfinite(per), per, worst)
        return out

    def every_place_described(self) -> bool:
        """Whether every place has a training view with ranges (else a place's distance depends on the others')."""
        known = self.__dict__.get("_described")
        if known is None:
            known = self._described = bool(self.descriptors_) and all(d.shape[0] > 0 for d in self.descriptors_)
        return bool(known)

    def distances_at(
        self, observations: Sequence[Observation], places: Sequence[int] | np.ndarray, *, descriptors: FArray | None = None
    ) -> FArray:
        """:meth:`distances` at the given places only, shape ``(n, len(places))``: the same values.

        A place without any training ranges gets the row's largest distance over *every* place in
        :meth:`distances`; when there is one, all places are scored. ``descriptors``: those of the
        observations that have ranges, when already at hand.
        """
        from scipy.spatial.distance import cdist

        pl = np.asarray(places, dtype=np.int64)
        if not self.every_place_described():
            return self.distances(observations)[:, pl]
        obs = list(observations)
        out = np.zeros((len(obs), pl.size))
        idx = [i for i, o in enumerate(obs) if o.ranges is not None]
        if not idx or pl.size == 0:
            return out
        q = np.stack([self.descriptor(obs[i]) for i in idx]) if descriptors is None else descriptors
        starts = self.__dict__.get("_starts")
        if starts is None or starts.size != len(self.descriptors_) + 1:
            starts = self._starts = np.append(np.searchsorted(self._owner, np.arange(len(self.descriptors_))), self._owner.size)
        counts = starts[pl + 1] - starts[pl]
        rows = self._refs[np.repeat(starts[pl] - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()))]
        d = cdist(q, rows, metric="cityblock")
        out[idx] = np.minimum.reduceat(d, np.cumsum(counts) - counts, axis=1)
        return out

    def log_likelihood_at(self, observations: Sequence[Observation], places: Sequence[int] | np.ndarray) -> FArray:
        return self._likelihood_of(self.distances_at(observations, places))

    def unknown_log_likelihood(self, observations: Sequence[Observation]) -> FArray:
        """The likelihood at ``unknown_cost_`` for views with ranges, 0 (no evidence) for the others."""
        has = np.array([o.ranges is not None for o in observations], dtype=float)
        return super().unknown_log_likelihood(observations) * has

    def to_state(self) -> dict[str, Any]:
        return {
            "descriptors": [d.copy() for d in self.descriptors_],
            "counts": [None if c is None else c.copy() for c in self.__dict__.get("counts_", [None] * len(self.descriptors_))],
            **self._calibration_state(),
        }

    def set_state(self, state: dict[str, Any], groups: Sequence[Sequence[Observation]]) -> RangeTerm:
        """Restore the term: per place its beam counts (``state["counts"]``), else its descriptors, else the scans."""
        width = self.bins().size + 1
        descs = state.get("descriptors")
        counts = state.get("counts")
        if descs is None and counts is None:  # recompute from the observations (databases that stored raw ranges)
            self.counts_ = [self._counts(g) for g in groups]
            self.descriptors_ = [descriptors_from_counts(c) for c in self.counts_ if c is not None]
        else:
            n = len(counts if counts is not None else descs)  # type: ignore[arg-type]
            self.counts_ = []
            self.descriptors_ = []
            try:
                for j in range(n):
                    c = None if counts is None else counts[j]
                    if c is not None:
                        c = np.asarray(c, dtype=np.int64).reshape(-1, width)
                        if np.any(c < 0):
                            raise DatabaseError("stored range counts are negative")
                        self.descriptors_.append(descriptors_from_counts(c))
                    elif descs is not None and descs[j] is not None:
                        self.descriptors_.append(np.asarray(descs[j], dtype=np.float64).reshape(-1, width))
                    else:
                        raise DatabaseError(f"stored range term: place {j} has neither counts nor descriptors")
                    self.counts_.append(c)
            except ValueError as err:
                raise DatabaseError(f"stored range descriptors do not have {width} columns") from err
        if len(self.descriptors_) != len(groups):
            raise DatabaseError(f"stored range term holds {len(self.descriptors_)} places for {len(groups)}")
        self._n_seen = [len(g) for g in groups]
        self._set_calibration_state(state)
        self._index()
        return self


def range_descriptor(obs: Observation, bins: FArray) -> FArray:
    """Cumulative histogram of an observation's beam ranges, shape ``(len(bins) + 1,)``.

    ``bins`` are the upper edges (metres) of all but the last bin; ranges at
    or beyond the last edge and beams without return fall in the last bin.
    The histogram is normalised to sum 1 before the cumulative sum, so the
    last entry is 1 and L1 distances between descriptors are earth mover's
    distances (in bins) between the range distributions.
    """
    if obs.ranges is None:
        raise InvalidParameterError("the range term needs observations with ranges (Observation.ranges)")
    return cumulative_range_histogram(obs.ranges, bins)


def range_counts(ranges: FArray, bins: FArray) -> NDArray[np.int64]:
    """Beams per bin of a range profile, shape ``(len(bins) + 1,)`` (see :func:`cumulative_range_histogram`)."""
    r = np.asarray(ranges, dtype=np.float64)
    idx = np.searchsorted(bins, np.where(np.isfinite(r), r, np.inf), side="right")
    return np.bincount(np.minimum(idx, bins.size), minlength=bins.size + 1)


def range_counts_many(ranges: Sequence[FArray], bins: FArray) -> NDArray[np.int64]:
    """:func:`range_counts` of many range profiles at once, shape ``(len(ranges), len(bins) + 1)``."""
    width = bins.size + 1
    out = np.zeros((len(ranges), width), dtype=np.int64)
    step = 4096  # profiles a call: bounded temporary memory (a map's views at once would take gigabytes)
    for a in range(0, len(ranges), step):
        part = ranges[a : a + step]
        sizes = np.fromiter((r.size for r in part), dtype=np.int64, count=len(part))
        r = np.concatenate([np.asarray(x, dtype=np.float64) for x in part])
        idx = np.minimum(np.searchsorted(bins, np.where(np.isfinite(r), r, np.inf), side="right"), bins.size)
        view = np.repeat(np.arange(len(part)), sizes)
        out[a : a + len(part)] = np.bincount(view * width + idx, minlength=len(part) * width).reshape(len(part), width)
    return out


def descriptors_from_counts(counts: NDArray[np.int64]) -> FArray:
    """Cumulative histograms of rows of beam counts, shape ``counts.shape``: each row divided by its sum, then summed up.

    The very values of :func:`cumulative_range_histogram` (a row of zeros gives all ones).
    """
    h = np.asarray(counts).astype(np.float64)
    if h.ndim == 1:
        total = h.sum()
        return np.cumsum(h / total) if total > 0 else np.ones(h.size)
    out = np.ones(h.shape)
    total = h.sum(axis=1)
    live = total > 0
    out[live] = np.cumsum(h[live] / total[live, None], axis=1)
    return out


def cumulative_range_histogram(ranges: FArray, bins: FArray) -> FArray:
    """Cumulative histogram of beam ranges (metres), shape ``(len(bins) + 1,)``; see :func:`range_descriptor`.

    ``bins`` are the upper edges of all but the last bin (a range equal to an
    edge falls in the bin above it); ranges at or beyond the last edge and
    beams without return (``inf``, ``nan``) fall in the last bin. The counts
    are divided by the number of beams, so the last entry is 1 (all ones for
    an empty scan).
    """
    return descriptors_from_counts(range_counts(ranges, bins))
