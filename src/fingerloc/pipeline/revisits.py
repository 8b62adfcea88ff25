"""Is this view a place seen before, and which? A filter over the run's earlier views (loop closures).

The question of a loop-closure detector, asked of the place model's own
likelihood (:mod:`fingerloc.pipeline.view_distances`, ``D[i, j]`` = minus the
log-likelihood of view ``i`` at the place of view ``j``) and answered as
Markov localization answers it, over a graph built from the visiting order
alone (the earlier views, in order, each linked to its neighbours in time):

* states: "at the place of earlier view ``j``" for every view ``j`` old
  enough to count as a revisit (``j < eligible[i]``), and "a place not seen
  before" (*new*);
* motion: from view ``j`` the robot goes on to ``j + k``, ``k`` in ``-2..2``
  with weights ``exp(-k^2 / 2)`` (it may follow its earlier path either way,
  or stop); with probability ``leave`` it leaves the earlier path for a new
  place, and from a new place it reaches one of the eligible earlier views
  (uniformly) with probability ``leave``;
* evidence: ``exp(-D[i, j])`` for "at view ``j``", and for *new* the mean of
  ``exp(-D[i, k])`` over the run's views ``k`` not within ``recent`` views of
  ``i`` (:func:`background_log_likelihood`): the likelihood of the view at a
  place drawn at random from the environment, as FAB-MAP (Cummins and Newman,
  IJRR 2008) estimates its new-place likelihood from a sample of views. A view
  of a long corridor matches many places equally well, so its new-place
  likelihood is high too and it does not close a loop on that alone.

Per view the filter gives the earlier view with the highest posterior and its
probability (:class:`RevisitPosterior`): a loop closure when the probability is
high. No pose is used anywhere.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import logsumexp

from .._types import FArray, IArray
from ..errors import InvalidParameterError
from ..observation import Observation
from ..validation import check_int, check_number

__all__ = [
    "LEAVE_PROBABILITY",
    "RECENT_VIEWS",
    "STEP_KERNEL",
    "LoopClosures",
    "RevisitPosterior",
    "background_log_likelihood",
    "loop_closures",
    "revisit_filter",
    "square_distances",
]

#: Probability per view of leaving the earlier path for a new place (and of reaching it from one).
LEAVE_PROBABILITY = 0.3
#: Views this close in order to a view are not a revisit of it and not in its new-place sample.
RECENT_VIEWS = 10
#: Steps ``k`` along the earlier path per view and their weights ``exp(-k^2 / 2)`` (normalised).
STEP_KERNEL: tuple[tuple[int, float], ...] = tuple(
    (k, math.exp(-0.5 * k * k) / sum(math.exp(-0.5 * j * j) for j in range(-2, 3))) for k in range(-2, 3)
)


def background_log_likelihood(distances: Any, recent: int = RECENT_VIEWS) -> FArray:
    """The new-place log-likelihood of every view: ``log mean_k exp(-D[i, k])`` over the views ``|k - i| > recent``.

    Parameters
    ----------
    distances : array_like, shape (n, n)
        ``D`` of :func:`~fingerloc.pipeline.view_distances.view_distance_matrix`.
    recent : int, default RECENT_VIEWS
        A run too short to leave any such view uses every other view.

    Returns
    -------
    ndarray, shape (n,)
        Nats; 0 for a run of one view.
    """
    d = square_distances(distances)
    n = d.shape[0]
    r = check_int("recent", recent, minimum=0)
    out = np.zeros(n)
    idx = np.arange(n)
    for i in range(n):
        far = np.abs(idx - i) > r
        if not far.any():
            far = idx != i
        if far.any():
            out[i] = float(logsumexp(-d[i, far])) - math.log(int(far.sum()))
    return out


@dataclass(frozen=True, slots=True)
class RevisitPosterior:
    """The revisit filter's answer per view (:func:`revisit_filter`).

    Attributes
    ----------
    best : ndarray of int, shape (n,)
        The eligible earlier view with the highest posterior; -1 when none is eligible.
    log_probability : ndarray, shape (n,)
        Its log posterior (``-inf`` when none).
    unknown : ndarray, shape (n,)
        Posterior probability of a new place.
    """

    best: IArray
    log_probability: FArray
    unknown: FArray


def square_distances(distances: Any) -> FArray:
    """``distances`` as a finite square float64 matrix (a view-distance matrix ``D``), else an error."""
    d = np.asarray(distances, dtype=np.float64)
    if d.ndim != 2 or d.shape[0] != d.shape[1]:
        raise InvalidParameterError(f"distances must be a square matrix, got shape {d.shape}")
    if not np.all(np.isfinite(d)):
        raise InvalidParameterError("distances must be finite")
    return d


def revisit_filter(
    distances: Any,
    background: Any,
    eligible: Any,
    *,
    leave: float = LEAVE_PROBABILITY,
) -> RevisitPosterior:
    """Filter the views in order over "at earlier view ``j``" and "new place" (module docstring).

    Parameters
    ----------
    distances : array_like, shape (n, n)
        ``D[i, j]``: minus the log-likelihood of view ``i`` at view ``j``'s place.
    background : array_like, shape (n,)
        The new-place log-likelihood of each view (:func:`background_log_likelihood`).
    eligible : array_like of int, shape (n,)
        View ``i`` may be a revisit of views ``0 .. eligible[i] - 1`` only
        (the most recent views are not a revisit); each in ``0 .. i``.
    leave : float, default LEAVE_PROBABILITY

    Returns
    -------
    RevisitPosterior
    """
    d = square_distances(distances)
    n = d.shape[0]
    bg = np.asarray(background, dtype=np.float64).reshape(-1)
    el = np.asarray(eligible).reshape(-1)
    if bg.size != n or el.size != n:
        raise InvalidParameterError(
            f"background and eligible need one entry per view ({n}), got {bg.size} and {el.size}"
        )
    if not np.all(np.isfinite(bg)):
        raise InvalidParameterError("background must be finite")
    if el.size and (not np.issubdtype(el.dtype, np.integer) or np.any(el < 0) or np.any(el > np.arange(n))):
        raise InvalidParameterError("eligible[i] must be an integer in 0 .. i")
    p = check_number("leave", leave, minimum=0.0, maximum=1.0, low_open=True, high_open=True)
    lp, l1p = math.log(p), math.log1p(-p)
    best = np.full(n, -1, dtype=np.int64)
    logp = np.full(n, -np.inf)
    unknown = np.ones(n)
    a = np.full(n, -np.inf)  # log belief over the views (as earlier places)
    au = 0.0  # log belief of a new place
    for i in range(n):
        m = int(el[i])
        known = float(logsumexp(a)) if np.isfinite(a).any() else -np.inf
        pred = np.full(n, -np.inf)
        for k, w in STEP_KERNEL:
            lw = math.log(w)
            if k > 0:
                pred[k:] = np.logaddexp(pred[k:], a[:-k] + lw)
            elif k < 0:
                pred[:k] = np.logaddexp(pred[:k], a[-k:] + lw)
            else:
                pred = np.logaddexp(pred, a + lw)
        pred += l1p
        u = float(np.logaddexp(known + lp, au + l1p))
        if m > 0:
            pred[:m] = np.logaddexp(pred[:m], au + lp - math.log(m))
        else:
            u = float(np.logaddexp(u, au + lp))
        pred[m:] = -np.inf
        pred[:m] -= d[i, :m]
        u += float(bg[i])
        z = float(np.logaddexp(float(logsumexp(pred[:m])) if m > 0 else -np.inf, u))
        a = pred - z
        au = u - z
        unknown[i] = math.exp(au)
        if m > 0:
            j = int(np.argmax(a[:m]))
            best[i] = j
            logp[i] = float(a[j])
    return RevisitPosterior(best, logp, unknown)


@dataclass(frozen=True, slots=True)
class LoopClosures:
    """Loop-closure candidates of a run's views (:func:`loop_closures`).

    Attributes
    ----------
    best : ndarray of int, shape (n,)
        Per view, the earlier view it most probably revisits (-1: no eligible earlier view).
    log_probability : ndarray, shape (n,)
        The log posterior of that answer: the detector's score (higher = surer).
    unknown : ndarray, shape (n,)
        Posterior probability that the view shows a new place.
    distances : ndarray, shape (n, n)
        ``D`` (:func:`~fingerloc.pipeline.view_distances.view_distance_matrix`).
    scales : dict of str -> float
        Each term's ``lambda``.
    """

    best: IArray
    log_probability: FArray
    unknown: FArray
    distances: FArray
    scales: dict[str, float]


def loop_closures(
    observations: Sequence[Observation],
    options: Mapping[str, Any],
    eligible: Any = None,
    *,
    recent: int = RECENT_VIEWS,
    leave: float = LEAVE_PROBABILITY,
) -> LoopClosures:
    """Which earlier view each view revisits, and how sure: the fingerprint program as a loop-closure detector.

    Parameters
    ----------
    observations : sequence of Observation, length n
        The views in recording order.
    options : mapping
        Resolved model options (JSON form; the preset's).
    eligible : array_like of int, shape (n,), optional
        View ``i`` may revisit views ``0 .. eligible[i] - 1``; default
        ``max(0, i - recent)``.
    recent : int, default RECENT_VIEWS
        Views left out of each view's new-place sample (and of its
        candidates when ``eligible`` is not given).
    leave : float, default LEAVE_PROBABILITY

    Returns
    -------
    LoopClosures
    """
    from .view_distances import view_distance_matrix

    obs = list(observations)
    r = check_int("recent", recent, minimum=0)
    n = len(obs)
    el = np.maximum(0, np.arange(n) - r) if eligible is None else np.asarray(eligible, dtype=np.int64).reshape(-1)
    d, scales = view_distance_matrix(obs, options)
    post = revisit_filter(d, background_log_likelihood(d, r), el, leave=leave)
    return LoopClosures(post.best, post.log_probability, post.unknown, d, scales)
