"""Smoke test of the ``align`` section of ``fingerloc bench speed`` (tiny sizes)."""

from __future__ import annotations

import numpy as np
import pytest

from fingerloc.experiments.speed_align import align_figures, random_fingerprints


def test_align_figures_small():
    figs = align_figures(n_queries=2, n_references=40, n_baseline=20, repeat=1)
    assert figs["cyclic_equals_brute"] is True
    assert (figs["queries"], figs["references"], figs["length"]) == (2, 40, 40)
    # the ratios are the ratios of the reported times
    assert figs["cyclic_weighted_over_unit"] == pytest.approx(
        figs["cyclic_weighted_ms_per_query"] / figs["cyclic_unit_ms_per_query"]
    )
    assert figs["cyclic_speedup_over_brute"] == pytest.approx(
        figs["cyclic_brute_ms_per_query"] / figs["cyclic_unit_ms_per_query"]
    )
    assert figs["weighted_plain_cells_per_s"] == pytest.approx(
        2 * 40 * 40 * 40 / (figs["weighted_plain_ms_per_query"] * 2 / 1e3)
    )


def test_random_fingerprints_are_seeded():
    a = random_fingerprints(3, 40, np.random.default_rng(1))
    b = random_fingerprints(3, 40, np.random.default_rng(1))
    assert a == b and all(len(s) == 40 for s in a)
