"""Markov localization on the CARMEN logs: filtered methods and the kidnapped-robot experiment (issue 8).

* :class:`FilteredMethod` wraps any single-shot method of the real-log
  benchmark (:mod:`fingerloc.experiments.carmen`) with the discrete Bayes
  filter of :mod:`fingerloc.map.filter`. It is registered as
  ``fingerprint-filtered`` (the ``fingerprint`` method, whatever its current
  configuration) and, run only when named, ``baseline-histogram-filtered`` and
  ``baseline-scancontext-filtered`` (the baselines' scores turned into
  pseudo-likelihoods, to show the filter's effect on another front end);
  ablations ``fingerprint-filtered-no-odometry`` (per-step counts) and
  ``fingerprint-filtered-unscaled`` (``beta = 1``), also run only when named.
* :class:`PoseFilteredMethod`: the same front end followed by the pose
  particle filter of :mod:`fingerloc.map.pose_filter` (odometry increments,
  not only distances; the particles also weighed by the heading each view
  implies, :class:`~fingerloc.map.pose_filter.HeadingModel`), registered as
  ``fingerprint-odometry``; ablations ``fingerprint-odometry-exact``,
  ``fingerprint-odometry-untempered``, ``fingerprint-odometry-noheading``
  and ``fingerprint-odometry-heading-untempered``, and
  ``baseline-histogram-odometry``, run only when named.
* :func:`kidnap_experiment`: splice two distant stretches of a log's query
  pass and count the steps the filter needs to recover (either filter).

Everything the filter needs is taken from the **mapping pass** only:

* the place graph: the nearest place centre (its Voronoi cell) of every
  mapping scan, in file order; consecutive scans count a stay (same place) or
  a passage (:meth:`fingerloc.map.graph.PlaceGraph.from_sequence`);
* odometry: ``L`` = metres travelled per change of place along the mapping
  pass; each step's travelled distance is the distance between consecutive
  scan poses (the corrected poses stand in for odometry: over one step of
  about a metre the two differ little);
* the likelihood scale ``beta`` (:func:`fingerloc.map.filter.fit_likelihood_scale`):
  the base method is fit on half of the training scans and scores the other
  half, two ways round (halves = alternate *visits* of each place, so that a
  held-out scan was not taken a second before a training one); ``beta``
  maximises the held-out log-probability of the right place. The fingerprint
  program's independence assumptions make its log-likelihoods overconfident;
  the baselines' similarities have no probabilistic scale at all.
* the uniform mixing term: ``1 / (N + 2)``, ``N`` counted steps (Laplace's rule
  for a jump never seen while mapping).

Nothing is tuned on the query pass. The filter steps through **every**
query-pass scan in file order; scans outside every place's radius are
prediction-only steps (no observation), as the issue asks.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from .._types import FArray, IArray
from ..errors import InvalidParameterError
from ..map.filter import FilterResult, TransitionModel, fit_outlier_weight, run_filter
from ..map.graph import PlaceGraph
from ..map.pose_filter import Challenger, HeadingModel
from ..map.relocalize import Augmented
from ..map.scan_map import ScanMap, end_points
from ..pipeline.tracker import (
    HEADING_TEMPER_M,
    HOLD_MARGIN,
    POSE_PARTICLES,
    SCAN_FRESH,
    TIE_BREAK,
    TUNE_WITH_HEADING,
    Calibration,
    FitScore,
    HeldOut,
    Tracker,
    challenger_of,
    heading_of,
    held_out_calibration,
    held_out_headings,
    run_pose_steps,
    scan_tuning_inputs,
    step_distances,
    tune_pose_filter,
    with_heading_model,
)
from ..pipeline.tracker import MIN_CALIBRATION_ROWS as _MIN_CALIBRATION_ROWS
from ..pipeline.tracker import mapping_graph as _mapping_graph
from ..sensors import Scan
from ..validation import check_random_state
from .protocol import METHODS, Method, Split, load_methods, make_split, rank_metrics, register_method, true_place_ranks

__all__ = [
    "FilteredMethod",
    "KidnapResult",
    "PoseFilteredMethod",
    "TrackingData",
    "field_of_view",
    "implied_headings",
    "kidnap_experiment",
    "mapping_graph",
    "prepare_tracking",
    "run_kidnap",
    "step_distances",
    "tracking_ranks",
    "with_synthetic_likelihood",
]


#: Total-variation distance below which two posteriors count as merged (kidnapping forgotten).
MERGED_TV = 0.1
#: A pose at no place weighs this / P at an observation when ``rho`` is fitted (the pose filter's old default rho).
DEFAULT_OFF_PLACE = 0.1

#: Held-out rows needed to fit the likelihood scale from visits; fewer -> alternate scans.
MIN_CALIBRATION_ROWS = _MIN_CALIBRATION_ROWS


def _positions(scans: Sequence[Scan]) -> FArray:
    return _full_poses(scans)[:, :2]


def mapping_graph(positions: Any, split: Split) -> tuple[PlaceGraph, float]:
    """The place graph and ``L`` (metres per place change) of a log's mapping pass.

    The library's :func:`fingerloc.pipeline.tracker.mapping_graph` on the
    mapping pass, places ``"0" .. "P-1"``.

    Parameters
    ----------
    positions : array_like, shape (n_scans, 2)
        Every scan's position, metres.
    split : Split

    Returns
    -------
    graph : PlaceGraph
    metres_per_move : float
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2)[: split.n_mapping]
    return _mapping_graph(pos, split.centres)


def _method_fit_score(factory: Callable[[], Method], scans: Sequence[Scan]) -> FitScore:
    """The library's :data:`~fingerloc.pipeline.tracker.FitScore` of a benchmark method over scans."""

    def fit_score(tr: IArray, y: IArray, te: IArray) -> FArray:
        m = factory()
        m.fit([scans[i] for i in tr.tolist()], y)
        return np.asarray(m.score([scans[i] for i in te.tolist()]), dtype=np.float64)

    return fit_score


