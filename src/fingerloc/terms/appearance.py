"""The appearance term ``A``: how the whole view looks, whatever the heading.

The camera's analogue of the laser's range term ``R``: each observation may
carry a heading-free appearance descriptor (``Observation.appearance``, e.g.
the square roots of the colour and gradient histograms of three strips of
elevation of :func:`fingerloc.features.vision.appearance_descriptor`). The
term compares it with the descriptors of every training view of every place:

    d(o, place)        = min over the place's training views v of D(o.appearance, v.appearance)
    log P(A | place)   = -lambda * d(o, place)          (up to a constant shared by the places)

``D`` is the L1 distance (``metric="l1"``) or the Hellinger distance
(``metric="hellinger"``: ``sqrt(sum (sqrt a - sqrt b)^2)``, for histograms).
``lambda`` is fit by leave-one-out on the training views: each training view
in turn is a query against the others, and ``lambda`` maximises the mean
log-probability of its own place under this term alone (a softmax over the
places of ``-lambda d``). The "no learned place" hypothesis scores
``-lambda * unknown_cost_``, the median leave-one-out distance of a training
view to the nearest *other* place.

Observations without a descriptor get a zero row (the term says nothing); a
place whose training views have none gets the row's largest distance.
Descriptors of different lengths cannot be compared: when the lengths are
those of two versions of fingerloc's own descriptor (94 numbers: version 1,
222: version 2), the error names both versions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._types import IArray
from ..errors import InvalidParameterError
from ..observation import Observation
from .base import FArray
from .distance import fit_lambda
from .indexed import IndexedTerm, _first_mismatch

__all__ = ["METRICS", "AppearanceTerm", "fit_lambda"]

#: Distances between appearance descriptors.
METRICS: tuple[str, ...] = ("l1", "hellinger")


#: Descriptor lengths of fingerloc's own panorama descriptor versions (kept in step with
#: ``fingerloc.features.vision.APPEARANCE_VERSIONS``; not imported, so that this module stays light).
_DESCRIPTOR_VERSIONS: dict[int, int] = {94: 1, 222: 2}


def _versions_hint(a: int, b: int) -> str:
    """What to do when two descriptor lengths differ because fingerloc's descriptor changed."""
    va, vb = _DESCRIPTOR_VERSIONS.get(a), _DESCRIPTOR_VERSIONS.get(b)
    if va is None or vb is None:
        return ""
    return (
        f" (appearance descriptor versions {va} and {vb}: the features were extracted by different fingerloc "
        "versions; extract the references and the queries again with one version and learn again)"
    )


class AppearanceTerm(IndexedTerm[FArray]):
    """The heading-free appearance term ``A`` of the Bayesian program.

    Parameters
    ----------
    metric : {"l1", "hellinger"}, default "l1"
        Distance between two descriptors.
    max_queries : int, default 2000
        At most this many training views (a seeded sample) serve as
        leave-one-out queries when fitting ``lambda_``.
    lambda_bounds : (float, float), default (1e-3, 1e4)
        Search interval of ``lambda_``.

    Attributes
    ----------
    lambda_ : float
        Inverse temperature of the term (1 / distance unit); 1 when fewer
        than two places have descriptors.
    unknown_cost_ : float or None
        Distance scored by the "no learned place" hypothesis.
    refs_ : ndarray, shape (m, d)
        Descriptors of the training views that have one, grouped by place.
    owner_ : ndarray of int, shape (m,)
        Place index (into ``groups``) of each row of ``refs_``, non-decreasing.
    n_places_ : int
    """

    name = "A"
    heading_free = True
    likelihood = "exp"
    _label = "appearance"

    def __init__(
        self,
        *,
        metric: str = "l1",
        max_queries: int = 2000,
        lambda_bounds: tuple[float, float] = (1e-3, 1e4),
    ) -> None:
        self.metric = metric
        self.max_queries = max_queries
        self.lambda_bounds = lambda_bounds

    def __repr__(self) -> str:
        return f"AppearanceTerm(metric={self.metric!r}, max_queries={self.max_queries!r})"

    def _validate(self) -> None:
        if self.metric not in METRICS:
            raise InvalidParameterError(f"metric must be one of {', '.join(METRICS)}, got {self.metric!r}")
        super()._validate()
        lo, hi = (float(v) for v in self.lambda_bounds)
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
            raise InvalidParameterError(f"lambda_bounds must satisfy 0 < low < high, got {self.lambda_bounds!r}")

    # -- fitting -----------------------------------------------------------------
    def _feature(self, o: Observation) -> FArray | None:
        return o.appearance

    def _store(self, features: list[FArray]) -> None:
        bad = _first_mismatch([a.size for a in features])
        if bad is not None:
            raise InvalidParameterError(
                f"appearance: every descriptor must have the same length, got {bad[0]} and {bad[1]}"
                f"{_versions_hint(*bad)}"
            )
        self.refs_ = np.stack(features) if features else np.zeros((0, 0))

    def _loo_matrix(self, rows: IArray, cols: IArray | None = None) -> FArray | None:
        """Distances between training views; views without a descriptor are never anyone's neighbour."""
        if self.refs_.shape[0] < 2:
            return None
        desc = np.zeros((self._has.size, self.refs_.shape[1]))
        desc[self._has] = self.refs_
        cc = np.arange(self._has.size) if cols is None else cols
        d = self._pairwise(desc[rows], desc[cc])
        d[:, ~self._has[cc]] = np.inf
        d[~self._has[rows]] = np.inf
        return d

    # -- inference ---------------------------------------------------------------
    def _pairwise(self, a: FArray, b: FArray) -> FArray:
        from scipy.spatial.distance import cdist

        if self.metric == "hellinger":
            return cdist(np.sqrt(a), np.sqrt(b), metric="euclidean")
        return cdist(a, b, metric="cityblock")

    def distances(self, observations: Sequence[Observation]) -> FArray:
        """Distance of each observation to each place, shape ``(n, P)`` (see the module docstring)."""
        self._check_fitted()
        obs = list(observations)
        out = np.zeros((len(obs), self.n_places_))
        idx = [i for i, o in enumerate(obs) if o.appearance is not None]
        if not idx or self.refs_.shape[0] == 0:
            return out
        q = np.stack([obs[i].appearance for i in idx])  # type: ignore[misc]
        if q.shape[1] != self.refs_.shape[1]:
            raise InvalidParameterError(
                f"appearance: the observations' descriptors have length {q.shape[1]}, "
                f"the learned places' {self.refs_.shape[1]}{_versions_hint(q.shape[1], self.refs_.shape[1])}"
            )
        per = self._per_place(self._pairwise(q, self.refs_))
        worst = np.max(np.where(np.isfinite(per), per, -np.inf), axis=1, keepdims=True)
        out[idx] = np.where(np.isfinite(per), per, worst)
        return out

    # -- state -------------------------------------------------------------------
    def _params_state(self) -> dict[str, Any]:
        """``{"metric"}``, before ``"lambda"`` and ``"unknown_cost"`` in :meth:`to_state`."""
        return {"metric": self.metric}

    def _params_from_state(self, state: dict[str, Any]) -> dict[str, Any]:
        return {"metric": state["metric"]}
