"""Distance terms that index one feature of every training view: ``A``, ``AP`` and ``K``.

Each of these terms reads one feature of an observation (the appearance
descriptor, the column profile, the keypoints), keeps the feature of every
training view that carries one, and scores an observation by its distance to
the nearest such view of each place (:mod:`.distance`). What they share lives
here:

* the bookkeeping of the training views: which views carry the feature, the
  place (``owner_``) and the index within its place (``view_``) of each stored
  view, re-built from every place by :meth:`IndexedTerm.update`, which keeps
  ``lambda_`` and ``unknown_cost_``;
* fitting (check the parameters, index the views, calibrate), the "not
  fitted" check, the "no evidence" of observations without the feature, and
  the state for the place database (the term's parameters and its
  calibration; the features come back from the stored observations);
* a default scoring of one observation at a time against every stored view
  (:meth:`IndexedTerm._view_distances`), for the terms that cannot score a
  batch at once.

A subclass gives :meth:`IndexedTerm._feature` (the feature of an observation,
or None) and :meth:`IndexedTerm._store` (its own store of the training
features), and either :meth:`IndexedTerm._view_distances` or its own
:meth:`~.DistanceTerm.distances` and :meth:`~.DistanceTerm._loo_matrix`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Generic, Self, TypeVar

import numpy as np

from .._types import IArray
from ..errors import InvalidParameterError, NotFittedError
from ..observation import Observation
from .base import FArray
from .distance import DistanceTerm

__all__ = ["IndexedTerm"]

#: The feature a term reads from an observation.
F = TypeVar("F")
T = TypeVar("T")


def _first_mismatch(keys: Sequence[T]) -> tuple[T, T] | None:
    """The first of ``keys`` that differs from ``keys[0]``, and ``keys[0]``; None when all are equal."""
    return next(((k, keys[0]) for k in keys[1:] if k != keys[0]), None)


class IndexedTerm(DistanceTerm, Generic[F]):
    """Base of the distance terms that keep one feature of every training view (module docstring).

    Attributes
    ----------
    lambda_ : float
    unknown_cost_ : float or None
    n_places_ : int
        Number of places (``len(groups)``).
    owner_ : ndarray of int, shape (m,)
        Place index (into ``groups``) of each stored training view, non-decreasing.
    view_ : ndarray of int, shape (m,)
        Index of each stored training view among its place's training observations.
    """

    #: The term in error messages ("... term state is malformed").
    _label: str = ""

    # -- what the subclasses give ------------------------------------------------
    def _feature(self, o: Observation) -> F | None:
        """The term's feature of ``o``, or None when ``o`` carries none (the term says nothing of it)."""
        raise NotImplementedError

    def _store(self, features: list[F]) -> None:
        """Check and keep the features of the training views that carry one (in the order of ``groups``)."""
        raise NotImplementedError

    def _view_distances(self, feature: F) -> FArray:
        """Distance of one feature to each stored training view, shape ``(m,)``."""
        raise NotImplementedError

    def _params_state(self) -> dict[str, Any]:
        """The term's parameters in :meth:`to_state` (before the calibration)."""
        return {}

    def _params_from_state(self, state: dict[str, Any]) -> dict[str, Any]:
        """The parameters (attribute names and values) that :meth:`set_state` restores from ``state``."""
        return {}

    def _validate(self) -> None:
        mq = self.max_queries
        if isinstance(mq, bool) or not isinstance(mq, (int, np.integer)) or mq < 1:
            raise InvalidParameterError(f"max_queries must be an integer >= 1, got {mq!r}")

    # -- fitting -----------------------------------------------------------------
    def _index(self, groups: Sequence[Sequence[Observation]]) -> None:
        features: list[F] = []
        owner: list[int] = []
        view: list[int] = []
        for j, group in enumerate(groups):
            for i, o in enumerate(group):
                f = self._feature(o)
                if f is None:
                    continue
                features.append(f)
                owner.append(j)
                view.append(i)
        self._store(features)
        self.n_places_ = len(groups)
        self.owner_ = np.asarray(owner, dtype=np.int64)
        self.view_ = np.asarray(view, dtype=np.int64)
        self._features = features
        self._has = np.array([self._feature(o) is not None for g in groups for o in g], dtype=bool)

    def fit(self, groups: Sequence[Sequence[Observation]]) -> Self:
        """Store the feature of every training view and fit ``lambda_`` / ``unknown_cost_`` by leave-one-out."""
        self._validate()
        self._index(groups)
        self.calibrate(groups)
        return self

    def update(self, groups: Sequence[Sequence[Observation]], changed: Sequence[int]) -> Self:
        """Re-index the features of every place; ``lambda_`` and ``unknown_cost_`` are kept."""
        self._check_fitted()
        self._index(groups)
        return self

    def _check_fitted(self) -> None:
        if not hasattr(self, "owner_"):
            raise NotFittedError(f"this {type(self).__name__} is not fitted yet; call fit() first")

    def _loo_matrix(self, rows: IArray, cols: IArray | None = None) -> FArray | None:
        """Distances between training views; views without the feature are never anyone's neighbour."""
        if len(self._features) < 2:
            return None
        pos = np.cumsum(self._has) - 1  # stored view of each training view that carries the feature
        d = np.full((rows.size, self._has.size), np.inf)
        for k, r in enumerate(rows):
            if not self._has[r]:
                continue
            d[k, self._has] = self._view_distances(self._features[int(pos[r])])
        return d if cols is None else d[:, cols]

    # -- inference ---------------------------------------------------------------
    def _per_place(self, d: FArray) -> FArray:
        """Least distance to each place, shape ``(n, P)``; inf for a place without stored views."""
        out = np.full((d.shape[0], self.n_places_), np.inf)
        has = np.bincount(self.owner_, minlength=self.n_places_) > 0
        if d.shape[0] and has.any():
            starts = np.searchsorted(self.owner_, np.flatnonzero(has))
            out[:, has] = np.minimum.reduceat(d, starts, axis=1)
        return out

    def distances(self, observations: Sequence[Observation]) -> FArray:
        """Distance of each observation to the nearest view of each place, shape ``(n, P)``.

        Rows of observations without the feature are 0 (the term says
        nothing); a place without stored views gets the row's largest finite
        distance.
        """
        self._check_fitted()
        obs = list(observations)
        out = np.zeros((len(obs), self.n_places_))
        if self.owner_.size == 0:
            return out
        for i, o in enumerate(obs):
            f = self._feature(o)
            if f is None:
                continue
            per = self._per_place(self._view_distances(f)[None])[0]
            fin = np.isfinite(per)
            out[i] = np.where(fin, per, per[fin].max() if fin.any() else 0.0)
        return out

    def unknown_log_likelihood(self, observations: Sequence[Observation]) -> FArray:
        """``-lambda_ * unknown_cost_`` for observations with the feature, 0 for the others, shape ``(n,)``."""
        self._check_fitted()
        has = np.array([self._feature(o) is not None for o in observations], dtype=np.float64)
        return super().unknown_log_likelihood(observations) * has

    # -- state -------------------------------------------------------------------
    def to_state(self) -> dict[str, Any]:
        """The term's parameters, ``"lambda"`` and ``"unknown_cost"``; the features come back from the stored observations."""
        self._check_fitted()
        return {**self._params_state(), **self._calibration_state()}

    def set_state(self, state: dict[str, Any], groups: Sequence[Sequence[Observation]]) -> Self:
        """Restore from :meth:`to_state` and the places' stored observations (``groups``)."""
        try:
            lam = float(state["lambda"])
            unknown = state.get("unknown_cost")
            unknown = None if unknown is None else float(unknown)
            params = self._params_from_state(state)
        except (KeyError, TypeError, ValueError) as err:
            raise InvalidParameterError(f"{self._label} term state is malformed: {state!r}") from err
        if not (math.isfinite(lam) and lam > 0 and (unknown is None or (math.isfinite(unknown) and unknown >= 0))):
            raise InvalidParameterError(f"{self._label} term state is malformed: {state!r}")
        for key, value in params.items():
            setattr(self, key, value)
        self._validate()
        self._index(groups)
        self._set_calibration_state(state)
        return self

    @classmethod
    def from_state(cls, state: dict[str, Any], groups: Sequence[Sequence[Observation]]) -> Self:
        """A fitted term from :meth:`to_state` and the places' stored observations."""
        return cls().set_state(state, groups)
