"""The map: the place database (SQLite), the place graph, the Markov filter over it, the pose filter and its driver.

The names below are imported on first use (PEP 562), so that reading a place
database does not import the filters (scipy.optimize, scipy.spatial).
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

_LAZY = {
    "SCHEMA_VERSION": ".database",
    "load_model": ".database",
    "save_model": ".database",
    "MarkovFilter": ".filter",
    "TransitionModel": ".filter",
    "run_filter": ".filter",
    "PlaceGraph": ".graph",
    "load_graph": ".graph",
    "PoseFilter": ".pose_filter",
    "PoseTracking": ".driver",
    "run_pose_filter": ".driver",
    "ScanMap": ".scan_map",
    "scan_points": ".scan_map",
}

__all__ = [
    "SCHEMA_VERSION",
    "MarkovFilter",
    "PlaceGraph",
    "PoseFilter",
    "PoseTracking",
    "ScanMap",
    "TransitionModel",
    "load_graph",
    "load_model",
    "run_filter",
    "run_pose_filter",
    "save_model",
    "scan_points",
]

if TYPE_CHECKING:
    from .database import SCHEMA_VERSION, load_model, save_model
    from .driver import PoseTracking, run_pose_filter
    from .filter import MarkovFilter, TransitionModel, run_filter
    from .graph import PlaceGraph, load_graph
    from .pose_filter import PoseFilter
    from .scan_map import ScanMap, scan_points


def __getattr__(name: str) -> Any:
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'fingerloc.map' has no attribute {name!r}")
    value = getattr(import_module(mod, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
