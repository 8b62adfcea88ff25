"""The place database: one SQLite file, versioned schema, atomic saves, never pickle.

Layout (schema version 5, written now; docs/FORMATS.md §2)::

    meta(key TEXT PRIMARY KEY, value TEXT)         -- format, schema_version, fingerloc_version,
                                                   -- params, lambdas, unknown_costs, fitted_weights,
                                                   -- default_fov, preset, calibration, runs,
                                                   -- term_params (the keypoint term's fitted choices),
                                                   -- temper (PlaceModel's fitted factor) (JSON)
    places(id INTEGER PRIMARY KEY, label TEXT UNIQUE, medoid INTEGER,
           consensus_letters TEXT, consensus_bearings BLOB)
    observations(id INTEGER PRIMARY KEY, place_id INTEGER, idx INTEGER, data BLOB, source TEXT)
                                                   -- binary records (fingerloc.map._records)
    fingerprints(obs_id INTEGER PRIMARY KEY, letters TEXT, bearings BLOB)
                                                   -- only those the records do not give back bit for bit
    mixtures(place_id INTEGER, term TEXT, weights BLOB, means BLOB, sigmas BLOB,
             PRIMARY KEY (place_id, term))
    graph_edges(src TEXT, dst TEXT, count INTEGER, PRIMARY KEY (src, dst))
    range_descriptors(place_id INTEGER PRIMARY KEY, width INTEGER, data BLOB, encoding TEXT)
                                                   -- beam counts per bin (|u1, <u2, <u4) or float64 rows (<f8)
    place_positions(label TEXT PRIMARY KEY, idx INTEGER, x REAL, y REAL)
    content_hashes(hash BLOB PRIMARY KEY) WITHOUT ROWID   -- SHA-256 digests of the stored observations
    scan_map(id INTEGER PRIMARY KEY CHECK (id = 0), origin_x REAL, origin_y REAL, resolution REAL,
             nx INTEGER, ny INTEGER, sigma REAL, floor REAL, clip REAL, n_cells INTEGER,
             encoding TEXT, cells BLOB)        -- the mapping run's laser end points (at most one row):
                                               -- the occupancy grid as a zlib'd bitmap

Schema version 1 stored each observation as its JSON Lines record
(``observations.record TEXT``) and every fingerprint; version 2 added the map
of a recorded run (place positions, hex content hashes, float64 range
descriptors, the meta keys preset, calibration and runs); version 3 stored
observations as binary records, digests as bytes and range counts as small
integers; version 4 adds the ``scan_map`` table (a map without one, and every
older file: no scan evidence); version 5 adds the meta keys ``sensor`` (what
the views were made of: modality, field of view) and ``checksum`` (a digest of
every table's rows, :func:`fingerloc.map._validate.table_digests`, checked when
a table is read). All
still load. Learning an observation whose content hash is stored again does not
duplicate it.

Arrays are little-endian float64 blobs (radians) unless said otherwise. A save writes a complete new
file next to the target in one transaction, syncs it, and renames it over the
target: a crash mid-write leaves the old file as it was.

Writers are serialised by an exclusive lock (``flock``) on ``<db>.lock`` next
to the database (:mod:`fingerloc.map._lock`): :func:`locked` holds it around a
read-modify-write (``learn`` into an existing database), and
:func:`save_model` takes it too, so two writers at once never lose each
other's places; a writer that waits says so and gives up after a timeout.
Under the lock, temporary files ``<db>.*.tmp`` that a killed writer left are
removed, and SQLite's own leftovers of another program (a hot rollback
journal, a WAL file) are settled by SQLite before the database is read or
replaced. Only a regular file (or a symbolic link to one: the link stays,
its target is replaced) is written; a new file's mode follows the umask, a
replaced file keeps its mode. Inside an :class:`~fingerloc.atomic.OutputGroup`
the rename waits for the group's end. Reading opens the file read-only.
Every value read is checked (:mod:`fingerloc.map._validate`): a crafted but
valid SQLite file gives a :class:`~fingerloc.errors.DatabaseError` naming the
table and field, never a wrong model or a traceback.
"""

from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import sqlite3
import tempfile
from collections.abc import Iterator, Mapping
from contextlib import closing, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..atomic import check_target, replace, temporary_name, temporary_patterns, umask, write_fault
from ..errors import DatabaseError, DataFormatError, FingerlocError
from ..io.jsonl import observation_from_record, observation_to_record, parse_record
from ..model import PlaceModel
from ._lock import DEFAULT_LOCK_TIMEOUT_S, locked, real_path
from ._records import decode_observation, encode_observation
from ._validate import (
    DIGEST_KEY,
    check_calibration,
    check_digest,
    check_number_map,
    check_positions,
    check_preset,
    check_runs,
    digest_value,
    missing_tables,
)
from .database_rows import decode_rows

__all__ = [
    "DEFAULT_LOCK_TIMEOUT_S",
    "FORMAT",
    "SCHEMA_VERSION",
    "MapInfo",
    "hold_lock",
    "load_model",
    "locked",
    "observation_hash",
    "read_graph_edges",
    "read_map_info",
    "save_model",
]

FORMAT = "fingerloc-places"
SCHEMA_VERSION = 5
#: Schema versions this fingerloc reads.
READABLE_VERSIONS = ("1", "2", "3", "4", "5")
#: SQLite page size of a written database: small pages keep the tables of a small map small.
PAGE_SIZE = 1024
#: Largest number of mixture components a stored model may have (``-k``).
MAX_COMPONENTS = 1000

