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
    for name in ("basic", "bench", "compare", "demo", "features", "kidnap", "learn", "localize", "logs", "loops", "mapping", "mog", "places", "reports", "robot", "track"):
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


def _fail(msg: str) -> None:
    sys.stderr.write(f"error: {_one_line(msg)}\n")
    sys.stderr.flush()
    raise SystemExit(2)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``fingerloc`` console script.

    Every failure a user can cause ends here as one line ``error: ...`` on
    stderr and exit code 2: fingerloc's own errors, the option parser's usage
    errors, and command-line arguments that are not valid UTF-8.
    """
    args = sys.argv[1:] if argv is None else list(argv)
    if args == ["--version"]:  # the fast path: nothing else to import
        from .._version import __version__

        sys.stdout.write(f"fingerloc {__version__}\n")
        sys.stdout.flush()
        raise SystemExit(0)
    from ..errors import FingerlocError

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
    try:
        rc = _load().app(args=args, prog_name="fingerloc", standalone_mode=False)
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
    raise SystemExit(rc if isinstance(rc, int) else 0)
