"""``fingerloc track`` (Markov localization along a trajectory) and ``fingerloc bench kidnap`` (issue 8)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from .._lazy import LazyModule
from ..errors import InvalidParameterError
from ._io import all_or_nothing, check_output, warn
from .app import app, bench_app, console, err_console
from .bench import write_json

if TYPE_CHECKING:
    import numpy as np
else:
    np = LazyModule("numpy")  # imported when a command runs, not for --help
from .options import (
    BASE_FRAME_OPTION,
    KIND_OPTION,
    LOCK_TIMEOUT_OPTION,
    POSE_SOURCE_OPTION,
    SKIP_BAD_OPTION,
    TOPIC_OPTION,
    bag_options,
    check_db_target,
    read_run_files,
)

compat = LazyModule("fingerloc.pipeline.compat")


def _summary(best: np.ndarray, log_post: np.ndarray, truth: np.ndarray) -> dict[str, Any]:
    from ..experiments.protocol import rank_metrics, true_place_ranks

    known = truth >= 0
    if not np.any(known):
        return {"labelled": 0}
    ranks = true_place_ranks(log_post[known], truth[known])
    return {"labelled": int(known.sum()), **rank_metrics(ranks)}


@app.command("track")
@all_or_nothing  # outputs renamed together at the end, the database's writer lock held to the end
def track_cmd(
    data: Path = typer.Argument(..., help="A run in order: JSON Lines, a CARMEN log or a ROS bag."),
    db: Path = typer.Option(..., "--db", help="Place database ('fingerloc map', or 'learn' with the place graph)."),
    json_out: Path | None = typer.Option(None, "--json", help="Write every step's posterior summary as JSON here."),
    map_log: bool = typer.Option(
        False,
        "--map",
        help="CARMEN log or bag: first make the map from its mapping part into --db ('fingerloc map' with its "
        "defaults), then track the rest.",
    ),
    overwrite: bool = typer.Option(False, "--overwrite", help="With --map: replace --db if it exists."),
    observe: str = typer.Option(
        "queries",
        help="Log or bag with poses: 'queries' (scans within a place's radius observe, the others only predict, as "
        "in 'bench carmen') or 'all'.",
    ),
    scale: float | None = typer.Option(
        None, help="Likelihood scale beta [the database's calibration; JSON Lines without one: 1]."
    ),
    metres_per_move: float | None = typer.Option(
        None,
        "--metres-per-move",
        help="Odometry: mean metres per place change [the database's calibration; JSON Lines: from --graph-from poses, else off].",
    ),
    uniform_mix: float | None = typer.Option(None, help="Uniform mixing per step [1 / (counted steps + 2)]."),
    alpha: float = typer.Option(1.0, help="Additive smoothing of the transition counts."),
    graph_from: Path | None = typer.Option(
        None,
        "--graph-from",
        help="JSON Lines: labelled observations in the order the robot passed them (e.g. the file given to "
        "'learn'); their consecutive places give the graph, stored into --db (and odometry when they have poses).",
    ),
    filter_kind: str = typer.Option(
        "places",
        "--filter",
        help="'places': discrete filter over the places; 'pose': particle filter over the robot's pose with the "
        "odometry increments (needs poses, and place positions: a database made by 'fingerloc map', or "
        "JSON Lines with --graph-from, both with poses).",
    ),
    odometry_error: float | None = typer.Option(
        None,
        "--odometry-error",
        help="Pose filter: simulate wheel-odometry errors on the poses' increments, times this factor (0 = the "
        "poses' own increments) [CARMEN logs: 1, their poses are corrected ones, as in 'bench carmen'; else 0].",
    ),
    radius: float | None = typer.Option(
        None, help="Pose filter, JSON Lines with --graph-from: metres within which a pose is at a place [half the median spacing]."
    ),
    seed: int = typer.Option(0, min=0, help="Pose filter: seed of the particles (and of simulated odometry errors)."),
    heading: bool = typer.Option(
        True,
        "--heading/--no-heading",
        help="Pose filter with a database made by 'fingerloc map': weigh the particles also by the heading each view "
        "implies (the alignment against the place's best view, and that view's recorded heading), with the heading "
        "model the map fitted on its mapping part (when it has one: 'map' fits it by default).",
    ),
    scan: bool = typer.Option(
        True,
        "--scan/--no-scan",
        help="Pose filter with a database made by 'fingerloc map': weigh the particles also by how well each "
        "scan's laser end points fit the map's (its scan map, with the power scan_gamma of its calibration; "
        "with --map: store the scan map too).",
    ),
    scan_gamma: float | None = typer.Option(
        None, "--scan-gamma", help="Pose filter: power of the scan evidence (0 = off) [the database's calibration]."
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print only the summary."),
    report: Path | None = typer.Option(
        None, "--report", help="Write a report folder here: index.html (open it in a browser) and its figures."
    ),
    kind: str = KIND_OPTION,
    topic: list[str] | None = TOPIC_OPTION,
    pose_source: str = POSE_SOURCE_OPTION,
    base_frame: str | None = BASE_FRAME_OPTION,
    skip_bad: bool = SKIP_BAD_OPTION,
    lock_timeout: float = LOCK_TIMEOUT_OPTION,
) -> None:
    """Filter the posterior over places along a sequence of observations.

    Per step: the best place, its probability and the posterior's entropy
    (bits); with known places, the filtered and single-shot top-1 and mean
    rank of the true place. ``--filter places`` (default) is the discrete
    Bayes filter on the place graph; ``--filter pose`` the particle filter of
    ``fingerloc.map.pose_filter``, which follows the odometry's direction and
    turn, not only the distance. With a database made by 'fingerloc map',
    both use its calibration (likelihood scale, metres per place change,
    tempering, kidnapping probability).
    """
    from .reports import check_report, track_report

    check_report(report)
    _check_options(observe, filter_kind, odometry_error, radius, scale, metres_per_move, alpha, uniform_mix)
    if scan_gamma is not None and not (math.isfinite(scan_gamma) and scan_gamma >= 0):
        raise InvalidParameterError(f"--scan-gamma must be a finite number >= 0, got {scan_gamma!r}")
    check_output(json_out, "--json")
    bag = bag_options(topic, pose_source, base_frame)
    raw_kind = _check_db_flags(data, db, kind, map_log, graph_from, overwrite)
    # writes to --db wait until every check and the filter have passed: a failed command changes nothing
    pending: list[Any] = []
    if raw_kind != "jsonl" or (graph_from is None and _has_map(db)):
        tr = _track_with_map(
            data, db, kind=kind, bag=bag, skip_bad=skip_bad, map_log=map_log, observe=observe, scale=scale,
            metres_per_move=metres_per_move, alpha=alpha, uniform_mix=uniform_mix, odometry_error=odometry_error,
            filter_kind=filter_kind, seed=seed, pending=pending, heading=heading, scan=scan, scan_gamma=scan_gamma,
        )  # fmt: skip
    else:
        tr = _track_jsonl(
            data, db, scale=scale, graph_from=graph_from, pending=pending, metres_per_move=metres_per_move,
            alpha=alpha, uniform_mix=uniform_mix, odometry_error=odometry_error, filter_kind=filter_kind,
            radius=radius, seed=seed,
        )  # fmt: skip
    for write in pending:
        write()
    steps = _steps(tr, quiet)
    summary = _track_summary(tr, filter_kind)
    _print_summary(summary, tr, filter_kind)
    warn(compat.check_queries(summary["filtered"].get("labelled", 0)))  # fewer than 10 labelled steps
    write_json(json_out, {"steps": steps, "summary": summary})
    if report is not None:
        track_report(report, result=tr.result, log_likelihood=tr.beta * tr.ll, truth=tr.truth, classes=tr.classes,
                     names=tr.names, geo=tr.geo, data=data, db=db)  # fmt: skip


@dataclass(slots=True)
class _Tracked:
    """A run tracked by either filter: what ``track`` prints, writes and draws.

    ``ll`` (n_steps, P) single-shot log-likelihoods (NaN rows: prediction
    only), ``truth`` (n_steps,) true place column or -1, ``geo`` the poses and
    place centres known (for the report).
    """

    ll: Any
    truth: Any
    classes: list[str]
    names: list[str]
    beta: float
    metres: float | None
    transition: Any
    result: Any
    odometry_error: float
    geo: dict[str, Any]
    scan_gamma: float | None = None


def _check_options(
    observe: str,
    filter_kind: str,
    odometry_error: float | None,
    radius: float | None,
    scale: float | None,
    metres_per_move: float | None,
    alpha: float,
    uniform_mix: float | None,
) -> None:
    """One-line errors for the filter's options, before anything is read."""
    if observe not in ("queries", "all"):
        raise InvalidParameterError(f"--observe must be 'queries' or 'all', got {observe!r}")
    if filter_kind not in ("places", "pose"):
        raise InvalidParameterError(f"--filter must be 'places' or 'pose', got {filter_kind!r}")
    if odometry_error is not None and not (math.isfinite(odometry_error) and 0 <= odometry_error <= 100):
        raise InvalidParameterError(f"--odometry-error must be a factor in [0, 100], got {odometry_error!r}")
    if radius is not None and not (math.isfinite(radius) and radius > 0):
        raise InvalidParameterError(f"--radius must be a positive number of metres, got {radius!r}")
    if scale is not None and not (math.isfinite(scale) and scale > 0):
        raise InvalidParameterError(f"--scale must be a positive number, got {scale!r}")
    if metres_per_move is not None and not (math.isfinite(metres_per_move) and metres_per_move > 0):
        raise InvalidParameterError(f"--metres-per-move must be a positive number of metres, got {metres_per_move!r}")
    if not (math.isfinite(alpha) and alpha >= 0):
        raise InvalidParameterError(f"--alpha must be a finite number >= 0, got {alpha!r}")
    if uniform_mix is not None and not (0 <= uniform_mix < 1):
        raise InvalidParameterError(f"--uniform-mix must be in [0, 1), got {uniform_mix!r}")