_SCHEMA = """
CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE places(id INTEGER PRIMARY KEY, label TEXT UNIQUE NOT NULL, medoid INTEGER NOT NULL,
                    consensus_letters TEXT, consensus_bearings BLOB);
CREATE TABLE observations(id INTEGER PRIMARY KEY, place_id INTEGER NOT NULL REFERENCES places(id),
                          idx INTEGER NOT NULL, data BLOB NOT NULL, source TEXT);
CREATE TABLE fingerprints(obs_id INTEGER PRIMARY KEY REFERENCES observations(id), letters TEXT NOT NULL,
                          bearings BLOB NOT NULL);
CREATE TABLE mixtures(place_id INTEGER NOT NULL REFERENCES places(id), term TEXT NOT NULL,
                      weights BLOB NOT NULL, means BLOB NOT NULL, sigmas BLOB NOT NULL,
                      PRIMARY KEY (place_id, term));
CREATE TABLE graph_edges(src TEXT NOT NULL, dst TEXT NOT NULL, count INTEGER NOT NULL, PRIMARY KEY (src, dst));
CREATE TABLE range_descriptors(place_id INTEGER PRIMARY KEY REFERENCES places(id), width INTEGER NOT NULL,
                               data BLOB NOT NULL, encoding TEXT NOT NULL);
"""

# The map of a recorded run (MapInfo), in its own tables (schema versions 2 to 4; scan_map from version 4).
_SCHEMA_MAP = """
CREATE TABLE place_positions(label TEXT PRIMARY KEY, idx INTEGER NOT NULL, x REAL NOT NULL, y REAL NOT NULL);
CREATE TABLE content_hashes(hash BLOB PRIMARY KEY) WITHOUT ROWID;
CREATE TABLE scan_map(id INTEGER PRIMARY KEY CHECK (id = 0), origin_x REAL NOT NULL, origin_y REAL NOT NULL,
                      resolution REAL NOT NULL, nx INTEGER NOT NULL, ny INTEGER NOT NULL, sigma REAL NOT NULL,
                      floor REAL NOT NULL, clip REAL NOT NULL, n_cells INTEGER NOT NULL, encoding TEXT NOT NULL,
                      cells BLOB NOT NULL);
"""

#: ``scan_map.encoding``: the grid's cells ``(i, j)`` as bit ``i * ny + j`` of a bitmap, most significant bit
#: first in each byte (``numpy.packbits``), compressed with zlib.
SCAN_MAP_ENCODING = "bitmap-zlib"


@dataclass(slots=True)
class MapInfo:
    """What a place database holds besides the model (schema version 2).

    Attributes
    ----------
    preset : dict or None
        The resolved preset (``fingerloc.pipeline.presets.ResolvedPreset.to_json``).
    positions : dict of str -> (x, y)
        Place centres in the run's frame, metres, in creation order.
    calibration : dict or None
        The filters' parameters calibrated on the mapping part
        (``fingerloc.pipeline.tracker.Calibration.to_json``).
    content_hashes : set of str
        :func:`observation_hash` of every stored observation.
    runs : list of dict
        The mapped runs: ``{"name", "key", "n_scans", "n_mapping"}``.
    scan_map : ScanMap or None
        The mapping run's laser end points
        (:class:`~fingerloc.map.scan_map.ScanMap`, schema version 4); ``None``:
        none stored (a run without ranges, ``map --no-scan``, older files).
    sensor : dict or None
        What the stored views were made of (schema version 5,
        :func:`sensor_summary`): ``modality`` (``"laser"``, ``"image"`` or
        both), ``fov_deg`` (the views' median field of view, degrees),
        ``poses`` (how many views have one), and whatever a command adds
        (a bag's ``topics``); ``None`` in older files (then computed from the
        stored views on load).
    """

    preset: dict[str, Any] | None = None
    positions: dict[str, tuple[float, float]] = field(default_factory=dict)
    calibration: dict[str, Any] | None = None
    content_hashes: set[str] = field(default_factory=set)
    runs: list[dict[str, Any]] = field(default_factory=list)
    scan_map: Any = None
    sensor: dict[str, Any] | None = None


#: Feature kinds of a laser view and of an image view (what :func:`sensor_summary` calls the modality).
LASER_FIELDS = ("c", "ex", "b", "w", "ranges")
IMAGE_FIELDS = ("ve", "cp", "appearance", "profile", "keypoints")


def view_modality(obs: Any) -> set[str]:
    """``{"laser"}``, ``{"image"}``, both or neither: what an observation's features come from."""
    out = set()
    for kind, names in (("laser", LASER_FIELDS), ("image", IMAGE_FIELDS)):
        for n in names:
            v = getattr(obs, n, None)
            if v is not None and (not hasattr(v, "size") or v.size) and (not hasattr(v, "__len__") or len(v)):
                out.add(kind)
                break
    return out


def sensor_summary(observations: Any) -> dict[str, Any]:
    """What a set of views was made of: ``{"modality": [...], "fov_deg": median width, "poses": count, "views": n}``."""
    views = list(observations)
    kinds: set[str] = set()
    for o in views:
        kinds |= view_modality(o)
    fov = [math.degrees(sum(w for _, w in o.fov)) for o in views]
    return {
        "modality": sorted(kinds),
        "fov_deg": round(float(np.median(fov)), 3) if fov else None,
        "poses": sum(o.pose is not None for o in views),
        "views": len(views),
    }