class FilteredMethod:
    """A single-shot method of the benchmark followed by the Markov filter over places.

    The benchmark runner calls :meth:`set_context` with the log's scans and
    split before :meth:`fit` (the filter needs the trajectory: the mapping
    pass for the graph, the query pass for the steps between queries).

    Parameters
    ----------
    base : str
        Registered name of the single-shot method.
    odometry : bool, default True
        Use the travelled distance of each step (``K = expm(d / L (M - I))``);
        False uses the per-step stay / move counts.
    calibrate : bool, default True
        Fit the likelihood scale ``beta`` on the mapping pass (module
        docstring); False uses the base scores as log-likelihoods (``beta = 1``).
    alpha : float, default 1.0
        Additive smoothing of the transition counts.

    Attributes
    ----------
    base_ : Method
    graph_ : PlaceGraph
    transition_ : TransitionModel
    scale_ : float
        ``beta``.
    result_ : FilterResult
        The filter's output over the whole query pass after :meth:`score`.
    """

    name = "filtered"

    def __init__(self, base: str, *, odometry: bool = True, calibrate: bool = True, alpha: float = 1.0) -> None:
        self.base = base
        self.odometry = odometry
        self.calibrate = calibrate
        self.alpha = alpha
        self._context: tuple[list[Scan], Split] | None = None

    def _factory(self) -> Callable[[], Method]:
        from functools import partial

        from .shared import shared_method

        load_methods()
        if self.base not in METHODS:
            raise InvalidParameterError(f"unknown base method {self.base!r} (known: {', '.join(METHODS)})")
        # the base's fits and scores are shared with the run's other methods (inside shared_results only)
        return partial(shared_method, self.base, METHODS[self.base])

    def set_context(self, scans: Sequence[Scan], split: Split) -> None:
        """The whole log (file order) and its split; called by the runner before :meth:`fit`."""
        self._context = (list(scans), split)

    def _need_context(self) -> tuple[list[Scan], Split]:
        if self._context is None:
            raise InvalidParameterError(
                f"{self.name} needs the log's trajectory: call set_context(scans, split) before fit (run_log does)"
            )
        return self._context

    def fit(self, scans: Sequence[Scan], labels: Any) -> FilteredMethod:
        """Fit the base method, build the graph and transition model, calibrate the likelihood scale."""
        all_scans, split = self._need_context()
        y = np.asarray(labels, dtype=np.int64).reshape(-1)
        factory = self._factory()
        self.base_ = factory()
        self.base_.fit(scans, y)
        pos = _positions(all_scans)
        self.graph_, metres = mapping_graph(pos, split)
        self.transition_ = TransitionModel.from_graph(
            self.graph_, alpha=self.alpha, metres_per_move=metres if self.odometry else None
        )
        self.scale_ = 1.0
        self.calibration_rows_ = 0
        self.held_out_: HeldOut | None = None
        if self.calibrate:  # the library's calibration (fingerloc.pipeline.tracker.held_out_calibration)
            self.held_out_ = held_out_calibration(
                _method_fit_score(factory, scans),
                split.train_idx,
                y,
                split.n_places,
                by_visits=len(scans) == split.n_train,
            )
            self.scale_, self.calibration_rows_ = self.held_out_.beta, self.held_out_.rows
        return self

    def step_log_likelihoods(self, query_scores: Any) -> tuple[FArray, FArray]:
        """Per-step log-likelihood rows of the query pass (NaN = prediction only) and the steps' distances.

        Parameters
        ----------
        query_scores : array_like, shape (n_queries, P)
            The base method's scores of the split's queries.

        Returns
        -------
        log_likelihood : ndarray, shape (n_scans - n_mapping, P)
        distances : ndarray, shape (n_scans - n_mapping,)
        """
        all_scans, split = self._need_context()
        s = np.asarray(query_scores, dtype=np.float64)
        ll = np.full((split.n_scans - split.n_mapping, split.n_places), np.nan)
        ll[split.query_idx - split.n_mapping] = self.scale_ * np.where(np.isnan(s), -np.inf, s)
        return ll, step_distances(_positions(all_scans[split.n_mapping :]))

    def score(self, scans: Sequence[Scan]) -> FArray:
        """The filtered log-posterior at each query, shape (n_queries, P); the filter runs over the whole query pass."""
        _, split = self._need_context()
        if len(scans) != split.n_queries:
            raise InvalidParameterError(
                f"{self.name} scores the split's {split.n_queries} queries, got {len(scans)} scans"
            )
        self.query_scores_ = np.asarray(self.base_.score(scans), dtype=np.float64)
        ll, dist = self.step_log_likelihoods(self.query_scores_)
        self.result_: FilterResult = self._run_query_pass(ll, dist)
        return self.result_.log_posterior[split.query_idx - split.n_mapping]

    def _run_query_pass(self, log_likelihood: FArray, distances: FArray) -> FilterResult:
        """The filter over the whole query pass (rows of :meth:`step_log_likelihoods`)."""
        return run_filter(log_likelihood, self.transition_, distances=distances)


@register_method("fingerprint-filtered")
def _fingerprint_filtered() -> Method:
    return FilteredMethod("fingerprint")


@register_method("fingerprint-filtered-no-odometry", default=False)
def _fingerprint_filtered_no_odometry() -> Method:
    # Ablation: per-step stay / move counts instead of the travelled distance.
    return FilteredMethod("fingerprint", odometry=False)


@register_method("fingerprint-filtered-unscaled", default=False)
def _fingerprint_filtered_unscaled() -> Method:
    # Ablation: the model's log-posterior as the log-likelihood (beta = 1, no calibration).
    return FilteredMethod("fingerprint", calibrate=False)


@register_method("baseline-histogram-filtered", default=False)
def _histogram_filtered() -> Method:
    return FilteredMethod("baseline-histogram")


@register_method("baseline-scancontext-filtered", default=False)
def _scancontext_filtered() -> Method:
    return FilteredMethod("baseline-scancontext")


