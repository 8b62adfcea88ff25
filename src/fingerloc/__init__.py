"""fingerloc: topological global localization with fingerprints and Bayesian programming.

Implements Tapus, Heinzer and Siegwart, "Bayesian Programming for Topological
Global Localization with Fingerprints", ICRA 2004 (see SPEC.md).
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("fingerloc")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

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