def observation_hash(obs: Any) -> str:
    """A content hash of an observation with its place label (SHA-256 hex).

    The hash of the observation's JSON Lines record (bearings in degrees
    rounded to 9 digits, keys sorted): two observations with the same place,
    features, field of view, pose, timestamp, scan and appearance hash alike.
    The same measurement under another label is another claim, not a copy.
    """
    rec = observation_to_record(obs, ndigits=9)
    text = json.dumps(rec, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _write_map_info(con: sqlite3.Connection, info: MapInfo | None) -> None:
    for statement in _SCHEMA_MAP.strip().split(";\n"):
        if statement.strip():
            con.execute(statement)  # inside the save's transaction (executescript would commit it)
    if info is None:
        return
    meta = {
        "preset": info.preset,
        "calibration": info.calibration,
        "runs": info.runs,
        "sensor": info.sensor,
    }
    con.executemany("INSERT INTO meta VALUES (?, ?)", [(k, _meta_json(v)) for k, v in meta.items() if v])
    con.executemany(
        "INSERT INTO place_positions VALUES (?, ?, ?, ?)",
        [(str(lab), k, float(x), float(y)) for k, (lab, (x, y)) in enumerate(info.positions.items())],
    )
    try:
        digests = sorted(bytes.fromhex(h) for h in info.content_hashes)
    except ValueError as err:
        raise DatabaseError(f"a content hash is not hexadecimal ({err})") from err
    con.executemany("INSERT INTO content_hashes VALUES (?)", [(h,) for h in digests])
    if info.scan_map is not None:
        con.execute("INSERT INTO scan_map VALUES (0, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", _scan_map_row(info.scan_map))


def _scan_map_row(sm: Any) -> tuple[Any, ...]:
    """A :class:`~fingerloc.map.scan_map.ScanMap` as a ``scan_map`` row (without its id)."""
    import zlib

    from .scan_map import SCAN_MAX_CELLS, ScanMap

    if not isinstance(sm, ScanMap):
        raise DatabaseError(f"a scan map must be a ScanMap, got {type(sm).__name__}")
    nx, ny = sm.shape
    if nx * ny > SCAN_MAX_CELLS:
        raise DatabaseError(f"cannot store a scan map of {nx} x {ny} cells (at most {SCAN_MAX_CELLS})")
    grid = np.zeros((nx, ny), dtype=bool)
    grid[sm.cells[:, 0], sm.cells[:, 1]] = True
    blob = zlib.compress(np.packbits(grid.reshape(-1)).tobytes(), 9)
    o = sm.origin
    return (float(o[0]), float(o[1]), float(sm.resolution), nx, ny, float(sm.sigma), float(sm.floor),
            float(sm.clip), int(sm.cells.shape[0]), SCAN_MAP_ENCODING, blob)  # fmt: skip


def _scan_map_from_row(row: tuple[Any, ...]) -> Any:
    """The :class:`~fingerloc.map.scan_map.ScanMap` of a ``scan_map`` row (without its id), checked."""
    import zlib

    from .scan_map import SCAN_MAX_CELLS, ScanMap

    ox, oy, res, nx, ny, sigma, floor, clip, n_cells, encoding, blob = row
    if encoding != SCAN_MAP_ENCODING:
        raise DatabaseError(f"unknown encoding {encoding!r}")
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in (nx, ny, n_cells)):
        raise DatabaseError(f"grid size {nx!r} x {ny!r} and cell count {n_cells!r} must be integers")
    if not (1 <= nx and 1 <= ny and nx * ny <= SCAN_MAX_CELLS):
        raise DatabaseError(f"grid of {nx} x {ny} cells (1 to {SCAN_MAX_CELLS})")
    if not all(isinstance(v, float) and math.isfinite(v) for v in (ox, oy, res, sigma, floor, clip)):
        raise DatabaseError("origin, resolution, sigma, floor and clip must be finite numbers")
    if not isinstance(blob, bytes):
        raise DatabaseError(f"cells must be a blob, got {type(blob).__name__}")
    size = (nx * ny + 7) // 8
    try:
        z = zlib.decompressobj()
        raw = z.decompress(blob, size)
        if len(raw) != size or z.unconsumed_tail or not z.eof or z.unused_data:
            raise DatabaseError(f"the cells' bitmap is not {size} bytes")
    except zlib.error as err:
        raise DatabaseError(f"the cells' bitmap is not zlib data ({err})") from err
    bits = np.unpackbits(np.frombuffer(raw, dtype=np.uint8))
    if np.any(bits[nx * ny :]):
        raise DatabaseError("the cells' bitmap has bits beyond the grid")
    cells = np.argwhere(bits[: nx * ny].reshape(nx, ny).astype(bool))
    if cells.shape[0] != n_cells:
        raise DatabaseError(f"{cells.shape[0]} occupied cells, the row says {n_cells}")
    try:
        return ScanMap(np.array([ox, oy]), res, (nx, ny), cells, sigma=sigma, floor=floor, clip=clip)
    except FingerlocError as err:
        raise DatabaseError(str(err)) from err


def _read_scan_map(con: sqlite3.Connection, path: str | Path) -> Any:
    """The stored scan map, or None (none stored, or a file older than schema version 4)."""
    if not con.execute("SELECT 1 FROM sqlite_master WHERE type='table' AND name='scan_map'").fetchone():
        return None
    rows = con.execute(
        "SELECT origin_x, origin_y, resolution, nx, ny, sigma, floor, clip, n_cells, encoding, cells FROM scan_map"
    ).fetchall()
    if not rows:
        return None
    if len(rows) > 1:
        raise DatabaseError(f"{path}: corrupt scan map in the place database ({len(rows)} rows, at most 1)")
    try:
        return _scan_map_from_row(rows[0])
    except DatabaseError as err:
        raise DatabaseError(f"{path}: corrupt scan map in the place database ({err})") from err


def read_map_info(path: str | Path, *, scan_map: bool = True) -> MapInfo:
    """The map information of a place database (empty for a schema version 1 file), every value checked.

    ``scan_map``: read the scan map too (False: ``info.scan_map`` is None).

    Raises
    ------
    DatabaseError
        When the file is not a readable place database or a value of its map
        information is of the wrong type or out of range (the message names
        the table and field).
    """
    with _open(path) as con:
        meta = dict(con.execute("SELECT key, value FROM meta").fetchall())
        if meta.get("schema_version") == "1":
            return MapInfo()
        where = str(path)
        info = MapInfo()
        for key in ("preset", "calibration", "runs", "sensor"):
            if key not in meta:
                continue
            try:
                value = json.loads(meta[key])
            except (TypeError, ValueError) as err:
                raise DatabaseError(f"{where}: meta.{key} is not valid JSON ({err})") from None
            if key == "preset":
                info.preset = check_preset(value, where)
            elif key == "calibration":
                info.calibration = check_calibration(value, where)
            elif key == "runs":
                info.runs = check_runs(value, where)
            elif isinstance(value, dict):
                info.sensor = value
            else:
                raise DatabaseError(f"{where}: meta.sensor must be a JSON object, got {type(value).__name__}")
        info.positions = check_positions(con.execute("SELECT label, idx, x, y FROM place_positions").fetchall(), where)
        hashes = set()
        v3 = meta.get("schema_version") not in ("1", "2")
        for (h,) in con.execute("SELECT hash FROM content_hashes"):
            if v3 and isinstance(h, bytes) and len(h) == 32:  # schema version 3: the digest itself
                hashes.add(h.hex())
            elif not v3 and isinstance(h, str) and len(h) == 64 and all(c in "0123456789abcdef" for c in h):
                hashes.add(h)
            else:
                want = "a 32-byte SHA-256 digest" if v3 else "64 hexadecimal digits"
                raise DatabaseError(f"{where}: content_hashes.hash must be {want}, got {h!r}")
        info.content_hashes = hashes
        if scan_map:
            info.scan_map = _read_scan_map(con, path)
        _verify(con, path, (*_INFO_TABLES, "scan_map") if scan_map else _INFO_TABLES)
    return info


