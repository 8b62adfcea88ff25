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

* **Scan evidence** (optional, a :class:`~fingerloc.map.scan_map.ScanMap`):
  the observation's laser end points weigh each particle by how well they
  fit the mapping run's at the particle's pose (a likelihood field), and a
  belief whose best particle fits worse than usual is taken for lost.

The filter moves one step at a time; :mod:`fingerloc.map.driver` runs it
along a run (tempering, the place filter alongside, re-initialisation after
a gap, and the relocalization strategies). The odometry model is in
:mod:`fingerloc.map.motion`, the heading evidence in :mod:`fingerloc.map.heading`.

Everything is in log space; a likelihood of zero never makes a NaN.
"""

from __future__ import annotations

import math
from typing import Any, Literal, overload

import numpy as np
from scipy.spatial import cKDTree

from .._lse import logsumexp  # scipy.special.logsumexp, bit for bit, without its per-call overhead
from .._types import FArray, IArray
from ..angles import wrap
from ..errors import InvalidParameterError
from ..validation import check_random_state
from ._checks import finite as _finite
from .heading import HeadingModel
from .motion import MotionNoise, as_poses
from .scan_map import ScanMap

__all__ = ["PoseFilter", "observation_weights", "path_start_poses"]


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
    lost_uniform_share : float, default 0.0
        A lost re-draw's prior is ``(1 - share) kidnap_prior + share /
        P``: the place filter run beside the particles was fed the same
        views that misled them, so its belief may be as lost as theirs (a
        re-draw taken from it alone lands where the particles already are);
        in ``[0, 1]`` (``lost_uniform``: 1).
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
        lost_uniform_share: float = 0.0,
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
        self.lost_uniform_share = _finite("lost_uniform_share", lost_uniform_share)
        if self.lost_uniform_share > 1:
            raise InvalidParameterError(f"lost_uniform_share must be in [0, 1], got {lost_uniform_share!r}")
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
        self._grid: Any = None
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
        if self.centres.shape[0] > 32:  # beyond a few dozen places a grid cell's candidates are faster (the same answer)
            if self._grid is None:
                from ._nearest import CentreGrid

                self._grid = CentreGrid(self.centres)
            return self._grid.nearest(xy)
        from ._nearest import nearest_centres  # the tree's answer, compiled brute force

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
            elif kidnap_prior is not None and self.lost_uniform_share > 0:
                kp = np.asarray(kidnap_prior, dtype=np.float64).reshape(-1)
                u = self.lost_uniform_share
                kidnap_prior = np.logaddexp(math.log1p(-u) + kp - logsumexp(kp), math.log(u / P)) if u < 1 else None
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
    p = as_poses(poses)
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
