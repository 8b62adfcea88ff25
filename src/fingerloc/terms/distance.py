"""Terms whose likelihood is a function of a distance to a place's stored views.

``P(term | loc) ∝ exp(-lambda * d(obs, loc))``, ``d`` the least distance to the
place's references, ``lambda`` chosen on the training data; the fingerprint
term also has the paper's form ``1 / (d + 1)``. Shared here:

* **calibration** (leave-one-out on the training views): ``unknown_cost_`` is
  the median distance of a training view to the nearest *other* place, and
  ``lambda_`` maximises the mean leave-one-out log-probability of the right
  place under the term alone (:func:`fit_lambda`). At most ``max_queries``
  training views (a fixed seeded sample) serve as queries. When the queries
  times the training views would pass ``max_pairs`` (6 million: 1,000 places
  of 3 views), the calibration runs on a *sample of places* instead: places
  drawn at random (seeded) until their views fill ``max_pairs / max_queries``
  (3,000 views), the queries among their views, distances only to their
  views. Learning then costs the same calibration whatever the size of the
  map. ``lambda_`` hardly depends on the number of places (the tilted mean of
  the distances to the other places sets it); ``unknown_cost_``, the distance
  to the nearest other place, is larger on a sample (fewer places to be
  near). ``calibration_`` says which was done;
* the "unknown place" likelihood: the term's likelihood at ``unknown_cost_``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.special import logsumexp

from ..metrics import min_per_place_groups
from ..observation import Observation
from .base import FArray, Term

__all__ = ["DistanceTerm", "fit_lambda"]


class DistanceTerm(Term):
    """Base of the distance terms; subclasses give :meth:`distances` and :meth:`_loo_matrix`.

    Attributes
    ----------
    lambda_ : float
        Scale of the exponential form (1 until calibrated).
    unknown_cost_ : float or None
        Distance that stands for "no learned place" (None until calibrated).
    calibration_ : dict
        What the latest calibration used: ``sampled`` (a sample of places, see the module
        docstring), ``queries``, ``views`` and ``places``; empty when none was needed.
    """

    #: "exp" or "paper" (``1 / (d + 1)``, the fingerprint term only)
    likelihood: str = "exp"
    #: compute ``unknown_cost_`` even when ``lambda_`` needs no calibration
    need_unknown: bool = False
    max_queries: int = 2000
    #: most distances (queries x training views) a calibration computes; beyond, a sample of places
    max_pairs: int = 6_000_000
    #: search interval of ``lambda_``
    lambda_bounds: tuple[float, float] = (1e-3, 1e4)

    def distances(self, observations: Sequence[Observation]) -> FArray:
        """Least distance of each observation to each place, shape ``(n, P)``."""
        raise NotImplementedError

    def _loo_matrix(self, rows: NDArray[np.int64], cols: NDArray[np.int64] | None = None) -> FArray | None:
        """Distances of training views ``rows`` to training views ``cols`` (default: every one), ``(len(rows), len(cols))``.

        ``inf`` where undefined; None when the term has nothing to calibrate on.
        """
        raise NotImplementedError

    def _reset_calibration(self) -> None:
        self.lambda_ = 1.0
        self.unknown_cost_: float | None = None
        self.calibration_: dict[str, Any] = {}

    def _wants_calibration(self) -> bool:
        return self.likelihood == "exp" or self.need_unknown

    def calibrate(self, groups: Sequence[Sequence[Observation]]) -> None:
        """Leave-one-out calibration of ``lambda_`` and ``unknown_cost_`` (module docstring)."""
        self._reset_calibration()
        n_places = len(groups)
        if n_places < 2 or not self._wants_calibration():
            return
        owner = np.array([j for j, g in enumerate(groups) for _ in g], dtype=np.int64)
        cols, sub_owner = None, owner
        if min(owner.size, self.max_queries) * owner.size > self.max_pairs:
            cols, sub_owner = _sample_places(owner, n_places, self._sample_views())
        n_views = sub_owner.size
        rows = np.arange(n_views)  # positions among the calibration's views
        if n_views > self.max_queries:
            rows = np.sort(np.random.default_rng(0).choice(n_views, self.max_queries, replace=False))
        self.calibration_ = {
            "sampled": cols is not None,
            "queries": int(rows.size),
            "views": int(n_views),
            "places": int(np.unique(sub_owner).size),
        }
        d = self._loo_matrix(rows, None) if cols is None else self._loo_matrix(cols[rows], cols)
        if d is None:
            return
        d[np.arange(rows.size), rows] = np.inf  # leave one out
        if cols is None:
            c_all = min_per_place_groups(d, np.searchsorted(owner, np.arange(n_places)))
            truth = owner[rows]
        else:  # the sample's places, numbered 0 .. m - 1
            dense = np.searchsorted(np.unique(sub_owner), sub_owner)
            c_all = min_per_place_groups(d, np.searchsorted(dense, np.arange(int(dense[-1]) + 1)))
            truth = dense[rows]
        ok = np.isfinite(c_all[np.arange(rows.size), truth])
        if not ok.any():
            return
        c, t = c_all[ok], truth[ok]
        wrong = c.copy()
        wrong[np.arange(t.size), t] = np.inf
        nearest_wrong = wrong.min(axis=1)
        if np.isfinite(nearest_wrong).any():
            self.unknown_cost_ = float(np.median(nearest_wrong[np.isfinite(nearest_wrong)]))
        if self.likelihood == "exp":
            self.lambda_ = fit_lambda(c, t, bounds=self.lambda_bounds)

    def _sample_views(self) -> int:
        """Views of the sample of places a calibration beyond ``max_pairs`` uses."""
        per_query = self.max_pairs // max(1, self.max_queries)
        return int(per_query if per_query >= self.max_queries else math.isqrt(self.max_pairs))

    def _likelihood_of(self, d: FArray) -> FArray:
        if self.likelihood == "paper":
            return np.asarray(-np.log1p(d))  # P(Fp|loc) = 1 / (cost + 1)
        return np.asarray(-self.lambda_ * d)  # P(term|loc) ∝ exp(-lambda d)

    def log_likelihood(self, observations: Sequence[Observation], *, rotations: FArray | None = None) -> FArray:
        return self._likelihood_of(self.distances(observations))

    def unknown_log_likelihood(self, observations: Sequence[Observation]) -> FArray:
        c = 0.0 if self.unknown_cost_ is None else self.unknown_cost_
        return np.full(len(observations), float(self._likelihood_of(np.array([c]))[0]))

    def _calibration_state(self) -> dict[str, Any]:
        return {"lambda": self.lambda_, "unknown_cost": self.unknown_cost_}

    def _set_calibration_state(self, state: dict[str, Any]) -> None:
        self.lambda_ = float(state.get("lambda", 1.0))
        u = state.get("unknown_cost")
        self.unknown_cost_ = None if u is None else float(u)


def _sample_places(owner: NDArray[np.int64], n_places: int, n_views: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Training views of places drawn at random (seeded) until ``n_views`` views: their indices (ascending) and places.

    At least two places are drawn.
    """
    counts = np.bincount(owner, minlength=n_places)
    order = np.random.default_rng(0).permutation(n_places)
    filled = np.cumsum(counts[order])
    take = max(2, int(np.searchsorted(filled, n_views, side="left")) + 1)
    chosen = np.zeros(n_places, dtype=bool)
    chosen[order[:take]] = True
    cols = np.flatnonzero(chosen[owner])
    return cols, owner[cols]


def fit_lambda(c: FArray, truth: NDArray[np.int64], *, bounds: tuple[float, float] = (1e-3, 1e4)) -> float:
    """``lambda`` maximising the mean ``log softmax(-lambda c)[truth]`` over the rows of ``c``.

    Parameters
    ----------
    c : ndarray, shape (n, P)
        Leave-one-out distances of ``n`` training views to the ``P`` places
        (``inf`` for a place with no other view).
    truth : ndarray of int, shape (n,)
        The place of each view.
    bounds : (float, float)
        Search interval.
    """
    from scipy.optimize import minimize_scalar

    cf = np.where(np.isfinite(c), c, np.nanmax(np.where(np.isfinite(c), c, np.nan)) * 10 + 1)
    rows = np.arange(truth.size)

    def nll(log_lam: float) -> float:
        ll = -math.exp(log_lam) * cf
        return float(-(ll[rows, truth] - logsumexp(ll, axis=1)).mean())

    res = minimize_scalar(nll, bounds=(math.log(bounds[0]), math.log(bounds[1])), method="bounded")
    return float(math.exp(res.x))