def hold_lock(path: str | Path, *, timeout: float | None = None, notify: Any = None) -> None:
    """Take the writer lock of ``path`` until the current :class:`~fingerloc.atomic.OutputGroup` ends.

    For a command whose read-modify-write spans several functions (``track
    --graph-from`` reads the database, runs the filter, then stores the
    graph): the lock is held from this call to the group's last rename.
    Outside a group, use ``with locked(path):`` around the read and the write.

    Raises
    ------
    InvalidParameterError
        No output group is active.
    DatabaseLockedError
        Another process held the lock for ``timeout`` seconds.
    """
    from ..atomic import current_group
    from ..errors import InvalidParameterError

    group = current_group()
    if group is None:
        raise InvalidParameterError("hold_lock needs an active OutputGroup (or use 'with locked(path):')")
    group.hold(locked(path, timeout=timeout, notify=notify))


def _remove_stale(real: Path) -> None:
    """Remove temporary files of dead writers (call under :func:`locked`: no live writer has any)."""
    for pattern in temporary_patterns(real):
        for tmp in real.parent.glob(pattern):
            for f in (tmp, Path(str(tmp) + "-journal")):
                try:
                    f.unlink(missing_ok=True)
                except OSError:
                    pass


def _blob(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype="<f8").tobytes()


def _array(b: Any) -> np.ndarray:
    if not isinstance(b, bytes) or len(b) % 8:
        raise DatabaseError(f"corrupt array in the place database (expected a float64 blob, got {type(b).__name__})")
    a = np.frombuffer(b, dtype="<f8").astype(np.float64)
    if not np.all(np.isfinite(a)):
        raise DatabaseError("corrupt array in the place database (a value is not finite)")
    return a


def _default_fov(groups: list[list[Any]]) -> tuple[tuple[float, float], ...] | None:
    """The field of view most observations share, when it is not the full circle (stored once, in ``meta``)."""
    from collections import Counter

    from ..observation import FULL_FOV

    common = Counter(o.fov for g in groups for o in g).most_common(1)
    return None if not common or common[0][0] == FULL_FOV or common[0][1] < 2 else common[0][0]


def _observation_blob(obs: Any, stored_fp: Any, scan: bool, default_fov: Any, make_fp: Any) -> tuple[bytes, bool]:
    """An observation's binary record, and whether its fingerprint must be stored too.

    Wall lengths and ranges go as float32 when the fingerprint computed from
    the decoded record is bit for bit ``stored_fp`` (else as float64); the
    fingerprint is stored only when even the float64 record does not give it back.
    """
    data = b""
    for walls32 in (True, False) if obs.w.size else (False,):
        data = encode_observation(obs, scan=scan, default_fov=default_fov, walls32=walls32)
        if stored_fp is None:
            return data, False
        again = make_fp(decode_observation(data, label=obs.label, source=obs.source, default_fov=default_fov))
        if again.letters == stored_fp[0] and np.array_equal(again.bearings, stored_fp[1]):
            return data, False
    return data, True


def _observation_blobs(
    observations: list[Any], stored: list[Any], scan: bool, default_fov: Any, params: dict[str, Any]
) -> list[tuple[bytes, bool]]:
    """:func:`_observation_blob` of every observation, the fingerprints of the decoded records computed in batches."""
    from .database_rows import record_fingerprints

    def fingerprints(rows: list[int], data: list[bytes]) -> list[Any]:
        obs = [observations[i] for i in rows]
        return record_fingerprints(data, [o.label for o in obs], [o.source for o in obs], params, default_fov=default_fov)

    def same(fp: Any, want: Any) -> bool:
        return bool(fp.letters == want[0] and np.array_equal(fp.bearings, want[1]))

    out = [
        (encode_observation(o, scan=scan, default_fov=default_fov, walls32=bool(o.w.size)), False) for o in observations
    ]
    check = [i for i, s in enumerate(stored) if s is not None]
    retry: list[int] = []
    for i, fp in zip(check, fingerprints(check, [out[i][0] for i in check]), strict=True):
        if not same(fp, stored[i]):
            if observations[i].w.size:  # float32 walls changed the fingerprint: float64 ones
                retry.append(i)
            else:
                out[i] = (out[i][0], True)
    if retry:
        again = [encode_observation(observations[i], scan=scan, default_fov=default_fov) for i in retry]
        for i, data, fp in zip(retry, again, fingerprints(retry, again), strict=True):
            out[i] = (data, not same(fp, stored[i]))
    return out


#: Encodings of the range term's rows in ``range_descriptors.encoding`` (schema version 3): numpy dtypes.
_RANGE_ENCODINGS = {"<f8": "descriptors", "|u1": "counts", "<u2": "counts", "<u4": "counts"}


def _range_blob(desc: np.ndarray, counts: Any) -> tuple[bytes, str]:
    """A place's range rows as (blob, encoding): its beam counts as small integers when they give the
    descriptors back bit for bit, else the float64 descriptors."""
    from ..terms.range import descriptors_from_counts

    if counts is not None and counts.shape == desc.shape and np.array_equal(descriptors_from_counts(counts), desc):
        top = int(counts.max(initial=0))
        dtype = "|u1" if top < 2**8 else "<u2" if top < 2**16 else "<u4"
        if top < 2**32 and int(counts.min(initial=0)) >= 0:
            return np.ascontiguousarray(counts, dtype=dtype).tobytes(), dtype
    return _blob(desc), "<f8"


