"""``fingerloc track - --follow`` (standard input, or a file as it grows): the command's streaming mode.

Called by ``track`` (:mod:`fingerloc.cli.track`) with its options; the loop
itself is :func:`fingerloc.cli._follow.follow_track`, one step per item by
:class:`fingerloc.pipeline.follow.StreamStepper`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import InvalidParameterError
from ._follow import follow_summary, follow_track
from ._io import write_json
from .app import err_console

__all__ = ["track_follow"]


def track_follow(
    data: Path,
    db: Path,
    *,
    unused: dict[str, Any],
    json_out: Path | None,
    tum: Path | None,
    kitti: Path | None,
    quiet: bool,
    kind: str,
    skip_bad: bool,
    idle_timeout: float | None,
    max_range: float | None,
    observe: str,
    tracker_options: dict[str, Any],
    odometry_error: float | None,
) -> None:
    """Track ``data`` line by line against the map in ``db`` (module docstring); the answers as JSON lines on stdout.

    ``unused``: the batch-only options as given (flag -> value); any that is set is an error.
    ``odometry_error``: the pose filter's simulated odometry errors [CARMEN streams: 1, their poses are
    corrected ones, as offline ``track``; else 0].
    """
    from ..pipeline.follow import StreamStepper
    from ..pipeline.placemap import load_map

    given = [flag for flag, v in unused.items() if v]
    where = "standard input ('-')" if str(data) == "-" else "--follow"
    if given:
        raise InvalidParameterError(f"{given[0]} does not go with {where}")
    if kind not in ("auto", "carmen", "jsonl"):
        raise InvalidParameterError(
            f"--kind with {where} must be auto, carmen or jsonl (a bag is read whole), got {kind!r}"
        )
    if max_range is not None and not max_range > 0:
        raise InvalidParameterError(f"--max-range must be a positive number of metres, got {max_range!r}")
    filter_kind = tracker_options["filter"]
    if (tum is not None or kitti is not None) and filter_kind == "places":
        raise InvalidParameterError(
            f"{'--tum' if tum is not None else '--kitti'} needs the pose filter (--filter pose)"
        )
    if db.is_dir():
        raise InvalidParameterError(f"--db: {db} is a directory, not a place database")
    pm = load_map(db, scan=bool(tracker_options.get("scan", True)) and filter_kind in ("pose", "auto"))
    if filter_kind == "pose" and not pm.has_positions:
        raise InvalidParameterError(
            f"{db}: the pose filter needs place positions: make the database with 'fingerloc map'"
        )
    options = {k: v for k, v in tracker_options.items() if v is not None}
    state: dict[str, Any] = {}

    def note(text: str) -> None:
        err_console.print(text, markup=False)

    def step(item: Any) -> Any:
        nonlocal filter_kind
        stepper = state.get("stepper")
        if stepper is None:  # the first item tells the stream's format, and so the odometry default
            if filter_kind == "auto":  # the pose filter when the map has positions and the stream poses
                filter_kind, why = pm.default_filter()
                if filter_kind == "pose" and item.pose is None and item.odometry is None:
                    filter_kind, why = "places", "filter: places (the stream's first line has no pose or odometry)"
                options["filter"] = filter_kind
                if filter_kind != "pose" and (tum is not None or kitti is not None):
                    raise InvalidParameterError(f"{'--tum' if tum is not None else '--kitti'} needs the pose filter, and {why.partition('(')[2].rstrip(')')}")
                note(why)
            factor = odometry_error
            if factor is None:
                factor = 1.0 if item.kind == "carmen" and filter_kind == "pose" else 0.0
                if factor:
                    note("CARMEN poses are corrected ones: simulating wheel-odometry errors (--odometry-error 1)")
            tracker = pm.tracker(**options, odometry_error=factor if filter_kind == "pose" else 0.0)
            stepper = state["stepper"] = StreamStepper(pm, tracker, observe=observe)
        return stepper.step(item)

    res = follow_track(data, step, kind=kind, follow=True, skip_bad=skip_bad, idle_timeout=idle_timeout,
                       max_range=max_range, tum=tum, kitti=kitti, quiet=quiet, warn=note)  # fmt: skip
    summary = follow_summary(res.answers, pm.labels, filter_kind)
    f = summary["filtered"]
    tail = f", filtered top-1 {f['top1']:.3f} over {f['labelled']} labelled observed steps" if f.get("labelled") else ""
    skipped = f", {res.skipped} bad line(s) skipped" if res.skipped else ""
    note(f"{summary['steps']} steps ({summary['observed_steps']} observed), {summary['places']} places, "
         f"{filter_kind} filter{tail}{skipped} ({res.ended})")  # fmt: skip
    write_json(json_out, {"steps": [a.to_json() for a in res.answers], "summary": summary})
