"""The pose filter's answer between observations (held_best) and Augmented MCL with a reserve (issue 15)."""

import math

import numpy as np
import pytest

from fingerloc.errors import InvalidParameterError
from fingerloc.map.filter import FilterResult
from fingerloc.map.pose_filter import PoseFilter, odometry_increments, run_pose_filter
from fingerloc.map.relocalize import Augmented, held_best, run_augmented_pose_filter

from ._paths import polyline as _polyline
from ._paths import sensor_scores as _sensor
from ._paths import truth_places as _truth

CORRIDOR = np.column_stack([np.arange(10) * 3.0, np.zeros(10)])


def _posterior(rows):
    return FilterResult.from_log_posterior(np.log(np.asarray(rows, dtype=np.float64)))


def test_held_best_keeps_the_answer_through_a_near_tie():
    """Between observations a near-tie flips the argmax; held, the answer changes only when another leads by the margin."""
    rows = [[0.6, 0.4], [0.49, 0.51], [0.52, 0.48], [0.45, 0.55], [0.3, 0.7], [0.55, 0.45], [0.45, 0.55]]
    observed = [True, False, False, False, False, False, True]
    res = _posterior(rows)
    assert res.best.tolist() == [0, 1, 0, 1, 1, 0, 1]
    held = held_best(res, observed, 0.2)
    assert held.best.tolist() == [0, 0, 0, 0, 1, 1, 1]  # 0.7 > 0.3 + 0.2 switches; 0.55 vs 0.45 does not switch back
    assert held.best_probability[3] == pytest.approx(0.45)
    np.testing.assert_array_equal(held.log_posterior, res.log_posterior)
    assert held_best(res, observed, 0.0).best.tolist() == res.best.tolist()  # margin 0: the argmax
    assert held_best(res, observed, math.inf).best.tolist() == [0, 0, 0, 0, 0, 0, 1]  # hold until the next observation
    with pytest.raises(InvalidParameterError, match="margin"):
        held_best(res, observed, -0.1)
    with pytest.raises(InvalidParameterError, match="observed"):
        held_best(res, observed[:3], 0.1)


def test_held_best_makes_two_runs_agree_more_between_observations():
    """Two runs of one tracking pose filter (other draws, 100 particles) along a corridor: held, they disagree less between places."""
    poses = _polyline([(0, 0), (27, 0)], 0.25)
    truth = _truth(poses, CORRIDOR, radius=0.5)
    inc = odometry_increments(poses)
    obs = truth >= 0
    plain = held = 0
    for s in range(3):
        ll = _sensor(truth, 10, 3.0, s)
        runs = [
            run_pose_filter(ll, inc, PoseFilter(CORRIDOR, 0.5, n_particles=100, kidnap=0.01, outlier=0.3,
                                                start=np.array([[0.0, 0.0, 0.0]]), random_state=seed),
                            temper=(2.0, math.pi))
            for seed in (2 * s + 1, 2 * s + 2)
        ]  # fmt: skip
        plain += int(np.sum(runs[0].best[~obs] != runs[1].best[~obs]))
        h = [held_best(r, obs, 0.1) for r in runs]
        held += int(np.sum(h[0].best[~obs] != h[1].best[~obs]))
    assert plain >= 4 and held <= plain // 2


def _kidnapped_run(seed, augmented):
    """Tracked along the corridor from place 0, then carried (unobserved) to place 8 and driven back towards place 4."""
    a = _polyline([(0, 0), (9, 0)], 0.5)
    b = _polyline([(24, 0), (12, 0)], 0.5)
    inc = np.vstack([odometry_increments(a), np.zeros((1, 3)), odometry_increments(b)])
    truth = np.r_[_truth(a, CORRIDOR), _truth(b, CORRIDOR)]
    ll = _sensor(truth, 10, 3.0, seed)
    f = PoseFilter(CORRIDOR, 1.0, n_particles=1000, kidnap=0.002, start=np.array([[0.0, 0.0, 0.0]]), random_state=seed)
    if augmented is None:
        res = run_pose_filter(ll, inc, f, temper=(2.0, math.pi))
    else:
        res = run_augmented_pose_filter(ll, inc, f, augmented, temper=(2.0, math.pi))
    after = np.flatnonzero(truth >= 0)
    after = after[after > a.shape[0]]
    right = res.best[after] == truth[after]
    return right, f


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_augmented_mcl_relocalizes_a_kidnapped_filter(seed):
    """A tiny kidnapping term: the plain filter stays lost for many observations; Augmented MCL recovers within 4."""
    right, _ = _kidnapped_run(seed, None)
    plain_first = int(np.flatnonzero(right)[0]) if right.any() else right.size
    right, f = _kidnapped_run(seed, Augmented(slow=0.05, fast=0.5, cap=0.5))
    assert f.shares_  # the fall of the short-term average was seen
    first = int(np.flatnonzero(right)[0])
    assert first <= 4 and right[first:].mean() >= 0.9
    assert first < plain_first