def _check_db_flags(data: Path, db: Path, kind: str, map_log: bool, graph_from: Path | None, overwrite: bool) -> str:
    """The run's kind (``carmen``, ``bag`` or ``jsonl``), after the checks of --map, --graph-from and --overwrite."""
    from ..pipeline.readers import detect_kind

    raw_kind = (detect_kind(data) if kind == "auto" else kind) or "jsonl"
    if map_log:
        if raw_kind == "jsonl":
            raise InvalidParameterError("--map needs a CARMEN log or a bag (map JSON Lines with 'fingerloc map')")
        if graph_from is not None:
            raise InvalidParameterError("--graph-from is for JSON Lines; with --map the graph comes from the run")
        check_db_target(db, overwrite)
    elif overwrite:
        raise InvalidParameterError("--overwrite goes with --map")
    if db.is_dir():
        raise InvalidParameterError(f"--db: {db} is a directory, not a place database")
    return raw_kind


def _track_with_map(
    data: Path, db: Path, *, filter_kind: str, seed: int, heading: bool = True, **options: Any
) -> _Tracked:
    """A raw run (or JSON Lines) against a database made by 'fingerloc map': the library's tracker."""
    ll, truth, poses, classes, tracker, names, factor, hd, pts = _run_steps(
        data, db, filter_kind=filter_kind, heading=heading, **options
    )
    res = tracker.run(ll, poses, filter=filter_kind, odometry_error=factor, seed=seed, headings=hd, points=pts)
    cal = tracker.calibration
    geo = {"poses": poses, "centres": tracker.centres}
    gamma = None
    if filter_kind == "pose":
        gamma = float(cal.scan_gamma) if tracker.scan_map is not None and pts is not None else 0.0
    return _Tracked(ll, truth, classes, names, cal.beta, cal.metres_per_move, tracker.transition_, res, factor, geo,
                    gamma)  # fmt: skip


