"""The real-log benchmark's filtered methods: a single-shot method followed by either filter.

* :class:`FilteredMethod` wraps any single-shot method of the benchmark
  (:mod:`fingerloc.experiments.carmen`) with the discrete Bayes filter over
  the place graph (:mod:`fingerloc.map.filter`): ``fingerprint-filtered``
  and, run only when named, ``baseline-histogram-filtered``,
  ``baseline-scancontext-filtered`` and the ablations
  ``fingerprint-filtered-no-odometry`` (per-step counts) and
  ``fingerprint-filtered-unscaled`` (``beta = 1``).
* :class:`PoseFilteredMethod`: the same front end followed by the pose
  particle filter (odometry increments, the heading each view implies, the
  scan evidence): ``fingerprint-odometry`` and its ablations.

Both are calibrated on the log's **mapping pass** only, by the library's one
calibration (:func:`fingerloc.pipeline.calibrate.calibrate_map`, as
``fingerloc map``): the place graph and metres per place change, the
likelihood scale ``beta`` from held-out visits, the heading model, the pose
filter's reliability and tempering and the scan evidence's power, each
variant a :class:`~fingerloc.config.Config`. Nothing is tuned on the query
pass. The filter steps through **every** query-pass scan in file order; scans
outside every place's radius are prediction-only steps.

The shared logs hold only corrected poses, so the pose filter's odometry is
the poses' increments corrupted by simulated wheel-odometry errors
(:func:`~fingerloc.map.motion.wheel_odometry`, seeded), or exact.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .._lse import logsumexp
from .._types import FArray, IArray
from ..config import Config
from ..errors import InvalidParameterError
from ..map.driver import PoseTracking, run_pose_filter
from ..map.filter import FilterResult, TransitionModel, run_filter
from ..map.motion import wheel_odometry
from ..map.scan_map import ScanMap, end_points
from ..pipeline.calibrate import MapCalibration, MappingPart, calibrate_map
from ..pipeline.calibration import FitScore, implied_headings, step_distances
from ..pipeline.filters import place_transition_of, pose_filter_of, pose_tracking, transition_of
from ..pipeline.places import place_label
from ..sensors import Scan
from .protocol import METHODS, Method, Split, load_methods, register_method

__all__ = ["BENCH_FILTERED", "BENCH_POSE", "FilteredMethod", "PoseFilteredMethod", "field_of_view", "full_poses"]

#: The place filter's calibration: the likelihood scale and the graph (nothing of the pose filter).
BENCH_FILTERED = Config().with_(calibration={"heading": False, "tune": False, "scan": False})
#: The pose filter's, without the scan evidence (``fingerprint-odometry`` adds it: the map's default).
BENCH_POSE = Config().with_(calibration={"scan": False})


def full_poses(scans: Sequence[Scan]) -> FArray:
    """Every scan's pose, shape (n, 3) (metres, radians)."""
    if any(s.pose is None for s in scans):
        raise InvalidParameterError("every scan needs a pose for the place graph and odometry")
    return np.array([s.pose for s in scans if s.pose is not None], dtype=np.float64).reshape(-1, 3)


def field_of_view(scans: Sequence[Scan]) -> float:
    """Median field of view of the scans, radians (pi when there are none)."""
    fov = [sum(w for _, w in s.fov) for s in scans]
    return float(np.median(fov)) if fov else float(np.pi)


def _method_fit_score(factory: Callable[[], Method], scans: Sequence[Scan]) -> FitScore:
    """The library's :data:`~fingerloc.pipeline.calibration.FitScore` of a benchmark method over scans."""

    def fit_score(tr: IArray, y: IArray, te: IArray) -> FArray:
        m = factory()
        m.fit([scans[i] for i in tr.tolist()], y)
        return np.asarray(m.score([scans[i] for i in te.tolist()]), dtype=np.float64)

    return fit_score