def test_a_reserve_keeps_the_exact_mixture():
    """The kidnapping share kept as m weighted particles: the answer is (1 - s) tracked + s sensor; weights sum to 1."""
    from fingerloc.map.relocalize import _update_with_reserve

    f = PoseFilter(CORRIDOR, 1.0, n_particles=500, kidnap=0.0, outlier=0.2, start=np.array([[0.0, 0.0, 0.0]]),
                   random_state=0)  # fmt: skip
    g = PoseFilter(CORRIDOR, 1.0, n_particles=500, kidnap=0.0, outlier=0.2, start=np.array([[0.0, 0.0, 0.0]]),
                   random_state=0)  # fmt: skip
    row = np.where(np.arange(10) == 6, 4.0, 0.0)
    tracked = g.update(row, 0.5, None, kidnap=0.0)  # the same draws: the tracked part alone
    post = _update_with_reserve(f, row, 0.5, None, 0.1, 200)
    sensor = 0.5 * f.place_likelihood(row)
    sensor = np.exp(sensor - np.log(np.exp(sensor).sum()))
    np.testing.assert_allclose(np.exp(post), 0.9 * np.exp(tracked) + 0.1 * sensor, atol=1e-12)
    assert f.particles_.shape == (700, 3)
    w = np.exp(f.log_weights_)
    assert w.sum() == pytest.approx(1.0) and w[500:].sum() == pytest.approx(0.1)
    d = np.hypot(f.particles_[500:, 0] - 18.0, f.particles_[500:, 1])
    assert abs(np.mean(d <= 1.0) - sensor[6]) < 0.1  # the reserve is drawn at place 6 with the sensor's probability
    assert sensor[6] > 3 * sensor[0]
    f.predict([0.5, 0.0, 0.0])
    f.update(row, 0.5)  # the next update weighs all 700 and resamples to 500
    assert f.particles_.shape == (500, 3)


def test_augmented_settings_are_checked():
    for bad in ({"slow": 0.5, "fast": 0.1}, {"cap": 1.5}, {"threshold": 0.0}, {"reserve": -1}, {"floor": 0.6, "cap": 0.5}):
        with pytest.raises(InvalidParameterError):
            Augmented(**bad)


def test_pose_filtered_method_options_are_checked():
    from fingerloc.experiments.markov import PoseFilteredMethod

    with pytest.raises(InvalidParameterError, match="hold_margin"):
        PoseFilteredMethod("fingerprint", hold_margin=-0.1)
    m = PoseFilteredMethod("fingerprint", hold_margin=0.05, augmented=Augmented(reserve=100, adaptive=False))
    assert m.hold_margin == 0.05 and m.augmented is not None and m.augmented.reserve == 100


def test_tie_broken_best_asks_the_deterministic_belief_between_observations():
    """Near-ties (within delta of the best) between observations go to the place the tie-breaker believes most."""
    from fingerloc.map.relocalize import tie_broken_best

    rows = [[0.5, 0.3, 0.2], [0.36, 0.34, 0.30], [0.36, 0.34, 0.30], [0.6, 0.1, 0.3], [0.34, 0.36, 0.30]]
    observed = [True, False, False, False, True]
    tb = np.log([[0.1, 0.8, 0.1], [0.1, 0.8, 0.1], [0.1, 0.1, 0.8], [0.1, 0.8, 0.1], [0.8, 0.1, 0.1]])
    res = _posterior(rows)
    out = tie_broken_best(res, observed, tb, 0.05)
    # step 1: places 0 and 1 within 0.05 of the best -> 1, the tie-breaker's; step 2: the same candidates (place 2
    # is 0.06 below), the tie-breaker ranks them equal -> the first, 0; step 3: a clear lead stays; step 4 observed
    assert out.best.tolist() == [0, 1, 0, 0, 1]
    assert tie_broken_best(res, observed, tb, 0.1).best.tolist() == [0, 1, 2, 0, 1]
    assert tie_broken_best(res, observed, tb, 0.0).best.tolist() == res.best.tolist()
    np.testing.assert_array_equal(out.log_posterior, res.log_posterior)
    with pytest.raises(InvalidParameterError, match="delta"):
        tie_broken_best(res, observed, tb, -1.0)


def test_the_tracker_answers_between_observations_with_the_calibration_defaults():
    """run_pose_steps with hold_margin and tie_break = the plain run's answers passed through answer_between."""
    from fingerloc.map.filter import TransitionModel
    from fingerloc.map.relocalize import answer_between
    from fingerloc.pipeline.tracker import HOLD_MARGIN, TIE_BREAK, Calibration, run_pose_steps

    assert (Calibration().hold_margin, Calibration().tie_break) == (HOLD_MARGIN, TIE_BREAK) == (0.05, 0.02)
    poses = _polyline([(0, 0), (27, 0)], 0.25)
    truth = _truth(poses, CORRIDOR, radius=0.5)
    ll = _sensor(truth, 10, 1.5, 0)
    inc = np.vstack([np.zeros((1, 3)), odometry_increments(poses)])
    trans = TransitionModel.uniform(10)

    def run(**kw):
        f = PoseFilter(CORRIDOR, 0.5, n_particles=200, kidnap=0.01, outlier=0.3, random_state=4)
        return run_pose_steps(ll, inc, f, trans, temper=(2.0, math.pi), **kw)

    plain = run()
    both = run(hold_margin=0.05, tie_break=0.02)
    np.testing.assert_array_equal(both.log_posterior, plain.log_posterior)
    expected = answer_between(plain, ll, inc, trans, hold_margin=0.05, tie_break=0.02)
    np.testing.assert_array_equal(both.best, expected.best)
    obs = truth >= 0
    np.testing.assert_array_equal(both.best[obs], plain.best[obs])  # observed steps: the argmax