class PoseFilteredMethod(FilteredMethod):
    """A single-shot method followed by the pose particle filter (:mod:`fingerloc.map.pose_filter`).

    Like :class:`FilteredMethod` (same base fit and likelihood scale
    ``beta``), but the filter tracks the robot's pose in the mapping frame
    with the odometry *increments* (direction and turn, not only distance).
    Set from the mapping pass only: the place centres and the protocol's
    radius; the particles are drawn from the first observation (uniform
    prior over the places times its likelihood, any heading); the kidnapping
    probability per observation is ``1 / (n_train + 2)`` (Laplace's rule
    over the mapping pass's observations, as the discrete filter's mixing
    term); the motion noise is the filter's default; ``outlier`` and the
    tempering distance are chosen along the mapping pass (``tune``, below).
    Observations are tempered (:func:`~fingerloc.map.pose_filter.observation_weights`):
    one counts fully after the robot has travelled the place spacing (2 m,
    the map's own scale: views closer than that are one place) or turned by
    the laser's field of view (a disjoint view), in proportion before.

    The shared logs hold only corrected poses, so the odometry is simulated:
    the exact increments corrupted by :class:`~fingerloc.map.pose_filter.OdometryError`
    (``odometry="simulated"``, seeded) or left exact (``odometry="exact"``).

    Parameters
    ----------
    base : str
    odometry : {"simulated", "exact"}, default "simulated"
    n_particles : int, default POSE_PARTICLES
        :data:`fingerloc.pipeline.tracker.POSE_PARTICLES`, as :class:`~fingerloc.pipeline.tracker.Tracker`.
    outlier : float, default 0.1
    seed : int, default 0
        Seeds the simulated odometry and the particle filter.
    calibrate : bool, default True
        Fit ``beta`` (:class:`FilteredMethod`).
    temper : bool, default True
        Weigh observations by the motion since the previous one.
    odometry_error : float, default 1.0
        Factor on every error of the simulated odometry (0 = exact).
    relocalize : bool, default True
        Run the discrete filter alongside; its predicted belief is where a
        kidnapped robot is looked for (:func:`~fingerloc.map.pose_filter.run_pose_filter`).
    kidnap : float, optional
        Kidnapping probability per observation; default ``1 / (n_train + 2)``.
    observe : bool, default True
        False: the sensor's rows are replaced by uniform ones at the observed
        steps (``odometry-only``): what the odometry and the place layout
        alone give. The filter still learns at each query that the robot is
        at *some* place (the benchmark observes only there).
    start_at_first_observation : bool, default True
        Draw the particles from the first observation (prior times its
        likelihood) instead of carrying the start prior blindly
        (:func:`~fingerloc.map.pose_filter.run_pose_filter`).
    reset_threshold : float, optional
        Sensor resetting after this many nats of disagreement (CUSUM) with
        the place filter; ``None`` = off.
    gap_metres : float, optional
        Odometry steps longer than this re-initialise at the next observation.
    off_place : float, optional
        The filter's likelihood weight of a pose at no place (default
        ``outlier``); with ``outlier="fit"`` it stays 0.1.

    challenger : bool, default False
        Run a challenger filter started from the sensor and switch to it when
        its trajectory's log Bayes factor against the incumbent's exceeds
        ``challenger_switch_nats``
        (:func:`~fingerloc.map.pose_filter.run_challenged_pose_filter`; also
        during ``tune``).
    challenger_switch_nats : float, default 3.0
    heading : bool, default True
        Weigh the particles also by the heading each observation implies
        (:class:`~fingerloc.map.pose_filter.HeadingModel`): a base method
        that estimates the robot's heading relative to the matched training
        view (the fingerprint program's cyclic alignment,
        :meth:`fingerloc.model.PlaceModel.headings_with_reference`) and that
        view's recorded heading give, per place, an absolute heading
        (:func:`implied_headings`). The heading model is fitted on the
        mapping pass (:func:`~fingerloc.map.pose_filter.fit_heading_model`
        on the held-out rows of ``beta``: each at its own place, from the
        fold model that did not see it); the tuning runs with it when ``tune_heading``. A base
        method without headings (the baselines) leaves it off. The default
        since the third session of issue 15 (docs/RESULTS.md: +2 to +6
        points pooled at each of five seeds on the shared logs); method
        ``fingerprint-odometry-noheading`` turns it off.
    heading_reverse : bool, default True
        Let the heading model have a peak at the reverse heading.
    heading_temper_metres : float, default HEADING_TEMPER_M
        The heading evidence counts fully after this much travel (or the
        field of view's turn); 0: as the observations (the tuned tempering).
        :data:`fingerloc.pipeline.tracker.HEADING_TEMPER_M` (8 m): on the
        shared logs' mapping passes a held-out view's heading error stays
        correlated with the previous ones' up to 8 m of travel.
    tune_heading : bool, default TUNE_WITH_HEADING (False)
        Run ``tune`` (on the mapping pass) with the heading evidence too
        (:data:`fingerloc.pipeline.tracker.TUNE_WITH_HEADING`: as good
        without, in half the time).
    heading_slope : bool, default True
        Let the heading estimate's reliability grow with the view's
        probability of the place (:class:`~fingerloc.map.pose_filter.HeadingModel`).
    augmented : Augmented, optional
        Augmented MCL: a share of the belief re-drawn from the sensor when
        the short-term average likelihood falls below the long-term one
        (:func:`~fingerloc.map.relocalize.run_augmented_pose_filter`; the
        tuning on the mapping pass runs without it). ``None`` = off.
    hold_margin : float, optional, default HOLD_MARGIN (0.05)
        Between observations the best place is held unless another place's
        probability exceeds it by this much
        (:func:`~fingerloc.map.relocalize.held_best`; the posterior and the
        answers at observed steps are unchanged). ``None`` = the argmax.
    tie_break : float, optional, default TIE_BREAK (0.02)
        Between observations, among the places within this probability of
        the answer, the one the discrete place filter (deterministic, over
        the same steps) believes most
        (:func:`~fingerloc.map.relocalize.tie_broken_best`; after
        ``hold_margin``). ``None`` = off. Both defaults since issue 15's
        third session (docs/RESULTS.md): two runs with other random draws
        disagree less between places, tracking is unchanged.
    scan : bool, default False
        Weigh the particles also by the laser end points of each observed
        scan against the mapping pass's
        (:class:`~fingerloc.map.scan_map.ScanMap` of every mapping scan at
        its corrected pose: the recorded run), with the power ``scan_gamma``
        chosen along the mapping pass by ``tune`` (each held-out training
        scan scored against a map of the other fold's training scans,
        :func:`~fingerloc.pipeline.tracker.fold_scan_maps`; 0 = off when the
        mapping pass does not favour it). On for ``fingerprint-odometry``
        (docs/RESULTS.md, "Scan evidence"); without ``tune``, or with
        ``observe=False`` and no tuning, ``scan_gamma`` is used as given.
    scan_gamma : float, optional
        A fixed power of the scan evidence instead of the tuned one (an
        ablation: not decided on the mapping pass).
    scan_starts : int, default 1
        The tuning of the scan evidence's power runs from this many starts
        along the mapping pass (``scan_starts`` of
        :func:`~fingerloc.pipeline.tracker.tune_pose_filter`).
    scan_fresh : int, default SCAN_FRESH
        With the scan evidence, a (re)initialisation from the sensor (the
        first observation, a gap, a lost belief) draws this many times the
        particles (``Calibration.scan_fresh``, also in the tuning;
        :data:`fingerloc.pipeline.tracker.SCAN_FRESH`, 10: docs/RESULTS.md,
        "A filter that does not stay locked"); 1: as before.
    lost : bool, default True
        With the scan evidence and its power tuned: lost detection by the
        scan fit, calibrated on the mapping pass (``lost`` of
        :func:`~fingerloc.pipeline.tracker.tune_pose_filter`); False: as before.
    lost_after : int, default 1
        Observations in a row below the lost threshold before a re-draw
        (``Calibration.lost_after``).
    lost_statistic : {"best", "mean"}, default "best"
    lost_uniform : bool, default False
        The fit statistic and the re-draw's prior
        (:class:`~fingerloc.map.pose_filter.PoseFilter`).

    ``outlier="fit"`` fits ``rho`` to the front end's reliability on the
    mapping pass (:func:`~fingerloc.map.filter.fit_outlier_weight` on the
    same held-out rows as ``beta``).

    ``tune=True`` (the default) chooses ``rho`` (0.1, 0.3 or the fitted one)
    and the tempering distance (1, 2 or 4 m) along the *mapping* pass with
    the library's :func:`~fingerloc.pipeline.tracker.tune_pose_filter` (the
    same as ``fingerloc map``). Nothing is taken from the query pass.
    """

    name = "pose-filtered"

    def __init__(
        self,
        base: str,
        *,
        odometry: str = "simulated",
        n_particles: int = POSE_PARTICLES,
        outlier: float | str = 0.1,
        seed: int = 0,
        calibrate: bool = True,
        temper: bool = True,
        odometry_error: float = 1.0,
        relocalize: bool = True,
        kidnap: float | None = None,
        observe: bool = True,
        start_at_first_observation: bool = True,
        reset_threshold: float | None = None,
        gap_metres: float | None = None,
        off_place: float | None = None,
        tune: bool = True,
        challenger: bool = False,
        challenger_switch_nats: float = 3.0,
        heading: bool = True,
        heading_reverse: bool = True,
        heading_slope: bool = True,
        heading_temper_metres: float = HEADING_TEMPER_M,
        tune_heading: bool = TUNE_WITH_HEADING,
        augmented: Augmented | None = None,
        hold_margin: float | None = HOLD_MARGIN,
        tie_break: float | None = TIE_BREAK,
        scan: bool = False,
        scan_gamma: float | None = None,
        scan_starts: int = 1,
        scan_fresh: int = SCAN_FRESH,
        lost: bool = True,
        lost_after: int = 1,
        lost_statistic: str = "best",
        lost_uniform: bool = False,
    ) -> None:
        super().__init__(base, calibrate=calibrate)
        if isinstance(scan_fresh, bool) or not isinstance(scan_fresh, (int, np.integer)) or scan_fresh < 1:
            raise InvalidParameterError(f"scan_fresh must be an integer >= 1, got {scan_fresh!r}")
        self.scan_fresh = int(scan_fresh)
        self.lost = bool(lost)
        self.lost_after = int(lost_after)
        self.lost_statistic = lost_statistic
        self.lost_uniform = bool(lost_uniform)
        self.scan = bool(scan)
        self.scan_starts = int(scan_starts)
        if scan_gamma is not None and not (math.isfinite(scan_gamma) and scan_gamma >= 0):
            raise InvalidParameterError(f"scan_gamma must be a finite number >= 0, got {scan_gamma!r}")
        self.scan_gamma = scan_gamma
        self.heading = bool(heading)
        self.heading_reverse = bool(heading_reverse)
        self.heading_slope = bool(heading_slope)
        self.heading_temper_metres = float(heading_temper_metres)
        self.tune_heading = bool(tune_heading)
        if tie_break is not None and (math.isnan(tie_break) or tie_break < 0):
            raise InvalidParameterError(f"tie_break must be >= 0, got {tie_break!r}")
        self.tie_break = tie_break
        self.augmented = augmented
        if hold_margin is not None and (math.isnan(hold_margin) or hold_margin < 0):
            raise InvalidParameterError(f"hold_margin must be >= 0 (or inf), got {hold_margin!r}")
        self.hold_margin = hold_margin
        self.challenger = bool(challenger)
        self.challenger_switch_nats = challenger_switch_nats
        self.tune = tune
        if isinstance(outlier, str) and outlier != "fit":
            raise InvalidParameterError(f"outlier must be a probability or 'fit', got {outlier!r}")
        self.observe = observe
        self.start_at_first_observation = start_at_first_observation
        self.reset_threshold = reset_threshold
        self.gap_metres = gap_metres
        self.off_place = off_place
        if kidnap is not None and not (math.isfinite(kidnap) and 0 <= kidnap < 1):
            raise InvalidParameterError(f"kidnap must be a probability in [0, 1), got {kidnap!r}")
        self.kidnap = kidnap
        self.temper = temper
        self.relocalize = relocalize
        if not (math.isfinite(odometry_error) and odometry_error >= 0):
            raise InvalidParameterError(f"odometry_error must be a finite factor >= 0, got {odometry_error!r}")
        self.odometry_error = odometry_error
        if odometry not in ("simulated", "exact"):
            raise InvalidParameterError(f"odometry must be 'simulated' or 'exact', got {odometry!r}")
        self.odometry_source = odometry
        self.n_particles = n_particles
        self.outlier = outlier
        self.seed = seed

    def fit(self, scans: Sequence[Scan], labels: Any) -> PoseFilteredMethod:
        """Fit the base method and ``beta`` (:meth:`FilteredMethod.fit`), then set up the library's tracker."""
        from ..map.pose_filter import wheel_odometry
        from ..pipeline.places import PLACE_RADIUS_M, PLACE_SPACING_M

        super().fit(scans, labels)
        all_scans, split = self._need_context()
        poses = _full_poses(all_scans)
        self.kidnap_ = 1.0 / (len(scans) + 2) if self.kidnap is None else self.kidnap
        held = self.held_out_
        if self.outlier == "fit":
            usable = held is not None and held.labels.size > 0
            outlier = fit_outlier_weight(self.scale_ * held.scores, held.labels) if held is not None and usable else 0.1
            off_place = DEFAULT_OFF_PLACE if self.off_place is None else self.off_place
        else:
            outlier = float(self.outlier)
            off_place = outlier if self.off_place is None else self.off_place
        metres = self.transition_.metres_per_move
        self.calibration_ = Calibration(
            beta=self.scale_,
            metres_per_move=1.0 if metres is None else metres,
            temper_metres=PLACE_SPACING_M,
            temper_radians=field_of_view(all_scans[: split.n_mapping]),
            kidnap=self.kidnap_,
            radius=PLACE_RADIUS_M,
            spacing=PLACE_SPACING_M,
            alpha=self.alpha,
            n_train=len(scans),
            calibration_rows=self.calibration_rows_,
            outlier=outlier,
            off_place=off_place,
            start_at_first_observation=self.start_at_first_observation,
            gap_metres=self.gap_metres,
            challenger=self.challenger,
            challenger_switch_nats=self.challenger_switch_nats,
            hold_margin=self.hold_margin,
            tie_break=self.tie_break,
            scan_fresh=self.scan_fresh if self.scan else 1,
            lost_after=self.lost_after,
            lost_statistic=self.lost_statistic,
            lost_uniform=self.lost_uniform,
        )
        factor = self.odometry_error if self.odometry_source == "simulated" else 0.0
        self.held_headings_: FArray | None = None
        if self.heading and self.observe and held is not None and held.labels.size:
            self.held_headings_ = self._held_out_headings(scans, np.asarray(labels, dtype=np.int64).reshape(-1))
            if self.held_headings_ is not None:
                self.calibration_ = with_heading_model(
                    self.calibration_, held, self.held_headings_, poses[split.train_idx[held.index], 2],
                    reverse=self.heading_reverse, slope=self.heading_slope, temper_metres=self.heading_temper_metres,
                )  # fmt: skip
        self.tracker_ = Tracker(split.centres, self.graph_, self.calibration_, n_particles=self.n_particles)
        self.tuning_: list[dict[str, float]] = []
        self.scan_map_: ScanMap | None = None
        self.scan_points_: list[FArray] | None = None
        scan_args: dict[str, Any] = {}
        if self.scan:
            self.scan_points_ = [end_points(s) for s in all_scans]
            self.scan_map_ = ScanMap.from_scans(self.scan_points_[: split.n_mapping], poses[: split.n_mapping])
            if self.scan_gamma is None and held is not None:
                scan_args = scan_tuning_inputs(self.scan_points_, poses, split.train_idx, labels, held)
        if self.tune and held is not None and (self.observe or (self.scan and self.scan_gamma is None)):
            # without the sensor (observe=False) the tuning runs on uniform rows: what the scan evidence adds alone
            tuned_on = held if self.observe else replace(held, scores=np.zeros_like(held.scores))
            self.calibration_, self.tuning_ = tune_pose_filter(
                self.tracker_, tuned_on, split.train_idx, poses[: split.n_mapping], odometry_error=factor,
                seed=self.seed, temper=self.temper, relocalize=self.relocalize,
                headings=self.held_headings_ if self.tune_heading else None,
                scan_starts=self.scan_starts, scan_fresh=self.scan_fresh, lost=self.lost and self.observe,
                **scan_args,
            )  # fmt: skip
        if self.scan and self.scan_gamma is not None:
            self.calibration_ = replace(self.calibration_, scan_gamma=float(self.scan_gamma))
        if self.tune or self.scan:
            self.tracker_ = Tracker(
                split.centres, self.graph_, self.calibration_, n_particles=self.n_particles, scan_map=self.scan_map_
            )
        self.scan_gamma_ = self.calibration_.scan_gamma if self.scan_map_ is not None else 0.0
        self.outlier_ = self.calibration_.outlier
        self.heading_model_: HeadingModel | None = heading_of(self.calibration_)
        self.temper_metres_ = self.calibration_.temper_metres
        self.temper_radians_ = self.calibration_.temper_radians
        self.filter_ = self.tracker_.pose_filter(self.seed)
        self.increments_ = wheel_odometry(poses[split.n_mapping :], factor, random_state=self.seed + 1)
        return self

    def _held_out_headings(self, scans: Sequence[Scan], labels: IArray) -> FArray | None:
        """Implied headings of the held-out rows of ``beta`` (rows as ``held_out_.scores``), or None without headings.

        Each fold's model is the calibration's (the same factory, fit on the
        same scans and labels: shared within a benchmark run).
        """
        held = self.held_out_
        if held is None:
            return None
        _, split = self._need_context()
        factory = self._factory()
        base = getattr(self, "base_", None)
        if base is None or not hasattr(base, "_observations"):  # a baseline: no model, no headings
            return None

        def fit_model(tr: IArray, y: IArray) -> Any:
            m = factory()
            m.fit([scans[i] for i in tr.tolist()], y)
            return getattr(m, "model_", None)

        observations = base._observations(list(scans))
        return held_out_headings(fit_model, observations, labels, held, split.n_places)

    def score(self, scans: Sequence[Scan]) -> FArray:
        """As :class:`FilteredMethod`; with a heading model, the queries' implied headings are computed first."""
        self.step_headings_: FArray | None = None
        if getattr(self, "heading_model_", None) is not None:
            _, split = self._need_context()
            h = implied_headings(self.base_, scans, split.n_places)
            if h is not None:
                self.step_headings_ = np.full((split.n_scans - split.n_mapping, split.n_places), np.nan)
                self.step_headings_[split.query_idx - split.n_mapping] = h
        return super().score(scans)

    def step_points(self) -> list[FArray | None] | None:
        """The laser end points (robot frame) of each query-pass step: at the observed steps (the queries), None
        elsewhere; None without scan evidence."""
        if getattr(self, "scan_points_", None) is None or getattr(self, "scan_map_", None) is None:
            return None
        _, split = self._need_context()
        assert self.scan_points_ is not None
        out: list[FArray | None] = [None] * (split.n_scans - split.n_mapping)
        for i in split.query_idx.tolist():
            out[i - split.n_mapping] = self.scan_points_[i]
        return out

    def run_steps(self, log_likelihood: Any, increments: Any, headings: Any = None, points: Any = None) -> FilterResult:
        """Run the pose filter along steps (NaN rows = prediction only); ``increments`` has one row per step (row 0 unused).

        ``headings`` (same shape as ``log_likelihood``): the implied headings
        of the steps (used with a heading model). ``points`` (one (m, 2)
        array or None per step): the steps' laser end points (used with the
        scan evidence, :meth:`step_points`).
        """
        ll = np.asarray(log_likelihood, dtype=np.float64)
        if not self.observe:  # the sensor switched off: uniform rows where it observed
            ll = np.where(np.all(np.isnan(ll), axis=1, keepdims=True), np.nan, np.zeros_like(ll))
        return run_pose_steps(
            ll,
            increments,
            self.filter_,
            self.transition_,
            temper=(self.temper_metres_, self.temper_radians_) if self.temper else None,
            relocalize=self.relocalize,
            start_at_first_observation=self.start_at_first_observation,
            gap_metres=self.gap_metres,
            reset_threshold=self.reset_threshold,
            challenger=self._challenger(),
            headings=headings if self.observe else None,
            heading_temper=self._heading_temper(),
            augmented=self.augmented,
            hold_margin=self.hold_margin,
            tie_break=self.tie_break,
            points=points if getattr(self, "scan_map_", None) is not None else None,
        )

    def _heading_temper(self) -> tuple[float, float] | None:
        """The heading evidence's own tempering (metres, radians) of the fitted calibration, or None."""
        cal = getattr(self, "calibration_", None)
        if not self.temper or cal is None or cal.heading_temper_metres <= 0:
            return None
        return (float(cal.heading_temper_metres), float(self.temper_radians_))

    def _challenger(self) -> Challenger | None:
        """The challenger settings of the fitted calibration (before :meth:`fit`: of the constructor's options)."""
        cal = getattr(self, "calibration_", None)
        if cal is None:
            cal = Calibration(challenger=self.challenger, challenger_switch_nats=self.challenger_switch_nats)
        return challenger_of(cal)

    def _run_query_pass(self, log_likelihood: FArray, distances: FArray) -> FilterResult:
        """The pose filter over the whole query pass, with the method's odometry increments."""
        return self.run_steps(
            log_likelihood, np.vstack([np.zeros((1, 3)), self.increments_]), getattr(self, "step_headings_", None),
            self.step_points(),
        )  # fmt: skip


