"""``fingerloc bench loops``: loop-closure detection and places from fingerprints, scored against the poses."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import typer

from ..errors import InvalidParameterError
from ._io import all_or_nothing, check_output, warn, write_json
from .app import bench_app, console, err_console

__all__ = ["loops_cmd", "print_loops"]


def print_loops(js: dict[str, Any]) -> None:
    """Print ``bench loops --json``'s figures as two aligned tables (plain text)."""
    rows = [*js["logs"].items(), ("pooled", js["pooled"])]
    lw = max([len("log"), *(len(n) for n, _ in rows)])
    mw = max([len("method"), *(len(m) for _, lg in rows for m in lg["methods"])])
    head = (
        f"{'log':<{lw}} {'queries':>7} {'pos':>5}  {'method':<{mw}}  {'max_f1':>6} {'r@100':>6} {'r@99':>6} "
        f"{'AP':>6} {'cpu_s':>6}"
    )
    console.print(head, soft_wrap=True)
    console.print("-" * len(head), soft_wrap=True)
    for name, lg in rows:
        for k, (m, f) in enumerate(lg["methods"].items()):
            prefix = f"{name:<{lw}} {lg['queries']:>7} {lg['positives']:>5}" if k == 0 else " " * (lw + 14)
            console.print(
                f"{prefix}  {m:<{mw}}  {f['max_f1']:>6.3f} {f['recall_at_100']:>6.3f} {f['recall_at_99']:>6.3f} "
                f"{f['average_precision']:>6.3f} {f['seconds']:>6.1f}",
                soft_wrap=True,
            )
    maps = [(n, lg["fingerprint_map"]) for n, lg in rows if lg.get("fingerprint_map")]
    if maps:
        console.print("")
        head2 = (
            f"{'log':<{lw}} {'places':>6} {'pose_places':>11} {'ratio':>5} {'purity':>6} {'queries':>7} "
            f"{'localize':>8} {'track':>6}"
        )
        console.print(
            "places from fingerprints (first half of each log) against the pose-based map; the rest of the log "
            "localized (queries: later scans within 3 m of a place's median position; top-1 of localize and of the "
            "place filter)",
            soft_wrap=True,
        )
        console.print(head2, soft_wrap=True)
        console.print("-" * len(head2), soft_wrap=True)
        for name, mp in maps:
            ratio = mp["places"] / mp["pose_places"] if mp["pose_places"] else float("nan")
            extra = ""
            if "map_queries" in mp:
                extra = f" {mp['map_queries']:>7} {mp['localize_top1']:>8.3f} {mp['track_top1']:>6.3f}"
            console.print(
                f"{name:<{lw}} {mp['places']:>6} {mp['pose_places']:>11} {ratio:>5.2f} {mp['purity']:>6.3f}{extra}",
                soft_wrap=True,
            )


@bench_app.command("loops")
@all_or_nothing  # --json and the report's files renamed into place together at the end, or none
def loops_cmd(
    logs: list[Path] = typer.Argument(..., metavar="LOG", help="Laser logs with poses (CARMEN .log/.log.gz, bags)."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures as JSON to this file."),
    report: Path | None = typer.Option(
        None, "--report", help="Write a report folder here: PR curves and the fingerprint-made places of every log."
    ),
    method: list[str] = typer.Option(
        [],
        "--method",
        "-m",
        help="Run only this method (repeatable): fingerprint, fingerprint-single, "
        "baseline-scancontext, baseline-histogram [every one but fingerprint-single].",
    ),
    distance: float = typer.Option(
        2.0, "--distance", help="D: a candidate within this many metres of the query is a true match."
    ),
    exclude_s: float = typer.Option(
        30.0, "--exclude-s", help="T: scans of the last T seconds before the query are no candidates."
    ),
    exclude_scans: int = typer.Option(
        10, "--exclude-scans", min=0, help="Logs whose timestamps cannot measure T: the last N scans are no candidates."
    ),
    places: bool = typer.Option(
        True, "--places/--no-places", help="Also make each log's map from fingerprints and score it (purity, places)."
    ),
    skip_bad: bool = typer.Option(False, "--skip-bad", help="Skip malformed log lines."),
) -> None:
    """Loop-closure detection on laser logs, against ground truth from their poses.

    A query is every scan with an earlier scan outside the last --exclude-s
    seconds; its true matches are those within --distance metres. Each method
    names its best earlier scan with a score: precision-recall curve, recall
    at 100 % and 99 % precision, max F1 and average precision, per log and
    pooled. With --places (default) each log's first half is also mapped from
    its fingerprints alone and scored: places against the pose-based map's and
    place purity (share of views within 3 m of their place's median position).
    """
    from ..experiments.loops import LOOP_METHODS, run_loop_benchmark

    for m in method:
        if m not in LOOP_METHODS:
            raise InvalidParameterError(f"--method: unknown method {m!r} (known: {', '.join(LOOP_METHODS)})")
    if not (math.isfinite(distance) and distance > 0):
        raise InvalidParameterError(f"--distance must be a positive number of metres, got {distance!r}")
    if not (math.isfinite(exclude_s) and exclude_s >= 0):
        raise InvalidParameterError(f"--exclude-s must be a number of seconds >= 0, got {exclude_s!r}")
    check_output(json_out, "--json")
    from .reports import check_report

    check_report(report)
    with err_console.status("benchmarking...") as status:
        run = run_loop_benchmark(
            logs, method or None, distance_m=distance, exclude_s=exclude_s, exclude_scans=exclude_scans,
            fingerprint_map=places, skip_bad=skip_bad, on_progress=lambda s: status.update(s),
        )  # fmt: skip
    js = run.to_json()
    print_loops(js)
    write_json(json_out, js)
    if report is not None:
        from ..reporting.loops import write_loops_report

        items = []
        for lg in run.logs:
            fm = lg.fingerprint_map
            items.append({
                "name": lg.name,
                "metrics": js["logs"][lg.name]["methods"],
                "curves": {m: (c.precision, c.recall) for m, c in ((m, r.curve(lg.n_positive)) for m, r in lg.methods.items())},
                "positives": lg.n_positive,
                "trajectory": lg.positions if fm is not None else None,
                "assignment": None if fm is None else fm.assignment,
                "closures": None if fm is None else fm.closures,
                "map": lg.map_figures or None,
            })  # fmt: skip
        pooled = {
            "metrics": js["pooled"]["methods"],
            "curves": {m: (c.precision, c.recall) for m, c in ((m, run.pooled_curve(m)) for m in run.method_names)},
            "positives": js["pooled"]["positives"],
        }
        path = write_loops_report(report, items, pooled=pooled, protocol=js["protocol"])
        err_console.print(f"wrote {path} (open it in a browser)", soft_wrap=True, markup=False)
    warn(f"{name}: no query has a true match ({lg['queries']} queries; a true match is an earlier scan within "
         f"{distance:g} m, outside the last {exclude_s:g} s): its figures are 0 by definition, not a measurement"
         for name, lg in js["logs"].items() if not lg["positives"])  # fmt: skip
