"""Localization over the places with odometry as a motion model: a particle filter anchored to the place map.

The discrete filter of :mod:`fingerloc.map.filter` keeps one number per place
and uses odometry only as a travelled *distance*. A wheeled robot's odometry
says more: how far it went, in which direction and how much it turned. When
the place centres are known in the mapping run's frame (they are wherever the
mapping run had poses: SLAM, a corrected log, a surveyed map), that direction
is usable, and it is what carries a belief across the stretches where the
robot sees no learned place.

State: the robot's pose ``(x, y, theta)`` in the mapping frame, represented by
``N`` weighted particles. The answer is still a posterior over *places*: the
weight of the particles whose nearest place centre is ``j`` (its Voronoi
cell), mixed with the kidnapping term below.

* **Predict** with one odometry increment ``(dx, dy, dtheta)`` in the robot
  frame of the previous step (:func:`odometry_increments`), perturbed per
  particle by :class:`MotionNoise`.
* **Update** with a single-shot method's log-likelihood row over the places
  ``l_j`` (e.g. the fingerprint program's log-posterior): the row is turned
  into a robust place likelihood ``p_j = (1 - rho) softmax(l)_j + rho / P``
  (``rho`` = the chance that the front end's answer is noise, which bounds how
  hard one observation can kill a hypothesis; the fingerprint program's errors
  repeat at consecutive scans, docs/RESULTS.md); a particle within
  ``radius`` of place ``j``'s centre takes ``p_j``; a particle within no
  place's radius sees the observation explained by noise alone, ``rho / P``.
* **Kidnapping**: before each observation the robot may have been carried
  anywhere with probability ``epsilon`` (the uniform mixing term of the
  discrete filter, per observation). That component's posterior over places
  is ``proportional to p_j`` and is added to the answer exactly; for the
  future it is represented by fresh particles drawn from the places in
  proportion to ``p_j`` (uniform in the place's disc, uniform heading), with
  their exact total weight, then everything is resampled back to ``N``
  (systematic resampling).

* **Heading** (optional, :class:`HeadingModel`): a front end that also
  estimates the robot's heading relative to the matched reference view (the
  fingerprint's cyclic alignment), with that view's pose from the mapping
  run, implies an absolute heading per candidate place. A particle at place
  ``j`` is then also weighed by a robust density of (its heading - the
  heading implied at ``j``): a von Mises peak, an optional peak at the
  reverse heading (a corridor looks alike both ways) and a uniform outlier
  part. Fresh particles (kidnapping, the start from the first observation)
  draw their heading from it.

* **Lost and found** (:func:`run_pose_filter` options): the particles can be
  drawn from the first observation instead of a start prior carried blindly
  (a run that starts far from every place), re-drawn after a gap in the log
  (an odometry step longer than ``gap_metres``), and partly re-seeded from
  the place filter's posterior when it has explained the views better for
  long (sensor resetting, :meth:`PoseFilter.reseed`; Lenser and Veloso 2000,
  Thrun, Fox, Burgard and Dellaert 2001).

Everything is in log space; a likelihood of zero never makes a NaN.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any, Literal, overload

import numpy as np
from scipy.spatial import cKDTree

from .._lse import logsumexp  # scipy.special.logsumexp, bit for bit, without its per-call overhead
from .._types import FArray, IArray
from ..angles import wrap
from ..errors import InvalidParameterError
from ..validation import check_random_state
from .filter import FilterResult, MarkovFilter
from .scan_map import ScanMap

__all__ = [
    "Challenger",
    "HeadingModel",
    "MotionNoise",
    "OdometryError",
    "PoseFilter",
    "compose_increments",
    "fit_heading_model",
    "observation_weights",
    "odometry_increments",
    "path_start_poses",
    "run_challenged_pose_filter",
    "run_pose_filter",
    "simulate_odometry",
    "wheel_odometry",
]



def _finite(name: str, value: Any, *, low: float = 0.0) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"{name} must be a finite number >= {low:g}, got {value!r}") from None
    if not (math.isfinite(v) and v >= low):
        raise InvalidParameterError(f"{name} must be a finite number >= {low:g}, got {value!r}")
    return v


def _poses(poses: Any) -> FArray:
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InvalidParameterError(f"poses must have shape (n, 3) (x m, y m, theta rad), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise InvalidParameterError("poses must be finite")
    return p


def odometry_increments(poses: Any) -> FArray:
    """Odometry increments between consecutive poses, in the robot frame of the earlier pose.

    Parameters
    ----------
    poses : array_like, shape (n, 3)
        ``x``, ``y`` (metres) and heading ``theta`` (radians), in any fixed frame.

    Returns
    -------
    ndarray, shape (max(n - 1, 0), 3)
        Row ``t``: ``dx`` (forward, m), ``dy`` (left, m), ``dtheta`` (rad, in
        ``[-pi, pi)``) from pose ``t`` to pose ``t + 1``.
        :func:`compose_increments` inverts it.
    """
    p = _poses(poses)
    if p.shape[0] < 2:
        return np.zeros((0, 3))
    d = np.diff(p[:, :2], axis=0)
    c, s = np.cos(p[:-1, 2]), np.sin(p[:-1, 2])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], wrap(np.diff(p[:, 2]))])


def compose_increments(start: Any, increments: Any) -> FArray:
    """Dead reckoning: the poses reached from ``start`` by ``increments``, shape (n + 1, 3)."""
    s = _poses(np.asarray(start, dtype=np.float64).reshape(1, 3))[0]
    inc = np.asarray(increments, dtype=np.float64).reshape(-1, 3)
    out = np.empty((inc.shape[0] + 1, 3))
    out[0] = s
    for t, (dx, dy, dth) in enumerate(inc):
        x, y, th = out[t]
        out[t + 1] = (x + math.cos(th) * dx - math.sin(th) * dy, y + math.sin(th) * dx + math.cos(th) * dy,
                      float(wrap(th + dth)))  # fmt: skip
    return out


@dataclass(frozen=True, slots=True)
class MotionNoise:
    """The filter's motion model: one-sigma errors of an odometry increment.

    Per step, each particle moves by ``dx (1 + e1) + n1``, ``dy (1 + e2) + n2``
    (``e ~ N(0, translation)``, ``n ~ N(0, translation_floor + translation *
    distance)``) and turns by ``dtheta + N(0, rotation_floor +
    rotation_per_metre * distance + rotation * |dtheta|)``.

    Attributes
    ----------
    translation : float, default 0.05
        Relative error of the travelled distance.
    translation_floor : float, default 0.02
        Metres per step, even when standing still.
    rotation : float, default 0.1
        Relative error of a turn.
    rotation_per_metre : float, default 0.03
        Radians of heading error per metre travelled.
    rotation_floor : float, default 0.02
        Radians per step.
    """

    translation: float = 0.05
    translation_floor: float = 0.02
    rotation: float = 0.1
    rotation_per_metre: float = 0.03
    rotation_floor: float = 0.02

    def __post_init__(self) -> None:
        for name in ("translation", "translation_floor", "rotation", "rotation_per_metre", "rotation_floor"):
            _finite(name, getattr(self, name))


@dataclass(frozen=True, slots=True)
class OdometryError:
    """Errors of a simulated wheel odometry (:func:`simulate_odometry`), one sigma unless said.

    The defaults describe a plain differential-drive indoor robot: a 2 %
    systematic scale error of the distance, 5 % random error per step, 5 % of
    each turn, 0.01 rad per metre of random heading drift and a systematic
    heading drift of 0.005 rad (0.3 deg) per metre. They are the kind of error
    the filter's :class:`MotionNoise` is meant to cover.
    """

    scale: float = 0.02
    translation: float = 0.05
    rotation: float = 0.05
    drift_per_metre: float = 0.01
    bias_per_metre: float = 0.005

    def scaled(self, factor: float) -> OdometryError:
        """Every error times ``factor`` (>= 0; 0 = an exact odometry)."""
        f = _finite("factor", factor)
        return OdometryError(*(f * getattr(self, x.name) for x in fields(self)))

    def __post_init__(self) -> None:
        for name in ("translation", "rotation", "drift_per_metre"):
            _finite(name, getattr(self, name))
        for name in ("scale", "bias_per_metre"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v <= -1.0:
                raise InvalidParameterError(f"{name} must be a finite number > -1, got {v!r}")


def simulate_odometry(
    poses: Any, error: OdometryError | None = None, *, random_state: int | np.random.Generator | None = 0
) -> FArray:
    """Odometry increments of a trajectory with simulated wheel-odometry errors, shape (n - 1, 3).

    For logs whose only poses are corrected ones (the shared CARMEN logs: their
    ``ODOM`` lines are corrected too), the exact increments would be an
    odometry without error; this corrupts them with ``error`` (default
    :class:`OdometryError`), seeded.
    """
    err = OdometryError() if error is None else error
    inc = odometry_increments(poses)
    rng = check_random_state(random_state)
    n = inc.shape[0]
    dist = np.hypot(inc[:, 0], inc[:, 1])
    out = inc.copy()
    out[:, :2] *= (1.0 + err.scale) * (1.0 + err.translation * rng.standard_normal((n, 1)))
    out[:, 2] = wrap(
        inc[:, 2]
        + err.rotation * np.abs(inc[:, 2]) * rng.standard_normal(n)
        + err.drift_per_metre * dist * rng.standard_normal(n)
        + err.bias_per_metre * dist
    )
    return out


def wheel_odometry(poses: Any, error_factor: float = 1.0, *, random_state: int | np.random.Generator | None = 0) -> FArray:
    """The increments a wheel odometry would report along ``poses``, shape (n - 1, 3).

    ``error_factor`` 0: the poses' exact increments (:func:`odometry_increments`);
    otherwise :func:`simulate_odometry` with ``OdometryError().scaled(error_factor)``.
    """
    f = _finite("error_factor", error_factor)
    if f == 0:
        return odometry_increments(poses)
    return simulate_odometry(poses, OdometryError().scaled(f), random_state=random_state)


@dataclass(frozen=True, slots=True)
class HeadingModel:
    """How far the robot's true heading lies from the heading a view implies at a place: a robust density.

    ``delta = true heading - implied heading`` (radians) has density
    ``f(delta | x) = g(x) [(1 - reverse) vM(delta; 0, kappa) + reverse
    vM(delta; pi, kappa)] + (1 - g(x)) / (2 pi)``: a von Mises peak where
    the alignment behind the estimate is right, part of it at the reverse
    heading (a corridor seen from its other end can look alike), and a
    uniform part for estimates that are noise. How often the estimate is
    right depends on how well the view matched the place: ``g(x) = cap
    sigmoid(intercept + slope x)``, ``x`` = the observation's log-probability
    of that place (the softmax of its row, <= 0). The pose filter weighs a
    particle at a place by ``2 pi f(particle heading - implied heading |
    x)`` (1 when the place has no implied heading: as uninformative as the
    uniform part). :func:`fit_heading_model` fits it on the mapping run.

    Attributes
    ----------
    kappa : float, default 20.0
        Concentration of the peaks (> 0; 1 / kappa ~ their variance in rad^2).
    intercept : float, default 0.0
        Logit of ``g / cap`` for a place the observation is sure of (``x = 0``).
    slope : float, default 0.0
        Per nat of ``x`` (0: the same reliability for every place).
    reverse : float, default 0.0
        Share of the peak at the reverse heading, in ``[0, 1]``.
    cap : float, default 0.95
        Largest peak share (the uniform part keeps ``1 - cap``), in ``[0, 1]``.
    """

    kappa: float = 20.0
    intercept: float = 0.0
    slope: float = 0.0
    reverse: float = 0.0
    cap: float = 0.95

    def __post_init__(self) -> None:
        k = _finite("kappa", self.kappa)
        if k <= 0:
            raise InvalidParameterError(f"kappa must be > 0, got {self.kappa!r}")
        _finite("slope", self.slope)
        if not math.isfinite(float(self.intercept)):
            raise InvalidParameterError(f"intercept must be finite, got {self.intercept!r}")
        for name in ("reverse", "cap"):
            if _finite(name, getattr(self, name)) > 1:
                raise InvalidParameterError(f"{name} must be in [0, 1], got {getattr(self, name)!r}")

    def peak_share(self, x: Any = 0.0) -> FArray:
        """``g(x)``: the chance that the heading estimate is right (``x`` = log-probability of the place)."""
        xx = np.maximum(np.asarray(x, dtype=np.float64), -50.0)
        return np.asarray(self.cap / (1.0 + np.exp(-(self.intercept + self.slope * xx))), dtype=np.float64)

    def log_factor(self, delta: Any, x: Any = 0.0) -> FArray:
        """``log(2 pi f(delta | x))``: a particle's weight factor, relative to an uninformative heading."""
        from scipy.special import i0e

        d = np.asarray(delta, dtype=np.float64)
        g = self.peak_share(x)
        c = np.cos(d)
        norm = 1.0 / float(i0e(self.kappa))  # 2 pi vM(delta) = exp(kappa (cos delta - 1)) / i0e(kappa)
        peak = (1.0 - self.reverse) * np.exp(self.kappa * (c - 1.0))
        if self.reverse > 0:
            peak = peak + self.reverse * np.exp(self.kappa * (-c - 1.0))
        with np.errstate(divide="ignore"):
            return np.asarray(np.log(g * norm * peak + (1.0 - g)), dtype=np.float64)

    def log_mean_tempered(self, weight: float, x: Any = 0.0) -> FArray:
        """``log mean_delta (2 pi f(delta | x)) ** weight`` over the circle, per ``x`` (0 at weight 1)."""
        xs = np.asarray(x, dtype=np.float64)
        if weight == 1.0:
            return np.zeros(xs.shape)
        grid = np.linspace(-math.pi, math.pi, 360, endpoint=False)
        lf = weight * self.log_factor(grid[:, None], xs.reshape(1, -1))
        top = lf.max(axis=0)
        return np.asarray(top + np.log(np.mean(np.exp(lf - top), axis=0)), dtype=np.float64).reshape(xs.shape)

    def sample(self, implied: Any, rng: np.random.Generator, x: Any = 0.0) -> FArray:
        """Headings drawn from ``f(. | x)`` around each implied heading (radians)."""
        mu = np.asarray(implied, dtype=np.float64).reshape(-1)
        n = mu.size
        g = np.broadcast_to(self.peak_share(x), (n,))
        u = rng.uniform(0.0, 1.0, n)
        flip = rng.uniform(0.0, 1.0, n) < self.reverse
        peak = wrap(mu + np.where(flip, math.pi, 0.0) + rng.vonmises(0.0, self.kappa, n))
        return np.where(u < g, peak, rng.uniform(-math.pi, math.pi, n))


