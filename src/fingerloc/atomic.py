"""Output files written whole or not at all.

Every file fingerloc writes (a place database, JSON, JSON Lines) follows one
protocol:

1. :func:`check_target` checks the output location before any work: the
   path is a regular file or does not exist yet (a character device, a FIFO,
   a socket or a symbolic link loop is refused: writing "through" them would
   replace them with a regular file), its folder exists and is writable, its
   name fits the file system;
2. the content goes to a temporary file beside the target
   (:func:`temporary_name`: a short name even for a target whose own name is
   near the file system's limit), synced;
3. :func:`replace` renames the temporary file over the target.

An :class:`OutputGroup` makes several outputs one unit: inside it,
:func:`replace` only records the rename, and the renames are done together
when the group's block ends without an error (on an error every temporary
file is removed, and the targets stay as they were). Locks taken inside the
group (``fingerloc.map.database.locked``) are held until the renames are
done. A group also carries a command's lock policy (how long to wait for a
database's writer lock, and where to say that it waits).
"""

from __future__ import annotations

import contextvars
import errno
import hashlib
import os
import stat
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, ExitStack, contextmanager
from pathlib import Path
from types import TracebackType
from typing import Any

from .errors import InvalidParameterError

__all__ = [
    "OutputGroup",
    "check_target",
    "current_group",
    "file_kind",
    "name_max",
    "replace",
    "temporary_name",
    "umask",
    "write_fault",
]

Notify = Callable[[str], None]

_GROUP: contextvars.ContextVar[OutputGroup | None] = contextvars.ContextVar("fingerloc_output_group", default=None)

#: Longest file name (bytes) assumed when the file system does not say.
DEFAULT_NAME_MAX = 255


def umask() -> int:
    """The process's umask (read without changing it for longer than the call)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def file_kind(mode: int) -> str:
    """A readable name of a file type from its ``st_mode`` (``"character device"``, ``"FIFO"``...)."""
    for test, name in (
        (stat.S_ISREG, "regular file"),
        (stat.S_ISDIR, "directory"),
        (stat.S_ISCHR, "character device"),
        (stat.S_ISBLK, "block device"),
        (stat.S_ISFIFO, "FIFO (named pipe)"),
        (stat.S_ISSOCK, "socket"),
        (stat.S_ISLNK, "symbolic link"),
    ):
        if test(mode):
            return name
    return "special file"


def name_max(directory: Path) -> int:
    """Longest file name (bytes) the file system of ``directory`` accepts."""
    try:
        return int(os.pathconf(directory, "PC_NAME_MAX"))
    except (OSError, ValueError):
        return DEFAULT_NAME_MAX


def check_target(path: str | Path, what: str, *, create_parent: bool = False) -> Path:
    """Check an output file's location before any work; return the file to write (links followed).

    Parameters
    ----------
    path : str or Path
        The output as the user gave it.
    what : str
        How the user named it (``--json``, ``--db``), for the messages.
    create_parent : bool
        Accept a missing parent folder (the caller creates it).

    Returns
    -------
    Path
        The file that will be replaced: ``path`` itself, or the file a
        symbolic link at ``path`` points to (the link stays).

    Raises
    ------
    InvalidParameterError
        One line naming ``what`` and the path: a symbolic link loop, an
        existing directory, device, FIFO or socket, a missing or read-only
        folder, a name longer than the file system allows.
    """
    p = Path(path)
    if str(p) in ("", "."):
        raise InvalidParameterError(f"{what}: {str(path)!r} is not a file name")
    target = p
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        st = None
    except OSError as err:
        raise InvalidParameterError(f"{what}: {p}: {err.strerror or err}") from None
    if st is not None and stat.S_ISLNK(st.st_mode):
        try:
            target = Path(os.path.realpath(p, strict=True))
        except FileNotFoundError:
            target = Path(os.path.realpath(p))  # a dangling link: its target is created
        except OSError as err:
            if err.errno == errno.ELOOP:
                raise InvalidParameterError(f"{what}: {p} is a symbolic link loop, not a file") from None
            raise InvalidParameterError(f"{what}: {p}: {err.strerror or err}") from None
        try:
            st = os.stat(target)
        except FileNotFoundError:
            st = None
        except OSError as err:
            raise InvalidParameterError(f"{what}: {p}: {err.strerror or err}") from None
    if st is not None and not stat.S_ISREG(st.st_mode):
        kind = file_kind(st.st_mode)
        hint = " (give a file name)" if kind == "directory" else " (give the name of a regular file)"
        raise InvalidParameterError(f"{what}: {p} is a {kind}, not a regular file{hint}")
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        if create_parent and not parent.exists():
            return target
        why = "is not a directory" if parent.exists() else "does not exist"
        raise InvalidParameterError(f"{what}: {p}: directory {parent} {why}")
    limit = name_max(parent)
    size = len(os.fsencode(target.name))
    if size > limit:
        raise InvalidParameterError(f"{what}: {p}: a file name of {size} bytes is longer than the {limit} allowed here")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InvalidParameterError(f"{what}: {p}: directory {parent} is not writable")
    return target


def temporary_name(target: Path) -> tuple[str, str]:
    """Prefix and suffix of a temporary file beside ``target`` (for :func:`tempfile.mkstemp`).

    ``<name>.XXXXXXXX.tmp`` when that fits the file system's name limit; for a
    longer name, ``.<start of name>~<hash>.XXXXXXXX.tmp`` (the hash of the whole
    name keeps two long names apart).
    """
    name = target.name
    parent = target.parent if str(target.parent) else Path(".")
    if len(os.fsencode(name)) + 16 <= name_max(parent):
        return name + ".", ".tmp"
    digest = hashlib.sha256(os.fsencode(name)).hexdigest()[:16]
    head = os.fsencode(name)[:64].decode("utf-8", "ignore")
    return f".{head}~{digest}.", ".tmp"


def temporary_patterns(target: Path) -> tuple[str, ...]:
    """Glob patterns of the temporary files :func:`temporary_name` makes for ``target``."""
    prefix, suffix = temporary_name(target)
    return (f"{_glob_escape(prefix)}*{suffix}",)


def _glob_escape(text: str) -> str:
    return "".join(f"[{c}]" if c in "*?[" else c for c in text)


def write_fault(directory: Path, detail: str) -> str:
    """Why a write in ``directory`` failed, in words, when the system's message is vague (SQLite says "disk
    I/O error" for a file-size limit): a full file system, else a file-size limit, else ``detail``."""
    import resource

    try:
        st = os.statvfs(directory)
        if st.f_bavail * st.f_frsize < 1 << 16:
            return "no space left on the device"
    except OSError:
        pass
    soft, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    if soft != resource.RLIM_INFINITY:
        return f"file too large (a file-size limit of {soft} bytes, e.g. ulimit -f)"
    if "full" in detail:
        return "no space left on the device"
    return detail


