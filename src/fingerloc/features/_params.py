"""Checks shared by the feature extractors' parameter classes."""

from __future__ import annotations

from dataclasses import fields
from typing import Any

import numpy as np

from ..errors import InvalidParameterError

__all__ = ["_check_positive", "_from_kwargs"]


def _check_positive(obj: object, names: tuple[str, ...], *, allow_zero: bool = False) -> None:
    for name in names:
        v = getattr(obj, name)
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
        ok = ok and (v >= 0 if allow_zero else v > 0)
        if not ok:
            what = "a number >= 0" if allow_zero else "a positive number"
            raise InvalidParameterError(f"{name} must be {what}, got {v!r}")


def _from_kwargs(cls: Any, params: dict[str, Any], what: str) -> Any:
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(params) - known)
    if unknown:
        raise InvalidParameterError(f"unknown {what} parameter {unknown[0]!r} (known: {', '.join(sorted(known))})")
    return cls(**params)
