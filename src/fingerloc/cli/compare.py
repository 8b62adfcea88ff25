"""``fingerloc bench compare A.json B.json``: which figures of two benchmark runs differ."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from ..errors import DataFormatError, InvalidParameterError
from .app import bench_app, console

__all__ = ["compare_cmd"]


@bench_app.command("compare")
def compare_cmd(
    first: Path = typer.Argument(..., help="A benchmark's --json output (the reference)."),
    second: Path = typer.Argument(..., help="Another run's --json output of the same benchmark."),
    timings: bool = typer.Option(False, "--timings", help="Also list the timings that differ, with their ratio."),
) -> None:
    """Compare two --json outputs of a benchmark: every figure that differs, timings apart.

    Exit code 0 when every figure but the timings is the same, 1 when some
    differ (as diff does), 2 on bad input.
    """
    from ..experiments.compare import compare_json

    docs = []
    for p in (first, second):
        try:
            docs.append(json.loads(p.read_text(encoding="utf-8")))
        except FileNotFoundError:
            raise InvalidParameterError(f"{p}: no such file") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
            raise DataFormatError(f"not a JSON document ({err})", path=p) from None
    diffs = compare_json(docs[0], docs[1], timings=timings)
    figures = [d for d in diffs if not d.timing]
    for d in diffs:
        ratio = "" if d.ratio is None or not d.timing else f"  (x{d.ratio:.3f})"
        console.print(f"{'timing ' if d.timing else ''}{d.path}: {d.first!r} -> {d.second!r}{ratio}", markup=False, soft_wrap=True)
    console.print("identical figures" if not figures else f"{len(figures)} figure(s) differ", markup=False)
    raise typer.Exit(1 if figures else 0)
