"""The work of ``fingerloc localize``, chunk by chunk: serially in this process or as Dask tasks.

A *chunk* is a run of consecutive observations (:data:`LOCALIZE_CHUNK` of
them). :func:`answer_chunk` computes its answers (the terms once, then the
posterior, ranks and headings) and returns plain data: the JSON records
already encoded as text, the table rows, the ranks of the true places. The
serial command calls it chunk after chunk; with ``--workers`` /
``--scheduler`` each Dask task is :func:`answer_lines`, which parses a chunk
of JSON Lines text with the reader's own checks, loads the place database
once per worker process, and calls the same function, so the output is the
same byte for byte. Only text and plain numbers travel between processes
(never a pickled observation or model).
"""

from __future__ import annotations

import hashlib
import json
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import DatabaseError, DataFormatError, EmptyInputError
from ..pipeline.localize import LOCALIZE_CHUNK, ChunkAnswers, answer_chunk
from ._io import strict_json

__all__ = ["LinesTask", "answer_lines", "encode_record", "jsonl_chunks"]

def encode_record(record: Any) -> tuple[str, dict[str, str]]:
    """One record as strict JSON text (non-finite numbers as ``null``) and where those nulls are (paths inside it)."""
    clean, nulls = strict_json(record)
    return json.dumps(clean, allow_nan=False), nulls


# -- JSON Lines in chunks ---------------------------------------------------------------------------


def jsonl_chunks(path: Path, size: int | None = None) -> Iterator[tuple[int, list[tuple[int, str]]]]:
    """The non-blank lines of a JSON Lines file in chunks of ``size``: (index of the chunk's first observation, [(line number, text)]).

    Lines are split as :func:`fingerloc.io.jsonl.iter_observations` splits
    them (text mode, UTF-8); the text is not parsed here.

    Raises
    ------
    DataFormatError
        The file cannot be read or is not UTF-8 (naming the line).
    EmptyInputError
        When it holds no non-blank line.
    """
    if size is None:
        size = LOCALIZE_CHUNK  # read when called (tests shrink it)
    from ..io.jsonl import iter_lines  # bounded lines, NUL bytes and non-UTF-8 refused

    count = 0
    chunk: list[tuple[int, str]] = []
    for lineno, line in iter_lines(path):
        chunk.append((lineno, line))
        if len(chunk) == size:
            yield count, chunk
            count += len(chunk)
            chunk = []
    if chunk:
        yield count, chunk
        count += len(chunk)
    if count == 0:
        raise EmptyInputError("no observation in file (empty)", path=path)


def parse_lines(path: Path, lines: list[tuple[int, str]]) -> list[Any]:
    """The observations of a chunk of JSON Lines, with the reader's checks and messages (``FILE:LINE: ...``)."""
    from ..io.jsonl import observation_from_record, parse_record

    out = []
    for lineno, line in lines:
        try:
            out.append(observation_from_record(parse_record(line)))
        except DataFormatError as err:
            raise err.at(path=path, line=lineno) from err
    return out


@dataclass(frozen=True, slots=True)
class LinesTask:
    """One Dask task of ``localize --workers``: a chunk of JSON Lines text and how to answer it.

    ``db_sha256`` is the client's database content hash: a worker that finds
    another file at ``db`` refuses it instead of answering with another map.
    """

    db: str
    db_sha256: str
    data: str
    start: int
    lines: list[tuple[int, str]]
    top: int
    table: bool
    records: bool


#: Per worker process: (database path, content hash) -> the loaded map (each worker loads it once).
_MAPS: dict[tuple[str, str], Any] = {}
_MAPS_LOCK = threading.Lock()


def file_sha256(path: Path) -> str:
    """SHA-256 hex of a file's bytes."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _worker_map(db: str, sha: str) -> Any:
    from ..pipeline.placemap import load_map

    with _MAPS_LOCK:
        lm = _MAPS.get((db, sha))
        if lm is None:
            if file_sha256(Path(db)) != sha:
                raise DatabaseError(f"{db}: the worker's file differs from the client's (give workers the same database)")
            lm = load_map(db)
            _MAPS.clear()  # one database at a time
            _MAPS[(db, sha)] = lm
    return lm


def answer_lines(task: LinesTask) -> ChunkAnswers | tuple[str, str]:
    """A Dask task: parse the chunk's lines and answer them; a fingerloc error comes back as ``("error", message)``."""
    from ..errors import FingerlocError

    try:
        lm = _worker_map(task.db, task.db_sha256)
        path = Path(task.data)
        obs = parse_lines(path, task.lines)
        names = [f"{path.name}:{task.start + i + 1}" for i in range(len(obs))]
        return answer_chunk(lm.model, obs, names, task.start, task.top, table=task.table, records=task.records)
    except FingerlocError as err:  # re-raised by the client as one line, whatever Dask does with exceptions
        return ("error", str(err))
