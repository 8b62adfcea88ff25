"""A pose filter that does not stay locked on a wrong pose: a denser proposal at a (re)initialisation
from the sensor (``fresh_factor``) and lost detection by the scan fit (``lost_fit``, ``lost_kidnap``,
:func:`fingerloc.pipeline.calibrate.calibrate_lost`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fingerloc.errors import FingerlocError
from fingerloc.map.driver import run_pose_filter
from fingerloc.map.motion import wheel_odometry
from fingerloc.map.pose_filter import PoseFilter
from fingerloc.pipeline.calibrate import calibrate_lost
from fingerloc.pipeline.calibration import Calibration
from tests._corridor import CENTRES, MAP, POSES, TRUTH, TWIN, inputs


def _filter(seed, start, **kw):
    both = np.vstack([POSES, POSES + TWIN])
    return PoseFilter(CENTRES, 1.0, n_particles=300, scan_map=MAP, scan_gamma=10.0, kidnap=0.001, start=start,
                      place_poses=both, random_state=seed, **kw)  # fmt: skip


def _run(seed, start, **kw):
    ll, pts = inputs(seed)
    f = _filter(seed, start, **kw)
    inc = wheel_odometry(POSES, 1.0, random_state=seed + 1)
    res = run_pose_filter(ll, inc, f, temper=(1.0, math.pi), points=pts)
    return res, f


def _calibrated(seed):
    """The lost rule's constants from a run that starts at the true poses (the mapping pass's role)."""
    res, f = _run(seed + 50, POSES[:1])
    thr, kap = calibrate_lost(f.fit_trace_, res.best == TRUTH)
    assert thr is not None and 0 < kap < 1
    return thr, kap


@pytest.mark.parametrize("seed", [3, 4])
def test_a_belief_locked_in_the_twin_corridor_is_let_go_by_the_scan_fit(seed):
    wrong = POSES[:1] + TWIN  # the belief starts in B, the corridor the fingerprint slightly prefers
    late = np.arange(TRUTH.size) >= TRUTH.size // 2
    res, f = _run(seed, wrong)
    assert np.mean(res.best[late] == TRUTH[late]) < 0.2  # without the rule the filter stays in B
    thr, kap = _calibrated(seed)
    res, f = _run(seed, wrong, lost_fit=thr, lost_kidnap=kap, fresh_factor=10)
    assert f.lost_steps_ and f.lost_steps_[0] < 10  # the bad fit is seen at once
    assert np.mean(res.best[late] == TRUTH[late]) > 0.8  # and the robot is found in A


def test_a_denser_proposal_finds_the_true_pose_at_the_first_observation():
    """Global localization from one view: 30 particles drawn at the places the fingerprint names (it confuses the
    twin corridors and neighbours) rarely hold one near the true pose; 30 times as many usually do."""
    ll, pts = inputs(0)
    both = np.vstack([POSES, POSES + TWIN])
    right = {1: 0, 30: 0}
    for seed in range(20):
        i = 4 + 3 * seed
        for k in right:
            f = PoseFilter(CENTRES, 1.0, n_particles=30, scan_map=MAP, scan_gamma=10.0, fresh_factor=k,
                           place_poses=both, random_state=seed)  # fmt: skip
            post = f.update(ll[i], kidnap=1.0, points=pts[i])
            right[k] += int(np.argmax(post) == TRUTH[i])
    assert right[1] <= 6 and right[30] >= 13


def test_off_is_bit_identical():
    ll, pts = inputs(3)
    inc = wheel_odometry(POSES, 1.0, random_state=4)
    runs = []
    for kw in ({}, {"lost_fit": None, "fresh_factor": 1}, {"lost_fit": 0.5, "lost_kidnap": 0.0},
               {"lost_fit": -np.inf, "lost_kidnap": 0.5}):  # fmt: skip
        f = _filter(5, None, **kw)
        res = run_pose_filter(ll[:30], inc[:29], f, temper=(1.0, math.pi), points=pts[:30],
                              start_at_first_observation=True)  # fmt: skip
        runs.append((res.log_posterior, f.particles_.copy()))
    for lp, parts in runs[1:]:
        assert np.array_equal(lp, runs[0][0]) and np.array_equal(parts, runs[0][1])
    # without scan evidence the proposal's size does not change either
    outs = []
    for k in (1, 10):
        f = PoseFilter(CENTRES, 1.0, n_particles=200, fresh_factor=k, random_state=2)
        outs.append(np.array([f.update(r, kidnap=1.0 if t == 0 else None) for t, r in enumerate(ll[:5])]))
    assert np.array_equal(outs[0], outs[1])


def test_calibrate_lost_and_bad_input():
    thr, kap = calibrate_lost([np.nan, -0.1, -0.2, -0.3, -2.0, -1.5], [True, True, True, True, False, True], 0.25)
    assert thr == pytest.approx(np.quantile([-0.1, -0.2, -0.3, -1.5], 0.25))
    assert kap == pytest.approx((1 + 1) / (2 + 2))  # below: -2.0 (wrong), -1.5 (right)
    assert calibrate_lost([np.nan, -1.0], [True, False]) == (None, 0.0)
    with pytest.raises(FingerlocError):
        calibrate_lost([0.0], [True, False])
    for kw in ({"fresh_factor": 0}, {"fresh_factor": 1.5}, {"lost_kidnap": 2.0}, {"lost_fit": math.nan}):
        with pytest.raises(FingerlocError):
            PoseFilter(CENTRES, 1.0, **kw)
    cal = Calibration(lost_fit=-0.7, lost_kidnap=0.2)
    assert Calibration.from_json(cal.to_json()) == cal
