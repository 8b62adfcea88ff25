"""Shared test configuration: hypothesis profiles, and the numba kernels compiled before the first test.

``HYPOTHESIS_PROFILE=long`` runs the property and fuzz tests with many more
examples (minutes; see docs/ROBUSTNESS.md); the default ``ci`` profile keeps
the whole fuzz battery under a minute.

numba compiles a kernel on its first call and keeps it on disk (``cache=True``);
on a fresh clone that first call takes seconds. The test run compiles the
alignment and mixture kernels once before the first test, so that a test's time
is its own work; ``FINGERLOC_TEST_NO_WARMUP=1`` skips that.
"""

from __future__ import annotations

import os
import time

import pytest
from hypothesis import HealthCheck, settings

from ._logs import rooms_path, write_log

settings.register_profile("ci", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile(
    "long", max_examples=2000, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large]
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def pytest_sessionstart(session):
    if os.environ.get("FINGERLOC_TEST_NO_WARMUP"):
        return
    import numpy as np

    from fingerloc.align import CostModel, alignment_costs, minimum_energy_costs
    from fingerloc.align._cyclic import cyclic_batch_brute
    from fingerloc.align._encode import encode_many
    from fingerloc.mog import fit_mixtures
    from fingerloc.observation import Observation
    from fingerloc.terms.fingerprint import FingerprintTerm

    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    refs = ["".join(rng.choice(list("vcbfnABCh"), int(n))) for n in rng.integers(5, 30, 80)]
    feature = CostModel.feature_aware()
    for costs in (None, feature):
        alignment_costs(refs[:2], refs, cyclic=True, costs=costs)
        alignment_costs(refs[:2], refs, costs=costs)
    minimum_energy_costs(refs[:2], refs[:20])
    (qc, qo), (rc, ro) = encode_many(refs[:2]), encode_many(refs[:8])
    cyclic_batch_brute(qc, qo, rc, ro, feature.substitution, feature.indel)  # the tests' oracle
    for n in (4, 40):  # the serial and the parallel fit
        fit_mixtures([rng.uniform(-3, 3, 40) for _ in range(n)], 3, random_state=1)

    def obs(label: str) -> Observation:
        return Observation(ve=rng.uniform(0, 2 * np.pi, 4), c=rng.uniform(0, 2 * np.pi, 2),
                           b=rng.uniform(0, 2 * np.pi, 1), label=label)  # fmt: skip

    groups = [[obs(f"p{j}"), obs(f"p{j}")] for j in range(5)]
    term = FingerprintTerm(cyclic=True, costs=feature).fit(groups)
    term.update([*groups, [obs("p5")]], [5])
    term.distances([obs("q")])
    _warm_up_the_index(rng)
    session.config._fingerloc_warmup_s = time.perf_counter() - t0


def _warm_up_the_index(rng):
    """The exact index's kernels (every bound level, the exact scores, the posterior's passes) on a small laser map."""
    from fingerloc.pipeline.presets import resolve_preset
    from fingerloc.retrieval import PlaceIndex
    from fingerloc.sim.campus import campus_observations

    train, queries = campus_observations(12, n_queries=1, seed=1)
    model = resolve_preset("laser2d").model().fit(train)
    PlaceIndex(model).search(queries[:2], k=3, tol=1e-3, truth=[queries[0].label, None])


def pytest_report_header(config):
    took = getattr(config, "_fingerloc_warmup_s", None)
    return None if took is None else f"fingerloc: numba kernels compiled or loaded in {took:.1f} s"


def fuzz_examples(n: int) -> int:
    """``n`` examples in CI, 20 times as many under ``HYPOTHESIS_PROFILE=long``."""
    return n * 20 if os.environ.get("HYPOTHESIS_PROFILE") == "long" else n


@pytest.fixture(scope="module")
def rooms_log(tmp_path_factory):
    """A synthetic CARMEN log: two loops through three rooms (mapping, then query)."""
    return write_log(tmp_path_factory.mktemp("rooms") / "rooms-corrected.log", rooms_path())
