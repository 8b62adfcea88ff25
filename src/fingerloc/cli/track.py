"""``fingerloc track``: localization along a run, step by step, with either filter (the library's tracker)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from .._lazy import LazyModule
from ..errors import InvalidParameterError
from ._io import all_or_nothing, check_output, warn
from .app import app, console, err_console
from .bench import write_json
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

if TYPE_CHECKING:
    import numpy as np

    from ..pipeline.placemap import PlaceMap
else:
    np = LazyModule("numpy")  # imported when a command runs, not for --help
compat = LazyModule("fingerloc.pipeline.compat")

__all__ = ["track_cmd"]


@app.command("track")
@all_or_nothing  # outputs renamed together at the end, the database's writer lock held to the end
def track_cmd(
    data: Path = typer.Argument(
        ..., help="A run in order: JSON Lines, a CARMEN log or a ROS bag ('-': standard input, tracked as it arrives)."
    ),
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
        "auto",
        "--filter",
        help="'pose': particle filter over the robot's pose with the odometry increments (needs poses, and place "
        "positions: a database made by 'fingerloc map', or JSON Lines with --graph-from, both with poses); "
        "'places': discrete filter over the places; 'auto': the pose filter when the run and the map allow it, "
        "else the places (printed on stderr).",
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
    follow: bool = typer.Option(
        False, "--follow", help="Track line by line as the input arrives (a file: as it grows), one JSON line out "
        "per step, flushed (docs/ROBOT.md); standard input ('-') always is."
    ),
    idle_timeout: float | None = typer.Option(
        None, "--idle-timeout", help="--follow on a file: stop after this many seconds without a new line [never]."
    ),
    max_range: float | None = typer.Option(
        None, "--max-range", help="Standard input / --follow, CARMEN: metres at and beyond which a reading is no "
        "return [a known no-return code seen in the stream]."
    ),
    tum: Path | None = typer.Option(None, "--tum", help="Write the pose filter's poses as a TUM trajectory here."),
    kitti: Path | None = typer.Option(None, "--kitti", help="Write the pose filter's poses as KITTI poses here."),
) -> None:
    """Filter the posterior over places along a sequence of observations.

    Per step: the best place, its probability and the posterior's entropy
    (bits); with known places, the filtered and single-shot top-1 and mean
    rank of the true place. ``--filter pose`` is the particle filter, which
    follows the odometry's direction and turn, not only the distance;
    ``--filter places`` the discrete Bayes filter over the places (when it was
    below the single shot on the map's mapping part, it answers the single
    shot at the observations and says so). Without ``--filter``: the pose
    filter when the run has poses and the map place positions, else places.
    With a database made by 'fingerloc map', both use its calibration
    (likelihood scale, metres per place change, tempering, kidnapping
    probability). ``--json`` also gives each step's clock (``stamp``) and the
    pose filter's pose estimate with its covariance.
    """
    from ..pipeline.placemap import check_track_options
    from ..pipeline.readers import detect_kind
    from ._follow import write_trajectories
    from .reports import check_report, track_report

    check_report(report)
    check_track_options(observe=observe, filter=filter_kind, odometry_error=odometry_error, radius=radius, beta=scale,
                        metres_per_move=metres_per_move, alpha=alpha, uniform_mix=uniform_mix, scan_gamma=scan_gamma)
    check_output(json_out, "--json")
    check_output(tum, "--tum")
    check_output(kitti, "--kitti")
    if (tum is not None or kitti is not None) and filter_kind == "places":
        raise InvalidParameterError(f"{'--tum' if tum is not None else '--kitti'} needs the pose filter (--filter pose)")
    if str(data) == "-" or follow:
        from .track_follow import track_follow

        unused = {"--map": map_log, "--overwrite": overwrite, "--graph-from": graph_from, "--report": report,
                  "--radius": radius, "--topic": topic, "--base-frame": base_frame}  # fmt: skip
        track_follow(data, db, unused=unused, json_out=json_out, tum=tum, kitti=kitti, quiet=quiet, kind=kind,
                     skip_bad=skip_bad, idle_timeout=idle_timeout, max_range=max_range, observe=observe,
                     tracker_options={"filter": filter_kind, "seed": seed, "scan": scan, "heading": heading,
                                      "beta": scale, "metres_per_move": metres_per_move, "alpha": alpha,
                                      "uniform_mix": uniform_mix, "scan_gamma": scan_gamma},
                     odometry_error=odometry_error)  # fmt: skip
        return
    if idle_timeout is not None or max_range is not None:
        raise InvalidParameterError(f"{'--idle-timeout' if idle_timeout is not None else '--max-range'} goes with "
                                    "--follow or standard input ('-')")  # fmt: skip
    bag = bag_options(topic, pose_source, base_frame)
    raw_kind = (detect_kind(data) if kind == "auto" else kind) or "jsonl"
    _check_db_flags(raw_kind, db, map_log, graph_from, overwrite)
    # writes to --db wait until every check and the filter have passed: a failed command changes nothing
    pending: list[Any] = []
    run = read_run_files([data], kind=kind, skip_bad=skip_bad, bag=bag)
    pm = _place_map(run, db, map_log=map_log, graph_from=graph_from, radius=radius, heading=heading, scan=scan,
                    pose=filter_kind == "pose", pending=pending, load_scan=filter_kind != "places")  # fmt: skip
    doubts = compat.check_map(pm) if map_log else compat.check_run(pm, run)  # what does not fit: an error now, doubts
    why = None
    if filter_kind == "auto":
        filter_kind, why = pm.default_filter(run)
        if filter_kind != "pose" and (tum is not None or kitti is not None):  # before the work, not after
            raise InvalidParameterError(f"{'--tum' if tum is not None else '--kitti'} needs the pose filter, and {why.partition('(')[2].rstrip(')')}")
    tr = pm.track(
        run, filter=filter_kind, seed=seed, observe=observe, odometry_error=odometry_error, scan=scan, heading=heading,
        beta=scale, metres_per_move=metres_per_move, alpha=alpha, uniform_mix=uniform_mix, scan_gamma=scan_gamma,
        on_note=lambda s: err_console.print(s, markup=False),
    )  # fmt: skip
    if why is not None:  # after the tracking: a failed command prints its one error line only
        err_console.print(why, markup=False)
    for write in pending:
        write()
    steps = tr.steps
    if not quiet:
        for rec in steps:
            true = rec["true"]
            mark = "" if true is None else ("  right" if true == rec["best"] else f"  (true {true})")
            console.print(
                f"{rec['step']:5d} {'obs ' if rec['observed'] else 'pred'} {rec['name']:<28} best {rec['best']:<10} "
                f"p {rec['probability']:.3f}  H {rec['entropy_bits']:.2f} bits{mark}",
                soft_wrap=True,
                markup=False,
            )
    for line in tr.summary_lines():
        console.print(line, soft_wrap=True, markup=False)
    write_json(json_out, {"steps": steps, "summary": tr.summary})
    write_trajectories(tr.answers, tum=tum, kitti=kitti, warn=lambda s: err_console.print(s, markup=False))
    if report is not None:
        beta = tr.summary["likelihood_scale"]
        track_report(report, result=tr.result, log_likelihood=beta * tr.log_likelihood, truth=tr.truth,
                     classes=tr.places, names=[a.name for a in tr.answers],
                     geo={"poses": tr.poses, "centres": tr.centres}, data=data, db=db)  # fmt: skip
    warn(doubts + compat.check_queries(tr.summary["filtered"].get("labelled", 0)))  # once every output is written


def _check_db_flags(raw_kind: str, db: Path, map_log: bool, graph_from: Path | None, overwrite: bool) -> None:
    """The checks of --map, --graph-from and --overwrite against the run's kind (``carmen``, ``bag`` or ``jsonl``)."""
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


