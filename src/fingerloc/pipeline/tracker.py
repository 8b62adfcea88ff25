"""Localization as the data arrive: one step per scan or observation, with either filter.

A :class:`Tracker` (``place_map.tracker()``) holds a map's model and one
filter, and answers each step with an :class:`Answer`: the place the robot is
at, the posterior's top entries, the unknown-place probability, the pose
filter's pose estimate with its covariance, and the time the step took::

    tracker = place_map.tracker(filter="pose")
    for scan, odom, t in robot:                   # a laser scan, the odometry pose, the clock
        answer = tracker.step(scan, odometry=odom, stamp=t)
        print(answer.place, answer.probability, answer.pose)

Each step (:meth:`Tracker.step`): the item's features are extracted with the
map's preset, the model scores every place (``log P(place | view)``, scaled
by the calibration's ``beta``), the heading the view implies at each place
and its laser end points are computed when the map uses them; then the filter
moves by the odometry since the previous step and updates.

The implied headings cost one alignment per place. On a map of more than
:data:`HEADING_ALL_MAX` places the pose filter's heading evidence is computed
only at :data:`HEADING_NEAR` places near the particles (within a place radius
plus :data:`HEADING_REACH_M` of one: the heading weighs a particle at its
place; those holding the most particles times the view's likelihood) and the
:data:`HEADING_TOP` places the view's likelihood ranks first (where the
kidnapping component draws fresh particles and their headings)
(:meth:`Tracker.heading_places`); elsewhere the view brings no heading
evidence, as at a place without one. Offline tracking applies the same rule,
so both give the same answers.

* ``filter="pose"``: the pose particle filter
  (:class:`~fingerloc.map.driver.PoseTracking`), which needs the place
  positions of a map made from poses (``fingerloc map``);
* ``filter="places"``: the discrete filter over the places
  (:class:`~fingerloc.map.filter.MarkovFilter`), which needs only the
  travelled distance: the metric kernel over the places' positions when the
  map has them, else the place graph's chain
  (:func:`~fingerloc.pipeline.filters.place_transition_of`); when it was below
  the single shot on the mapping part's held-out views, it answers the
  single shot at the observed steps (``steps_aside``).

Offline tracking of a recorded run (:meth:`fingerloc.pipeline.placemap.PlaceMap.track`)
is this loop over the run (the model's scores computed in one batch, which
gives the same numbers).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .._types import FArray, IArray
from ..config import Config
from ..errors import InvalidParameterError
from ..map.driver import Challenger, PoseTracking
from ..map.filter import MarkovFilter, TransitionModel, entropy_bits
from ..map.motion import OdometrySimulator, odometry_increments
from ..observation import Observation
from ..sensors import Scan
from .calibration import Calibration, PlaceColumns
from .filters import place_transition_of, pose_filter_of, pose_tracking, transition_of

if TYPE_CHECKING:
    from ..map.graph import PlaceGraph
    from ..map.pose_filter import PoseFilter
    from ..map.scan_map import ScanMap

__all__ = [
    "FILTERS", "HEADING_ALL_MAX", "HEADING_NEAR", "HEADING_REACH_M", "HEADING_TOP", "POSE_MODE_ITERATIONS",
    "POSE_MODE_RADII", "Answer", "Tracker", "end_points_of", "scaled",
]  # fmt: skip

#: The filters a tracker runs.
FILTERS: tuple[str, ...] = ("places", "pose")
#: Entries of the posterior an :class:`Answer` lists.
TOP_ENTRIES = 5
#: Up to this many places, the implied heading of every place is computed at every observation.
HEADING_ALL_MAX = 100
#: Above HEADING_ALL_MAX places: the places near the particles whose heading is computed, at most.
HEADING_NEAR = 12
#: Above HEADING_ALL_MAX places: the places of the view's likelihood ranked first whose heading is computed.
HEADING_TOP = 4
#: Metres a particle may move in one step past a place's radius and still find that place's heading computed.
HEADING_REACH_M = 1.0
#: Metres: the particles are grouped on a grid of this cell size to find the places near them.
_HEADING_CELL_M = 0.5
#: The pose estimate: the particles within this many place radii of the answered place's mode.
POSE_MODE_RADII = 2.0
#: The pose estimate: mean-shift iterations from the answered place's centre.
POSE_MODE_ITERATIONS = 3


def scaled(log_posterior: Any, beta: float) -> FArray:
    """``beta * log P(place | observation)``; NaN rows (no observation) stay NaN, NaN entries become ``-inf``."""
    s = np.asarray(log_posterior, dtype=np.float64)
    empty = np.all(np.isnan(s), axis=-1, keepdims=True)
    out = beta * np.where(np.isnan(s), -np.inf, s)
    return np.where(empty, np.nan, out)


def end_points_of(item: Scan | Observation) -> FArray | None:
    """An item's laser end points (robot frame, metres, every ``SCAN_STRIDE``-th beam), shape (m, 2); None without ranges."""
    from ..map.scan_map import end_points, scan_points

    if isinstance(item, Scan):
        return end_points(item)
    if item.ranges is None or item.range_bearings is None:
        return None
    return scan_points(item.ranges, item.range_bearings)


