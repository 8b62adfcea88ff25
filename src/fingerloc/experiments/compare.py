"""Two benchmark JSON files side by side (``fingerloc bench compare``): which figures differ.

Any two ``--json`` outputs of the same benchmark (``bench carmen``, ``bench
speed``, ``bench kidnap``, ``reproduce ...``) are walked together. Accuracy
figures (everything but timings) must be equal; timings (keys ending in
``_s``, ``_ms``, ``_us``, ``ms_per_query``, ``learn_s`` ...) differ from run to
run (as do speed-ups, memory and the load average) and are listed apart,
with their ratio, only when asked for.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

__all__ = ["Difference", "compare_json", "is_timing"]

#: Words of a key that name a measurement of time or resources (``ms_per_query``, ``speedup_vs_sklearn``,
#: ``peak_rss_mb``, ``load_average_1min``, ``cyclic_weighted_over_unit``): these vary between runs.
_TIMING_WORDS = frozenset(
    {"s", "ms", "us", "ns", "seconds", "cpu", "wall", "speedup", "ratio", "over", "load", "rss", "mb", "kb", "bytes",
     "second", "hz"}
)  # fmt: skip


def is_timing(key: str) -> bool:
    """Whether a JSON key names a timing or a resource measurement (seconds, rates, speed-ups, memory, load)."""
    return bool(set(re.split(r"[_\-.]", key.lower())) & _TIMING_WORDS)


@dataclass(frozen=True, slots=True)
class Difference:
    """One figure that differs between two runs.

    Attributes
    ----------
    path : str
        Where in the JSON (``logs.intel.methods.fingerprint.top1``).
    first, second : Any
        The two values (``None`` when the figure is only in one file).
    timing : bool
        A timing (see :func:`is_timing`).
    """

    path: str
    first: Any
    second: Any
    timing: bool = False

    @property
    def ratio(self) -> float | None:
        """``second / first`` for two positive numbers, else None."""
        a, b = self.first, self.second
        if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool) and a > 0:
            return float(b) / float(a)
        return None


def _equal(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


def compare_json(first: Any, second: Any, *, timings: bool = False, path: str = "") -> list[Difference]:
    """The figures that differ between two JSON documents (timings only with ``timings``), in document order."""
    out: list[Difference] = []
    if isinstance(first, dict) and isinstance(second, dict):
        for k in list(first) + [k for k in second if k not in first]:
            p = f"{path}.{k}" if path else str(k)
            timing = is_timing(str(k))
            if timing and not timings:
                continue
            if k not in first or k not in second:
                out.append(Difference(p, first.get(k), second.get(k), timing))
            elif timing and not isinstance(first[k], (dict, list)):
                if not _equal(first[k], second[k]):
                    out.append(Difference(p, first[k], second[k], True))
            else:
                out += compare_json(first[k], second[k], timings=timings, path=p)
    elif isinstance(first, list) and isinstance(second, list) and len(first) == len(second):
        for i, (a, b) in enumerate(zip(first, second, strict=True)):
            out += compare_json(a, b, timings=timings, path=f"{path}[{i}]")
    elif not _equal(first, second):
        out.append(Difference(path, first, second))
    return out