class FilteredMethod:
    """A single-shot method of the benchmark followed by the Markov filter over places.

    The benchmark runner calls :meth:`fit_log` with the whole log and its
    split (the filter needs the trajectory: the mapping pass for the graph,
    the query pass for the steps between queries), then :meth:`score`.

    Parameters
    ----------
    base : str
        Registered name of the single-shot method.
    config : Config, optional
        The calibration's settings (default :data:`BENCH_FILTERED`; with
        ``config.calibration.enabled`` False: ``beta = 1``).
    odometry : bool, default True
        Use the travelled distance of each step; False uses the graph's
        per-step stay / move counts (no positions).
    kernel : {"metric", "graph"}, default "metric"
        The transitions: the metric kernel over the places' positions
        (:func:`~fingerloc.pipeline.filters.place_transition_of`), or the
        place graph's chain ``K = expm(d / L (M - I))``.
    step_aside : bool, default True
        Answer the single shot at the observed steps when the filter was below
        it on the mapping pass's held-out views (:func:`~fingerloc.pipeline.calibrate.with_place_check`).

    Attributes
    ----------
    base_ : Method
    calibrated_ : MapCalibration
    graph_ : PlaceGraph
    transition_ : TransitionModel
    scale_ : float
        ``beta``.
    result_ : FilterResult
        The filter's output over the whole query pass after :meth:`score`.
    """

    name = "filtered"

    def __init__(
        self, base: str, config: Config | None = None, *, odometry: bool = True, kernel: str = "metric",
        step_aside: bool = True,
    ) -> None:  # fmt: skip
        if kernel not in ("metric", "graph"):
            raise InvalidParameterError(f"kernel must be 'metric' or 'graph', got {kernel!r}")
        self.base = base
        self.config = BENCH_FILTERED if config is None else config
        self.odometry = odometry
        self.kernel = kernel
        self.step_aside = step_aside

    def _factory(self) -> Callable[[], Method]:
        from functools import partial

        from .shared import shared_method

        load_methods()
        if self.base not in METHODS:
            raise InvalidParameterError(f"unknown base method {self.base!r} (known: {', '.join(METHODS)})")
        # the base's fits and scores are shared with the run's other methods (inside shared_results only)
        return partial(shared_method, self.base, METHODS[self.base])

    def _calibrate(self, scans: Sequence[Scan], split: Split, *, observe: bool = True, odometry_error: float = 0.0,
                   seed: int = 0) -> MapCalibration:  # fmt: skip
        """Fit the base method and run the library's calibration on the mapping pass."""
        factory = self._factory()
        train = [scans[i] for i in split.train_idx.tolist()]
        y = split.train_labels.copy()
        self.base_ = factory()
        self.base_.fit(train, y)
        poses = full_poses(scans)
        cc = self.config.calibration
        fit_headings = None
        base = self.base_
        if cc.heading and hasattr(base, "_observations"):  # a fingerprint method: a model with headings
            observations = base._observations(train)

            def fit_headings(tr: IArray, yy: IArray, te: IArray, own: Any = None) -> FArray:
                m = factory()
                m.fit([train[i] for i in tr.tolist()], yy)
                model = getattr(m, "model_", None)
                labels = [str(k) for k in range(int(yy.max()) + 1)]
                return implied_headings(model, [observations[i] for i in te.tolist()], labels, own=own)

        points = None
        if cc.scan:
            self.scan_points_: list[FArray] | None = [end_points(s) for s in scans]
            points = self.scan_points_[: split.n_mapping]
        else:
            self.scan_points_ = None
        mapping = MappingPart(
            split.train_idx, y, split.centres, poses[: split.n_mapping], field_of_view(scans[: split.n_mapping]),
            [place_label(j) for j in range(split.n_places)], points,
        )  # fmt: skip
        mc = calibrate_map(_method_fit_score(factory, train), mapping, self.config, fit_headings=fit_headings,
                           odometry_error=odometry_error, seed=seed, observe=observe)  # fmt: skip
        self.calibrated_ = mc
        self.graph_ = mc.graph
        self.scale_ = mc.calibration.beta
        self.calibration_rows_ = mc.calibration.calibration_rows
        self.held_out_ = mc.held
        return mc

    def fit_log(self, scans: Sequence[Scan], split: Split) -> FilteredMethod:
        """Fit the base method on the split's training scans and calibrate on the mapping pass."""
        mc = self._calibrate(scans, split)
        self._split = split
        self._positions = full_poses(scans)[:, :2]
        if self.kernel == "metric" and self.odometry:  # the calibration measured this filter on the mapping pass
            self.transition_ = place_transition_of(mc.graph, mc.calibration, self.config, split.centres)
        else:
            self.transition_ = TransitionModel.from_graph(
                mc.graph, alpha=self.config.pose_filter.alpha,
                metres_per_move=mc.calibration.metres_per_move if self.odometry else None,
            )  # fmt: skip
        self.steps_aside_ = self.step_aside and mc.calibration.place_filter_steps_aside()
        return self

    def _need_split(self) -> Split:
        split = getattr(self, "_split", None)
        if split is None:
            raise InvalidParameterError(f"{self.name} is fitted on a whole log: call fit_log(scans, split) first")
        return split

    def fit(self, scans: Sequence[Scan], labels: Any) -> FilteredMethod:
        """Not available: a filtered method needs the whole log (:meth:`fit_log`)."""
        raise InvalidParameterError(f"{self.name} needs the log's trajectory: call fit_log(scans, split) (run_log does)")

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
        split = self._need_split()
        s = np.asarray(query_scores, dtype=np.float64)
        ll = np.full((split.n_scans - split.n_mapping, split.n_places), np.nan)
        ll[split.query_idx - split.n_mapping] = self.scale_ * np.where(np.isnan(s), -np.inf, s)
        return ll, step_distances(self._positions[split.n_mapping :])

    def score(self, scans: Sequence[Scan]) -> FArray:
        """The filtered log-posterior at each query, shape (n_queries, P); the filter runs over the whole query pass."""
        split = self._need_split()
        if len(scans) != split.n_queries:
            raise InvalidParameterError(f"{self.name} scores the split's {split.n_queries} queries, got {len(scans)} scans")
        self.query_scores_ = np.asarray(self.base_.score(scans), dtype=np.float64)
        self._before_score(scans)
        ll, dist = self.step_log_likelihoods(self.query_scores_)
        self.result_: FilterResult = self._run_query_pass(ll, dist)
        return self.result_.log_posterior[split.query_idx - split.n_mapping]

    def _before_score(self, scans: Sequence[Scan]) -> None:
        """What a subclass computes from the queries before the filter runs."""

    def _run_query_pass(self, log_likelihood: FArray, distances: FArray) -> FilterResult:
        """The filter over the whole query pass (rows of :meth:`step_log_likelihoods`); at the observed steps the
        single shot instead when the filter steps aside."""
        res = run_filter(log_likelihood, self.transition_, distances=distances)
        if not getattr(self, "steps_aside_", False):
            return res
        out = res.log_posterior.copy()
        seen = ~np.all(np.isnan(log_likelihood), axis=1)
        rows = np.where(np.isnan(log_likelihood[seen]), -np.inf, log_likelihood[seen])
        out[seen] = rows - logsumexp(rows, axis=1, keepdims=True)
        return FilterResult.from_log_posterior(out)


