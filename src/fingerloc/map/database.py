"""The place database: one SQLite file, versioned schema, atomic saves, never pickle.

Layout (schema version 1)::

    meta(key TEXT PRIMARY KEY, value TEXT)         -- format, schema_version, fingerloc_version,
                                                   -- params, lambdas, unknown_costs, fitted_weights (JSON)
    places(id INTEGER PRIMARY KEY, label TEXT UNIQUE, medoid INTEGER,
           consensus_letters TEXT, consensus_bearings BLOB)
    observations(id INTEGER PRIMARY KEY, place_id INTEGER, idx INTEGER, record TEXT)
                                                   -- the JSON Lines record of the observation
    fingerprints(obs_id INTEGER PRIMARY KEY, letters TEXT, bearings BLOB)
    mixtures(place_id INTEGER, term TEXT, weights BLOB, means BLOB, sigmas BLOB,
             PRIMARY KEY (place_id, term))
    graph_edges(src TEXT, dst TEXT, count INTEGER, PRIMARY KEY (src, dst))

Arrays are little-endian float64 blobs (radians). A save writes a complete new
file next to the target in one transaction, syncs it, and renames it over the
target: a crash mid-write leaves the old file as it was.

Writers are serialised by an exclusive lock (``flock``) on ``<db>.lock`` next
to the database: :func:`locked` holds it around a read-modify-write (``learn``
into an existing database), and :func:`save_model` takes it too, so two
writers at once never lose each other's places. Under the lock, temporary
files ``<db>.*.tmp`` that a killed writer left are removed. A symbolic link
at the target is written through (the link stays, its target is replaced);
a new file's mode follows the umask, a replaced file keeps its mode.
Reading opens the file read-only; a hot rollback journal left by a foreign
SQLite writer is handed to SQLite to roll back (under the lock) first.
Every value read is checked: a crafted but valid SQLite file gives a
:class:`~fingerloc.errors.DatabaseError`, never a wrong model or a traceback.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
import tempfile
import threading
from collections.abc import Iterator, Mapping
from contextlib import closing, contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..errors import DatabaseError, DataFormatError, FingerlocError
from ..fingerprint import Fingerprint
from ..io.jsonl import observation_from_record, observation_to_record, parse_record
from ..model import PlaceData, PlaceModel

__all__ = ["FORMAT", "SCHEMA_VERSION", "load_model", "locked", "read_graph_edges", "save_model"]

FORMAT = "fingerloc-places"
SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE places(id INTEGER PRIMARY KEY, label TEXT UNIQUE NOT NULL, medoid INTEGER NOT NULL,
                    consensus_letters TEXT, consensus_bearings BLOB);
CREATE TABLE observations(id INTEGER PRIMARY KEY, place_id INTEGER NOT NULL REFERENCES places(id),
                          idx INTEGER NOT NULL, record TEXT NOT NULL);
CREATE TABLE fingerprints(obs_id INTEGER PRIMARY KEY REFERENCES observations(id), letters TEXT NOT NULL,
                          bearings BLOB NOT NULL);
CREATE TABLE mixtures(place_id INTEGER NOT NULL REFERENCES places(id), term TEXT NOT NULL,
                      weights BLOB NOT NULL, means BLOB NOT NULL, sigmas BLOB NOT NULL,
                      PRIMARY KEY (place_id, term));
CREATE TABLE graph_edges(src TEXT NOT NULL, dst TEXT NOT NULL, count INTEGER NOT NULL, PRIMARY KEY (src, dst));
"""


_held: dict[str, int] = {}
_held_guard = threading.RLock()


def _real(path: str | Path) -> Path:
    """The file a database path names: symbolic links followed (the file need not exist)."""
    return Path(os.path.realpath(path))


@contextmanager
def locked(path: str | Path) -> Iterator[None]:
    """Hold the exclusive writer lock of a place database (``<db>.lock``), re-entrantly.

    Wrap a read-modify-write (load, change, :func:`save_model`) in it so that
    no other process writes the database in between; other processes wait.

    Raises
    ------
    DatabaseError
        When the lock file cannot be created (a missing or read-only directory).
    """
    real = _real(path)
    key = str(real)
    with _held_guard:
        if _held.get(key):
            _held[key] += 1
            reentrant = True
        else:
            reentrant = False
    if reentrant:
        try:
            yield
        finally:
            with _held_guard:
                _held[key] -= 1
        return
    directory = real.parent
    if not directory.is_dir():
        raise DatabaseError(f"{path}: directory {directory} does not exist")
    lock_path = real.with_name(real.name + ".lock")
    try:
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as err:
        raise DatabaseError(f"{path}: cannot create the lock file {lock_path} ({err.strerror or err})") from err
    try:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX: no inter-process lock
            fcntl = None  # type: ignore[assignment]
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX)
        with _held_guard:
            _held[key] = 1
        try:
            yield
        finally:
            with _held_guard:
                _held.pop(key, None)
    finally:
        os.close(fd)  # closing releases the flock