def _track_jsonl(
    data: Path,
    db: Path,
    *,
    scale: float | None,
    graph_from: Path | None,
    pending: list[Any],
    metres_per_move: float | None,
    alpha: float,
    uniform_mix: float | None,
    odometry_error: float | None,
    filter_kind: str,
    radius: float | None,
    seed: int,
) -> _Tracked:
    """JSON Lines against a database made by 'fingerloc learn' (the graph stored, or from --graph-from)."""
    from ..map.filter import TransitionModel, run_filter

    ll, truth, dist, graph, classes, beta, metres, names, geo = _jsonl_steps(
        data, db, scale=scale, graph_from=graph_from, pending=pending
    )
    if metres_per_move is not None:
        metres = metres_per_move
    if graph.graph.number_of_edges() == 0:
        err_console.print(f"{db}: no place graph stored; every place may follow every place (single-shot)")
        transition = TransitionModel.uniform(len(classes))
    else:
        transition = TransitionModel.from_graph(graph, classes, alpha=alpha, uniform_mix=uniform_mix, metres_per_move=metres)
    factor = 0.0 if odometry_error is None else odometry_error
    if filter_kind == "pose":
        res = _pose_filter_run(beta * ll, transition, geo, radius=radius, odometry_error=factor, seed=seed)
    else:
        res = run_filter(beta * ll, transition, distances=dist)
    return _Tracked(ll, truth, classes, names, beta, metres, transition, res, factor, geo)


