"""The challenger strategy: a second pose filter started from the sensor, adopted when its trajectory fits better."""

import math

import numpy as np
import pytest
from scipy.special import logsumexp

from fingerloc.errors import InvalidParameterError
from fingerloc.map.driver import Challenger, PoseTracking, run_pose_filter
from fingerloc.map.motion import odometry_increments
from fingerloc.map.pose_filter import PoseFilter

from ._paths import polyline as _polyline
from ._paths import sensor_scores as _sensor
from ._paths import truth_places as _truth

CORRIDOR = np.column_stack([np.arange(10) * 3.0, np.zeros(10)])




def _kidnapped(seed, challenger):
    """The particles are sure the robot is at place 0 (no kidnapping term); it is at place 5 and the sensor says so."""
    poses = _polyline([(15, 0), (27, 0)], 0.5)
    truth = _truth(poses, CORRIDOR)
    ll = _sensor(truth, 10, 3.0, seed)
    f = PoseFilter(CORRIDOR, 1.0, kidnap=0.0, start=np.array([[0.0, 0.0, 0.0]]), random_state=seed)
    drv = PoseTracking(f, strategy=challenger, temper=(2.0, math.pi))
    res = run_pose_filter(ll, odometry_increments(poses), drv)
    q = truth >= 0
    return res.best[q] == truth[q], drv


@pytest.mark.parametrize(("seed", "tempered"), [(0, True), (1, True), (2, True), (0, False)])
def test_the_challenger_recovers_a_kidnapped_filter(seed, tempered):
    """Without a kidnapping term the filter never leaves its wrong belief; the challenger takes over within 10 observations."""
    right, _ = _kidnapped(seed, None)
    assert right.mean() < 0.2  # the failure, kept visible
    right, f = _kidnapped(seed, Challenger(tempered_evidence=tempered))
    assert f.resets_ >= 1 and f.switches_
    first = int(np.flatnonzero(right)[0])
    assert first <= 10 and right[first:].mean() >= 0.9


def _confident_mistakes(seed, challenger):
    """A tracked robot on the corridor; for 6 observations the sensor names a random wrong place, confidently."""
    poses = _polyline([(0, 0), (27, 0)], 0.5)
    truth = _truth(poses, CORRIDOR)
    ll = _sensor(truth, 10, 3.0, seed)
    rng = np.random.default_rng(100 + seed)
    q = np.flatnonzero(truth >= 0)
    bad = q[(q > 15) & (q < 50)][:6]
    for t in bad:
        wrong = int(rng.choice([j for j in range(10) if j != truth[t]]))
        ll[t] = rng.normal(size=10)
        ll[t, wrong] += 6.0
    f = PoseFilter(CORRIDOR, 1.0, kidnap=0.005, start=np.array([[0.0, 0.0, 0.0]]), random_state=seed)
    drv = PoseTracking(f, strategy=challenger, temper=(2.0, math.pi))
    res = run_pose_filter(ll, odometry_increments(poses), drv)
    after = q[q > bad[-1]]
    return float(np.mean(res.best[after] == truth[after])), drv


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_run_of_wrong_answers_inconsistent_with_the_odometry_does_not_switch(seed):
    top1, f = _confident_mistakes(seed, Challenger())
    assert top1 >= 0.9
    assert any(e == "spawn" for _, e, _ in f.challenger_trace_)  # challengers were tried ...
    assert f.resets_ == 0  # ... and lost


def test_log_evidence_by_hand():
    f = PoseFilter(CORRIDOR, 1.0, n_particles=50, outlier=0.2, off_place=0.1, random_state=0)
    row = np.random.default_rng(0).normal(size=10)
    lp = 0.5 * f.place_likelihood(row)
    d = np.hypot(f.particles_[:, None, 0] - CORRIDOR[None, :, 0], f.particles_[:, None, 1] - CORRIDOR[None, :, 1])
    near, dist = np.argmin(d, axis=1), np.min(d, axis=1)
    lik = np.where(dist <= 1.0, lp[near], 0.5 * math.log(0.1 / 10))
    want = float(logsumexp(f.log_weights_ + lik))
    before = f.particles_.copy()
    assert f.log_evidence(row, 0.5) == pytest.approx(want, abs=1e-12)
    assert np.array_equal(f.particles_, before)  # nothing moved


def test_spawn_and_adopt():
    f = PoseFilter(CORRIDOR, 1.0, n_particles=300, random_state=0)
    g = f.spawn(100)
    assert g.n_particles == 100 and g.particles_.shape == (100, 3) and f.particles_.shape == (300, 3)
    g.update(np.where(np.arange(10) == 7, 5.0, 0.0), 1.0, kidnap=1.0)
    post = f.adopt(g)
    assert f.particles_.shape == (300, 3)
    assert int(np.argmax(post)) == 7 and np.isclose(np.exp(post).sum(), 1.0)
    with pytest.raises(InvalidParameterError):
        f.adopt(PoseFilter(CORRIDOR[:3], 1.0, n_particles=20))


@pytest.mark.parametrize(
    "kw", [{"n_particles": 5}, {"switch_nats": -1.0}, {"drop_nats": math.nan}, {"max_observations": 0}, {"spawn_nats": math.inf}]
)
def test_challenger_settings_are_checked(kw):
    with pytest.raises(InvalidParameterError):
        Challenger(**kw)


def test_the_tracker_runs_the_challenger_from_the_config():
    """``config.pose_filter.strategy`` is what ``track --filter pose`` and the benchmark read: the same run as the driver's."""
    from fingerloc.config import Config
    from fingerloc.map.filter import MarkovFilter
    from fingerloc.pipeline.calibration import Calibration, mapping_graph
    from fingerloc.pipeline.filters import pose_filter_of, pose_tracking, strategy_of, transition_of

    poses = _polyline([(0, 0), (27, 0), (0, 0)], 0.5)
    truth = _truth(poses, CORRIDOR)
    ll = _sensor(truth, 10, 3.0, 0)
    graph, metres = mapping_graph(poses[:, :2], CORRIDOR)
    cal = Calibration(metres_per_move=metres, kidnap=0.01)
    cfg = Config().with_(pose_filter={"strategy": "challenger", "challenger_switch_nats": 2.0, "n_particles": 200})
    assert strategy_of(cfg) == Challenger(switch_nats=2.0) and strategy_of(Config()) is None
    transition = transition_of(graph, cal, cfg)
    drv = pose_tracking(pose_filter_of(CORRIDOR, cal, cfg, seed=3), transition, cal, cfg)
    got = run_pose_filter(ll, odometry_increments(poses), drv)
    f = PoseFilter(CORRIDOR, 1.0, n_particles=200, kidnap=0.01, random_state=3)
    want_drv = PoseTracking(
        f, strategy=Challenger(switch_nats=2.0), temper=(2.0, math.pi), place_filter=MarkovFilter(transition),
        start_at_first_observation=True, hold_margin=0.05, tie_break=0.02,
    )  # fmt: skip
    want = run_pose_filter(ll, odometry_increments(poses), want_drv)
    assert np.array_equal(got.log_posterior, want.log_posterior) and np.array_equal(got.best, want.best)
    assert want_drv.challenger_trace_  # challengers were started
