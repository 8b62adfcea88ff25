"""``fingerloc features``: extract features from sensor files and print or save them.

The readers (one per input *kind*: a file -> ``(name, Observation)`` pairs)
live in the library, :mod:`fingerloc.pipeline.files`; this module prints
and saves what they return.
"""

from __future__ import annotations

from importlib import import_module
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from .._lazy import LazyAttr, LazyModule
from ..errors import InvalidParameterError
from ._io import check_output
from .app import app, bench_app, console, err_console, real_console
from .options import BASE_FRAME_HELP, POSE_SOURCE_HELP, TOPIC_HELP, bag_options

# numpy and the readers are imported when a command runs, not for --help
if TYPE_CHECKING:
    import numpy as np

    from ..observation import Observation
    from ..pipeline.files import KINDS, FeatureOptions, load_image, panorama_from_file
else:
    np = LazyModule("numpy")
deg_to_rad = LazyAttr("fingerloc.angles", "deg_to_rad")
rad_to_deg360 = LazyAttr("fingerloc.angles", "rad_to_deg360")
hue_letter = LazyAttr("fingerloc.fingerprint", "hue_letter")

__all__ = ["KINDS", "FeatureOptions", "format_observation", "load_image", "panorama_from_file"]

#: The names of :data:`fingerloc.pipeline.files.KINDS`, in its order, for the help text (tests/test_cli_startup.py).
KIND_NAMES = ("panorama", "omni", "carmen", "bag")
_FROM_FILES = ("KINDS", "FeatureOptions", "load_image", "panorama_from_file")


