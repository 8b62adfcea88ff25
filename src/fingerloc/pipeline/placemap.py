"""A place map: the model, its places and graph, what it learned and how it tracks (the library's front door).

:func:`fingerloc.make_map` makes one from a run's poses, :func:`load_map`
reads one from a place database; both give a :class:`PlaceMap`::

    import fingerloc as fl
    run = fl.read_run("robot-run.log.gz")
    pm = fl.make_map(run)
    pm.save("places.sqlite")
    pm = fl.load_map("places.sqlite")
    pm.localize(run).summary             # what `fingerloc localize --json` writes as "summary"
    result = pm.track(run, filter="pose")
    result.summary                       # what `fingerloc track --json` writes as "summary"
    tracker = pm.tracker()               # live: tracker.step(scan, odometry=pose, stamp=t)

The command line calls these methods: the same run and seed give the same
numbers from Python and from the shell.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._types import FArray, IArray
from ..config import Config
from ..errors import InvalidParameterError
from ..map.filter import FilterResult, TransitionModel
from ..map.graph import PlaceGraph
from ..metrics import rank_metrics, true_place_ranks
from .calibration import Calibration, implied_headings, posterior_columns, read_calibration, stored_calibration
from .filters import place_transition_of
from .places import nearest_within
from .presets import ResolvedPreset
from .readers import Run
from .tracker import FILTERS, Answer, Tracker, end_points_of, scaled

if TYPE_CHECKING:
    from ..map.scan_map import ScanMap
    from ..observation import Observation
    from .places import PlaceSplit

__all__ = ["LocalizeResult", "PlaceMap", "TrackResult", "check_track_options", "load_map", "store_graph"]

Note = Callable[[str], None]


def _quiet(_: str) -> None:
    return None


@dataclass(slots=True)
class TrackResult:
    """A run tracked by either filter (:meth:`PlaceMap.track`).

    Attributes
    ----------
    answers : list of Answer
        One per step, in run order.
    summary : dict
        What ``fingerloc track --json`` writes as ``"summary"``: steps, the calibration
        used, the filtered and single-shot top-1 / mean rank of the labelled observed steps.
    result : FilterResult
        The answers as arrays (log-posterior, best place, its probability, entropy).
    log_likelihood : ndarray, shape (n_steps, P)
        The single-shot ``log P(place | view)`` per step, unscaled (NaN rows: no observation).
    truth : ndarray of int, shape (n_steps,)
        The true place's column per step (-1: unknown).
    places : list of str
        The columns' places.
    poses : ndarray, shape (n_steps, 3) or None
        The run's poses of the tracked steps (metres, radians).
    centres : ndarray, shape (P, 2) or None
        The place centres.
    odometry_error : float
        The factor of the simulated wheel-odometry errors (pose filter).
    """

    answers: list[Answer]
    summary: dict[str, Any]
    result: FilterResult
    log_likelihood: FArray
    truth: IArray
    places: list[str]
    poses: FArray | None = None
    centres: FArray | None = None
    odometry_error: float = 0.0

    @property
    def steps(self) -> list[dict[str, Any]]:
        """Every step's record of ``track --json``."""
        return [a.to_json() for a in self.answers]

    def summary_lines(self) -> list[str]:
        """The summary in words (what ``fingerloc track`` prints last): the scores of the labelled observed steps
        when there are any, then the filter and the calibration it used."""
        s = self.summary
        f, single = s["filtered"], s["single_shot"]
        lines = []
        if f.get("labelled"):
            lines.append(
                f"{f['labelled']} labelled observed steps: filtered top-1 {f['top1']:.3f}, mean rank {f['mean_rank']:.2f}; "
                f"single-shot top-1 {single['top1']:.3f}, mean rank {single['mean_rank']:.2f}"
            )
        head = f"{s['steps']} steps ({s['observed_steps']} observed), {s['places']} places, beta {s['likelihood_scale']:.3g}, "
        if s["filter"] == "pose":
            gamma = s.get("scan_gamma")
            evidence = "" if not gamma else f", scan evidence gamma {gamma:g}"
            return [*lines, head + f"pose filter (odometry increments, error factor {self.odometry_error:g}{evidence})"]
        metres = s["metres_per_move"]
        if s.get("transitions") == "metric":
            odometry = "metric transitions over the place positions (the place spacing, widened by the distance travelled)"
        else:
            odometry = "odometry off" if metres is None else f"odometry {metres:.2f} m per place change"
        lines.append(head + f"uniform mixing {s['uniform_mix']:.3g}, {odometry}")
        if s.get("place_filter"):
            lines.append(str(s["place_filter"]))
        return lines


