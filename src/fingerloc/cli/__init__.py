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
from . import basic, bench, demo, features, logs, mapping, mog, places, reports, robot, track  # noqa: F401  isort: skip

__all__ = ["app", "bench_app", "main", "reproduce_app"]


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``fingerloc`` console script."""
    try:
        app(args=argv, prog_name="fingerloc")
    except FingerlocError as err:
        msg = " ".join(str(err).split())  # one line, whatever the message holds
        sys.stderr.write(f"error: {msg}\n")
        sys.stderr.flush()
        raise SystemExit(2) from None
