"""The pose filter's answer between observations, and relocalization after a kidnapping (issue 15).

Two additions to :mod:`fingerloc.map.pose_filter`, kept apart from it:

* :func:`held_best`: the best place *between* observations reported with
  hysteresis. A particle filter's place posterior between two places is a
  near-tie of Voronoi cells that two runs (other random draws) break
  differently; the answer there keeps the previous best place unless
  another place's probability exceeds it by ``margin``. At an observed step
  the answer is the posterior's argmax, as before. The posterior itself is
  unchanged. :func:`tie_broken_best` breaks such near-ties by a
  deterministic belief instead (the discrete place filter run alongside).
* :func:`run_augmented_pose_filter`: Augmented Monte Carlo localization
  (Thrun, Burgard and Fox, *Probabilistic Robotics*, 2005, section 8.3.5).
  Two exponential averages of the particles' mean observation likelihood, a
  slow one ``w_slow`` and a fast one ``w_fast``; when the recent views are
  explained worse than usual (``w_fast < w_slow``) a share
  ``max(0, 1 - w_fast / w_slow)`` of the belief is drawn afresh from the
  sensor (the place filter's predicted belief times the observation's
  likelihood), here through the pose filter's own kidnapping component
  (:meth:`~fingerloc.map.pose_filter.PoseFilter.update` with ``kidnap=``
  that share): the posterior over places stays an exact mixture, and the
  fresh particles carry the share's weight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._lse import logsumexp
from ..errors import InvalidParameterError
from .filter import FilterResult, MarkovFilter, TransitionModel, run_filter
from .pose_filter import PoseFilter, _place_step, _run_inputs

__all__ = ["Augmented", "answer_between", "held_best", "run_augmented_pose_filter", "tie_broken_best"]


def held_best(result: FilterResult, observed: Any, margin: float) -> FilterResult:
    """``result`` with its best place held between observations unless another place leads by ``margin``.

    Parameters
    ----------
    result : FilterResult
    observed : array_like of bool, shape (n_steps,)
        Steps with an observation: there the best place is the argmax.
    margin : float
        Probability (>= 0; ``inf``: hold the last answer until the next
        observation). At a step without observation the previous step's
        best place ``k`` stays the answer unless ``max_j p_j > p_k + margin``;
        then the argmax.

    Returns
    -------
    FilterResult
        The same ``log_posterior`` and ``entropy_bits``; ``best`` and
        ``best_probability`` of the held answer.
    """
    m = float(margin)
    if math.isnan(m) or m < 0:
        raise InvalidParameterError(f"margin must be a probability difference >= 0 (or inf), got {margin!r}")
    obs = np.asarray(observed, dtype=bool).reshape(-1)
    lp = result.log_posterior
    n = lp.shape[0]
    if obs.size != n:
        raise InvalidParameterError(f"observed must have one entry per step ({n}), got {obs.size}")
    p = np.exp(lp)
    best = result.best.copy()
    for t in range(1, n):
        if obs[t]:
            continue
        k = int(best[t - 1])
        if not p[t, best[t]] > p[t, k] + m:
            best[t] = k
    return FilterResult(lp, best, p[np.arange(n), best] if n else np.zeros(0), result.entropy_bits)


def tie_broken_best(result: FilterResult, observed: Any, tie_break: Any, delta: float) -> FilterResult:
    """``result`` with near-ties between observations broken by a deterministic belief ``tie_break``.

    A particle filter whose belief is spread over many places (far from the
    map, or a sensor trusted little) has a near-flat place posterior, whose
    argmax two runs (other draws) pick differently. At a step without
    observation the answer here is, among the places whose probability is
    within ``delta`` of the largest, the one ``tie_break`` (e.g. the discrete
    place filter run alongside, which draws no random numbers) believes
    most. At an observed step it is the argmax, as before; the posterior is
    unchanged.

    Parameters
    ----------
    result : FilterResult
    observed : array_like of bool, shape (n_steps,)
    tie_break : array_like, shape (n_steps, P)
        Log-probabilities (or any scores, larger = more likely) per step.
    delta : float
        Probability (>= 0; 0 = exact ties only).

    Returns
    -------
    FilterResult
    """
    d = float(delta)
    if math.isnan(d) or d < 0:
        raise InvalidParameterError(f"delta must be a probability difference >= 0, got {delta!r}")
    obs = np.asarray(observed, dtype=bool).reshape(-1)
    lp = result.log_posterior
    n = lp.shape[0]
    tb = np.asarray(tie_break, dtype=np.float64)
    if obs.size != n or tb.shape != lp.shape:
        raise InvalidParameterError(f"observed and tie_break must have {n} steps (tie_break {lp.shape}), got {obs.size}, {tb.shape}")
    p = np.exp(lp)
    best = result.best.copy()
    for t in np.flatnonzero(~obs).tolist():
        cand = np.flatnonzero(p[t] >= p[t, best[t]] - d)
        best[t] = int(cand[np.argmax(np.nan_to_num(tb[t, cand], nan=-np.inf))])
    return FilterResult(lp, best, p[np.arange(n), best] if n else np.zeros(0), result.entropy_bits)


def answer_between(
    result: FilterResult,
    log_likelihood: Any,
    increments: Any,
    transition: TransitionModel,
    *,
    hold_margin: float | None = None,
    tie_break: float | None = None,
) -> FilterResult:
    """The pose filter's answers between observations made less random: :func:`held_best`, then :func:`tie_broken_best`.

    ``tie_break`` asks the discrete place filter over ``transition`` run on
    the same rows (NaN = prediction only) and the travelled distances of
    ``increments`` (one row per step, row 0 unused): deterministic, it draws
    no random numbers. ``None`` leaves that part out; both ``None``:
    ``result`` itself.
    """
    ll = np.asarray(log_likelihood, dtype=np.float64)
    observed = ~np.all(np.isnan(ll), axis=1)
    out = result
    if hold_margin is not None:
        out = held_best(out, observed, hold_margin)
    if tie_break is not None:
        inc = np.asarray(increments, dtype=np.float64).reshape(-1, 3)
        dist = np.hypot(inc[:, 0], inc[:, 1])
        if dist.size:
            dist[0] = 0.0
        out = tie_broken_best(out, observed, run_filter(ll, transition, distances=dist).log_posterior, tie_break)
    return out


@dataclass(frozen=True, slots=True)
class Augmented:
    """Settings of :func:`run_augmented_pose_filter` (Augmented MCL).

    Attributes
    ----------
    slow : float, default 0.05
        ``alpha_slow``: rate of the long-term average per observation
        (times the observation's tempering weight).
    fast : float, default 0.5
        ``alpha_fast`` (> ``slow``): rate of the short-term average.
    cap : float, default 0.5
        Largest share drawn afresh at one observation (in ``[0, 1]``).
    floor : float, default 0.0
        Smallest share drawn afresh at every observation (a constant
        sensor-drawn share, as the mixture proposal of Thrun, Fox, Burgard
        and Dellaert 2001 keeps one); 0 = only the adaptive share.
    threshold : float, default 1.0
        The share is ``max(0, 1 - (w_fast / w_slow) / threshold)``: 1 is
        the book's rule; below 1 only a deeper fall of the short-term
        average re-draws.
    relative : bool, default False
        Average the particles' likelihood *relative to* the sensor's own
        ("the robot is anywhere": the place filter's predicted belief, or
        uniform, times the likelihood) instead of the raw one, so that a
        view the front end gets wrong (low likelihood everywhere) does not
        look like a kidnapping.
    reserve : int, default 0
        Particles drawn from the sensor at every observation and kept at
        their own small weight (the kidnapping share) instead of being
        resampled with the tracked ones (which leaves a handful of them,
        each with a guessed heading): the same posterior, a richer set of
        kidnapping hypotheses for the next observations to weigh. 0 = the
        pose filter's own kidnapping component.
    adaptive : bool, default True
        False: no averages, the share is ``floor`` or the filter's own
        kidnapping probability (with ``reserve``: the reserve alone).
    """

    slow: float = 0.05
    fast: float = 0.5
    cap: float = 0.5
    floor: float = 0.0
    threshold: float = 1.0
    relative: bool = False
    reserve: int = 0
    adaptive: bool = True

    def __post_init__(self) -> None:
        for name in ("slow", "fast", "cap", "floor"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and 0 <= v <= 1):
                raise InvalidParameterError(f"{name} must be in [0, 1], got {getattr(self, name)!r}")
        if isinstance(self.reserve, bool) or not isinstance(self.reserve, (int, np.integer)) or self.reserve < 0:
            raise InvalidParameterError(f"reserve must be an integer >= 0, got {self.reserve!r}")
        if not (math.isfinite(float(self.threshold)) and 0 < self.threshold <= 1):
            raise InvalidParameterError(f"threshold must be in (0, 1], got {self.threshold!r}")
        if self.adaptive and self.fast <= self.slow and self.floor == 0:
            raise InvalidParameterError(f"fast must exceed slow, got fast={self.fast!r}, slow={self.slow!r}")
        if self.floor > self.cap:
            raise InvalidParameterError(f"floor must not exceed cap, got {self.floor!r} > {self.cap!r}")


def run_augmented_pose_filter(
    log_likelihood: Any,
    increments: Any,
    pose_filter: PoseFilter,
    augmented: Augmented | None = None,
    *,
    weights: Any = None,
    temper: tuple[float, float] | None = None,
    place_filter: MarkovFilter | None = None,
    start_at_first_observation: bool = False,
    gap_metres: float | None = None,
) -> FilterResult:
    """:func:`~fingerloc.map.pose_filter.run_pose_filter` with Augmented MCL's adaptive re-drawing (module docstring).

    At each observation (weight ``w`` from the tempering), before the
    update: ``l`` = the particles' mean likelihood of the observation
    (:meth:`~fingerloc.map.pose_filter.PoseFilter.log_evidence`, untempered);
    ``w_slow += slow * w * (l - w_slow)``, ``w_fast += fast * w * (l -
    w_fast)`` (both start at the first ``l``, and again after a
    re-initialisation); the share ``s = min(cap, max(floor, 1 - w_fast /
    w_slow))``. When ``s`` exceeds the filter's own tempered kidnapping
    probability, the update takes ``kidnap=s``: the belief becomes ``(1 -
    s)`` the tracked particles' posterior plus ``s`` the sensor's (place
    filter's predicted belief, or uniform, times the likelihood), and fresh
    particles drawn there carry that share. Otherwise the update is the
    plain one.

    Parameters
    ----------
    log_likelihood, increments, pose_filter, weights, temper, place_filter, start_at_first_observation, gap_metres
        As :func:`~fingerloc.map.pose_filter.run_pose_filter`.
    augmented : Augmented, optional
        Default ``Augmented()``.

    Returns
    -------
    FilterResult
        ``pose_filter.shares_`` is set to ``(step, share)`` of every
        observation whose share exceeded the kidnapping probability.
    """
    aug = Augmented() if augmented is None else augmented
    ll, inc, wts = _run_inputs(pose_filter, log_likelihood, increments, weights, temper)
    P, n = pose_filter.n_places, ll.shape[0]
    pose_filter.reset()
    if place_filter is not None:
        if place_filter.transition.n_places != P:
            raise InvalidParameterError(f"the place filter has {place_filter.transition.n_places} places, need {P}")
        place_filter.reset()
    gap = math.inf if gap_metres is None else float(gap_metres)
    out = np.empty_like(ll)
    lost = bool(start_at_first_observation)
    w_slow = w_fast = math.nan
    shares: list[tuple[int, float]] = []
    for t in range(n):
        row = ll[t]
        observed = not np.all(np.isnan(row))
        prior = _place_step(place_filter, row, inc, t, observed)
        if t > 0:
            pose_filter.predict(inc[t - 1])
            if math.hypot(inc[t - 1, 0], inc[t - 1, 1]) > gap:
                lost = True
        if not observed:
            out[t] = pose_filter.place_log_posterior()
            continue
        if lost:
            out[t] = pose_filter.update(row, 1.0, prior, kidnap=1.0)
            lost, w_slow, w_fast = False, math.nan, math.nan
            continue
        w = float(wts[t])
        level = math.exp(pose_filter.log_evidence(row, 1.0))
        if aug.relative:
            alt = np.full(P, -math.log(P)) if prior is None else np.asarray(prior, dtype=np.float64)
            level /= float(np.exp(logsumexp(alt - logsumexp(alt) + pose_filter.place_likelihood(row))))
        if math.isnan(w_slow):
            w_slow = w_fast = level
        else:
            w_slow += aug.slow * w * (level - w_slow)
            w_fast += aug.fast * w * (level - w_fast)
        share = max(aug.floor, 1.0 - w_fast / w_slow / aug.threshold) if w_slow > 0 and aug.adaptive else aug.floor
        share = min(aug.cap, share)
        eps = -math.expm1(w * math.log1p(-pose_filter.kidnap))
        if share > eps:
            shares.append((t, share))
        share = max(share, eps)
        if aug.reserve:
            out[t] = _update_with_reserve(pose_filter, row, w, prior, share, aug.reserve)
        elif share > eps:
            out[t] = pose_filter.update(row, w, prior, kidnap=share)
        else:
            out[t] = pose_filter.update(row, w, prior)
    pose_filter.shares_ = shares  # type: ignore[attr-defined]
    return FilterResult.from_log_posterior(out)


def _update_with_reserve(pose_filter: PoseFilter, row: Any, weight: float, prior: Any, share: float, m: int) -> Any:
    """The update with kidnapping probability ``share``, its component kept as ``m`` particles of weight ``share / m``.

    The tracked particles are weighed and resampled to ``N`` (no kidnapping
    term), then ``m`` particles drawn from the sensor's posterior (``prior``
    times the observation's robust likelihood, as the kidnapping component
    of :meth:`~fingerloc.map.pose_filter.PoseFilter.update`) are appended
    with total weight ``share``; the tracked ones keep ``1 - share``. The
    next update weighs all ``N + m`` and resamples to ``N``. Returns the
    place log-posterior, the exact mixture.
    """
    P = pose_filter.n_places
    lp = weight * pose_filter.place_likelihood(row)
    alt = np.full(P, -math.log(P)) if prior is None else np.asarray(prior, dtype=np.float64).reshape(-1)
    kid = alt - logsumexp(alt) + lp
    lse = float(logsumexp(kid))
    tracked = pose_filter.update(row, weight, prior, kidnap=0.0)
    if share <= 0 or not math.isfinite(lse):
        return tracked
    fresh = pose_filter._sample_at_places(kid, m, lse)
    pose_filter.particles_ = np.vstack([pose_filter.particles_, fresh])
    pose_filter.log_weights_ = np.concatenate(
        [pose_filter.log_weights_ + math.log1p(-share), np.full(m, math.log(share) - math.log(m))]
    )
    post = np.logaddexp(math.log1p(-share) + tracked, math.log(share) + (kid - lse))
    post = post - logsumexp(post)
    pose_filter._place_log_posterior = post
    return post.copy()