@dataclass(frozen=True, slots=True)
class Answer:
    """One step's answer of a :class:`Tracker`.

    Attributes
    ----------
    step : int
        0-based, since the tracker's start (or :meth:`Tracker.reset`).
    stamp : float or None
        Seconds, the input's clock, as given to :meth:`Tracker.step`.
    name : str
        The item's name (file and line of a recorded run), or ``""``.
    observed : bool
        The step had an observation (else the filter only predicted).
    place : str
        The answer: the most probable place (between observations, the held one).
    probability : float
        Its posterior probability.
    entropy_bits : float
        The posterior's entropy, bits.
    posterior : tuple of (str, float)
        The :data:`TOP_ENTRIES` most probable places and their probabilities, descending.
    unknown : float or None
        The model's probability that the view shows no learned place (a model with an
        unknown-place prior, at an observed step), else None.
    pose : (float, float, float) or None
        The pose filter's estimate ``(x, y, theta)`` in the map's frame (metres,
        radians): the weighted mean of the particles of the answered place's mode
        (those within :data:`POSE_MODE_RADII` place radii of a flat-kernel mean
        shift started at the place's centre), the circular mean heading; None for
        the place filter.
    covariance : 3 x 3 tuple or None
        The weighted second moment of every particle's ``(x, y, theta)`` about
        ``pose`` (heading differences wrapped), metres and radians squared: the
        estimate's expected squared error under the whole belief.
    latency_s : float
        Seconds the step took (features, model, filter).
    true : str or None
        The true place when known (a labelled observation, or a pose within a place's radius).
    log_posterior : ndarray, shape (P,)
        The whole place log-posterior (columns: the map's places in order).
    """

    step: int
    stamp: float | None
    name: str
    observed: bool
    place: str
    probability: float
    entropy_bits: float
    posterior: tuple[tuple[str, float], ...]
    unknown: float | None
    pose: tuple[float, float, float] | None
    covariance: tuple[tuple[float, ...], ...] | None
    latency_s: float
    true: str | None
    log_posterior: FArray

    def to_json(self) -> dict[str, Any]:
        """The step's record of ``track --json`` (NaN written as null)."""

        def num(v: float | None) -> float | None:
            return None if v is None or not math.isfinite(v) else float(v)

        return {
            "step": self.step,
            "name": self.name,
            "observed": self.observed,
            "best": self.place,
            "probability": float(self.probability),
            "entropy_bits": float(self.entropy_bits),
            "true": self.true,
            "stamp": num(self.stamp),
            "pose": None if self.pose is None else [num(v) for v in self.pose],
            "covariance": None if self.covariance is None else [[num(v) for v in row] for row in self.covariance],
            "posterior": [[p, float(v)] for p, v in self.posterior],
            "unknown": num(self.unknown),
            "latency_ms": 1000.0 * self.latency_s,
        }


