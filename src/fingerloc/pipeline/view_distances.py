"""Distances between the views of one run, in the units of the place model's own likelihood.

The place model (:class:`~fingerloc.model.PlaceModel`) scores a view against a
place by distance terms: the fingerprint string's alignment cost (``Fp``), the
range histograms (``R``), a camera's appearance (``A``), aligned profile
(``AP``) and local features (``K``), each as ``P(term | place) ∝ exp(-lambda
d)`` with ``lambda`` fitted leave-one-out on the training places
(:mod:`fingerloc.terms.distance`). Here the same terms compare every view of a
run with every other one, without any place given:

* :func:`term_distances`: each term's distance between views (one
  "place" per reference view), shape ``(n_queries, n_references)``;
* :func:`fit_term_scales`: each term's ``lambda``, fitted by the model itself
  with runs of :data:`CALIBRATION_VIEWS` consecutive views standing for places
  (a view and its neighbours in time show the same place; no pose is used);
* :func:`view_distance_matrix`: ``D[i, j] = sum_t w_t lambda_t d_t(i, j)``,
  minus the log-likelihood of view ``i`` at the place of view ``j`` (up to
  a constant), the unit every rule of :mod:`fingerloc.pipeline.topology` uses;
* :func:`keyframes`: the views that differ from the previous keyframe by at
  least :data:`KEYFRAME_CHANGE` of the distance between unrelated views, so
  that a run recorded at 40 Hz and one recorded every metre give comparable
  sequences of *distinct* views.

Only the distance terms count (the angle-space mixtures VE, CP, Ex and B have
no distance between two views); a term whose model weight is 0 is left out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .._types import FArray, IArray
from ..errors import InvalidParameterError
from ..observation import Observation

__all__ = [
    "CALIBRATION_VIEWS",
    "DISTANCE_TERMS",
    "KEYFRAME_CHANGE",
    "distance_term_weights",
    "fit_term_scales",
    "keyframes",
    "term_distances",
    "term_spreads",
    "view_distance_matrix",
]

#: The terms with a distance between two views (the mixtures VE, CP, Ex, B have none).
DISTANCE_TERMS: tuple[str, ...] = ("Fp", "R", "A", "AP", "K")
#: Consecutive views that stand for one place while each term's ``lambda`` is fitted.
CALIBRATION_VIEWS = 3
#: A view is a keyframe when its change from the previous keyframe (each term's distance divided by
#: that term's median distance between unrelated views, averaged over the terms) reaches this.
KEYFRAME_CHANGE = 0.15
#: Views compared per model fit while keyframes are chosen.
_KEYFRAME_BLOCK = 16
#: Random views standing for "unrelated views" in :func:`term_spreads` (references, queries).
_SPREAD_SAMPLE = (64, 256)


def distance_term_weights(options: Mapping[str, Any]) -> dict[str, float]:
    """The distance terms of resolved model options and their weights (``weights`` of the model; 1 by default).

    Terms with weight 0 are left out; fitted weights (``"fit"``) count 1.

    Raises
    ------
    InvalidParameterError
        When no distance term with a positive weight is left.
    """
    terms = [str(t) for t in options.get("terms", ())]
    given = options.get("weights")
    weights = dict(given) if isinstance(given, Mapping) else {}
    out = {t: float(weights.get(t, 1.0)) for t in terms if t in DISTANCE_TERMS}
    out = {t: w for t, w in out.items() if w > 0}
    if not out:
        raise InvalidParameterError(
            f"places from fingerprints need a distance term ({', '.join(DISTANCE_TERMS)}) with a positive "
            f"weight; the model has terms {', '.join(terms) or 'none'}"
        )
    return out


def _term_model(options: Mapping[str, Any], terms: Sequence[str], *, calibrated: bool) -> Any:
    """A model of ``options`` restricted to ``terms`` (weights off); ``calibrated``: fit each term's lambda."""
    from .presets import model_from_options

    opts = dict(options)
    opts.update(terms=list(terms), weights=None, unknown_prior=0.0, fp_reference="all")
    opts["fp_likelihood"] = "exp" if calibrated else "paper"  # "paper": the string term skips its calibration
    return model_from_options(opts)


def term_distances(
    observations: Sequence[Observation],
    options: Mapping[str, Any],
    references: Sequence[Observation] | None = None,
) -> dict[str, FArray]:
    """Each distance term's distance from every view to every reference view.

    Parameters
    ----------
    observations : sequence of Observation, length n
    options : mapping
        Resolved model options (JSON form, :attr:`~fingerloc.pipeline.presets.ResolvedPreset.options`).
    references : sequence of Observation, length m, optional
        Default: ``observations``.

    Returns
    -------
    dict of str -> ndarray, shape (n, m)
        Per term of :func:`distance_term_weights`: the term's distance (an
        alignment cost, an L1 distance between histograms...); non-finite
        values are replaced by the largest finite one of the term.
    """
    names = list(distance_term_weights(options))
    refs = list(observations if references is None else references)
    obs = list(observations)
    if not obs or not refs:
        return {t: np.zeros((len(obs), len(refs))) for t in names}
    model = _term_model(options, names, calibrated=False).fit(refs, [str(i) for i in range(len(refs))])
    out: dict[str, FArray] = {}
    for t in names:
        d = np.asarray(model.terms_[t].distances(obs), dtype=np.float64)
        finite = np.isfinite(d)
        out[t] = np.where(finite, d, np.max(d[finite]) if finite.any() else 0.0)
    return out


