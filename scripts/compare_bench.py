"""Compare two ``fingerloc bench carmen --json`` files, timing fields aside (issue 17).

    python scripts/compare_bench.py before.json after.json

Prints every figure that differs (``logs.<log>.methods.<method>.<figure>``,
``pooled...``) and exits 1 if any does, 0 if the two runs agree on every
figure but ``ms_per_query`` and ``learn_s`` (which are timings).
"""

from __future__ import annotations

import json
import sys
from typing import Any

TIMING_FIELDS = ("ms_per_query", "learn_s")


def without_timings(js: Any) -> Any:
    """The JSON with every timing field removed (recursively)."""
    if isinstance(js, dict):
        return {k: without_timings(v) for k, v in js.items() if k not in TIMING_FIELDS}
    if isinstance(js, list):
        return [without_timings(v) for v in js]
    return js


def differences(a: Any, b: Any, path: str = "") -> list[str]:
    """Paths where ``a`` and ``b`` differ (timing fields ignored), with both values."""
    a, b = without_timings(a), without_timings(b)
    out: list[str] = []
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            p = f"{path}.{k}" if path else str(k)
            if k not in a or k not in b:
                out.append(f"{p}: only in {'second' if k not in a else 'first'}")
            else:
                out += differences(a[k], b[k], p)
    elif a != b and not (a != a and b != b):  # NaN == NaN here
        out.append(f"{path}: {a!r} != {b!r}")
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    with open(argv[0], encoding="utf-8") as f1, open(argv[1], encoding="utf-8") as f2:
        diff = differences(json.load(f1), json.load(f2))
    for line in diff:
        print(line)
    print("identical figures" if not diff else f"{len(diff)} figures differ")
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
