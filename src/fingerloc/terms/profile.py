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

from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..observation import Observation
from .base import FArray
from .indexed import IndexedTerm, _first_mismatch

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


class ProfileTerm(IndexedTerm[FArray]):
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
    _label = "profile"

    def __init__(self, *, max_queries: int = 2000) -> None:
        self.max_queries = max_queries

    def __repr__(self) -> str:
        return f"ProfileTerm(max_queries={self.max_queries!r})"

    # -- fitting -----------------------------------------------------------------
    def _feature(self, o: Observation) -> FArray | None:
        return o.profile

    def _store(self, features: list[FArray]) -> None:
        bad = _first_mismatch([p.shape for p in features])
        if bad is not None:
            raise InvalidParameterError(f"profile: every profile must have the same shape, got {bad[0]} and {bad[1]}")
        self.shape_: tuple[int, ...] | None = features[0].shape if features else None
        self.fft_ = np.fft.rfft(np.stack(features), axis=1) if features else np.zeros((0, 0, 0), dtype=np.complex128)

    def _peaks(self, query: FArray) -> tuple[FArray, FArray]:
        if self.shape_ is None or query.shape != self.shape_:
            hint = ""
            if self.shape_ is not None and {query.shape[0], self.shape_[0]} == {36, 72} and query.shape[1:] == self.shape_[1:]:
                hint = (
                    " (fingerloc's panorama profiles had 72 sectors in older versions, 36 now: "
                    "extract the references and the queries again with one version and learn again)"
                )
            raise InvalidParameterError(
                f"profile: the observation's profile has shape {query.shape}, the learned places' {self.shape_}{hint}"
            )
        return profile_peaks(query, self.fft_, self.shape_[0])

    def _view_distances(self, feature: FArray) -> FArray:
        """``1 - rho`` of one profile to each stored training profile, shape ``(m,)``."""
        rho, _ = self._peaks(feature)
        return 1.0 - rho

    # -- inference ---------------------------------------------------------------
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