@dataclass(slots=True)
class LocalizeResult:
    """Single-shot answers for every observation (:meth:`PlaceMap.localize`).

    Attributes
    ----------
    answers : list of dict
        The records ``fingerloc localize --json`` writes under ``"observations"``.
    summary : dict
        ``{"n", "top1", "mean_rank"}`` over the labelled observations (None without any).
    preset : str or None
    observations : list of Observation
    log_posterior : ndarray, shape (n, P)
        Columns: the model's places (``model.classes_``).
    """

    answers: list[dict[str, Any]]
    summary: dict[str, Any]
    preset: str | None
    observations: list[Observation]
    log_posterior: FArray


@dataclass(slots=True)
class _Steps:
    """A run laid out as tracking steps: scores of the observed ones, truth, poses, names."""

    ll: FArray
    truth: IArray
    poses: FArray | None
    names: list[str]
    headings: FArray | None = None
    points: list[Any] | None = None
    unknown: FArray | None = None


@dataclass(slots=True)
class PlaceMap:
    """A place map (module docstring): what ``fingerloc map`` stores in a place database.

    Attributes
    ----------
    model : PlaceModel
        The fitted place model (its places: ``model.classes_``).
    labels : list of str
        The places in the filters' order (creation order for a map made from poses).
    positions : ndarray, shape (P, 2) or None
        Place centres in the run's frame, metres (``None``: a database made by ``learn``).
    preset : ResolvedPreset or None
        The sensor preset and every resolved model option.
    calibration : Calibration or None
        What the filters learned on the mapping part.
    config : Config
        The settings the map was made with (and tracks with).
    graph : PlaceGraph
        The place graph, places in ``labels`` order.
    runs : list of dict
        The mapped runs: ``{"name", "key", "n_scans", "n_mapping"}``.
    content_hashes : set of str
        Hashes of every stored observation (``learn`` skips those it holds).
    scan_map : ScanMap or None
        The mapping part's laser end points (``None``: none).
    split : PlaceSplit or None
        A map just made: its places, training scans and queries (indices into the run).
    training : list of Observation or None
        A map just made: the labelled training observations, in run order.
    tuning : list of dict
        A map just made: every setting the calibration tried on the mapping part.
    """

    model: Any
    labels: list[str]
    positions: FArray | None
    preset: ResolvedPreset | None
    calibration: Calibration | None
    config: Config
    graph: PlaceGraph
    runs: list[dict[str, Any]] = field(default_factory=list)
    content_hashes: set[str] = field(default_factory=set)
    scan_map: ScanMap | None = None
    split: PlaceSplit | None = None
    training: list[Observation] | None = None
    tuning: list[dict[str, float]] = field(default_factory=list)

    # -- what it holds ----------------------------------------------------------------------------

    @property
    def has_positions(self) -> bool:
        """True for a map made from poses: place positions and a calibration."""
        return self.positions is not None and self.calibration is not None

    def default_filter(self, run: Run | None = None) -> tuple[str, str]:
        """The best filter this map and ``run`` allow, and why: ``("pose", reason)`` or ``("places", reason)``.

        The pose filter (it follows the odometry's direction and turn, and the
        map's scan evidence) when the map has place positions and a
        calibration and the run has a pose (odometry) at every step; the
        filter over places otherwise (it needs only the travelled distance,
        or nothing).
        """
        if not self.has_positions:
            return "places", "filter: places (the map has no place positions: the pose filter needs a map made from poses)"
        if run is not None and run.poses is None:
            return "places", "filter: places (the run has no poses or odometry: the pose filter needs them)"
        return "pose", "filter: pose (the map has place positions and the run has poses: the pose filter follows the odometry)"

    @property
    def position_dict(self) -> dict[str, tuple[float, float]]:
        """Place centres by label (empty without positions)."""
        if self.positions is None:
            return {}
        return {lab: (float(x), float(y)) for lab, (x, y) in zip(self.labels, self.positions, strict=True)}

    def mapped_run(self, key: str) -> dict[str, Any] | None:
        """The stored mapped run with this content key (:attr:`Run.key`), if any."""
        return next((r for r in self.runs if r.get("key") == key), None)

    # -- the database -----------------------------------------------------------------------------

    def save(self, path: str | Path) -> int:
        """Write the map to a place database (replacing the file); returns its size in bytes."""
        from ..map.database import MapInfo, save_model

        info = MapInfo(
            preset=None if self.preset is None else self.preset.to_json(),
            positions=self.position_dict,
            calibration=None if self.calibration is None else stored_calibration(self.calibration, self.config),
            content_hashes=set(self.content_hashes),
            runs=list(self.runs),
            scan_map=self.scan_map,
        )
        return save_model(self.model, path, graph_edges=self.graph.edges(), info=info)

    # -- single shot --------------------------------------------------------------------------------

    def queries(self, run: Run, *, on_note: Note | None = None) -> tuple[list[Observation], list[str]]:
        """The observations ``localize`` answers for a run, with their names.

        JSON Lines: every observation as it is. A laser log or bag: its scans
        through the map's preset; with poses and place positions, only the
        scans within the map's radius of a place, labelled with the nearest
        (on the run the map was made from, only those after its mapping part).
        ``on_note`` hears what was chosen and why.
        """
        note = on_note or _quiet
        if run.records is not None:
            return list(run.records), list(run.names)
        features = {} if self.preset is None else self.preset.features
        poses = run.poses
        if poses is None or not self.has_positions:
            why = "its scans have no poses" if poses is None else "the database has no place positions"
            note(f"{run.paths[0]}: {why}: every scan is a query, unlabelled")
            return run.observations(features=features), list(run.names)
        assert self.positions is not None and self.calibration is not None
        start = self._start(run, "querying", note)
        idx, near = nearest_within(poses[start:, :2], self.positions, self.calibration.radius)
        idx = idx + start
        obs = [o.with_label(self.labels[j]) for o, j in zip(run.observations(idx, features=features), near.tolist(), strict=True)]
        note(f"{idx.size} scan(s) within {self.calibration.radius:g} m of a place are the queries")
        return obs, [run.names[i] for i in idx.tolist()]

    def _start(self, run: Run, verb: str, note: Note) -> int:
        """The first step of a run worth answering: after the mapping part on the run the map was made from."""
        mapped = self.mapped_run(run.key)
        if mapped is None:
            return 0
        start = int(mapped["n_mapping"])
        note(f"{run.paths[0]} is the run the map was made from: {verb} its scans after the mapping part "
             f"(from scan {start} of {len(run)})")  # fmt: skip
        return start

    def localize(self, data: Run | Sequence[Observation], *, top: int = 3, on_note: Note | None = None) -> LocalizeResult:
        """The posterior over places of every observation (or query scan) of ``data``: ``localize --json``."""
        from .localize import LOCALIZE_CHUNK, answer_chunk

        if isinstance(data, Run):
            obs, names = self.queries(data, on_note=on_note)
        else:
            obs = list(data)
            names = [f"#{i}" for i in range(len(obs))]
        records: list[dict[str, Any]] = []
        ranks: list[int] = []
        logp = []
        for s in range(0, len(obs), LOCALIZE_CHUNK):
            a = answer_chunk(self.model, obs[s : s + LOCALIZE_CHUNK], names[s:], s, top, table=False, records=True, keep=True)
            records += [json.loads(r) for r in a.records]
            ranks += [r for r in a.rank_of_true if r > 0]
            logp.append(a.logp)
        summary: dict[str, Any] = {"n": len(obs), "top1": None, "mean_rank": None}
        if ranks:
            summary["top1"] = float(np.mean(np.array(ranks) == 1))
            summary["mean_rank"] = float(np.mean(ranks))
        lp = np.vstack(logp) if logp else np.zeros((0, len(self.model.classes_)))
        return LocalizeResult(records, summary, None if self.preset is None else self.preset.name, obs, lp)

    # -- tracking -----------------------------------------------------------------------------------

    def tracker(
        self,
        *,
        filter: str = "pose",
        seed: int = 0,
        scan: bool = True,
        heading: bool = True,
        beta: float | None = None,
        metres_per_move: float | None = None,
        alpha: float | None = None,
        uniform_mix: float | None = None,
        scan_gamma: float | None = None,
        odometry_error: float = 0.0,
    ) -> Tracker:
        """A streaming :class:`~fingerloc.pipeline.tracker.Tracker` over this map's places.

        Parameters
        ----------
        filter : {"pose", "places"}, default "pose"
            The pose filter needs place positions (a map made by ``fingerloc map``).
        seed : int, default 0
            The pose filter's particles.
        scan, heading : bool, default True
            Use the map's scan evidence and heading model (when it has them).
        beta, metres_per_move, alpha, uniform_mix, scan_gamma : optional
            Override the calibration's likelihood scale, metres per place change,
            the transition counts' smoothing, the uniform mixing per step, the
            scan evidence's power.
        odometry_error : float, default 0
            Simulated wheel-odometry errors on the increments between the odometry
            poses the steps give, times this factor (replaying a log of corrected poses).
        """
        if filter not in FILTERS:
            raise InvalidParameterError(f"filter must be one of {', '.join(FILTERS)}, got {filter!r}")
        cal = self.calibration if self.calibration is not None else Calibration()
        cfg = self.config
        if beta is not None:
            cal = replace(cal, beta=float(beta))
        if metres_per_move is not None:
            cal = replace(cal, metres_per_move=float(metres_per_move))
        if scan_gamma is not None:
            cal = replace(cal, scan_gamma=float(scan_gamma))
        if alpha is not None:
            cfg = cfg.with_(pose_filter={"alpha": float(alpha)})
        if filter == "pose" and not self.has_positions:
            raise InvalidParameterError(
                "the pose filter needs place positions and a calibration: make the database with 'fingerloc map' "
                "(or track JSON Lines with --graph-from)"
            )
        transition = None
        if uniform_mix is not None and filter == "places" and self.positions is not None:
            transition = place_transition_of(self.graph, cal, cfg, self.positions, uniform_mix=uniform_mix)
        elif uniform_mix is not None and self.graph.graph.number_of_edges() > 0:
            transition = TransitionModel.from_graph(
                self.graph, alpha=cfg.pose_filter.alpha, uniform_mix=uniform_mix, metres_per_move=cal.metres_per_move
            )
        return Tracker(
            self.model, self.labels, self.graph, cal, cfg, centres=self.positions, filter=filter,
            features=None if self.preset is None else dict(self.preset.features), seed=seed,
            scan_map=self.scan_map if scan else None, heading=heading, transition=transition,
            odometry_error=odometry_error,
        )  # fmt: skip

    def _steps(self, run: Run, *, filter: str, observe: str, use_scan: bool, use_heading: bool, note: Note) -> _Steps:
        """The run as tracking steps (the observed ones scored in one batch)."""
        p = len(self.labels)
        features = {} if self.preset is None else dict(self.preset.features)
        poses = run.poses
        if run.records is not None and (poses is None or all(o.label for o in run.records)):
            # JSON Lines: every observation observes; the truth is its label
            col = {lab: j for j, lab in enumerate(self.labels)}
            truth = np.array([col.get(str(o.label), -1) if o.label else -1 for o in run.records], dtype=np.int64)
            obs = list(run.records)
            steps = _Steps(posterior_columns(self.model, obs, p, self.labels), truth, poses, list(run.names))
            if use_scan:
                steps.points = [end_points_of(o) for o in obs]
            if use_heading:
                steps.headings = implied_headings(self.model, obs, self.labels)
            return steps
        if filter == "places" and (poses is None or not self.has_positions):
            # the place filter needs neither: every scan observes, no true place is known
            start = self._start(run, "tracking", note)
            obs = run.observations(np.arange(start, len(run)), features=features)
            n = len(obs)
            return _Steps(posterior_columns(self.model, obs, p, self.labels), np.full(n, -1, dtype=np.int64),
                          None if poses is None else poses[start:], run.names[start:])  # fmt: skip
        if poses is None:
            raise InvalidParameterError(f"{run.paths[0]}: tracking a raw run needs a pose on every scan")
        if not self.has_positions:
            raise InvalidParameterError(
                f"{run.paths[0]}: the map has no place positions or calibration stored; make the database with "
                "'fingerloc map' (or track JSON Lines with --graph-from)"
            )
        assert self.positions is not None and self.calibration is not None
        start = self._start(run, "tracking", note)
        poses = poses[start:]
        near_idx, near = nearest_within(poses[:, :2], self.positions, self.calibration.radius)
        n = poses.shape[0]
        truth = np.full(n, -1, dtype=np.int64)
        truth[near_idx] = near
        observed = near_idx if observe == "queries" else np.arange(n)
        ll = np.full((n, p), np.nan)
        obs = run.observations(observed + start, features=features)
        ll[observed] = posterior_columns(self.model, obs, p, self.labels)
        steps = _Steps(ll, truth, poses, run.names[start:])
        if use_scan:
            pts: list[Any] = [None] * n
            for k, i in enumerate(observed.tolist()):
                pts[i] = end_points_of(run.scans[i + start] if run.scans is not None else obs[k])
            steps.points = pts
        if use_heading:
            steps.headings = np.full((n, p), np.nan)
            steps.headings[observed] = implied_headings(self.model, obs, self.labels)
        return steps

    def track(
        self,
        run: Run,
        *,
        filter: str = "pose",
        seed: int = 0,
        observe: str = "queries",
        odometry_error: float | None = None,
        scan: bool = True,
        heading: bool = True,
        beta: float | None = None,
        metres_per_move: float | None = None,
        alpha: float | None = None,
        uniform_mix: float | None = None,
        scan_gamma: float | None = None,
        on_note: Note | None = None,
    ) -> TrackResult:
        """Track a recorded run step by step: ``fingerloc track --json``.

        Parameters
        ----------
        run : Run
            A laser log or bag with poses (tracked against a map made from poses),
            or JSON Lines observations in order. The place filter also tracks a
            laser log or bag without poses, or against a map without place
            positions (a map made from fingerprints): every scan observes.
        filter : {"pose", "places", "auto"}, default "pose"
            ``auto``: :meth:`default_filter` (said through ``on_note``).
        seed : int, default 0
            Seeds the particles (``seed``) and the simulated odometry errors (``seed + 1``).
        observe : {"queries", "all"}, default "queries"
            A run with poses: only the scans within a place's radius observe (the
            others only predict), or every scan.
        odometry_error : float, optional
            Pose filter: simulated wheel-odometry errors on the poses' increments, times
            this factor (default 1 for CARMEN logs, whose poses are corrected ones; else 0).
        scan, heading, beta, metres_per_move, alpha, uniform_mix, scan_gamma
            :meth:`tracker`'s.
        on_note : callable, optional
            Hears what was chosen and why (one line each).

        Returns
        -------
        TrackResult
        """
        note = on_note or _quiet
        if filter == "auto":
            filter, why = self.default_filter(run)
            note(why)
        check_track_options(observe=observe, filter=filter, odometry_error=odometry_error, beta=beta,
                            metres_per_move=metres_per_move, alpha=alpha, uniform_mix=uniform_mix,
                            scan_gamma=scan_gamma)  # fmt: skip
        factor = 0.0
        if filter == "pose":
            factor = odometry_error if odometry_error is not None else (1.0 if run.kind == "carmen" else 0.0)
        tracker = self.tracker(filter=filter, seed=seed, scan=scan, heading=heading, beta=beta,
                               metres_per_move=metres_per_move, alpha=alpha, uniform_mix=uniform_mix,
                               scan_gamma=scan_gamma, odometry_error=factor)  # fmt: skip
        use_scan = tracker.uses_scan
        st = self._steps(run, filter=filter, observe=observe, use_scan=use_scan, use_heading=tracker.heading, note=note)
        n = st.ll.shape[0]
        if filter == "pose":
            if st.poses is None:
                raise InvalidParameterError("the pose filter needs a pose at every step")
            if odometry_error is None and factor:
                note("CARMEN poses are corrected ones: simulating wheel-odometry errors (--odometry-error 1)")
        rows = scaled(st.ll, tracker.calibration.beta)
        stamps = run.timestamps
        if stamps is not None:
            stamps = stamps[len(run) - n :]
        answers: list[Answer] = []
        for t in range(n):
            answers.append(
                tracker.step_scores(
                    rows[t],
                    odometry=None if st.poses is None else st.poses[t],
                    stamp=None if stamps is None else float(stamps[t]),
                    headings=None if st.headings is None else st.headings[t],
                    points=None if st.points is None else st.points[t],
                    truth=None if st.truth[t] < 0 else self.labels[int(st.truth[t])],
                    name=st.names[t],
                )
            )
        result = _result(answers, self.labels)
        gamma = None
        if filter == "pose":
            gamma = float(tracker.calibration.scan_gamma) if use_scan and st.points is not None else 0.0
        summary = _track_summary(st.ll, st.truth, result, tracker, filter, gamma)
        return TrackResult(answers, summary, result, st.ll, st.truth, list(self.labels), st.poses, self.positions, factor)

    def with_visits(self, observations: Sequence[Observation], *, radius: float | None = None) -> PlaceMap:
        """This map with the place graph, positions and odometry of labelled observations in visiting order.

        For a database made by ``learn`` (no positions): ``observations`` (e.g.
        the file given to ``learn``) give the place graph by their order and,
        when every one has a pose and every place has a view among them, the
        place positions (the mean of each place's view positions), the metres
        per place change and a calibration for the pose filter (radius: half
        the median distance to the nearest other centre unless given; the
        observations count fully after two radii of travel or the sensors'
        median field of view). The particles start from the start prior (as a
        run that begins at a known place). ``positions`` stays None without poses.
        """
        from ..map.filter import metres_per_move as _metres

        classes = list(self.labels)
        seq = [o.label for o in observations]
        bad = next((i for i, lab in enumerate(seq) if lab not in set(classes)), None)
        if bad is not None:
            raise InvalidParameterError(f"observation {bad + 1}: place {seq[bad]!r} is not in the map (every line needs a learned 'place')")
        g = PlaceGraph.from_sequence(classes, [str(lab) for lab in seq])
        out = replace(self, graph=g)
        if len(observations) < 2 or any(o.pose is None for o in observations):
            return out
        col = {c: j for j, c in enumerate(classes)}
        tp = np.array([o.pose for o in observations if o.pose is not None], dtype=np.float64)
        lab_idx = np.array([col[str(lab)] for lab in seq], dtype=np.int64)
        metres = _metres(tp[:, :2], lab_idx)
        base = self.calibration if self.calibration is not None else Calibration()
        out = replace(out, calibration=replace(base, metres_per_move=float(metres)))
        if not np.all(np.isin(np.arange(len(classes)), lab_idx)):
            return out
        centres = np.array([tp[lab_idx == j, :2].mean(axis=0) for j in range(len(classes))])
        r = radius
        if r is None:
            if centres.shape[0] < 2:
                raise InvalidParameterError("give a radius: one place has no spacing to take it from")
            d = np.linalg.norm(centres[:, None] - centres[None], axis=2)
            np.fill_diagonal(d, np.inf)
            r = 0.5 * float(np.median(d.min(axis=1)))
        fov = 2 * math.pi * float(np.median([o.fov_coverage() for o in observations]))
        cal = replace(
            out.calibration or base, radius=float(r), spacing=2.0 * float(r), temper_metres=2.0 * float(r),
            temper_radians=fov, kidnap=1.0 / (len(observations) + 2), n_train=len(observations), outlier=0.1,
            off_place=0.1, heading=None, scan_gamma=0.0, lost_fit=None, lost_kidnap=0.0,
        )  # fmt: skip
        cfg = self.config.with_(pose_filter={"start_at_first_observation": False, "gap_m": None, "strategy": "plain"})
        return replace(out, positions=centres, calibration=cal, config=cfg, scan_map=None)