def _range_rows(data: Any, encoding: Any, width: int) -> tuple[str, np.ndarray]:
    """``("descriptors", float64 rows)`` or ``("counts", int64 rows)`` of a ``range_descriptors`` row."""
    kind = _RANGE_ENCODINGS.get(encoding) if isinstance(encoding, str) else None
    if kind is None or not isinstance(data, bytes):
        raise DatabaseError(f"corrupt range descriptors in the place database (encoding {encoding!r})")
    if kind == "descriptors":
        a = _array(data)
    else:
        item = np.dtype(encoding).itemsize
        if len(data) % item:
            raise DatabaseError(f"corrupt range counts in the place database ({len(data)} bytes of {encoding})")
        a = np.frombuffer(data, dtype=encoding).astype(np.int64)
    if a.size % width:
        raise DatabaseError(f"corrupt range descriptors in the place database (not rows of {width})")
    return kind, a.reshape(-1, width)


def _costs_to_json(costs: Any) -> Any:
    """An alignment cost model as JSON: its full tables (``None`` for unit costs)."""
    if costs is None:
        return None
    try:
        return {"substitution": _compact(np.asarray(costs.substitution).tolist()), "indel": _compact(np.asarray(costs.indel).tolist())}
    except AttributeError as err:
        raise DatabaseError(f"cannot store alignment costs of type {type(costs).__name__}") from err


def _compact(values: Any) -> Any:
    """Nested lists of floats with the whole numbers written as integers (``1`` for ``1.0``: the same value, shorter JSON)."""
    if isinstance(values, list):
        return [_compact(v) for v in values]
    return int(values) if isinstance(values, float) and values.is_integer() and abs(values) < 2**53 else values


def _costs_from_json(data: Any) -> Any:
    if data is None:
        return None
    from ..align import CostModel

    return CostModel(substitution=np.asarray(data["substitution"]), indel=np.asarray(data["indel"]))


def _meta_json(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"))


def save_model(
    model: PlaceModel,
    path: str | Path,
    *,
    graph_edges: Mapping[tuple[str, str], int] | None = None,
    info: MapInfo | None = None,
) -> int:
    """Write a fitted model to a place database, atomically.

    The model's state (:meth:`PlaceModel.to_state`) is spread over the tables
    of the module docstring: observations as JSON Lines records, the
    fingerprint term's fingerprints, medoids and consensus strings, the
    mixture terms' parameters, the distance terms' calibration in ``meta``.

    Parameters
    ----------
    model : PlaceModel
        A fitted model.
    path : str or Path
        The database file; replaced as a whole if it exists.
    graph_edges : mapping (src, dst) -> count, optional
        Transitions of the place graph to store with the places.
    info : MapInfo, optional
        Place positions, calibration, preset, content hashes (schema version
        2), the scan map (schema version 4), the sensor summary (schema
        version 5; computed from the model's views when ``info`` has none).

    Returns
    -------
    int
        Size of the written file in bytes.

    Raises
    ------
    InvalidParameterError
        The target is not a regular file (a directory, a device, a FIFO, a
        symbolic link loop) or its folder is missing or read-only.
    DatabaseError
        The file cannot be written (a full disk, a file-size limit, a
        read-only file system): one line, the old file untouched and no
        temporary file left.
    """
    state = model.to_state()
    target = Path(path)
    params = dict(state["params"])
    params["costs"] = _costs_to_json(params["costs"])
    rs = params["random_state"]
    params["random_state"] = rs if isinstance(rs, int) or rs is None else None
    params["terms"] = list(params["terms"])
    if params["weights"] is not None and not isinstance(params["weights"], str):
        params["weights"] = dict(params["weights"])
    real = check_target(target, "place database")
    if info is None:
        info = MapInfo()
    if info.sensor is None:
        info = MapInfo(**{**{f: getattr(info, f) for f in MapInfo.__dataclass_fields__}, "sensor": sensor_summary(
            o for group in state["observations"] for o in group)})  # fmt: skip
    with locked(target):
        _remove_stale(real)
        try:
            return _save_locked(real, params, state, graph_edges, info)
        except sqlite3.Error as err:
            why = write_fault(real.parent, str(err))
            raise DatabaseError(f"{target}: cannot write the place database ({why}); it is unchanged") from None
        except OSError as err:
            why = write_fault(real.parent, err.strerror or str(err)) if err.errno in (errno.ENOSPC, errno.EFBIG, errno.EIO) else (err.strerror or str(err))
            raise DatabaseError(f"{target}: cannot write the place database ({why}); it is unchanged") from None


def _save_locked(
    target: Path,
    params: dict[str, Any],
    state: dict[str, Any],
    graph_edges: Mapping[tuple[str, str], int] | None,
    info: MapInfo | None,
) -> int:
    """Write the tables of the module docstring to a new file beside ``target``, then rename it over ``target``."""
    labels = state["labels"]
    terms = state["terms"]
    fp = terms.get("Fp")
    rng = terms.get("R")
    lambdas = {n: t["lambda"] for n, t in terms.items() if "lambda" in t}
    unknown = {n: t["unknown_cost"] for n, t in terms.items() if t.get("unknown_cost") is not None}
    directory = target.parent
    mode = target.stat().st_mode & 0o7777 if target.is_file() else 0o666 & ~umask()

    prefix, suffix = temporary_name(target)
    try:
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=directory)
    except OSError as err:
        raise DatabaseError(f"{target}: cannot write in {directory} ({err.strerror or err})") from err
    os.close(fd)
    try:
        with closing(sqlite3.connect(tmp)) as con:
            con.execute(f"PRAGMA page_size={PAGE_SIZE}")  # before the first table
            con.execute("PRAGMA journal_mode=DELETE")
            with con:  # one transaction
                con.executescript("BEGIN;" + _SCHEMA.replace(";\n", ";\n"))
                meta = {
                    "format": FORMAT,
                    "schema_version": str(SCHEMA_VERSION),
                    "fingerloc_version": __version__,
                    "params": _meta_json(params),
                    "lambdas": _meta_json(lambdas),
                    "unknown_costs": _meta_json(unknown),
                    "fitted_weights": _meta_json(state["weights"]),
                }
                if state.get("temper", 1.0) != 1.0:  # PlaceModel(temper=True)'s fitted factor
                    meta["temper"] = _meta_json(float(state["temper"]))
                if "K" in terms:  # the keypoint term's parameters and fitted model choice (JSON-ready)
                    meta["term_params"] = _meta_json({"K": {k: v for k, v in terms["K"].items() if k not in ("lambda", "unknown_cost")}})
                default_fov = _default_fov(state["observations"])
                if default_fov is not None:
                    meta["default_fov"] = _meta_json([list(pair) for pair in default_fov])
                if any(isinstance(lab, int) and not isinstance(lab, bool) for lab in labels):
                    meta["labels"] = _meta_json([lab if isinstance(lab, int) and not isinstance(lab, bool) else str(lab) for lab in labels])
                con.executemany("INSERT INTO meta VALUES (?, ?)", meta.items())
                place_rows = []
                views: list[tuple[int, int, Any, Any]] = []  # (place, index, observation, stored fingerprint)
                for pid, (label, group) in enumerate(zip(labels, state["observations"], strict=True)):
                    cons = fp["consensus"][pid] if fp else None
                    place_rows.append((
                        pid,
                        str(label),
                        fp["medoids"][pid] if fp else 0,
                        None if cons is None else cons[0],
                        None if cons is None else _blob(cons[1]),
                    ))  # fmt: skip
                    for idx, obs in enumerate(group):
                        views.append((pid, idx, obs, fp["fingerprints"][pid][idx] if fp else None))
                con.executemany("INSERT INTO places VALUES (?, ?, ?, ?, ?)", place_rows)
                blobs = _observation_blobs([v[2] for v in views], [v[3] for v in views], rng is None, default_fov, params)
                # ids 1, 2, ... in order: those SQLite gives rows inserted one by one into the new table
                con.executemany(
                    "INSERT INTO observations(id, place_id, idx, data, source) VALUES (?, ?, ?, ?, ?)",
                    ((row + 1, pid, idx, blobs[row][0], obs.source) for row, (pid, idx, obs, _) in enumerate(views)),
                )
                con.executemany(
                    "INSERT INTO fingerprints VALUES (?, ?, ?)",
                    ((row + 1, stored[0], _blob(stored[1])) for row, (_, _, _, stored) in enumerate(views) if blobs[row][1] and stored is not None),
                )
                for name, t in terms.items():
                    for pid, mx in enumerate(t.get("mixtures", [])):
                        if mx is not None:
                            w, m, sg = mx
                            con.execute("INSERT INTO mixtures VALUES (?, ?, ?, ?, ?)", (pid, name, _blob(w), _blob(m), _blob(sg)))
                for pid, desc in enumerate(rng["descriptors"] if rng is not None else []):
                    counts = rng.get("counts", [None] * (pid + 1))[pid]
                    con.execute("INSERT INTO range_descriptors VALUES (?, ?, ?, ?)", (pid, int(desc.shape[1]), *_range_blob(desc, counts)))
                for (src, dst), count in (graph_edges or {}).items():
                    con.execute("INSERT INTO graph_edges VALUES (?, ?, ?)", (src, dst, int(count)))
                _write_map_info(con, info)
                con.execute("INSERT INTO meta VALUES (?, ?)", (DIGEST_KEY, digest_value(con)))
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        size = Path(tmp).stat().st_size
        replace(tmp, target)
    except BaseException:
        for f in (Path(tmp), Path(tmp + "-journal")):
            try:
                f.unlink(missing_ok=True)
            except OSError:
                pass
        raise
    return size


