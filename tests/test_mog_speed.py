"""The ``mog`` section of ``fingerloc bench speed`` (slow: it times scikit-learn too)."""

from __future__ import annotations

import numpy as np
import pytest

from fingerloc.experiments.speed_mog import make_samples, speed_mog


def test_make_samples():
    s = make_samples(3, 50, 4, seed=1)
    assert len(s) == 3 and all(x.shape == (50,) for x in s)
    assert all(np.all((x >= -np.pi) & (x < np.pi)) for x in s)


@pytest.mark.slow
def test_speed_section_quick():
    figs = speed_mog(True)
    assert figs["mixtures"] == 100 and figs["k"] == 5
    pytest.importorskip("sklearn")
    # scikit-learn is in the test extra: the comparison must be there, and we must win it
    assert figs["speedup_vs_sklearn"] > 1.0
    assert figs["speedup_single_fit_call_vs_sklearn"] > 1.0