def _result(answers: Sequence[Answer], labels: Sequence[str]) -> FilterResult:
    """The answers as a :class:`FilterResult`."""
    from ..map.filter import entropy_bits

    n = len(answers)
    col = {lab: j for j, lab in enumerate(labels)}
    lp = np.vstack([a.log_posterior for a in answers]) if n else np.zeros((0, len(labels)))
    best = np.array([col[a.place] for a in answers], dtype=np.int64)
    prob = np.array([a.probability for a in answers], dtype=np.float64)
    return FilterResult(lp, best, prob, entropy_bits(lp) if n else np.zeros(0))


def _summary(log_post: FArray, truth: IArray) -> dict[str, Any]:
    known = truth >= 0
    if not np.any(known):
        return {"labelled": 0}
    ranks = true_place_ranks(log_post[known], truth[known])
    return {"labelled": int(known.sum()), **rank_metrics(ranks)}


def _track_summary(ll: FArray, truth: IArray, result: FilterResult, tracker: Tracker, filter: str, gamma: float | None) -> dict[str, Any]:
    """``summary`` of ``track --json``: steps, the calibration used, filtered and single-shot figures."""
    single = np.where(np.isnan(ll), 0.0, ll)
    observed = ~np.all(np.isnan(ll), axis=1)
    t = np.where(observed, truth, -1)
    cal = tracker.calibration
    metres = cal.metres_per_move if tracker.transition.metric else tracker.transition.metres_per_move
    return {
        "steps": int(ll.shape[0]),
        "observed_steps": int(observed.sum()),
        "places": tracker.n_places,
        "likelihood_scale": cal.beta,
        "metres_per_move": metres,
        "uniform_mix": tracker.transition.uniform_mix,
        "filter": filter,
        **({} if gamma is None else {"scan_gamma": gamma}),
        **({"transitions": "metric" if tracker.transition.metric else "graph", "steps_aside": tracker.steps_aside,
            "place_filter": cal.place_filter_reason() or None} if filter == "places" else {}),
        "filtered": _summary(result.log_posterior, t),
        "single_shot": _summary(single, t),
    }


