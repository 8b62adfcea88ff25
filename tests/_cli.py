"""Running the ``fingerloc`` command line in-process, for the tests."""

from __future__ import annotations

from typing import Any

from fingerloc.cli import main


def run_cli(capsys: Any, *args: object) -> tuple[int, str, str]:
    """Run ``fingerloc ARGS...``; return the exit code, stdout and stderr."""
    code = 0
    try:
        main([str(a) for a in args])
    except SystemExit as e:
        code = int(e.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err
