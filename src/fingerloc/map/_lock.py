"""The writer lock of a place database, and SQLite's own journals settled under it.

One writer at a time: every command that changes a database holds an
exclusive ``flock`` on ``<db>.lock`` (beside the database) from its first
read to its last write (:func:`locked`). A process that finds the lock held
says so (``notify``), polls, and gives up with a
:class:`~fingerloc.errors.DatabaseLockedError` after ``timeout`` seconds.
The holder writes its process id into the lock file, so that the message
can name it.

Under the lock, :func:`settle_journals` hands SQLite's leftovers of another
program to SQLite: a hot rollback journal (``<db>-journal``, a write that
died) is rolled back, and a database in WAL mode (``<db>-wal``, ``<db>-shm``)
is checkpointed and switched back to a rollback journal, which removes the
two files. A database fingerloc replaces is therefore never left beside a WAL
file that SQLite would apply to the new one.
"""

from __future__ import annotations

import errno
import math
import os
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import closing, contextmanager
from pathlib import Path

from ..atomic import current_group
from ..errors import DatabaseError, DatabaseLockedError

__all__ = ["DEFAULT_LOCK_TIMEOUT_S", "locked", "settle_journals"]

#: Seconds a writer waits for another writer's lock before it gives up (``--lock-timeout``).
DEFAULT_LOCK_TIMEOUT_S = 60.0

Notify = Callable[[str], None]

_held: dict[tuple[int, str], int] = {}
_held_guard = threading.RLock()


def real_path(path: str | Path) -> Path:
    """The file a database path names: symbolic links followed (the file need not exist)."""
    return Path(os.path.realpath(path))


def lock_path(path: str | Path) -> Path:
    """``<db>.lock`` beside the file ``path`` names."""
    real = real_path(path)
    return real.with_name(real.name + ".lock")


def _uri(p: Path) -> str:
    from urllib.parse import quote

    return quote(str(p.absolute()))


def _holder(fd: int) -> str:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return ""
    return f" by process {text}" if text.isdigit() else ""


def _check_timeout(timeout: float | None) -> float:
    t = DEFAULT_LOCK_TIMEOUT_S if timeout is None else timeout
    if isinstance(t, bool) or not isinstance(t, (int, float)) or math.isnan(t) or t < 0:
        from ..errors import InvalidParameterError

        raise InvalidParameterError(f"lock timeout must be a number of seconds >= 0, got {timeout!r}")
    return float(t)


def _acquire(fd: int, path: str | Path, lock: Path, timeout: float, notify: Notify | None) -> None:
    import fcntl

    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return
    except OSError as err:
        if err.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            raise DatabaseError(f"{path}: cannot lock {lock} ({err.strerror or err})") from None
    who = _holder(fd)
    if notify is not None:
        limit = "for ever" if math.isinf(timeout) else f"up to {timeout:g} s (--lock-timeout)"
        notify(f"waiting for {lock}: another fingerloc{who} is writing {path}; waiting {limit}")
    start = time.monotonic()
    delay = 0.02
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return
        except OSError as err:
            if err.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise DatabaseError(f"{path}: cannot lock {lock} ({err.strerror or err})") from None
        waited = time.monotonic() - start
        if waited >= timeout:
            raise DatabaseLockedError(
                f"{path}: gave up after {waited:.0f} s waiting for the writer lock {lock}, held{_holder(fd) or who} "
                "(another fingerloc writing this database; try again when it has finished, or give --lock-timeout)"
            )
        time.sleep(min(delay, max(timeout - waited, 0.0) + 0.001))
        delay = min(delay * 1.5, 0.5)


@contextmanager
def locked(path: str | Path, *, timeout: float | None = None, notify: Notify | None = None) -> Iterator[None]:
    """Hold the exclusive writer lock of a place database (``<db>.lock``), re-entrantly.

    Wrap a read-modify-write (load, change, save) in it: no other fingerloc
    process writes the database in between. Inside an
    :class:`~fingerloc.atomic.OutputGroup`, the lock is kept until the
    group's files are renamed into place.

    Parameters
    ----------
    path : str or Path
        The database (it need not exist yet).
    timeout : float, optional
        Seconds to wait for another writer (default: the current output
        group's, else :data:`DEFAULT_LOCK_TIMEOUT_S`; ``math.inf``: for ever).
    notify : callable, optional
        Gets one line when the lock is busy (default: the output group's).

    Raises
    ------
    DatabaseLockedError
        Another process held the lock for ``timeout`` seconds.
    DatabaseError
        The lock file cannot be created (a missing or read-only directory).
    """
    group = current_group()
    if group is not None:
        timeout = group.lock_timeout if timeout is None else timeout
        notify = group.notify if notify is None else notify
    wait = _check_timeout(timeout)
    real = real_path(path)
    key = (threading.get_ident(), str(real))  # re-entrant per thread: another thread waits on the flock
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
    lock = lock_path(path)
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as err:
        raise DatabaseError(f"{path}: cannot create the lock file {lock} ({err.strerror or err})") from None

    def release() -> None:
        with _held_guard:
            _held.pop(key, None)
        os.close(fd)  # closing releases the flock

    try:
        _acquire(fd, path, lock, wait, notify)
        try:  # the holder's process id, for a waiting writer's message (a full disk: no id, still locked)
            os.ftruncate(fd, 0)
            os.pwrite(fd, str(os.getpid()).encode(), 0)
        except OSError:
            pass
        with _held_guard:
            _held[key] = 1
        settle_journals(real, path)
    except BaseException:
        release()
        raise
    if group is not None:
        group.at_end(release)  # after the group's renames
        yield
        return
    try:
        yield
    finally:
        release()


def settle_journals(real: Path, shown: str | Path | None = None) -> None:
    """Let SQLite settle what another program left beside ``real``: roll back a hot journal, end WAL mode.

    Call under :func:`locked`. Nothing to do (no ``-journal``, no ``-wal``):
    no file is opened.

    Raises
    ------
    DatabaseError
        When SQLite cannot do it (another program holds the database open, a
        read-only folder): one line saying what to do.
    """
    name = shown if shown is not None else real
    journal = Path(str(real) + "-journal")
    wal = Path(str(real) + "-wal")
    if not real.is_file() or not (journal.exists() or wal.exists()):
        return
    try:
        with closing(sqlite3.connect(f"file:{_uri(real)}?mode=rw", uri=True, timeout=0.5)) as con:
            con.execute("SELECT count(*) FROM sqlite_master").fetchone()  # rolls a hot journal back
            mode = con.execute("PRAGMA journal_mode").fetchone()
            if (mode is not None and str(mode[0]).lower() == "wal") or wal.exists():
                con.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()
                con.execute("PRAGMA journal_mode=DELETE").fetchone()
    except sqlite3.Error as err:
        what = "a WAL file (-wal) of another program" if wal.exists() else "a rollback journal of a failed write"
        raise DatabaseError(
            f"{name}: {what} is beside the database and SQLite cannot settle it ({err}); "
            "close every program that has the database open, then try again"
        ) from None
    for leftover in (wal, Path(str(real) + "-shm")):
        if leftover.exists() and wal.exists():
            raise DatabaseError(
                f"{name}: {leftover.name} stays beside the database after a checkpoint (another program has it "
                "open in WAL mode); close it, then try again"
            )
