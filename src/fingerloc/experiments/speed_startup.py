"""Speed section ``startup`` of ``fingerloc bench speed``: how long the command takes to start.

Runs ``fingerloc --version`` and ``fingerloc --help`` in fresh interpreters
(the console script's own code: ``from fingerloc.cli import main; main()``),
five times each, and reports the median wall time and the median CPU time of
the child process (user + system), which a loaded machine disturbs less.
"""

from __future__ import annotations

import resource
import statistics
import subprocess
import sys
import time
from typing import Any

from .speed import section

__all__ = ["startup_figures"]


def _run_once(args: list[str]) -> tuple[float, float]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-c", "from fingerloc.cli import main; main()", *args],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def startup_figures(repeat: int = 5) -> dict[str, Any]:
    """Median wall and CPU seconds of ``fingerloc --version`` and ``fingerloc --help`` over ``repeat`` runs."""
    out: dict[str, Any] = {"runs": repeat}
    for name, args in (("version", ["--version"]), ("help", ["--help"])):
        runs = [_run_once(args) for _ in range(repeat)]
        out[f"{name}_median_s"] = statistics.median(w for w, _ in runs)
        out[f"{name}_median_cpu_s"] = statistics.median(c for _, c in runs)
    return out


@section("startup")
def speed_startup(quick: bool) -> dict[str, Any]:
    """Start-up time of the command line."""
    return startup_figures(3 if quick else 5)
