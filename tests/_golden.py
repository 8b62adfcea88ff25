"""Golden comparisons that tolerate the last bits a numpy / numba / BLAS build may change.

Golden files were written by one build of the numeric libraries. Another build
(a newer numpy, another numba, another CPU's vector width) may round sums in
another order: values then differ by a few ulps (seen: up to 3e-15 relative).
These helpers compare structure, strings, integers and booleans exactly and
floats within :data:`RTOL` relative (or :data:`ATOL` absolute) error; text is
compared token by token, a printed number within one unit of its last printed
digit (a value at a rounding edge may print either way).
"""

from __future__ import annotations

import math
import re
from typing import Any

#: Relative tolerance on floats: far above a few ulps, far below any change of method.
RTOL = 1e-9
#: Absolute tolerance on floats near zero.
ATOL = 1e-12

_NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")


def _close(a: float, b: float, rtol: float, atol: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    if math.isinf(a) or math.isinf(b):
        return a == b
    return abs(a - b) <= atol + rtol * max(abs(a), abs(b))


def assert_close(actual: Any, expected: Any, *, rtol: float = RTOL, atol: float = ATOL, where: str = "$") -> None:
    """Nested lists / dicts equal, floats within ``rtol`` / ``atol``; ``where`` names the first difference."""
    if isinstance(expected, dict):
        assert isinstance(actual, dict), f"{where}: expected an object, got {type(actual).__name__}"
        assert list(actual) == list(expected), f"{where}: keys {list(actual)} != {list(expected)}"
        for k in expected:
            assert_close(actual[k], expected[k], rtol=rtol, atol=atol, where=f"{where}.{k}")
    elif isinstance(expected, (list, tuple)):
        assert isinstance(actual, (list, tuple)), f"{where}: expected a list, got {type(actual).__name__}"
        assert len(actual) == len(expected), f"{where}: length {len(actual)} != {len(expected)}"
        for i, (a, e) in enumerate(zip(actual, expected, strict=True)):
            assert_close(a, e, rtol=rtol, atol=atol, where=f"{where}[{i}]")
    elif isinstance(expected, bool) or expected is None or isinstance(expected, str):
        assert actual == expected, f"{where}: {actual!r} != {expected!r}"
    elif isinstance(expected, int) and isinstance(actual, int) and not isinstance(actual, bool):
        assert actual == expected, f"{where}: {actual!r} != {expected!r}"
    elif isinstance(expected, (int, float)):
        assert isinstance(actual, (int, float)) and not isinstance(actual, bool), f"{where}: {actual!r} is not a number"
        assert _close(float(actual), float(expected), rtol, atol), f"{where}: {actual!r} != {expected!r}"
    else:
        assert actual == expected, f"{where}: {actual!r} != {expected!r}"


def _printed_unit(token: str) -> float:
    """One unit of the last digit a number was printed with (``0.123`` -> 0.001, ``12`` -> 1)."""
    mant, _, exp = token.lower().partition("e")
    dec = len(mant.split(".", 1)[1]) if "." in mant else 0
    return 10.0 ** (-dec + (int(exp) if exp else 0))


def assert_text_close(actual: str, expected: str, *, rtol: float = RTOL) -> None:
    """Printed text equal but for numbers, each within one unit of its last printed digit (or ``rtol``)."""
    a_lines, e_lines = actual.splitlines(), expected.splitlines()
    assert len(a_lines) == len(e_lines), f"{len(a_lines)} lines != {len(e_lines)}"
    for n, (a, e) in enumerate(zip(a_lines, e_lines, strict=True), start=1):
        assert _NUMBER.split(a) == _NUMBER.split(e), f"line {n}: {a!r} != {e!r}"
        for ta, te in zip(_NUMBER.findall(a), _NUMBER.findall(e), strict=True):
            if ta == te:
                continue
            unit = max(_printed_unit(ta), _printed_unit(te))
            assert _close(float(ta), float(te), rtol, unit * 1.000001), f"line {n}: {ta} != {te} in {a!r}"