def _pose_estimate(
    particles: FArray, log_weights: FArray, centre: Any = None, reach: float | None = None
) -> tuple[tuple[float, float, float], tuple[tuple[float, ...], ...]]:
    """The pose estimate of weighted particles and its covariance (:class:`Answer`'s ``pose`` and ``covariance``).

    With ``centre`` (the answered place's, metres) and ``reach`` (metres): the
    weighted mean of the particles within ``reach`` of a point that starts at
    ``centre`` and moves to that mean, :data:`POSE_MODE_ITERATIONS` times (a
    flat-kernel mean shift: the mode of the answered place, not a mean between
    two hypotheses); no particle there: every particle. The heading is the
    circular mean of the same particles. The covariance is every particle's
    weighted second moment about the estimate (headings wrapped): the expected
    squared error of the estimate under the whole belief, other modes included.
    """
    w = np.exp(log_weights - np.max(log_weights))
    w = w / w.sum()
    sel: Any = slice(None)
    if centre is not None and reach is not None:
        c = np.asarray(centre, dtype=np.float64)[:2]
        for _ in range(POSE_MODE_ITERATIONS):
            inside = np.hypot(particles[:, 0] - c[0], particles[:, 1] - c[1]) <= reach
            if not np.any(inside) or not w[inside].sum() > 0:
                break
            sel = inside
            c = (w[inside] @ particles[inside, :2]) / w[inside].sum()
    ws, ps = w[sel], particles[sel]
    ws = ws / ws.sum()
    x, y = float(ws @ ps[:, 0]), float(ws @ ps[:, 1])
    th = math.atan2(float(ws @ np.sin(ps[:, 2])), float(ws @ np.cos(ps[:, 2])))
    d = np.column_stack([particles[:, 0] - x, particles[:, 1] - y, np.mod(particles[:, 2] - th + math.pi, 2 * math.pi) - math.pi])
    cov = (d * w[:, None]).T @ d
    return (x, y, th), tuple(tuple(float(v) for v in row) for row in cov)


