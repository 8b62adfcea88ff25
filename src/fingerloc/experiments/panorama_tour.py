"""The development tours of ``fingerloc bench panorama``: photos, places, positions, and the tour's own headings.

Two sources of labels:

* a **virtual tour's source files**: TypeScript area definitions that list
  each area's photos (``id: '...'``, ``imageUrl: '...'``, ``buildingBlock``,
  ``floorLevel``), an optional table of hand-placed map positions per photo id
  (``'photo-id': { x: 0.5, y: 0.7 }``) and the navigation arrows between
  photos (:func:`load_tour_links`: ground-truth headings);
* a **labels CSV** (:func:`load_labels_csv`): one row per photo, columns
  ``file,place`` and optionally ``x,y`` (map units), the same file that
  ``fingerloc features --labels`` reads.

Nothing of the data ships with fingerloc: the commands read it from the
paths the user gives.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataFormatError, InvalidParameterError

__all__ = [
    "DEFAULT_BAND",
    "DEFAULT_WIDTH",
    "CampusPhoto",
    "TourLink",
    "load_labels_csv",
    "load_photo_band",
    "load_tour_layout",
    "load_tour_links",
    "places_by_area",
    "places_by_position",
]


DEFAULT_BAND = (0.25, 0.75)
DEFAULT_WIDTH = 1440


@dataclass(frozen=True, slots=True)
class CampusPhoto:
    """One photo of the tour.

    Attributes
    ----------
    photo_id : str
    file : str
        Path relative to the photo folder (``/``-separated).
    area : str
        Area id.
    floor : str
        ``"<building>-<floor>"``.
    position : (x, y) or None
        Map position (map units), when known.
    """

    photo_id: str
    file: str
    area: str
    floor: str
    position: tuple[float, float] | None


_AREA = re.compile(r":\s*Area\s*=\s*\{")
_PHOTO = re.compile(r"\bid:\s*'([^']+)',\s*imageUrl:\s*'([^']+)'")
_FIRST_ID = re.compile(r"\bid:\s*'([^']+)'")
_BLOCK = re.compile(r"\bbuildingBlock:\s*'([^']+)'")
_FLOOR = re.compile(r"\bfloorLevel:\s*(\d+)")
_POS = re.compile(r"'([^']+)':\s*\{\s*x:\s*([0-9.]+|null),\s*y:\s*([0-9.]+|null)\s*\}")


def load_tour_layout(areas_dir: str | Path, minimap: str | Path | None = None) -> list[CampusPhoto]:
    """The tour's photos with their area, floor and map position.

    Parameters
    ----------
    areas_dir : path
        Folder searched recursively for ``*.ts`` files holding ``... : Area = {``
        objects.
    minimap : path, optional
        File of ``'photo-id': { x: .., y: .. }`` entries; default: the first
        ``minimap/minimapLocations.ts`` next to ``areas_dir`` or above it.

    Returns
    -------
    list of CampusPhoto
        In the order of the sorted file names, then of the files' text; one per
        image file (the first area listing it wins).
    """
    root = Path(areas_dir)
    if not root.is_dir():
        raise DataFormatError("not a folder of area definitions (*.ts)", path=root)
    if minimap is None:
        for cand in (root.parent / "minimap" / "minimapLocations.ts", root / "minimap" / "minimapLocations.ts"):
            if cand.is_file():
                minimap = cand
                break
    positions: dict[str, tuple[float, float]] = {}
    if minimap is not None:
        try:
            text = Path(minimap).read_text(encoding="utf-8")
        except OSError as err:
            raise DataFormatError(f"cannot read: {err.strerror or err}", path=Path(minimap)) from err
        for pid, x, y in _POS.findall(text):
            if x != "null" and y != "null":
                positions[pid] = (float(x), float(y))
    out: list[CampusPhoto] = []
    seen: set[str] = set()
    for ts in sorted(root.rglob("*.ts")):
        text = ts.read_text(encoding="utf-8")
        starts = [m.end() for m in _AREA.finditer(text)]
        for k, s in enumerate(starts):
            chunk = text[s : starts[k + 1] if k + 1 < len(starts) else len(text)]
            area = _FIRST_ID.search(chunk)
            if area is None:
                continue
            block = _BLOCK.search(chunk)
            floor = _FLOOR.search(chunk)
            floor_key = f"{block.group(1) if block else '?'}-{floor.group(1) if floor else '?'}"
            for pid, url in _PHOTO.findall(chunk):
                rel = url.split("360_photos_compressed/", 1)[-1].lstrip("/")
                if rel in seen:
                    continue
                seen.add(rel)
                out.append(CampusPhoto(pid, rel, area.group(1), floor_key, positions.get(pid)))
    if not out:
        raise DataFormatError("no area with photos found in the *.ts files", path=root)
    return out


#: Bearing of each tour arrow relative to the photo's ``startingAngle`` (the tour's ``DIRECTION_ANGLES``).
_ARROW_OFFSETS: dict[str, float] = {
    "forward": 0.0,
    "forwardRight": 45.0,
    "right": 90.0,
    "backRight": 135.0,
    "back": 180.0,
    "backLeft": 225.0,
    "left": 270.0,
    "forwardLeft": 315.0,
}
#: The tour's explicit arrow angles for horizontal moves (its ``ARROW_OVERRIDES``).
_ARROW_OVERRIDES: dict[tuple[str, str], float] = {
    ("w-f1-main-entrance", "forwardLeft"): 155.0,
    ("w-gym-entry", "forward"): 220.0,
}
_START = re.compile(r"\bstartingAngle:\s*(-?[0-9.]+)")
_ARROW = re.compile(
    r"\b(forward|forwardRight|right|backRight|back|backLeft|left|forwardLeft):\s*\{\s*connection:\s*'([^']+)'\s*\}"
)


@dataclass(frozen=True, slots=True)
class TourLink:
    """Two photos the tour links both ways, with the heading between them from the tour's arrows.

    Attributes
    ----------
    a, b : str
        Photo files (relative, as :attr:`CampusPhoto.file`).
    heading_deg : float
        A feature at bearing ``x`` in ``a`` is at bearing ``x + heading_deg``
        in ``b`` (bearings counter-clockwise, the image's columns clockwise).
    same_area : bool
    """

    a: str
    b: str
    heading_deg: float
    same_area: bool


def load_tour_links(areas_dir: str | Path) -> list[TourLink]:
    """Ground-truth headings between linked photos, from the tour's navigation arrows.

    The tour shows, in photo ``a``, an arrow towards each linked photo at the
    viewer angle ``startingAngle + offset(direction)`` (or an explicit
    override); when ``b`` links back to ``a``, the line from ``a`` to ``b``
    is seen at viewer angle ``alpha`` in ``a`` and the opposite direction at
    ``beta`` in ``b``, so the two photos' frames differ by
    ``beta - 180 - alpha`` viewer degrees. The viewer angle grows with the
    image column (checked on the photos: the other sign doubles the median
    disagreement with an image-to-image correlation), i.e. clockwise, so the
    heading in bearings is ``alpha - beta + 180``. The arrows were placed by
    hand, at 45 deg steps from one angle per photo: a few degrees of error
    and sometimes more where a corridor bends.
    """
    root = Path(areas_dir)
    if not root.is_dir():
        raise DataFormatError("not a folder of area definitions (*.ts)", path=root)
    photos: dict[str, tuple[str, str, dict[str, float]]] = {}
    for ts in sorted(root.rglob("*.ts")):
        text = ts.read_text(encoding="utf-8")
        starts = [m.end() for m in _AREA.finditer(text)]
        for k, s0 in enumerate(starts):
            chunk = text[s0 : starts[k + 1] if k + 1 < len(starts) else len(text)]
            area = _FIRST_ID.search(chunk)
            if area is None:
                continue
            found = list(_PHOTO.finditer(chunk))
            for j, m in enumerate(found):
                body = chunk[m.end() : found[j + 1].start() if j + 1 < len(found) else len(chunk)]
                st = _START.search(body)
                start = float(st.group(1)) if st else 0.0
                arrows = {
                    target: _ARROW_OVERRIDES.get((m.group(1), d), (start + _ARROW_OFFSETS[d]) % 360.0)
                    for d, target in _ARROW.findall(body)
                }
                rel = m.group(2).split("360_photos_compressed/", 1)[-1].lstrip("/")
                photos.setdefault(m.group(1), (rel, area.group(1), arrows))
    links: list[TourLink] = []
    for pid, (file_a, area_a, arrows) in photos.items():
        for target, alpha in arrows.items():
            other = photos.get(target)
            if other is None or target <= pid or pid not in other[2]:
                continue
            beta = other[2][pid]
            links.append(TourLink(file_a, other[0], float((alpha - beta + 180.0) % 360.0), area_a == other[1]))
    return links


def places_by_area(photos: Sequence[CampusPhoto]) -> list[str | None]:
    """Place label of each photo: its area id."""
    return [p.area for p in photos]


def places_by_position(photos: Sequence[CampusPhoto], *, spacing: float = 0.03) -> list[str | None]:
    """Place label of each photo from its map position (None without one).

    Per floor, in order, a photo farther than ``spacing`` (map units) from
    every existing centre becomes a new centre; each photo then takes its
    nearest centre (as the laser benchmark's places, :mod:`.carmen`).
    """
    if not (math.isfinite(spacing) and spacing > 0):
        raise InvalidParameterError(f"spacing must be a positive number of map units, got {spacing!r}")
    centres: dict[str, list[tuple[float, float]]] = {}
    for p in photos:
        if p.position is None:
            continue
        cs = centres.setdefault(p.floor, [])
        if not cs or min(math.dist(c, p.position) for c in cs) > spacing:
            cs.append(p.position)
    out: list[str | None] = []
    for p in photos:
        if p.position is None:
            out.append(None)
            continue
        cs = centres[p.floor]
        k = int(np.argmin([math.dist(c, p.position) for c in cs]))
        out.append(f"{p.floor}#{k}")
    return out




def load_labels_csv(path: str | Path) -> list[CampusPhoto]:
    """The photos of a labels CSV (:func:`fingerloc.io.labels.read_labels`) as :class:`CampusPhoto` entries.

    ``area`` = the place, ``floor`` = ``""`` (one floor: positions are
    grouped over the whole CSV), ``photo_id`` = ``file``, files relative to
    the photo folder the caller reads from (or absolute).
    """
    from ..io.labels import read_labels

    return [CampusPhoto(r.file, r.file, r.place, "", r.position) for r in read_labels(path)]


# ---------------------------------------------------------------------------
# reading photos


def load_photo_band(path: str | Path, *, band: tuple[float, float] = DEFAULT_BAND, width: int = DEFAULT_WIDTH) -> Any:
    """The band of elevations of an equirectangular photo, resampled to ``width`` columns (a Panorama).

    Column 0's left edge is at bearing 0; bearings decrease to the right (the
    defaults of ``fingerloc features``).
    """
    from PIL import Image, UnidentifiedImageError

    from ..sensors import Panorama

    p = Path(path)
    try:
        with Image.open(p) as im:
            rgb = im.convert("RGB")
    except FileNotFoundError as err:
        raise DataFormatError("no such file", path=p) from err
    except (UnidentifiedImageError, OSError, ValueError) as err:
        raise DataFormatError(f"cannot read image: {err}", path=p) from err
    w, h = rgb.size
    top, bottom = round(band[0] * h), round(band[1] * h)
    crop = rgb.crop((0, top, w, bottom))
    new_h = max(2, round((bottom - top) * width / w))
    small = crop.resize((width, new_h), Image.Resampling.BOX)
    meta: dict[str, object] = {"source": str(p), "elevation_deg": (90.0 - 180.0 * top / h, 90.0 - 180.0 * bottom / h)}
    return Panorama(np.asarray(small, dtype=np.uint8), meta=meta)