@contextmanager
def _open(path: str | Path) -> Iterator[sqlite3.Connection]:
    p = Path(path)
    if p.is_dir():
        raise DatabaseError(f"{p} is a directory, not a place database")
    if not p.is_file():
        raise DatabaseError(f"{p}: no such place database")
    if Path(str(real_path(p)) + "-journal").exists():
        with locked(p):  # SQLite rolls the journal back (fingerloc.map._lock.settle_journals)
            pass
    try:
        con = sqlite3.connect(f"file:{_uri_path(p)}?mode=ro", uri=True)
    except sqlite3.Error as err:
        raise DatabaseError(f"{p}: cannot open as a place database ({err})") from err
    try:
        try:
            ok = con.execute("PRAGMA quick_check").fetchone()
            if ok is None or ok[0] != "ok":
                why = " ".join(str(ok[0]).split()) if ok else "no answer"  # SQLite's report spans lines
                raise DatabaseError(f"{p}: corrupt place database ({why})")
            tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
            if "meta" not in tables:
                raise DatabaseError(f"{p}: not a fingerloc place database (no meta table)")
            meta = dict(con.execute("SELECT key, value FROM meta").fetchall())
            if meta.get("format") != FORMAT:
                raise DatabaseError(f"{p}: not a fingerloc place database (format {meta.get('format')!r})")
            version = meta.get("schema_version")
            if version not in READABLE_VERSIONS:
                newer = isinstance(version, str) and version.isdigit() and int(version) > SCHEMA_VERSION
                raise DatabaseError(
                    f"{p}: place database schema version {version!r} is not supported "
                    f"(this fingerloc reads versions {', '.join(READABLE_VERSIONS)}"
                    + ("; it was written by a newer fingerloc: upgrade fingerloc)" if newer else ")")
                )
            missing = missing_tables(str(version), tables)
            if missing:
                raise DatabaseError(
                    f"{p}: schema version {version} promises the table(s) {', '.join(missing)}, which the file "
                    "lacks (damaged or edited); restore a copy or make the database again"
                )
            yield con
        except sqlite3.Error as err:
            raise DatabaseError(f"{p}: not a valid place database ({err})") from err
        except UnicodeDecodeError as err:
            raise DatabaseError(f"{p}: damaged place database (a text value is not UTF-8: {err.reason})") from err
    finally:
        con.close()


