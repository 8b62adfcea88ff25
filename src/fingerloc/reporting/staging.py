"""Report folders written whole or not at all.

A report is a folder of files (``index.html``, figures, ``report.json``, a
sub-folder of photos). :func:`staged_folder` gives the writer a temporary
folder beside the report's; when the writer is done, every file it wrote is
renamed over its namesake in the report folder through
:func:`fingerloc.atomic.replace`: inside a command's
:class:`~fingerloc.atomic.OutputGroup` together with the command's other
outputs, or not at all. On an error the report folder stays as it was, and a
folder this created is removed again. :func:`staged_report` wraps a writer
``write(out_dir, ...) -> index path`` in it.
"""

from __future__ import annotations

import contextvars
import functools
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

from ..atomic import current_group, replace

__all__ = ["staged_folder", "staged_report"]

R = TypeVar("R", bound="Path | None")

_ACTIVE: contextvars.ContextVar[tuple[Path, ...]] = contextvars.ContextVar("fingerloc_staged", default=())


def _missing_dirs(path: Path) -> list[Path]:
    """The folders of ``path`` and above it that do not exist yet, the deepest first."""
    out = []
    for p in (path, *path.parents):
        if p.is_dir():
            break
        out.append(p)
    return out


@contextmanager
def staged_folder(out: str | Path) -> Iterator[Path]:
    """A temporary folder whose files (sub-folders included) replace their namesakes under ``out`` at the end.

    Parameters
    ----------
    out : str or Path
        The report folder; it may exist (files not written again stay) or not (it is created, with its parents).
        A folder inside one being staged already is written directly (the outer one stages it).

    Yields
    ------
    Path
        The temporary folder, on the same file system as ``out``.
    """
    target = Path(out)
    if any(target.is_relative_to(t) for t in _ACTIVE.get()):  # inside a folder staged already: it covers this
        target.mkdir(parents=True, exist_ok=True)
        yield target
        return
    base = target.parent
    while not base.is_dir():  # the nearest existing folder: the same file system as the report's
        base = base.parent
    created: list[Path] = []
    tmp = Path(tempfile.mkdtemp(prefix=".fingerloc-report-", dir=base))

    def clean() -> None:
        shutil.rmtree(tmp, ignore_errors=True)
        for d in sorted(set(created), key=lambda p: -len(p.parts)):
            try:
                d.rmdir()  # only when empty: files renamed into it stay
            except OSError:
                pass

    token = _ACTIVE.set((*_ACTIVE.get(), tmp))
    try:
        try:
            yield tmp
        finally:
            _ACTIVE.reset(token)
        files = sorted(p for p in tmp.rglob("*") if p.is_file())
        for f in files:
            dest = target / f.relative_to(tmp)
            created.extend(_missing_dirs(dest.parent))
            dest.parent.mkdir(parents=True, exist_ok=True)
            replace(f, dest)
    except OSError as err:
        clean()
        name = err.filename
        if name is not None and Path(name).is_relative_to(tmp):  # name the report's file, not the temporary one
            raise OSError(err.errno, err.strerror, str(target / Path(name).relative_to(tmp))) from None
        raise
    except BaseException:
        clean()
        raise
    group = current_group()
    if group is None:
        clean()
    else:
        group.at_end(clean)


def staged_report(write: Callable[..., R]) -> Callable[..., R]:
    """``write(out_dir, ...)`` run on a :func:`staged_folder` of ``out_dir``; the path it returns, under ``out_dir``."""

    @functools.wraps(write)
    def wrapper(out_dir: str | Path, *args: Any, **kwargs: Any) -> R:
        target = Path(out_dir)
        with staged_folder(target) as tmp:
            page = write(tmp, *args, **kwargs)
        if page is None:
            return page
        return target / Path(page).relative_to(tmp)  # type: ignore[return-value]

    return wrapper