def _steps(tr: _Tracked, quiet: bool) -> list[dict[str, Any]]:
    """One JSON record per step (printed as a line unless ``quiet``)."""
    steps: list[dict[str, Any]] = []
    for t in range(tr.ll.shape[0]):
        rec: dict[str, Any] = {
            "step": t,
            "name": tr.names[t],
            "observed": bool(not np.all(np.isnan(tr.ll[t]))),
            "best": tr.classes[int(tr.result.best[t])],
            "probability": float(tr.result.best_probability[t]),
            "entropy_bits": float(tr.result.entropy_bits[t]),
            "true": None if tr.truth[t] < 0 else tr.classes[int(tr.truth[t])],
        }
        steps.append(rec)
        if not quiet:
            mark = "" if rec["true"] is None else ("  right" if rec["true"] == rec["best"] else f"  (true {rec['true']})")
            console.print(
                f"{t:5d} {'obs ' if rec['observed'] else 'pred'} {tr.names[t]:<28} best {rec['best']:<10} "
                f"p {rec['probability']:.3f}  H {rec['entropy_bits']:.2f} bits{mark}",
                soft_wrap=True,
                markup=False,
            )
    return steps


def _track_summary(tr: _Tracked, filter_kind: str) -> dict[str, Any]:
    """``summary`` of ``track --json``: steps, the calibration used, filtered and single-shot figures."""
    single = np.where(np.isnan(tr.ll), 0.0, tr.ll)
    observed = ~np.all(np.isnan(tr.ll), axis=1)
    truth = np.where(observed, tr.truth, -1)
    return {
        "steps": int(tr.ll.shape[0]),
        "observed_steps": int(observed.sum()),
        "places": len(tr.classes),
        "likelihood_scale": tr.beta,
        "metres_per_move": tr.metres,
        "uniform_mix": tr.transition.uniform_mix,
        "filter": filter_kind,
        **({} if tr.scan_gamma is None else {"scan_gamma": tr.scan_gamma}),
        "filtered": _summary(tr.result.best, tr.result.log_posterior, truth),
        "single_shot": _summary(np.argmax(single, axis=1), single, truth),
    }


def _print_summary(summary: dict[str, Any], tr: _Tracked, filter_kind: str) -> None:
    f, s = summary["filtered"], summary["single_shot"]
    if f.get("labelled"):
        console.print(
            f"{f['labelled']} labelled observed steps: filtered top-1 {f['top1']:.3f}, mean rank {f['mean_rank']:.2f}; "
            f"single-shot top-1 {s['top1']:.3f}, mean rank {s['mean_rank']:.2f}",
            soft_wrap=True,
        )
    head = f"{summary['steps']} steps ({summary['observed_steps']} observed), {len(tr.classes)} places, beta {tr.beta:.3g}, "
    if filter_kind == "pose":
        scan = "" if not tr.scan_gamma else f", scan evidence gamma {tr.scan_gamma:g}"
        console.print(head + f"pose filter (odometry increments, error factor {tr.odometry_error:g}{scan})", soft_wrap=True)
    else:
        odometry = "off" if tr.metres is None else f"{tr.metres:.2f} m per place change"
        console.print(head + f"uniform mixing {tr.transition.uniform_mix:.3g}, odometry {odometry}", soft_wrap=True)