def implied_headings(method: Any, scans: Sequence[Scan], n_places: int) -> FArray | None:
    """The robot's heading each scan implies at each place ``0 .. n_places - 1`` (radians, mapping frame), shape (n, P).

    ``method`` is a fitted fingerprint method (its ``model_``, a
    :class:`~fingerloc.model.PlaceModel` whose training observations carry
    the scans' poses): :func:`fingerloc.pipeline.tracker.implied_headings`.
    None for a method without a model (the baselines).
    """
    from ..pipeline.places import place_label
    from ..pipeline.tracker import implied_headings as _implied

    model = getattr(method, "model_", None)
    if model is None or not hasattr(model, "headings_with_reference"):
        return None
    obs = method._observations(scans) if scans else []
    return _implied(model, obs, [place_label(j) for j in range(n_places)])


def field_of_view(scans: Sequence[Scan]) -> float:
    """Median field of view of the scans, radians (pi when there are none)."""
    fov = [sum(w for _, w in s.fov) for s in scans]
    return float(np.median(fov)) if fov else math.pi


def _full_poses(scans: Sequence[Scan]) -> FArray:
    if any(s.pose is None for s in scans):
        raise InvalidParameterError("every scan needs a pose for the place graph and odometry")
    return np.array([s.pose for s in scans if s.pose is not None], dtype=np.float64).reshape(-1, 3)