def fit_heading_model(
    delta: Any,
    x: Any = None,
    *,
    reverse: bool = True,
    slope: bool = True,
    cap: float = 0.95,
    max_kappa: float = 400.0,
) -> HeadingModel | None:
    """Fit :class:`HeadingModel` to heading errors ``true - implied`` (radians) by maximum likelihood.

    Meant for the mapping run: each held-out mapping view's heading implied
    at its own place (by a front end fit on the other views) against the
    view's recorded heading, with ``x`` the view's log-probability of that
    place (default 0: no dependence). ``reverse`` / ``slope``: fit those
    parts too (else 0). ``None`` when fewer than 10 finite errors are given
    (no heading evidence).
    """
    from scipy.optimize import minimize

    d = np.asarray(delta, dtype=np.float64).reshape(-1)
    xx = np.zeros_like(d) if x is None else np.asarray(x, dtype=np.float64).reshape(-1)
    if xx.shape != d.shape:
        raise InvalidParameterError(f"x must have one entry per error ({d.size}), got {xx.size}")
    ok = np.isfinite(d) & ~np.isnan(xx)
    d, xx = wrap(d[ok]), np.maximum(xx[ok], -50.0)
    if d.size < 10:
        return None
    cp = _finite("cap", cap)

    def model(p: FArray) -> HeadingModel:
        return HeadingModel(
            kappa=float(min(math.exp(p[0]), max_kappa)),
            intercept=float(p[1]),
            slope=float(p[2]) if slope else 0.0,
            reverse=float(1.0 / (1.0 + math.exp(-p[3]))) if reverse else 0.0,
            cap=cp,
        )

    def nll(p: FArray) -> float:
        return -float(np.sum(model(p).log_factor(d, xx)))

    best = None
    for k0 in (2.0, 10.0, 50.0):
        r = minimize(nll, np.array([math.log(k0), 0.0, 0.5, -2.0]), method="L-BFGS-B",
                     bounds=[(math.log(1e-2), math.log(max_kappa)), (-10, 10), (0, 10), (-10, 10)])  # fmt: skip
        if best is None or r.fun < best.fun:
            best = r
    assert best is not None
    return model(best.x)