def _pose_filter_run(
    ll: np.ndarray, transition: Any, geo: dict[str, Any], *, radius: float | None, odometry_error: float, seed: int
) -> Any:
    """The pose filter along the steps (``geo``: step poses, place centres, radius, n_train, fov)."""
    from ..map.filter import MarkovFilter
    from ..map.pose_filter import PoseFilter, run_pose_filter, wheel_odometry

    if geo.get("poses") is None or geo.get("centres") is None:
        raise InvalidParameterError(geo.get("why", "the pose filter needs poses of the steps and of the places"))
    centres = np.asarray(geo["centres"], dtype=np.float64)
    r = radius if radius is not None else geo.get("radius")
    if r is None:
        if centres.shape[0] < 2:
            raise InvalidParameterError("give --radius: one place has no spacing to take it from")
        d = np.linalg.norm(centres[:, None] - centres[None], axis=2)
        np.fill_diagonal(d, np.inf)
        r = 0.5 * float(np.median(d.min(axis=1)))
    inc = wheel_odometry(np.asarray(geo["poses"], dtype=np.float64), odometry_error, random_state=seed + 1)
    f = PoseFilter(centres, float(r), kidnap=1.0 / (int(geo["n_train"]) + 2), random_state=seed)
    temper = (2.0 * float(r), float(geo.get("fov", math.pi)))  # a new view: the place spacing, or the field of view
    res = run_pose_filter(ll, inc, f, temper=temper, place_filter=MarkovFilter(transition))
    from ..map.relocalize import answer_between
    from ..pipeline.tracker import HOLD_MARGIN, TIE_BREAK

    # the answers between observations as the tracker gives them (held, near-ties to the place filter)
    return answer_between(res, ll, np.vstack([np.zeros((1, 3)), inc]), transition, hold_margin=HOLD_MARGIN,
                          tie_break=TIE_BREAK)  # fmt: skip


def _jsonl_steps(
    data: Path, db: Path, *, scale: float | None, graph_from: Path | None, pending: list[Any]
) -> tuple[Any, ...]:
    from ..io.jsonl import read_observations
    from ..map.database import hold_lock, load_model, read_map_info, save_model
    from ..map.filter import metres_per_move
    from ..map.graph import PlaceGraph, load_graph
    from ..pipeline.tracker import step_distances

    if graph_from is not None:
        hold_lock(db)  # the writer lock from this read to the graph's store (a concurrent learn waits)
    model = load_model(db)
    classes = [str(c) for c in model.classes_]
    metres = None
    g: PlaceGraph | None = None
    geo: dict[str, Any] = {"why": "the pose filter needs the places' positions: give --graph-from with poses"}
    if graph_from is not None:
        train = read_observations(graph_from)
        seq = [o.label for o in train]
        bad = next((i for i, lab in enumerate(seq) if lab not in set(classes)), None)
        if bad is not None:
            raise InvalidParameterError(
                f"{graph_from}:{bad + 1}: place {seq[bad]!r} is not in {db} (every line needs a learned 'place')"
            )
        g = PlaceGraph.from_sequence(classes, [str(lab) for lab in seq])

        def store() -> None:
            save_model(model, db, graph_edges=g.edges(), info=read_map_info(db))  # keep the preset, hashes...
            err_console.print(f"{db}: stored the place graph of {graph_from} ({len(g.edges())} edges)", markup=False)

        pending.append(store)
        if len(train) > 1 and all(o.pose is not None for o in train):
            col = {c: j for j, c in enumerate(classes)}
            tp = np.array([o.pose for o in train if o.pose is not None], dtype=np.float64)
            lab_idx = np.array([col[str(lab)] for lab in seq], dtype=np.int64)
            metres = metres_per_move(tp[:, :2], lab_idx)
            if np.all(np.isin(np.arange(len(classes)), lab_idx)):
                centres = np.array([tp[lab_idx == j, :2].mean(axis=0) for j in range(len(classes))])
                geo = {"centres": centres, "n_train": len(train),
                       "fov": 2 * math.pi * float(np.median([o.fov_coverage() for o in train]))}  # fmt: skip
            else:
                geo = {"why": f"{graph_from}: not every place of {db} has a view there, so not every place has a position"}
    graph = load_graph(db, classes) if g is None else g
    obs = read_observations(data)
    if not obs:
        raise InvalidParameterError(f"{data}: no observation to track")
    warn(compat.check_observations(model, obs, what=str(data)))  # modality, field of view
    ll = np.asarray(model.predict_log_proba(obs), dtype=np.float64)  # what beta is calibrated on
    col = {c: j for j, c in enumerate(classes)}
    truth = np.array([col.get(o.label, -1) if o.label else -1 for o in obs], dtype=np.int64)
    dist = None
    if all(o.pose is not None for o in obs):
        dist = step_distances([o.pose[:2] for o in obs if o.pose is not None])
        geo["poses"] = np.array([o.pose for o in obs if o.pose is not None], dtype=np.float64)
    elif "centres" in geo:
        geo = {"why": f"{data}: the pose filter needs a pose on every observation"}
    names = [f"{data.name}:{i + 1}" for i in range(len(obs))]
    beta = scale
    if beta is None:
        cal = read_map_info(db).calibration
        beta = 1.0 if cal is None else float(cal.get("beta", 1.0))  # learn's calibration on its training views
    return ll, truth, dist, graph, classes, beta, metres, names, geo