@register_method("fingerprint-odometry")
def _fingerprint_odometry() -> Method:
    # With the scan evidence, its power chosen on the mapping pass (0 when the mapping pass does not favour it).
    return PoseFilteredMethod("fingerprint", scan=True)


@register_method("fingerprint-odometry-noscan", default=False)
def _fingerprint_odometry_noscan() -> Method:
    # The default before the scan evidence (issue 15): the fingerprint's place scores and implied headings only.
    return PoseFilteredMethod("fingerprint")


@register_method("scan-odometry", default=False)
def _scan_odometry() -> Method:
    # The same filter with the scan evidence and uniform rows at the queries: what the scan adds without the fingerprint.
    return PoseFilteredMethod("fingerprint", observe=False, scan=True)


@register_method("fingerprint-odometry-exact", default=False)
def _fingerprint_odometry_exact() -> Method:
    # Ablation: the corrected poses' increments as an error-free odometry.
    return PoseFilteredMethod("fingerprint", odometry="exact", scan=True)


@register_method("fingerprint-odometry-untempered", default=False)
def _fingerprint_odometry_untempered() -> Method:
    # Ablation: every observation counts as independent evidence.
    return PoseFilteredMethod("fingerprint", temper=False)


@register_method("odometry-only")
def _odometry_only() -> Method:
    # What the odometry and the place layout give without the sensor (uniform rows at the queries).
    return PoseFilteredMethod("fingerprint", observe=False)


@register_method("histogram-odometry")
def _histogram_odometry() -> Method:
    # The histogram baseline's likelihood under the same pose filter.
    return PoseFilteredMethod("baseline-histogram")


@register_method("histogram-scan-odometry", default=False)
def _histogram_scan_odometry() -> Method:
    # The histogram baseline under the same filter as fingerprint-odometry, scan evidence included.
    return PoseFilteredMethod("baseline-histogram", scan=True)


@register_method("baseline-histogram-odometry", default=False)
def _baseline_histogram_odometry() -> Method:
    # The former name of histogram-odometry, kept for scripts.
    return PoseFilteredMethod("baseline-histogram")


@register_method("fingerprint-odometry-reliability", default=False)
def _fingerprint_odometry_reliability() -> Method:
    # rho fitted to the front end's held-out reliability on the mapping pass (off-place weight kept at 0.1).
    return PoseFilteredMethod("fingerprint", outlier="fit")


@register_method("fingerprint-odometry-eager", default=False)
def _fingerprint_odometry_eager() -> Method:
    # Ablation: the start prior carried by dead reckoning to the first observation (the former default).
    return PoseFilteredMethod("fingerprint", start_at_first_observation=False)


@register_method("fingerprint-odometry-challenger", default=False)
def _fingerprint_odometry_challenger() -> Method:
    # A challenger filter started from the sensor, adopted when its trajectory fits the views better (3 nats).
    return PoseFilteredMethod("fingerprint", challenger=True)


@register_method("fingerprint-odometry-noheading", default=False)
def _fingerprint_odometry_noheading() -> Method:
    # The pose filter without the heading each view implies (the default before the third session of issue 15).
    return PoseFilteredMethod("fingerprint", heading=False)


@register_method("fingerprint-odometry-heading-untempered", default=False)
def _fingerprint_odometry_heading_untempered() -> Method:
    # Ablation: the heading evidence tempered as the observations (not over its own 8 m).
    return PoseFilteredMethod("fingerprint", heading_temper_metres=0.0)