def _remove_stale(real: Path) -> None:
    """Remove temporary files of dead writers (call under :func:`locked`: no live writer has any)."""
    for tmp in real.parent.glob(f"{real.name}.*.tmp"):
        for f in (tmp, Path(str(tmp) + "-journal")):
            try:
                f.unlink(missing_ok=True)
            except OSError:
                pass


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _blob(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype="<f8").tobytes()


def _array(b: Any) -> np.ndarray:
    if not isinstance(b, bytes) or len(b) % 8:
        raise DatabaseError(f"corrupt array in the place database (expected a float64 blob, got {type(b).__name__})")
    a = np.frombuffer(b, dtype="<f8").astype(np.float64)
    if not np.all(np.isfinite(a)):
        raise DatabaseError("corrupt array in the place database (a value is not finite)")
    return a


def _costs_to_json(costs: Any) -> Any:
    """An alignment cost model as JSON: its full tables (``None`` for unit costs)."""
    if costs is None:
        return None
    try:
        return {"substitution": np.asarray(costs.substitution).tolist(), "indel": np.asarray(costs.indel).tolist()}
    except AttributeError as err:
        raise DatabaseError(f"cannot store alignment costs of type {type(costs).__name__}") from err


def _costs_from_json(data: Any) -> Any:
    if data is None:
        return None
    from ..align import CostModel

    return CostModel(substitution=np.asarray(data["substitution"]), indel=np.asarray(data["indel"]))


def save_model(
    model: PlaceModel,
    path: str | Path,
    *,
    graph_edges: Mapping[tuple[str, str], int] | None = None,
) -> int:
    """Write a fitted model to a place database, atomically.

    Parameters
    ----------
    model : PlaceModel
        A fitted model.
    path : str or Path
        The database file; replaced as a whole if it exists.
    graph_edges : mapping (src, dst) -> count, optional
        Transitions of the place graph to store with the places.

    Returns
    -------
    int
        Size of the written file in bytes.
    """
    model._check_fitted()
    target = Path(path)
    params = model.get_params()
    params["costs"] = _costs_to_json(params["costs"])
    rs = params["random_state"]
    params["random_state"] = rs if isinstance(rs, int) or rs is None else None
    if target.is_dir():
        raise DatabaseError(f"{target} is a directory, not a place database")
    real = _real(target)
    directory = real.parent
    if not directory.is_dir():
        raise DatabaseError(f"{target}: directory {directory} does not exist")
    with locked(target):
        _remove_stale(real)
        return _save_locked(model, real, params, graph_edges)


