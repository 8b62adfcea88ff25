"""fingerloc: topological global localization with fingerprints and Bayesian programming.

The front door::

    import fingerloc as fl
    run = fl.read_run("robot-run.log.gz")        # a CARMEN log, a ROS bag or JSON Lines -> Run
    pm = fl.make_map(run)                        # PlaceMap: model, places, graph, calibration, scan map
    pm.save("places.sqlite"); pm = fl.load_map("places.sqlite")
    pm.localize(run).summary                     # = `fingerloc localize --json`'s summary
    result = pm.track(run, filter="pose")        # TrackResult; result.summary = `fingerloc track --json`'s
    tracker = pm.tracker()                       # live: tracker.step(scan, odometry=pose, stamp=t) -> Answer

Settings are a :class:`Config` (``fl.make_map(run, fl.Config().with_(places={"spacing_m": 3.0}))``).
Implements Tapus, Heinzer and Siegwart, "Bayesian Programming for Topological
Global Localization with Fingerprints", ICRA 2004 (see docs/METHOD.md).
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

from ._version import __version__

# The public names below are imported on first use (PEP 562), so that
# ``import fingerloc`` (and ``fingerloc --version``) does not load numpy.
_LAZY = {
    "read_run": ".pipeline.readers",
    "read_runs": ".pipeline.readers",
    "Run": ".pipeline.readers",
    "make_map": ".pipeline.mapping",
    "load_map": ".pipeline.placemap",
    "PlaceMap": ".pipeline.placemap",
    "TrackResult": ".pipeline.placemap",
    "LocalizeResult": ".pipeline.placemap",
    "Tracker": ".pipeline.tracker",
    "Answer": ".pipeline.tracker",
    "Config": ".config",
    "Calibration": ".pipeline.calibration",
    "PlaceModel": ".model",
    "Scan": ".sensors",
    "dist_as": ".angles",
    "wrap": ".angles",
    "DatabaseError": ".errors",
    "DataFormatError": ".errors",
    "EmptyInputError": ".errors",
    "FingerlocError": ".errors",
    "InvalidParameterError": ".errors",
    "NotFittedError": ".errors",
    "UnknownLetterError": ".errors",
    "Fingerprint": ".fingerprint",
    "make_fingerprint": ".fingerprint",
    "parse_fingerprint": ".fingerprint",
    "FEATURE_TYPES": ".observation",
    "Observation": ".observation",
}

if TYPE_CHECKING:
    from .angles import dist_as, wrap
    from .config import Config
    from .errors import (
        DatabaseError,
        DataFormatError,
        EmptyInputError,
        FingerlocError,
        InvalidParameterError,
        NotFittedError,
        UnknownLetterError,
    )
    from .fingerprint import Fingerprint, make_fingerprint, parse_fingerprint
    from .model import PlaceModel
    from .observation import FEATURE_TYPES, Observation
    from .pipeline.calibration import Calibration
    from .pipeline.mapping import make_map
    from .pipeline.placemap import LocalizeResult, PlaceMap, TrackResult, load_map
    from .pipeline.readers import Run, read_run, read_runs
    from .pipeline.tracker import Answer, Tracker
    from .sensors import Scan


def __getattr__(name: str) -> Any:
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'fingerloc' has no attribute {name!r}")
    value = getattr(import_module(mod, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "FEATURE_TYPES",
    "Answer",
    "Calibration",
    "Config",
    "DataFormatError",
    "DatabaseError",
    "EmptyInputError",
    "FingerlocError",
    "Fingerprint",
    "InvalidParameterError",
    "LocalizeResult",
    "NotFittedError",
    "Observation",
    "PlaceMap",
    "PlaceModel",
    "Run",
    "Scan",
    "TrackResult",
    "Tracker",
    "UnknownLetterError",
    "__version__",
    "dist_as",
    "load_map",
    "make_fingerprint",
    "make_map",
    "parse_fingerprint",
    "read_run",
    "read_runs",
    "wrap",
]