class PoseFilteredMethod(FilteredMethod):
    """A single-shot method followed by the pose particle filter (module docstring).

    Parameters
    ----------
    base : str
    config : Config, optional
        Default :data:`BENCH_POSE` (the map's defaults without the scan evidence).
    odometry : {"simulated", "exact"}, default "simulated"
        The poses' increments corrupted by simulated wheel-odometry errors
        (seeded), or left exact.
    odometry_error : float, default 1.0
        Factor on every error of the simulated odometry (0 = exact).
    seed : int, default 0
        Seeds the particles (``seed``), the simulated odometry (``seed + 1``)
        and the tuning runs (``seed + 2``).
    observe : bool, default True
        False: the sensor's rows are replaced by uniform ones at the observed
        steps (``odometry-only``): what the odometry, the place layout and the
        scan evidence give without the single-shot method.
    """

    name = "pose-filtered"

    def __init__(
        self,
        base: str,
        config: Config | None = None,
        *,
        odometry: str = "simulated",
        odometry_error: float = 1.0,
        seed: int = 0,
        observe: bool = True,
    ) -> None:
        super().__init__(base, BENCH_POSE if config is None else config)
        if odometry not in ("simulated", "exact"):
            raise InvalidParameterError(f"odometry must be 'simulated' or 'exact', got {odometry!r}")
        if not (np.isfinite(odometry_error) and odometry_error >= 0):
            raise InvalidParameterError(f"odometry_error must be a finite factor >= 0, got {odometry_error!r}")
        self.odometry_source = odometry
        self.odometry_error = float(odometry_error)
        self.seed = int(seed)
        self.observe = bool(observe)

    def fit_log(self, scans: Sequence[Scan], split: Split) -> PoseFilteredMethod:
        """Fit the base method, calibrate on the mapping pass, set up the pose filter and the query pass's odometry."""
        factor = self.odometry_error if self.odometry_source == "simulated" else 0.0
        mc = self._calibrate(scans, split, observe=self.observe, odometry_error=factor, seed=self.seed)
        self._split = split
        poses = full_poses(scans)
        self._positions = poses[:, :2]
        cal = mc.calibration
        self.calibration_ = cal
        self.scan_map_: ScanMap | None = mc.scan_map
        self.transition_ = transition_of(mc.graph, cal, self.config)
        f = pose_filter_of(split.centres, cal, self.config, seed=self.seed, scan_map=self.scan_map_)
        self.tracking_: PoseTracking = pose_tracking(f, self.transition_, cal, self.config)
        self.filter_ = f
        self.tuning_ = mc.tuning
        self.heading_model_ = cal.heading
        self.increments_ = wheel_odometry(poses[split.n_mapping :], factor, random_state=self.seed + 1)
        return self

    def _before_score(self, scans: Sequence[Scan]) -> None:
        """With a heading model, the queries' implied headings."""
        self.step_headings_: FArray | None = None
        if self.heading_model_ is None:
            return
        split = self._need_split()
        model = getattr(self.base_, "model_", None)
        if model is None or not hasattr(model, "headings_with_reference"):
            return
        obs = self.base_._observations(scans) if scans else []  # type: ignore[attr-defined]
        h = implied_headings(model, obs, [place_label(j) for j in range(split.n_places)])
        self.step_headings_ = np.full((split.n_scans - split.n_mapping, split.n_places), np.nan)
        self.step_headings_[split.query_idx - split.n_mapping] = h

    def step_points(self) -> list[FArray | None] | None:
        """The laser end points (robot frame) of each query-pass step: at the observed steps (the queries), None
        elsewhere; None without scan evidence."""
        if self.scan_points_ is None or self.scan_map_ is None:
            return None
        split = self._need_split()
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
        return run_pose_filter(
            ll, increments, self.tracking_, headings=headings if self.observe else None,
            points=points if self.scan_map_ is not None else None,
        )  # fmt: skip

    def _run_query_pass(self, log_likelihood: FArray, distances: FArray) -> FilterResult:
        """The pose filter over the whole query pass, with the method's odometry increments."""
        return self.run_steps(
            log_likelihood, np.vstack([np.zeros((1, 3)), self.increments_]), getattr(self, "step_headings_", None),
            self.step_points(),
        )  # fmt: skip


