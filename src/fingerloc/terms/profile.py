"""The aligned-profile term ``AP``: the view bearing by bearing, compared over every rotation.

Each observation may carry a column profile (``Observation.profile``, e.g.
:func:`fingerloc.features.vision.column_profile`: coarse cells of the band
around the horizon, rows = bearings). The term turns the query's profile
over every whole-row rotation against each training view's profile and keeps
the best circular correlation:

    rho(o, v)          = max over shifts s of mean_k,c  o.profile[k, c] * v.profile[k + s, c]
    d(o, place)        = min over the place's training views v of (1 - rho(o, v))
    log P(AP | place)  = -lambda * d(o, place)          (up to a constant shared by the places)

so, unlike the heading-free appearance term ``A`` (histograms), it sees
*where* around the robot each colour and structure is, whatever the heading.
``lambda`` and ``unknown_cost_`` are calibrated leave-one-out on the
training views, as for ``A`` (:mod:`.distance`).

The shift of the best view also gives the heading between the query and that
view (:meth:`ProfileTerm.heading_at`), refined between rows by a parabola.
Observations without a profile get a zero row (the term says nothing).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._types import IArray
from ..errors import InvalidParameterError, NotFittedError
from ..observation import Observation
from .base import FArray
from .distance import DistanceTerm

__all__ = ["ProfileTerm", "profile_peaks"]


def profile_peaks(query: FArray, refs_fft: Any, n_cols: int) -> tuple[FArray, FArray]:
    """Best correlation and its refined shift (rows) of one profile against many, shapes ``(m,)``.

    ``refs_fft``: ``np.fft.rfft`` of the reference profiles along their rows, shape ``(m, n_cols // 2 + 1, c)``.
    """
    fq = np.conj(np.fft.rfft(query, axis=0))
    corr = np.fft.irfft((fq[None] * refs_fft).sum(axis=2), n=n_cols, axis=1) / query.size  # (m, n_cols)
    k = np.argmax(corr, axis=1)
    rows = np.arange(corr.shape[0])
    y0, y1, y2 = corr[rows, k - 1], corr[rows, k], corr[rows, (k + 1) % n_cols]
    den = y0 - 2.0 * y1 + y2
    frac = np.where(den < 0, 0.5 * (y0 - y2) / np.where(den < 0, den, -1.0), 0.0)
    return np.asarray(y1, dtype=np.float64), np.asarray(k + frac, dtype=np.float64)


class ProfileTerm(DistanceTerm):
    """The aligned-profile term ``AP`` of the Bayesian program (module docstring).

    Parameters
    ----------
    max_queries : int, default 2000
        At most this many training views (a seeded sample) serve as
        leave-one-out queries when fitting ``lambda_``.

    Attributes
    ----------
    lambda_ : float
    unknown_cost_ : float or None
    n_places_ : int
    """

    name = "AP"
    heading_free = True
    likelihood = "exp"

    def __init__(self, *, max_queries: int = 2000) -> None:
        self.max_queries = max_queries

    def __repr__(self) -> str:
        return f"ProfileTerm(max_queries={self.max_queries!r})"

    def _validate(self) -> None:
        mq = self.max_queries
        if isinstance(mq, bool) or not isinstance(mq, (int, np.integer)) or mq < 1:
            raise InvalidParameterError(f"max_queries must be an integer >= 1, got {mq!r}")

    # -- fitting -----------------------------------------------------------------
    def _index(self, groups: Sequence[Sequence[Observation]]) -> None:
        rows: list[FArray] = []
        owner: list[int] = []
        view: list[int] = []
        shape: tuple[int, ...] | None = None
        for j, group in enumerate(groups):
            for i, o in enumerate(group):
                if o.profile is None:
                    continue
                if shape is None:
                    shape = o.profile.shape
                elif o.profile.shape != shape:
                    raise InvalidParameterError(
                        f"profile: every profile must have the same shape, got {o.profile.shape} and {shape}"
                    )
                rows.append(o.profile)
                owner.append(j)
                view.append(i)
        self.n_places_ = len(groups)
        self.shape_ = shape
        self.fft_ = np.fft.rfft(np.stack(rows), axis=1) if rows else np.zeros((0, 0, 0), dtype=np.complex128)
        self.owner_ = np.asarray(owner, dtype=np.int64)
        self.view_ = np.asarray(view, dtype=np.int64)
        self._has = np.array([o.profile is not None for g in groups for o in g], dtype=bool)
        self._profiles = rows

    def fit(self, groups: Sequence[Sequence[Observation]]) -> ProfileTerm:
        """Store every training profile and fit ``lambda_`` / ``unknown_cost_`` by leave-one-out."""
        self._validate()
        self._index(groups)
        self.calibrate(groups)
        return self

    def update(self, groups: Sequence[Sequence[Observation]], changed: Sequence[int]) -> ProfileTerm:
        """Re-index the profiles of every place; ``lambda_`` and ``unknown_cost_`` are kept."""
        self._check_fitted()
        self._index(groups)
        return self

    def _check_fitted(self) -> None:
        if not hasattr(self, "fft_"):
            raise NotFittedError("this ProfileTerm is not fitted yet; call fit() first")

    def _peaks(self, query: FArray) -> tuple[FArray, FArray]:
        if self.shape_ is None or query.shape != self.shape_:
            hint = ""
            if self.shape_ is not None and {query.shape[0], self.shape_[0]} == {36, 72} and query.shape[1:] == self.shape_[1:]:
                hint = (
                    " (fingerloc's panorama profiles had 72 sectors before issue 14's second pass, 36 since: "
                    "extract the references and the queries again with one version and learn again)"
                )
            raise InvalidParameterError(
                f"profile: the observation's profile has shape {query.shape}, the learned places' {self.shape_}{hint}"
            )
        return profile_peaks(query, self.fft_, self.shape_[0])

    def _loo_matrix(self, rows: IArray) -> FArray | None:
        """``1 - rho`` between training views; views without a profile are never anyone's neighbour."""
        if len(self._profiles) < 2:
            return None
        pos = np.cumsum(self._has) - 1  # row of refs for each training view with a profile
        d = np.full((rows.size, self._has.size), np.inf)
        for k, r in enumerate(rows):
            if not self._has[r]:
                continue
            rho, _ = self._peaks(self._profiles[int(pos[r])])
            d[k, self._has] = 1.0 - rho
        return d

    # -- inference ---------------------------------------------------------------
    def _per_place(self, d: FArray) -> FArray:
        out = np.full(self.n_places_, np.inf)
        np.minimum.at(out, self.owner_, d)
        return out

    def distances(self, observations: Sequence[Observation]) -> FArray:
        """``1 - rho`` of each observation to the nearest view of each place, shape ``(n, P)``."""
        self._check_fitted()
        obs = list(observations)
        out = np.zeros((len(obs), self.n_places_))
        if self.owner_.size == 0:
            return out
        for i, o in enumerate(obs):
            if o.profile is None:
                continue
            rho, _ = self._peaks(o.profile)
            per = self._per_place(1.0 - rho)
            fin = np.isfinite(per)
            out[i] = np.where(fin, per, per[fin].max() if fin.any() else 0.0)
        return out

    def unknown_log_likelihood(self, observations: Sequence[Observation]) -> FArray:
        """``-lambda_ * unknown_cost_`` for observations with a profile, 0 for the others, shape ``(n,)``."""
        self._check_fitted()
        has = np.array([o.profile is not None for o in observations], dtype=np.float64)
        return super().unknown_log_likelihood(observations) * has

    def heading_at(self, observation: Observation, place: int) -> tuple[float | None, int]:
        """Heading of ``observation`` against the best-matching training view of place index ``place``.

        Returns ``(heading_deg, view)``: a feature at bearing ``b`` in the
        observation is at bearing ``b + heading_deg`` in that view (degrees,
        ``[0, 360)``), ``view`` its index among the place's training
        observations; ``(None, -1)`` without profiles.
        """
        self._check_fitted()
        sel = np.flatnonzero(self.owner_ == place)
        if observation.profile is None or sel.size == 0:
            return None, -1
        rho, shift = self._peaks(observation.profile)
        best = int(sel[np.argmax(rho[sel])])
        assert self.shape_ is not None
        return float(np.mod(shift[best] * 360.0 / self.shape_[0], 360.0)), int(self.view_[best])

    # -- state -------------------------------------------------------------------
    def to_state(self) -> dict[str, Any]:
        """``{"lambda", "unknown_cost"}``; the profiles come back from the stored observations."""
        self._check_fitted()
        return dict(self._calibration_state())

    def set_state(self, state: dict[str, Any], groups: Sequence[Sequence[Observation]]) -> ProfileTerm:
        """Restore from :meth:`to_state` and the places' stored observations (``groups``)."""
        try:
            lam = float(state["lambda"])
            unknown = state.get("unknown_cost")
            unknown = None if unknown is None else float(unknown)
        except (KeyError, TypeError, ValueError) as err:
            raise InvalidParameterError(f"profile term state is malformed: {state!r}") from err
        if not (math.isfinite(lam) and lam > 0 and (unknown is None or (math.isfinite(unknown) and unknown >= 0))):
            raise InvalidParameterError(f"profile term state is malformed: {state!r}")
        self._validate()
        self._index(groups)
        self._set_calibration_state(state)
        return self

    @classmethod
    def from_state(cls, state: dict[str, Any], groups: Sequence[Sequence[Observation]]) -> ProfileTerm:
        """A fitted term from :meth:`to_state` and the places' stored observations."""
        return cls().set_state(state, groups)