@register_method("fingerprint-odometry-reset", default=False)
def _fingerprint_odometry_reset() -> Method:
    # Sensor resetting when the place filter has out-explained the particles by 8 nats (CUSUM).
    return PoseFilteredMethod("fingerprint", reset_threshold=8.0)


# ---------------------------------------------------------------------------------------------------
# Kidnapped robot
# ---------------------------------------------------------------------------------------------------


@dataclass(slots=True)
class TrackingData:
    """A fitted filtered method on one log, with the query pass's per-step inputs.

    Attributes
    ----------
    method : FilteredMethod
    log_likelihood : ndarray, shape (n_steps, P)
        Scaled base scores at the queries, NaN elsewhere (query pass, file order).
    distances : ndarray, shape (n_steps,)
    truth : ndarray of int, shape (n_steps,)
        True place of each query-pass step (``-1`` outside every place's radius).
    positions : ndarray, shape (n_steps, 2)
    increments : ndarray, shape (n_steps, 3), optional
        Odometry from the previous step to each step (row 0 zero); needed by
        a :class:`PoseFilteredMethod`.
    headings : ndarray, shape (n_steps, P), optional
        The heading each step's view implies at each place (NaN elsewhere),
        for a :class:`PoseFilteredMethod` with a heading model.
    cells : ndarray of int, shape (n_steps,), optional
        The place whose centre is nearest to each step's (corrected) position
        (its Voronoi cell): the ground-truth place at *every* step, also
        between places, as the pose filter answers there.
    points : list of (m, 2) arrays or None, length n_steps, optional
        Each step's laser end points (robot frame) at the observed steps, for
        a :class:`PoseFilteredMethod` with the scan evidence (:meth:`PoseFilteredMethod.step_points`).
    """

    method: FilteredMethod
    log_likelihood: FArray
    distances: FArray
    truth: IArray
    positions: FArray
    increments: FArray | None = None
    headings: FArray | None = None
    cells: IArray | None = None
    points: list[FArray | None] | None = None

    def run(self, idx: Any = None) -> FilterResult:
        """The method's filter over the steps ``idx`` (default all), in that order.

        Row 0 of the chosen steps starts the filter (its distance / increment
        is not used); a later step's motion is its own recorded one, so a
        spliced sequence carries the second stretch's own odometry across the
        splice (an unobserved kidnapping).
        """
        sel = np.arange(self.truth.size) if idx is None else np.asarray(idx, dtype=np.int64)
        ll = self.log_likelihood[sel]
        if isinstance(self.method, PoseFilteredMethod):
            if self.increments is None:
                raise InvalidParameterError("a pose filter needs the steps' odometry increments")
            hd = None if self.headings is None else self.headings[sel]
            pts = None if self.points is None else [self.points[i] for i in sel.tolist()]
            return self.method.run_steps(ll, self.increments[sel], hd, pts)
        dist = self.distances[sel].copy()
        if dist.size:
            dist[0] = 0.0
        return run_filter(ll, self.method.transition_, distances=dist)


def prepare_tracking(
    scans: Sequence[Scan], base: str = "fingerprint", *, pose: bool = False, **options: Any
) -> TrackingData:
    """Split a log (benchmark protocol), fit ``FilteredMethod(base)`` (``pose``: :class:`PoseFilteredMethod`) and score its queries."""
    pos = _positions(scans)
    split = make_split(pos)
    if split.n_queries == 0:
        raise InvalidParameterError("the log's query pass has no scan within a place's radius")
    m = PoseFilteredMethod(base, **options) if pose else FilteredMethod(base, **options)
    m.set_context(scans, split)
    m.fit([scans[i] for i in split.train_idx.tolist()], split.train_labels.copy())
    qs = np.asarray(m.base_.score([scans[i] for i in split.query_idx.tolist()]), dtype=np.float64)
    ll, dist = m.step_log_likelihoods(qs)
    truth = np.full(split.n_scans - split.n_mapping, -1, dtype=np.int64)
    truth[split.query_idx - split.n_mapping] = split.query_labels
    inc = getattr(m, "increments_", None)
    steps_inc = None if inc is None else np.vstack([np.zeros((1, 3)), inc])
    hd = None
    if getattr(m, "heading_model_", None) is not None:
        h = implied_headings(m.base_, [scans[i] for i in split.query_idx.tolist()], split.n_places)
        if h is not None:
            hd = np.full(ll.shape, np.nan)
            hd[split.query_idx - split.n_mapping] = h
    pts = m.step_points() if isinstance(m, PoseFilteredMethod) else None
    return TrackingData(
        m, ll, dist, truth, pos[split.n_mapping :], steps_inc, hd, nearest_cells(pos[split.n_mapping :], split.centres), pts
    )


def nearest_cells(positions: Any, centres: Any) -> IArray:
    """Index of the nearest centre of each position (its Voronoi cell), shape (n,)."""
    from scipy.spatial import cKDTree

    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    if pos.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    return np.asarray(cKDTree(c).query(pos)[1], dtype=np.int64)


def with_synthetic_likelihood(
    data: TrackingData, separation: float, *, random_state: int | np.random.Generator | None = 0
) -> TrackingData:
    """The same trajectory, graph and steps with a synthetic front end (to isolate the filter's behaviour).

    At every query step each place's log-likelihood is a standard normal draw
    and the true place's draw is raised by ``separation`` (in standard
    deviations); prediction-only steps stay NaN. Clearly not a measurement of
    any real method.
    """
    if not (math.isfinite(separation) and separation >= 0):
        raise InvalidParameterError(f"separation must be a finite number >= 0, got {separation!r}")
    rng = check_random_state(random_state)
    q = data.truth >= 0
    ll = np.full_like(data.log_likelihood, np.nan)
    ll[q] = rng.normal(size=(int(q.sum()), ll.shape[1]))
    ll[np.flatnonzero(q), data.truth[q]] += separation
    return TrackingData(data.method, ll, data.distances, data.truth, data.positions, data.increments, None, data.cells)  # no headings: not this front end