def _pose(base: str = "fingerprint", scan: bool = False, **changes: Any) -> Callable[[], Method]:
    """A registered pose-filtered method: :data:`BENCH_POSE` (``scan``: the scan evidence on) with ``changes``
    (``places``, ``calibration``, ``pose_filter`` mappings are config parts; the rest, method options)."""
    parts = {k: changes.pop(k) for k in ("places", "calibration", "pose_filter") if k in changes}
    config = BENCH_POSE.with_(calibration={"scan": scan}).with_(**parts)
    return lambda: PoseFilteredMethod(base, config, **changes)


def _register() -> None:
    """The filtered methods of the benchmark (``default=False``: run only when named)."""
    register_method("fingerprint-filtered")(lambda: FilteredMethod("fingerprint"))
    register_method("fingerprint-filtered-no-odometry", default=False)(lambda: FilteredMethod("fingerprint", odometry=False))
    # The former default: the place graph's chain, always filtering.
    register_method("fingerprint-filtered-graph", default=False)(
        lambda: FilteredMethod("fingerprint", kernel="graph", step_aside=False)
    )
    register_method("fingerprint-filtered-nocheck", default=False)(lambda: FilteredMethod("fingerprint", step_aside=False))
    register_method("fingerprint-filtered-unscaled", default=False)(
        lambda: FilteredMethod("fingerprint", BENCH_FILTERED.with_(calibration={"enabled": False}))
    )
    register_method("baseline-histogram-filtered", default=False)(lambda: FilteredMethod("baseline-histogram"))
    register_method("baseline-scancontext-filtered", default=False)(lambda: FilteredMethod("baseline-scancontext"))
    # The map's defaults: the fingerprint's place scores, implied headings and the scan evidence.
    register_method("fingerprint-odometry")(_pose(scan=True))
    register_method("fingerprint-odometry-noscan", default=False)(_pose())
    # What the scan evidence gives without the fingerprint (uniform rows at the queries).
    register_method("scan-odometry", default=False)(_pose(scan=True, observe=False))
    register_method("fingerprint-odometry-exact", default=False)(_pose(scan=True, odometry="exact"))
    register_method("fingerprint-odometry-untempered", default=False)(_pose(pose_filter={"temper": False}))
    # What the odometry and the place layout give without the sensor.
    register_method("odometry-only")(_pose(observe=False))
    register_method("histogram-odometry")(_pose("baseline-histogram"))
    register_method("histogram-scan-odometry", default=False)(_pose("baseline-histogram", scan=True))
    register_method("baseline-histogram-odometry", default=False)(_pose("baseline-histogram"))
    register_method("fingerprint-odometry-reliability", default=False)(_pose(calibration={"outlier_fit": True}))
    register_method("fingerprint-odometry-eager", default=False)(_pose(pose_filter={"start_at_first_observation": False}))
    register_method("fingerprint-odometry-challenger", default=False)(_pose(pose_filter={"strategy": "challenger"}))
    register_method("fingerprint-odometry-noheading", default=False)(_pose(calibration={"heading": False}))
    register_method("fingerprint-odometry-heading-untempered", default=False)(_pose(calibration={"heading_temper_m": 0.0}))
    register_method("fingerprint-odometry-reset", default=False)(_pose(pose_filter={"strategy": "reset"}))
    # The former lost re-draw: its prior entirely the place filter's belief.
    register_method("fingerprint-odometry-lostplace", default=False)(_pose(scan=True, pose_filter={"lost_uniform_share": 0.0}))
    for factor in (2.0, 4.0):  # the simulated odometry errors times 2 and 4
        register_method(f"fingerprint-odometry-x{factor:g}", default=False)(_pose(scan=True, odometry_error=factor))
        register_method(f"odometry-only-x{factor:g}", default=False)(_pose(observe=False, odometry_error=factor))
    register_method("odometry-only-exact", default=False)(_pose(observe=False, odometry="exact"))
    # rho = 0.1 and the place spacing's tempering, not chosen on the mapping pass
    register_method("fingerprint-odometry-untuned", default=False)(_pose(calibration={"tune": False}))
    register_method("histogram-odometry-untuned", default=False)(_pose("baseline-histogram", calibration={"tune": False}))


_register()

