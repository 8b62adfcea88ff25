"""Shared test configuration: hypothesis profiles.

``HYPOTHESIS_PROFILE=long`` runs the property and fuzz tests with many more
examples (minutes; see docs/ROBUSTNESS.md); the default ``ci`` profile keeps
the whole fuzz battery under a minute.
"""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

from ._logs import rooms_path, write_log

settings.register_profile("ci", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile(
    "long", max_examples=2000, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large]
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def fuzz_examples(n: int) -> int:
    """``n`` examples in CI, 20 times as many under ``HYPOTHESIS_PROFILE=long``."""
    return n * 20 if os.environ.get("HYPOTHESIS_PROFILE") == "long" else n


@pytest.fixture(scope="module")
def rooms_log(tmp_path_factory):
    """A synthetic CARMEN log: two loops through three rooms (mapping, then query)."""
    return write_log(tmp_path_factory.mktemp("rooms") / "rooms-corrected.log", rooms_path())