def check_track_options(
    *,
    observe: str = "queries",
    filter: str = "pose",
    odometry_error: float | None = None,
    radius: float | None = None,
    beta: float | None = None,
    metres_per_move: float | None = None,
    alpha: float | None = None,
    uniform_mix: float | None = None,
    scan_gamma: float | None = None,
) -> None:
    """Check :meth:`PlaceMap.track`'s options (``auto`` is also a ``filter`` here: the command line's default).

    Raises
    ------
    InvalidParameterError
        One line naming the option (as the command line spells it) and the value.
    """
    if observe not in ("queries", "all"):
        raise InvalidParameterError(f"--observe must be 'queries' or 'all', got {observe!r}")
    if filter not in (*FILTERS, "auto"):
        raise InvalidParameterError(f"--filter must be 'pose', 'places' or 'auto', got {filter!r}")
    for flag, v in (("--odometry-error", odometry_error), ("--alpha", alpha), ("--scan-gamma", scan_gamma)):
        if v is not None and not (math.isfinite(v) and v >= 0):
            raise InvalidParameterError(f"{flag} must be a finite number >= 0, got {v!r}")
    if odometry_error is not None and odometry_error > 100:  # a factor on the odometry's simulated errors
        raise InvalidParameterError(f"--odometry-error must be a factor in [0, 100], got {odometry_error!r}")
    for flag, v in (("--radius", radius), ("--scale", beta), ("--metres-per-move", metres_per_move)):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise InvalidParameterError(f"{flag} must be a positive number, got {v!r}")
    if uniform_mix is not None and not (0 <= uniform_mix < 1):
        raise InvalidParameterError(f"--uniform-mix must be in [0, 1), got {uniform_mix!r}")


