"""Values read from a place database, checked like input: one line naming the table and the field.

A place database is a file: it can be damaged, edited or crafted. Every
number the loader hands on (the calibration, place positions, lambdas,
mixture weights, content hashes, the mapped runs, the preset) is checked
here, and schema version 5 files carry a digest of their whole content
(:func:`table_digests`) that catches a flipped byte anywhere in their rows.
"""

from __future__ import annotations

import hashlib
import math
import sqlite3
import struct
from collections.abc import Mapping, Sequence
from typing import Any

from ..errors import DatabaseError

__all__ = [
    "MAX_COORD_M",
    "TABLES",
    "check_calibration",
    "check_positions",
    "check_preset",
    "check_runs",
    "digest_value",
    "missing_tables",
    "table_digests",
]

#: Largest |x| or |y| of a stored position, metres (the JSON Lines reader's bound).
MAX_COORD_M = 1e9

#: Tables each schema version promises.
_V1 = frozenset({"meta", "places", "observations", "fingerprints", "mixtures", "graph_edges"})
_V2 = _V1 | {"range_descriptors", "place_positions", "content_hashes"}
TABLES: dict[str, frozenset[str]] = {"1": _V1, "2": _V2, "3": _V2, "4": _V2 | {"scan_map"}, "5": _V2 | {"scan_map"}}

#: The meta key of the content digest (schema version 5).
DIGEST_KEY = "checksum"


def missing_tables(version: str, tables: set[str]) -> list[str]:
    """The tables schema ``version`` promises that ``tables`` lacks, sorted."""
    return sorted(TABLES.get(version, frozenset()) - tables)


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


# field -> (low, high, integer): a number in [low, high] (None: open); every other number must be finite
_CALIBRATION: dict[str, tuple[float | None, float | None, bool]] = {
    "beta": (1e-12, 1e12, False),
    "metres_per_move": (1e-12, 1e12, False),
    "temper_metres": (0.0, 1e12, False),
    "temper_radians": (0.0, 1e6, False),
    "kidnap": (0.0, 1.0, False),
    "radius": (1e-12, MAX_COORD_M, False),
    "spacing": (1e-12, MAX_COORD_M, False),
    "alpha": (0.0, 1e12, False),
    "n_train": (0, 2**53, True),
    "calibration_rows": (0, 2**53, True),
    "outlier": (0.0, 1.0, False),
    "off_place": (0.0, 1.0, False),
    "heading_kappa": (0.0, 1e12, False),
    "heading_cap": (0.0, 1e12, False),
    "heading_temper_metres": (0.0, 1e12, False),
    "scan_gamma": (0.0, 1e12, False),
    "scan_fresh": (1, 10**6, True),
    "lost_kidnap": (0.0, 1.0, False),
    "lost_after": (1, 10**9, True),
    "gap_metres": (1e-12, 1e12, False),
    "hold_margin": (0.0, 1.0, False),
    "tie_break": (0.0, 1.0, False),
}
_NULLABLE = frozenset({"gap_metres", "lost_fit", "hold_margin", "tie_break", "metres_per_move"})


