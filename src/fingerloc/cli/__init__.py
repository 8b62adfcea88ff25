"""The ``fingerloc`` command line (DESIGN.md, "The command line").

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
    for name in ("basic", "bench", "demo", "features", "logs", "mapping", "mog", "places", "reports", "robot", "track"):
        import_module(f".{name}", __name__)

    # importing the submodule ``app`` bound the package attribute ``app`` to it: bind the Typer objects
    globals().update(app=app_module.app, bench_app=app_module.bench_app, reproduce_app=app_module.reproduce_app)
    return app_module


def __getattr__(name: str) -> Any:
    if name in ("app", "bench_app", "reproduce_app"):
        return getattr(_load(), name)
    raise AttributeError(f"module 'fingerloc.cli' has no attribute {name!r}")


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``fingerloc`` console script."""
    args = sys.argv[1:] if argv is None else list(argv)
    if args == ["--version"]:  # the fast path: nothing else to import
        from .._version import __version__

        sys.stdout.write(f"fingerloc {__version__}\n")
        sys.stdout.flush()
        raise SystemExit(0)
    from ..errors import FingerlocError

    try:
        _load().app(args=argv, prog_name="fingerloc")
    except FingerlocError as err:
        msg = " ".join(str(err).split())  # one line, whatever the message holds
        sys.stderr.write(f"error: {msg}\n")
        sys.stderr.flush()
        raise SystemExit(2) from None
