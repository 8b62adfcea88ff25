"""A pose filter that does not stay locked on a wrong pose (issue 15): a denser proposal at a (re)initialisation
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
from fingerloc.map.scan_map import ScanMap
from fingerloc.pipeline.calibrate import calibrate_lost
from fingerloc.pipeline.calibration import Calibration
from tests._paths import polyline, truth_places


def _wall(x0, x1, y, doors):
    xs = np.arange(x0, x1, 0.05)
    keep = np.all(np.abs(xs[:, None] - np.array(doors)[None, :]) > 0.5, axis=1)
    return np.column_stack([xs[keep], np.full(keep.sum(), y)])


def _world():
    """Two closed 20 m corridors 10 m apart (A at y = 0, B at y = 10), alike but for one wall (20 cm off, other doors)."""
    a = [_wall(0, 20, 1.5, (3, 9, 15)), _wall(0, 20, -1.5, (5, 12, 18))]
    b = [_wall(0, 20, 11.5, (3, 9, 15)), _wall(0, 20, 8.3, (8, 15))]
    ends = [np.column_stack([np.full(60, x), y0 + np.linspace(-1.5, 1.5, 60)]) for x in (0, 20) for y0 in (0, 10)]
    return np.vstack(a + b + ends)


def _scan_at(world, pose, rng):
    """End points a 360-degree scanner at ``pose`` sees within 8 m (no occlusion), 2 cm of noise, robot frame."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    rel = world - pose[:2]
    rob = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]])
    seen = rob[np.hypot(rob[:, 0], rob[:, 1]) < 8.0][::4]
    return seen + 0.02 * rng.standard_normal(seen.shape)


_TWIN = np.array([0.0, 10.0, 0.0])  # from corridor A to its twin B
_WORLD = _world()
_MAP = ScanMap.from_points(_WORLD, resolution=0.1)
_POSES = polyline([(1.0, 0.0), (19.0, 0.0)], 0.25)  # the robot drives along corridor A
_CA = np.column_stack([np.arange(1.0, 20.0, 2.0), np.zeros(10)])
_CENTRES = np.vstack([_CA, _CA + _TWIN[:2]])  # places 0-9 in A, their twins 10-19 in B
_TRUTH = truth_places(_POSES, _CENTRES)


def _inputs(seed):
    """Scans along A; fingerprint rows that confuse neighbours and the twin corridor, B slightly favoured."""
    rng = np.random.default_rng(seed)
    pts = [_scan_at(_WORLD, p, rng) for p in _POSES]
    k = np.arange(20) % 10
    ll = -0.4 * np.abs(k[None, :] - (_TRUTH % 10)[:, None]) + 0.3 * rng.standard_normal((_TRUTH.size, 20))
    ll[:, 10:] += 0.2
    return ll, pts


def _filter(seed, start, **kw):
    both = np.vstack([_POSES, _POSES + _TWIN])
    return PoseFilter(_CENTRES, 1.0, n_particles=300, scan_map=_MAP, scan_gamma=10.0, kidnap=0.001, start=start,
                      place_poses=both, random_state=seed, **kw)  # fmt: skip


def _run(seed, start, **kw):
    ll, pts = _inputs(seed)
    f = _filter(seed, start, **kw)
    inc = wheel_odometry(_POSES, 1.0, random_state=seed + 1)
    res = run_pose_filter(ll, inc, f, temper=(1.0, math.pi), points=pts)
    return res, f


def _calibrated(seed):
    """The lost rule's constants from a run that starts at the true poses (the mapping pass's role)."""
    res, f = _run(seed + 50, _POSES[:1])
    thr, kap = calibrate_lost(f.fit_trace_, res.best == _TRUTH)
    assert thr is not None and 0 < kap < 1
    return thr, kap


@pytest.mark.parametrize("seed", [3, 4])
def test_a_belief_locked_in_the_twin_corridor_is_let_go_by_the_scan_fit(seed):
    wrong = _POSES[:1] + _TWIN  # the belief starts in B, the corridor the fingerprint slightly prefers
    late = np.arange(_TRUTH.size) >= _TRUTH.size // 2
    res, f = _run(seed, wrong)
    assert np.mean(res.best[late] == _TRUTH[late]) < 0.2  # without the rule the filter stays in B
    thr, kap = _calibrated(seed)
    res, f = _run(seed, wrong, lost_fit=thr, lost_kidnap=kap, fresh_factor=10)
    assert f.lost_steps_ and f.lost_steps_[0] < 10  # the bad fit is seen at once
    assert np.mean(res.best[late] == _TRUTH[late]) > 0.8  # and the robot is found in A


def test_a_denser_proposal_finds_the_true_pose_at_the_first_observation():
    """Global localization from one view: 30 particles drawn at the places the fingerprint names (it confuses the
    twin corridors and neighbours) rarely hold one near the true pose; 30 times as many usually do."""
    ll, pts = _inputs(0)
    both = np.vstack([_POSES, _POSES + _TWIN])
    right = {1: 0, 30: 0}
    for seed in range(20):
        i = 4 + 3 * seed
        for k in right:
            f = PoseFilter(_CENTRES, 1.0, n_particles=30, scan_map=_MAP, scan_gamma=10.0, fresh_factor=k,
                           place_poses=both, random_state=seed)  # fmt: skip
            post = f.update(ll[i], kidnap=1.0, points=pts[i])
            right[k] += int(np.argmax(post) == _TRUTH[i])
    assert right[1] <= 6 and right[30] >= 13


def test_off_is_bit_identical():
    ll, pts = _inputs(3)
    inc = wheel_odometry(_POSES, 1.0, random_state=4)
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
        f = PoseFilter(_CENTRES, 1.0, n_particles=200, fresh_factor=k, random_state=2)
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
            PoseFilter(_CENTRES, 1.0, **kw)
    cal = Calibration(lost_fit=-0.7, lost_kidnap=0.2)
    assert Calibration.from_json(cal.to_json()) == cal
