"""Sensor files -> observations, one reader per input kind (``fingerloc features``).

Each input *kind* has one reader function in :data:`KINDS` that turns a file
into ``(name, Observation)`` pairs (one per image, or one per scan of a log).
To add a kind, write such a function and register it in :data:`KINDS`;
options it needs go into :class:`FeatureOptions`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataFormatError, InvalidParameterError
from ..observation import Observation
from ..sensors import Panorama
from .readers import detect_kind, iter_bag_observations, iter_carmen_observations

__all__ = ["KINDS", "LASER_KINDS", "FeatureOptions", "Reader", "detect_kind", "load_image", "panorama_from_file"]

#: Input kinds that are laser logs (one observation per scan).
LASER_KINDS: tuple[str, ...] = ("carmen", "bag")


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
    topic : str, tuple of str or None
        ROS bag: the scan topic; several topics are merged into one
        observation per time step (:func:`fingerloc.io.rosbag.iter_bag_scans`).
    base_frame : str or None
        ROS bag: the robot's frame (default: the root of the static transforms above the lidars).
    pose_source : str
        ROS bag: ``auto``, ``none``, ``tf``, ``tf:FRAME``, ``odom`` or ``odom:TOPIC``.
    skip_bad : bool
        Laser logs: skip malformed lines / messages (their count goes to stderr).
    beacon_threshold : float or None
        Laser logs: absolute intensity threshold of a beacon, overriding the
        detector's per-scan adaptive threshold.
    notify : callable or None
        Laser logs: gets a note on skipped lines.
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
    topic: str | tuple[str, ...] | None = None
    base_frame: str | None = None
    pose_source: str = "auto"
    skip_bad: bool = False
    beacon_threshold: float | None = None
    notify: Callable[[str], None] | None = None
    max_pixels: int | None = None
    beacon_params: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        import math

        def finite(name: str, v: Any) -> None:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InvalidParameterError(f"{name} must be a finite number, got {v!r}")

        finite("bearing_offset (--bearing-offset-deg)", self.bearing_offset)
        if self.center is not None:
            for v in self.center:
                finite("center (--center)", v)
        if self.radii is not None:
            r_in, r_out = self.radii
            finite("radii (--radii)", r_in)
            finite("radii (--radii)", r_out)
            if not 0 <= r_in < r_out:
                raise InvalidParameterError(f"radii (--radii) must satisfy 0 <= inner < outer, got {self.radii!r}")
        if self.band is not None:
            lo, hi = self.band
            finite("band (--band)", lo)
            finite("band (--band)", hi)
            if not 0 <= lo < hi <= 1:
                raise InvalidParameterError(f"band (--band) must satisfy 0 <= top < bottom <= 1, got {self.band!r}")
        if isinstance(self.max_width, bool) or not isinstance(self.max_width, int) or self.max_width < 64:
            raise InvalidParameterError(f"max_width must be an integer >= 64, got {self.max_width!r}")
        if self.max_pixels is not None and (isinstance(self.max_pixels, bool) or not isinstance(self.max_pixels, int)
                                            or self.max_pixels < 1):  # fmt: skip
            raise InvalidParameterError(f"max_pixels (--max-pixels) must be a positive integer, got {self.max_pixels!r}")
        if self.beacon_threshold is not None:
            finite("beacon_threshold (--beacon-threshold)", self.beacon_threshold)


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
    meta: dict[str, object] = {"source": str(path), "equirectangular": abs(w / h - 2.0) < 0.05}
    if band is not None:
        lo, hi = round(band[0] * h), round(band[1] * h)
        img = img[lo:hi]
        if img.shape[0] < 2:
            raise DataFormatError(f"the band {band!r} of a {w}x{h} image holds {img.shape[0]} row(s)", path=path)
        if meta["equirectangular"]:  # rows are elevations from +90 (top) to -90 deg (the keypoints' positions)
            meta["elevation_deg"] = (90.0 - 180.0 * lo / h, 90.0 - 180.0 * hi / h)
    _check_derived(path, img.shape[1], img.shape[0], opts)
    img = _shrink(img, opts.max_width)
    return Panorama(img, bearing_offset=opts.bearing_offset, clockwise=not opts.counter_clockwise, meta=meta)


#: Arrays the pipeline derives from an image at a fixed width (the keypoint band's float images, a few at once)
#: must stay under this part of the pixel limit.
DERIVED_SHARE = 4


def _check_derived(path: Path, width: int, height: int, opts: FeatureOptions) -> None:
    """Every array the panorama pipeline allocates must stay under the pixel limit, not only the decoded image.

    The panorama is shrunk to ``max_width`` columns (never grown), and the
    keypoint detector resamples the band to a fixed width (1440 columns):
    a tall thin image (64 x 20000) would make that band 1440 x 450,000.
    """
    from ..features.keypoints import KeypointParams
    from ..io.images import DEFAULT_MAX_PIXELS, check_pixels

    limit = max(1, (DEFAULT_MAX_PIXELS if opts.max_pixels is None else opts.max_pixels) // DERIVED_SHARE)
    k = KeypointParams().width
    rows = max(8, round(height * k / max(width, 1)))
    check_pixels(k, rows, limit, f"its keypoint band ({width}x{height} resampled to {k} columns)", path)
    shrunk = (width, height) if width <= opts.max_width else (opts.max_width, max(2, round(height * opts.max_width / width)))
    check_pixels(shrunk[0], shrunk[1], limit, "its panorama band", path)


def _read_panorama(path: Path, opts: FeatureOptions) -> Iterator[tuple[str, Observation]]:
    from ..features.vision import PHOTO_EDGE_PARAMS, observation_from_views

    pano = panorama_from_file(path, opts)
    # a full 2:1 photo: only the strongest edges (real photos show many weak ones)
    params = PHOTO_EDGE_PARAMS if pano.meta.get("equirectangular") else {}
    obs = observation_from_views(panorama=pano, label=opts.place, appearance=True, profile=True, source=str(path), **params)
    yield str(path), _with_keypoints(obs, pano)


def _with_keypoints(obs: Observation, pano: Panorama) -> Observation:
    """The observation with the panorama's keypoints (term ``K``)."""
    from dataclasses import replace

    from ..features.keypoints import extract_keypoints

    return replace(obs, keypoints=extract_keypoints(pano))


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
    obs = observation_from_views(panorama=pano, label=opts.place, appearance=True, profile=True, source=str(path))
    yield str(path), _with_keypoints(obs, pano)


def _features(opts: FeatureOptions) -> dict[str, Any]:
    out: dict[str, Any] = dict(opts.beacon_params)
    if opts.beacon_threshold is not None:
        out["beacon_threshold"] = float(opts.beacon_threshold)
    return out


def _read_carmen(path: Path, opts: FeatureOptions) -> Iterator[tuple[str, Observation]]:
    return iter_carmen_observations(path, place=opts.place, skip_bad=opts.skip_bad, notify=opts.notify, **_features(opts))


def _read_bag(path: Path, opts: FeatureOptions) -> Iterator[tuple[str, Observation]]:
    return iter_bag_observations(path, place=opts.place, skip_bad=opts.skip_bad, notify=opts.notify,
                                 bag_options={"topic": opts.topic, "base_frame": opts.base_frame,
                                              "pose_source": opts.pose_source}, **_features(opts))  # fmt: skip


#: Input kinds: name -> reader. Laser log readers (``carmen``, ``bag``, :mod:`.readers`)
#: yield one ``(name, observation_from_scan(scan, label=opts.place))`` per scan.
KINDS: dict[str, Reader] = {
    "panorama": _read_panorama,
    "omni": _read_omni,
    "carmen": _read_carmen,
    "bag": _read_bag,
}


