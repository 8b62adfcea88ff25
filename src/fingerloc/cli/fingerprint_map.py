"""``fingerloc map --places fingerprints``: a place map from the views alone (no pose), its database and report."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ._io import warn
from .app import err_console

__all__ = ["map_fingerprints"]


def map_fingerprints(
    run: Any,
    db: Path,
    *,
    preset: str,
    overrides: Mapping[str, Any] | None,
    mapping_part: float,
    until: float | None,
    json_out: Path | None,
    report: Path | None,
    data: Path,
    tum: Path | None = None,
    doubts: Sequence[str] = (),
) -> None:
    """Make the map, save it to ``db``, print one summary line; ``--json``: the labelled keyframes; ``--report``;
    ``--tum``: the run's poses (a run with poses only, checked before any work). ``doubts``: warnings about the
    run (:func:`fingerloc.pipeline.compat.check_run_for_map`), said with the map's own once every output is
    written."""
    from ..config import Config
    from ..errors import InvalidParameterError
    from ..pipeline.compat import check_map
    from ..pipeline.presets import empty_terms
    from ..pipeline.topology import PURITY_RADIUS_M, place_purity, places_from_fingerprints

    if tum is not None and run.poses is None:
        raise InvalidParameterError("--tum: the run has no pose on every scan")
    with err_console.status("mapping from fingerprints...") as status:
        fm = places_from_fingerprints(
            run, preset=preset, overrides=overrides, mapping_part=mapping_part, until=until,
            on_step=lambda s: status.update(s),
        )  # fmt: skip
    err_console.print(fm.preset.reason, markup=False)
    empty = empty_terms(fm.preset.options, fm.training)
    if empty:
        err_console.print(f"warning: no view has {', '.join(empty)} bearings: those terms cannot tell places apart "
                          "(see --preset / --terms)", markup=False)  # fmt: skip
    config = Config().with_(places={"mapping_part": mapping_part, "until_s": until}, calibration={"enabled": False})
    place_map = fm.place_map(config)
    size = place_map.save(db)
    poses = run.poses
    figures: dict[str, Any] = {}
    score = ""
    if poses is not None:
        from ..pipeline.places import places_from_trajectory

        purity = place_purity(fm.assignment, poses[: fm.n_mapping, :2], PURITY_RADIUS_M)
        pose_places = places_from_trajectory(poses[:, :2], n_mapping=fm.n_mapping).n_places
        figures = {"purity (views within 3 m of their place's median position)": round(purity, 4),
                   "places of the pose-based map (2 m spacing)": pose_places}  # fmt: skip
        score = f"; scored against the poses: purity {purity:.3f}, the pose-based map has {pose_places} places"
    err_console.print(
        f"{db}: {fm.n_places} place(s) from fingerprints ({fm.keyframes.size} keyframes of the first {fm.n_mapping} "
        f"of {fm.n_scans} views, {fm.closures.shape[0]} loop closure(s)); preset {fm.preset.name}; beta "
        f"{fm.calibration.beta:.3g}; no place positions{score}; {size} bytes",
        markup=False,
        soft_wrap=True,
    )
    if json_out is not None:
        from ..io.jsonl import write_observations

        n = write_observations(json_out, fm.training)
        err_console.print(f"wrote {n} labelled keyframes to {json_out}", markup=False)
    if tum is not None:
        from ..atomic import replacing
        from ._follow import write_reference

        with replacing(tum) as tmp:  # renamed with the database and the other outputs when the command ends well
            write_reference(tmp, run.timestamps, poses,
                            warn=lambda s: err_console.print(s.replace(str(tmp), str(tum)), markup=False))  # fmt: skip
    if report is not None:
        from ..reporting.loops import write_places_report

        page = write_places_report(
            report, labels=fm.labels, assignment=fm.assignment, keyframes=fm.keyframes, closures=fm.closures,
            consensus=[None if c is None else c.letters for c in fm.consensus], trajectory=poses,
            notes=[f"fingerloc map {data} --places fingerprints --db {db}"], figures=figures,
        )  # fmt: skip
        err_console.print(f"wrote {page} (open it in a browser)", soft_wrap=True, markup=False)
    warn([*doubts, *check_map(place_map)])  # stationary, one place, no features: said once every output is written