class PoseFilter:
    """Particle filter over the robot's pose, answering a posterior over places (module docstring).

    Parameters
    ----------
    centres : array_like, shape (P, 2)
        Place centres in the mapping frame, metres (place ``j`` is row ``j``).
    radius : float
        Metres: a pose within ``radius`` of a centre is *at* that place.
    n_particles : int, default 3000
    motion : MotionNoise, optional
    kidnap : float, default 0.005
        ``epsilon``: probability per observation that the robot was carried
        anywhere since the previous one (in ``[0, 1)``).
    outlier : float, default 0.1
        ``rho``: weight of the noise part of the place likelihood (in ``[0, 1]``).
    off_place : float, optional
        Likelihood of an observation, relative to the mean over the places,
        for a pose at no place (``[0, 1]``): such a particle weighs
        ``off_place / P``. Default ``outlier`` (the view is then explained
        by noise alone). Kept apart from ``outlier`` when ``outlier`` is
        fitted to the front end's reliability
        (:func:`fingerloc.map.filter.fit_outlier_weight`): how often the
        front end names the wrong place says nothing of how likely a view is
        away from every place.
    start : array_like, shape (m, 2) or (m, 3), optional
        Positions (or poses, heading in radians) the robot may start from,
        equally likely; the initial particles are drawn from them with
        ``radius / 2`` of jitter, and a heading jitter of ``heading_jitter``
        when headings are given (uniform headings otherwise). Default: the
        place centres (a uniform prior over the places, as the discrete
        filter's). Positions where the robot spent long (e.g. every scan of a
        mapping run) weigh the prior towards those places;
        :func:`path_start_poses` spreads them evenly along a path instead.
    place_poses : array_like, shape (m, 3), optional
        Poses at which the robot has been seen (e.g. the mapping run's scans,
        with the reversed headings too): particles re-seeded at place ``j``
        (kidnapping, :meth:`reseed`) take one of the poses within ``radius``
        of its centre, jittered, instead of a point of its disc with a
        uniform heading. A place with no such pose falls back to the disc.
    heading_jitter : float, default 0.2
        Radians (one sigma) added to the headings of ``start`` and
        ``place_poses``.
    heading : HeadingModel, optional
        Weigh particles also by the heading an observation implies at their
        place (``headings`` of :meth:`update`); ``None``: headings are ignored.
    scan_map : ScanMap, optional
        Weigh particles also by how well the observation's laser end points
        (``points`` of :meth:`update`) fit the mapping run's
        (:class:`~fingerloc.map.scan_map.ScanMap`): a particle at pose ``x``
        is weighed by ``exp(scan_gamma * L(x))``, ``L`` the mean end-point
        log-likelihood, tempered as the observation. ``None``: end points
        are ignored.
    scan_gamma : float, default 0
        The power of the scan evidence (0: off; chosen on the mapping part
        by :func:`fingerloc.pipeline.tracker.tune_pose_filter`).
    fresh_factor : int, default 1
        With the scan evidence, an update that re-draws particles from the
        sensor on purpose (``kidnap`` given to :meth:`update`: the first
        observation, a gap; or a lost belief, below) draws this many times
        as many fresh particles (then resamples to ``n_particles``): the
        scan likelihood is sharp, and a sparse draw may hold no particle
        near the true pose, so the best-fitting wrong one wins outright.
    lost_fit : float, optional
        Lost detection (Augmented MCL's idea, Thrun, Burgard and Fox 2005,
        8.3.5, with the scan likelihood, whose absolute value says how well
        the belief explains the view): at an update with end points, the
        tracked particles' fit (``lost_statistic``) is compared with this
        threshold (calibrated on the mapping part,
        :func:`fingerloc.pipeline.tracker.calibrate_lost`); after
        ``lost_after`` updates in a row below it, that update re-draws
        particles from the sensor with probability ``lost_kidnap`` (the
        kidnapping component, ``fresh_factor`` times denser), and the
        tracked particles keep the rest: they compete by their likelihood.
        ``None``: off.
    lost_kidnap : float, default 0
        In ``[0, 1]``.
    lost_after : int, default 1
    lost_statistic : {"best", "mean"}, default "best"
        The fit: the best end-point log-likelihood among the tracked
        particles (does any of them explain the view?), or their mean
        weighted by the observation (depends on how spread the belief is).
    lost_uniform : bool, default False
        A lost re-draw looks everywhere (uniform prior over the places)
        instead of at ``kidnap_prior`` (e.g. a place filter's belief).
    random_state : int or Generator, optional

    Attributes
    ----------
    particles_ : ndarray, shape (N, 3)
    log_weights_ : ndarray, shape (N,)
        Normalised (``logsumexp == 0``).
    fit_trace_ : list of float
        The tracked particles' fit (``lost_statistic``) at each update since
        :meth:`reset` (NaN without end points, or at a re-draw on purpose).
    lost_steps_ : list of int
        The updates (0-based, since :meth:`reset`) where the lost rule re-drew.
    scan_fit_ : float
        The last update's posterior mean end-point log-likelihood (NaN without end points).
    """

    def __init__(
        self,
        centres: Any,
        radius: float,
        *,
        n_particles: int = 3000,
        motion: MotionNoise | None = None,
        kidnap: float = 0.005,
        outlier: float = 0.1,
        off_place: float | None = None,
        start: Any = None,
        place_poses: Any = None,
        heading_jitter: float = 0.2,
        heading: HeadingModel | None = None,
        scan_map: ScanMap | None = None,
        scan_gamma: float = 0.0,
        fresh_factor: int = 1,
        lost_fit: float | None = None,
        lost_kidnap: float = 0.0,
        lost_after: int = 1,
        lost_statistic: str = "best",
        lost_uniform: bool = False,
        random_state: int | np.random.Generator | None = 0,
    ) -> None:
        c = np.asarray(centres, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] != 2 or c.shape[0] == 0 or not np.all(np.isfinite(c)):
            raise InvalidParameterError(f"centres must be a finite array of shape (P >= 1, 2), got {c.shape}")
        self.centres = c
        self.radius = _finite("radius", radius)
        if self.radius <= 0:
            raise InvalidParameterError(f"radius must be > 0 metres, got {radius!r}")
        if isinstance(n_particles, bool) or not isinstance(n_particles, (int, np.integer)) or n_particles < 10:
            raise InvalidParameterError(f"n_particles must be an integer >= 10, got {n_particles!r}")
        self.n_particles = int(n_particles)
        self.motion = MotionNoise() if motion is None else motion
        self.kidnap = _finite("kidnap", kidnap)
        if self.kidnap >= 1:
            raise InvalidParameterError(f"kidnap must be in [0, 1), got {kidnap!r}")
        self.outlier = _finite("outlier", outlier)
        if self.outlier > 1:
            raise InvalidParameterError(f"outlier must be in [0, 1], got {outlier!r}")
        self.off_place = self.outlier if off_place is None else _finite("off_place", off_place)
        if self.off_place > 1:
            raise InvalidParameterError(f"off_place must be in [0, 1], got {off_place!r}")
        st = c if start is None else np.asarray(start, dtype=np.float64)
        if st.ndim != 2 or st.shape[1] not in (2, 3) or st.shape[0] == 0 or not np.all(np.isfinite(st)):
            raise InvalidParameterError(f"start must be a finite array of shape (m >= 1, 2 or 3), got {st.shape}")
        self.start = st
        self.heading_jitter = _finite("heading_jitter", heading_jitter)
        if heading is not None and not isinstance(heading, HeadingModel):
            raise InvalidParameterError(f"heading must be a HeadingModel or None, got {heading!r}")
        self.heading = heading
        if scan_map is not None and not isinstance(scan_map, ScanMap):
            raise InvalidParameterError(f"scan_map must be a ScanMap or None, got {scan_map!r}")
        self.scan_map = scan_map
        self.scan_gamma = _finite("scan_gamma", scan_gamma)
        if isinstance(fresh_factor, bool) or not isinstance(fresh_factor, (int, np.integer)) or fresh_factor < 1:
            raise InvalidParameterError(f"fresh_factor must be an integer >= 1, got {fresh_factor!r}")
        self.fresh_factor = int(fresh_factor)
        self.lost_fit = None if lost_fit is None else float(lost_fit)
        if self.lost_fit is not None and math.isnan(self.lost_fit):
            raise InvalidParameterError("lost_fit must be a number or None, got NaN")
        self.lost_kidnap = _finite("lost_kidnap", lost_kidnap)
        if self.lost_kidnap > 1:
            raise InvalidParameterError(f"lost_kidnap must be in [0, 1], got {lost_kidnap!r}")
        if isinstance(lost_after, bool) or not isinstance(lost_after, (int, np.integer)) or lost_after < 1:
            raise InvalidParameterError(f"lost_after must be an integer >= 1, got {lost_after!r}")
        self.lost_after = int(lost_after)
        if lost_statistic not in ("best", "mean"):
            raise InvalidParameterError(f"lost_statistic must be 'best' or 'mean', got {lost_statistic!r}")
        self.lost_statistic = lost_statistic
        self.lost_uniform = bool(lost_uniform)
        self.scan_fit_ = math.nan
        self._place_poses: list[FArray] = [np.zeros((0, 3))] * c.shape[0]
        if place_poses is not None:
            pp = np.asarray(place_poses, dtype=np.float64)
            if pp.ndim != 2 or pp.shape[1] != 3 or not np.all(np.isfinite(pp)):
                raise InvalidParameterError(f"place_poses must be a finite array of shape (m, 3), got {pp.shape}")
            if pp.shape[0]:
                d, j = cKDTree(c).query(pp[:, :2])
                near = np.asarray(j)[np.asarray(d) <= self.radius]
                pp = pp[np.asarray(d) <= self.radius]
                self._place_poses = [pp[near == k] for k in range(c.shape[0])]
        self._any_place_poses = any(k.shape[0] for k in self._place_poses)
        self._rng = (
            check_random_state(random_state)
        )
        self._tree = cKDTree(c)
        self._near_cache: tuple[FArray, FArray, IArray, FArray] | None = None
        self.reset()

    @property
    def n_places(self) -> int:
        """Number of places ``P``."""
        return int(self.centres.shape[0])

    def reset(self) -> PoseFilter:
        """Particles drawn from ``start`` (global localization: nothing known)."""
        n, rng = self.n_particles, self._rng
        k = rng.integers(0, self.start.shape[0], n)
        xy = self.start[k, :2] + 0.5 * self.radius * rng.standard_normal((n, 2))
        if self.start.shape[1] == 3:
            th = wrap(self.start[k, 2] + self.heading_jitter * rng.standard_normal(n))
        else:
            th = rng.uniform(-math.pi, math.pi, n)
        self.particles_ = np.column_stack([xy, th])
        self.log_weights_ = np.full(n, -math.log(n))
        self._place_log_posterior = self._particle_places()
        self.resets_ = 0
        self.lost_steps_: list[int] = []
        self.fit_trace_: list[float] = []
        self._updates = 0
        self._low = 0
        self.switches_: list[int] = []
        self.challenger_trace_: list[tuple[int, str, float]] = []
        return self

    def _nearest(self, xy: FArray) -> tuple[FArray, IArray]:
        if self.centres.shape[0] > 256:  # many places: the tree
            d, j = self._tree.query(xy)
            return np.asarray(d, dtype=np.float64), np.asarray(j, dtype=np.int64)
        from ._nearest import nearest_centres  # the tree's answer, compiled brute force (issue 17)

        return nearest_centres(xy, self.centres)

    def _particles_nearest(self) -> tuple[FArray, IArray]:
        """Distance to and index of each particle's nearest centre, kept until the particles change.

        The filter replaces ``particles_`` (a new array) whenever it moves or
        resamples them, and recomputes after changing them in place
        (:meth:`reseed`); particles changed in place by a caller differ from
        the kept copy and are recomputed too.
        """
        cache = self._near_cache
        p = self.particles_
        if cache is not None and cache[0] is p and p.flags.c_contiguous and np.array_equal(cache[3], p):
            return cache[1], cache[2]
        d, near = self._nearest(p[:, :2])
        self._near_cache = (p, d, near, p.copy())  # the copy: particles changed in place by a caller are seen
        return d, near

    def _particle_places(self) -> FArray:
        from ._pf_kernels import bincount_weights

        self._near_cache = None
        _, near = self._particles_nearest()
        mass = bincount_weights(near, np.exp(self.log_weights_), self.n_places)
        with np.errstate(divide="ignore"):
            lp = np.log(mass)
        return lp - logsumexp(lp)

    def place_log_posterior(self) -> FArray:
        """Log-probability of each place now, shape (P,)."""
        return self._place_log_posterior.copy()

    def predict(self, increment: Any) -> FArray:
        """Move every particle by one odometry increment ``(dx, dy, dtheta)`` (robot frame, m and rad).

        Returns the place log-posterior after the move (the kidnapping term is
        applied at the next observation).
        """
        inc = np.asarray(increment, dtype=np.float64).reshape(-1)
        if inc.size != 3 or not np.all(np.isfinite(inc)):
            raise InvalidParameterError(
                f"an odometry increment is 3 finite numbers (dx, dy, dtheta), got {increment!r}"
            )
        dx, dy, dth = (float(v) for v in inc)
        m, rng = self.motion, self._rng
        n_now = int(self.particles_.shape[0])
        dist = math.hypot(dx, dy)
        st = m.translation_floor + m.translation * dist
        # the former NumPy expressions' draws, in their order: ex's two, ey's two, then the turn's
        z1 = rng.standard_normal(n_now)
        z2 = rng.standard_normal(n_now)
        z3 = rng.standard_normal(n_now)
        z4 = rng.standard_normal(n_now)
        sr = m.rotation_floor + m.rotation_per_metre * dist + m.rotation * abs(dth)
        th = self.particles_[:, 2]
        c, s = np.cos(th), np.sin(th)
        z5 = rng.standard_normal(n_now)
        from ._pf_kernels import move_particles

        moved = np.empty((n_now, 3))
        move_particles(np.ascontiguousarray(self.particles_), z1, z2, z3, z4, z5, c, s,
                       dx, dy, dth, m.translation, st, sr, moved)  # fmt: skip
        self.particles_ = moved
        self._place_log_posterior = self._particle_places()
        return self.place_log_posterior()

    def place_likelihood(self, log_likelihood: Any) -> FArray:
        """The robust place log-likelihood ``log p_j`` of one observation row, shape (P,)."""
        row = np.asarray(log_likelihood, dtype=np.float64).reshape(-1)
        if row.size != self.n_places:
            raise InvalidParameterError(f"a log-likelihood row needs {self.n_places} entries, got {row.size}")
        if np.any(np.isnan(row)) or np.any(row == np.inf):
            raise InvalidParameterError("a log-likelihood row must not hold NaN or +inf")
        if not np.any(np.isfinite(row)):
            soft = np.full(self.n_places, -math.log(self.n_places))  # no place explains it: uninformative
        else:
            soft = row - logsumexp(row)
        if self.outlier == 0:
            return soft
        if self.outlier == 1:
            return np.full(self.n_places, -math.log(self.n_places))
        return np.logaddexp(math.log1p(-self.outlier) + soft, math.log(self.outlier / self.n_places))

    def _headings(self, headings: Any) -> FArray | None:
        """The checked implied headings of one observation, shape (P,) (None: no heading evidence)."""
        if headings is None or self.heading is None:
            return None
        h = np.asarray(headings, dtype=np.float64).reshape(-1)
        if h.size != self.n_places or np.any(np.isinf(h)):
            raise InvalidParameterError(f"headings must be {self.n_places} angles in radians (NaN = none), without inf")
        return None if np.all(np.isnan(h)) else h

    @staticmethod
    def _place_confidence(log_likelihood: Any) -> FArray:
        """``x``: the row's log-probability of each place (softmax; -50 at most below), shape (P,)."""
        row = np.asarray(log_likelihood, dtype=np.float64).reshape(-1)
        if not np.any(np.isfinite(row)):
            return np.full(row.size, -math.log(max(row.size, 1)))
        return np.maximum(row - logsumexp(row), -50.0)

    def _heading_log_factor(self, d: FArray, near: IArray, h: FArray, x: FArray) -> FArray:
        """Each particle's ``log 2 pi f(theta - implied | x)`` at its place (0 at no place or no implied heading)."""
        assert self.heading is not None
        out = np.zeros(d.shape[0])
        hh = h[near]
        at = (d <= self.radius) & np.isfinite(hh)
        if np.any(at):
            out[at] = self.heading.log_factor(self.particles_[at, 2] - hh[at], x[near[at]])
        return out

    def update(
        self,
        log_likelihood: Any,
        weight: float = 1.0,
        kidnap_prior: Any = None,
        kidnap: float | None = None,
        headings: Any = None,
        heading_weight: float | None = None,
        points: Any = None,
        scan_map: ScanMap | None = None,
    ) -> FArray:
        """Weigh the particles by one observation, apply the kidnapping term, resample; the place log-posterior.

        ``weight`` in ``(0, 1]`` counts the observation as that fraction of an
        independent one: the robust likelihood is raised to ``weight`` and the
        kidnapping probability becomes ``1 - (1 - epsilon) ** weight``.
        ``kidnap_prior`` (log-probabilities over the places, shape (P,)): where
        a kidnapped robot may be, e.g. the discrete place filter's predicted
        belief; default uniform. ``kidnap`` overrides the kidnapping
        probability of this observation, untempered (1 = the particles are
        forgotten and re-drawn from ``kidnap_prior`` times the likelihood:
        a global (re)initialisation from the sensor).
        ``headings`` (radians, shape (P,), NaN = none): the robot's heading
        the observation implies at each place; with the filter's
        :class:`HeadingModel` a particle at place ``j`` is also weighed by
        ``(2 pi f(theta - headings[j])) ** weight``, and fresh particles at
        ``j`` draw their heading from ``f``. ``heading_weight`` (in ``(0,
        1]``, default ``weight``): the exponent of the heading factor, when
        the heading evidence is tempered on its own (its errors repeat over
        longer stretches than the place's).
        ``points`` (shape (m, 2), robot frame, metres): the observation's
        laser end points; with the filter's ``scan_map`` and ``scan_gamma >
        0`` every particle, the fresh ones included, is also weighed by
        ``exp(weight * scan_gamma * L(pose))``, and the place posterior is
        then the weighted particles' (an importance-sampling estimate).
        ``scan_map`` scores this observation's ``points`` instead of the
        filter's map (the mapping part's held-out runs, where each row has a
        map that never saw it: :func:`~fingerloc.pipeline.tracker.tune_pose_filter`).
        """
        w_obs = _finite("weight", weight)
        if kidnap is not None and not 0 <= _finite("kidnap", kidnap) <= 1:
            raise InvalidParameterError(f"kidnap must be in [0, 1], got {kidnap!r}")
        if not 0 < w_obs <= 1:
            raise InvalidParameterError(f"an observation's weight must be in (0, 1], got {weight!r}")
        lp = w_obs * self.place_likelihood(log_likelihood)
        P = self.n_places
        floor = w_obs * math.log(self.off_place / P) if self.off_place > 0 else -np.inf
        from ._pf_kernels import bincount_weights, observation_weights_at

        d, near = self._particles_nearest()
        w = np.empty(d.shape[0])
        any_finite = observation_weights_at(d, near, lp, self.radius, float(floor), self.log_weights_, w)
        hd = self._headings(headings)
        conf = log_mean = None
        w_head = w_obs if heading_weight is None else _finite("heading_weight", heading_weight)
        if not 0 < w_head <= 1:
            raise InvalidParameterError(f"heading_weight must be in (0, 1], got {heading_weight!r}")
        if hd is not None:
            assert self.heading is not None
            conf = self._place_confidence(log_likelihood)
            w += w_head * self._heading_log_factor(d, near, hd, conf)
            # the kidnapped component integrates the (tempered) heading factor over a uniform heading
            log_mean = np.zeros(P)
            if w_head != 1.0:
                has = np.isfinite(hd)
                log_mean[has] = self.heading.log_mean_tempered(w_head, conf[has])
                lp = lp + log_mean
        smap = self.scan_map if scan_map is None else scan_map
        scan = self._scan_points(points, smap)
        fits: list[FArray] = []
        self.scan_fit_ = math.nan
        if scan is not None:
            fits.append(self._scan(self.particles_, scan, smap))
            w += (w_obs * self.scan_gamma) * fits[0]
        tracked = float(logsumexp(w)) if any_finite else -np.inf
        dense = kidnap is not None and scan is not None  # a (re)initialisation from the sensor: a denser proposal
        fit = math.nan
        if scan is not None and kidnap is None and math.isfinite(tracked):
            if self.lost_statistic == "best":  # the tracked particles' best fit: does any of them explain the view?
                fit = float(np.max(np.where(np.isfinite(w), fits[0], -np.inf)))
            else:  # the tracked belief's fit: its weighted mean end-point log-likelihood (lost detection)
                fit = float(np.dot(np.exp(w - tracked), fits[0]))
        self.fit_trace_.append(fit)
        self._updates += 1
        self._low = self._low + 1 if self.lost_fit is not None and fit < self.lost_fit else 0
        if self._low >= self.lost_after and self.lost_kidnap > 0:
            # the belief explains the view worse than the map usually does at the true pose: re-draw from the sensor
            kidnap, dense = self.lost_kidnap, True
            self.lost_steps_.append(self._updates - 1)
            if self.lost_uniform:  # the belief is lost: so may be the prior that followed it (a place filter's)
                kidnap_prior = None
        eps = -math.expm1(w_obs * math.log1p(-self.kidnap)) if kidnap is None else float(kidnap)
        # place posterior: tracked particles' mass plus the kidnapping component (exact: uniform prior x p_j)
        with np.errstate(divide="ignore"):
            if math.isfinite(tracked):
                mass = np.log(bincount_weights(near, np.exp(w - tracked), P))
            else:
                mass = np.log(np.bincount(near, minlength=P))
        if kidnap_prior is None:
            prior = np.full(P, -math.log(P))
        else:
            prior = np.asarray(kidnap_prior, dtype=np.float64).reshape(-1)
            if prior.size != P or np.any(np.isnan(prior)) or not np.any(np.isfinite(prior)):
                raise InvalidParameterError(f"kidnap_prior must be {P} log-probabilities, not all -inf, without NaN")
            prior = prior - logsumexp(prior)
        kid = prior + lp
        lse_kid = float(logsumexp(kid))  # used three times below: computed once, the same float
        comp_kid = (math.log(eps) if eps > 0 else -np.inf) + lse_kid
        comp_trk = (math.log1p(-eps) + tracked) if math.isfinite(tracked) and eps < 1 else -np.inf
        if not math.isfinite(comp_trk) and not math.isfinite(comp_kid):
            # nothing explains the observation (outlier = 0 and every particle away from a place): keep the prior
            return self.place_log_posterior()
        post = np.logaddexp(comp_trk + mass, comp_kid + (kid - lse_kid))
        self._place_log_posterior = post - logsumexp(post)
        # particles for the future: tracked ones plus the kidnapping component's, then resample to N
        parts = [self.particles_]
        logw = [w - tracked + comp_trk] if math.isfinite(comp_trk) else [np.full(w.size, -np.inf)]
        if math.isfinite(comp_kid):
            m = self.n_particles if not math.isfinite(comp_trk) else max(self.n_particles // 3, 1)
            if dense:
                m *= self.fresh_factor
            fresh, corr = self._sample_at_places(
                kid, m, lse_kid, headings=hd, confidence=conf, log_mean=log_mean, weight=w_head, correction=True
            )
            parts.append(fresh)
            extra: float | FArray = 0.0
            if scan is not None:
                fits.append(self._scan(fresh, scan, smap))
                extra = (w_obs * self.scan_gamma) * fits[-1]
            logw.append(comp_kid - math.log(m) + corr + extra)
        allp, alw = np.concatenate(parts), np.concatenate(logw)
        if scan is not None:  # the fresh particles' scan weights are not in the analytic posterior: the particles'
            top = float(np.max(alw))
            if math.isfinite(top):  # the belief's fit: the posterior mean of the end points' log-likelihood
                pw = np.exp(alw - top)
                self.scan_fit_ = float(np.dot(pw, np.concatenate(fits)) / pw.sum())
            at = np.concatenate([near] + [self._nearest(q[:, :2])[1] for q in parts[1:]])  # the tracked: known
            with np.errstate(divide="ignore"):
                post = np.log(bincount_weights(at, np.exp(alw - top), P))
            self._place_log_posterior = post - logsumexp(post)
        self._resample(allp, alw)
        return self.place_log_posterior()

    def _scan_points(self, points: Any, scan_map: ScanMap | None) -> FArray | None:
        """The checked end points of one observation, shape (m, 2), or None when the scan evidence is off."""
        if scan_map is not None and not isinstance(scan_map, ScanMap):
            raise InvalidParameterError(f"scan_map must be a ScanMap or None, got {scan_map!r}")
        if points is None or scan_map is None or self.scan_gamma == 0:
            return None
        q = np.asarray(points, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != 2 or not np.all(np.isfinite(q)):
            raise InvalidParameterError(f"points must be a finite array of shape (m, 2), got {q.shape}")
        return q if q.shape[0] else None

    def _scan(self, particles: FArray, points: FArray, scan_map: ScanMap | None) -> FArray:
        assert scan_map is not None
        return scan_map.log_likelihood(particles, points)

    @overload
    def _sample_at_places(
        self, log_p: FArray, m: int, log_total: float | None = ..., *, headings: FArray | None = ...,
        confidence: FArray | None = ..., log_mean: FArray | None = ..., weight: float = ...,
        correction: Literal[False] = ...,
    ) -> FArray: ...  # fmt: skip

    @overload
    def _sample_at_places(
        self, log_p: FArray, m: int, log_total: float | None = ..., *, headings: FArray | None = ...,
        confidence: FArray | None = ..., log_mean: FArray | None = ..., weight: float = ...,
        correction: Literal[True],
    ) -> tuple[FArray, FArray]: ...  # fmt: skip

    def _sample_at_places(
        self,
        log_p: FArray,
        m: int,
        log_total: float | None = None,
        *,
        headings: FArray | None = None,
        confidence: FArray | None = None,
        log_mean: FArray | None = None,
        weight: float = 1.0,
        correction: bool = False,
    ) -> FArray | tuple[FArray, FArray]:
        """``m`` particles at the places by ``log_p``; with ``headings``, headings drawn from the heading model.

        ``confidence``: each place's ``x`` (:class:`HeadingModel`); ``log_mean``:
        each place's :meth:`HeadingModel.log_mean_tempered` at ``weight``, if
        already known.

        With ``correction``, also each particle's log importance weight: a
        heading drawn from ``f`` stands for the tempered target
        ``(2 pi f) ** weight / mean((2 pi f) ** weight)``.
        """
        out = self._sample_places_only(log_p, m, log_total)
        corr = np.zeros(m)
        if headings is not None and self.heading is not None:
            _, j = self._nearest(out[:, :2])
            hh = headings[j]
            has = np.isfinite(hh)
            if np.any(has):
                x = np.zeros(m) if confidence is None else confidence[j]
                th = self.heading.sample(hh[has], self._rng, x[has])
                out[has, 2] = th
                if weight != 1.0:
                    lm = (
                        log_mean[j[has]]
                        if log_mean is not None
                        else self.heading.log_mean_tempered(weight, x[has])
                    )
                    corr[has] = (weight - 1.0) * self.heading.log_factor(th - hh[has], x[has]) - lm
        return (out, corr) if correction else out

    def _sample_places_only(self, log_p: FArray, m: int, log_total: float | None = None) -> FArray:
        rng = self._rng
        pr = np.exp(log_p - (logsumexp(log_p) if log_total is None else log_total))
        j = rng.choice(self.n_places, size=m, p=pr / pr.sum())
        ang = rng.uniform(0.0, 2 * math.pi, m)
        rad = self.radius * np.sqrt(rng.uniform(0.0, 1.0, m))
        out = np.column_stack(
            [self.centres[j, 0] + rad * np.cos(ang), self.centres[j, 1] + rad * np.sin(ang),
             rng.uniform(-math.pi, math.pi, m)]
        )  # fmt: skip
        if not self._any_place_poses:
            return out
        for k in np.unique(j).tolist():
            known = self._place_poses[k]
            if known.shape[0] == 0:
                continue
            rows = np.flatnonzero(j == k)
            pick = known[rng.integers(0, known.shape[0], rows.size)]
            out[rows, :2] = pick[:, :2] + 0.25 * self.radius * rng.standard_normal((rows.size, 2))
            out[rows, 2] = wrap(pick[:, 2] + self.heading_jitter * rng.standard_normal(rows.size))
        return out

    def reseed(self, log_p: Any, fraction: float) -> FArray:
        """Sensor resetting: replace ``fraction`` of the particles by fresh ones drawn at the places by ``log_p``.

        Lenser and Veloso's sensor-resetting localization (2000) and the
        mixture proposal of Thrun, Fox, Burgard and Dellaert (2001): when the
        particles have lost the robot, a proposal from the sensor (here a
        place posterior, e.g. the single-shot one or the discrete filter's)
        puts hypotheses back where the robot may be. The replaced particles
        are a random subset and keep their weights (equal after an update,
        which resamples), so about ``fraction`` of the mass moves. Returns the place log-posterior afterwards.

        Parameters
        ----------
        log_p : array_like, shape (P,)
            Log-probabilities of the places (not all ``-inf``).
        fraction : float
            In ``[0, 1]``.
        """
        f = _finite("fraction", fraction)
        if f > 1:
            raise InvalidParameterError(f"fraction must be in [0, 1], got {fraction!r}")
        lp = np.asarray(log_p, dtype=np.float64).reshape(-1)
        if lp.size != self.n_places or np.any(np.isnan(lp)) or not np.any(np.isfinite(lp)):
            raise InvalidParameterError(f"log_p must be {self.n_places} log-probabilities, not all -inf, without NaN")
        n = self.particles_.shape[0]
        m = round(f * n)
        if m:
            idx = self._rng.choice(n, size=m, replace=False)
            self.particles_[idx] = self._sample_at_places(lp, m)
            self._place_log_posterior = self._particle_places()
        return self.place_log_posterior()

    def log_evidence(self, log_likelihood: Any, weight: float = 1.0, headings: Any = None) -> float:
        """Log predictive likelihood of one observation under the tracked particles (no kidnapping; state unchanged).

        ``log sum_i w_i l_i``: the particles' normalised weights times the
        tempered robust likelihood each would give the observation (as
        :meth:`update` weighs them). Two filters' sums over the same
        observations compare their trajectories' fit (a Bayes factor).
        """
        w_obs = _finite("weight", weight)
        lp = w_obs * self.place_likelihood(log_likelihood)
        floor = w_obs * math.log(self.off_place / self.n_places) if self.off_place > 0 else -np.inf
        d, near = self._particles_nearest()
        w = self.log_weights_ + np.where(d <= self.radius, lp[near], floor)
        hd = self._headings(headings)
        if hd is not None:
            w = w + w_obs * self._heading_log_factor(d, near, hd, self._place_confidence(log_likelihood))
        return float(logsumexp(w)) if np.any(np.isfinite(w)) else -math.inf

    def spawn(self, n_particles: int | None = None) -> PoseFilter:
        """A filter with the same map and settings (and the same random generator), ``n_particles`` (default this one's)."""
        other = PoseFilter.__new__(PoseFilter)
        for k, v in self.__dict__.items():
            setattr(other, k, v)
        if n_particles is not None:
            if isinstance(n_particles, bool) or not isinstance(n_particles, (int, np.integer)) or n_particles < 10:
                raise InvalidParameterError(f"n_particles must be an integer >= 10, got {n_particles!r}")
            other.n_particles = int(n_particles)
        other.reset()
        return other

    def adopt(self, other: PoseFilter) -> FArray:
        """Take over ``other``'s belief (its particles resampled to this filter's count); the place log-posterior."""
        if other.n_places != self.n_places:
            raise InvalidParameterError(f"cannot adopt a filter over {other.n_places} places, need {self.n_places}")
        self._resample(other.particles_, other.log_weights_)
        self._place_log_posterior = other.place_log_posterior()
        return self.place_log_posterior()

    def _resample(self, particles: FArray, log_w: FArray) -> None:
        """Systematic resampling of ``N`` particles from weighted ``particles``."""
        from ._pf_kernels import gather_rows, systematic_indices

        n = self.n_particles
        p = np.exp(log_w - logsumexp(log_w))
        idx = systematic_indices(p, float(self._rng.uniform()), n)
        self.particles_ = gather_rows(np.ascontiguousarray(particles, dtype=np.float64), idx)
        self.log_weights_ = np.full(n, -math.log(n))

    def step(
        self, log_likelihood: Any = None, increment: Any = None, weight: float = 1.0, kidnap_prior: Any = None
    ) -> FArray:
        """Predict with ``increment`` (if given), then update with ``log_likelihood`` (if given)."""
        if increment is not None:
            self.predict(increment)
        if log_likelihood is None:
            return self.place_log_posterior()
        return self.update(log_likelihood, weight, kidnap_prior)


class SharedDraws:
    """The random draws of one seed, recorded by a first run and replayed by the next (private; issue 17).

    Runs of the filter that differ only in settings which do not change the
    *sequence* of draws (the tuning grid of
    :func:`fingerloc.pipeline.tracker.tune_pose_filter`: same seed, same
    steps, other ``outlier`` and tempering) draw the same random numbers.
    :meth:`generator` gives a :class:`numpy.random.Generator` seeded with
    ``seed`` that returns, call for call, what a fresh ``default_rng(seed)``
    would: the first generator draws and records; the next ones return the
    recorded arrays while their calls are the same (method and arguments),
    and at the first call that differs they bring their own bit generator to
    that point (re-drawing the calls so far) and draw for themselves from
    then on. Recorded arrays are read only. ``choice`` with probabilities
    is done as NumPy does it (a cumulative sum of ``p``, ``random(size)``,
    ``searchsorted``) so that its uniform draws are shared.
    """

    def __init__(self, seed: int) -> None:
        self.seed = int(seed)
        self.log: list[tuple[tuple[Any, ...], Any]] = []

    def generator(self) -> np.random.Generator:
        """A generator equal in its draws to ``numpy.random.default_rng(seed)``."""
        return _ReplayGenerator(self)


def _shareable(x: Any) -> bool:
    if isinstance(x, tuple):
        return all(_shareable(v) for v in x)
    return x is None or isinstance(x, (bool, int, float, str, np.integer, np.floating))


class _ReplayGenerator(np.random.Generator):
    """A generator that replays :class:`SharedDraws` while its calls match (see there)."""

    def __init__(self, shared: SharedDraws) -> None:
        super().__init__(np.random.PCG64(shared.seed))
        self._shared = shared
        self._i = 0  # calls made
        self._synced = 0  # calls whose draws the own bit generator has made
        self._own = False  # diverged from the record: every draw is this generator's

    def _draw(self, name: str, args: tuple[Any, ...], kwargs: dict[str, Any]) -> Any:
        if self._own and self._synced == self._i:  # diverged and in step: a plain draw (the same as below)
            self._i = self._synced = self._i + 1
            return getattr(np.random.Generator, name)(self, *args, **kwargs)
        key = (name, args, tuple(sorted(kwargs.items())))
        log = self._shared.log
        i = self._i
        if not self._own:
            if i < len(log):  # a recorded key holds no array: the comparison is of plain values
                try:
                    same = name != "choice" and log[i][0] == key
                except ValueError:  # an array among the arguments
                    same = False
                if same:
                    self._i = i + 1
                    return log[i][1]
                self._own = True
            elif name == "choice" or not _shareable(key[1:]):
                self._own = True
        if self._synced < i:  # bring the own bit generator to call i: the record's calls so far
            for k in range(self._synced, i):
                n_k, a_k, kw_k = log[k][0]
                getattr(np.random.Generator, n_k)(self, *a_k, **dict(kw_k))
        out = getattr(np.random.Generator, name)(self, *args, **kwargs)
        self._i = self._synced = i + 1
        if not self._own:
            if isinstance(out, np.ndarray):
                out.flags.writeable = False
            log.append((key, out))
        return out

    def standard_normal(self, *args: Any, **kwargs: Any) -> Any:
        return self._draw("standard_normal", args, kwargs)

    def uniform(self, *args: Any, **kwargs: Any) -> Any:
        return self._draw("uniform", args, kwargs)

    def random(self, *args: Any, **kwargs: Any) -> Any:
        return self._draw("random", args, kwargs)

    def integers(self, *args: Any, **kwargs: Any) -> Any:
        return self._draw("integers", args, kwargs)

    def vonmises(self, *args: Any, **kwargs: Any) -> Any:
        return self._draw("vonmises", args, kwargs)

    def choice(self, a: Any, size: Any = None, replace: bool = True, p: Any = None, **kwargs: Any) -> Any:  # type: ignore[override]
        if p is not None and replace and not kwargs and isinstance(a, (int, np.integer)) and isinstance(size, (int, np.integer)):
            # numpy.random.Generator.choice with p: cdf = cumsum(p) / its last entry; searchsorted(cdf, random(size), "right")
            pp = np.asarray(p, dtype=np.float64)
            if pp.ndim == 1 and pp.size == a and np.all(np.isfinite(pp)) and not np.any(pp < 0) and abs(pp.sum() - 1.0) < 1e-9:
                cdf = pp.cumsum()
                cdf /= cdf[-1]
                return np.asarray(cdf.searchsorted(self.random(int(size)), side="right"), dtype=np.int64)
        return self._draw("choice", (a, size, replace, p), kwargs)  # never shared


def path_start_poses(poses: Any, *, spacing: float = 0.5, both_directions: bool = True) -> FArray:
    """Poses spread evenly along a path (one per ``spacing`` metres travelled), for a start prior or re-seeding.

    A robot that is lost is somewhere it can drive: on the path of the mapping
    run, facing along it (or back, with ``both_directions``). Taking every
    scan's pose would weigh the prior by the time spent (a robot standing
    still for a minute at one place); one pose per ``spacing`` metres of
    path weighs it by length instead.

    Parameters
    ----------
    poses : array_like, shape (n, 3)
        The path, metres and radians, in order.
    spacing : float, default 0.5
        Metres of path per kept pose (> 0).
    both_directions : bool, default True
        Also each kept pose with the reversed heading.

    Returns
    -------
    ndarray, shape (m, 3)
        ``m >= 1`` (the first pose is always kept).
    """
    p = _poses(poses)
    sp = _finite("spacing", spacing)
    if p.shape[0] == 0 or sp <= 0:
        raise InvalidParameterError(f"path_start_poses needs at least one pose and spacing > 0, got {p.shape[0]}, {spacing!r}")
    arc = np.r_[0.0, np.cumsum(np.hypot(*np.diff(p[:, :2], axis=0).T))]
    keep = np.r_[0, np.flatnonzero(np.diff(np.floor(arc / sp)) > 0) + 1] if p.shape[0] > 1 else np.zeros(1, np.int64)
    out = p[keep]
    if both_directions:
        out = np.vstack([out, np.column_stack([out[:, :2], wrap(out[:, 2] + math.pi)])])
    return out


def observation_weights(increments: Any, observed: Any, *, metres: float, radians: float = math.inf) -> FArray:
    """Weight of each observation as a fraction of an independent one, from the motion since the previous one.

    Consecutive scans from nearly the same pose see the same thing, and a
    front end that is wrong on one is wrong on the next; counting them as
    independent evidence makes a filter overconfident (the reason AMCL updates
    only after the robot has moved). Here an observation counts
    ``min(1, travelled / metres + |turned| / radians)``, the motion summed
    since the previous observation; the first observation counts 1.

    Parameters
    ----------
    increments : array_like, shape (n_steps - 1, 3)
    observed : array_like of bool, shape (n_steps,)
    metres : float
        Distance after which a view counts as new (> 0).
    radians : float, default inf
        Turn after which a view counts as new (> 0; inf = turns do not count).

    Returns
    -------
    ndarray, shape (n_steps,)
        The weight at observed steps, 0 elsewhere; every weight of an observed step is > 0.
    """
    m = _finite("metres", metres)
    r = float(radians)
    if m <= 0 or not r > 0:
        raise InvalidParameterError(f"metres and radians must be > 0, got {metres!r}, {radians!r}")
    obs = np.asarray(observed, dtype=bool).reshape(-1)
    inc = np.asarray(increments, dtype=np.float64).reshape(-1, 3)
    if inc.shape[0] != max(obs.size - 1, 0):
        raise InvalidParameterError(f"need {max(obs.size - 1, 0)} increments for {obs.size} steps, got {inc.shape[0]}")
    out = np.zeros(obs.size)
    moved, turned, first = 0.0, 0.0, True
    for t in range(obs.size):
        if t > 0:
            moved += math.hypot(inc[t - 1, 0], inc[t - 1, 1])
            turned += abs(inc[t - 1, 2])
        if obs[t]:
            out[t] = 1.0 if first else min(1.0, max(moved / m + (turned / r if math.isfinite(r) else 0.0), 1e-3))
            moved, turned, first = 0.0, 0.0, False
    return out



def _run_inputs(
    pose_filter: Any, log_likelihood: Any, increments: Any, weights: Any, temper: Any
) -> tuple[FArray, FArray, FArray]:
    """The checked inputs of a filter run: scores (n_steps, P), increments (n_steps - 1, 3), step weights (n_steps,).

    Increments may hold n_steps rows (the first is dropped); without ``weights``,
    ``temper = (metres, radians)`` gives them (:func:`observation_weights`).
    """
    ll = np.asarray(log_likelihood, dtype=np.float64)
    P = pose_filter.n_places
    if ll.ndim != 2 or ll.shape[1] != P:
        raise InvalidParameterError(f"log_likelihood must have shape (n_steps, {P}), got {ll.shape}")
    n = ll.shape[0]
    inc = np.asarray(increments, dtype=np.float64).reshape(-1, 3) if n else np.zeros((0, 3))
    if inc.shape[0] == n:
        inc = inc[1:]
    if n and inc.shape[0] != n - 1:
        raise InvalidParameterError(f"increments must have n_steps - 1 ({n - 1}) or n_steps rows, got {inc.shape[0]}")
    if weights is None and temper is not None:
        weights = observation_weights(inc, ~np.all(np.isnan(ll), axis=1), metres=temper[0], radians=temper[1])
    wts = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if wts.size != n:
        raise InvalidParameterError(f"weights must have one entry per step ({n}), got {wts.size}")
    return ll, inc, wts

def _update(
    f: PoseFilter, row: FArray, weight: float, prior: Any, kidnap: float | None, headings: FArray | None,
    heading_weight: float | None = None, points: FArray | None = None, scan_map: ScanMap | None = None,
) -> FArray:  # fmt: skip
    """``f.update``, with ``headings``, ``points`` and ``scan_map`` only when there are some (a filter class
    without them keeps working)."""
    extra: dict[str, Any] = {} if points is None else {"points": points}
    if scan_map is not None:
        extra["scan_map"] = scan_map
    if headings is None:
        if kidnap is None:
            return f.update(row, weight, prior, **extra)
        return f.update(row, weight, prior, kidnap=kidnap, **extra)
    return f.update(row, weight, prior, kidnap=kidnap, headings=headings, heading_weight=heading_weight, **extra)


def _evidence(f: PoseFilter, row: FArray, weight: float, headings: FArray | None) -> float:
    """``f.log_evidence``, with ``headings`` only when there are some."""
    return f.log_evidence(row, weight) if headings is None else f.log_evidence(row, weight, headings)


def _run_headings(headings: Any, shape: tuple[int, ...]) -> FArray | None:
    """The checked implied headings of a run, shape (n_steps, P), or None."""
    if headings is None:
        return None
    h = np.asarray(headings, dtype=np.float64)
    if h.shape != tuple(shape):
        raise InvalidParameterError(f"headings must have the log-likelihood's shape {tuple(shape)}, got {h.shape}")
    return h


def _run_points(points: Any, n: int) -> list[FArray | None] | None:
    """The checked end points of a run: one (m, 2) array or None per step, or None."""
    if points is None:
        return None
    pts = list(points)
    if len(pts) != n:
        raise InvalidParameterError(f"points must have one entry per step ({n}), got {len(pts)}")
    return [None if q is None else np.asarray(q, dtype=np.float64).reshape(-1, 2) for q in pts]


def _place_step(place_filter: MarkovFilter | None, row: FArray, inc: FArray, t: int, observed: bool) -> FArray | None:
    """One step of the discrete place filter run beside a pose filter: its predicted belief at step ``t``
    (the kidnapping prior of the pose filter's update; None without a place filter), then its update by
    the observation ``row`` when ``observed``. ``inc``: the run's odometry increments (row ``t - 1`` leads
    to step ``t``)."""
    if place_filter is None:
        return None
    prior = place_filter.predict(math.hypot(inc[t - 1, 0], inc[t - 1, 1])) if t > 0 else place_filter.log_belief_
    if observed:
        place_filter.update(np.where(np.isnan(row), -np.inf, row))
    return prior


def run_pose_filter(
    log_likelihood: Any,
    increments: Any,
    pose_filter: PoseFilter,
    *,
    weights: Any = None,
    temper: tuple[float, float] | None = None,
    place_filter: MarkovFilter | None = None,
    reset_threshold: float | None = None,
    reset_fraction: float = 0.5,
    start_at_first_observation: bool = False,
    gap_metres: float | None = None,
    answer_untempered: bool = False,
    headings: Any = None,
    heading_weights: Any = None,
    points: Any = None,
    scan_maps: Sequence[ScanMap | None] | None = None,
) -> FilterResult:
    """Run a :class:`PoseFilter` (reset first) along a trajectory.

    Parameters
    ----------
    log_likelihood : array_like, shape (n_steps, P)
        Row ``t``: the single-shot log-likelihood of each place at step ``t``;
        a row of NaN = no observation (prediction only).
    increments : array_like, shape (n_steps - 1, 3) or (n_steps, 3)
        Odometry from step ``t - 1`` to step ``t`` (robot frame); with
        ``n_steps`` rows, row 0 is ignored.
    pose_filter : PoseFilter
    weights : array_like, shape (n_steps,), optional
        Each observation's weight; default 1, or from ``temper``.
    temper : (metres, radians), optional
        Weigh the observations by the motion between them
        (:func:`observation_weights` with these scales), when ``weights`` is
        not given.
    place_filter : MarkovFilter, optional
        A discrete filter over the same places, run alongside (reset first;
        travelled distances from the increments; untempered observations):
        its predicted belief is where a kidnapped robot is looked for
        (``kidnap_prior``), so that the pose filter re-localizes as fast as
        the place filter does.
    reset_threshold : float, optional
        Sensor resetting (:meth:`PoseFilter.reseed`) when the particles and
        the sensor disagree for long. At each observation with place
        likelihood ``p`` (robust, tempered by the observation's weight
        ``w``), the evidence that the particles still hold the robot against
        the alternative (the place filter's predicted belief, else a uniform
        prior over the places) is
        ``r = w (log sum_j pose_j p_j - log sum_j alt_j p_j)``; the
        one-sided cumulative sum ``S = min(0, S + r)`` (Page's CUSUM test for
        a change) falls when observation after observation the alternative
        explains the views better. When ``S < -reset_threshold`` (nats),
        ``reset_fraction`` of the particles are re-drawn from the
        alternative's posterior ``alt_j p_j`` and ``S`` restarts at 0.
        ``None``: no resetting.
    reset_fraction : float, default 0.5
        In ``(0, 1]``.
    start_at_first_observation : bool, default False
        Global localization from the sensor: the particles are drawn at the
        first observation from the places' prior times its likelihood
        (:meth:`PoseFilter.update` with ``kidnap=1``, at the filter's
        ``place_poses`` when given), not carried by dead reckoning from the
        start prior. A prior spread over the places and moved blindly over a
        long unobserved stretch (a run that starts far from every place)
        thins out to a few particles anywhere; the sensor's first answer is
        a far better proposal. Before it the answer is the start prior moved
        by the odometry.
    gap_metres : float, optional
        An odometry increment longer than this (metres) is a gap in the log
        (a jump of the poses, a pause of the recording while the robot was
        moved): the next observation re-initialises the particles as
        ``start_at_first_observation`` does. ``None``: no gap detection.
    answer_untempered : bool, default False
        The answer at an observed step weighs the particles' predicted
        place posterior by the step's *whole* robust likelihood (the
        tempering still governs what the particles keep for later): the
        weight discounts evidence that repeats earlier views, which the
        particles already carry, not the current view itself.
    headings : array_like, shape (n_steps, P), optional
        Row ``t``: the heading (radians, mapping frame) observation ``t``
        implies at each place (NaN = none); used when the filter has a
        :class:`HeadingModel` (:meth:`PoseFilter.update`).
    heading_weights : array_like, shape (n_steps,), optional
        The heading evidence's own weight per step (``heading_weight`` of
        :meth:`PoseFilter.update`); default the observations' weights.
    points : sequence of (m, 2) arrays or None, length n_steps, optional
        Each step's laser end points (robot frame, metres; ``None``: none),
        used when the filter has a scan map (``points`` of
        :meth:`PoseFilter.update`).
    scan_maps : sequence of ScanMap or None, length n_steps, optional
        The map each step's ``points`` are scored against instead of the
        filter's (``None`` entries: the filter's; ``scan_map`` of
        :meth:`PoseFilter.update`).

    Returns
    -------
    FilterResult
        Also ``resets`` (number of re-seedings) is set as an attribute of the
        filter: ``pose_filter.resets_``.
    """
    ll, inc, wts = _run_inputs(pose_filter, log_likelihood, increments, weights, temper)
    P, n = pose_filter.n_places, ll.shape[0]
    hds = _run_headings(headings, ll.shape)
    hws = None if heading_weights is None else np.asarray(heading_weights, dtype=np.float64).reshape(-1)
    if hws is not None and hws.size != n:
        raise InvalidParameterError(f"heading_weights must have one entry per step ({n}), got {hws.size}")
    pts = _run_points(points, n)
    maps = None if scan_maps is None else list(scan_maps)
    if maps is not None and len(maps) != n:
        raise InvalidParameterError(f"scan_maps must have one entry per step ({n}), got {len(maps)}")
    if reset_threshold is not None:
        thr = _finite("reset_threshold", reset_threshold)
        frac = _finite("reset_fraction", reset_fraction)
        if not 0 < frac <= 1:
            raise InvalidParameterError(f"reset_fraction must be in (0, 1], got {reset_fraction!r}")
    pose_filter.reset()
    if place_filter is not None:
        if place_filter.transition.n_places != P:
            raise InvalidParameterError(f"the place filter has {place_filter.transition.n_places} places, need {P}")
        place_filter.reset()
    gap = math.inf if gap_metres is None else _finite("gap_metres", gap_metres)
    out = np.empty_like(ll)
    cusum, resets = 0.0, 0
    lost = bool(start_at_first_observation)
    uniform = np.full(P, -math.log(P))
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
        if reset_threshold is not None:
            lp = pose_filter.place_likelihood(row)
            alt = uniform if prior is None else prior
            mine = pose_filter.place_log_posterior() + lp
            theirs = alt + lp
            r = float(wts[t]) * (float(logsumexp(mine)) - float(logsumexp(theirs)))
            cusum = min(0.0, cusum + r)
        hd = None if hds is None else hds[t]
        q = None if pts is None else pts[t]
        sm = None if maps is None else maps[t]
        if lost:
            out[t] = _update(pose_filter, row, 1.0, prior, 1.0, hd, points=q, scan_map=sm)
            lost, cusum = False, 0.0
            continue
        predicted = pose_filter.place_log_posterior() if answer_untempered else None
        out[t] = _update(pose_filter, row, float(wts[t]), prior, None, hd, None if hws is None else float(hws[t]), q, sm)
        if predicted is not None:
            full = predicted + pose_filter.place_likelihood(row)
            if np.any(np.isfinite(full)):
                out[t] = full - logsumexp(full)
        if reset_threshold is not None and cusum < -thr:
            out[t] = pose_filter.reseed(theirs - logsumexp(theirs), frac)
            cusum, resets = 0.0, resets + 1
    pose_filter.resets_ = resets
    return FilterResult.from_log_posterior(out)


@dataclass(frozen=True, slots=True)
class Challenger:
    """Settings of the challenger filter of :func:`run_challenged_pose_filter`.

    Attributes
    ----------
    n_particles : int, default 1000
        Particles of the challenger (the incumbent keeps its own count).
    spawn_nats : float, default 0.0
        A challenger is started at an observation that the "robot was put
        anywhere" hypothesis (the place filter's predicted belief times the
        observation's likelihood) explains better than the incumbent's
        particles by more than this many nats (tempered).
    switch_nats : float, default 3.0
        The challenger replaces the incumbent when the log Bayes factor of
        its trajectory against the incumbent's (summed log predictive
        likelihoods since it started, the starting observation included)
        exceeds this.
    drop_nats : float, default 3.0
        The challenger is dropped when that log Bayes factor falls below ``-drop_nats``.
    max_observations : int, default 10
        ... or after this many observations without a switch ...
    merged_tv : float, default 0.25
        ... or when its place posterior is within this total variation of
        the incumbent's (it has found the same track: no rival).
    tempered_evidence : bool, default True
        Compare the two trajectories with the tempered likelihoods (as the
        updates weigh them); False: every observation at full weight in the
        Bayes factor (the updates stay tempered).
    """

    n_particles: int = 1000
    spawn_nats: float = 0.0
    switch_nats: float = 3.0
    drop_nats: float = 3.0
    max_observations: int = 10
    merged_tv: float = 0.25
    tempered_evidence: bool = True

    def __post_init__(self) -> None:
        if isinstance(self.n_particles, bool) or not isinstance(self.n_particles, (int, np.integer)) or self.n_particles < 10:
            raise InvalidParameterError(f"n_particles must be an integer >= 10, got {self.n_particles!r}")
        _finite("switch_nats", self.switch_nats)
        _finite("drop_nats", self.drop_nats)
        if not math.isfinite(float(self.spawn_nats)):
            raise InvalidParameterError(f"spawn_nats must be finite, got {self.spawn_nats!r}")
        if isinstance(self.max_observations, bool) or not isinstance(self.max_observations, (int, np.integer)) or self.max_observations < 1:
            raise InvalidParameterError(f"max_observations must be an integer >= 1, got {self.max_observations!r}")


def _total_variation(log_p: FArray, log_q: FArray) -> float:
    return 0.5 * float(np.abs(np.exp(log_p) - np.exp(log_q)).sum())


def run_challenged_pose_filter(
    log_likelihood: Any,
    increments: Any,
    pose_filter: PoseFilter,
    challenger: Challenger | None = None,
    *,
    weights: Any = None,
    temper: tuple[float, float] | None = None,
    place_filter: MarkovFilter | None = None,
    start_at_first_observation: bool = False,
    gap_metres: float | None = None,
    headings: Any = None,
) -> FilterResult:
    """:func:`run_pose_filter` with a challenger: a second filter started from the sensor, adopted when its trajectory fits better.

    A kidnapped (or lost) pose filter recovers slowly: its kidnapping term
    re-draws a few particles with the views' likelihood, and those, with a
    guessed heading, seldom survive the next moves. Here, when an
    observation is explained better by "the robot is anywhere" (the place
    filter's predicted belief, or uniform, times the robust likelihood) than
    by the incumbent's particles, a whole second filter (the *challenger*) is
    started from that observation (as :meth:`PoseFilter.update` with
    ``kidnap=1``: the places' prior times the likelihood, any heading) and
    moved by the same odometry. At each later observation both filters'
    log predictive likelihoods (:meth:`PoseFilter.log_evidence`, tempered as
    the updates) are added to a log Bayes factor, which starts with the
    starting observation's ratio. A run of confident wrong single-shot
    answers seldom forms a trajectory consistent with the odometry and the
    place layout, so a challenger born of them loses and is dropped; after a
    real kidnapping the incumbent's particles are at the wrong places (or at
    none) while the challenger's follow the robot, and it wins within a few
    observations. The incumbent then adopts the challenger's particles
    (:meth:`PoseFilter.adopt`). Answers are the incumbent's.

    Parameters
    ----------
    log_likelihood, increments, pose_filter, weights, temper, place_filter, start_at_first_observation, gap_metres, headings
        As :func:`run_pose_filter`.
    challenger : Challenger, optional
        Default ``Challenger()``.

    Returns
    -------
    FilterResult
        ``pose_filter.resets_`` is set to the number of switches,
        ``pose_filter.switches_`` to the steps where they happened and
        ``pose_filter.challenger_trace_`` to ``(step, event, log Bayes
        factor)`` for every spawn, comparison, switch and drop.
    """
    ch = Challenger() if challenger is None else challenger
    ll, inc, wts = _run_inputs(pose_filter, log_likelihood, increments, weights, temper)
    P, n = pose_filter.n_places, ll.shape[0]
    hds = _run_headings(headings, ll.shape)
    pose_filter.reset()
    if place_filter is not None:
        if place_filter.transition.n_places != P:
            raise InvalidParameterError(f"the place filter has {place_filter.transition.n_places} places, need {P}")
        place_filter.reset()
    gap = math.inf if gap_metres is None else _finite("gap_metres", gap_metres)
    out = np.empty_like(ll)
    lost = bool(start_at_first_observation)
    uniform = np.full(P, -math.log(P))
    rival: PoseFilter | None = None
    factor, age = 0.0, 0
    switches: list[int] = []
    trace: list[tuple[int, str, float]] = []
    for t in range(n):
        row = ll[t]
        observed = not np.all(np.isnan(row))
        prior = _place_step(place_filter, row, inc, t, observed)
        if t > 0:
            pose_filter.predict(inc[t - 1])
            if rival is not None:
                rival.predict(inc[t - 1])
            if math.hypot(inc[t - 1, 0], inc[t - 1, 1]) > gap:
                lost, rival = True, None
        if not observed:
            out[t] = pose_filter.place_log_posterior()
            continue
        hd = None if hds is None else hds[t]
        if lost:
            out[t] = _update(pose_filter, row, 1.0, prior, 1.0, hd)
            lost = False
            continue
        w = float(wts[t])
        we = w if ch.tempered_evidence else 1.0
        mine = _evidence(pose_filter, row, we, hd)
        if rival is not None:
            factor += _evidence(rival, row, we, hd) - mine
            _update(rival, row, w, prior, None, hd)
            age += 1
            trace.append((t, "compare", factor))
        out[t] = _update(pose_filter, row, w, prior, None, hd)
        if rival is not None:
            if factor > ch.switch_nats:
                out[t] = pose_filter.adopt(rival)
                switches.append(t)
                trace.append((t, "switch", factor))
                rival = None
            elif (
                factor < -ch.drop_nats
                or age >= ch.max_observations
                or _total_variation(rival.place_log_posterior(), out[t]) < ch.merged_tv
            ):
                trace.append((t, "drop", factor))
                rival = None
            continue
        alt = uniform if prior is None else np.asarray(prior, dtype=np.float64) - logsumexp(prior)
        anywhere = float(logsumexp(alt + we * pose_filter.place_likelihood(row)))
        if anywhere - mine > ch.spawn_nats:
            rival = pose_filter.spawn(ch.n_particles)
            _update(rival, row, 1.0, prior, 1.0, hd)
            factor, age = anywhere - mine, 0
            trace.append((t, "spawn", factor))
    pose_filter.resets_ = len(switches)
    pose_filter.switches_ = switches
    pose_filter.challenger_trace_ = trace
    return FilterResult.from_log_posterior(out)