def __getattr__(name: str) -> Any:
    if name in _FROM_FILES:  # re-exported from fingerloc.pipeline.files, imported on first use
        return getattr(import_module("fingerloc.pipeline.files"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def format_observation(name: str, obs: Observation) -> str:
    """Readable lines: bearings in degrees of each feature type present, patches with hue letters."""

    def degs(a: np.ndarray) -> str:
        return " ".join(f"{x:.1f}" for x in np.sort(rad_to_deg360(a))) if a.size else "-"

    lines = [f"{name}" + (f"  [{obs.label}]" if obs.label else "")]
    if obs.full_fov or obs.ve.size or obs.cp.size:
        lines.append(f"  vertical edges ({obs.ve.size}): {degs(obs.ve)}")
        cp_deg = rad_to_deg360(obs.cp)
        order = np.argsort(cp_deg)
        pats = " ".join(
            f"{b:.1f}:{hue_letter(h)}({h:.0f})" for b, h in zip(cp_deg[order], obs.cp_hue[order], strict=True)
        )
        lines.append(f"  colour patches ({obs.cp.size}): {pats or '-'}")
    if obs.c.size or obs.ex.size or obs.b.size or not obs.full_fov:
        lines.append(f"  corners ({obs.c.size}): {degs(obs.c)}")
        lines.append(f"  extremities ({obs.ex.size}): {degs(obs.ex)}")
        lines.append(f"  beacons ({obs.b.size}): {degs(obs.b)}")
    return "\n".join(lines)


@app.command("features")
def features_cmd(
    files: list[Path] = typer.Argument(
        ..., help="Sensor files: panorama or omnidirectional images, CARMEN logs, ROS bags."
    ),
    kind: str = typer.Option(
        "auto",
        "--kind",
        help=f"Input kind: auto | {' | '.join(KIND_NAMES)}. auto: .log, .log.gz, .gz, .clf -> carmen; "
        ".bag, .db3, .mcap or a ROS 2 bag folder -> bag; other files -> omni with --center, else panorama.",
    ),
    bearing_offset_deg: float = typer.Option(
        0.0, "--bearing-offset-deg", help="Bearing (deg) of the left edge of column 0 (omni: of the image's +x axis)."
    ),
    counter_clockwise: bool = typer.Option(
        False, "--counter-clockwise", help="Panorama bearings grow with the column (default: they decrease)."
    ),
    center: tuple[float, float] | None = typer.Option(
        None, "--center", help="Omni: mirror centre X Y, pixels.", show_default=False
    ),
    radii: tuple[float, float] | None = typer.Option(
        None, "--radii", help="Omni: inner and outer ring radius R_IN R_OUT, pixels.", show_default=False
    ),
    mirror: bool = typer.Option(False, "--mirror", help="Omni: image seen from below (bearings clockwise)."),
    band: tuple[float, float] | None = typer.Option(
        None,
        "--band",
        help="Panorama rows to use, as parts of the height (top = 0), e.g. 0.2 0.8. "
        "Default: the middle half of a 2:1 equirectangular image, else all rows.",
        show_default=False,
    ),
    place: str | None = typer.Option(None, "--place", help="Place label of every observation."),
    labels: Path | None = typer.Option(
        None,
        "--labels",
        help="CSV of the photos' places (columns file,place[,x,y]; files relative to the CSV's folder): "
        "a whole tour in one call.",
        show_default=False,
    ),
    topic: list[str] | None = typer.Option(None, "--topic", metavar="TOPIC", help=TOPIC_HELP, show_default=False),
    base_frame: str | None = typer.Option(None, "--base-frame", metavar="FRAME", help=BASE_FRAME_HELP, show_default=False),
    pose_source: str = typer.Option("auto", "--pose-source", metavar="SOURCE", help=POSE_SOURCE_HELP),
    skip_bad: bool = typer.Option(False, "--skip-bad", help="Laser logs: skip malformed lines and report how many."),
    beacon_threshold: float | None = typer.Option(
        None,
        "--beacon-threshold",
        min=0.0,
        max=1e15,
        help="Laser logs: absolute intensity threshold of a beacon (default: adaptive, per scan).",
        show_default=False,
    ),
    beacon_ratio: float | None = typer.Option(
        None, "--beacon-ratio", min=1.0, max=1e6, help="Laser logs: a beacon is this many times its surroundings [2]."
    ),
    beacon_global_ratio: float | None = typer.Option(
        None, "--beacon-global-ratio", min=1.0, max=1e6, help="Laser logs: ...and this many times the scan's median [2.5]."
    ),
    beacon_window_m: float | None = typer.Option(
        None, "--beacon-window-m", min=0.01, max=10.0, help="Laser logs: half width of the surroundings, metres [0.4]."
    ),
    beacon_max_width: float | None = typer.Option(
        None, "--beacon-max-width", min=0.01, max=10.0, help="Laser logs: widest beacon, metres [0.5]."
    ),
    beacon_min_width: float | None = typer.Option(
        None, "--beacon-min-width", min=0.001, max=10.0, help="Laser logs: narrowest beacon, metres [0.04]."
    ),
    max_pixels: int = typer.Option(
        64_000_000, "--max-pixels", min=1, help="Images: refuse an image of more pixels (width x height) than this."
    ),
    json_out: Path | None = typer.Option(None, "--json", help="Write the observations as JSON Lines to this file."),
) -> None:
    """Extract vertical edges and colour patches (and laser features) from sensor files; print their bearings."""
    from ..io.jsonl import write_observations

    check_output(json_out, "--json")
    for flag, pair in (("--center", center), ("--radii", radii), ("--band", band)):
        if pair is not None and not all(np.isfinite(pair)):
            raise InvalidParameterError(f"{flag} must be finite numbers, got {pair[0]} {pair[1]}")
    if place is not None:
        from ..io.jsonl import check_text

        check_text(place, "--place")
    places: list[str | None] = [place] * len(files)
    if labels is not None:
        from ..io.jsonl import check_text
        from ..io.labels import match_labels, read_labels

        if place is not None:
            raise InvalidParameterError("give --place or --labels, not both")
        rows = match_labels(files, read_labels(labels), labels.parent)
        for r in rows:
            check_text(r.place, f"--labels place of {r.file}")
        places = [r.place for r in rows]
    from ..pipeline.files import KINDS, LASER_KINDS, FeatureOptions, detect_kind

    if kind != "auto" and kind not in KINDS:
        raise InvalidParameterError(f"--kind must be one of auto, {', '.join(KINDS)}, got {kind!r}")
    if band is not None and not (0.0 <= band[0] < band[1] <= 1.0):
        raise InvalidParameterError(f"--band must satisfy 0 <= LO < HI <= 1, got {band[0]} {band[1]}")
    if radii is not None and not (0.0 <= radii[0] < radii[1]):
        raise InvalidParameterError(f"--radii must satisfy 0 <= R_IN < R_OUT, got {radii[0]} {radii[1]}")
    bag = bag_options(topic, pose_source, base_frame)
    opts = FeatureOptions(
        notify=lambda s: err_console.print(s, soft_wrap=True, markup=False),
        place=place,
        bearing_offset=float(deg_to_rad(bearing_offset_deg)),
        counter_clockwise=counter_clockwise,
        center=center,
        radii=radii,
        mirror=mirror,
        band=band,
        topic=bag["topic"],
        base_frame=bag["base_frame"],
        pose_source=bag["pose_source"],
        skip_bad=skip_bad,
        beacon_threshold=beacon_threshold,
        max_pixels=max_pixels,
        beacon_params=tuple(
            (name, float(v))
            for name, v in (
                ("beacon_ratio", beacon_ratio),
                ("beacon_global_ratio", beacon_global_ratio),
                ("beacon_window_m", beacon_window_m),
                ("beacon_max_width", beacon_max_width),
                ("beacon_min_width", beacon_min_width),
            )
            if v is not None
        ),
    )
    from dataclasses import replace

    from rich.progress import Progress

    from .logs import format_scan_line

    observations: list[Observation] = []
    with Progress(console=real_console(err_console), transient=True, disable=len(files) < 2) as progress:
        task = progress.add_task("extracting", total=len(files))
        for path, where in zip(files, places, strict=True):
            k = kind
            if k == "auto":
                k = detect_kind(path) or ("omni" if center is not None else "panorama")
            fmt = format_scan_line if k in LASER_KINDS else format_observation
            for name, obs in KINDS[k](path, replace(opts, place=where)):
                console.print(fmt(name, obs), markup=False, soft_wrap=True)
                observations.append(obs)
            progress.advance(task)
    if json_out is not None:
        n = write_observations(json_out, observations)
        err_console.print(f"wrote {n} observations to {json_out}")


@bench_app.command("features")
def bench_features_cmd(
    offices: int = typer.Option(10, "--offices", help="Simulated offices."),
    poses: int = typer.Option(10, "--poses", help="Poses per office (within --radius of its anchor)."),
    radius: float = typer.Option(0.7, "--radius", help="Poses lie within this distance of the anchor, metres."),
    tol_deg: float = typer.Option(5.0, "--tol-deg", help="Largest bearing error of a match, degrees."),
    jpeg: int = typer.Option(85, "--jpeg", help="JPEG quality of the rendered images (0: no compression)."),
    no_omni: bool = typer.Option(False, "--no-omni", help="Skip the omnidirectional images."),
    seed: int = typer.Option(0, "--seed", help="Seed of offices, poses and sensor noise."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures as JSON to this file."),
) -> None:
    """Precision and recall of the feature extractors against the simulator's ground truth."""
    from rich.progress import Progress
    from rich.table import Table

    from ..experiments.extractors import run_extractor_bench
    from .bench import write_json

    check_output(json_out, "--json")
    if not 0 <= jpeg <= 100:
        raise InvalidParameterError(f"--jpeg must be in 0..100, got {jpeg}")
    with Progress(console=real_console(err_console), transient=True) as progress:
        task = progress.add_task("extracting", total=offices * poses)
        res = run_extractor_bench(
            n_offices=offices,
            n_poses=poses,
            radius=radius,
            tol_deg=tol_deg,
            jpeg_quality=jpeg or None,
            omni=not no_omni,
            seed=seed,
            on_step=lambda done, total: progress.update(task, completed=done),
        )
    table = Table(title=f"feature extractors vs simulator truth (within {tol_deg:g} deg, {offices}x{poses} poses)")
    for col in ("type", "true/meas.", "found/meas.", "precision", "recall", "mean |err| deg", "hue letter"):
        table.add_column(col, justify="right")

    def fmt(v: object, spec: str = ".3f") -> str:
        return "-" if v is None else format(v, spec)

    for name, s in res["types"].items():
        table.add_row(
            name,
            fmt(s["true_per_measurement"], ".2f"),
            fmt(s["found_per_measurement"], ".2f"),
            fmt(s["precision"]),
            fmt(s["recall"]),
            fmt(s["mean_abs_error_deg"], ".2f"),
            fmt(s.get("hue_letter_right")),
        )
    console.print(table)
    write_json(json_out, res)


@bench_app.command("panorama")
def bench_panorama_cmd(
    photo_dir: Path = typer.Argument(..., help="Folder of the equirectangular photos (file names relative to it)."),
    areas: Path | None = typer.Option(
        None, "--areas", help="Folder of a virtual tour's area definitions (*.ts).", show_default=False
    ),
    labels: Path | None = typer.Option(
        None, "--labels", help="Labels CSV instead of --areas: columns file,place[,x,y].", show_default=False
    ),
    minimap: Path | None = typer.Option(
        None,
        "--minimap",
        help="Map positions file (default: minimap/minimapLocations.ts beside --areas).",
        show_default=False,
    ),
    cache: Path | None = typer.Option(
        None, "--cache", help="JSON Lines cache of the extracted features (read, then rewritten).", show_default=False
    ),
    spacing: float = typer.Option(0.03, "--spacing", help="Places by position: centres this far apart, map units."),
    components: int = typer.Option(3, "-k", "--components", help="Mixture components per place (VE, CP)."),
    width: int = typer.Option(1440, "--width", help="Photos are resampled to this many columns (one per 0.25 deg)."),
    shortlist: int = typer.Option(8, "--shortlist", min=0, help="Views kept by the bag-of-words retrieval (recall)."),
    shortlist_appearance: int = typer.Option(
        5, "--shortlist-appearance", min=0, help="Views nearest by appearance added to the retrieval's shortlist."
    ),
    preset: str | None = typer.Option(
        None,
        "--preset",
        help="Also answer each query with a PlaceModel of this preset fit on the other photos (slow).",
        show_default=False,
    ),
    weights: str | None = typer.Option(
        None,
        "--weights",
        help="With --preset: its term weights replaced, 'fit' or TERM=W,... as for learn (terms left out weigh 1).",
        show_default=False,
    ),
    preset_only: bool = typer.Option(
        False, "--preset-only", help="With --preset: only the PlaceModel answers (skip the single terms and fusions)."
    ),
    unknown_prior: float = typer.Option(
        0.1, "--unknown-prior", min=0.0, max=0.99, help="With --preset: prior of the unknown place it reports."
    ),
    max_queries: int | None = typer.Option(
        None, "--max-queries", min=1, help="With --preset: at most this many queries (a seeded sample).", show_default=False
    ),
    speed_photos: int = typer.Option(
        0, "--speed", min=0, help="Also time features (on N photos at 2048x1024) and localize (1,000 views)."
    ),
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures as JSON to this file."),
) -> None:
    """Leave-one-out place recognition on real 360 deg photos: single terms, fusions, an HSV-histogram baseline."""
    from rich.progress import Progress
    from rich.table import Table

    from ..experiments.panorama import PANORAMA_METHODS, run_panorama_bench
    from .bench import write_json

    check_output(json_out, "--json")
    if not (spacing > 0 and np.isfinite(spacing)):
        raise InvalidParameterError(f"--spacing must be a positive number of map units, got {spacing}")
    if components < 1:
        raise InvalidParameterError(f"--components must be >= 1, got {components}")
    if width < 64:
        raise InvalidParameterError(f"--width must be >= 64 columns, got {width}")
    if (areas is None) == (labels is None):
        raise InvalidParameterError("give --areas (a tour's area definitions) or --labels (a labels CSV), one of them")
    overrides: dict[str, Any] = {}
    if preset is not None:
        from ..pipeline.presets import PRESETS
        from .options import model_overrides

        if preset not in PRESETS:
            raise InvalidParameterError(f"--preset must be one of {', '.join(PRESETS)}, got {preset!r}")
        overrides = model_overrides(weights=weights)
    elif weights is not None or preset_only:
        raise InvalidParameterError("--weights and --preset-only go with --preset")
    with Progress(console=real_console(err_console), transient=True) as progress:
        tasks: dict[str, object] = {}

        def step(name: str, done: int, total: int) -> None:
            if name not in tasks:
                tasks[name] = progress.add_task(name, total=total)
            progress.update(tasks[name], completed=done, total=total)  # type: ignore[arg-type]

        if preset_only:
            res: dict[str, Any] = {"photos": None, "places": {}}
        else:
            res = run_panorama_bench(
                photo_dir,
                areas,
                labels=labels,
                minimap=minimap,
                cache=cache,
                spacing=spacing,
                n_components=components,
                width=width,
                shortlist=shortlist,
                shortlist_appearance=shortlist_appearance,
                on_step=step,
            )
        if preset is not None or speed_photos:
            _bench_panorama_model(res, photo_dir, areas, labels, minimap, cache, width, spacing, preset, overrides,
                                  unknown_prior, max_queries, speed_photos, step)  # fmt: skip
    _print_panorama(res, PANORAMA_METHODS, Table)
    write_json(json_out, res)


def _bench_panorama_model(
    res: dict[str, Any],
    photo_dir: Path,
    areas: Path | None,
    labels: Path | None,
    minimap: Path | None,
    cache: Path | None,
    width: int,
    spacing: float,
    preset: str | None,
    overrides: dict[str, Any],
    unknown_prior: float,
    max_queries: int | None,
    speed_photos: int,
    step: Any,
) -> None:
    """The PlaceModel path (``--preset``) and the timings (``--speed``), into ``res``."""
    from ..experiments.panorama import (
        extract_features,
        load_labels_csv,
        load_tour_layout,
        places_by_area,
        places_by_position,
    )
    from ..experiments.panorama_model import run_preset_loo, speed

    photos = load_tour_layout(areas, minimap) if areas is not None else load_labels_csv(labels)  # type: ignore[arg-type]
    feats = extract_features(photo_dir, photos, cache=cache, width=width)
    res["photos"] = sum(f is not None for f in feats)
    if preset is not None:
        res["preset"] = {}
        for name, labs in (("area", places_by_area(photos)), ("position", places_by_position(photos, spacing=spacing))):
            idx = [i for i, f in enumerate(feats) if f is not None and labs[i] is not None]
            if len({labs[i] for i in idx}) < 2:
                continue
            res["preset"][name] = run_preset_loo(
                [feats[i].observation for i in idx],  # type: ignore[union-attr]
                [str(labs[i]) for i in idx],
                preset=preset,
                overrides=overrides,
                unknown_prior=unknown_prior,
                max_queries=max_queries,
                on_step=_stepper(step, f"{preset} by {name}"),
            )
    if speed_photos:
        have = [i for i, f in enumerate(feats) if f is not None]
        by_area = places_by_area(photos)
        res["speed"] = speed(
            [photo_dir / photos[i].file for i in have[:speed_photos]],
            [feats[i].observation for i in have],  # type: ignore[union-attr]
            [str(by_area[i]) for i in have],
        )


def _fmt(v: float | None, spec: str = ".3f") -> str:
    return "-" if v is None else format(v, spec)


def _stepper(step: Any, name: str) -> Any:
    return lambda done, total: step(name, done, total)


def _print_panorama(res: dict[str, Any], methods: tuple[str, ...], table_cls: Any) -> None:
    if res["places"]:
        _print_methods(res, methods, table_cls)
    _print_extras(res)


def _print_methods(res: dict[str, Any], methods: tuple[str, ...], table_cls: Any) -> None:
    table = table_cls(title=f"leave-one-out top-1 / mean rank / calibration error on {res['photos']} photos")
    table.add_column("method")
    for name, r in res["places"].items():
        table.add_column(f"{name} ({r['n_queries']} queries, {r['n_places']} places)", justify="right")
    for m in methods:
        cells = []
        for r in res["places"].values():
            f = r["methods"][m]
            cal = f["calibration"]
            cells.append(
                "-" if f["top1"] is None else f"{f['top1']:.3f} / {f['mean_rank']:.2f} / ECE {cal['ece']:.2f}"
            )
        table.add_row(m, *cells)
    console.print(table)


def _print_extras(res: dict[str, Any]) -> None:
    kp = res.get("keypoints", {})
    if kp:
        tilt = "-" if kp.get("tilt_deg") is None else f"{kp['tilt_deg']:.2f} deg"
        console.print(f"keypoints: relative-pose model {kp['model']} (median tilt of the training pairs {tilt})")
    for name, r in res["places"].items():
        rr = r.get("retrieval")
        if rr:
            console.print(
                f"retrieval ({name}, shortlist {rr['shortlist']} + {rr.get('shortlist_appearance', 0)} by appearance): "
                f"best-verified view kept {rr['best_view']:.3f}, "
                f"true place kept {rr['true_place']:.3f}; K top-1 {rr['top1_shortlist']:.3f} "
                f"(every view verified {rr['top1_all']:.3f})"
            )
    for key, h in res.get("heading_links", {}).items():
        if key != "pairs" and h["pairs"] and h["median_error_deg"] is not None:
            med = h["median_error_estimated_deg"]
            console.print(
                f"heading vs the tour's arrows, {key}: {h['estimated']} of {h['pairs']} pairs estimated, median error "
                f"{'-' if med is None else f'{med:.1f}'} deg (all pairs {h['median_error_deg']:.1f}), "
                f"within 10 deg {h['within_10'] or 0:.2f}"
            )
    hc = res.get("heading_closure")
    if hc and hc["triples"]:
        console.print(
            f"keypoint headings around {hc['triples']} triples of one area (h_ab + h_bc - h_ac, >= {hc['min_inliers']} "
            f"inliers): median {hc['median_deg']:.2f} deg (per pair about {hc['per_pair_deg']:.2f}), "
            f"within 2 deg {hc['within_2_deg']:.2f}"
        )
    for name, p in res.get("preset", {}).items():
        cal = p["calibration"] or {}
        unk = p["unknown"]
        console.print(
            f"preset {p['preset']} by {name}: top-1 {_fmt(p['top1'])} of {p['n_queries']}; ECE {_fmt(cal.get('ece'))}, "
            f"mean confidence {_fmt(cal.get('mean_confidence'))}, wrong answers above 0.9 / 0.99: "
            f"{_fmt(cal.get('wrong_above_0.9'))} / {_fmt(cal.get('wrong_above_0.99'))} of {cal.get('wrong', 0)}; "
            f"P(unknown) known places "
            f"{_fmt(unk['known']['mean'])}, unknown places {_fmt(unk['unknown']['mean'])}; "
            f"headings of right answers {p['heading_from']}"
        )
        for v, f in p.get("variants", {}).items():
            if v != "preset":
                c = f["calibration"]
                console.print(
                    f"  same models, {v}: top-1 {f['top1']:.3f}; ECE {c['ece']:.2f}, wrong answers above 0.9 / 0.99: "
                    f"{_fmt(c['wrong_above_0.9'])} / {_fmt(c['wrong_above_0.99'])} of {c['wrong']}"
                )
    sp = res.get("speed")
    if sp:
        console.print(
            f"speed (load average {' '.join(f'{x:.2f}' for x in sp['load_average'])}): features "
            f"{sp['features_cpu_s']['median']:.3f} s CPU a 2048x1024 photo (median of {sp['features_cpu_s']['photos']}); "
            f"localize {1000 * sp['localize_cpu_s']['median']:.1f} ms CPU ({1000 * sp['localize_wall_s']['median']:.1f} ms wall, "
            f"{sp.get('blas_threads') or '?'} BLAS threads) a query against {sp['views']} views"
        )


@bench_app.command("panorama-edges")
def bench_panorama_edges_cmd(
    labels: Path = typer.Argument(..., help="Hand labels of vertical edges (JSON, e.g. tests/data/campus_edges.json)."),
    photos: Path = typer.Option(..., "--photos", help="Folder the labels' file names are relative to."),
    tol_deg: float | None = typer.Option(
        None, "--tol-deg", help="Largest bearing error of a match, degrees (default: the labels').", show_default=False
    ),
    max_edges: int = typer.Option(12, "--max-edges", help="Keep the N strongest edges per photo (0: all)."),
    nms_deg: float = typer.Option(3.0, "--nms-deg", help="One edge per this many degrees (non-maximum suppression)."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures as JSON to this file."),
) -> None:
    """Precision and recall of the vertical-edge extractor against hand-labelled real photos."""
    from rich.table import Table

    from ..experiments.panorama import run_edge_bench
    from .bench import write_json

    check_output(json_out, "--json")
    if tol_deg is not None and not (tol_deg > 0 and np.isfinite(tol_deg)):
        raise InvalidParameterError(f"--tol-deg must be a positive number of degrees, got {tol_deg}")
    if max_edges < 0:
        raise InvalidParameterError(f"--max-edges must be >= 0, got {max_edges}")
    if not (nms_deg > 0 and np.isfinite(nms_deg)):
        raise InvalidParameterError(f"--nms-deg must be a positive number of degrees, got {nms_deg}")
    with err_console.status("extracting edges..."):
        res = run_edge_bench(labels, photos, tol_deg=tol_deg, edge_params={"max_edges": max_edges, "nms_deg": nms_deg})
    table = Table(title=f"vertical edges vs hand labels (within {res['tolerance_deg']:g} deg)")
    for col in ("photo", "labelled", "found", "matched"):
        table.add_column(col, justify="right")
    for r in res["photos"]:
        table.add_row(r["file"], str(r["true"]), str(r["found"]), str(r["matched"]))
    console.print(table)
    p, r = res["precision"], res["recall"]
    console.print(
        f"precision {'-' if p is None else f'{p:.3f}'}  recall {'-' if r is None else f'{r:.3f}'}  "
        f"({res['matched']} matched, {res['found']} found, {res['true']} labelled)"
    )
    write_json(json_out, res)