def fit_term_scales(
    observations: Sequence[Observation], options: Mapping[str, Any], *, run_length: int = CALIBRATION_VIEWS
) -> dict[str, float]:
    """Each distance term's ``lambda``, fitted as the place model fits it, on runs of consecutive views.

    Views ``0 .. run_length - 1`` are one place, the next ``run_length`` the
    next place, and so on; the model's leave-one-out calibration
    (:func:`fingerloc.terms.distance.fit_lambda`) then gives each term the
    scale under which a view's own neighbours in time are most probable.
    With fewer than two such places every scale is 1.

    Returns
    -------
    dict of str -> float
        Per term of :func:`distance_term_weights`, ``lambda`` (1 / the term's distance unit).
    """
    names = list(distance_term_weights(options))
    obs = list(observations)
    if int(run_length) < 1:
        raise InvalidParameterError(f"run_length must be >= 1, got {run_length!r}")
    if len(obs) < 2 * int(run_length):
        return dict.fromkeys(names, 1.0)
    labels = [str(i // int(run_length)) for i in range(len(obs))]
    model = _term_model(options, names, calibrated=True).fit(obs, labels)
    return {t: float(getattr(model.terms_[t], "lambda_", 1.0)) for t in names}


def view_distance_matrix(
    observations: Sequence[Observation],
    options: Mapping[str, Any],
    *,
    scales: Mapping[str, float] | None = None,
) -> tuple[FArray, dict[str, float]]:
    """``D[i, j] = sum_t w_t lambda_t d_t(i, j)`` between every two views (module docstring).

    Parameters
    ----------
    observations : sequence of Observation, length n
    options : mapping
        Resolved model options (JSON form).
    scales : mapping of str -> float, optional
        Each term's ``lambda``; default :func:`fit_term_scales` on these views.

    Returns
    -------
    D : ndarray, shape (n, n)
        Non-negative; minus a log-likelihood up to a constant (nats).
    scales : dict of str -> float
    """
    weights = distance_term_weights(options)
    lam = dict(fit_term_scales(observations, options) if scales is None else scales)
    per = term_distances(observations, options)
    n = len(observations)
    out = np.zeros((n, n))
    for t, w in weights.items():
        out += w * float(lam.get(t, 1.0)) * per[t]
    return out, lam


def term_spreads(observations: Sequence[Observation], options: Mapping[str, Any], *, seed: int = 0) -> dict[str, float]:
    """Each distance term's median distance between two views taken at random: the scale of "unrelated views".

    At most 64 reference and 256 query views (seeded), pairs of a view
    with itself left out. A term whose median is 0 gets 1.
    """
    obs = list(observations)
    n = len(obs)
    names = list(distance_term_weights(options))
    if n < 2:
        return dict.fromkeys(names, 1.0)
    rng = np.random.default_rng(seed)
    r_idx = np.sort(rng.choice(n, min(n, _SPREAD_SAMPLE[0]), replace=False))
    q_idx = np.sort(rng.choice(n, min(n, _SPREAD_SAMPLE[1]), replace=False))
    per = term_distances([obs[i] for i in q_idx], options, [obs[i] for i in r_idx])
    other = q_idx[:, None] != r_idx[None, :]
    out: dict[str, float] = {}
    for t in names:
        v = per[t][other]
        med = float(np.median(v)) if v.size else 0.0
        out[t] = med if med > 0 and math.isfinite(med) else 1.0
    return out


def keyframes(
    observations: Sequence[Observation],
    options: Mapping[str, Any],
    *,
    change: float = KEYFRAME_CHANGE,
    spreads: Mapping[str, float] | None = None,
) -> IArray:
    """The views that differ enough from the previous keyframe (module docstring).

    View 0 is a keyframe; walking on, a view is the next keyframe when its
    change from the last keyframe, ``sum_t w_t d_t / s_t / sum_t w_t`` with
    ``s_t`` the term's spread (:func:`term_spreads`), reaches ``change``.

    Parameters
    ----------
    observations : sequence of Observation, length n
    options : mapping
        Resolved model options (JSON form).
    change : float, default KEYFRAME_CHANGE
        ``>= 0``; 0 keeps every view.
    spreads : mapping, optional
        Each term's spread; default :func:`term_spreads`.

    Returns
    -------
    ndarray of int, shape (k,)
        Indices of the keyframes, ascending, starting with 0 (empty for no view).
    """
    if not (isinstance(change, (int, float)) and math.isfinite(change) and change >= 0):
        raise InvalidParameterError(f"change must be a number >= 0, got {change!r}")
    obs = list(observations)
    n = len(obs)
    if n == 0:
        return np.zeros(0, np.int64)
    if change == 0 or n == 1:
        return np.arange(n, dtype=np.int64)
    weights = distance_term_weights(options)
    s = dict(term_spreads(obs, options) if spreads is None else spreads)
    total_w = sum(weights.values())
    keys = [0]
    start = 1
    while start < n:
        block = list(range(start, min(n, start + _KEYFRAME_BLOCK)))
        per = term_distances([obs[i] for i in block], options, [obs[keys[-1]]])
        c = sum(w * per[t][:, 0] / float(s.get(t, 1.0)) for t, w in weights.items()) / total_w
        hit = np.flatnonzero(np.asarray(c) >= change)
        if hit.size:
            keys.append(block[int(hit[0])])
            start = keys[-1] + 1
        else:
            start = block[-1] + 1
    return np.asarray(keys, dtype=np.int64)