def _save_locked(
    model: PlaceModel, target: Path, params: dict[str, Any], graph_edges: Mapping[tuple[str, str], int] | None
) -> int:
    directory = target.parent
    mode = target.stat().st_mode & 0o7777 if target.is_file() else 0o666 & ~_umask()
    try:
        fd, tmp = tempfile.mkstemp(prefix=target.name + ".", suffix=".tmp", dir=directory)
    except OSError as err:
        raise DatabaseError(f"{target}: cannot write in {directory} ({err.strerror or err})") from err
    os.close(fd)
    try:
        with closing(sqlite3.connect(tmp)) as con:
            con.execute("PRAGMA journal_mode=DELETE")
            with con:  # one transaction
                con.executescript("BEGIN;" + _SCHEMA.replace(";\n", ";\n"))
                meta = {
                    "format": FORMAT,
                    "schema_version": str(SCHEMA_VERSION),
                    "fingerloc_version": __version__,
                    "params": json.dumps(params),
                    "lambdas": json.dumps(model.lambdas_),
                    "unknown_costs": json.dumps(model.unknown_costs_),
                    "fitted_weights": json.dumps(getattr(model, "weights_", {})),
                }
                con.executemany("INSERT INTO meta VALUES (?, ?)", meta.items())
                for pid, place in enumerate(model.places_.values()):
                    cons = place.consensus
                    con.execute(
                        "INSERT INTO places VALUES (?, ?, ?, ?, ?)",
                        (
                            pid,
                            place.label,
                            place.medoid,
                            None if cons is None else cons.letters,
                            None if cons is None else _blob(cons.bearings),
                        ),
                    )
                    for idx, (obs, fp) in enumerate(zip(place.observations, place.fingerprints, strict=True)):
                        cur = con.execute(
                            "INSERT INTO observations(place_id, idx, record) VALUES (?, ?, ?)",
                            (pid, idx, json.dumps(observation_to_record(obs, ndigits=12))),
                        )
                        con.execute(
                            "INSERT INTO fingerprints VALUES (?, ?, ?)", (cur.lastrowid, fp.letters, _blob(fp.bearings))
                        )
                    for term, (w, m, s) in place.mixtures.items():
                        con.execute(
                            "INSERT INTO mixtures VALUES (?, ?, ?, ?, ?)", (pid, term, _blob(w), _blob(m), _blob(s))
                        )
                for (src, dst), count in (graph_edges or {}).items():
                    con.execute("INSERT INTO graph_edges VALUES (?, ?, ?)", (src, dst, int(count)))
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target.stat().st_size


@contextmanager
def _open(path: str | Path) -> Iterator[sqlite3.Connection]:
    p = Path(path)
    if p.is_dir():
        raise DatabaseError(f"{p} is a directory, not a place database")
    if not p.is_file():
        raise DatabaseError(f"{p}: no such place database")
    if Path(str(_real(p)) + "-journal").exists():
        _recover_hot_journal(p)
    try:
        con = sqlite3.connect(f"file:{_uri_path(p)}?mode=ro", uri=True)
    except sqlite3.Error as err:
        raise DatabaseError(f"{p}: cannot open as a place database ({err})") from err
    try:
        try:
            ok = con.execute("PRAGMA quick_check").fetchone()
            if ok is None or ok[0] != "ok":
                raise DatabaseError(f"{p}: corrupt place database ({ok[0] if ok else 'no answer'})")
            tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
            if "meta" not in tables:
                raise DatabaseError(f"{p}: not a fingerloc place database (no meta table)")
            meta = dict(con.execute("SELECT key, value FROM meta").fetchall())
            if meta.get("format") != FORMAT:
                raise DatabaseError(f"{p}: not a fingerloc place database (format {meta.get('format')!r})")
            if meta.get("schema_version") != str(SCHEMA_VERSION):
                raise DatabaseError(
                    f"{p}: place database schema version {meta.get('schema_version')!r} is not supported "
                    f"(this fingerloc reads version {SCHEMA_VERSION})"
                )
            yield con
        except sqlite3.Error as err:
            raise DatabaseError(f"{p}: not a valid place database ({err})") from err
    finally:
        con.close()


def _uri_path(p: Path) -> str:
    from urllib.parse import quote

    return quote(str(p.absolute()))


def _recover_hot_journal(p: Path) -> None:
    """Let SQLite roll back a hot journal next to ``p`` (a write that died): open read-write once."""
    with locked(p):
        try:
            with closing(sqlite3.connect(f"file:{_uri_path(p)}?mode=rw", uri=True)) as con:
                con.execute("SELECT count(*) FROM sqlite_master").fetchone()
        except sqlite3.Error as err:
            raise DatabaseError(f"{p}: a rollback journal was left by a failed write and cannot be rolled back ({err})") from err


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
            return _load(con, path)
        except DatabaseError:
            raise
        except (KeyError, TypeError, ValueError, IndexError, OverflowError, AttributeError, FingerlocError) as err:
            raise DatabaseError(f"{path}: invalid place database ({type(err).__name__}: {err})") from err


