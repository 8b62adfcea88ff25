"""The pose filter's answer between observations (held, tie-broken) and Augmented MCL with a reserve."""

import math

import numpy as np
import pytest

from fingerloc.errors import InvalidParameterError
from fingerloc.map.driver import AnswerRule, Augmented, PoseTracking, _update_with_reserve, run_pose_filter
from fingerloc.map.motion import odometry_increments
from fingerloc.map.pose_filter import PoseFilter

from ._paths import polyline as _polyline
from ._paths import sensor_scores as _sensor
from ._paths import truth_places as _truth

CORRIDOR = np.column_stack([np.arange(10) * 3.0, np.zeros(10)])


def _answers(rows, observed, hold_margin=None, tie_break=None, beliefs=None):
    """The answer rule along rows of probabilities: (best places, their probabilities)."""
    rule = AnswerRule(hold_margin, tie_break)
    out = [rule.step(np.log(r), o, None if beliefs is None else beliefs[t]) for t, (r, o) in enumerate(zip(rows, observed, strict=True))]
    return [b for b, _ in out], [p for _, p in out]


def test_held_best_keeps_the_answer_through_a_near_tie():
    """Between observations a near-tie flips the argmax; held, the answer changes only when another leads by the margin."""
    rows = [[0.6, 0.4], [0.49, 0.51], [0.52, 0.48], [0.45, 0.55], [0.3, 0.7], [0.55, 0.45], [0.45, 0.55]]
    observed = [True, False, False, False, False, False, True]
    argmax = [int(np.argmax(r)) for r in rows]
    assert argmax == [0, 1, 0, 1, 1, 0, 1]
    assert _answers(rows, observed)[0] == argmax  # no rule: the argmax
    best, prob = _answers(rows, observed, 0.2)
    assert best == [0, 0, 0, 0, 1, 1, 1]  # 0.7 > 0.3 + 0.2 switches; 0.55 vs 0.45 does not switch back
    assert prob[3] == pytest.approx(0.45)
    assert _answers(rows, observed, 0.0)[0] == argmax  # margin 0: the argmax
    assert _answers(rows, observed, math.inf)[0] == [0, 0, 0, 0, 0, 0, 1]  # hold until the next observation
    with pytest.raises(InvalidParameterError, match="hold_margin"):
        AnswerRule(-0.1)


def test_held_best_makes_two_runs_agree_more_between_observations():
    """Two runs of one tracking pose filter (other draws, 100 particles) along a corridor: held, they disagree less between places."""
    poses = _polyline([(0, 0), (27, 0)], 0.25)
    truth = _truth(poses, CORRIDOR, radius=0.5)
    inc = odometry_increments(poses)
    obs = truth >= 0
    plain = held = 0
    for s in range(3):
        ll = _sensor(truth, 10, 3.0, s)
        for margin in (None, 0.1):
            runs = [
                run_pose_filter(ll, inc, PoseFilter(CORRIDOR, 0.5, n_particles=100, kidnap=0.01, outlier=0.3,
                                                    start=np.array([[0.0, 0.0, 0.0]]), random_state=seed),
                                temper=(2.0, math.pi), hold_margin=margin)
                for seed in (2 * s + 1, 2 * s + 2)
            ]  # fmt: skip
            np.testing.assert_array_equal(runs[0].best[obs], np.argmax(runs[0].log_posterior[obs], axis=1))
            differ = int(np.sum(runs[0].best[~obs] != runs[1].best[~obs]))
            if margin is None:
                plain += differ
            else:
                held += differ
    assert plain >= 4 and held <= plain // 2


