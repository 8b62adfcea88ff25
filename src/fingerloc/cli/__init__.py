"""The ``fingerloc`` command line (DESIGN.md, "The command line").

Each area registers its commands in its own module; this package only builds
the application and turns a :class:`~fingerloc.errors.FingerlocError` into one
line on stderr and exit code 2.
"""

from __future__ import annotations

import sys

from ..errors import FingerlocError
from .app import app, bench_app, reproduce_app

# Command modules register themselves on import.
from . import basic, bench, demo, features, logs, mog, places, robot, track  # noqa: F401  isort: skip

__all__ = ["app", "bench_app", "main", "reproduce_app"]


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

    args = sys.argv[1:] if argv is None else list(argv)
    for a in args:
        try:
            str(a).encode("utf-8")
        except UnicodeEncodeError:
            _fail(f"argument {str(a).encode('utf-8', 'backslashreplace').decode('ascii', 'replace')!r} is not valid UTF-8")
    try:
        rc = app(args=args, prog_name="fingerloc", standalone_mode=False)
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