def check_calibration(value: Any, where: str) -> dict[str, Any]:
    """The stored calibration (``meta.calibration``) as a dict of checked values.

    Raises
    ------
    DatabaseError
        ``where: meta.calibration.FIELD must be ...`` for a value of the wrong
        type, not finite or out of its range.
    """
    if not isinstance(value, dict):
        raise DatabaseError(f"{where}: meta.calibration must be a JSON object, got {type(value).__name__}")
    for k, v in value.items():
        name = f"{where}: meta.calibration.{k}"
        if v is None and k in _NULLABLE:
            continue
        if isinstance(v, (bool, str, dict, list)) or v is None:
            if k in _CALIBRATION:
                raise DatabaseError(f"{name} must be a number, got {v!r}")
            continue  # a setting (a strategy's name, a flag, the stored config): checked where it is read
        if not _finite(v):
            raise DatabaseError(f"{name} must be a finite number, got {v!r}")
        rule = _CALIBRATION.get(k)
        if rule is None:
            if abs(v) > 1e15:
                raise DatabaseError(f"{name} is out of range ({v!r})")
            continue
        lo, hi, integer = rule
        if integer and (not isinstance(v, int) and not float(v).is_integer()):
            raise DatabaseError(f"{name} must be an integer, got {v!r}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise DatabaseError(f"{name} must be in [{lo:g}, {hi:g}], got {v!r}")
    return value


def check_positions(rows: list[tuple[Any, Any, Any, Any]], where: str) -> dict[str, tuple[float, float]]:
    """``place_positions`` rows ``(label, idx, x, y)`` as ``{label: (x, y)}`` in ``idx`` order, checked."""
    out: dict[str, tuple[float, float]] = {}
    seen_idx: set[int] = set()
    for lab, idx, x, y in sorted(rows, key=lambda r: (r[1] if isinstance(r[1], int) else 0)):
        if not isinstance(lab, str) or not lab:
            raise DatabaseError(f"{where}: place_positions.label must be non-empty text, got {lab!r}")
        if isinstance(idx, bool) or not isinstance(idx, int) or idx < 0 or idx in seen_idx:
            raise DatabaseError(f"{where}: place_positions.idx of place {lab!r} must be a distinct integer >= 0, got {idx!r}")
        seen_idx.add(idx)
        for axis, v in (("x", x), ("y", y)):
            if not _finite(v) or abs(v) > MAX_COORD_M:
                raise DatabaseError(
                    f"{where}: place_positions.{axis} of place {lab!r} must be a finite number of metres "
                    f"within +-{MAX_COORD_M:g}, got {v!r}"
                )
        out[lab] = (float(x), float(y))
    return out


def check_runs(value: Any, where: str) -> list[dict[str, Any]]:
    """``meta.runs``: a list of ``{"name", "key", "n_scans", "n_mapping"}`` with sane counts."""
    if not isinstance(value, list):
        raise DatabaseError(f"{where}: meta.runs must be a JSON list, got {type(value).__name__}")
    for k, r in enumerate(value):
        if not isinstance(r, dict):
            raise DatabaseError(f"{where}: meta.runs[{k}] must be a JSON object, got {type(r).__name__}")
        for f in ("name", "key"):
            if f in r and not isinstance(r[f], str):
                raise DatabaseError(f"{where}: meta.runs[{k}].{f} must be text, got {r[f]!r}")
        for f in ("n_scans", "n_mapping"):
            v = r.get(f, 0)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise DatabaseError(f"{where}: meta.runs[{k}].{f} must be an integer >= 0, got {v!r}")
        if r.get("n_mapping", 0) > r.get("n_scans", 0):
            raise DatabaseError(f"{where}: meta.runs[{k}].n_mapping {r['n_mapping']} exceeds n_scans {r.get('n_scans')}")
    return value


def check_preset(value: Any, where: str) -> dict[str, Any]:
    """``meta.preset``: an object with a name, options and laser extractor arguments that the extractor accepts."""
    if not isinstance(value, dict):
        raise DatabaseError(f"{where}: meta.preset must be a JSON object, got {type(value).__name__}")
    if not isinstance(value.get("name"), str):
        raise DatabaseError(f"{where}: meta.preset.name must be text, got {value.get('name')!r}")
    for f in ("options", "overrides", "features"):
        if f in value and not isinstance(value[f], dict):
            raise DatabaseError(f"{where}: meta.preset.{f} must be a JSON object, got {type(value[f]).__name__}")
    features = value.get("features") or {}
    if features:
        from ..errors import FingerlocError
        from ..features.laser import LaserParams

        try:
            LaserParams.from_kwargs(dict(features))
        except (FingerlocError, TypeError) as err:
            raise DatabaseError(f"{where}: meta.preset.features: {err}") from None
    return value


def check_number_map(value: Any, what: str, where: str, *, minimum: float | None = None, neg_inf: bool = False) -> dict[str, float]:
    """A stored ``{name: number}`` map (``lambdas``, ``unknown_costs``, ``fitted_weights``), checked."""
    if not isinstance(value, dict):
        raise DatabaseError(f"{where}: meta.{what} must be a JSON object, got {type(value).__name__}")
    out: dict[str, float] = {}
    for k, v in value.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise DatabaseError(f"{where}: meta.{what}.{k} must be a number, got {v!r}")
        f = float(v)
        if not (math.isfinite(f) or (neg_inf and f == -math.inf)):
            raise DatabaseError(f"{where}: meta.{what}.{k} must be a finite number, got {v!r}")
        if minimum is not None and f < minimum:
            raise DatabaseError(f"{where}: meta.{what}.{k} must be >= {minimum:g}, got {v!r}")
        out[str(k)] = f
    return out


def _encode_value(v: Any) -> bytes:
    if v is None:
        return b"N"
    if isinstance(v, int):
        return b"I" + str(v).encode() + b";"
    if isinstance(v, float):
        return b"F" + v.hex().encode() + b";"
    if isinstance(v, str):
        b = v.encode("utf-8", "surrogatepass")
        return b"S" + struct.pack("<Q", len(b)) + b
    if isinstance(v, bytes):
        return b"B" + struct.pack("<Q", len(v)) + v
    raise DatabaseError(f"unexpected value of type {type(v).__name__} in the place database")


def table_digests(con: sqlite3.Connection) -> dict[str, str]:
    """SHA-256 (hex) of every table's rows, by table name (the digests' own ``meta`` row left out).

    Rows are encoded value by value (type, then the value: integers and text
    exactly, floats by their bits, blobs as bytes) and sorted: a digest
    depends on the content only, not on SQLite's page layout or row order.
    """
    names = sorted(
        r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%'")
    )
    out = {}
    for name in names:
        rows = []
        for row in con.execute(f'SELECT * FROM "{name}"'):
            if name == "meta" and row and row[0] == DIGEST_KEY:
                continue
            rows.append(b"".join(_encode_value(v) for v in row))
        rows.sort()
        h = hashlib.sha256(struct.pack("<Q", len(rows)))
        for r in rows:
            h.update(struct.pack("<Q", len(r)))
            h.update(r)
        out[name] = h.hexdigest()
    return out


def digest_value(con: sqlite3.Connection) -> str:
    """The ``meta.checksum`` value of a database being written: its tables' digests as JSON."""
    import json

    return json.dumps({"sha256": table_digests(con)}, sort_keys=True, separators=(",", ":"))


def check_digest(con: sqlite3.Connection, meta: Mapping[str, Any], where: str, tables: Sequence[str]) -> None:
    """Compare the ``tables`` a reader used with their stored digests (schema version 5; older: nothing to do).

    Raises
    ------
    DatabaseError
        Naming the first table whose rows differ from its digest (a flipped
        byte, or an edit after fingerloc wrote the file), or a missing digest.
    """
    if meta.get("schema_version") in ("1", "2", "3", "4"):
        return
    import json

    try:
        stored = json.loads(meta.get(DIGEST_KEY, ""))["sha256"]
        if not isinstance(stored, dict):
            raise TypeError
    except (TypeError, ValueError, KeyError):
        raise DatabaseError(
            f"{where}: meta.{DIGEST_KEY} is missing or unreadable: the file is damaged or was edited; make it again"
        ) from None
    now = table_digests(con)
    for t in tables:
        if t in now and stored.get(t) != now[t]:
            raise DatabaseError(
                f"{where}: table {t} does not match its checksum (meta.{DIGEST_KEY}): a damaged byte or an edit "
                "after fingerloc wrote the file; restore a copy or make the database again"
            )
