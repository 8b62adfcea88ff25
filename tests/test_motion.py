"""Simulated wheel odometry: a whole run at once or one increment at a time, the same numbers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc.errors import InvalidParameterError
from fingerloc.map.motion import OdometrySimulator, odometry_increments, wheel_odometry


@settings(max_examples=30, deadline=None)
@given(st.integers(2, 60), st.integers(0, 2**31 - 1), st.sampled_from([0.0, 0.5, 1.0, 4.0]))
def test_one_increment_at_a_time_is_the_whole_run(n, seed, factor):
    poses = np.cumsum(np.random.default_rng(seed).normal(0, 0.5, (n, 3)), axis=0)
    whole = wheel_odometry(poses, factor, random_state=seed % 1000)
    sim = OdometrySimulator(factor, seed % 1000)
    steps = np.array([sim.corrupt(odometry_increments(poses[t - 1 : t + 1])[0]) for t in range(1, n)])
    np.testing.assert_array_equal(steps.reshape(-1, 3), whole)
    sim.reset()
    again = np.array([sim.corrupt(i) for i in odometry_increments(poses)])
    np.testing.assert_array_equal(again.reshape(-1, 3), whole)


def test_the_errors_are_drawn_and_checked():
    poses = np.column_stack([np.arange(50) * 0.5, np.zeros(50), np.zeros(50)])
    noisy = wheel_odometry(poses, 1.0, random_state=0)
    exact = odometry_increments(poses)
    assert not np.array_equal(noisy, exact)
    assert np.all(np.abs(noisy[:, 0] / exact[:, 0] - 1.02) < 0.25)  # 2 % scale, 5 % random per step
    with pytest.raises(InvalidParameterError):
        OdometrySimulator(-1.0)