class Tracker:
    """Either filter along a run, one step at a time (module docstring).

    Made by :meth:`fingerloc.pipeline.placemap.PlaceMap.tracker`; the arguments
    below are what that method resolves.

    Parameters
    ----------
    model : PlaceModel
        The fitted place model.
    labels : sequence of str
        The places in the filters' order (column ``j`` = place ``labels[j]``).
    graph : PlaceGraph
        The place graph, places in ``labels`` order.
    calibration : Calibration
    config : Config
    centres : array_like, shape (P, 2), optional
        Place centres (metres); needed by the pose filter.
    filter : {"pose", "places"}, default "pose"
    features : mapping, optional
        The preset's laser feature parameters (scans -> observations).
    seed : int, default 0
        Seeds the pose filter's particles.
    scan_map : ScanMap, optional
        The map's laser end points (pose filter, with ``calibration.scan_gamma > 0``).
    heading : bool, default True
        Use the calibration's heading model (pose filter).
    transition : TransitionModel, optional
        The place filter's transition model (default from the graph and
        calibration; for ``filter="places"`` with ``centres``, the metric kernel).
    odometry_error : float, default 0
        Simulated wheel-odometry errors on the increments between the odometry
        poses given to :meth:`step`, times this factor (a replay of a log whose
        poses are corrected ones; :class:`~fingerloc.map.motion.OdometrySimulator`,
        seeded with ``seed + 1``); 0: the poses' own increments.
    heading_budget : (int, int) or None, default (HEADING_NEAR, HEADING_TOP)
        On a map of more than :data:`HEADING_ALL_MAX` places, the implied
        headings are computed at most at this many places near the particles
        and at this many places of the view's likelihood ranked first
        (:meth:`heading_places`); None: at every place.
    """

    def __init__(
        self,
        model: Any,
        labels: Sequence[str],
        graph: PlaceGraph,
        calibration: Calibration,
        config: Config,
        *,
        centres: Any = None,
        filter: str = "pose",
        features: dict[str, Any] | None = None,
        seed: int = 0,
        scan_map: ScanMap | None = None,
        heading: bool = True,
        transition: TransitionModel | None = None,
        odometry_error: float = 0.0,
        heading_budget: tuple[int, int] | None = (HEADING_NEAR, HEADING_TOP),
    ) -> None:
        if filter not in FILTERS:
            raise InvalidParameterError(f"filter must be one of {', '.join(FILTERS)}, got {filter!r}")
        self.model = model
        self.labels = [str(x) for x in labels]
        self.calibration = calibration
        self.config = config
        self.filter = filter
        self.features = dict(features or {})
        self.seed = int(seed)
        self.odometry = OdometrySimulator(odometry_error, self.seed + 1)
        if transition is not None:
            self.transition = transition
        elif filter == "places":
            self.transition = place_transition_of(graph, calibration, config, centres)
        else:
            self.transition = transition_of(graph, calibration, config)
        #: The place filter answers the single shot at observed steps (it lost to it on the mapping part).
        self.steps_aside = filter == "places" and calibration.place_filter_steps_aside()
        self.heading = bool(heading) and filter == "pose" and calibration.heading is not None
        if heading_budget is not None:
            if len(heading_budget) != 2 or any(isinstance(v, bool) or int(v) < 0 for v in heading_budget):
                raise InvalidParameterError(f"heading_budget must be two integers >= 0 or None, got {heading_budget!r}")
            heading_budget = (int(heading_budget[0]), int(heading_budget[1]))
        self.heading_budget = heading_budget
        self._grid: Any = None
        self._heading_set: tuple[int, Any, IArray | None] | None = None
        self.columns = PlaceColumns(model, self.labels)  # the places' columns and views, looked up once
        self.scan_map = scan_map if filter == "pose" else None
        self._pose: PoseTracking | None = None
        self._places: MarkovFilter | None = None
        if filter == "pose":
            if centres is None:
                raise InvalidParameterError("the pose filter needs the place positions (a map made by 'fingerloc map')")
            c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
            if c.shape[0] != len(self.labels):
                raise InvalidParameterError(f"{c.shape[0]} place positions for {len(self.labels)} places")
            pf = pose_filter_of(c, calibration, config, seed=self.seed, scan_map=scan_map)
            self._pose = pose_tracking(pf, self.transition, calibration, config)
        else:
            self._places = MarkovFilter(self.transition)
        self.reset()

    @property
    def n_places(self) -> int:
        """Number of places ``P``."""
        return len(self.labels)

    @property
    def uses_scan(self) -> bool:
        """Whether the steps' laser end points weigh the particles (a scan map, and a power > 0)."""
        return self.scan_map is not None and self.calibration.scan_gamma > 0

    @property
    def pose_filter(self) -> PoseFilter | None:
        """The pose filter (None for the place filter)."""
        return None if self._pose is None else self._pose.pose_filter

    def reset(self) -> Tracker:
        """Back to the start: nothing known (the pose filter's random generator carries on)."""
        if self._pose is not None:
            self._pose.reset()
        if self._places is not None:
            self._places.reset()
        self._t = 0
        self._odometry: FArray | None = None
        self._heading_set = None
        self.odometry.reset()
        return self

    def heading_places(self, log_likelihood: Any) -> IArray | None:
        """The places (column indices, ascending) whose implied heading this step uses; None: every place.

        Every place on a map of at most :data:`HEADING_ALL_MAX` places, with
        ``heading_budget=None``, or with the challenger strategy (its second
        filter's particles). Else, with ``heading_budget = (near, top)``: of
        the places whose centre lies within the place radius plus
        :data:`HEADING_REACH_M` of a particle (the particles as they are before
        this step's motion, on a grid of 0.5 m cells), the ``near`` ones with
        the most particles so close times the place's likelihood in
        ``log_likelihood``; and the ``top`` places of ``log_likelihood``
        ranked first (ties in column order). The set depends only on the
        particles and the row, so streaming and offline tracking compute the
        same one.

        Parameters
        ----------
        log_likelihood : array_like, shape (P,)
            The step's scaled log-likelihood row (NaN: no observation).
        """
        pose = self._pose
        if (
            not self.heading
            or self.heading_budget is None
            or self.n_places <= HEADING_ALL_MAX
            or pose is None
            or isinstance(pose.strategy, Challenger)
        ):
            return None
        hit = self._heading_set
        if hit is not None and hit[0] == self._t and hit[1] is log_likelihood:
            return hit[2]
        row = np.asarray(log_likelihood, dtype=np.float64).reshape(-1)
        n_near, n_top = self.heading_budget
        top = np.argsort(-np.where(np.isnan(row), -np.inf, row), kind="stable")[:n_top]
        pf = pose.pose_filter
        if self._grid is None:
            from ..map._nearest import CentreGrid

            self._grid = CentreGrid(pf.centres)
        cells = np.floor(pf.particles_[:, :2] / _HEADING_CELL_M).astype(np.int64)
        lo = cells.min(axis=0)
        width = int(cells[:, 1].max() - lo[1]) + 1
        code, per_cell = np.unique((cells[:, 0] - lo[0]) * width + (cells[:, 1] - lo[1]), return_counts=True)
        mid = (np.column_stack([code // width, code % width]) + lo + 0.5) * _HEADING_CELL_M
        reach = float(pf.radius) + HEADING_REACH_M + _HEADING_CELL_M * math.sqrt(0.5)
        held = self._grid.mass_within(mid, per_cell.astype(np.float64), reach)
        with np.errstate(divide="ignore"):
            score = np.where(held > 0, np.log(held) + np.where(np.isnan(row), -np.inf, row), -np.inf)
        ranked = np.argsort(-score, kind="stable")[:n_near]
        out = np.union1d(ranked[held[ranked] > 0], top.astype(np.int64))
        self._heading_set = (self._t, log_likelihood, out)
        return out

    # -- one step from raw data ---------------------------------------------------------------------

    def observe(self, item: Scan | Observation) -> tuple[FArray, FArray | None, FArray | None, float | None]:
        """What one item brings to the filter: its scaled log-likelihood row (P,), implied headings (P,) or None,
        laser end points (m, 2) or None, and the unknown-place probability or None."""
        obs = item
        if isinstance(item, Scan):
            from ..features.laser import observation_from_scan

            obs = observation_from_scan(item, **self.features)
        if not isinstance(obs, Observation):
            raise InvalidParameterError(f"a tracker step takes a Scan or an Observation, got {type(item).__name__}")
        row = scaled(self.columns.posterior([obs]), self.calibration.beta)[0]
        hd = None
        if self.heading:
            hd = self.columns.headings([obs], self.heading_places(row))[0]
        pts = end_points_of(item) if self.uses_scan else None
        unknown = None
        if getattr(self.model, "unknown_prior", 0) > 0:
            unknown = float(self.model.predict_unknown_proba([obs])[0])
        return row, hd, pts, unknown

    def step(
        self,
        item: Scan | Observation | None = None,
        odometry: Any = None,
        stamp: float | None = None,
        *,
        increment: Any = None,
        distance: float | None = None,
        observe: bool = True,
        truth: str | None = None,
        name: str = "",
    ) -> Answer:
        """One step: move by the odometry since the previous step, observe ``item``; the answer.

        Parameters
        ----------
        item : Scan or Observation, optional
            The step's view (``None``: prediction only).
        odometry : array_like, shape (3,), optional
            The robot's odometry pose ``(x, y, theta)`` (metres, radians, any fixed
            frame); the motion since the previous step's is used (none at the first).
        stamp : float, optional
            Seconds, the input's clock (copied into the answer).
        increment : array_like, shape (3,), optional
            Instead of ``odometry``: the motion ``(dx, dy, dtheta)`` since the previous
            step, in the previous step's robot frame.
        distance : float, optional
            The place filter's travelled metres (default: the increment's length).
        observe : bool, default True
            False: the item only predicts (a scan between places of a recorded run).
        truth : str, optional
            The true place, copied into the answer.
        name : str, optional
            The item's name, copied into the answer.

        Returns
        -------
        Answer
        """
        t0 = time.perf_counter()
        row = hd = pts = None
        unknown = None
        if item is not None and observe:
            row, hd, pts, unknown = self.observe(item)
        return self.step_scores(
            row, odometry, stamp, increment=increment, distance=distance, headings=hd, points=pts, unknown=unknown,
            truth=truth, name=name, started=t0,
        )  # fmt: skip

    # -- one step from scores -----------------------------------------------------------------------

    def _motion(self, odometry: Any, increment: Any, distance: float | None) -> tuple[FArray | None, float | None]:
        """The increment and distance since the previous step (None at the first step)."""
        if increment is not None:
            inc = np.asarray(increment, dtype=np.float64).reshape(-1)
            if inc.size != 3 or not np.all(np.isfinite(inc)):
                raise InvalidParameterError(f"an odometry increment is 3 finite numbers (dx, dy, dtheta), got {increment!r}")
        elif odometry is not None:
            pose = np.asarray(odometry, dtype=np.float64).reshape(-1)
            if pose.size != 3 or not np.all(np.isfinite(pose)):
                raise InvalidParameterError(f"an odometry pose is 3 finite numbers (x, y, theta), got {odometry!r}")
            prev, self._odometry = self._odometry, pose
            if prev is None:
                return None, distance
            inc = self.odometry.corrupt(odometry_increments(np.vstack([prev, pose]))[0])
            if distance is None:
                distance = float(np.hypot(pose[0] - prev[0], pose[1] - prev[1]))
        else:
            return None, distance
        if distance is None:
            distance = float(np.hypot(inc[0], inc[1]))
        return inc, distance

    def step_scores(
        self,
        log_likelihood: Any,
        odometry: Any = None,
        stamp: float | None = None,
        *,
        increment: Any = None,
        distance: float | None = None,
        headings: Any = None,
        points: Any = None,
        unknown: float | None = None,
        truth: str | None = None,
        name: str = "",
        started: float | None = None,
    ) -> Answer:
        """:meth:`step` with the item's scores already computed (:meth:`observe`: the scaled row, headings, end points).

        ``log_likelihood`` of shape (P,), or ``None`` / all NaN: prediction only.
        """
        t0 = time.perf_counter() if started is None else started
        if headings is not None and log_likelihood is not None:
            cols = self.heading_places(log_likelihood)
            if cols is not None:  # the heading evidence only where it is used (heading_places)
                full = np.asarray(headings, dtype=np.float64).reshape(-1)
                if full.size != self.n_places:
                    raise InvalidParameterError(f"implied headings need {self.n_places} entries, got {full.size}")
                headings = np.full(self.n_places, np.nan)
                headings[cols] = full[cols]
        t = self._t
        self._t += 1
        inc, dist = self._motion(odometry, increment, distance)
        row = None if log_likelihood is None else np.asarray(log_likelihood, dtype=np.float64).reshape(-1)
        if row is not None and row.size != self.n_places:
            raise InvalidParameterError(f"a log-likelihood row needs {self.n_places} entries, got {row.size}")
        observed = row is not None and not bool(np.all(np.isnan(row)))
        pose = cov = None
        if self._pose is not None:
            s = self._pose.step(row, inc, headings=headings, points=points)
            lp, best, prob = s.log_posterior, s.best, s.probability
            pf = self._pose.pose_filter
            pose, cov = _pose_estimate(pf.particles_, pf.log_weights_, pf.centres[best], POSE_MODE_RADII * pf.radius)
        else:
            assert self._places is not None
            lp = self._places.step(row if observed else None, dist)
            if observed and self.steps_aside:
                assert row is not None
                single = np.where(np.isnan(row), -np.inf, row)
                lp = single - float(np.logaddexp.reduce(single))
            best = int(np.argmax(lp))
            prob = float(np.exp(lp[best]))
        order = np.argsort(-lp, kind="stable")[:TOP_ENTRIES]
        post = tuple((self.labels[j], float(np.exp(lp[j]))) for j in order.tolist())
        return Answer(
            step=t, stamp=None if stamp is None else float(stamp), name=name, observed=observed,
            place=self.labels[best], probability=float(prob), entropy_bits=float(entropy_bits(lp)), posterior=post,
            unknown=unknown if observed else None, pose=pose, covariance=cov,
            latency_s=time.perf_counter() - t0, true=truth, log_posterior=lp,
        )  # fmt: skip
