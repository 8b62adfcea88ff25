"""The real-log benchmark's protocol, metrics and method registry (shared by :mod:`.carmen` and :mod:`.markov`).

The places, training scans and queries of a log come from the library
(:func:`fingerloc.pipeline.places.places_from_trajectory`, first half
mapping); this module holds what every benchmark module shares, so that the
method modules import it and not each other. Methods are registered by the
modules named in :data:`METHOD_MODULES`, loaded (by name) the first time a
method is looked up.
"""

from __future__ import annotations

import importlib
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from .._types import FArray, IArray
from ..errors import InvalidParameterError
from ..metrics import rank_metrics, true_place_ranks
from ..pipeline.places import PLACE_RADIUS_M as _PLACE_RADIUS_M
from ..pipeline.places import PLACE_SPACING_M as _PLACE_SPACING_M
from ..pipeline.places import PlaceSplit, places_from_trajectory
from ..pipeline.readers import load_log_scans
from ..sensors import Scan

__all__ = [
    "DEFAULT_METHODS",
    "METHODS",
    "METHOD_MODULES",
    "PLACE_RADIUS_M",
    "PLACE_SPACING_M",
    "Method",
    "Split",
    "load_log_scans",
    "load_methods",
    "log_name",
    "make_method",
    "make_split",
    "rank_metrics",
    "register_method",
    "true_place_ranks",
]


#: Modules whose import registers benchmark methods (loaded by :func:`load_methods`).
METHOD_MODULES: tuple[str, ...] = ("fingerloc.experiments.carmen", "fingerloc.experiments.filtered")


#: D: a mapping scan strictly farther than this from every centre makes a new place, metres.
PLACE_SPACING_M = _PLACE_SPACING_M
#: R: scans within this distance (inclusive) of a centre train / query it, metres.
PLACE_RADIUS_M = _PLACE_RADIUS_M



# ---------------------------------------------------------------------------------------------------
# Protocol
# ---------------------------------------------------------------------------------------------------


#: Places, training scans and queries of one log (the library's :class:`~fingerloc.pipeline.places.PlaceSplit`).
Split = PlaceSplit


def make_split(
    positions: Any,
    *,
    place_spacing: float = PLACE_SPACING_M,
    radius: float = PLACE_RADIUS_M,
    n_mapping: int | None = None,
) -> Split:
    """Apply the benchmark's protocol to a trajectory (module docstring, steps 1-3).

    The library's :func:`~fingerloc.pipeline.places.places_from_trajectory`
    with the first half of the scans mapping (``fingerloc map``'s defaults),
    or the first ``n_mapping`` scans when given (a hardened benchmark run:
    :func:`fingerloc.experiments.carmen.run_benchmark`'s ``mapping_part``).

    Parameters
    ----------
    positions : array_like, shape (n, 2)
        Robot positions of the scans in file order, metres.
    place_spacing : float, default 2.0
        ``D``, metres (a new place needs a distance strictly greater).
    radius : float, default 1.0
        ``R``, metres (inclusive).

    n_mapping : int, optional
        Scans of the mapping pass (default ``n // 2``).

    Returns
    -------
    Split
    """
    if not (isinstance(place_spacing, (int, float)) and place_spacing > 0 and math.isfinite(place_spacing)):
        raise InvalidParameterError(f"place_spacing must be a positive number of metres, got {place_spacing!r}")
    return places_from_trajectory(positions, mapping_part=0.5, n_mapping=n_mapping, spacing=place_spacing, radius=radius)


# ---------------------------------------------------------------------------------------------------
# Metrics: fingerloc.metrics (true_place_ranks, rank_metrics), re-exported here for the experiments
# ---------------------------------------------------------------------------------------------------


# ---------------------------------------------------------------------------------------------------
# Methods
# ---------------------------------------------------------------------------------------------------


@runtime_checkable
class Method(Protocol):
    """A place-recognition method under test.

    ``fit`` learns places ``0 .. n_places - 1`` from training scans (every
    place has at least one); ``score`` returns an ``(n_queries, n_places)``
    array, higher = more likely that place (any monotone scale: log-posterior,
    similarity, negative distance).
    """

    name: str

    def fit(self, scans: Sequence[Scan], labels: IArray) -> object: ...

    def score(self, scans: Sequence[Scan]) -> FArray: ...


#: name -> factory making a fresh, unfitted method.
METHODS: dict[str, Callable[[], Method]] = {}


#: Names run when no method is asked for (registration order).
DEFAULT_METHODS: list[str] = []


def register_method(name: str, *, default: bool = True) -> Callable[[Callable[[], Method]], Callable[[], Method]]:
    """Register a method factory under ``name`` (a decorator).

    Names starting with ``fingerprint`` are fingerprint programs, names
    starting with ``baseline-`` scan-descriptor baselines. ``default=False``
    keeps a method out of the default run (it runs when named).
    """
    if not re.fullmatch(r"[a-z0-9][a-z0-9._-]*", name):
        raise InvalidParameterError(f"method name must be lower-case letters, digits, '.', '_' or '-', got {name!r}")

    def deco(factory: Callable[[], Method]) -> Callable[[], Method]:
        METHODS[name] = factory
        if default and name not in DEFAULT_METHODS:
            DEFAULT_METHODS.append(name)
        elif not default and name in DEFAULT_METHODS:
            DEFAULT_METHODS.remove(name)
        return factory

    return deco


def load_methods() -> dict[str, Callable[[], Method]]:
    """Import every module of :data:`METHOD_MODULES` (they register their methods); returns :data:`METHODS`."""
    for mod in METHOD_MODULES:
        importlib.import_module(mod)
    return METHODS


def make_method(name: str) -> Method:
    """A fresh method by registered name."""
    load_methods()
    if name not in METHODS:
        raise InvalidParameterError(f"unknown method {name!r} (known: {', '.join(METHODS)})")
    m = METHODS[name]()
    m.name = name
    return m


def log_name(path: str | Path) -> str:
    """The benchmark's name of a log: the file name without ``-corrected.log.gz`` (or ``.log.gz``, ``.log``...)."""
    name = Path(path).name
    for suffix in ("-corrected.log.gz", "-corrected.log", ".log.gz", ".clf.gz", ".log", ".clf", ".gz"):
        if name.endswith(suffix) and len(name) > len(suffix):
            return name[: -len(suffix)]
    return name
