"""Smoke test of the ``align`` section of ``fingerloc bench speed`` (tiny sizes)."""

from __future__ import annotations

import numpy as np

from fingerloc.experiments.speed_align import align_figures, random_fingerprints


def test_align_figures_small():
    figs = align_figures(n_queries=2, n_references=40, n_baseline=20, repeat=1)
    assert figs["cyclic_equals_brute"] is True
    for key in (
        "unit_plain_ratio_to_rapidfuzz",
        "weighted_plain_cells_per_s",
        "cyclic_unit_ms_per_query",
        "cyclic_speedup_over_brute",
        "cyclic_weighted_ms_per_query",
        "minimum_energy_ms_per_query",
    ):
        assert figs[key] > 0


def test_random_fingerprints_are_seeded():
    a = random_fingerprints(3, 40, np.random.default_rng(1))
    b = random_fingerprints(3, 40, np.random.default_rng(1))
    assert a == b and all(len(s) == 40 for s in a)
