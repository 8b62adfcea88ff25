"""Plumbing every command shares: output paths checked up front, strict JSON, literal text.

* :func:`check_output` runs before any computation: the directory of an
  output file must exist and be writable, and the path must not be a
  directory, so that a long run never ends in a traceback or a stray
  temporary file.
* :func:`write_json` writes strict JSON (RFC 8259: no ``NaN`` or
  ``Infinity``; a non-finite number becomes ``null`` and its place is listed
  under ``"nulls"`` with the reason), atomically, with the file mode that the
  umask gives.
* :func:`lit` makes a user's string (a place label, a path) a
  :class:`rich.text.Text`, which rich never reads as markup; the consoles of
  :mod:`.app` do not interpret markup or emoji codes at all.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from .._lazy import LazyAttr
from ..errors import InvalidParameterError

if TYPE_CHECKING:
    from rich.text import Text
else:
    Text = LazyAttr("rich.text", "Text")  # rich is imported when a command prints

__all__ = ["atomic_write_text", "check_output", "lit", "strict_json", "write_json"]


def check_output(path: Path | None, flag: str, *, directory: bool = False) -> None:
    """Check that ``path`` can be written, before any work; ``None`` passes.

    Parameters
    ----------
    path : Path or None
        The output file (or directory, with ``directory=True``) as the user gave it.
    flag : str
        The option's name as the user wrote it (``--json``), for the message.
    directory : bool
        The output is a directory (created if missing) rather than a file.

    Raises
    ------
    InvalidParameterError
        Naming the flag and the path: a missing or read-only parent
        directory, a directory where a file goes, or a file where a directory goes.
    """
    if path is None:
        return
    p = Path(path)
    if str(p) in ("", "."):
        if directory:
            parent = Path(".")
        else:
            raise InvalidParameterError(f"{flag}: {str(path)!r} is not a file name")
    parent = p.parent if str(p.parent) else Path(".")
    if directory and p.is_dir():
        if not os.access(p, os.W_OK | os.X_OK):
            raise InvalidParameterError(f"{flag}: directory {p} is not writable")
        return
    if p.is_dir():
        raise InvalidParameterError(f"{flag}: {p} is a directory (give a file name)")
    if directory and p.exists():
        raise InvalidParameterError(f"{flag}: {p} exists and is not a directory")
    if not parent.is_dir():
        what = "is not a directory" if parent.exists() else "does not exist"
        raise InvalidParameterError(f"{flag}: {p}: directory {parent} {what}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InvalidParameterError(f"{flag}: {p}: directory {parent} is not writable")
    if p.exists() and not os.access(p, os.W_OK) and not os.access(parent, os.W_OK):
        raise InvalidParameterError(f"{flag}: {p} is not writable")


def strict_json(data: Any) -> tuple[Any, dict[str, str]]:
    """``data`` with every non-finite float replaced by ``None``; and where, why.

    Returns
    -------
    clean : object
        Same structure; tuples become lists, numpy scalars become Python numbers.
    nulls : dict
        JSON-pointer-like path (``/logs/a/top1``) -> the reason (``"not a finite number: nan"``).
    """
    nulls: dict[str, str] = {}

    def walk(x: Any, where: str) -> Any:
        if isinstance(x, dict):
            return {str(k): walk(v, f"{where}/{k}") for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [walk(v, f"{where}/{i}") for i, v in enumerate(x)]
        if isinstance(x, bool) or x is None or isinstance(x, (str, int)):
            return x
        if isinstance(x, float):
            if math.isfinite(x):
                return x
            nulls[where or "/"] = f"not a finite number: {x!r}"
            return None
        item = getattr(x, "item", None)  # numpy scalars
        if callable(item):
            try:
                return walk(item(), where)
            except (TypeError, ValueError):
                pass
        tolist = getattr(x, "tolist", None)  # numpy arrays
        if callable(tolist):
            return walk(tolist(), where)
        return x

    return walk(data, ""), nulls


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextmanager
def atomic_text_file(path: Path) -> Iterator[TextIO]:
    """A text file (UTF-8) written in place of ``path`` only when the block ends without an error.

    The temporary file sits next to ``path`` and is removed on any failure;
    the new file gets mode ``0o666 & ~umask`` (or the old file's mode), and a
    symbolic link at ``path`` stays a link (its target is replaced).
    """
    target = Path(os.path.realpath(path)) if Path(path).is_symlink() else Path(path)
    directory = target.parent if str(target.parent) else Path(".")
    mode = target.stat().st_mode & 0o7777 if target.is_file() else 0o666 & ~_umask()
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            yield fh
        os.chmod(tmp, mode)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`atomic_text_file`)."""
    with atomic_text_file(path) as fh:
        fh.write(text)


class JsonRecordStream:
    """A JSON object ``{"KEY": [record, ...], ...tail}`` written record by record (bounded memory).

    Records are strict JSON (non-finite numbers become ``null``, listed in a
    ``"nulls"`` member with their paths, as :func:`write_json` does); one
    record a line. :meth:`finish` writes the other members.
    """

    def __init__(self, fh: TextIO, key: str) -> None:
        self._fh = fh
        self._key = key
        self._n = 0
        self._nulls: dict[str, str] = {}
        fh.write("{" + json.dumps(key) + ": [\n")

    def add(self, record: object) -> None:
        """Append one record."""
        clean, nulls = strict_json(record)
        self.add_encoded(json.dumps(clean, allow_nan=False), nulls)

    def add_encoded(self, text: str, nulls: dict[str, str]) -> None:
        """Append one record already encoded as strict JSON ``text``; ``nulls``: its ``null`` paths inside it and why."""
        self._nulls.update({f"/{self._key}/{self._n}{k}": v for k, v in nulls.items()})
        self._fh.write(("" if self._n == 0 else ",\n") + text)
        self._n += 1

    def finish(self, tail: dict[str, object]) -> None:
        """Close the array and write the other members (and ``"nulls"`` when there were any)."""
        clean, nulls = strict_json(tail)
        self._nulls.update(nulls)
        if self._nulls:
            clean["nulls"] = self._nulls
        self._fh.write("\n]")
        for k, v in clean.items():
            self._fh.write(",\n" + json.dumps(str(k)) + ": " + json.dumps(v, indent=2, allow_nan=False))
        self._fh.write("\n}\n")


def write_json(path: Path | None, data: object, *, flag: str = "--json") -> None:
    """Write ``data`` as indented strict JSON to ``path`` (when given), atomically.

    Non-finite numbers are written as ``null``; when there are any and
    ``data`` is an object, a ``"nulls"`` member lists where and why.
    """
    if path is None:
        return
    from .app import err_console

    clean, nulls = strict_json(data)
    if nulls and isinstance(clean, dict) and "nulls" not in clean:
        clean["nulls"] = nulls
    text = json.dumps(clean, indent=2, allow_nan=False) + "\n"
    check_output(path, flag)
    try:
        atomic_write_text(Path(path), text)
    except OSError as err:
        raise InvalidParameterError(f"{flag}: cannot write {path}: {err.strerror or err}") from err
    err_console.print(lit(f"wrote {path}"))


def lit(text: object) -> Text:
    """A user's string as rich text that is printed literally (no markup, no emoji codes)."""
    return Text(str(text))
