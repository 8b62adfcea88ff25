"""The kidnapped-robot experiment on CARMEN logs (``fingerloc bench kidnap``).

:func:`prepare_tracking` fits a filtered method of the real-log benchmark
(:mod:`fingerloc.experiments.filtered`) on a log's mapping pass and lays out
its query pass as steps (:class:`TrackingData`); :func:`kidnap_experiment`
splices two distant stretches of the query pass and counts the steps the
filter needs to recover (either filter), against a second never-kidnapped
run (the floor: what the column can show for a filter that draws random numbers).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._types import FArray, IArray
from ..config import Config
from ..errors import InvalidParameterError
from ..map.filter import FilterResult, run_filter
from ..sensors import Scan
from ..validation import check_random_state
from .filtered import BENCH_POSE, FilteredMethod, PoseFilteredMethod, full_poses
from .protocol import make_split, rank_metrics, true_place_ranks

__all__ = [
    "MERGED_TV",
    "KidnapResult",
    "TrackingData",
    "kidnap_experiment",
    "nearest_cells",
    "prepare_tracking",
    "run_kidnap",
    "tracking_ranks",
    "with_synthetic_likelihood",
]

#: Total-variation distance below which two posteriors count as merged (kidnapping forgotten).
MERGED_TV = 0.1


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
    scans: Sequence[Scan],
    base: str = "fingerprint",
    *,
    pose: bool = False,
    config: Config | None = None,
    **options: Any,
) -> TrackingData:
    """Split a log (benchmark protocol), fit ``FilteredMethod(base, config)`` (``pose``:
    :class:`~fingerloc.experiments.filtered.PoseFilteredMethod` with ``options``) and score its queries, as
    ``bench carmen`` does (a verifying base maps the log's mapping pass)."""
    pos = full_poses(scans)[:, :2]
    split = make_split(pos)
    if split.n_queries == 0:
        raise InvalidParameterError("the log's query pass has no scan within a place's radius")
    from .shared import shared_results
    from .verify import mapping_context

    m = PoseFilteredMethod(base, config, **options) if pose else FilteredMethod(base, config, **options)
    queries = [scans[i] for i in split.query_idx.tolist()]
    with shared_results(), mapping_context(scans, split):  # as bench carmen fits and scores (the same answers)
        m.fit_log(scans, split)
        qs = np.asarray(m.base_.score(queries), dtype=np.float64)
    ll, dist = m.step_log_likelihoods(qs)
    truth = np.full(split.n_scans - split.n_mapping, -1, dtype=np.int64)
    truth[split.query_idx - split.n_mapping] = split.query_labels
    inc = getattr(m, "increments_", None)
    steps_inc = None if inc is None else np.vstack([np.zeros((1, 3)), inc])
    hd = pts = None
    if isinstance(m, PoseFilteredMethod):
        m._before_score(queries)
        hd = m.step_headings_
        pts = m.step_points()
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

        What is recovery and what is noise (added fields):

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
    method's defaults: :class:`~fingerloc.map.driver.PoseTracking`)
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
        opts: dict[str, Any] = {}
        config = None
        if pose:
            opts = {"seed": seed, "odometry_error": odometry_error}
            changes = {k: v for k, v in (("hold_margin", hold_margin), ("tie_break", tie_break)) if v is not None}
            config = BENCH_POSE.with_(calibration={"scan": scan, "kidnap": kidnap}, pose_filter=changes)
        data = prepare_tracking(scans, base, pose=pose, config=config, **opts)
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
