"""``fingerloc map``: places from a recorded run's poses, learned with the sensor's preset.

"""

from __future__ import annotations

import math
from pathlib import Path

import typer

from ..errors import InvalidParameterError
from ._io import all_or_nothing, warn
from .app import app, err_console
from .options import (
    BASE_FRAME_OPTION,
    KIND_OPTION,
    LOCK_TIMEOUT_OPTION,
    POSE_SOURCE_OPTION,
    SKIP_BAD_OPTION,
    TOPIC_OPTION,
    bag_options,
    check_db_target,
    check_output,
    model_overrides,
    read_run_files,
)
from .reports import check_report, map_report

__all__ = ["map_cmd"]

@app.command("map")
@all_or_nothing  # the database and --json / --queries renamed together at the end, or none
def map_cmd(
    runs: list[Path] = typer.Argument(..., metavar="RUN", help="A recorded run: CARMEN log, ROS bag, or JSON Lines with poses (several files: one run in order)."),
    db: Path = typer.Option(..., "--db", help="Place database to write (schema 4)."),
    preset: str = typer.Option("auto", "--preset", help="paper | laser2d | panorama | multimodal | auto (from the data)."),
    mapping_part: float | None = typer.Option(None, "--mapping-part", help="Fraction of the run that maps, from its start [0.5]."),
    until: float | None = typer.Option(None, "--until", help="The mapping part: scans within this many seconds of the first (instead of --mapping-part)."),
    spacing: float = typer.Option(2.0, "--spacing", help="A mapping scan farther than this (metres) from every place makes a new place."),
    radius: float = typer.Option(1.0, "--radius", help="Scans within this distance (metres, inclusive) of a place train it (nearest place)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace --db if it exists."),
    json_out: Path | None = typer.Option(None, "--json", help="Also write the labelled training observations (JSON Lines) here."),
    queries_out: Path | None = typer.Option(
        None, "--queries", help="Also write the queries (later scans within --radius of a place, labelled with the nearest) as JSON Lines here."
    ),
    kind: str = KIND_OPTION,
    topic: list[str] | None = TOPIC_OPTION,
    pose_source: str = POSE_SOURCE_OPTION,
    base_frame: str | None = BASE_FRAME_OPTION,
    skip_bad: bool = SKIP_BAD_OPTION,
    components: int | None = typer.Option(None, "-k", "--components", help="Mixture components (overrides the preset)."),
    terms: str | None = typer.Option(None, help="Terms, comma-separated (overrides the preset)."),
    laser_letters: bool | None = typer.Option(None, "--laser-letters/--no-laser-letters", help="Overrides the preset."),
    fp_likelihood: str | None = typer.Option(None, help="'paper' or 'exp' (overrides the preset)."),
    cyclic: bool | None = typer.Option(None, "--cyclic/--no-cyclic", help="Overrides the preset."),
    costs: str | None = typer.Option(None, help="'unit' or 'feature' (overrides the preset)."),
    no_calibration: bool = typer.Option(False, "--no-calibration", help="Do not fit the likelihood scale beta (beta = 1; faster)."),
    heading: bool = typer.Option(
        True, "--heading/--no-heading",
        help="Fit the pose filter's heading model on the mapping part (two more fits), used by 'track --filter pose'.",
    ),
    scan: bool = typer.Option(
        True, "--scan/--no-scan",
        help="Store the mapping part's laser end points (a scan map; runs with ranges only) and choose the power of "
        "their evidence on the mapping part, used by 'track --filter pose'.",
    ),
    report: Path | None = typer.Option(
        None, "--report", help="Write a report folder here: index.html (open it in a browser) with the map and every place."
    ),
    lock_timeout: float = LOCK_TIMEOUT_OPTION,
    tum: Path | None = typer.Option(
        None, "--tum", help="Also write the run's poses (every scan) as a TUM trajectory here: the reference for evo."
    ),
    places: str = typer.Option(
        "poses", "--places", help="'poses': a place every --spacing metres of the poses; 'fingerprints': places from "
        "the views alone, no pose needed (docs/LOOPS.md; --spacing, --radius, --heading, --scan, --no-calibration do "
        "not apply)."
    ),
) -> None:
    """Make a place map from a recorded run's poses.

    The first part of the run maps (--mapping-part, default the first half,
    or --until SECONDS): a place for every mapping scan farther than
    --spacing from every existing place; every mapping scan within --radius
    of a place trains its nearest place. The places are learned with the
    preset, and the database also stores the place positions, the place
    graph (visiting order) and the filters' calibration, so that
    'fingerloc localize' and 'fingerloc track' need only the database.
    """
    from ..config import Config
    from ..pipeline.compat import check_map, check_run_for_map
    from ..pipeline.mapping import make_map
    from ..pipeline.presets import PRESET_NAMES, empty_terms

    if preset not in PRESET_NAMES:
        raise InvalidParameterError(f"--preset must be one of {', '.join(PRESET_NAMES)}, got {preset!r}")
    if mapping_part is not None and until is not None:
        raise InvalidParameterError("give --mapping-part or --until, not both")
    if mapping_part is not None and not (0 < mapping_part <= 1):
        raise InvalidParameterError(f"--mapping-part must be a fraction in (0, 1], got {mapping_part!r}")
    if until is not None and not (math.isfinite(until) and until >= 0):
        raise InvalidParameterError(f"--until must be a number of seconds >= 0, got {until!r}")
    for flag, v in (("--spacing", spacing), ("--radius", radius)):
        if not (math.isfinite(v) and v > 0):
            raise InvalidParameterError(f"{flag} must be a positive number of metres, got {v!r}")
    if places not in ("poses", "fingerprints"):
        raise InvalidParameterError(f"--places must be 'poses' or 'fingerprints', got {places!r}")
    if places == "fingerprints" and queries_out is not None:
        raise InvalidParameterError("--queries needs place positions: it goes with --places poses")
    overrides = model_overrides(components=components, terms=terms, laser_letters=laser_letters,
                                fp_likelihood=fp_likelihood, cyclic=cyclic, costs=costs)  # fmt: skip
    check_db_target(db, overwrite)
    check_output(json_out, "--json")
    check_output(queries_out, "--queries")
    check_output(tum, "--tum")
    check_report(report)
    bag = bag_options(topic, pose_source, base_frame)
    run = read_run_files(runs, kind=kind, skip_bad=skip_bad, bag=bag)
    doubts = check_run_for_map(run)  # no usable scan: an error now; a stationary run: a warning once mapped
    if places == "fingerprints":
        from .fingerprint_map import map_fingerprints

        map_fingerprints(run, db, preset=preset, overrides=overrides, until=until,
                         mapping_part=0.5 if mapping_part is None else mapping_part, json_out=json_out,
                         report=report, data=runs[0], tum=tum, doubts=doubts)  # fmt: skip
        return
    config = Config().with_(
        places={"spacing_m": spacing, "radius_m": radius, "mapping_part": 0.5 if mapping_part is None else mapping_part,
                "until_s": until},
        calibration={"enabled": not no_calibration, "heading": heading, "scan": scan},
    )  # fmt: skip
    with err_console.status("mapping...") as status:
        pm = make_map(run, config, preset=preset, overrides=overrides, on_step=lambda s: status.update(s))
    assert pm.preset is not None and pm.calibration is not None and pm.split is not None and pm.training is not None
    err_console.print(pm.preset.reason, markup=False)
    late = doubts + check_map(pm)  # one place, beta at a bound, empty views: said once every output is written
    empty = empty_terms(pm.preset.options, pm.training)
    if empty:
        late.append(f"no training scan has {', '.join(empty)} bearings: those terms cannot tell places apart (see "
                    "--preset / --terms)")  # fmt: skip
    size = pm.save(db)
    sp, cal = pm.split, pm.calibration
    sm = pm.scan_map
    scan_note = "" if sm is None else f"; scan map of {sm.cells.shape[0]} cells, scan gamma {cal.scan_gamma:g}"
    err_console.print(
        f"{db}: {sp.n_places} place(s) from {sp.n_train} training scan(s) of the first {sp.n_mapping} of "
        f"{sp.n_scans}; preset {pm.preset.name}; beta {cal.beta:.3g}, {cal.metres_per_move:.2f} m per place "
        f"change, kidnap {cal.kidnap:.3g}{scan_note}; {size} bytes",
        markup=False,
        soft_wrap=True,
    )
    from ..io.jsonl import write_observations

    if json_out is not None:
        n = write_observations(json_out, pm.training)
        err_console.print(f"wrote {n} labelled observations to {json_out}", markup=False)
    if queries_out is not None:
        features = pm.preset.features
        q = run.observations(sp.query_idx, features=features)
        n = write_observations(queries_out, [o.with_label(pm.labels[j]) for o, j in zip(q, sp.query_labels.tolist(), strict=True)])
        err_console.print(f"wrote {n} labelled queries to {queries_out}", markup=False)
    if tum is not None:
        from ._follow import write_reference

        write_reference(tum, run.timestamps, run.poses, warn=lambda s: err_console.print(s, markup=False))
    if report is not None:
        map_report(report, model=pm.model, centres=pm.positions, radius=radius, edges=pm.graph.edges(),
                   trajectory=run.poses, scans=run.scans, data=runs[0], db=db)  # fmt: skip
    warn(late)
