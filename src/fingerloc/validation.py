"""One home for checking user-facing parameters.

Every check raises :class:`~fingerloc.errors.InvalidParameterError` with a
one-line message that names the parameter as the caller wrote it, the
constraint and the bad value (scikit-learn's style). Library functions pass
their own parameter name; the command line passes its flag (``--seed``).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Collection
from typing import Any

import numpy as np

from .errors import InvalidParameterError

__all__ = ["check_bool", "check_choice", "check_int", "check_number", "check_random_state"]


def check_int(name: str, value: object, *, minimum: int | None = None, maximum: int | None = None) -> int:
    """``value`` as an int (bools refused), within ``[minimum, maximum]`` where given."""
    if not isinstance(value, numbers.Integral) or isinstance(value, bool):
        raise InvalidParameterError(f"{name} must be an integer, got {value!r}")
    v = int(value)
    if (minimum is not None and v < minimum) or (maximum is not None and v > maximum):
        raise InvalidParameterError(f"{name} must be an integer in {_interval(minimum, maximum, True, True)}, got {v}")
    return v


def check_number(
    name: str,
    value: object,
    *,
    minimum: float | None = None,
    maximum: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    finite: bool = True,
) -> float:
    """``value`` as a float (bools and strings refused), finite unless ``finite=False``, within the interval."""
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        raise InvalidParameterError(f"{name} must be a number, got {value!r}")
    v = float(value)
    bad = math.isnan(v) or (finite and not math.isfinite(v))
    if minimum is not None:
        bad = bad or (v <= minimum if low_open else v < minimum)
    if maximum is not None:
        bad = bad or (v >= maximum if high_open else v > maximum)
    if bad:
        what = "a finite number" if finite else "a number"
        interval = _interval(minimum, maximum, not low_open, not high_open)
        raise InvalidParameterError(f"{name} must be {what}" + (f" in {interval}" if interval else "") + f", got {value!r}")
    return v


def check_bool(name: str, value: object) -> bool:
    """``value`` if it is a bool (numpy's too)."""
    if not isinstance(value, bool | np.bool_):
        raise InvalidParameterError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def check_choice(name: str, value: object, choices: Collection[Any]) -> Any:
    """``value`` if it is one of ``choices``."""
    try:
        ok = value in choices
    except TypeError:  # unhashable value against a set
        ok = False
    if not ok:
        listed = ", ".join(repr(c) for c in choices)
        raise InvalidParameterError(f"{name} must be one of {listed}, got {value!r}")
    return value


def check_random_state(random_state: object, name: str = "random_state") -> np.random.Generator:
    """A :class:`numpy.random.Generator` from ``None`` (fresh entropy), a non-negative int, or a Generator.

    A Generator is returned as is (so successive calls draw from one stream);
    global seeding is never used.
    """
    if random_state is None:
        return np.random.default_rng()
    if isinstance(random_state, np.random.Generator):
        return random_state
    if isinstance(random_state, numbers.Integral) and not isinstance(random_state, bool):
        if int(random_state) < 0:
            raise InvalidParameterError(f"{name} must be a non-negative integer or a numpy Generator, got {random_state}")
        return np.random.default_rng(int(random_state))
    raise InvalidParameterError(
        f"{name} must be None, a non-negative integer or a numpy.random.Generator, got {random_state!r}"
    )


def _interval(lo: float | None, hi: float | None, lo_closed: bool, hi_closed: bool) -> str:
    if lo is None and hi is None:
        return ""
    left = ("[" if lo_closed else "(") + ("-inf" if lo is None else f"{lo:g}")
    right = ("inf" if hi is None else f"{hi:g}") + ("]" if hi_closed else ")")
    return f"{left}, {right}"
