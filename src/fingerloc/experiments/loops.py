"""The loop-closure benchmark (``fingerloc bench loops``): place recognition as the field scores it.

Protocol (one for every method):

1. The laser scans of a log in file order. A *query* is every scan ``i``
   with at least one *candidate*: a scan taken before it and not within the
   last ``T`` seconds (:data:`EXCLUDE_S`, 30 s). When a log's timestamps
   cannot measure that window (they stand still or go back for more than a
   tenth of its steps, as csail's, written with six significant digits), the
   last :data:`EXCLUDE_SCANS` scans (10) are left out instead; the JSON says
   which window each log used.
2. Ground truth from the poses: a query is a *positive* when some candidate
   lies within ``D`` metres of it (:data:`DISTANCE_M`, 2 m).
3. Every method names, for each query, its best candidate and a score
   (higher = surer). At a threshold, a query scoring at least the threshold is
   a detection: a true positive when the named candidate lies within ``D``
   of the query, else a false positive. Precision = TP / (TP + FP), recall =
   TP / positives (a positive whose named candidate is wrong counts against
   precision and recall).
4. Over every threshold: the precision-recall curve; ``recall_at_100`` and
   ``recall_at_99`` (the largest recall at a precision of at least 1 and 0.99;
   0 when none), ``max_f1``, ``average_precision`` (the sum over thresholds of
   the recall gained times the precision there). Per log and pooled over the
   logs' queries.

Methods (:data:`LOOP_METHODS`): ``fingerprint``, the place model of the laser
preset as a loop-closure detector
(:func:`fingerloc.pipeline.revisits.loop_closures`: the revisit filter over
the earlier scans, with a FAB-MAP-style new-place likelihood; no pose);
``fingerprint-single`` (run when named), the same evidence scan by scan
without the filter; ``baseline-scancontext`` and ``baseline-histogram``, the
descriptors of ``bench carmen`` (:mod:`fingerloc.experiments.carmen`), each
naming the candidate it finds most similar, its similarity the score.

The fingerprint map (:func:`fingerloc.pipeline.topology.places_from_fingerprints`,
defaults: the first half of the log) is scored against the poses: its
places, the pose-based map's
(:func:`~fingerloc.pipeline.places.places_from_trajectory`, defaults), the
purity at ``R`` = 3 m (:func:`~fingerloc.pipeline.topology.place_purity`), and
how it localizes the rest of the log: a later scan within ``R`` of some
place's median position is a query, an answer naming such a place is right
(``localize_top1``: single shot; ``track_top1``: the place filter).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._types import FArray, IArray
from ..errors import InvalidParameterError

__all__ = [
    "DEFAULT_LOOP_METHODS",
    "DISTANCE_M",
    "EXCLUDE_S",
    "EXCLUDE_SCANS",
    "LOOP_METHODS",
    "LogLoops",
    "LoopBenchmark",
    "MethodLoops",
    "PRCurve",
    "candidate_window",
    "loop_metrics",
    "loop_truth",
    "pr_curve",
    "run_loop_benchmark",
    "usable_timestamps",
]

#: D: a candidate within this distance of the query is a true match, metres.
DISTANCE_M = 2.0
#: T: scans taken within this many seconds before the query are no candidates.
EXCLUDE_S = 30.0
#: Without usable timestamps: this many scans before the query are no candidates.
EXCLUDE_SCANS = 10
#: Share of a log's timestamp steps that may stand still or go back before the timestamps count as unusable.
_BAD_STEPS = 0.1


# ----------------------------------------------------------------------------------------------- protocol


def usable_timestamps(timestamps: Any) -> bool:
    """True when the timestamps (seconds, shape (n,)) are finite and rise at more than 90 % of their steps."""
    if timestamps is None:
        return False
    t = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    if t.size < 2 or not np.all(np.isfinite(t)):
        return False
    return float(np.mean(np.diff(t) <= 0)) <= _BAD_STEPS


def candidate_window(
    n: int, timestamps: Any = None, *, exclude_s: float = EXCLUDE_S, exclude_scans: int = EXCLUDE_SCANS
) -> tuple[IArray, str]:
    """How many earlier scans each scan may match: scan ``i``'s candidates are scans ``0 .. eligible[i] - 1``.

    With usable timestamps (:func:`usable_timestamps`) the scans taken within
    ``exclude_s`` seconds before scan ``i`` are left out (``eligible[i] = i -
    #{j < i : t_j > t_i - exclude_s}``); otherwise the last ``exclude_scans``.

    Returns
    -------
    eligible : ndarray of int, shape (n,)
    window : str
        ``"30 s"`` or ``"10 scans"``: the window used.
    """
    if not (isinstance(exclude_s, (int, float)) and math.isfinite(exclude_s) and exclude_s >= 0):
        raise InvalidParameterError(f"exclude_s must be a number of seconds >= 0, got {exclude_s!r}")
    if isinstance(exclude_scans, bool) or not isinstance(exclude_scans, (int, np.integer)) or exclude_scans < 0:
        raise InvalidParameterError(f"exclude_scans must be an integer >= 0, got {exclude_scans!r}")
    idx = np.arange(n, dtype=np.int64)
    if usable_timestamps(timestamps) and np.asarray(timestamps).size == n:
        t = np.asarray(timestamps, dtype=np.float64).reshape(-1)
        recent = np.array([int(np.count_nonzero(t[:i] > t[i] - exclude_s)) for i in range(n)], dtype=np.int64)
        return idx - recent, f"{exclude_s:g} s"
    return np.maximum(0, idx - int(exclude_scans)), f"{int(exclude_scans)} scans"


def loop_truth(positions: Any, eligible: Any, distance: float = DISTANCE_M) -> tuple[IArray, NDArray[np.bool_]]:
    """The queries (scans with a candidate) and which of them are positives (a candidate within ``distance``).

    Returns
    -------
    queries : ndarray of int, shape (q,)
        Scan indices, ascending.
    positive : ndarray of bool, shape (q,)
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    el = np.asarray(eligible, dtype=np.int64).reshape(-1)
    queries = np.flatnonzero(el > 0).astype(np.int64)
    positive = np.zeros(queries.size, dtype=bool)
    for k, i in enumerate(queries.tolist()):
        c = pos[: el[i]]
        positive[k] = bool(np.any(np.hypot(c[:, 0] - pos[i, 0], c[:, 1] - pos[i, 1]) <= distance))
    return queries, positive


@dataclass(frozen=True, slots=True)
class PRCurve:
    """A precision-recall curve, one point per distinct score threshold (descending), starting at recall 0.

    Attributes
    ----------
    precision, recall : ndarray, shape (k + 1,)
        The first point is (1, 0): no detection.
    thresholds : ndarray, shape (k + 1,)
        Score of each point (``+inf`` for the first).
    """

    precision: FArray
    recall: FArray
    thresholds: FArray


def pr_curve(scores: Any, correct: Any, n_positive: int) -> PRCurve:
    """The precision-recall curve of detections (protocol step 4).

    Parameters
    ----------
    scores : array_like, shape (q,)
        Each query's score (NaN or ``-inf``: never a detection).
    correct : array_like of bool, shape (q,)
        Whether its named candidate is a true match.
    n_positive : int
        Queries with a true match (the recall's denominator).
    """
    s = np.asarray(scores, dtype=np.float64).reshape(-1)
    ok = np.asarray(correct, dtype=bool).reshape(-1)
    if s.size != ok.size:
        raise InvalidParameterError(f"scores and correct must have the same length, got {s.size} and {ok.size}")
    live = np.isfinite(s) | (s == np.inf)
    s, ok = s[live], ok[live]
    order = np.argsort(-s, kind="stable")
    s, ok = s[order], ok[order]
    tp = np.cumsum(ok)
    fp = np.cumsum(~ok)
    last = np.r_[s[1:] != s[:-1], True] if s.size else np.zeros(0, bool)
    tp, fp, thr = tp[last], fp[last], s[last]
    denom = max(int(n_positive), 1)
    precision = np.r_[1.0, tp / np.maximum(tp + fp, 1)]
    recall = np.r_[0.0, tp / denom]
    return PRCurve(precision, recall, np.r_[np.inf, thr])


def loop_metrics(curve: PRCurve) -> dict[str, float]:
    """``max_f1``, ``recall_at_100``, ``recall_at_99`` and ``average_precision`` of a curve."""
    p, r = curve.precision[1:], curve.recall[1:]

    def recall_at(level: float) -> float:
        sel = p >= level - 1e-12
        return float(r[sel].max()) if sel.any() else 0.0

    f1 = np.where(p + r > 0, 2 * p * r / np.maximum(p + r, 1e-300), 0.0)
    return {
        "max_f1": float(f1.max()) if f1.size else 0.0,
        "recall_at_100": recall_at(1.0),
        "recall_at_99": recall_at(0.99),
        "average_precision": float(np.sum(np.diff(curve.recall) * curve.precision[1:])),
    }


# ----------------------------------------------------------------------------------------------- methods

#: ``(scans, run, eligible) -> (best candidate per scan (-1: none), score per scan)``.
LoopDetector = Callable[[Sequence[Any], Any, IArray], tuple[IArray, FArray]]


def _best_by_similarity(sim: FArray, eligible: IArray) -> tuple[IArray, FArray]:
    n = sim.shape[0]
    best = np.full(n, -1, dtype=np.int64)
    score = np.full(n, -np.inf)
    for i in range(n):
        m = int(eligible[i])
        if m > 0:
            j = int(np.argmax(sim[i, :m]))
            best[i], score[i] = j, float(sim[i, j])
    return best, score


def _descriptor_detector(make: Callable[[], Any]) -> LoopDetector:
    def detect(scans: Sequence[Any], run: Any, eligible: IArray) -> tuple[IArray, FArray]:
        m = make().fit(list(scans), np.arange(len(scans)))
        return _best_by_similarity(np.asarray(m.score(list(scans)), dtype=np.float64), eligible)

    return detect


def _fingerprint_options(run: Any) -> tuple[list[Any], dict[str, Any]]:
    from ..pipeline.presets import resolve_preset

    obs = run.observations()
    resolved = resolve_preset("auto", obs)
    if resolved.features:
        obs = run.observations(features=resolved.features)
    return obs, resolved.options


def _fingerprint(scans: Sequence[Any], run: Any, eligible: IArray) -> tuple[IArray, FArray]:
    from ..pipeline.revisits import loop_closures

    obs, options = _fingerprint_options(run)
    lc = loop_closures(obs, options, eligible)
    return lc.best, lc.log_probability


def _fingerprint_single(scans: Sequence[Any], run: Any, eligible: IArray) -> tuple[IArray, FArray]:
    """The same evidence scan by scan: ``P(at view j | view i)`` against a new place (prior 1/2), no filter."""
    from scipy.special import logsumexp

    from ..pipeline.revisits import RECENT_VIEWS, background_log_likelihood
    from ..pipeline.view_distances import view_distance_matrix

    obs, options = _fingerprint_options(run)
    d, _ = view_distance_matrix(obs, options)
    bg = background_log_likelihood(d, RECENT_VIEWS)
    n = d.shape[0]
    best = np.full(n, -1, dtype=np.int64)
    score = np.full(n, -np.inf)
    for i in range(n):
        m = int(eligible[i])
        if m == 0:
            continue
        ll = -d[i, :m]
        j = int(np.argmax(ll))
        known = float(logsumexp(ll)) - math.log(m)
        best[i] = j
        score[i] = float(ll[j]) - math.log(m) - float(np.logaddexp(known, bg[i]))
    return best, score


def _loop_methods() -> dict[str, LoopDetector]:
    from .carmen import HistogramBaseline, ScanContextBaseline

    return {
        "fingerprint": _fingerprint,
        "fingerprint-single": _fingerprint_single,
        "baseline-scancontext": _descriptor_detector(ScanContextBaseline),
        "baseline-histogram": _descriptor_detector(HistogramBaseline),
    }


#: Every method name ``bench loops`` knows.
LOOP_METHODS: tuple[str, ...] = ("fingerprint", "fingerprint-single", "baseline-scancontext", "baseline-histogram")
#: The methods run by default (the others when named).
DEFAULT_LOOP_METHODS: tuple[str, ...] = ("fingerprint", "baseline-scancontext", "baseline-histogram")


# ----------------------------------------------------------------------------------------------- runner


@dataclass(slots=True)
class MethodLoops:
    """One method on one log: the candidate it names and its score per query, and whether it is right.

    Attributes
    ----------
    best : ndarray of int, shape (q,)
        Named candidate (scan index) per query.
    scores : ndarray, shape (q,)
    correct : ndarray of bool, shape (q,)
    seconds : float
        CPU seconds of the whole log (features, descriptors, matching).
    """

    best: IArray
    scores: FArray
    correct: NDArray[np.bool_]
    seconds: float

    def curve(self, n_positive: int) -> PRCurve:
        """The method's precision-recall curve on this log."""
        return pr_curve(self.scores, self.correct, n_positive)


@dataclass(slots=True)
class LogLoops:
    """One log: its queries, every method's detections and the fingerprint map's scores."""

    name: str
    path: str
    positions: FArray
    queries: IArray
    positive: NDArray[np.bool_]
    window: str
    methods: dict[str, MethodLoops] = field(default_factory=dict)
    fingerprint_map: Any = None
    map_figures: dict[str, Any] = field(default_factory=dict)

    @property
    def n_positive(self) -> int:
        """Queries with a true match."""
        return int(np.count_nonzero(self.positive))

    def to_json(self) -> dict[str, Any]:
        """``{"scans", "queries", "positives", "window", "methods": {name: figures}, "fingerprint_map": {...}}``."""
        out: dict[str, Any] = {
            "scans": int(self.positions.shape[0]),
            "queries": int(self.queries.size),
            "positives": self.n_positive,
            "window": self.window,
            "methods": {
                k: {**loop_metrics(v.curve(self.n_positive)), "seconds": v.seconds} for k, v in self.methods.items()
            },
        }
        if self.map_figures:
            out["fingerprint_map"] = dict(self.map_figures)
        return out


@dataclass(slots=True)
class LoopBenchmark:
    """Every log of one run; :meth:`to_json` gives ``bench loops --json``'s layout."""

    logs: list[LogLoops]
    method_names: list[str]
    distance_m: float
    exclude_s: float
    exclude_scans: int

    def pooled_curve(self, method: str) -> PRCurve:
        """The method's curve over every log's queries (each query weighs the same)."""
        runs = [(lg.methods[method], lg) for lg in self.logs if method in lg.methods]
        scores = np.concatenate([r.scores for r, _ in runs]) if runs else np.zeros(0)
        correct = np.concatenate([r.correct for r, _ in runs]) if runs else np.zeros(0, bool)
        return pr_curve(scores, correct, sum(lg.n_positive for _, lg in runs))

    def to_json(self) -> dict[str, Any]:
        """``{"logs": {name: ...}, "pooled": {"queries", "positives", "methods"}, "protocol": {...}}``."""
        pooled_map: dict[str, Any] = {}
        maps = [lg.map_figures for lg in self.logs if lg.map_figures]
        if maps:
            views = sum(m["mapping_views"] for m in maps)
            queries = sum(m.get("map_queries", 0) for m in maps)
            pooled_map = {
                "places": sum(m["places"] for m in maps),
                "pose_places": sum(m["pose_places"] for m in maps),
                "purity": sum(m["purity"] * m["mapping_views"] for m in maps) / views if views else float("nan"),
                "map_queries": queries,
                **{
                    k: sum(m[k] * m["map_queries"] for m in maps if m.get("map_queries")) / queries
                    if queries
                    else float("nan")
                    for k in ("localize_top1", "track_top1")
                },
            }
        pooled: dict[str, Any] = {
            "queries": sum(int(lg.queries.size) for lg in self.logs),
            "positives": sum(lg.n_positive for lg in self.logs),
            "methods": {
                m: {
                    **loop_metrics(self.pooled_curve(m)),
                    "seconds": sum(lg.methods[m].seconds for lg in self.logs if m in lg.methods),
                }
                for m in self.method_names
            },
        }
        if pooled_map:
            pooled["fingerprint_map"] = pooled_map
        return {
            "logs": {lg.name: lg.to_json() for lg in self.logs},
            "pooled": pooled,
            "protocol": {
                "distance_m": self.distance_m,
                "exclude_s": self.exclude_s,
                "exclude_scans_without_timestamps": self.exclude_scans,
                "purity_radius_m": _purity_radius(),
                "detection": "best candidate per query; true when within distance_m of the query",
            },
        }


def _purity_radius() -> float:
    from ..pipeline.topology import PURITY_RADIUS_M

    return PURITY_RADIUS_M


def _map_figures(run: Any, positions: FArray) -> tuple[Any, dict[str, Any]]:
    """The fingerprint map of a log and its scores against the poses (module docstring)."""
    from ..pipeline.places import places_from_trajectory
    from ..pipeline.topology import PURITY_RADIUS_M, place_purity, places_from_fingerprints

    fm = places_from_fingerprints(run, consensus=False)
    pose_places = places_from_trajectory(positions).n_places
    figures = {
        "places": fm.n_places,
        "pose_places": int(pose_places),
        "purity": place_purity(fm.assignment, positions[: fm.n_mapping], PURITY_RADIUS_M),
        "loop_closures": int(fm.closures.shape[0]),
        "keyframes": int(fm.keyframes.size),
        "mapping_views": int(fm.n_mapping),
        **_map_localization(fm, run, positions, PURITY_RADIUS_M),
    }
    return fm, figures


def _map_localization(fm: Any, run: Any, positions: FArray, radius: float) -> dict[str, Any]:
    """How the map made from fingerprints localizes the rest of the log, scored against the poses.

    A *query* is a scan after the mapping part lying within ``radius`` of some
    place's median position (the median of its views' positions); an answer is
    right when the place it names is such a place. ``localize_top1``: the
    single-shot answer (``fingerloc localize``); ``track_top1``: the place
    filter's (``fingerloc track --filter places``, every scan observing).
    """
    from ..pipeline.calibration import posterior_columns

    p = fm.n_places
    pos_map = positions[: fm.n_mapping]
    med = np.array([np.median(pos_map[fm.assignment == j], axis=0) for j in range(p)]).reshape(-1, 2)
    steps = np.arange(fm.n_mapping, positions.shape[0])
    if steps.size == 0 or p == 0:
        return {"map_queries": 0, "localize_top1": float("nan"), "track_top1": float("nan")}
    d = np.hypot(positions[steps, None, 0] - med[None, :, 0], positions[steps, None, 1] - med[None, :, 1])
    near = d <= radius
    answerable = near.any(axis=1)
    pm = fm.place_map()
    obs = run.observations(steps, features=fm.preset.features)
    single = np.argmax(posterior_columns(pm.model, obs, p, pm.labels), axis=1)
    res = pm.track(run, filter="places")
    col = {lab: j for j, lab in enumerate(pm.labels)}
    tracked = np.array([col[a.place] for a in res.answers], dtype=np.int64)
    rows = np.flatnonzero(answerable)
    if tracked.size != steps.size or rows.size == 0:
        return {"map_queries": int(rows.size), "localize_top1": float("nan"), "track_top1": float("nan")}
    return {
        "map_queries": int(rows.size),
        "localize_top1": float(np.mean(near[rows, single[rows]])),
        "track_top1": float(np.mean(near[rows, tracked[rows]])),
    }


def run_loop_benchmark(
    paths: Sequence[str | Path],
    methods: Sequence[str] | None = None,
    *,
    distance_m: float = DISTANCE_M,
    exclude_s: float = EXCLUDE_S,
    exclude_scans: int = EXCLUDE_SCANS,
    fingerprint_map: bool = True,
    skip_bad: bool = False,
    on_progress: Callable[[str], None] | None = None,
) -> LoopBenchmark:
    """Run the loop-closure protocol (module docstring) on laser logs with poses.

    Parameters
    ----------
    paths : sequence of path
        CARMEN logs (or bags with poses).
    methods : sequence of str, optional
        Names of :data:`LOOP_METHODS` (default :data:`DEFAULT_LOOP_METHODS`).
    distance_m, exclude_s, exclude_scans
        ``D``, ``T`` and the window without timestamps.
    fingerprint_map : bool, default True
        Also make and score each log's fingerprint map.
    skip_bad : bool, default False
        Skip malformed log lines.
    on_progress : callable, optional
        Called with a short text before each log and method.

    Returns
    -------
    LoopBenchmark
    """
    from ..pipeline.readers import read_run
    from .protocol import log_name

    if not paths:
        raise InvalidParameterError("at least one log is needed")
    if not (isinstance(distance_m, (int, float)) and math.isfinite(distance_m) and distance_m > 0):
        raise InvalidParameterError(f"distance_m must be a positive number of metres, got {distance_m!r}")
    names = list(DEFAULT_LOOP_METHODS) if not methods else list(dict.fromkeys(methods))
    for m in names:
        if m not in LOOP_METHODS:
            raise InvalidParameterError(f"unknown method {m!r} (known: {', '.join(LOOP_METHODS)})")
    candidate_window(0, exclude_s=exclude_s, exclude_scans=exclude_scans)  # the options' checks, before any read
    note = on_progress or (lambda s: None)
    detectors = _loop_methods()
    logs: list[LogLoops] = []
    seen: dict[str, int] = {}
    for path in paths:
        name = log_name(path)
        seen[name] = seen.get(name, 0) + 1
        name = name if seen[name] == 1 else f"{name}#{seen[name]}"
        note(f"{name}: reading")
        run = read_run(path, skip_bad=skip_bad)
        poses = run.poses
        if poses is None or run.scans is None:
            raise InvalidParameterError(
                f"{path}: the loop-closure benchmark needs laser scans with poses (the ground truth)"
            )
        pos = poses[:, :2]
        eligible, window = candidate_window(len(run), run.timestamps, exclude_s=exclude_s, exclude_scans=exclude_scans)
        queries, positive = loop_truth(pos, eligible, distance_m)
        lg = LogLoops(name, str(path), pos, queries, positive, window)
        for m in names:
            note(f"{name}: {m}")
            t0 = time.process_time()
            best, score = detectors[m](run.scans, run, eligible)
            secs = time.process_time() - t0
            b = best[queries]
            ok = np.zeros(queries.size, dtype=bool)
            named = b >= 0
            d = np.hypot(*(pos[b[named]] - pos[queries[named]]).T) if named.any() else np.zeros(0)
            ok[named] = d <= distance_m
            lg.methods[m] = MethodLoops(b, np.where(named, score[queries], -np.inf), ok, secs)
        if fingerprint_map:
            note(f"{name}: fingerprint map")
            lg.fingerprint_map, lg.map_figures = _map_figures(run, pos)
        logs.append(lg)
    return LoopBenchmark(logs, names, float(distance_m), float(exclude_s), int(exclude_scans))
