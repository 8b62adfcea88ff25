"""Labels of a photo tour: a CSV file with one row per photo (``file,place`` and optionally ``x,y``).

Read by ``fingerloc features --labels`` (each photo gets its place) and
``fingerloc bench panorama --labels`` (places, and places by position from
``x,y``). A header row names the columns, in any order; other columns are
ignored::

    file,place,x,y
    hall/1.jpg,hall,0.0,0.0
    hall/2.jpg,hall,2.5,0.4
    kitchen/1.jpg,kitchen,,

Paths are ``/``-separated (a ``\\`` is read as ``/``); what they are relative
to is the caller's (:func:`match_labels`).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..errors import DataFormatError

__all__ = ["MAX_LABELS_BYTES", "PhotoLabel", "match_labels", "read_labels"]

#: Largest labels CSV read (bytes): a tour of a million photos fits.
MAX_LABELS_BYTES = 64 << 20


@dataclass(frozen=True, slots=True)
class PhotoLabel:
    """One row of a labels CSV.

    Attributes
    ----------
    file : str
        The photo's path as written (``/``-separated).
    place : str
        Its place label.
    position : (x, y) or None
        Its map position (any unit), when given.
    """

    file: str
    place: str
    position: tuple[float, float] | None = None


def read_labels(path: str | Path) -> list[PhotoLabel]:
    """The photos of a labels CSV: columns ``file,place`` and optionally ``x,y`` (a header row names them).

    Each row gives a photo file, its place label, and, when the ``x`` and
    ``y`` columns exist and are filled, its map position.

    Raises
    ------
    DataFormatError
        Naming the file and line: unreadable, larger than :data:`MAX_LABELS_BYTES`,
        binary (NUL bytes) or not UTF-8, a malformed CSV row (a field over
        csv's limit), no ``file`` / ``place`` column, an empty file or place,
        a repeated file, a non-numeric or half-given position.
    """
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            raw = fh.read(MAX_LABELS_BYTES + 1)  # bounded: /dev/zero or a huge file is refused, not read whole
    except FileNotFoundError as err:
        raise DataFormatError("no such file", path=p) from err
    except OSError as err:
        raise DataFormatError(f"cannot read the labels ({err.strerror or err})", path=p) from err
    if len(raw) > MAX_LABELS_BYTES:
        raise DataFormatError(f"larger than {MAX_LABELS_BYTES:,} bytes: not a labels CSV", path=p)
    if b"\0" in raw:
        raise DataFormatError("binary data (NUL bytes), not a labels CSV", path=p, line=raw.count(b"\n", 0, raw.index(b"\0")) + 1)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise DataFormatError(f"not UTF-8 text (byte 0x{raw[err.start]:02x}); save the CSV as UTF-8", path=p,
                              line=raw.count(b"\n", 0, err.start) + 1) from None  # fmt: skip
    reader = csv.reader(text.splitlines())
    try:
        rows = list(reader)
    except csv.Error as err:
        raise DataFormatError(f"not a CSV row ({err})", path=p, line=max(reader.line_num, 1)) from None
    if not rows:
        raise DataFormatError("the labels file is empty (expected a header row file,place[,x,y])", path=p)
    header = [h.strip().lower() for h in rows[0]]
    if "file" not in header or "place" not in header:
        raise DataFormatError(f"the header row must name the columns file and place (and optionally x, y), got {rows[0]!r}", path=p, line=1)
    col = {name: header.index(name) for name in ("file", "place", "x", "y") if name in header}
    out: list[PhotoLabel] = []
    seen: set[str] = set()
    for lineno, row in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in row):
            continue
        cells = [c.strip() for c in row] + [""] * len(header)
        file, place = cells[col["file"]], cells[col["place"]]
        if not file or not place:
            raise DataFormatError("every row needs a file and a place", path=p, line=lineno)
        file = file.replace("\\", "/")
        if file in seen:
            raise DataFormatError(f"the file {file!r} is listed twice", path=p, line=lineno)
        seen.add(file)
        pos = None
        if "x" in col and "y" in col:
            x, y = cells[col["x"]], cells[col["y"]]
            if x or y:
                try:
                    pos = (float(x), float(y))
                except ValueError as err:
                    raise DataFormatError(f"x and y must be numbers, got {x!r} and {y!r}", path=p, line=lineno) from err
                if not all(math.isfinite(v) for v in pos):
                    raise DataFormatError(f"x and y must be finite, got {x!r} and {y!r}", path=p, line=lineno)
        out.append(PhotoLabel(file, place, pos))
    if not out:
        raise DataFormatError("the labels file lists no photo", path=p)
    return out


def match_labels(photos: Sequence[Path], labels: Sequence[PhotoLabel], base: Path) -> list[PhotoLabel]:
    """The row of each photo: the row whose file, relative to ``base`` (the CSV's folder) or absolute, is the
    photo; else the row whose file is the photo's path as given; else the only row with the photo's file name.

    Raises
    ------
    DataFormatError
        Naming a photo that no row (or more than one row by file name) names.
    """
    by_path = {}
    for r in labels:
        p = Path(r.file)
        by_path[str((p if p.is_absolute() else base / p).resolve())] = r
    by_text = {r.file: r for r in labels}
    by_name: dict[str, list[PhotoLabel]] = {}
    for r in labels:
        by_name.setdefault(Path(r.file).name, []).append(r)
    out = []
    for photo in photos:
        got = by_path.get(str(Path(photo).resolve())) or by_text.get(Path(photo).as_posix())
        if got is None:
            named = by_name.get(Path(photo).name, [])
            if len(named) != 1:
                why = "no row names it" if not named else f"{len(named)} rows have its file name"
                raise DataFormatError(f"the labels give no place for this photo ({why})", path=Path(photo))
            got = named[0]
        out.append(got)
    return out