def _load(con: sqlite3.Connection, path: str | Path) -> PlaceModel:
    meta = dict(con.execute("SELECT key, value FROM meta").fetchall())
    try:
        params = json.loads(meta["params"])
        if not isinstance(params, dict):
            raise TypeError(f"params must be a JSON object, got {type(params).__name__}")
        params["costs"] = _costs_from_json(params.get("costs"))
        model = PlaceModel(**params)
        model._validate()
        model.lambdas_ = _float_map(meta["lambdas"], "lambdas")
        model.unknown_costs_ = _float_map(meta["unknown_costs"], "unknown_costs")
        model.weights_ = _float_map(meta.get("fitted_weights", "{}"), "fitted_weights")
    except (KeyError, TypeError, ValueError, AttributeError, FingerlocError) as err:
        raise DatabaseError(f"{path}: invalid model parameters in the place database ({err})") from err
    places: dict[str, PlaceData] = {}
    rows = con.execute("SELECT id, label, medoid, consensus_letters, consensus_bearings FROM places ORDER BY id")
    ids: dict[int, PlaceData] = {}
    medoids: dict[int, int] = {}
    for pid, label, medoid, cl, cb in rows:
        if not isinstance(label, str) or not label:
            raise DatabaseError(f"{path}: place {pid}: label must be non-empty text, got {label!r}")
        if isinstance(medoid, bool) or not isinstance(medoid, int):
            raise DatabaseError(f"{path}: place {label!r}: medoid must be an integer, got {medoid!r}")
        if cl is not None and not isinstance(cl, str):
            raise DatabaseError(f"{path}: place {label!r}: consensus letters must be text, got {cl!r}")
        cons = None if cl is None else Fingerprint(cl, _array(cb))
        pd = PlaceData(label, [], [], {}, int(medoid), cons)
        places[label] = pd
        ids[pid] = pd
        medoids[pid] = int(medoid)
    q = (
        "SELECT o.place_id, o.record, f.letters, f.bearings FROM observations o "
        "LEFT JOIN fingerprints f ON f.obs_id = o.id ORDER BY o.place_id, o.idx"
    )
    for pid, record, letters, bearings in con.execute(q):
        if pid not in ids:
            raise DatabaseError(f"{path}: an observation row names place id {pid!r}, which the database does not hold")
        if not isinstance(record, str) or not isinstance(letters, str):
            raise DatabaseError(f"{path}: place {ids[pid].label!r}: observation row without its record or fingerprint")
        try:
            obs = observation_from_record(parse_record(record))
        except (ValueError, DataFormatError) as err:
            raise DatabaseError(f"{path}: corrupt observation record in the place database ({err})") from err
        ids[pid].observations.append(obs)
        ids[pid].fingerprints.append(Fingerprint(letters, _array(bearings)))
    for pid, term, w, m, s in con.execute("SELECT place_id, term, weights, means, sigmas FROM mixtures"):
        if pid not in ids:
            raise DatabaseError(f"{path}: a mixture row names place id {pid!r}, which the database does not hold")
        arrays = (_array(w), _array(m), _array(s))
        if not isinstance(term, str) or len({a.size for a in arrays}) != 1 or np.any(arrays[2] <= 0):
            raise DatabaseError(f"{path}: place {ids[pid].label!r}: corrupt mixture of term {term!r}")
        ids[pid].mixtures[term] = arrays
    if not places:
        raise DatabaseError(f"{path}: the place database holds no place")
    for pid, pd in ids.items():
        if not pd.observations:
            raise DatabaseError(f"{path}: place {pd.label!r} has no observation")
        if not 0 <= medoids[pid] < len(pd.observations):
            raise DatabaseError(
                f"{path}: place {pd.label!r}: medoid {medoids[pid]} is not one of its {len(pd.observations)} observations"
            )
    model.places_ = places
    model.classes_ = np.array(list(places), dtype=object)
    model._index_references()
    return model


def _float_map(text: Any, what: str) -> dict[str, float]:
    data = json.loads(text)
    if not isinstance(data, dict):
        raise TypeError(f"{what} must be a JSON object, got {type(data).__name__}")
    out = {str(k): float(v) for k, v in data.items()}
    if not all(math.isfinite(v) or v == -math.inf for v in out.values()):
        raise ValueError(f"{what}: a value is NaN or +inf")
    return out


def read_graph_edges(path: str | Path) -> dict[tuple[str, str], int]:
    """The place-graph transitions stored in a place database: ``{(src, dst): count}``."""
    out: dict[tuple[str, str], int] = {}
    with _open(path) as con:
        for s, d, c in con.execute("SELECT src, dst, count FROM graph_edges"):
            if not isinstance(s, str) or not isinstance(d, str) or isinstance(c, bool) or not isinstance(c, int) or c < 0:
                raise DatabaseError(f"{path}: invalid place-graph edge ({s!r}, {d!r}, count {c!r})")
            out[(s, d)] = c
    return out