def _has_map(db: Path) -> bool:
    """True when the database holds place positions and a calibration (made by 'fingerloc map')."""
    from ..map.database import read_map_info

    info = read_map_info(db, scan_map=False)
    return bool(info.positions) and info.calibration is not None


def _run_steps(
    data: Path,
    db: Path,
    *,
    kind: str,
    bag: dict[str, Any],
    skip_bad: bool,
    map_log: bool,
    observe: str,
    scale: float | None,
    metres_per_move: float | None,
    alpha: float,
    uniform_mix: float | None,
    odometry_error: float | None,
    filter_kind: str,
    pending: list[Any],
    heading: bool = True,
    scan: bool = True,
    scan_gamma: float | None = None,
) -> tuple[Any, ...]:
    """A run tracked with a map's stored places, positions and calibration (the library's tracker).

    With ``map_log``, the map is made from the run and its database write is
    appended to ``pending`` (done once the filter has run), not written here.
    With ``scan`` and the pose filter, the map's scan map and each observed
    step's laser end points (the last item; ``None`` without them) weigh the
    particles; ``scan_gamma`` overrides the calibration's power.
    """
    import dataclasses

    from ..pipeline.mapping import load_map, make_map, run_end_points, save_map
    from ..pipeline.places import nearest_within
    from ..pipeline.tracker import Tracker, heading_of, implied_headings, posterior_columns

    run = read_run_files([data], kind=kind, skip_bad=skip_bad, bag=bag)
    hd = None
    if map_log:
        warn(compat.check_run_for_map(run))  # no usable scan: an error; a stationary run: a warning
        with err_console.status("mapping...") as status:
            pm = make_map(run, heading=heading, scan=scan, on_step=lambda s: status.update(s))
        err_console.print(pm.preset.reason, markup=False)
        warn(compat.check_map(pm))  # one place, beta at a bound

        def store() -> None:
            size = save_map(pm, db)
            err_console.print(f"{db}: {pm.split.n_places} places, the place graph and the calibration, {size} bytes",
                              markup=False)  # fmt: skip

        pending.append(store)
        lm = pm.loaded()
    else:
        lm = load_map(db, scan=scan and filter_kind == "pose")
    use_scan = scan and filter_kind == "pose" and lm.scan_map is not None
    pts: list[Any] | None = None
    if lm.positions is None or lm.calibration is None:
        raise InvalidParameterError(
            f"{db}: no place positions or calibration stored; make the database with 'fingerloc map' (or track "
            "JSON Lines with --graph-from)"
        )
    poses = run.poses
    features = {} if lm.preset is None else lm.preset.features
    p = len(lm.labels)
    if run.records is not None and (poses is None or all(o.label for o in run.records)):
        # JSON Lines: every observation observes; the truth is its label
        col = {lab: j for j, lab in enumerate(lm.labels)}
        truth = np.array([col.get(str(o.label), -1) if o.label else -1 for o in run.records], dtype=np.int64)
        warn(compat.check_observations(lm, run.records, what=str(data)))  # modality, field of view
        ll = posterior_columns(lm.model, list(run.records), p, lm.labels)
        if use_scan:
            pts = run_end_points(run)
        if heading and filter_kind == "pose" and lm.calibration is not None and heading_of(lm.calibration) is not None:
            hd = implied_headings(lm.model, list(run.records), lm.labels)
        start = 0
    else:
        if poses is None:
            raise InvalidParameterError(f"{data}: tracking a raw run needs a pose on every scan")
        start = 0
        mapped = lm.mapped_run(run.key)
        if mapped is not None:
            start = int(mapped["n_mapping"])
            err_console.print(f"{data} is the run the map was made from: tracking its scans after the mapping "
                              f"part (from scan {start} of {len(run)})", markup=False)  # fmt: skip
        poses = poses[start:]
        warn(compat.check_frame(lm.positions, lm.calibration.radius, lm.calibration.spacing, poses, what=str(data)))
        near_idx, near = nearest_within(poses[:, :2], lm.positions, lm.calibration.radius)
        n = poses.shape[0]
        truth = np.full(n, -1, dtype=np.int64)
        truth[near_idx] = near
        observed = near_idx if observe == "queries" else np.arange(n)
        ll = np.full((n, p), np.nan)
        with err_console.status(f"scoring {observed.size} scans..."):
            obs = run.observations(observed + start, features=features)
            warn(compat.check_observations(lm, obs, what=str(data)))  # modality, field of view
            ll[observed] = posterior_columns(lm.model, obs, p, lm.labels)
            if use_scan:
                seen = run_end_points(run, observed + start)
                if seen is not None:
                    pts = [None] * n
                    for k, i in enumerate(observed.tolist()):
                        pts[i] = seen[k]
            if heading and filter_kind == "pose" and heading_of(lm.calibration) is not None:
                hd = np.full((n, p), np.nan)
                hd[observed] = implied_headings(lm.model, obs, lm.labels)
    cal = lm.calibration
    if scale is not None:
        cal = dataclasses.replace(cal, beta=scale)
    if metres_per_move is not None:
        cal = dataclasses.replace(cal, metres_per_move=metres_per_move)
    cal = dataclasses.replace(cal, alpha=alpha)
    if scan_gamma is not None:
        cal = dataclasses.replace(cal, scan_gamma=scan_gamma)
    tracker = Tracker(lm.positions, lm.graph, cal, uniform_mix=uniform_mix, scan_map=lm.scan_map if use_scan else None)
    factor = odometry_error
    if factor is None:
        factor = 1.0 if run.kind == "carmen" and filter_kind == "pose" else 0.0
        if factor:
            err_console.print("CARMEN poses are corrected ones: simulating wheel-odometry errors (--odometry-error 1)",
                              markup=False)  # fmt: skip
    names = run.names[start:]
    return ll, truth, poses, list(lm.labels), tracker, names, factor, hd, pts


