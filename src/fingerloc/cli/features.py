"""``fingerloc features``: extract features from sensor files and print or save them.

Each input *kind* has one reader function in :data:`KINDS` that turns a file
into ``(name, Observation)`` pairs (one per image, or one per scan of a log).
To add a kind (CARMEN logs, ROS bags), write such a function and register it
in :data:`KINDS`; options it needs go into :class:`FeatureOptions`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import typer

from ..angles import deg_to_rad, rad_to_deg360
from ..errors import DataFormatError, InvalidParameterError
from ..fingerprint import hue_letter
from ..observation import Observation
from ..sensors import Panorama
from ._io import check_output
from .app import app, bench_app, console, err_console

__all__ = ["KINDS", "FeatureOptions", "format_observation", "load_image", "panorama_from_file"]


@dataclass(frozen=True, slots=True)
class FeatureOptions:
    """Options of ``fingerloc features`` shared by every reader.

    Attributes
    ----------
    place : str or None
        Label of every observation.
    bearing_offset : float
        Radians: bearing of the left edge of panorama column 0, or of the
        omnidirectional image's ``+x`` axis.
    counter_clockwise : bool
        Panorama bearings grow with the column index (default: they decrease,
        as in a photograph taken turning right).
    center, radii : pairs of float or None
        Omnidirectional image: mirror centre (x, y) and ring radii, pixels.
    mirror : bool
        Omnidirectional image seen from below (bearings clockwise on screen).
    band : pair of float or None
        Rows (parts of the height, top = 0) of a panorama to use; ``None``:
        the middle half of a full 2:1 equirectangular image, else every row.
    max_width : int
        Panoramas wider than this are resampled down (area averaging).
    topic : str or None
        Topic of a ROS bag (for the ``bag`` kind).
    skip_bad : bool
        Laser logs: skip malformed lines / messages (their count goes to stderr).
    beacon_threshold : float or None
        Laser logs: absolute intensity threshold of a beacon, overriding the
        detector's per-scan adaptive threshold.
    max_pixels : int or None
        Images: largest width x height read (``None``: the default bound).
    beacon_params : tuple of (name, value)
        Laser logs: other beacon detector parameters of
        :class:`~fingerloc.features.laser.LaserParams` (``beacon_ratio``, ...).
    """

    place: str | None = None
    bearing_offset: float = 0.0
    counter_clockwise: bool = False
    center: tuple[float, float] | None = None
    radii: tuple[float, float] | None = None
    mirror: bool = False
    band: tuple[float, float] | None = None
    max_width: int = 1440
    topic: str | None = None
    skip_bad: bool = False
    beacon_threshold: float | None = None
    max_pixels: int | None = None
    beacon_params: tuple[tuple[str, float], ...] = ()


Reader = Callable[[Path, FeatureOptions], Iterator[tuple[str, Observation]]]


def load_image(path: Path, *, max_pixels: int | None = None) -> np.ndarray:
    """Read an image file (JPEG, PNG, ... via Pillow) as an (h, w, 3) ``uint8`` RGB array.

    At most ``max_pixels`` pixels (default :data:`fingerloc.io.images.DEFAULT_MAX_PIXELS`),
    checked before decoding.

    Raises
    ------
    DataFormatError
        Naming the path, when the file is missing, not an image, or too large.
    """
    from ..io.images import DEFAULT_MAX_PIXELS, open_image

    return open_image(path, max_pixels=DEFAULT_MAX_PIXELS if max_pixels is None else max_pixels)


def _shrink(img: np.ndarray, max_width: int) -> np.ndarray:
    h, w = img.shape[:2]
    if w <= max_width:
        return img
    from PIL import Image

    new_h = max(2, round(h * max_width / w))
    return np.asarray(Image.fromarray(img).resize((max_width, new_h), Image.Resampling.BOX), dtype=np.uint8)


def panorama_from_file(path: Path, opts: FeatureOptions) -> Panorama:
    """A :class:`Panorama` from an equirectangular image file (see :class:`FeatureOptions`)."""
    img = load_image(path, max_pixels=opts.max_pixels)
    h, w = img.shape[:2]
    if w < 64 or h < 8:
        raise DataFormatError(f"image too small for a 360 deg panorama: {w}x{h} pixels", path=path)
    band = opts.band
    if band is None and abs(w / h - 2.0) < 0.05:
        band = (0.25, 0.75)  # full equirectangular: elevations -45..+45 deg
    if band is not None:
        lo, hi = round(band[0] * h), round(band[1] * h)
        img = img[lo:hi]
    img = _shrink(img, opts.max_width)
    meta: dict[str, object] = {"source": str(path)}
    return Panorama(img, bearing_offset=opts.bearing_offset, clockwise=not opts.counter_clockwise, meta=meta)


def _read_panorama(path: Path, opts: FeatureOptions) -> Iterator[tuple[str, Observation]]:
    from ..features.vision import observation_from_views

    pano = panorama_from_file(path, opts)
    yield str(path), observation_from_views(panorama=pano, label=opts.place)


def _read_omni(path: Path, opts: FeatureOptions) -> Iterator[tuple[str, Observation]]:
    from ..features.vision import observation_from_views, unwarp_omni

    if opts.center is None or opts.radii is None:
        raise InvalidParameterError("--kind omni needs --center X Y and --radii R_IN R_OUT (pixels)")
    img = load_image(path, max_pixels=opts.max_pixels)
    width = int(np.clip(round(np.pi * sum(opts.radii) / 360.0) * 360, 360, max(360, opts.max_width)))
    pano = unwarp_omni(
        img,
        opts.center,
        opts.radii[0],
        opts.radii[1],
        width=int(width),
        bearing_offset=opts.bearing_offset,
        mirror=opts.mirror,
    )
    yield str(path), observation_from_views(panorama=pano, label=opts.place)


def _read_carmen(path: Path, opts: FeatureOptions) -> Iterator[tuple[str, Observation]]:
    from .logs import iter_carmen_observations

    return iter_carmen_observations(path, opts)


def _read_bag(path: Path, opts: FeatureOptions) -> Iterator[tuple[str, Observation]]:
    from .logs import iter_bag_observations

    return iter_bag_observations(path, opts)


#: Input kinds: name -> reader. Laser log readers (``carmen``, ``bag``, in :mod:`.logs`)
#: yield one ``(name, observation_from_scan(scan, label=opts.place))`` per scan.
KINDS: dict[str, Reader] = {
    "panorama": _read_panorama,
    "omni": _read_omni,
    "carmen": _read_carmen,
    "bag": _read_bag,
}


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
        help=f"Input kind: auto | {' | '.join(KINDS)}. auto: .log, .log.gz, .gz, .clf -> carmen; "
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
    topic: str | None = typer.Option(None, "--topic", help="ROS bag: the LaserScan topic (when there are several)."),
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
    if kind != "auto" and kind not in KINDS:
        raise InvalidParameterError(f"--kind must be one of auto, {', '.join(KINDS)}, got {kind!r}")
    if band is not None and not (0.0 <= band[0] < band[1] <= 1.0):
        raise InvalidParameterError(f"--band must satisfy 0 <= LO < HI <= 1, got {band[0]} {band[1]}")
    for flag, pair in (("--center", center), ("--radii", radii), ("--band", band)):
        if pair is not None and not all(np.isfinite(pair)):
            raise InvalidParameterError(f"{flag} must be finite numbers, got {pair[0]} {pair[1]}")
    if place is not None:
        from ..io.jsonl import check_text

        check_text(place, "--place")
    if radii is not None and not (0.0 <= radii[0] < radii[1]):
        raise InvalidParameterError(f"--radii must satisfy 0 <= R_IN < R_OUT, got {radii[0]} {radii[1]}")
    opts = FeatureOptions(
        place=place,
        bearing_offset=float(deg_to_rad(bearing_offset_deg)),
        counter_clockwise=counter_clockwise,
        center=center,
        radii=radii,
        mirror=mirror,
        band=band,
        topic=topic,
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
    from .logs import LASER_KINDS, detect_kind, format_scan_line

    observations: list[Observation] = []
    for path in files:
        k = kind
        if k == "auto":
            k = detect_kind(path) or ("omni" if center is not None else "panorama")
        fmt = format_scan_line if k in LASER_KINDS else format_observation
        for name, obs in KINDS[k](path, opts):
            console.print(fmt(name, obs), markup=False, soft_wrap=True)
            observations.append(obs)
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
    with Progress(console=err_console, transient=True) as progress:
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
