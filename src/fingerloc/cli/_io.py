"""Plumbing every command shares: output paths checked up front, strict JSON, literal text, faults as one line.

* :func:`check_output` runs before any computation: an output is a regular
  file (or a new name) in an existing, writable directory, or ``-`` for
  standard output; a directory, a device, a FIFO, a socket, a symbolic link
  loop or a name too long for the file system is refused with one line, so
  that a long run never ends in a traceback, a stray temporary file or a
  device replaced by a file.
* :func:`write_json` writes strict JSON (RFC 8259: no ``NaN`` or
  ``Infinity``; a non-finite number becomes ``null`` and its place is listed
  under ``"nulls"`` with the reason), atomically, with the file mode that the
  umask gives.
* :func:`lit` makes a user's string (a place label, a path) a
  :class:`rich.text.Text`, which rich never reads as markup; the consoles of
  :mod:`.app` do not interpret markup or emoji codes at all.
* :func:`warn` prints doubts as ``warning: ...`` lines; :func:`fault_message`
  turns what the system refuses (a full disk, a file-size limit, a read-only
  file system, a closed pipe) into the one line the command line prints.
"""

from __future__ import annotations

import errno
import json
import math
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from .._lazy import LazyAttr
from ..errors import InvalidParameterError

if TYPE_CHECKING:
    from rich.text import Text
else:
    Text = LazyAttr("rich.text", "Text")  # rich is imported when a command prints

__all__ = [
    "all_or_nothing",
    "atomic_write_text",
    "check_output",
    "fault_message",
    "lit",
    "strict_json",
    "warn",
    "write_json",
]

#: The output path that means standard output.
STDOUT = "-"


def check_output(path: Path | None, flag: str, *, directory: bool = False, stdout: bool = True) -> None:
    """Check that ``path`` can be written, before any work; ``None`` passes.

    Parameters
    ----------
    path : Path or None
        The output file (or directory, with ``directory=True``) as the user gave it.
    flag : str
        The option's name as the user wrote it (``--json``), for the message.
    directory : bool
        The output is a directory (created if missing) rather than a file.
    stdout : bool
        ``-`` is accepted for a file (standard output).

    Raises
    ------
    InvalidParameterError
        Naming the flag and the path: a missing or read-only parent
        directory, a directory where a file goes, a file where a directory
        goes, a device, FIFO or socket, a symbolic link loop, a name longer
        than the file system allows.
    """
    from ..atomic import check_target

    if path is None:
        return
    p = Path(path)
    if str(path) == STDOUT:
        if stdout and not directory:
            return
        raise InvalidParameterError(f"{flag}: '-' (standard output) is not accepted here; give a {'folder' if directory else 'file'} name")
    if directory:
        if str(p) in ("", "."):
            p = Path(".")
        if p.is_dir():
            if not os.access(p, os.W_OK | os.X_OK):
                raise InvalidParameterError(f"{flag}: directory {p} is not writable")
            return
        if p.exists() or p.is_symlink():
            raise InvalidParameterError(f"{flag}: {p} exists and is not a directory")
        parent = p.parent if str(p.parent) else Path(".")
        if not parent.is_dir():
            what = "is not a directory" if parent.exists() else "does not exist"
            raise InvalidParameterError(f"{flag}: {p}: directory {parent} {what}")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise InvalidParameterError(f"{flag}: {p}: directory {parent} is not writable")
        return
    check_target(p, flag)


def all_or_nothing(command: Callable[..., Any]) -> Callable[..., Any]:
    """Run a command inside one :class:`~fingerloc.atomic.OutputGroup`: its outputs are renamed into place together
    when it succeeds, none when it fails; database locks are held to the end; ``lock_timeout`` (``--lock-timeout``),
    when the command has it, is the group's lock policy and a wait is said on stderr."""
    import functools

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        from ..atomic import OutputGroup
        from .app import err_console

        timeout = kwargs.get("lock_timeout")
        if timeout is not None and (math.isnan(timeout) or timeout < 0):
            raise InvalidParameterError(f"--lock-timeout must be a number of seconds >= 0 (or inf), got {timeout!r}")
        with OutputGroup(lock_timeout=timeout, notify=lambda text: err_console.print(lit(text))):
            return command(*args, **kwargs)

    return wrapper


def warn(lines: Iterable[str]) -> None:
    """Print each doubt as one ``warning: ...`` line on stderr (literally)."""
    from .app import err_console

    for line in lines:
        err_console.print(lit("warning: " + " ".join(str(line).split())), soft_wrap=True)


#: errno -> what the user is told (the file name comes first when there is one).
_FAULTS = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large (a file-size limit, e.g. ulimit -f)",
    errno.EROFS: "read-only file system",
    errno.ENAMETOOLONG: "file name too long",
    errno.EPIPE: "output closed (broken pipe)",
    errno.EIO: "input/output error",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.ENOENT: "no such file or directory",
    errno.ENOTDIR: "not a directory",
    errno.EISDIR: "is a directory",
    errno.ELOOP: "too many levels of symbolic links",
    errno.EMFILE: "too many open files",
    errno.ENFILE: "too many open files in the system",
    errno.ENOMEM: "out of memory",
    errno.ETXTBSY: "text file busy",
    errno.EXDEV: "cannot rename across file systems",
}


def fault_message(err: BaseException) -> str | None:
    """One line for an error the system raised (a full disk, a closed pipe...), or ``None`` for anything else.

    ``OSError`` with one of the errno values above, SQLite's "disk is full" /
    "disk I/O error", and ``MemoryError`` get a message naming the file when
    the error names one; anything else is a bug and keeps its traceback.
    """
    import sqlite3

    if isinstance(err, MemoryError):
        return "out of memory"
    if isinstance(err, sqlite3.OperationalError):
        text = str(err)
        if any(k in text for k in ("disk is full", "disk I/O error", "readonly database", "unable to open")):
            return f"the place database cannot be written ({text})"
        return None
    if not isinstance(err, OSError) or err.errno not in _FAULTS:
        return None
    what = _FAULTS[err.errno]
    name = err.filename
    if name is not None:
        return f"cannot write {os.fsdecode(name)}: {what}" if err.errno != errno.ENOENT else f"{os.fsdecode(name)}: {what}"
    return what


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


@contextmanager
def atomic_text_file(path: Path) -> Iterator[TextIO]:
    """A text file (UTF-8) written in place of ``path`` only when the block ends without an error.

    The temporary file sits next to ``path`` and is removed on any failure
    (:func:`fingerloc.atomic.replacing`); the new file gets mode
    ``0o666 & ~umask`` (or the old file's mode), and a symbolic link at
    ``path`` stays a link (its target is replaced). ``-`` is standard output.
    """
    from ..atomic import check_target, replacing

    if str(path) == STDOUT:
        yield sys.stdout
        sys.stdout.flush()
        return
    target = check_target(path, str(path))
    with replacing(target) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        yield fh


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
        if err.errno == errno.EPIPE:
            raise
        raise InvalidParameterError(f"{flag}: cannot write {path}: {err.strerror or err}") from err
    if str(path) != STDOUT:
        err_console.print(lit(f"wrote {path}"))


def lit(text: object) -> Text:
    """A user's string as rich text that is printed literally (no markup, no emoji codes)."""
    return Text(str(text))