def fsync_directory(directory: Path) -> None:
    """Make a rename in ``directory`` durable (best effort: not every file system allows it)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def replace(tmp: str | Path, target: str | Path) -> None:
    """Rename ``tmp`` over ``target`` now, or when the current :class:`OutputGroup` ends."""
    group = _GROUP.get()
    if group is not None:
        group.defer(Path(tmp), Path(target))
        return
    os.replace(tmp, target)
    fsync_directory(Path(target).parent)


def current_group() -> OutputGroup | None:
    """The :class:`OutputGroup` of the running block, if any."""
    return _GROUP.get()


class OutputGroup(AbstractContextManager["OutputGroup"]):
    """Several outputs as one: renamed into place together, or none of them (module docstring).

    Parameters
    ----------
    lock_timeout : float, optional
        Seconds to wait for a place database's writer lock inside the group
        (``None``: the database module's default).
    notify : callable, optional
        Gets a line when a lock is waited for.
    """

    def __init__(self, *, lock_timeout: float | None = None, notify: Notify | None = None) -> None:
        self.lock_timeout = lock_timeout
        self.notify = notify
        self._renames: list[tuple[Path, Path]] = []
        self._stack = ExitStack()
        self._token: contextvars.Token[OutputGroup | None] | None = None

    def __enter__(self) -> OutputGroup:
        self._token = _GROUP.set(self)
        return self

    def defer(self, tmp: Path, target: Path) -> None:
        """Rename ``tmp`` over ``target`` when the group ends well (a later rename of one target wins)."""
        self._renames.append((tmp, target))

    def hold(self, cm: AbstractContextManager[Any]) -> Any:
        """Enter ``cm`` (a lock) now and exit it when the group ends, after the renames."""
        return self._stack.enter_context(cm)

    def at_end(self, callback: Callable[[], Any]) -> None:
        """Call ``callback`` when the group ends (either way), after the renames."""
        self._stack.callback(callback)

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> bool | None:
        if self._token is not None:
            _GROUP.reset(self._token)
            self._token = None
        try:
            if exc_type is None:
                self._commit()
            else:
                self._discard(self._renames)
        finally:
            self._renames = []
            self._stack.__exit__(exc_type, exc, tb)
        return None

    def _commit(self) -> None:
        pending = list(self._renames)
        try:
            while pending:
                tmp, target = pending[0]
                os.replace(tmp, target)
                pending.pop(0)
                fsync_directory(target.parent)
        except BaseException:
            self._discard(pending)
            raise

    @staticmethod
    def _discard(renames: list[tuple[Path, Path]]) -> None:
        for tmp, _ in renames:
            for f in (tmp, Path(str(tmp) + "-journal")):
                try:
                    f.unlink(missing_ok=True)
                except OSError:
                    pass


@contextmanager
def replacing(target: Path, *, mode: int | None = None) -> Iterator[Path]:
    """A temporary file beside ``target`` that replaces it when the block ends without an error.

    Yields the temporary file's path (created empty, mode 0600 until the
    end); the file is synced, given ``mode`` (default: the old file's mode,
    or ``0o666`` minus the umask for a new file) and renamed over ``target``
    (:func:`replace`). On an error it is removed and ``target`` stays.
    """
    import tempfile

    directory = target.parent if str(target.parent) else Path(".")
    keep = mode
    if keep is None:
        keep = target.stat().st_mode & 0o7777 if target.is_file() else 0o666 & ~umask()
    prefix, suffix = temporary_name(target)
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=directory)
    os.close(fd)
    try:
        yield Path(tmp)
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, keep)
        replace(tmp, target)
    except BaseException as err:
        for f in (Path(tmp), Path(tmp + "-journal")):
            try:
                f.unlink(missing_ok=True)
            except OSError:
                pass
        if isinstance(err, OSError) and err.filename is None and err.errno is not None:
            raise OSError(err.errno, os.strerror(err.errno), str(target)) from None  # name the output
        raise
