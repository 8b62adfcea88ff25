"""``fingerloc bench speed``: every speed figure in one run.

Each area contributes one *section*: a function ``(quick: bool) -> dict`` that
times its kernels and returns JSON-ready figures. Sections are registered with
:func:`section` by the modules imported at the bottom of this file.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

__all__ = ["SECTIONS", "best_time", "run_speed", "section"]

SectionFn = Callable[[bool], dict[str, Any]]

#: Registered sections, in run order: name -> function(quick) -> figures.
SECTIONS: dict[str, SectionFn] = {}


def section(name: str) -> Callable[[SectionFn], SectionFn]:
    """Register a speed-benchmark section under ``name``."""

    def deco(fn: SectionFn) -> SectionFn:
        SECTIONS[name] = fn
        return fn

    return deco


def best_time(
    fn: Callable[[], object], *, repeat: int = 3, number: int = 1, clock: Callable[[], float] = time.perf_counter
) -> float:
    """Best time in seconds of ``number`` calls of ``fn``, over ``repeat`` rounds.

    ``clock`` is wall time by default; ``time.thread_time`` gives the CPU time
    of this thread, which other processes on a loaded machine disturb less.
    """
    best = float("inf")
    for _ in range(repeat):
        t0 = clock()
        for _ in range(number):
            fn()
        best = min(best, (clock() - t0) / number)
    return best


def run_speed(
    names: list[str] | None = None,
    *,
    quick: bool = False,
    on_section: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run the named sections (all by default) and return ``{name: figures}``."""
    _load_sections()
    chosen = list(SECTIONS) if not names else names
    out: dict[str, Any] = {}
    for name in chosen:
        if name not in SECTIONS:
            from ..errors import InvalidParameterError

            raise InvalidParameterError(f"unknown speed section {name!r} (known: {', '.join(SECTIONS)})")
        if on_section is not None:
            on_section(name)
        out[name] = SECTIONS[name](quick)
    return out


def _load_sections() -> None:
    # Each import registers its section(s). Add a line per area.
    import importlib

    for mod in _SECTION_MODULES:
        importlib.import_module(mod)


_SECTION_MODULES: list[str] = [
    "fingerloc.experiments.speed_mog",
    "fingerloc.experiments.speed_align",
    "fingerloc.experiments.speed_model",
    "fingerloc.experiments.speed_laser",
    "fingerloc.experiments.speed_sim",
    "fingerloc.experiments.carmen",
    "fingerloc.experiments.extractors",
    "fingerloc.experiments.speed_markov",
    "fingerloc.experiments.speed_startup",
    "fingerloc.experiments.speed_localize",
]
