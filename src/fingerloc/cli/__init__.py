"""The ``fingerloc`` command line (README.md, "The command line"; file formats: docs/FORMATS.md).

Each area registers its commands in its own module; this package only builds
the application and turns a :class:`~fingerloc.errors.FingerlocError` into one
line on stderr and exit code 2.

Start-up is kept short: ``fingerloc --version`` answers before typer, rich or
numpy are imported, and the command modules import their heavy dependencies
(scipy, numba, matplotlib, rosbags) inside the command functions. The
application objects are built on first use (``fingerloc.cli.app``).
"""

from __future__ import annotations

import sys
from importlib import import_module
from types import ModuleType
from typing import Any

__all__ = ["app", "bench_app", "main", "reproduce_app"]


def _load() -> ModuleType:
    """Import the application and every command module (which register themselves)."""
    app_module = import_module(".app", __name__)  # not ``from . import app``: that would call __getattr__
    for name in ("basic", "bench", "compare", "demo", "features", "kidnap", "learn", "live", "localize", "logs", "loops", "mapping", "mog", "places", "reports", "robot", "track"):
        import_module(f".{name}", __name__)

    # importing the submodule ``app`` bound the package attribute ``app`` to it: bind the Typer objects
    globals().update(app=app_module.app, bench_app=app_module.bench_app, reproduce_app=app_module.reproduce_app)
    return app_module


def __getattr__(name: str) -> Any:
    if name in ("app", "bench_app", "reproduce_app"):
        return getattr(_load(), name)
    raise AttributeError(f"module 'fingerloc.cli' has no attribute {name!r}")


def _one_line(text: str) -> str:
    return " ".join(str(text).split())  # one line, whatever the message holds


def _fail(msg: str, code: int = 2) -> None:
    try:
        sys.stderr.write(f"error: {_one_line(msg)}\n")
        sys.stderr.flush()
    except OSError:  # stderr gone too: the exit code says it
        pass
    raise SystemExit(code)


class _Interrupted(BaseException):
    """SIGINT, raised by fingerloc's own handler (typer would turn a KeyboardInterrupt into a silent exit 130)."""


def _on_sigint(signum: int, frame: Any) -> None:
    raise _Interrupted


def _quiet_stdout() -> None:
    """After a fault on standard output: point it at /dev/null so that the exit's flush adds no second line."""
    import os

    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, sys.stdout.fileno())
        os.close(fd)
    except (OSError, ValueError, AttributeError):
        pass


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``fingerloc`` console script.

    Every failure a user can cause ends here as one line ``error: ...`` on
    stderr and exit code 2: fingerloc's own errors, the option parser's usage
    errors, command-line arguments that are not valid UTF-8, and what the
    system refuses (a full disk, a file-size limit, a read-only file system,
    a name too long, a closed output pipe: :func:`fingerloc.cli._io.fault_message`).
    SIGINT (Ctrl-C) ends in one line and exit code 130. numpy's
    floating-point RuntimeWarnings are not printed.
    """
    args = sys.argv[1:] if argv is None else list(argv)
    if args == ["--version"]:  # the fast path: nothing else to import
        from .._version import __version__

        sys.stdout.write(f"fingerloc {__version__}\n")
        sys.stdout.flush()
        raise SystemExit(0)
    try:  # typer >= 0.23 vendors click as typer._click
        from typer import _click
    except ImportError:  # pragma: no cover - older typer on click
        import click as _click  # type: ignore[no-redef]
    aborts: tuple[type[BaseException], ...] = (_click.exceptions.Abort,) if hasattr(_click.exceptions, "Abort") else ()
    try:
        from typer import exceptions as _typer_exceptions

        aborts += (_typer_exceptions.Abort,)
    except (ImportError, AttributeError):  # pragma: no cover - older typer
        pass

    for a in args:
        try:
            str(a).encode("utf-8")
        except UnicodeEncodeError:
            _fail(f"argument {str(a).encode('utf-8', 'backslashreplace').decode('ascii', 'replace')!r} is not valid UTF-8")
    import signal
    import warnings

    try:
        old_handler = signal.signal(signal.SIGINT, _on_sigint)
    except ValueError:  # not the main thread: SIGINT stays Python's
        old_handler = None
    try:
        with warnings.catch_warnings():
            # numpy's floating-point notes: the command line speaks in error: / warning: lines only
            warnings.simplefilter("ignore", RuntimeWarning)
            rc = _run(args, aborts, _click)
    finally:
        if old_handler is not None:
            signal.signal(signal.SIGINT, old_handler)
    raise SystemExit(rc if isinstance(rc, int) else 0)


def _run(args: list[str], aborts: tuple[type[BaseException], ...], _click: Any) -> Any:
    """The application, every failure a user or the system can cause turned into one line."""
    from ..errors import FingerlocError

    try:
        rc = _load().app(args=args, prog_name="fingerloc", standalone_mode=False)
        sys.stdout.flush()  # a full device or a closed pipe: here, not at the interpreter's exit
        return rc
    except _Interrupted:
        _quiet_stdout()
        _fail("interrupted (SIGINT); files being written were not kept", 130)
    except SystemExit as err:
        if type(sys.stdout).__name__ == "PacifyFlushWrapper":  # typer's handling of a closed pipe (EPIPE)
            _quiet_stdout()
            _fail("output closed (broken pipe)")
        raise err
    except (OSError, MemoryError) as err:
        from ._io import fault_message

        msg = fault_message(err)
        if msg is None:
            raise
        _quiet_stdout()
        _fail(msg)
    except FingerlocError as err:
        _fail(str(err))
    except _click.exceptions.NoArgsIsHelpError as err:
        err.show()
        raise SystemExit(2) from None
    except _click.exceptions.UsageError as err:
        msg = err.format_message()
        msg = msg[:1].lower() + msg[1:]
        cmd = err.ctx.command_path if err.ctx is not None else "fingerloc"
        _fail(f"{msg} (see '{cmd} --help')")
    except _click.exceptions.ClickException as err:
        _fail(err.format_message())
    except aborts:
        _fail("aborted")
    return None