def _place_map(
    run: Any, db: Path, *, map_log: bool, graph_from: Path | None, radius: float | None, heading: bool, scan: bool,
    pose: bool, pending: list[Any], load_scan: bool = True,
) -> PlaceMap:  # fmt: skip
    """The map to track against: made from the run (``--map``, saved later), or the database's (with the visits of
    ``--graph-from``, whose graph is saved later)."""
    from ..config import Config
    from ..map.database import hold_lock
    from ..pipeline.mapping import make_map
    from ..pipeline.placemap import load_map

    if map_log:
        early = compat.check_run_for_map(run)  # no usable scan: an error now; a stationary run: a warning below
        with err_console.status("mapping...") as status:
            pm = make_map(run, Config().with_(calibration={"heading": heading, "scan": scan}),
                          on_step=lambda s: status.update(s))  # fmt: skip
        assert pm.preset is not None and pm.split is not None
        err_console.print(pm.preset.reason, markup=False)
        warn(early)
        n_places = pm.split.n_places

        def save_map() -> None:
            size = pm.save(db)
            err_console.print(f"{db}: {n_places} places, the place graph and the calibration, {size} bytes", markup=False)

        pending.append(save_map)
        return pm
    if graph_from is not None:
        hold_lock(db)  # the writer lock from this read to the graph's store (a concurrent learn waits)
    pm = load_map(db, scan=scan and load_scan)
    if run.kind != "jsonl" or (graph_from is None and pm.has_positions):
        return pm
    if graph_from is not None:
        from ..io.jsonl import read_observations
        from ..pipeline.placemap import store_graph

        try:
            pm = pm.with_visits(read_observations(graph_from), radius=radius)
        except InvalidParameterError as err:
            raise InvalidParameterError(f"{graph_from}: {err}") from err
        graph = pm.graph

        def store() -> None:
            store_graph(db, graph.edges())
            err_console.print(f"{db}: stored the place graph of {graph_from} ({len(graph.edges())} edges)", markup=False)

        pending.append(store)
    if pm.graph.graph.number_of_edges() == 0:
        err_console.print(f"{db}: no place graph stored; every place may follow every place (single-shot)", markup=False)
    if pose and not pm.has_positions:
        why = f"{graph_from}: the pose filter needs every place's position: give --graph-from with poses" if graph_from \
            else "the pose filter needs the places' positions: give --graph-from with poses"
        raise InvalidParameterError(why)
    return pm