@dataclass(slots=True)
class KidnapResult:
    """Kidnapped-robot trials on one log.

    Attributes
    ----------
    trials : list of dict
        Per trial: ``a_start``, ``b_start`` (query-pass step indices),
        ``jump_m`` (metres between the two stretches), ``recover_steps`` (steps
        after the jump until the kidnapped filter's best place agrees with the
        best place of the filter that was never kidnapped, and keeps agreeing
        to the end of the stretch; ``None`` if it never does),
        ``recover_observed_steps`` (the same, comparing only at the observed
        (query) steps, where an answer is scored: a particle filter's best
        place between places is a near-tie that two runs break differently),
        ``merge_steps``
        (the same for the two posteriors' total-variation distance falling
        below :data:`MERGED_TV` for good),
        ``first_right_steps`` (steps after the jump until the best place is
        the true place at a query step; ``None`` if never) and the same for
        the never-kidnapped filter (``reference_first_right_steps``).

        What is recovery and what is noise (added fields, issue 15):

        * ``floor_recover_steps`` / ``floor_recover_observed_steps``: the
          criteria of ``recover_steps`` / ``recover_observed_steps`` applied
          to a *second never-kidnapped run* of the same filter over the
          whole query pass (for a particle filter: other random draws)
          against the reference, on the same B stretch. Nothing was
          kidnapped there, so anything above 0 steps is the filter's own
          run-to-run noise: the floor of the column. A deterministic filter
          (the discrete one over places) gives 0. ``floor_disagreement``: the
          fraction of B's steps where the two never-kidnapped runs name
          different places.
        * ``recover_truth_steps``: steps after the jump until the kidnapped
          filter's best place is the *true* place (the place whose radius
          holds the corrected pose) at every later observed step of B, at
          least one of them (unlike ``recover_observed_steps``, which
          counts a stretch as recovered after its last observation even
          when that was wrong);
          ``reference_recover_truth_steps``: the same for the
          never-kidnapped reference (its floor: a filter that is wrong at
          some late query never "recovers" on this column).
        * ``recover_cell_steps`` / ``reference_recover_cell_steps`` (when the
          data carry ``cells``): the same against the nearest place centre
          of the corrected pose at *every* step of B (its Voronoi cell).
        * ``observed`` / ``right`` / ``reference_right``: B's observed steps
          and how many of them the kidnapped filter and the reference name
          the true place (top-1 after a kidnapping, pooled by the summary).
    """

    name: str
    trials: list[dict[str, Any]]

    def summary(self, within: int = 10) -> dict[str, Any]:
        """Median / max of ``recover_steps`` and the fraction of trials recovered within ``within`` steps.

        Beside each recovery column, the same figures of its floor or
        ground-truth counterpart (the trial fields above): ``floor_*`` (a
        second never-kidnapped run against the reference), ``truth_*`` and
        ``reference_truth_*`` (the true place at observed steps), ``cell_*``
        and ``reference_cell_*`` (the true Voronoi cell at every step), and
        ``kidnapped_top1`` / ``reference_top1`` over B's observed steps. A
        field is ``None`` when no trial carries it.
        """
        out = self._summary(within)
        out.update(self._honest(within))
        return out

    def _honest(self, within: int) -> dict[str, Any]:
        """The floor and ground-truth figures (added fields; None where no trial has them)."""
        tr = self.trials
        out: dict[str, Any] = {}
        for key, field in (
            ("floor", "floor_recover_steps"),
            ("floor_observed", "floor_recover_observed_steps"),
            ("truth", "recover_truth_steps"),
            ("reference_truth", "reference_recover_truth_steps"),
            ("cell", "recover_cell_steps"),
            ("reference_cell", "reference_recover_cell_steps"),
        ):
            have = [t for t in tr if field in t]
            vals = [t[field] for t in have]
            out[f"{key}_within_{within}"] = (
                float(np.mean([v is not None and v <= within for v in vals])) if have else None
            )
            out[f"{key}_median_steps"] = _median(vals) if have else None
        dis = [t["floor_disagreement"] for t in tr if t.get("floor_disagreement") is not None]
        out["floor_disagreement"] = float(np.mean(dis)) if dis else None
        n_obs = sum(int(t.get("observed", 0)) for t in tr)
        out["kidnapped_top1"] = sum(int(t.get("right", 0)) for t in tr) / n_obs if n_obs else None
        out["reference_top1"] = sum(int(t.get("reference_right", 0)) for t in tr) / n_obs if n_obs else None
        return out

    def _summary(self, within: int) -> dict[str, Any]:
        rec = [t["recover_steps"] for t in self.trials]
        rec_seen = [t.get("recover_observed_steps") for t in self.trials]
        merged = [t["merge_steps"] for t in self.trials if t["merge_steps"] is not None]
        done = [r for r in rec if r is not None]
        first = [t["first_right_steps"] for t in self.trials if t["first_right_steps"] is not None]
        ref = [t["reference_first_right_steps"] for t in self.trials if t["reference_first_right_steps"] is not None]
        return {
            "trials": len(rec),
            "recovered": len(done),
            "median_recover_steps": float(np.median(done)) if done else None,
            "max_recover_steps": int(max(done)) if done else None,
            f"within_{within}": float(np.mean([r is not None and r <= within for r in rec])) if rec else None,
            "median_recover_observations": _median([t["recover_observations"] for t in self.trials]),
            "median_recover_observed_steps": _median(rec_seen),
            f"observed_within_{within}": float(np.mean([r is not None and r <= within for r in rec_seen]))
            if rec_seen
            else None,
            "merged": len(merged),
            "median_merge_steps": float(np.median(merged)) if merged else None,
            "median_merge_observations": _median([t["merge_observations"] for t in self.trials]),
            "median_first_right_steps": float(np.median(first)) if first else None,
            "median_reference_first_right_steps": float(np.median(ref)) if ref else None,
        }


def _median(values: Sequence[int | None]) -> float | None:
    done = [v for v in values if v is not None]
    return float(np.median(done)) if done else None


def kidnap_experiment(
    data: TrackingData,
    *,
    name: str = "",
    n_trials: int = 20,
    stretch: int = 40,
    min_jump_m: float = 10.0,
    min_queries: int = 5,
    random_state: int | np.random.Generator | None = 0,
) -> KidnapResult:
    """Splice two distant stretches of the query pass and measure recovery.

    A trial runs the filter on stretch A (``stretch`` steps from ``a``),
    then, without telling it, on stretch B (``stretch`` steps from ``b``),
    where the robot's position at ``b`` is at least ``min_jump_m`` from its
    position at the end of A, step ``b`` is observed (a query: the robot is
    carried off between two observations) and B holds at least
    ``min_queries`` query steps. Between queries the filter only predicts, so
    recovery is counted both in steps and in observations
    (``*_observations``: query steps of B up to and including the recovery
    step).
    The never-kidnapped reference is the filter run on the query pass from
    its start through B. The odometry distance of the jump step is B's own
    (the kidnapping is unobserved).

    Parameters
    ----------
    data : TrackingData
        From :func:`prepare_tracking`.
    n_trials : int, default 20
    stretch : int, default 40
        Steps in each stretch.
    min_jump_m : float, default 10.0
    min_queries : int, default 5
    random_state : int or Generator, optional

    Returns
    -------
    KidnapResult
    """
    if n_trials < 1 or stretch < 2:
        raise InvalidParameterError(f"n_trials >= 1 and stretch >= 2 are needed, got {n_trials}, {stretch}")
    rng = check_random_state(random_state)
    n = data.truth.size
    full = data.run()
    has_q = data.truth >= 0
    b_ok = [
        b
        for b in range(1, n - stretch + 1)
        if has_q[b] and int(has_q[b : b + stretch].sum()) >= min(min_queries, stretch)
    ]  # B starts at an observed step after step 0 (so the reference has a history)
    pairs = [
        (a, b)
        for a in range(0, n - stretch + 1)
        for b in b_ok
        if abs(b - (a + stretch)) > stretch
        and math.hypot(*(data.positions[b] - data.positions[a + stretch - 1])) >= min_jump_m
    ]
    trials: list[dict[str, Any]] = []
    if not pairs:
        return KidnapResult(name, trials)
    chosen = rng.choice(len(pairs), size=min(n_trials, len(pairs)), replace=False)
    for k in sorted(chosen.tolist()):
        a, b = pairs[k]
        idx = np.r_[a : a + stretch, b : b + stretch]
        res = data.run(idx)
        kid = res.best[stretch:]
        ref = full.best[b : b + stretch]
        truth = data.truth[b : b + stretch]
        agree = kid == ref
        recover = next((j for j in range(stretch) if np.all(agree[j:])), None)
        seen = has_q[b : b + stretch]
        recover_seen = next((j for j in range(stretch) if np.all(agree[j:][seen[j:]])), None)
        tv = 0.5 * np.abs(np.exp(res.log_posterior[stretch:]) - np.exp(full.log_posterior[b : b + stretch])).sum(axis=1)
        merged = next((j for j in range(stretch) if np.all(tv[j:] < MERGED_TV)), None)

        def first_right(best: IArray, truth: IArray = truth) -> int | None:
            hit = np.flatnonzero((truth >= 0) & (best == truth))
            return int(hit[0]) if hit.size else None

        cells = None if data.cells is None else data.cells[b : b + stretch]
        honest: dict[str, Any] = {
            "recover_truth_steps": _settles(kid == truth, seen, confirmed=True),
            "reference_recover_truth_steps": _settles(ref == truth, seen, confirmed=True),
            "observed": int(seen.sum()),
            "right": int(np.sum(seen & (kid == truth))),
            "reference_right": int(np.sum(seen & (ref == truth))),
        }
        if cells is not None:
            honest["recover_cell_steps"] = _settles(kid == cells)
            honest["reference_recover_cell_steps"] = _settles(ref == cells)
        trials.append(
            {
                "a_start": int(a),
                "b_start": int(b),
                "jump_m": float(math.hypot(*(data.positions[b] - data.positions[a + stretch - 1]))),
                "recover_steps": recover,
                "recover_observed_steps": recover_seen,
                "merge_steps": merged,
                "recover_observations": None if recover is None else int(has_q[b : b + recover + 1].sum()),
                "merge_observations": None if merged is None else int(has_q[b : b + merged + 1].sum()),
                "first_right_steps": first_right(kid),
                "reference_first_right_steps": first_right(ref),
                **honest,
            }
        )
    # The floor: a second never-kidnapped run (run after the trials, so that their draws are as before)
    # against the reference, with the same criteria, on each trial's B stretch.
    second = data.run()
    for t in trials:
        b = t["b_start"]
        agree = second.best[b : b + stretch] == full.best[b : b + stretch]
        t["floor_recover_steps"] = _settles(agree)
        t["floor_recover_observed_steps"] = _settles(agree, has_q[b : b + stretch])
        t["floor_disagreement"] = float(np.mean(~agree))
    return KidnapResult(name, trials)