def load_map(path: str | Path, *, scan: bool = True) -> PlaceMap:
    """Read a place database (any readable schema version) as a :class:`PlaceMap`.

    ``scan``: read the stored scan map too (False: ``scan_map`` is None).
    """
    from ..map.database import load_model, observation_hash, read_map_info
    from ..map.graph import load_graph

    model = load_model(path)
    info = read_map_info(path, scan_map=scan)
    classes = [str(c) for c in model.classes_]
    positions = None
    labels = classes
    if info.positions and set(info.positions) == set(classes):  # places learned later have no position
        labels = list(info.positions)
        positions = np.array([info.positions[lab] for lab in labels], dtype=np.float64).reshape(-1, 2)
    preset = None if info.preset is None else ResolvedPreset.from_json(info.preset)
    cal, cfg = (None, Config()) if info.calibration is None else read_calibration(info.calibration)
    if positions is None and cal is not None:  # learned from labels: no odometry unless the visits give it
        cal = replace(cal, metres_per_move=None)
    graph = load_graph(path, labels)
    hashes = info.content_hashes
    if not hashes:  # version 1: hash the stored observations
        hashes = {observation_hash(o) for p in model.places_.values() for o in p.observations}
    return PlaceMap(model, labels, positions, preset, cal, cfg, graph, info.runs, hashes, info.scan_map)


def store_graph(path: str | Path, edges: dict[tuple[str, str], int]) -> None:
    """Replace the place graph stored in a place database (everything else kept as it is)."""
    from ..map.database import load_model, locked, read_map_info, save_model

    with locked(path):  # the read and the write as one: a concurrent writer's places are kept
        save_model(load_model(path), path, graph_edges=edges, info=read_map_info(path))
