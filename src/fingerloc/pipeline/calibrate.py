"""The one calibration of a map on its mapping part: the likelihood scale, the heading model, the pose filter's tuning.

:func:`calibrate_map` is the sequence every caller runs (``fingerloc map``,
:func:`fingerloc.make_map`, and the real-log benchmark's filtered methods),
given a single-shot recogniser (a :data:`~fingerloc.pipeline.calibration.FitScore`)
and the mapping part (:class:`MappingPart`):

1. the place graph and ``metres_per_move`` from the mapping part's positions;
2. the scan map of the mapping part's laser end points (a run with ranges);
3. ``beta`` from held-out training views (:func:`~fingerloc.pipeline.calibration.held_out_calibration`);
4. the heading model (:func:`~fingerloc.pipeline.calibration.with_heading_model`);
5. the pose filter's reliability ``rho`` and tempering distance, then the power
   of the scan evidence and the lost rule, chosen by running the filter along
   the mapping part with each held-out view as an observation
   (:func:`tune_pose_filter`; each held-out view scored by a recogniser, and
   its end points against a scan map, that never saw it).

Nothing is taken from the queries. What each step tries is a
:class:`~fingerloc.config.CalibrationConfig` setting.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .._types import FArray, IArray
from ..config import Config
from ..errors import InvalidParameterError
from ..map.driver import run_pose_filter
from ..map.filter import SharedPlaceSteps, fit_outlier_weight
from ..map.graph import PlaceGraph
from ..map.motion import wheel_odometry
from ..map.replay import SharedDraws
from ..map.scan_map import ScanMap
from .calibration import (
    Calibration,
    FitHeadings,
    FitScore,
    HeldOut,
    held_out_calibration,
    held_out_headings,
    mapping_graph,
    step_distances,
    with_heading_model,
)
from .filters import pose_filter_of, pose_tracking, transition_of

__all__ = [
    "MapCalibration",
    "MappingPart",
    "calibrate_lost",
    "calibrate_map",
    "fold_scan_maps",
    "scan_folds",
    "scan_tuning_inputs",
    "tune_pose_filter",
    "with_place_check",
]


@dataclass(slots=True)
class MappingPart:
    """A run's mapping part, as the calibration needs it.

    Attributes
    ----------
    train_idx : ndarray of int, shape (n_train,)
        The training scans' indices in the run (all within the mapping part), in run order.
    labels : ndarray of int, shape (n_train,)
        Each training scan's place, ``0 .. P - 1``.
    centres : ndarray, shape (P, 2)
        Place centres, metres.
    poses : ndarray, shape (n_mapping, 3)
        Every mapping scan's pose (metres, radians), in run order.
    fov : float
        The sensor's median field of view, radians.
    place_names : list of str
        Place ``j``'s name.
    points : list of (m, 2) arrays, optional
        Every mapping scan's laser end points (robot frame, metres); ``None``: no ranges.
    """

    train_idx: IArray
    labels: IArray
    centres: FArray
    poses: FArray
    fov: float
    place_names: list[str]
    points: list[Any] | None = None

    def __post_init__(self) -> None:
        self.train_idx = np.asarray(self.train_idx, dtype=np.int64).reshape(-1)
        self.labels = np.asarray(self.labels, dtype=np.int64).reshape(-1)
        self.centres = np.asarray(self.centres, dtype=np.float64).reshape(-1, 2)
        self.poses = np.asarray(self.poses, dtype=np.float64).reshape(-1, 3)
        if self.train_idx.size != self.labels.size:
            raise InvalidParameterError(f"train_idx and labels differ in length: {self.train_idx.size}, {self.labels.size}")
        if self.train_idx.size and int(self.train_idx.max()) >= self.poses.shape[0]:
            raise InvalidParameterError("a training scan lies beyond the mapping part's poses")
        if len(self.place_names) != self.centres.shape[0]:
            raise InvalidParameterError(f"{len(self.place_names)} place names for {self.centres.shape[0]} centres")
        if self.points is not None and len(self.points) != self.poses.shape[0]:
            raise InvalidParameterError(f"points must have one entry per mapping scan ({self.poses.shape[0]}), got {len(self.points)}")

    @property
    def n_places(self) -> int:
        """Number of places ``P``."""
        return int(self.centres.shape[0])


@dataclass(slots=True)
class MapCalibration:
    """What :func:`calibrate_map` learned.

    Attributes
    ----------
    calibration : Calibration
    graph : PlaceGraph
        The place graph of the mapping part's visiting order.
    scan_map : ScanMap or None
        The mapping part's laser end points (``None``: no ranges, or ``config.calibration.scan`` off).
    held : HeldOut or None
        The held-out scores ``beta`` was fit on (``None``: not calibrated).
    headings : ndarray, shape (n_held, P), optional
        The held-out rows' implied headings (``None``: no heading model); at each row's own
        place only (NaN elsewhere) unless ``config.calibration.tune_with_heading``.
    tuning : list of dict
        Every (rho, tempering[, scan power]) tried along the mapping part, with its top-1.
    """

    calibration: Calibration
    graph: PlaceGraph
    scan_map: ScanMap | None = None
    held: HeldOut | None = None
    headings: FArray | None = None
    tuning: list[dict[str, float]] = field(default_factory=list)


def calibrate_map(
    fit_score: FitScore,
    mapping: MappingPart,
    config: Config,
    *,
    fit_headings: FitHeadings | None = None,
    odometry_error: float = 0.0,
    seed: int = 0,
    observe: bool = True,
    on_step: Callable[[str], None] | None = None,
) -> MapCalibration:
    """Calibrate the filters on a run's mapping part (module docstring).

    Parameters
    ----------
    fit_score : FitScore
        The single-shot recogniser over the training scans (row indices are
        positions among them, ``0 .. n_train - 1``).
    mapping : MappingPart
    config : Config
        ``config.places`` (spacing, radius), ``config.calibration`` (what is
        fitted and tried) and ``config.pose_filter`` (how the tuning runs filter).
    fit_headings : FitHeadings, optional
        The recogniser's implied headings (:func:`~fingerloc.pipeline.calibration.model_fit_headings`);
        needed for the heading model (``None``: no heading model).
    odometry_error : float, default 0
        Factor of the simulated wheel-odometry errors of the tuning runs.
    seed : int, default 0
        The tuning runs' seed (their particles: ``seed + 2``).
    observe : bool, default True
        False: the tuning runs see uniform rows at the held-out views (what
        the odometry and the scan evidence give without the recogniser), no
        heading model and no lost rule.
    on_step : callable, optional
        Called with a short text before each stage.

    Returns
    -------
    MapCalibration
    """
    note = on_step or (lambda s: None)
    cc, places = config.calibration, config.places
    m = mapping
    graph, metres = mapping_graph(m.poses[:, :2], m.centres, m.place_names)
    scan_map = None
    if cc.scan and m.points is not None and any(np.size(q) for q in m.points):
        note(f"mapping the laser end points of {m.poses.shape[0]} scans")
        scan_map = ScanMap.from_scans(m.points, m.poses)
    held = None
    windows = calibration_windows(m.poses.shape[0], cc.max_steps, cc.windows)
    scored = np.any(_within(m.train_idx, windows), axis=0) if len(windows) > 1 else None
    if cc.enabled:
        sample = "" if scored is None else f" ({len(windows)} stretches of {windows[0][1] - windows[0][0]} of its {m.poses.shape[0]} steps)"
        note(f"calibrating the filters on the mapping part{sample}")
        held = held_out_calibration(fit_score, m.train_idx, m.labels, m.n_places, min_rows=cc.min_rows, scored=scored)
    n_train = int(m.train_idx.size)
    outlier, off_place = 0.1, 0.1
    if cc.outlier_fit and held is not None and held.labels.size:
        outlier = fit_outlier_weight(held.beta * held.scores, held.labels)
    cal = Calibration(
        beta=1.0 if held is None else float(held.beta),
        metres_per_move=float(metres),
        temper_metres=float(places.spacing_m),
        temper_radians=float(m.fov),
        kidnap=1.0 / (n_train + 2) if cc.kidnap is None else float(cc.kidnap),
        radius=float(places.radius_m),
        spacing=float(places.spacing_m),
        n_train=n_train,
        calibration_rows=0 if held is None else held.rows,
        outlier=float(outlier),
        off_place=off_place,
    )
    headings = None
    if held is not None and observe and cc.heading and fit_headings is not None and held.labels.size:
        note("fitting the heading model on the mapping part")
        headings = held_out_headings(fit_headings, m.labels, held, m.n_places, own_only=not cc.tune_with_heading)
        if headings is not None:
            cal = with_heading_model(
                cal, held, headings, m.poses[m.train_idx[held.index], 2], reverse=cc.heading_reverse,
                slope=cc.heading_slope, temper_metres=cc.heading_temper_m,
            )  # fmt: skip
    tried: list[dict[str, float]] = []
    use_scan = scan_map is not None and cc.scan_gamma is None
    if held is not None and cc.tune and (observe or use_scan):
        note("choosing the pose filter's reliability and tempering on the mapping part")
        scan_args: dict[str, Any] = {}
        if use_scan and m.points is not None:
            scan_args = scan_tuning_inputs(m.points, m.poses, m.train_idx, m.labels, held, guard=cc.scan_guard_m)
        tuned_on = held if observe else replace(held, scores=np.zeros_like(held.scores))
        cal, tried = tune_pose_filter(
            cal, config, m.centres, graph, tuned_on, m.train_idx, m.poses, odometry_error=odometry_error, seed=seed,
            headings=headings if cc.tune_with_heading else None, lost=cc.lost and observe, windows=windows, **scan_args,
        )  # fmt: skip
    if scan_map is not None and cc.scan_gamma is not None:
        cal = replace(cal, scan_gamma=float(cc.scan_gamma))
    if held is not None and observe and held.labels.size:
        cal = with_place_check(cal, config, graph, m, held, windows=windows)
    return MapCalibration(cal, graph, scan_map, held, headings, tried)


def calibration_windows(n_steps: int, max_steps: int | None, windows: int = 4) -> list[tuple[int, int]]:
    """The stretches ``[a, b)`` of a mapping part of ``n_steps`` steps its calibration runs along.

    All of it (one stretch) up to ``max_steps`` steps (``None``: always);
    beyond, ``windows`` stretches of ``max_steps // windows`` steps, the first
    at the start, the last at the end, the others evenly between
    (:attr:`CalibrationConfig.max_steps <fingerloc.config.CalibrationConfig>`).
    """
    n = int(n_steps)
    if max_steps is None or n <= int(max_steps):
        return [(0, n)]
    k = max(1, min(int(windows), int(max_steps)))
    length = int(max_steps) // k
    if k == 1:
        a = (n - length) // 2
        return [(a, a + length)]
    starts = [(i * (n - length)) // (k - 1) for i in range(k)]
    return [(a, a + length) for a in starts]


def _within(steps: IArray, windows: Sequence[tuple[int, int]]) -> list[Any]:
    """Per stretch ``[a, b)`` of ``windows``: which of ``steps`` (step indices) lie in it (bool, shape of ``steps``)."""
    return [(steps >= a) & (steps < b) for a, b in windows]


def with_place_check(
    calibration: Calibration,
    config: Config,
    graph: PlaceGraph,
    mapping: MappingPart,
    held: HeldOut,
    *,
    windows: Sequence[tuple[int, int]] | None = None,
) -> Calibration:
    """The calibration with the place filter's and the single shot's top-1 on the mapping part's held-out views.

    The filter over places (:func:`~fingerloc.pipeline.filters.place_transition_of`, the places' positions
    known) runs along the mapping part with each held-out view (``beta`` times its held-out score) as an
    observation at its step (:func:`~fingerloc.map.filter.check_place_filter`); with ``windows``
    (:func:`calibration_windows`) along each stretch, the top-1 pooled over them.
    """
    from ..map.filter import check_place_filter
    from .filters import place_transition_of

    m = mapping
    rows = m.train_idx[held.index]
    ll = np.full((m.poses.shape[0], m.n_places), np.nan)
    ll[rows] = calibration.beta * np.where(np.isnan(held.scores), -np.inf, held.scores)
    labels = np.full(m.poses.shape[0], -1, dtype=np.int64)
    labels[rows] = held.labels
    transition = place_transition_of(graph, calibration, config, m.centres)
    dist = step_distances(m.poses[:, :2])
    wins = [(0, m.poses.shape[0])] if windows is None else list(windows)
    checks = [check_place_filter(ll[a:b], transition, labels[a:b], distances=dist[a:b]) for a, b in wins]
    if len(checks) == 1:  # the check's own fractions (a pooled one would round them again)
        filt, single = checks[0].filter_top1, checks[0].single_top1
    else:
        n = max(sum(c.rows for c in checks), 1)
        filt = sum(c.filter_top1 * c.rows for c in checks) / n
        single = sum(c.single_top1 * c.rows for c in checks) / n
    return replace(calibration, place_filter_top1=filt, place_single_top1=single)


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
    points: Sequence[Any], poses: Any, fold: Any, *, guard: float = 1.0, travel: Any = None, **options: Any
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
    guard : float, default 1.0
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


def scan_tuning_inputs(
    points: Sequence[Any], poses: Any, train_idx: Any, labels: Any, held: HeldOut, *, guard: float = 1.0
) -> dict[str, Any]:
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
        maps = fold_scan_maps([points[i] for i in tr.tolist()], ps[tr], fold, guard=guard, travel=travel)
    except InvalidParameterError:  # a fold without end points: no map to score its rows against
        return {}
    return {"scan_points": [points[i] for i in tr[held.index].tolist()], "scan_maps": maps, "scan_fold": fold}


def tune_pose_filter(
    calibration: Calibration,
    config: Config,
    centres: Any,
    graph: PlaceGraph,
    held: HeldOut,
    train_idx: Any,
    mapping_poses: Any,
    *,
    odometry_error: float = 0.0,
    seed: int = 0,
    headings: Any = None,
    scan_points: Sequence[FArray | None] | None = None,
    scan_maps: Sequence[ScanMap] | None = None,
    scan_fold: Any = None,
    lost: bool | None = None,
    windows: Sequence[tuple[int, int]] | None = None,
) -> tuple[Calibration, list[dict[str, float]]]:
    """Choose the pose filter's ``outlier`` (rho) and tempering distance along the **mapping** part, then its scan power.

    Each training scan's held-out score (the recogniser fit on the other
    visits, :func:`~fingerloc.pipeline.calibration.held_out_calibration`) is
    an observation of a run along the mapping part's poses, with simulated
    odometry of its own seed (``seed + 2``); every pair of
    ``config.calibration.outliers`` plus the reliability
    :func:`~fingerloc.map.filter.fit_outlier_weight` fits, times
    ``config.calibration.temper_m``, runs the filter, and the pair with the
    best top-1 at the training scans wins (ties: the earlier pair). Nothing
    is taken from the queries.

    The runs draw the same random numbers (one seed, the same steps) and run
    the same place filter alongside: with ``config.calibration.share_draws``
    both are computed once and replayed
    (:class:`~fingerloc.map.replay.SharedDraws`,
    :class:`~fingerloc.map.filter.SharedPlaceSteps`), which changes no result.

    ``headings`` (shape (n_held, P), radians, NaN = none): the heading each
    held-out row implies at each place (rows as ``held.scores``); with the
    calibration's heading model, the runs use them.

    ``scan_points`` (one (m, 2) array or None per held-out row, rows as
    ``held.scores``, robot frame) and ``scan_maps`` (:func:`fold_scan_maps`
    of the training scans with the folds ``scan_fold``, default
    ``held.fold``; :func:`scan_tuning_inputs` gives all three): then the
    power of the scan evidence is chosen too. At the chosen pair the filter
    runs again with each power of ``config.calibration.scan_gammas``, each
    held-out row's end points scored against its fold's map (one that never
    saw them); the best top-1 wins, 0 (the run above) on ties. With
    ``config.calibration.scan_starts`` > 1 each power, 0 included, runs from
    that many starts along the mapping part and its top-1 is pooled over the
    runs. With ``lost`` (default ``config.calibration.lost``) and a power >
    0 chosen, the lost rule's threshold and re-draw probability are
    calibrated on the chosen power's run (:func:`calibrate_lost`).

    ``windows`` (:func:`calibration_windows`, steps ``[a, b)`` of the mapping
    part; default all of it): every run goes along each stretch from its
    start (the scan powers' from its first held-out row) and the top-1 is
    pooled over the stretches' held-out rows; the lost rule is calibrated on
    the stretches' runs one after the other.

    Returns
    -------
    Calibration
        ``calibration`` with ``outlier``, ``temper_metres``, ``scan_gamma``,
        ``lost_fit`` and ``lost_kidnap`` chosen (unchanged without a held-out row).
    list of dict
        ``{"outlier", "temper_metres", "top1"}`` of every pair tried, then
        ``{"outlier", "temper_metres", "scan_gamma", "top1"}`` of every power tried.
    """
    cc = config.calibration
    cal = calibration
    poses = np.asarray(mapping_poses, dtype=np.float64).reshape(-1, 3)
    if held.index.size == 0:
        return cal, []
    rows = np.asarray(train_idx, dtype=np.int64)[held.index]
    P = np.asarray(centres).reshape(-1, 2).shape[0]
    ll = np.full((poses.shape[0], P), np.nan)
    ll[rows] = cal.beta * np.where(np.isnan(held.scores), -np.inf, held.scores)
    truth = held.labels
    hd = None
    if headings is not None and cal.heading is not None:
        hd = np.full(ll.shape, np.nan)
        hd[rows] = np.asarray(headings, dtype=np.float64).reshape(rows.size, -1)
    inc = np.vstack([np.zeros((1, 3)), wheel_odometry(poses, odometry_error, random_state=seed + 2)])
    wins = [(0, poses.shape[0])] if windows is None else [(int(a), int(b)) for a, b in windows]
    # one record of draws and place-filter beliefs a stretch: runs along one stretch draw the same numbers
    shared = [SharedDraws(seed + 2) if cc.share_draws else None for _ in wins]
    steps = [SharedPlaceSteps() if cc.share_draws else None for _ in wins]
    transition = transition_of(graph, cal, config)

    def run(trial: Calibration, w: int, start: int, scan_map: ScanMap | None = None, pts: Any = None, maps: Any = None) -> Any:
        sh, stop = shared[w], wins[w][1]
        f = pose_filter_of(centres, trial, config, seed=seed + 2, rng=None if sh is None else sh.generator(),
                           scan_map=scan_map)  # fmt: skip
        res = run_pose_filter(
            ll[start:stop], inc[start:stop], pose_tracking(f, transition, trial, config, place_steps=steps[w]),
            headings=None if hd is None else hd[start:stop], points=None if pts is None else pts[start:stop],
            scan_maps=None if maps is None else maps[start:stop],
        )  # fmt: skip
        return res, f

    in_win = _within(rows, wins)
    n_in = sum(int(np.sum(x)) for x in in_win)  # held-out rows within the stretches (they never overlap)
    fitted = fit_outlier_weight(ll[rows], truth)
    tried: list[dict[str, float]] = []
    best = (-1.0, cal)
    for rho in (*cc.outliers, fitted):
        for metres in cc.temper_m:  # these runs have no scan map: their scan power is 0
            trial = replace(cal, outlier=float(rho), temper_metres=float(metres), scan_gamma=0.0)
            right = 0
            for w, (a, _) in enumerate(wins):
                res, _f = run(trial, w, a)
                right += int(np.sum(res.best[rows[in_win[w]] - a] == truth[in_win[w]]))
            top1 = right / max(n_in, 1)
            tried.append({"outlier": float(rho), "temper_metres": float(metres), "top1": top1})
            if top1 > best[0]:
                best = (top1, trial)
    if scan_points is None or scan_maps is None:
        return best[1], tried
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
    chosen = replace(best[1], lost_fit=None, lost_kidnap=0.0)
    # (stretch, start): one stretch: ``scan_starts`` starts spread over its held-out rows; several: each from its first
    if len(wins) == 1:
        n_starts = cc.scan_starts
        starts = [(0, int(rows[(k * rows.size) // n_starts])) for k in range(n_starts)]
    else:
        starts = [(w, int(np.min(rows[in_win[w]]))) for w in range(len(wins)) if np.any(in_win[w])]
    if len(starts) > 1:  # the chosen pair without the scan evidence, from every start (one start: the run above)
        best = (-1.0, chosen)
    traces: dict[float, tuple[list[float], list[Any]]] = {}
    for gamma in ((0.0,) if len(starts) > 1 else ()) + tuple(cc.scan_gammas):
        trial = replace(chosen, scan_gamma=float(gamma))
        right = counted = 0
        fits: list[float] = []
        oks: list[Any] = []
        for k, (w, s0) in enumerate(starts):
            res, f = run(trial, w, s0, scan_maps[0], pts, maps)
            after = np.flatnonzero((rows >= s0) & in_win[w])
            after = after[np.argsort(rows[after], kind="stable")]  # in time order, as the filter's fit trace
            got = res.best[rows[after] - s0] == truth[after]
            if len(wins) > 1 or k == 0:
                fits += list(f.fit_trace_)
                oks.append(got)
            right += int(np.sum(got))
            counted += int(after.size)
        traces[float(gamma)] = (fits, oks)
        top1 = right / counted
        tried.append({"outlier": chosen.outlier, "temper_metres": chosen.temper_metres, "scan_gamma": float(gamma), "top1": top1})
        if top1 > best[0]:
            best = (top1, trial)
    use_lost = cc.lost if lost is None else lost
    if use_lost and best[1].scan_gamma > 0 and (len(wins) > 1 or starts[0][1] == int(rows[0])):
        trace, ok = traces[float(best[1].scan_gamma)]
        right_rows = np.concatenate(ok) if ok else np.zeros(0, dtype=bool)
        if len(trace) == right_rows.size == n_in:
            thr, kap = calibrate_lost(np.asarray(trace, dtype=np.float64), right_rows, cc.lost_quantile,
                                      after=config.pose_filter.lost_after)  # fmt: skip
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
    it is right; default 0.05); the re-draw probability is how often the answer was wrong
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
    thr = float(np.quantile(f[has & ok], 0.05 if quantile is None else quantile))
    low = has & (f < thr)
    run = np.zeros(f.size, dtype=np.int64)  # consecutive rows below the threshold, up to each row
    for i in range(f.size):
        run[i] = (run[i - 1] + 1 if i else 1) if low[i] else 0
    low = run >= max(int(after), 1)
    return thr, float((np.sum(low & ~ok) + 1) / (np.sum(low) + 2))