_VERIFIED: dict[tuple[str, int, int, int, tuple[str, ...]], bool] = {}

#: Observation rows read from the database and decoded at a time (their records are then let go).
LOAD_CHUNK_ROWS = 20_000

#: The tables each reader hands on (their digests are checked after the reader's own checks).
_MODEL_TABLES = ("meta", "places", "observations", "fingerprints", "mixtures", "range_descriptors")
_INFO_TABLES = ("meta", "place_positions", "content_hashes")


def _verify(con: sqlite3.Connection, path: str | Path, tables: tuple[str, ...]) -> None:
    """Check the digests of ``tables`` (schema version 5) once per file version (inode, size, modification time)."""
    try:
        st = os.stat(path)
        key: tuple[str, int, int, int, tuple[str, ...]] | None = (
            str(real_path(path)), st.st_ino, st.st_size, st.st_mtime_ns, tables)  # fmt: skip
    except OSError:
        key = None
    if key is not None and key in _VERIFIED:
        return
    check_digest(con, dict(con.execute("SELECT key, value FROM meta").fetchall()), str(path), tables)
    if key is not None:
        if len(_VERIFIED) > 64:
            _VERIFIED.clear()
        _VERIFIED[key] = True


def _uri_path(p: Path) -> str:
    from urllib.parse import quote

    return quote(str(p.absolute()))


def load_model(path: str | Path) -> PlaceModel:
    """Read a model from a place database without refitting anything.

    Raises
    ------
    DatabaseError
        When the file is missing, a directory, not SQLite, truncated or
        corrupt, of another format or an unsupported schema version, or when
        a stored value is of the wrong type or out of range (a medoid beyond
        the place's observations, a row naming a missing place, a place
        without observations, an array that is not a float64 blob).
    """
    with _open(path) as con:
        try:
            model = _load(con, path)
        except DatabaseError:
            raise
        except (KeyError, TypeError, ValueError, IndexError, OverflowError, AttributeError, FingerlocError) as err:
            raise DatabaseError(f"{path}: invalid place database ({type(err).__name__}: {err})") from err
        _verify(con, path, _MODEL_TABLES)
    return model


