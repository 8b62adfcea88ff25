"""The filters' calibration on a mapping run, and the calibrated tracker (issue 12).

Everything a filter needs is taken from the **mapping part** of a run only
(nothing is tuned on the queries):

* the place graph: the nearest place centre (its Voronoi cell) of every
  mapping scan, in order; consecutive scans count a stay or a passage
  (:meth:`fingerloc.map.graph.PlaceGraph.from_sequence`);
* ``metres_per_move``: metres travelled per change of place along the mapping part;
* the likelihood scale ``beta`` (:func:`fingerloc.map.filter.fit_likelihood_scale`):
  the model is fit on half of the training scans and scores the other half,
  two ways round (halves = alternate *visits* of each place,
  :func:`~fingerloc.pipeline.places.visit_folds`; fewer than
  :data:`MIN_CALIBRATION_ROWS` usable rows -> alternate scans); ``beta``
  maximises the held-out log-probability of the right place;
* the pose filter's kidnapping probability per observation ``1 / (n_train + 2)``
  (Laplace's rule over the mapping part's observations) and its tempering:
  an observation counts fully after the robot travelled the place spacing or
  turned by the sensor's median field of view, in proportion before.

:class:`Tracker` runs either filter along a run with these parameters: the
discrete filter over the place graph (``"places"``) or the pose particle
filter (``"pose"``), which follows the odometry's increments. The real-log
benchmark's filtered methods call the same functions.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from .._types import FArray, IArray
from ..errors import InvalidParameterError
from ..map.filter import (
    FilterResult,
    MarkovFilter,
    SharedPlaceSteps,
    TransitionModel,
    fit_likelihood_scale,
    fit_outlier_weight,
    run_filter,
)
from ..map.filter import metres_per_move as _metres_per_move
from ..map.graph import PlaceGraph, nearest_place_sequence
from .places import visit_folds

if TYPE_CHECKING:
    from ..map.pose_filter import Challenger, HeadingModel, PoseFilter
    from ..map.relocalize import Augmented
    from ..map.scan_map import ScanMap
    from ..observation import Observation

__all__ = [
    "FILTERS",
    "HEADING_TEMPER_M",
    "HOLD_MARGIN",
    "MIN_CALIBRATION_ROWS",
    "POSE_PARTICLES",
    "SCAN_GAMMAS",
    "SCAN_GUARD_M",
    "TIE_BREAK",
    "TUNE_WITH_HEADING",
    "Calibration",
    "FitScore",
    "HeldOut",
    "Tracker",
    "calibrate_labelled",
    "challenger_of",
    "fit_scale",
    "fold_scan_maps",
    "heading_of",
    "held_out_calibration",
    "held_out_headings",
    "held_out_rows",
    "held_out_scores",
    "implied_headings",
    "mapping_graph",
    "model_fit_score",
    "posterior_columns",
    "run_pose_steps",
    "scan_folds",
    "scan_tuning_inputs",
    "step_distances",
    "tune_grid",
    "tune_pose_filter",
    "with_heading_model",
]


#: Held-out rows needed to fit the likelihood scale from visits; fewer -> alternate scans.
MIN_CALIBRATION_ROWS = 10
#: Particles of the pose filter (:class:`Tracker` and the benchmark's pose-filtered methods).
POSE_PARTICLES = 3000
#: Metres after which the pose filter's heading evidence counts fully (issue 15: on the shared logs'
#: mapping passes a held-out view's heading error stays correlated with the previous views' up to 8 m).
HEADING_TEMPER_M = 8.0
#: Whether the tuning of the pose filter's reliability and tempering on the mapping part
#: (:func:`tune_pose_filter`) runs with the heading evidence. Off: on the shared logs the tuned filter
#: is as good either way (pooled top-1 0.805 against 0.807, mean of five seeds) and learns in half
#: the time (docs/RESULTS.md, issue 15 and 17); the heading model is fitted and used all the same.
TUNE_WITH_HEADING = False
#: The pose filter's answer between observations: held unless another place leads by this (issue 15).
HOLD_MARGIN = 0.05
#: ... and near-ties within this broken by the discrete place filter (issue 15).
TIE_BREAK = 0.02
#: The powers of the scan evidence :func:`tune_pose_filter` tries after rho and the tempering (0, the
#: filter without it, is always tried first and wins ties).
SCAN_GAMMAS: tuple[float, ...] = (1.0, 3.0, 10.0)

#: With the scan evidence, a (re)initialisation of the pose filter from the sensor draws this many times
#: its particles (then resamples to ``n_particles``): the scan likelihood is sharp, and the first draw must
#: hold a particle near the true pose (docs/RESULTS.md, "A filter that does not stay locked", issue 15).
SCAN_FRESH = 10

#: Lost detection: the belief is taken for lost when its scan fit falls below this quantile of the fits
#: the filter had on the mapping pass's held-out rows when it was right (:func:`calibrate_lost`).
LOST_QUANTILE = 0.05
#: A fold's scan map holds no scan within this of one of the fold's rows, metres (the place radius):
#: never a near-duplicate view of a held-out row (:func:`fold_scan_maps`).
SCAN_GUARD_M = 1.0
#: The filters a tracker runs.
FILTERS: tuple[str, ...] = ("places", "pose")

#: ``fit_score(train_rows, train_labels, test_rows) -> scores (n_test, k)``: fit a place
#: recogniser on rows with labels ``0 .. k - 1`` (every one used) and score the test rows.
FitScore = Callable[[IArray, IArray, IArray], FArray]


@dataclass(frozen=True, slots=True)
class Calibration:
    """The filters' parameters, calibrated on a run's mapping part (module docstring).

    Attributes
    ----------
    beta : float
        Likelihood scale: the filters use ``beta * log P(place | observation)``.
    metres_per_move : float
        Mean metres travelled per change of place (discrete filter's odometry).
    temper_metres, temper_radians : float
        An observation counts fully after this much travel or turn (pose filter).
    kidnap : float
        Kidnapping probability per observation (pose filter).
    radius : float
        Metres: a pose within it of a centre is at that place.
    spacing : float
        Metres between places (the map's scale).
    alpha : float
        Additive smoothing of the graph's transition counts.
    n_train : int
        Training observations of the mapping part.
    calibration_rows : int
        Held-out rows ``beta`` was fit on (0: ``beta = 1``).
    outlier : float
        Pose filter: ``rho``, how often the single shot's answer is noise
        (chosen on the mapping part by :func:`tune_pose_filter`).
    off_place : float
        Pose filter: likelihood weight of a pose at no place, at an observation.
    start_at_first_observation : bool
        Pose filter: draw the particles from the first observation (prior
        times its likelihood) instead of carrying the start prior blindly.
    gap_metres : float or None
        Pose filter: an odometry step longer than this (a gap in the run)
        re-draws the particles at the next observation.
    challenger : bool
        Pose filter: run a challenger filter started from the sensor and
        switch to it when its trajectory fits the views better
        (:func:`~fingerloc.map.pose_filter.run_challenged_pose_filter`).
    challenger_switch_nats : float
        The challenger's log Bayes factor that makes the switch.
    heading_kappa, heading_intercept, heading_slope, heading_reverse, heading_cap : float
        Pose filter: the :class:`~fingerloc.map.pose_filter.HeadingModel`
        of the headings the observations imply (fitted on the mapping part);
        ``heading_kappa == 0`` (the default): headings are not used.
    heading_temper_metres : float
        Pose filter: the heading evidence counts fully after this much
        travel (or the field of view's turn); 0: as the observations.
    scan_gamma : float
        Pose filter: the power of the laser end points' likelihood field
        (``scan_gamma`` of :class:`~fingerloc.map.pose_filter.PoseFilter`,
        with the map's :class:`~fingerloc.map.scan_map.ScanMap`); 0 (the
        default, and a map without one): not used.
    scan_fresh : int
        Pose filter, with the scan evidence: a (re)initialisation from the
        sensor draws this many times its particles (``fresh_factor`` of
        :class:`~fingerloc.map.pose_filter.PoseFilter`); 1: as many.
    lost_fit, lost_kidnap, lost_after, lost_statistic, lost_uniform
        Pose filter, with the scan evidence: when the tracked particles' scan
        fit falls below ``lost_fit`` (``lost_after`` observations in a row),
        the observation re-draws particles from the sensor with probability
        ``lost_kidnap`` (the same names of
        :class:`~fingerloc.map.pose_filter.PoseFilter`; ``lost_fit`` and
        ``lost_kidnap`` from :func:`calibrate_lost`); ``lost_fit`` None: off.
    hold_margin : float or None
        Pose filter, between observations: the previous best place stays
        the answer unless another place's probability exceeds it by this
        much (:func:`~fingerloc.map.relocalize.held_best`; None: the argmax).
    tie_break : float or None
        Pose filter, between observations: among the places within this
        probability of the answer, the one the discrete place filter believes
        most (:func:`~fingerloc.map.relocalize.tie_broken_best`; None: off).
        Neither changes the posterior nor the answers at observed steps.
    """

    beta: float = 1.0
    metres_per_move: float = 1.0
    temper_metres: float = 2.0
    temper_radians: float = math.pi
    kidnap: float = 0.005
    radius: float = 1.0
    spacing: float = 2.0
    alpha: float = 1.0
    n_train: int = 0
    calibration_rows: int = 0
    outlier: float = 0.1
    off_place: float = 0.1
    start_at_first_observation: bool = True
    gap_metres: float | None = None
    challenger: bool = False
    challenger_switch_nats: float = 3.0
    heading_kappa: float = 0.0
    heading_intercept: float = 0.0
    heading_slope: float = 0.0
    heading_reverse: float = 0.0
    heading_cap: float = 0.0
    heading_temper_metres: float = 0.0
    scan_gamma: float = 0.0
    scan_fresh: int = 1
    lost_fit: float | None = None
    lost_kidnap: float = 0.0
    lost_after: int = 1
    lost_statistic: str = "best"
    lost_uniform: bool = False
    hold_margin: float | None = HOLD_MARGIN
    tie_break: float | None = TIE_BREAK

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict of every field."""
        return asdict(self)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Calibration:
        """Inverse of :meth:`to_json` (unknown keys are ignored)."""
        names = set(cls.__dataclass_fields__)
        try:
            return cls(**{k: v for k, v in data.items() if k in names})
        except TypeError as err:
            raise InvalidParameterError(f"invalid stored calibration ({err})") from err


def step_distances(positions: Any) -> FArray:
    """Metres travelled from each step to the next, shape (n,) (entry 0 is 0)."""
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    d = np.zeros(pos.shape[0])
    if pos.shape[0] > 1:
        d[1:] = np.hypot(*np.diff(pos, axis=0).T)
    return d


def mapping_graph(positions: Any, centres: Any, labels: Sequence[str] | None = None) -> tuple[PlaceGraph, float]:
    """The place graph and ``metres_per_move`` of a mapping part.

    Parameters
    ----------
    positions : array_like, shape (n, 2)
        The mapping part's positions in order, metres.
    centres : array_like, shape (P, 2)
        Place centres, metres.
    labels : sequence of str, optional
        Place names (default ``"0" .. "P-1"``).

    Returns
    -------
    graph : PlaceGraph
    metres_per_move : float
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    places = [str(j) for j in range(c.shape[0])] if labels is None else [str(x) for x in labels]
    near = nearest_place_sequence(pos, c)
    g = PlaceGraph.from_sequence(places, [places[j] for j in near.tolist()])
    return g, _metres_per_move(pos, near) if pos.shape[0] > 1 else 1.0


def held_out_scores(fit_score: FitScore, labels: Any, fold: Any, n_places: int) -> tuple[FArray, IArray]:
    """Scores of each fold's rows by a recogniser fit on the other fold, shape (n_rows, n_places).

    Places absent from a training fold score ``-inf``. Rows come fold 0
    first, then fold 1 (:func:`held_out_rows` gives their positions).
    """
    y = np.asarray(labels, dtype=np.int64).reshape(-1)
    f_ = np.asarray(fold, dtype=np.int64).reshape(-1)
    rows: list[FArray] = []
    ys: list[IArray] = []
    for f in (0, 1):
        tr = np.flatnonzero(f_ != f)
        te = np.flatnonzero(f_ == f)
        if tr.size == 0 or te.size == 0:
            continue
        present = np.unique(y[tr])
        remap = np.full(n_places, -1, dtype=np.int64)
        remap[present] = np.arange(present.size)
        s = np.asarray(fit_score(tr, remap[y[tr]], te), dtype=np.float64)
        full = np.full((te.size, n_places), -np.inf)
        full[:, present] = s
        rows.append(full)
        ys.append(y[te])
    if not rows:
        return np.zeros((0, n_places)), np.zeros(0, np.int64)
    return np.concatenate(rows), np.concatenate(ys)


def held_out_rows(fold: Any) -> IArray:
    """Positions of :func:`held_out_scores`' rows among the training rows (fold 0's, then fold 1's)."""
    f_ = np.asarray(fold, dtype=np.int64).reshape(-1)
    parts = [np.flatnonzero(f_ == f) for f in (0, 1)]
    if any(p.size == 0 for p in parts):  # a fold without training rows scores nothing
        return np.zeros(0, np.int64)
    return np.concatenate(parts)


@dataclass(frozen=True, slots=True)
class HeldOut:
    """The held-out calibration of a mapping part (:func:`held_out_calibration`).

    Attributes
    ----------
    beta : float
    rows : int
        Usable held-out rows (0: ``beta = 1``).
    scores : ndarray, shape (n, P)
        Each training row's ``log P(place | obs)`` from a model fit on the other fold.
    labels : ndarray of int, shape (n,)
    index : ndarray of int, shape (n,)
        Position of each row among the training rows.
    fold : ndarray of int, shape (n_train,), optional
        The fold (0 / 1) of every training row the scores were computed with.
    """

    beta: float
    rows: int
    scores: FArray
    labels: IArray
    index: IArray
    fold: IArray | None = None


def held_out_calibration(
    fit_score: FitScore, train_idx: Any, labels: Any, n_places: int, *, by_visits: bool = True
) -> HeldOut:
    """``beta`` from held-out scores of the training rows, with the scores themselves (module docstring)."""
    y = np.asarray(labels, dtype=np.int64).reshape(-1)
    fold = visit_folds(train_idx, y) if by_visits else np.arange(y.size) % 2
    s, yy = held_out_scores(fit_score, y, fold, n_places)
    usable = int(np.sum(np.isfinite(s[np.arange(yy.size), yy]))) if yy.size else 0
    if usable < MIN_CALIBRATION_ROWS:
        fold = np.arange(y.size) % 2
        s, yy = held_out_scores(fit_score, y, fold, n_places)
        usable = int(np.sum(np.isfinite(s[np.arange(yy.size), yy]))) if yy.size else 0
    beta = fit_likelihood_scale(s, yy) if usable else 1.0
    return HeldOut(float(beta), usable, s, yy, held_out_rows(fold) if yy.size else np.zeros(0, np.int64), fold)


def fit_scale(
    fit_score: FitScore, train_idx: Any, labels: Any, n_places: int, *, by_visits: bool = True
) -> tuple[float, int]:
    """``beta`` from held-out scores of the training rows, and the number of usable rows (module docstring).

    Parameters
    ----------
    fit_score : FitScore
        Row indices are positions in ``labels`` (0 .. n_train - 1).
    train_idx : array_like of int, shape (n_train,)
        The training rows' indices in the run (for the visits).
    labels : array_like of int, shape (n_train,)
    n_places : int
    by_visits : bool, default True
        Folds by alternate visits; False: alternate rows.
    """
    h = held_out_calibration(fit_score, train_idx, labels, n_places, by_visits=by_visits)
    return h.beta, h.rows


def model_fit_score(options: Mapping[str, Any], observations: Sequence[Observation]) -> FitScore:
    """A :data:`FitScore` over ``observations`` with a :class:`~fingerloc.model.PlaceModel` of these options.

    Places are labelled ``"0" .. "k-1"``; the scores are the model's
    log-posterior, column ``j`` = place ``j``.
    """
    from .presets import model_from_options

    def fit_score(tr: IArray, y: IArray, te: IArray) -> FArray:
        model = model_from_options(options).fit([observations[i] for i in tr.tolist()], [str(v) for v in y.tolist()])
        return posterior_columns(model, [observations[i] for i in te.tolist()], int(y.max()) + 1)

    return fit_score


def posterior_columns(model: Any, observations: Sequence[Observation], n_places: int, labels: Sequence[str] | None = None) -> FArray:
    """``log P(place | observation)`` with columns in a given place order, shape (n, n_places).

    ``labels[j]`` is the label of column ``j`` (default ``str(j)``); places
    the model does not hold score ``-inf``.
    """
    out = np.full((len(observations), n_places), -np.inf)
    if not observations:
        return out
    names = [str(j) for j in range(n_places)] if labels is None else [str(x) for x in labels]
    col = {lab: j for j, lab in enumerate(names)}
    lp = np.asarray(model.predict_log_proba(list(observations)), dtype=np.float64)
    for k, c in enumerate(model.classes_):
        j = col.get(str(c))
        if j is not None:
            out[:, j] = lp[:, k]
    return out


def implied_headings(model: Any, observations: Sequence[Observation], labels: Sequence[str]) -> FArray:
    """The robot's heading each observation implies at each place, radians in the views' frame, shape (n, P).

    For place ``labels[j]``, :meth:`~fingerloc.model.PlaceModel.headings_with_reference`
    gives the heading ``h`` (degrees) of the observation against the place's
    best-matching training view (the fingerprint's cyclic alignment, or the
    profile's); that view's recorded pose ``(x, y, theta)`` (the mapping
    run's) makes it absolute. The model's convention is *bearing in the
    view = bearing in the observation - h* (``localize --json`` reports
    ``-h`` as ``heading_deg``: the README's *b + heading_deg*), so the
    robot's heading is ``theta - h`` (on the shared logs' mapping passes: median error 3-6 deg
    at the true place on aces and intel with this sign, 25-37 deg with the
    other; docs/RESULTS.md). NaN where a place is unknown to the model, has no estimate, or
    its view has no pose.
    """
    obs = list(observations)
    out = np.full((len(obs), len(labels)), np.nan)
    if not obs:
        return out
    places = getattr(model, "places_", {})
    by_name = {str(k): k for k in places}
    prepare = getattr(model, "prepare_headings", None)
    if prepare is not None and len(obs) > 1 and len(labels) > 1:
        prepare(obs)  # one batch of alignments for every place below (the same headings)
    for j, lab in enumerate(labels):
        key = by_name.get(str(lab))
        if key is None:
            continue
        views = places[key].observations
        theta = np.array([np.nan if o.pose is None else float(o.pose[2]) for o in views])
        h, v = model.headings_with_reference(obs, [key] * len(obs))
        ok = (v >= 0) & (v < theta.size) & np.isfinite(h)
        if np.any(ok):
            out[ok, j] = np.mod(theta[v[ok]] - np.radians(h[ok]) + math.pi, 2 * math.pi) - math.pi
    return out


def held_out_headings(
    fit_model: Callable[[IArray, IArray], Any],
    observations: Sequence[Observation],
    labels: Any,
    held: HeldOut,
    n_places: int,
) -> FArray | None:
    """Implied headings (:func:`implied_headings`) of the held-out rows of ``held``, rows as ``held.scores``; None without folds.

    ``fit_model(train_rows, train_labels)`` fits the same recogniser as the
    calibration's ``fit_score`` on those training rows (labels ``0 .. k -
    1``, as :func:`held_out_scores` remaps them) and returns a model with
    :meth:`~fingerloc.model.PlaceModel.headings_with_reference` whose
    training observations carry their poses.
    """
    if held.fold is None or held.index.size == 0:
        return None
    y = np.asarray(labels, dtype=np.int64).reshape(-1)
    parts: list[FArray] = []
    for f in (0, 1):
        tr, te = np.flatnonzero(held.fold != f), np.flatnonzero(held.fold == f)
        if tr.size == 0 or te.size == 0:
            continue
        present = np.unique(y[tr])
        remap = np.full(n_places, -1, dtype=np.int64)
        remap[present] = np.arange(present.size)
        model = fit_model(tr, remap[y[tr]])
        full = np.full((te.size, n_places), np.nan)
        full[:, present] = implied_headings(model, [observations[i] for i in te.tolist()], [str(k) for k in range(present.size)])
        parts.append(full)
    return np.concatenate(parts) if parts else None


def with_heading_model(
    calibration: Calibration,
    held: HeldOut,
    headings: Any,
    headings_true: Any,
    *,
    reverse: bool = True,
    slope: bool = True,
    temper_metres: float = HEADING_TEMPER_M,
) -> Calibration:
    """The calibration with the pose filter's heading model fitted on the mapping part's held-out rows.

    ``headings`` (rows as ``held.scores``): :func:`held_out_headings`;
    ``headings_true``: each held-out row's recorded heading (radians). The
    error at the row's own place and the row's log-probability of it
    (``beta``-scaled softmax) fit :func:`~fingerloc.map.pose_filter.fit_heading_model`.
    ``temper_metres``: the heading evidence's own tempering
    (``heading_temper_metres``). Unchanged when there are too few estimates.
    """
    from ..map.pose_filter import fit_heading_model

    h = np.asarray(headings, dtype=np.float64)
    rows = np.arange(held.labels.size)
    if h.shape != held.scores.shape or rows.size == 0:
        return calibration
    s = calibration.beta * np.where(np.isnan(held.scores), -np.inf, held.scores)
    with np.errstate(invalid="ignore"):
        top = np.max(s, axis=1, keepdims=True)
        x = (s - top - np.log(np.sum(np.exp(s - top), axis=1, keepdims=True)))[rows, held.labels]
    true = np.asarray(headings_true, dtype=np.float64).reshape(-1)
    hm = fit_heading_model(true - h[rows, held.labels], x if slope else None, reverse=reverse, slope=slope)
    if hm is None:
        return calibration
    return replace(
        calibration, heading_kappa=hm.kappa, heading_intercept=hm.intercept, heading_slope=hm.slope,
        heading_reverse=hm.reverse, heading_cap=hm.cap, heading_temper_metres=float(temper_metres),
    )  # fmt: skip


def run_pose_steps(
    log_likelihood: Any,
    increments: Any,
    pose_filter: PoseFilter,
    transition: TransitionModel,
    *,
    temper: tuple[float, float] | None,
    relocalize: bool = True,
    start_at_first_observation: bool = False,
    gap_metres: float | None = None,
    reset_threshold: float | None = None,
    challenger: Challenger | None = None,
    place_steps: SharedPlaceSteps | None = None,
    headings: Any = None,
    heading_temper: tuple[float, float] | None = None,
    augmented: Augmented | None = None,
    hold_margin: float | None = None,
    tie_break: float | None = None,
    points: Any = None,
    scan_maps: Sequence[ScanMap | None] | None = None,
) -> FilterResult:
    """The pose filter along steps, with the discrete filter alongside for relocalization.

    Parameters
    ----------
    log_likelihood : array_like, shape (n_steps, P)
        Scaled rows (NaN = prediction only).
    increments : array_like, shape (n_steps, 3)
        Odometry from the previous step (row 0 unused).
    pose_filter : PoseFilter
        Reset first (its random generator carries on).
    transition : TransitionModel
        Of the discrete filter run alongside (``relocalize``).
    temper : (metres, radians) or None
    relocalize : bool, default True
    start_at_first_observation, gap_metres, reset_threshold
        :func:`~fingerloc.map.pose_filter.run_pose_filter`.
    challenger : Challenger, optional
        Run :func:`~fingerloc.map.pose_filter.run_challenged_pose_filter`
        instead (``reset_threshold`` is then not used).
    place_steps : SharedPlaceSteps, optional
        The discrete filter's beliefs shared with other runs on the same
        steps (:func:`tune_pose_filter`); the same results.
    headings : array_like, shape (n_steps, P), optional
        The heading each observation implies at each place (radians, NaN =
        none), used when the pose filter has a heading model.
    heading_temper : (metres, radians), optional
        The heading evidence's own tempering (default: the observations').
    augmented : Augmented, optional
        Run :func:`~fingerloc.map.relocalize.run_augmented_pose_filter`
        (Augmented MCL) instead (``reset_threshold`` and ``headings`` are
        then not used; not with ``challenger``).
    hold_margin, tie_break : float, optional
        The answers between observations
        (:func:`~fingerloc.map.relocalize.answer_between`; ``None``: off).
    points : sequence of (m, 2) arrays or None, length n_steps, optional
        Each step's laser end points (robot frame), used when the pose
        filter has a scan map (the challenger and Augmented MCL runs ignore them).
    scan_maps : sequence of ScanMap or None, length n_steps, optional
        Per step, the map ``points`` are scored against instead of the
        filter's (:func:`~fingerloc.map.pose_filter.run_pose_filter`).
    """
    from ..map.pose_filter import observation_weights

    hw = None
    if headings is not None and heading_temper is not None:
        lls = np.asarray(log_likelihood, dtype=np.float64)
        hw = observation_weights(
            np.asarray(increments, dtype=np.float64).reshape(-1, 3)[1:], ~np.all(np.isnan(lls), axis=1),
            metres=heading_temper[0], radians=heading_temper[1],
        )  # fmt: skip
    res = _run_pose_steps(log_likelihood, increments, pose_filter, transition, temper=temper, relocalize=relocalize,
                          start_at_first_observation=start_at_first_observation, gap_metres=gap_metres,
                          reset_threshold=reset_threshold, challenger=challenger, place_steps=place_steps,
                          augmented=augmented, headings=headings, heading_weights=hw, points=points,
                          scan_maps=scan_maps)  # fmt: skip
    if hold_margin is None and tie_break is None:
        return res
    from ..map.relocalize import answer_between

    return answer_between(res, log_likelihood, increments, transition, hold_margin=hold_margin, tie_break=tie_break)


def _run_pose_steps(
    log_likelihood: Any,
    increments: Any,
    pose_filter: PoseFilter,
    transition: TransitionModel,
    *,
    temper: tuple[float, float] | None,
    relocalize: bool,
    start_at_first_observation: bool,
    gap_metres: float | None,
    reset_threshold: float | None,
    challenger: Challenger | None,
    place_steps: SharedPlaceSteps | None,
    augmented: Augmented | None,
    headings: Any,
    heading_weights: Any,
    points: Any = None,
    scan_maps: Sequence[ScanMap | None] | None = None,
) -> FilterResult:
    """:func:`run_pose_steps` before the answers between observations (Augmented MCL runs without headings)."""
    from ..map.pose_filter import run_challenged_pose_filter, run_pose_filter

    def places() -> MarkovFilter | None:
        if not relocalize:
            return None
        return MarkovFilter(transition) if place_steps is None else place_steps.filter(transition)

    if augmented is not None:
        if challenger is not None:
            raise InvalidParameterError("the challenger and Augmented MCL are not run together")
        from ..map.relocalize import run_augmented_pose_filter

        return run_augmented_pose_filter(
            log_likelihood,
            np.asarray(increments, dtype=np.float64).reshape(-1, 3)[1:],
            pose_filter,
            augmented,
            temper=temper,
            place_filter=places(),
            start_at_first_observation=start_at_first_observation,
            gap_metres=gap_metres,
        )

    if challenger is not None:
        return run_challenged_pose_filter(
            log_likelihood,
            np.asarray(increments, dtype=np.float64).reshape(-1, 3)[1:],
            pose_filter,
            challenger,
            temper=temper,
            place_filter=places(),
            start_at_first_observation=start_at_first_observation,
            gap_metres=gap_metres,
            headings=headings,
        )

    return run_pose_filter(
        log_likelihood,
        np.asarray(increments, dtype=np.float64).reshape(-1, 3)[1:],
        pose_filter,
        temper=temper,
        place_filter=places(),
        start_at_first_observation=start_at_first_observation,
        gap_metres=gap_metres,
        reset_threshold=reset_threshold,
        headings=headings,
        heading_weights=heading_weights,
        points=points,
        scan_maps=scan_maps,
    )


def challenger_of(calibration: Calibration) -> Challenger | None:
    """The calibration's challenger settings (None: no challenger)."""
    from ..map.pose_filter import Challenger

    if not calibration.challenger:
        return None
    return Challenger(switch_nats=calibration.challenger_switch_nats)


def heading_of(calibration: Calibration) -> HeadingModel | None:
    """The calibration's heading model (None: headings not used)."""
    from ..map.pose_filter import HeadingModel

    c = calibration
    if c.heading_kappa <= 0 or c.heading_cap <= 0:
        return None
    return HeadingModel(c.heading_kappa, c.heading_intercept, c.heading_slope, c.heading_reverse, c.heading_cap)


def tune_grid(fitted_outlier: float) -> list[tuple[float, float]]:
    """(rho, tempering metres) pairs tried by :func:`tune_pose_filter`, the former default first."""
    return [(rho, m) for rho in (0.1, 0.3, fitted_outlier) for m in (2.0, 1.0, 4.0)]


def scan_folds(train_idx: Any, labels: Any) -> IArray:
    """Fold (0 / 1) of each training scan for the scan maps: alternate visits *in time order*.

    A visit is a run of consecutive scans (consecutive indices) of one place
    (as :func:`~fingerloc.pipeline.places.visit_folds`), but the visits are
    counted along the run, not per place: on a mapping pass that visits each
    place once (the fingerprint's visit folds then put nearly every scan in
    fold 0) the folds still alternate place by place, so each fold's map
    covers the whole run from the neighbouring places.
    """
    idx = np.asarray(train_idx, dtype=np.int64).reshape(-1)
    lab = np.asarray(labels, dtype=np.int64).reshape(-1)
    if idx.size != lab.size:
        raise InvalidParameterError(f"train_idx and labels must have the same length, got {idx.size} and {lab.size}")
    new = np.ones(idx.size, dtype=bool)
    new[1:] = (lab[1:] != lab[:-1]) | (idx[1:] != idx[:-1] + 1)
    return ((np.cumsum(new) - 1) % 2).astype(np.int64)


def fold_scan_maps(
    points: Sequence[Any], poses: Any, fold: Any, *, guard: float = SCAN_GUARD_M, travel: Any = None, **options: Any
) -> tuple[ScanMap, ScanMap]:
    """The two scan maps of the tuning on the mapping part: ``maps[f]`` from the training scans *not* in fold ``f``.

    A held-out row of fold ``f`` is scored against ``maps[f]``, a map that
    never saw its end points. Consecutive scans of one visit see the same
    walls from nearly the same pose (the same people, the same noise), and
    so do the last scan of a visit and the first of the next: ``maps[f]``
    also leaves out every scan within ``guard`` metres of one of fold ``f``'s
    (default the place radius): along the run when ``travel`` is given (the
    same pass's neighbours go, another pass's scans of the same place stay,
    as at query time), in the plane otherwise. So a row's map holds no
    near-duplicate of it; it is a little poorer than the query-time one
    (which holds the mapping scans of the query's own place), so the tuning
    is, if anything, against the scan evidence. Only the training scans are
    used: a mapping scan outside every place lies between two training scans
    of one pass.
    The folds: :func:`scan_folds` (alternate visits in time order), which
    :func:`tune_pose_filter` takes as ``scan_fold``.

    Parameters
    ----------
    points : sequence of (m, 2) arrays or None, length n_train
        Each training scan's end points, robot frame (:func:`~fingerloc.map.scan_map.scan_points`).
    poses : array_like, shape (n_train, 3)
        The training scans' poses (mapping frame).
    fold : array_like of int, shape (n_train,)
        The fold of each training scan (:func:`scan_folds`).
    guard : float, default SCAN_GUARD_M
        Metres; 0 keeps every scan of the other fold.
    travel : array_like, shape (n_train,), optional
        The distance travelled along the run at each training scan (metres,
        non-decreasing in the run's order; the cumulative sum of :func:`step_distances`):
        the guard is measured along it.
    **options
        :meth:`~fingerloc.map.scan_map.ScanMap.from_scans`'s (resolution, sigma ...).

    Raises
    ------
    InvalidParameterError
        When a fold's complement has no end point (no map to score it against).
    """
    from ..map.scan_map import ScanMap

    pts = list(points)
    ps = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    f_ = np.asarray(fold, dtype=np.int64).reshape(-1)
    if not len(pts) == ps.shape[0] == f_.size:
        raise InvalidParameterError(f"points, poses and fold must have one entry per training scan, got {len(pts)}, {ps.shape[0]}, {f_.size}")
    g = float(guard)
    if not math.isfinite(g) or g < 0:
        raise InvalidParameterError(f"guard must be a finite number >= 0 (metres), got {guard!r}")
    from scipy.spatial import cKDTree

    tv = None if travel is None else np.asarray(travel, dtype=np.float64).reshape(-1)
    if tv is not None and tv.size != f_.size:
        raise InvalidParameterError(f"travel must have one entry per training scan ({f_.size}), got {tv.size}")
    maps: list[ScanMap] = []
    for f in (0, 1):
        near = np.zeros(f_.size, dtype=bool)
        mine = np.flatnonzero(f_ == f)
        if mine.size and g > 0:
            if tv is None:
                d, _ = cKDTree(ps[mine, :2]).query(ps[:, :2], k=1)
            else:
                d, _ = cKDTree(tv[mine, None]).query(tv[:, None], k=1)
            near = np.asarray(d) <= g
        keep = [i for i in range(f_.size) if f_[i] != f and not near[i] and pts[i] is not None and np.size(pts[i])]
        if not keep:
            raise InvalidParameterError(f"no end point outside fold {f}: no map to score its rows against")
        maps.append(ScanMap.from_scans([pts[i] for i in keep], ps[keep], **options))
    return maps[0], maps[1]


def scan_tuning_inputs(points: Sequence[Any], poses: Any, train_idx: Any, labels: Any, held: HeldOut) -> dict[str, Any]:
    """The scan evidence's keyword arguments of :func:`tune_pose_filter` for a mapping part.

    ``points``: the end points (robot frame, :func:`~fingerloc.map.scan_map.scan_points`)
    of every scan of the mapping part at least (indexed like ``poses``);
    ``poses``: those scans' poses, shape (n, 3), in the run's order;
    ``train_idx`` / ``labels``: the training scans and their places; ``held``:
    the held-out calibration rows. Returns ``scan_points`` (the held-out
    rows' end points, rows as ``held.scores``), ``scan_fold``
    (:func:`scan_folds`) and ``scan_maps`` (:func:`fold_scan_maps`, the guard
    measured along the run); empty (the scan evidence stays off) without
    held-out rows or when a fold's complement has no end point.
    """
    if held.index.size == 0:
        return {}
    tr = np.asarray(train_idx, dtype=np.int64).reshape(-1)
    ps = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    fold = scan_folds(tr, labels)
    travel = np.cumsum(step_distances(ps[: int(tr.max()) + 1, :2]))[tr]
    try:
        maps = fold_scan_maps([points[i] for i in tr.tolist()], ps[tr], fold, travel=travel)
    except InvalidParameterError:  # a fold without end points: no map to score its rows against
        return {}
    return {"scan_points": [points[i] for i in tr[held.index].tolist()], "scan_maps": maps, "scan_fold": fold}


def tune_pose_filter(
    tracker: Tracker,
    held: HeldOut,
    train_idx: Any,
    mapping_poses: Any,
    *,
    odometry_error: float = 0.0,
    seed: int = 0,
    temper: bool = True,
    relocalize: bool = True,
    share_draws: bool = True,
    headings: Any = None,
    scan_points: Sequence[FArray | None] | None = None,
    scan_maps: Sequence[ScanMap] | None = None,
    scan_fold: Any = None,
    scan_starts: int = 1,
    scan_fresh: int = SCAN_FRESH,
    lost: bool = True,
) -> tuple[Calibration, list[dict[str, float]]]:
    """Choose the pose filter's ``outlier`` (rho) and tempering distance along the **mapping** part.

    Each training scan's held-out score (the model fit on the other visits,
    :func:`held_out_calibration`) is an observation of a run along the
    mapping part's poses, with simulated odometry of its own seed
    (``seed + 2``); every pair of :func:`tune_grid` (rho 0.1, 0.3 or the
    reliability :func:`~fingerloc.map.filter.fit_outlier_weight` fits,
    tempering 2, 1 or 4 m) runs the filter, and the pair with the best top-1
    at the training scans wins (ties: the earlier pair). Nothing is taken
    from the queries.

    The runs of the grid draw the same random numbers (one seed, the same
    steps) and run the same place filter alongside: with ``share_draws``
    (the default) both are computed once and replayed
    (:class:`~fingerloc.map.pose_filter.SharedDraws`,
    :class:`~fingerloc.map.filter.SharedPlaceSteps`; a run whose calls
    differ computes its own from there), which changes no result.

    ``headings`` (shape (n_held, P), radians, NaN = none): the heading each
    held-out row implies at each place (rows as ``held.scores``); with the
    calibration's heading model, the runs use them.

    ``scan_points`` (one (m, 2) array or None per held-out row, rows as
    ``held.scores``, robot frame) and ``scan_maps`` (:func:`fold_scan_maps`
    of the training scans with the folds ``scan_fold``, one per training
    row, default ``held.fold``; :func:`scan_folds` is what the benchmark and
    ``fingerloc map`` should pass): then the power of the scan evidence is
    chosen too. At the chosen pair, the filter runs again with
    ``scan_gamma`` in :data:`SCAN_GAMMAS`, each held-out row's end points
    scored against its fold's map (one that never saw them); the best top-1
    wins, 0 (the run above) on ties. Without them ``scan_gamma`` is 0 and
    everything else as before, bit for bit. ``scan_starts`` > 1: each power,
    0 included, runs from that many starts along the mapping part (the
    held-out rows at 0, 1/k, 2/k ... of them; each run to the end), and its
    top-1 is pooled over the runs: a wrong global localization at a start
    counts more than once (an ablation, docs/RESULTS.md).

    With the scan evidence, every run (and the returned calibration) draws
    ``scan_fresh`` times the particles at a (re)initialisation from the
    sensor (``Calibration.scan_fresh``, :data:`SCAN_FRESH`); with ``lost``
    and a power > 0 chosen, the lost detection's threshold and re-draw
    probability are calibrated on the chosen power's run
    (:func:`calibrate_lost`: the tracked particles' scan fit at each
    held-out row, and whether the answer there was right; the runs
    themselves are without it). ``scan_fresh=1, lost=False``: as before, bit for bit.

    Returns
    -------
    Calibration
        ``tracker.calibration`` with ``outlier``, ``temper_metres`` and
        ``scan_gamma`` chosen (unchanged when there is no held-out row).
    list of dict
        ``{"outlier", "temper_metres", "top1"}`` of every pair tried, then
        ``{"outlier", "temper_metres", "scan_gamma", "top1"}`` of every
        power of the scan evidence tried.
    """
    from ..map.pose_filter import SharedDraws, wheel_odometry

    cal = tracker.calibration
    poses = np.asarray(mapping_poses, dtype=np.float64).reshape(-1, 3)
    if held.index.size == 0:
        return cal, []
    rows = np.asarray(train_idx, dtype=np.int64)[held.index]
    ll = np.full((poses.shape[0], tracker.centres.shape[0]), np.nan)
    ll[rows] = cal.beta * np.where(np.isnan(held.scores), -np.inf, held.scores)
    truth = held.labels
    hd = None
    if headings is not None and heading_of(cal) is not None:
        hd = np.full(ll.shape, np.nan)
        hd[rows] = np.asarray(headings, dtype=np.float64).reshape(rows.size, -1)
    inc = np.vstack([np.zeros((1, 3)), wheel_odometry(poses, odometry_error, random_state=seed + 2)])
    fitted = fit_outlier_weight(ll[rows], truth)
    tried: list[dict[str, float]] = []
    best = (-1.0, cal)
    shared = SharedDraws(seed + 2) if share_draws else None
    steps = SharedPlaceSteps() if share_draws else None
    for rho, metres in tune_grid(fitted):
        trial = replace(cal, outlier=float(rho), temper_metres=float(metres))
        t = Tracker(tracker.centres, tracker.graph, trial, n_particles=tracker.n_particles)
        f = t.pose_filter(seed + 2, rng=None if shared is None else shared.generator())
        res = t.run_pose(ll, inc, f, temper=temper, relocalize=relocalize, place_steps=steps, headings=hd)
        top1 = float(np.mean(res.best[rows] == truth))
        tried.append({"outlier": float(rho), "temper_metres": float(metres), "top1": top1})
        if top1 > best[0]:
            best = (top1, trial)
    if scan_points is None or scan_maps is None:
        return replace(best[1], scan_gamma=0.0), tried
    sfold = held.fold if scan_fold is None else np.asarray(scan_fold, dtype=np.int64).reshape(-1)
    if sfold is None or len(scan_maps) != 2:
        raise InvalidParameterError("scan evidence in the tuning needs the folds (scan_fold or held.fold) and two fold maps")
    sp = list(scan_points)
    if len(sp) != rows.size:
        raise InvalidParameterError(f"scan_points must have one entry per held-out row ({rows.size}), got {len(sp)}")
    pts: list[FArray | None] = [None] * poses.shape[0]
    maps: list[ScanMap | None] = [None] * poses.shape[0]
    row_fold = np.asarray(sfold, dtype=np.int64)[held.index]
    for k, r in enumerate(rows.tolist()):
        pts[r] = sp[k]
        maps[r] = scan_maps[int(row_fold[k])]
    if isinstance(scan_fresh, bool) or not isinstance(scan_fresh, (int, np.integer)) or scan_fresh < 1:
        raise InvalidParameterError(f"scan_fresh must be an integer >= 1, got {scan_fresh!r}")
    chosen = replace(best[1], scan_fresh=int(scan_fresh), lost_fit=None, lost_kidnap=0.0)
    n_starts = int(scan_starts)
    if n_starts < 1:
        raise InvalidParameterError(f"scan_starts must be an integer >= 1, got {scan_starts!r}")
    starts = [int(rows[(k * rows.size) // n_starts]) for k in range(n_starts)]
    if n_starts > 1:  # the chosen pair without the scan evidence, from every start (start 0: the run above)
        best = (-1.0, chosen)
    traces: dict[float, tuple[list[float], Any]] = {}
    for gamma in ((0.0,) if n_starts > 1 else ()) + SCAN_GAMMAS:
        trial = replace(chosen, scan_gamma=float(gamma))
        t = Tracker(tracker.centres, tracker.graph, trial, n_particles=tracker.n_particles, scan_map=scan_maps[0])
        right = 0
        counted = 0
        for s0 in starts:
            f = t.pose_filter(seed + 2, rng=None if shared is None else shared.generator())
            res = t.run_pose(ll[s0:], inc[s0:], f, temper=temper, relocalize=relocalize, place_steps=steps,
                             headings=None if hd is None else hd[s0:], points=pts[s0:], scan_maps=maps[s0:])  # fmt: skip
            after = rows >= s0
            if s0 == starts[0]:
                traces[float(gamma)] = (list(f.fit_trace_), res.best[rows - s0] == truth)
            right += int(np.sum(res.best[rows[after] - s0] == truth[after]))
            counted += int(np.sum(after))
        top1 = right / counted
        tried.append({"outlier": chosen.outlier, "temper_metres": chosen.temper_metres, "scan_gamma": float(gamma), "top1": top1})
        if top1 > best[0]:
            best = (top1, trial)
    if lost and best[1].scan_gamma > 0 and starts[0] == int(rows[0]):
        trace, ok = traces[float(best[1].scan_gamma)]
        if len(trace) == rows.size:
            thr, kap = calibrate_lost(np.asarray(trace, dtype=np.float64), ok, after=best[1].lost_after)
            if thr is not None:
                best = (best[0], replace(best[1], lost_fit=thr, lost_kidnap=kap))
    return best[1], tried


def calibrate_lost(
    fits: Any, right: Any, quantile: float | None = None, *, after: int = 1
) -> tuple[float | None, float]:
    """The lost detection's threshold and re-draw probability from a run along the mapping part.

    ``fits`` (one per observed row, NaN where there is none, e.g. at a
    global initialisation): the tracked belief's scan fit (the weighted mean
    end-point log-likelihood, :attr:`~fingerloc.map.pose_filter.PoseFilter.fit_trace_`);
    ``right``: whether the filter's answer at the row was right. The
    threshold is the ``quantile`` of the fits at the right rows (below it,
    the belief explains the view worse than the map nearly always does when
    it is right; default :data:`LOST_QUANTILE`); the re-draw probability is how often the answer was wrong
    at rows below the threshold (``after`` rows in a row), ``(wrong + 1) / (n + 2)`` (Laplace's rule).
    ``(None, 0)`` without a right row with a fit.
    """
    f = np.asarray(fits, dtype=np.float64).reshape(-1)
    ok = np.asarray(right, dtype=bool).reshape(-1)
    if f.size != ok.size:
        raise InvalidParameterError(f"fits and right must have the same length, got {f.size} and {ok.size}")
    has = np.isfinite(f)
    if not np.any(has & ok):
        return None, 0.0
    thr = float(np.quantile(f[has & ok], LOST_QUANTILE if quantile is None else quantile))
    low = has & (f < thr)
    run = np.zeros(f.size, dtype=np.int64)  # consecutive rows below the threshold, up to each row
    for i in range(f.size):
        run[i] = (run[i - 1] + 1 if i else 1) if low[i] else 0
    low = run >= max(int(after), 1)
    return thr, float((np.sum(low & ~ok) + 1) / (np.sum(low) + 2))


def calibrate_labelled(options: Mapping[str, Any], observations: Sequence[Observation]) -> Calibration:
    """The likelihood scale of labelled observations in visiting order (``fingerloc learn``).

    The file order stands for the visiting order: folds by alternate visits
    (:func:`fit_scale`), a model with ``options`` fit on one fold scoring the
    other. Only ``beta``, ``calibration_rows``, ``n_train`` and ``kidnap``
    are set; the rest keeps the defaults (no positions are known).
    """
    labels = [str(o.label) for o in observations]
    order = list(dict.fromkeys(labels))
    col = {lab: j for j, lab in enumerate(order)}
    y = np.array([col[lab] for lab in labels], dtype=np.int64)
    beta, rows = fit_scale(model_fit_score(options, observations), np.arange(y.size), y, len(order))
    return Calibration(beta=float(beta), kidnap=1.0 / (y.size + 2), n_train=int(y.size), calibration_rows=rows)


class Tracker:
    """Either filter along a run, with a map's calibration.

    Parameters
    ----------
    centres : array_like, shape (P, 2)
        Place centres, metres (column ``j`` of every log-likelihood is place ``j``).
    graph : PlaceGraph
        The place graph (its places in the same order as ``centres``).
    calibration : Calibration
    n_particles : int, default POSE_PARTICLES
        Pose filter.
    uniform_mix : float, optional
        Uniform mixing per step of the transition model (default
        ``1 / (counted steps + 2)``, :meth:`~fingerloc.map.filter.TransitionModel.from_graph`).
    scan_map : ScanMap, optional
        The mapping run's laser end points: with ``calibration.scan_gamma >
        0`` the pose filter weighs its particles by them too (``points`` of
        :meth:`run_pose` / :meth:`run`).

    Attributes
    ----------
    transition_ : TransitionModel
    """

    def __init__(
        self,
        centres: Any,
        graph: PlaceGraph,
        calibration: Calibration,
        *,
        n_particles: int = POSE_PARTICLES,
        uniform_mix: float | None = None,
        scan_map: ScanMap | None = None,
    ) -> None:
        self.centres = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
        self.scan_map = scan_map
        self.graph = graph
        self.calibration = calibration
        self.n_particles = n_particles
        if graph.graph.number_of_edges() == 0:
            self.transition_ = TransitionModel.uniform(self.centres.shape[0])
        else:
            self.transition_ = TransitionModel.from_graph(
                graph, alpha=calibration.alpha, uniform_mix=uniform_mix, metres_per_move=calibration.metres_per_move
            )

    def pose_filter(
        self, seed: int = 0, *, kidnap: float | None = None, rng: np.random.Generator | None = None
    ) -> PoseFilter:
        """A fresh pose filter over the places (seeded; ``rng``: this generator instead of one seeded with ``seed``)."""
        from ..map.pose_filter import PoseFilter

        return PoseFilter(
            self.centres,
            self.calibration.radius,
            n_particles=self.n_particles,
            kidnap=self.calibration.kidnap if kidnap is None else kidnap,
            outlier=self.calibration.outlier,
            off_place=self.calibration.off_place,
            heading=heading_of(self.calibration),
            scan_map=self.scan_map,
            scan_gamma=self.calibration.scan_gamma if self.scan_map is not None else 0.0,
            fresh_factor=int(self.calibration.scan_fresh),
            lost_fit=self.calibration.lost_fit,
            lost_kidnap=self.calibration.lost_kidnap,
            lost_after=int(self.calibration.lost_after),
            lost_statistic=self.calibration.lost_statistic,
            lost_uniform=bool(self.calibration.lost_uniform),
            random_state=seed if rng is None else rng,
        )

    def scaled(self, log_posterior: Any) -> FArray:
        """``beta * log P(place | observation)``; NaN rows (no observation) stay NaN, NaN entries become ``-inf``."""
        s = np.asarray(log_posterior, dtype=np.float64)
        empty = np.all(np.isnan(s), axis=1, keepdims=True) if s.ndim == 2 else np.zeros((0, 1), bool)
        out = self.calibration.beta * np.where(np.isnan(s), -np.inf, s)
        return np.where(empty, np.nan, out)

    def run_places(self, log_likelihood: Any, distances: Any = None) -> FilterResult:
        """The discrete filter over the place graph (already scaled rows; NaN = prediction only)."""
        return run_filter(log_likelihood, self.transition_, distances=distances)

    def run_pose(
        self,
        log_likelihood: Any,
        increments: Any,
        pose_filter: PoseFilter,
        *,
        temper: bool = True,
        relocalize: bool = True,
        reset_threshold: float | None = None,
        place_steps: SharedPlaceSteps | None = None,
        headings: Any = None,
        points: Any = None,
        scan_maps: Sequence[ScanMap | None] | None = None,
    ) -> FilterResult:
        """The pose filter (already scaled rows); ``increments`` has one row per step (row 0 unused);
        ``headings``, ``points``, ``scan_maps``: :func:`run_pose_steps`."""
        c = self.calibration
        return run_pose_steps(
            log_likelihood,
            increments,
            pose_filter,
            self.transition_,
            temper=(c.temper_metres, c.temper_radians) if temper else None,
            relocalize=relocalize,
            start_at_first_observation=c.start_at_first_observation,
            gap_metres=c.gap_metres,
            reset_threshold=reset_threshold,
            challenger=challenger_of(c),
            place_steps=place_steps,
            headings=headings,
            heading_temper=(c.heading_temper_metres, c.temper_radians) if temper and c.heading_temper_metres > 0 else None,
            hold_margin=c.hold_margin,
            tie_break=c.tie_break,
            points=points,
            scan_maps=scan_maps,
        )

    def run(
        self,
        log_posterior: Any,
        poses: Any = None,
        *,
        filter: str = "pose",
        odometry_error: float = 0.0,
        seed: int = 0,
        temper: bool = True,
        relocalize: bool = True,
        headings: Any = None,
        points: Any = None,
    ) -> FilterResult:
        """Track along a run.

        Parameters
        ----------
        log_posterior : array_like, shape (n_steps, P)
            The single-shot ``log P(place | observation)`` per step (a NaN
            row: no observation, prediction only). Scaled by ``beta`` here.
        poses : array_like, shape (n_steps, 3), optional
            The steps' poses (metres, radians); needed by the pose filter,
            and by the discrete filter's odometry.
        filter : {"pose", "places"}
        odometry_error : float, default 0
            Pose filter: simulated wheel-odometry errors on the poses'
            increments, times this factor (0 = the poses' own increments).
        seed : int, default 0
            Seeds the particles (``seed``) and the simulated odometry (``seed + 1``).
        headings : array_like, shape (n_steps, P), optional
            Pose filter: the heading (radians, the poses' frame) each
            observation implies at each place (NaN = none); used when the
            calibration has a heading model (:func:`heading_of`).
        points : sequence of (m, 2) arrays or None, length n_steps, optional
            Pose filter: each observation's laser end points (robot frame,
            metres, :func:`~fingerloc.map.scan_map.scan_points`; None: none);
            used with the tracker's ``scan_map`` and ``calibration.scan_gamma > 0``.

        Returns
        -------
        FilterResult
        """
        if filter not in FILTERS:
            raise InvalidParameterError(f"filter must be one of {', '.join(FILTERS)}, got {filter!r}")
        ll = self.scaled(log_posterior)
        p = None if poses is None else np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if p is not None and p.shape[0] != ll.shape[0]:
            raise InvalidParameterError(f"poses must have one row per step ({ll.shape[0]}), got {p.shape[0]}")
        if filter == "places":
            return self.run_places(ll, None if p is None else step_distances(p[:, :2]))
        if p is None:
            raise InvalidParameterError("the pose filter needs a pose at every step")
        from ..map.pose_filter import wheel_odometry

        inc = wheel_odometry(p, odometry_error, random_state=seed + 1)
        return self.run_pose(
            ll, np.vstack([np.zeros((1, 3)), inc]), self.pose_filter(seed), temper=temper, relocalize=relocalize,
            headings=headings, points=points,
        )  # fmt: skip