def _kidnapped_run(seed, augmented):
    """Tracked along the corridor from place 0, then carried (unobserved) to place 8 and driven back towards place 4."""
    a = _polyline([(0, 0), (9, 0)], 0.5)
    b = _polyline([(24, 0), (12, 0)], 0.5)
    inc = np.vstack([odometry_increments(a), np.zeros((1, 3)), odometry_increments(b)])
    truth = np.r_[_truth(a, CORRIDOR), _truth(b, CORRIDOR)]
    ll = _sensor(truth, 10, 3.0, seed)
    f = PoseFilter(CORRIDOR, 1.0, n_particles=1000, kidnap=0.002, start=np.array([[0.0, 0.0, 0.0]]), random_state=seed)
    drv = PoseTracking(f, strategy=augmented, temper=(2.0, math.pi))
    res = run_pose_filter(ll, inc, drv)
    after = np.flatnonzero(truth >= 0)
    after = after[after > a.shape[0]]
    right = res.best[after] == truth[after]
    return right, drv


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
    f = PoseFilter(CORRIDOR, 1.0, n_particles=500, kidnap=0.0, outlier=0.2, start=np.array([[0.0, 0.0, 0.0]]),
                   random_state=0)  # fmt: skip
    g = PoseFilter(CORRIDOR, 1.0, n_particles=500, kidnap=0.0, outlier=0.2, start=np.array([[0.0, 0.0, 0.0]]),
                   random_state=0)  # fmt: skip
    row = np.where(np.arange(10) == 6, 4.0, 0.0)
    tracked = g.update(row, 0.5, None, kidnap=0.0)  # the same draws: the tracked part alone
    post = _update_with_reserve(f, row, 0.5, None, 0.1, 200, {})
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


def test_tie_broken_best_asks_the_deterministic_belief_between_observations():
    """Near-ties (within delta of the best) between observations go to the place the tie-breaker believes most."""
    rows = [[0.5, 0.3, 0.2], [0.36, 0.34, 0.30], [0.36, 0.34, 0.30], [0.6, 0.1, 0.3], [0.34, 0.36, 0.30]]
    observed = [True, False, False, False, True]
    tb = np.log([[0.1, 0.8, 0.1], [0.1, 0.8, 0.1], [0.1, 0.1, 0.8], [0.1, 0.8, 0.1], [0.8, 0.1, 0.1]])
    # step 1: places 0 and 1 within 0.05 of the best -> 1, the tie-breaker's; step 2: the same candidates (place 2
    # is 0.06 below), the tie-breaker ranks them equal -> the first, 0; step 3: a clear lead stays; step 4 observed
    assert _answers(rows, observed, tie_break=0.05, beliefs=tb)[0] == [0, 1, 0, 0, 1]
    assert _answers(rows, observed, tie_break=0.1, beliefs=tb)[0] == [0, 1, 2, 0, 1]
    assert _answers(rows, observed, tie_break=0.0, beliefs=tb)[0] == [0, 0, 0, 0, 1]
    with pytest.raises(InvalidParameterError, match="tie_break"):
        AnswerRule(tie_break=-1.0)
    with pytest.raises(InvalidParameterError, match="belief"):
        _answers(rows, observed, tie_break=0.05)


def test_the_map_default_answers_between_observations_with_the_place_filter():
    """The config's defaults hold the answer (0.05) and break near-ties (0.02) by the place filter run alongside;
    the posterior, and the answers at observed steps, are the plain run's."""
    from fingerloc.config import Config
    from fingerloc.map.filter import MarkovFilter, TransitionModel

    pf = Config().pose_filter
    assert (pf.hold_margin, pf.tie_break) == (0.05, 0.02)
    poses = _polyline([(0, 0), (27, 0)], 0.25)
    truth = _truth(poses, CORRIDOR, radius=0.5)
    ll = _sensor(truth, 10, 1.5, 0)
    inc = np.vstack([np.zeros((1, 3)), odometry_increments(poses)])
    trans = TransitionModel.uniform(10)

    def run(**kw):
        f = PoseFilter(CORRIDOR, 0.5, n_particles=200, kidnap=0.01, outlier=0.3, random_state=4)
        drv = PoseTracking(f, place_filter=MarkovFilter(trans), temper=(2.0, math.pi), **kw)
        return run_pose_filter(ll, inc, drv)

    plain = run()
    both = run(hold_margin=0.05, tie_break=0.02)
    np.testing.assert_array_equal(both.log_posterior, plain.log_posterior)
    obs = truth >= 0
    np.testing.assert_array_equal(both.best[obs], plain.best[obs])  # observed steps: the argmax
    assert np.any(both.best[~obs] != plain.best[~obs])  # between them the rule answers