def _load(con: sqlite3.Connection, path: str | Path) -> PlaceModel:
    meta = dict(con.execute("SELECT key, value FROM meta").fetchall())
    try:
        params = json.loads(meta["params"])
        if not isinstance(params, dict):
            raise TypeError(f"params must be a JSON object, got {type(params).__name__}")
        params["costs"] = _costs_from_json(params.get("costs"))
        where = str(path)
        lambdas = check_number_map(json.loads(meta["lambdas"]), "lambdas", where, minimum=0.0)
        unknown = check_number_map(json.loads(meta["unknown_costs"]), "unknown_costs", where, neg_inf=True)
        weights = check_number_map(json.loads(meta.get("fitted_weights", "{}")), "fitted_weights", where, minimum=0.0)
        temper = float(json.loads(meta.get("temper", "1.0")))
        if not (math.isfinite(temper) and temper > 0):
            raise ValueError(f"temper must be a positive number, got {temper!r}")
        term_params = json.loads(meta.get("term_params", "{}"))
        if not isinstance(term_params, dict) or not all(isinstance(v, dict) for v in term_params.values()):
            raise TypeError("term_params must be a JSON object of objects")
        typed_labels = json.loads(meta["labels"]) if "labels" in meta else None
        default_fov = None
        if "default_fov" in meta:
            default_fov = tuple((float(a), float(b)) for a, b in json.loads(meta["default_fov"]))
            if not default_fov or not all(math.isfinite(a) and 0 < b <= 2 * math.pi + 1e-9 for a, b in default_fov):
                raise ValueError(f"default_fov: (start, width) pairs with 0 < width <= 2 pi, got {default_fov!r}")
        k = params.get("n_components")
        if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= MAX_COMPONENTS:
            raise ValueError(f"params.n_components must be an integer in [1, {MAX_COMPONENTS}], got {k!r}")
    except DatabaseError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError, FingerlocError) as err:
        raise DatabaseError(f"{path}: invalid model parameters in the place database ({err})") from err
    labels: list[Any] = []
    medoids: list[int] = []
    consensus: list[Any] = []
    index: dict[int, int] = {}
    rows = con.execute("SELECT id, label, medoid, consensus_letters, consensus_bearings FROM places ORDER BY id")
    for pid, label, medoid, cl, cb in rows:
        if not isinstance(label, str) or not label:
            raise DatabaseError(f"{path}: place {pid}: label must be non-empty text, got {label!r}")
        if isinstance(medoid, bool) or not isinstance(medoid, int):
            raise DatabaseError(f"{path}: place {label!r}: medoid must be an integer, got {medoid!r}")
        if cl is not None and not isinstance(cl, str):
            raise DatabaseError(f"{path}: place {label!r}: consensus letters must be text, got {cl!r}")
        index[pid] = len(labels)
        labels.append(label)
        medoids.append(medoid)
        consensus.append(None if cl is None else (cl, _array(cb)))
    observations: list[list[Any]] = [[] for _ in labels]
    fingerprints: list[list[Any]] = [[] for _ in labels]
    version = meta.get("schema_version")
    if version in ("1", "2"):
        q = (
            "SELECT o.place_id, o.record, NULL, f.letters, f.bearings FROM observations o "
            "LEFT JOIN fingerprints f ON f.obs_id = o.id ORDER BY o.place_id, o.idx"
        )
    else:
        q = (
            "SELECT o.place_id, o.data, o.source, f.letters, f.bearings FROM observations o "
            "LEFT JOIN fingerprints f ON f.obs_id = o.id ORDER BY o.place_id, o.idx"
        )
    pending: list[tuple[int, Any, Any]] = []  # schema 3+: (place, record, source), decoded a chunk at a time

    def decode_pending() -> None:
        try:
            decoded = decode_rows([r for _, r, _ in pending], [labels[j] for j, _, _ in pending], [s for _, _, s in pending], default_fov=default_fov)
        except DatabaseError as err:
            raise DatabaseError(f"{path}: {err}") from err
        for (j, _, _), obs in zip(pending, decoded, strict=True):
            observations[j].append(obs)
        pending.clear()  # the chunk's records go: the rows stream, only the observations stay

    for pid, record, source, letters, bearings in con.execute(q):
        if pid not in index:
            raise DatabaseError(f"{path}: an observation row names place id {pid!r}, which the database does not hold")
        if not (letters is None or isinstance(letters, str)) or not (source is None or isinstance(source, str)):
            raise DatabaseError(f"{path}: place {labels[index[pid]]!r}: observation row with a malformed record or fingerprint")
        if version in ("1", "2"):
            if not isinstance(record, str):
                raise DatabaseError(f"{path}: place {labels[index[pid]]!r}: observation row with a malformed record or fingerprint")
            try:
                obs = observation_from_record(parse_record(record))
            except (ValueError, DataFormatError) as err:
                raise DatabaseError(f"{path}: corrupt observation record in the place database ({err})") from err
            observations[index[pid]].append(obs)
        else:
            pending.append((index[pid], record, source))
            if len(pending) >= LOAD_CHUNK_ROWS:
                decode_pending()
        fingerprints[index[pid]].append(None if letters is None else (letters, _array(bearings)))
    if pending:
        decode_pending()
    mixtures: dict[str, list[Any]] = {}
    for pid, term, w, m, sg in con.execute("SELECT place_id, term, weights, means, sigmas FROM mixtures"):
        if pid not in index:
            raise DatabaseError(f"{path}: a mixture row names place id {pid!r}, which the database does not hold")
        arrays = (_array(w), _array(m), _array(sg))
        if not isinstance(term, str) or len({a.size for a in arrays}) != 1 or np.any(arrays[2] <= 0):
            raise DatabaseError(f"{path}: place {labels[index[pid]]!r}: corrupt mixture of term {term!r}")
        if np.any(arrays[0] < 0) or not abs(float(arrays[0].sum()) - 1.0) <= 1e-6:
            raise DatabaseError(
                f"{path}: mixtures.weights of place {labels[index[pid]]!r}, term {term!r}: weights must be >= 0 "
                f"and sum to 1, got {arrays[0].tolist()!r}"
            )
        mixtures.setdefault(term, [None] * len(labels))[index[pid]] = arrays
    descriptors: list[Any] | None = None
    counts: list[Any] | None = None
    if con.execute("SELECT 1 FROM sqlite_master WHERE type='table' AND name='range_descriptors'").fetchone():
        enc = "encoding" if version not in ("1", "2") else "'<f8'"
        rows_d = con.execute(f"SELECT place_id, width, data, {enc} FROM range_descriptors").fetchall()
        if rows_d:
            descriptors = [None] * len(labels)
            counts = [None] * len(labels)
            for pid, width, data, encoding in rows_d:
                if pid not in index or isinstance(width, bool) or not isinstance(width, int) or width < 1:
                    raise DatabaseError(f"{path}: a range descriptor row names place id {pid!r} or width {width!r}")
                try:
                    kind, block = _range_rows(data, encoding, width)
                except DatabaseError as err:
                    raise DatabaseError(f"{path}: place id {pid!r}: {err}") from err
                (descriptors if kind == "descriptors" else counts)[index[pid]] = block
            if any(d is None and c is None for d, c in zip(descriptors, counts, strict=True)):
                raise DatabaseError(f"{path}: range descriptors are missing for some places")
    if not labels:
        raise DatabaseError(f"{path}: the place database holds no place")
    for j, group in enumerate(observations):
        if not group:
            raise DatabaseError(f"{path}: place {labels[j]!r} has no observation")
        if not 0 <= medoids[j] < len(group):
            raise DatabaseError(
                f"{path}: place {labels[j]!r}: medoid {medoids[j]} is not one of its {len(group)} observations"
            )
    if typed_labels is not None:
        if not isinstance(typed_labels, list) or len(typed_labels) != len(labels):
            raise DatabaseError(f"{path}: the stored label types do not match the places")
        labels = typed_labels
    terms_state: dict[str, dict[str, Any]] = {name: {"mixtures": mx} for name, mx in mixtures.items()}
    for name in ("Fp", "R", "A", "AP", "K"):
        terms_state[name] = {**term_params.get(name, {}), "lambda": lambdas.get(name, 1.0), "unknown_cost": unknown.get(name)}
    terms_state["A"]["metric"] = "l1"  # the model's appearance term (fingerloc.terms.AppearanceTerm's default)
    if descriptors is not None:  # else (older databases) the range term describes the stored scans again
        terms_state["R"]["descriptors"] = descriptors
        terms_state["R"]["counts"] = counts
    # a view without a stored fingerprint gets it from its stored observation (the term computes it)
    terms_state["Fp"].update(fingerprints=fingerprints, medoids=medoids, consensus=consensus)
    for name in ("VE", "CP", "Ex", "B"):
        terms_state.setdefault(name, {"mixtures": [None] * len(labels)})
    state = {"params": params, "labels": labels, "observations": observations, "terms": terms_state, "weights": weights,
             "temper": temper}  # fmt: skip
    try:
        return PlaceModel.from_state(state)
    except DatabaseError as err:
        raise DatabaseError(f"{path}: {err}") from err


def read_graph_edges(path: str | Path) -> dict[tuple[str, str], int]:
    """The place-graph transitions stored in a place database: ``{(src, dst): count}``."""
    with _open(path) as con:
        out = _graph_edges(con, path)
        _verify(con, path, ("graph_edges",))
    return out


def _graph_edges(con: sqlite3.Connection, path: str | Path) -> dict[tuple[str, str], int]:
    out: dict[tuple[str, str], int] = {}
    for s, d, c in con.execute("SELECT src, dst, count FROM graph_edges"):
        if not isinstance(s, str) or not isinstance(d, str) or isinstance(c, bool) or not isinstance(c, int) or c < 0:
            raise DatabaseError(f"{path}: invalid place-graph edge ({s!r}, {d!r}, count {c!r})")
        out[(s, d)] = c
    return out
