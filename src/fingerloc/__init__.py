"""fingerloc: topological global localization with fingerprints and Bayesian programming.

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
    from .observation import FEATURE_TYPES, Observation


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
    "DataFormatError",
    "DatabaseError",
    "EmptyInputError",
    "FingerlocError",
    "Fingerprint",
    "InvalidParameterError",
    "NotFittedError",
    "Observation",
    "UnknownLetterError",
    "__version__",
    "dist_as",
    "make_fingerprint",
    "parse_fingerprint",
    "wrap",
]
