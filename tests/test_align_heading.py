"""The compiled heading of a cyclic alignment (fingerloc.align.cyclic_heading) against cyclic_alignment."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc.align import CostModel, cyclic_alignment, cyclic_heading
from fingerloc.align._heading_kernel import numpy_sum
from fingerloc.fingerprint import Fingerprint

COSTS = [CostModel(), CostModel.feature_aware()]


@pytest.mark.parametrize("n", [*range(0, 40), 127, 128, 129, 130, 255, 256, 257, 263, 511, 777, 1500])
def test_numpy_sum_is_numpy_s_own_sum_bit_for_bit(n):
    rng = np.random.default_rng(n)
    for scale in (1.0, 1e8):
        x = rng.standard_normal(n) * scale + rng.standard_normal(n) * 1e-9
        assert numpy_sum(x, n) == float(x.sum())  # exactly: the same additions in the same order


def _fp(letters: str, rng: np.random.Generator) -> Fingerprint:
    return Fingerprint(letters, np.sort(rng.uniform(-np.pi, np.pi, len(letters))))


@settings(max_examples=150, deadline=None)
@given(
    a=st.text(alphabet="cbfnvAei", min_size=0, max_size=14),
    b=st.text(alphabet="cbfnvAei", min_size=1, max_size=14),
    seed=st.integers(0, 2**32 - 1),
    feature=st.booleans(),
)
def test_cost_and_heading_are_those_of_cyclic_alignment(a, b, seed, feature):
    rng = np.random.default_rng(seed)
    fa, fb = _fp(a, rng), _fp(b, rng)
    costs = COSTS[int(feature)]
    want = cyclic_alignment(fa, fb, costs=costs)
    cost, heading = cyclic_heading(fa, fb, costs=costs)
    assert cost == want.cost
    if want.heading_deg is None:
        assert heading is None
    else:
        assert heading is not None
        gap = abs((heading - want.heading_deg + 180.0) % 360.0 - 180.0)
        assert gap <= 1e-9


def test_periodic_strings_pick_the_rotation_whose_pairs_agree():
    """'cncncn' ties over three rotations; the bearings decide, as in cyclic_alignment."""
    rng = np.random.default_rng(3)
    a = Fingerprint("cncncn", np.radians([0.0, 60.0, 120.0, 180.0, 240.0, 300.0]))
    b = Fingerprint("cncncn", np.radians(np.array([0.0, 60.0, 120.0, 180.0, 240.0, 300.0]) + 37.0))
    want = cyclic_alignment(a, b)
    cost, heading = cyclic_heading(a, b)
    assert cost == want.cost == 0.0
    assert heading == pytest.approx(want.heading_deg, abs=1e-9)
    assert heading == pytest.approx(360.0 - 37.0, abs=1e-9)
    # a plain string or an empty reference: the general path
    assert cyclic_heading(_fp("cb", rng), Fingerprint("", np.zeros(0)))[1] is None