def _settles(agree: Any, mask: Any = None, *, confirmed: bool = False) -> int | None:
    """First ``j`` such that ``agree`` holds at every step ``>= j`` (only the steps of ``mask``); None if none.

    The recovery criterion of :func:`kidnap_experiment`: ``j`` ranges over
    the stretch's steps, so a stretch whose last (masked) step disagrees
    never settles. Without ``confirmed`` a ``j`` after the last masked step
    counts (nothing is left to disagree: a stretch whose observations all
    come early "settles" after them, right or wrong); with it, ``j`` must
    be at or before the last masked step (at least one observation shows
    the answer right).
    """
    ok = np.asarray(agree, dtype=bool)
    m = np.ones(ok.size, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    last = int(np.flatnonzero(m)[-1]) + 1 if confirmed and m.any() else (0 if confirmed else ok.size)
    return next((j for j in range(min(ok.size, last)) if np.all(ok[j:][m[j:]])), None)


def run_kidnap(
    paths: Sequence[str | Path],
    *,
    base: str = "fingerprint",
    n_trials: int = 20,
    stretch: int = 40,
    min_jump_m: float = 10.0,
    seed: int = 0,
    synthetic: float | None = None,
    pose: bool = False,
    odometry_error: float = 1.0,
    kidnap: float | None = None,
    hold_margin: float | None = None,
    tie_break: float | None = None,
    scan: bool = True,
    on_progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """:func:`kidnap_experiment` on each log (JSON-ready: per log summary and trials, pooled summary).

    ``synthetic``: replace the base method's scores by a synthetic front end
    with this separation (:func:`with_synthetic_likelihood`). ``pose``: the
    pose particle filter (:class:`PoseFilteredMethod`, seeded with ``seed``,
    simulated odometry errors times ``odometry_error``, kidnapping
    probability ``kidnap`` per observation if given; ``hold_margin`` and
    ``tie_break``, the answers between observations, if given, else the
    method's defaults: :func:`~fingerloc.map.relocalize.answer_between`)
    instead of the discrete filter over places; with ``scan`` (the default,
    as ``fingerprint-odometry``) the pose filter also weighs the laser end
    points, the power chosen on the mapping pass (:class:`PoseFilteredMethod`).
    """
    from .protocol import load_log_scans, log_name

    out: dict[str, Any] = {"logs": {}, "params": {"base": base, "n_trials": n_trials, "stretch": stretch,
                                                  "min_jump_m": min_jump_m, "seed": seed, "synthetic": synthetic,
                                                  "filter": "pose" if pose else "places",
                                                  "odometry_error": odometry_error if pose else None,
                                                  "kidnap": kidnap if pose else None,
                                                  "hold_margin": hold_margin if pose else None,
                                                  "tie_break": tie_break if pose else None,
                                                  "scan": scan if pose else None}}  # fmt: skip
    all_trials: list[dict[str, Any]] = []
    ranks_single: list[IArray] = []
    ranks_filtered: list[IArray] = []
    for path in paths:
        name = log_name(path)
        if on_progress is not None:
            on_progress(f"{name}: fitting")
        t0 = time.perf_counter()
        scans, _ = load_log_scans(path)
        opts: dict[str, Any] = (
            {"seed": seed, "odometry_error": odometry_error, "kidnap": kidnap, "scan": scan} if pose else {}
        )
        if pose:
            opts.update({k: v for k, v in (("hold_margin", hold_margin), ("tie_break", tie_break)) if v is not None})
        data = prepare_tracking(scans, base, pose=pose, **opts)
        if synthetic is not None:
            data = with_synthetic_likelihood(data, synthetic, random_state=seed)
        res = kidnap_experiment(data, name=name, n_trials=n_trials, stretch=stretch, min_jump_m=min_jump_m,
                                random_state=seed)  # fmt: skip
        all_trials += res.trials
        single, filtered = tracking_ranks(data)
        ranks_single.append(single)
        ranks_filtered.append(filtered)
        out["logs"][name] = {
            "summary": res.summary(),
            "tracking": {"single_shot": rank_metrics(single), "filtered": rank_metrics(filtered)},
            "trials": res.trials,
            "seconds": time.perf_counter() - t0,
        }
    out["pooled"] = KidnapResult("pooled", all_trials).summary()
    out["pooled_tracking"] = {
        "single_shot": rank_metrics(np.concatenate(ranks_single)),
        "filtered": rank_metrics(np.concatenate(ranks_filtered)),
    }
    return out


def tracking_ranks(data: TrackingData) -> tuple[IArray, IArray]:
    """True-place ranks at the query steps: single-shot (the rows alone) and filtered along the query pass."""
    q = data.truth >= 0
    res = data.run()
    single = true_place_ranks(
        np.where(np.isnan(data.log_likelihood[q]), -np.inf, data.log_likelihood[q]), data.truth[q]
    )
    return single, true_place_ranks(res.log_posterior[q], data.truth[q])


def _register_odometry_error_variants() -> None:
    """``fingerprint-odometry-x2`` / ``-x4`` and ``odometry-only-exact`` / ``-x2`` / ``-x4``: the simulated errors times 0, 2, 4."""
    def make(observe: bool, factor: float) -> Callable[[], Method]:
        # the fingerprint's with the default's scan evidence; odometry-only stays odometry alone
        return lambda: PoseFilteredMethod("fingerprint", observe=observe, odometry_error=factor, scan=observe)

    for factor in (2.0, 4.0):
        register_method(f"fingerprint-odometry-x{factor:g}", default=False)(make(True, factor))
        register_method(f"odometry-only-x{factor:g}", default=False)(make(False, factor))
    register_method("odometry-only-exact", default=False)(
        lambda: PoseFilteredMethod("fingerprint", observe=False, odometry="exact")
    )
    # Ablations: rho = 0.1 and 2 m tempering fixed (the former defaults), not chosen on the mapping pass.
    register_method("fingerprint-odometry-untuned", default=False)(lambda: PoseFilteredMethod("fingerprint", tune=False))
    register_method("histogram-odometry-untuned", default=False)(
        lambda: PoseFilteredMethod("baseline-histogram", tune=False)
    )


_register_odometry_error_variants()