@bench_app.command("kidnap")
def kidnap_cmd(
    logs: list[Path] = typer.Argument(..., help="CARMEN logs (.log, .log.gz)."),
    base: str = typer.Option("fingerprint", help="Single-shot method under the filter (a 'bench carmen' name)."),
    trials: int = typer.Option(20, help="Kidnappings per log."),
    stretch: int = typer.Option(40, help="Steps before and after the kidnapping."),
    min_jump: float = typer.Option(10.0, "--min-jump", help="Metres between the two spliced stretches, at least."),
    synthetic: float | None = typer.Option(
        None, help="Replace the method's scores by a synthetic sensor: true place + this many sigma."
    ),
    seed: int = typer.Option(0, help="Seed of the trials' choice (and of the synthetic sensor, odometry, particles)."),
    filter_kind: str = typer.Option(
        "places", "--filter", help="'places': the discrete filter over places; 'pose': the pose particle filter."
    ),
    odometry_error: float = typer.Option(
        1.0, "--odometry-error", help="Pose filter: factor on the simulated odometry's errors (0 = exact)."
    ),
    kidnap: float | None = typer.Option(
        None, "--kidnap-prob", help="Pose filter: kidnapping probability per observation [1 / (training scans + 2)]."
    ),
    hold_margin: float | None = typer.Option(
        None, "--hold-margin", help="Pose filter: between observations keep the previous best place unless another "
        "place's probability exceeds it by this much [0.05; 0 = the argmax]."
    ),
    tie_break: float | None = typer.Option(
        None, "--tie-break", help="Pose filter: between observations, among the places within this probability of "
        "the answer, the one the discrete place filter believes most [0.02; 0 = exact ties only]."
    ),
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures and trials as JSON here."),
) -> None:
    """Kidnapped robot: splice two distant stretches of each log's query pass; steps until the filter recovers.

    Recovery = steps after the jump until the kidnapped filter's best place
    agrees with that of the filter that was never kidnapped, for good
    ('agree': at every later step of the stretch; 'at obs': at every later
    observed step, where an answer is scored).

    Second table, what is recovery and what is noise. 'floor': the same two
    criteria applied to a second never-kidnapped run (other random draws)
    against the reference on the same stretch; nothing was kidnapped, so its
    fraction within 10 steps is the best the column can show for this filter
    ('dis': the fraction of steps where the two unkidnapped runs disagree;
    the discrete filter over places is deterministic: floor 1.00, dis 0).
    'truth': steps until the best place is the true place (the corrected
    pose within its radius) at every later observed step, at least one, for
    the kidnapped filter and for the reference ('ref', its floor); 'cell': the same
    against the nearest place centre of the corrected pose at every step.
    'top-1 kid / ref': fraction of the stretches' observed steps at the true
    place after the kidnapping, and in the never-kidnapped run.
    """
    from ..experiments.markov import run_kidnap

    check_output(json_out, "--json")
    if filter_kind not in ("places", "pose"):
        raise InvalidParameterError(f"--filter must be 'places' or 'pose', got {filter_kind!r}")
    with err_console.status("kidnapping...") as status:
        res = run_kidnap(
            logs,
            base=base,
            n_trials=trials,
            stretch=stretch,
            min_jump_m=min_jump,
            seed=seed,
            synthetic=synthetic,
            pose=filter_kind == "pose",
            odometry_error=odometry_error,
            kidnap=kidnap,
            hold_margin=hold_margin,
            tie_break=tie_break,
            on_progress=lambda s: status.update(s),
        )
    rows = [*((n, lg["summary"]) for n, lg in res["logs"].items()), ("pooled", res["pooled"])]
    head = (
        f"{'log':<14} {'trials':>6} | {'agree':>5} {'steps':>6} {'obs':>5} {'<=10':>5} | {'at obs':>6} {'<=10':>5} | "
        f"{'merged':>6} {'steps':>6} {'obs':>5} | {'1st right':>9} {'ref':>5}"
    )
    console.print("recovery after a kidnapping (medians; agree = best place as the never-kidnapped filter's, "
                  "at obs = the same compared at observed steps only, "
                  "merged = posteriors within 0.1 total variation)", soft_wrap=True)  # fmt: skip
    console.print(head, soft_wrap=True)
    console.print("-" * len(head), soft_wrap=True)

    def f(v: Any, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    for name, s in rows:
        console.print(
            f"{name:<14} {s['trials']:>6} | {s['recovered']:>5} {f(s['median_recover_steps'], '.1f'):>6} "
            f"{f(s['median_recover_observations'], '.1f'):>5} {f(s['within_10'], '.2f'):>5} | "
            f"{f(s['median_recover_observed_steps'], '.1f'):>6} {f(s['observed_within_10'], '.2f'):>5} | "
            f"{s['merged']:>6} {f(s['median_merge_steps'], '.1f'):>6} {f(s['median_merge_observations'], '.1f'):>5} | "
            f"{f(s['median_first_right_steps'], '.1f'):>9} {f(s['median_reference_first_right_steps'], '.1f'):>5}",
            soft_wrap=True,
        )
    head2 = (
        f"{'log':<14} | {'floor':>5} {'at obs':>6} {'dis':>5} | {'truth':>5} {'ref':>5} | {'cell':>5} {'ref':>5} | "
        f"{'top-1 kid':>9} {'ref':>5}"
    )
    console.print("fraction of trials settled within 10 steps: a second never-kidnapped run (floor, all steps / "
                  "observed steps; dis = its per-step disagreement), the true place at observed steps (truth, "
                  "kidnapped / reference), the true cell at every step (cell); top-1 at the stretches' observed "
                  "steps", soft_wrap=True)  # fmt: skip
    console.print(head2, soft_wrap=True)
    console.print("-" * len(head2), soft_wrap=True)
    for name, s in rows:
        console.print(
            f"{name:<14} | {f(s['floor_within_10'], '.2f'):>5} {f(s['floor_observed_within_10'], '.2f'):>6} "
            f"{f(s['floor_disagreement'], '.3f'):>5} | {f(s['truth_within_10'], '.2f'):>5} "
            f"{f(s['reference_truth_within_10'], '.2f'):>5} | {f(s['cell_within_10'], '.2f'):>5} "
            f"{f(s['reference_cell_within_10'], '.2f'):>5} | {f(s['kidnapped_top1'], '.3f'):>9} "
            f"{f(s['reference_top1'], '.3f'):>5}",
            soft_wrap=True,
        )
    console.print("query steps along the query pass (top-1 / mean rank of the true place)", soft_wrap=True)
    tr = [*((n, lg["tracking"]) for n, lg in res["logs"].items()), ("pooled", res["pooled_tracking"])]
    for name, t in tr:
        a, b = t["single_shot"], t["filtered"]
        console.print(
            f"{name:<14} single-shot {a['top1']:.3f} / {a['mean_rank']:.2f}   filtered {b['top1']:.3f} / {b['mean_rank']:.2f}",
            soft_wrap=True,
        )
    write_json(json_out, res)
