"""Checks shared by the map layer's filters (private)."""

from __future__ import annotations

import math
from typing import Any

from ..errors import InvalidParameterError

__all__ = ["finite"]


def finite(name: str, value: Any, *, low: float = 0.0) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"{name} must be a finite number >= {low:g}, got {value!r}") from None
    if not (math.isfinite(v) and v >= low):
        raise InvalidParameterError(f"{name} must be a finite number >= {low:g}, got {value!r}")
    return v
