"""The pose particle filter over the place map (fingerloc.map.pose_filter) and its benchmark method."""

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import logsumexp

from fingerloc.config import Config
from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.carmen import run_benchmark
from fingerloc.experiments.filtered import PoseFilteredMethod
from fingerloc.experiments.kidnap import TrackingData, kidnap_experiment
from fingerloc.map.driver import PoseTracking, run_pose_filter
from fingerloc.map.filter import MarkovFilter, TransitionModel, run_filter
from fingerloc.map.graph import PlaceGraph
from fingerloc.map.motion import MotionNoise, OdometryError, compose_increments, odometry_increments, simulate_odometry
from fingerloc.map.pose_filter import PoseFilter, observation_weights

ANGLE = st.floats(-math.pi, math.pi - 1e-9)
COORD = st.floats(-50, 50)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(COORD, COORD, ANGLE), min_size=1, max_size=12))
def test_increments_and_dead_reckoning_invert_each_other(poses):
    p = np.array(poses, dtype=float)
    back = compose_increments(p[0], odometry_increments(p))
    assert back.shape == p.shape
    assert np.allclose(back[:, :2], p[:, :2], atol=1e-7)
    assert np.allclose(np.angle(np.exp(1j * (back[:, 2] - p[:, 2]))), 0.0, atol=1e-9)


def test_increment_is_in_the_robot_frame():
    # facing +y, moving +y by 2 m and turning left 90 deg: 2 m forward, 0 left
    inc = odometry_increments([[1.0, 1.0, math.pi / 2], [1.0, 3.0, math.pi]])
    assert np.allclose(inc[0, :2], [2.0, 0.0])
    assert inc[0, 2] == pytest.approx(math.pi / 2)


def test_simulated_odometry():
    t = np.linspace(0, 20, 81)
    poses = np.column_stack([t, np.zeros_like(t), np.zeros_like(t)])
    exact = odometry_increments(poses)
    zero = OdometryError(scale=0, translation=0, rotation=0, drift_per_metre=0, bias_per_metre=0)
    assert np.allclose(simulate_odometry(poses, zero), exact)
    noisy = simulate_odometry(poses, random_state=3)
    assert np.array_equal(noisy, simulate_odometry(poses, random_state=3))
    travelled = np.hypot(noisy[:, 0], noisy[:, 1]).sum()
    assert travelled == pytest.approx(20 * 1.02, rel=0.03)  # 2 % scale error, random part averages out
    # the systematic heading drift bends the dead-reckoned path to the left (0.005 rad / m)
    end = compose_increments(poses[0], noisy)[-1]
    assert end[2] > 0.02
    with pytest.raises(InvalidParameterError):
        OdometryError(translation=-0.1)
    with pytest.raises(InvalidParameterError):
        MotionNoise(rotation=float("nan"))


def test_observation_weights_by_hand():
    # steps: observed, 1 m, observed, 0.5 m + half a turn, observed, 3 m, (no obs), 1 m, observed
    inc = np.array([[1.0, 0, 0], [0.5, 0, math.pi / 2], [3.0, 0, 0], [1.0, 0, 0]])
    obs = [True, True, True, False, True]
    w = observation_weights(inc, obs, metres=2.0, radians=math.pi)
    assert w.tolist() == pytest.approx([1.0, 0.5, 0.75, 0.0, 1.0])
    w2 = observation_weights(inc, obs, metres=2.0)  # turns do not count
    assert w2.tolist() == pytest.approx([1.0, 0.5, 0.25, 0.0, 1.0])
    # standing still still counts a little (never 0 at an observed step)
    assert observation_weights(np.zeros((1, 3)), [True, True], metres=2.0)[1] > 0
    with pytest.raises(InvalidParameterError):
        observation_weights(inc, obs[:-1], metres=2.0)
    with pytest.raises(InvalidParameterError):
        observation_weights(inc, obs, metres=0.0)


def _filter(**kw):
    centres = np.array([[0.0, 0.0], [4.0, 0.0], [8.0, 0.0]])
    kw.setdefault("random_state", 0)
    return PoseFilter(centres, 1.0, n_particles=kw.pop("n_particles", 400), **kw)


def test_update_by_hand():
    """Four particles placed by hand; the place posterior is the formula of the module docstring."""
    f = _filter(n_particles=10, kidnap=0.1, outlier=0.2)
    f.particles_ = np.array([[0.1, 0, 0], [0.2, 0, 0], [4.5, 0, 0], [5.8, 0, 0]])  # places 0, 0, 1, none (1.8 m from place 1)
    f.log_weights_ = np.log(np.full(4, 0.25))
    row = np.log([0.5, 0.3, 0.2])
    post = np.exp(f.update(row))
    p = 0.8 * np.array([0.5, 0.3, 0.2]) + 0.2 / 3
    floor = 0.2 / 3
    tracked = np.array([0.25 * p[0] * 2, 0.25 * p[1], 0.0])
    tracked_total = tracked.sum() + 0.25 * floor
    tracked_place = tracked / tracked_total  # the floor particle belongs to place 1 (nearest) for the mass
    tracked_place[1] += 0.25 * floor / tracked_total
    kid = p / 3  # uniform prior
    want = 0.9 * tracked_total * tracked_place + 0.1 * kid.sum() * (kid / kid.sum())
    want /= want.sum()
    assert np.allclose(post, want, atol=1e-12)
    assert f.particles_.shape == (10, 3)
    assert logsumexp(f.log_weights_) == pytest.approx(0.0)


def test_probabilities_sum_to_one_and_no_nan():
    rng = np.random.default_rng(1)
    f = _filter(kidnap=0.01)
    for t in range(30):
        f.predict(rng.normal(0, 0.5, 3))
        row = rng.normal(size=3)
        if t % 5 == 0:
            row[rng.integers(3)] = -np.inf  # a place that cannot have produced the view
        if t == 7:
            row[:] = -np.inf  # no place explains it
        post = f.update(row, weight=rng.uniform(0.05, 1))
        assert not np.any(np.isnan(post))
        assert math.isclose(float(np.exp(post).sum()), 1.0, rel_tol=1e-9)
    # outlier 0, kidnap 0, every particle far away: nothing explains the view, the belief stays
    g = _filter(outlier=0.0, kidnap=0.0)
    g.particles_[:, :2] = 100.0
    before = g.place_log_posterior()
    after = g.update(np.log([0.2, 0.3, 0.5]))
    assert np.array_equal(before, after)


def test_bad_input():
    with pytest.raises(InvalidParameterError, match="centres"):
        PoseFilter(np.zeros((0, 2)), 1.0)
    with pytest.raises(InvalidParameterError, match="radius"):
        PoseFilter(np.zeros((2, 2)), 0.0)
    with pytest.raises(InvalidParameterError, match="kidnap"):
        _filter(kidnap=1.0)
    with pytest.raises(InvalidParameterError, match="outlier"):
        _filter(outlier=1.5)
    f = _filter()
    with pytest.raises(InvalidParameterError, match="3 entries"):
        f.update([0.0, 0.0])
    with pytest.raises(InvalidParameterError, match="NaN"):
        f.update([0.0, np.nan, 0.0])
    with pytest.raises(InvalidParameterError, match="weight"):
        f.update([0.0, 0.0, 0.0], weight=0.0)
    with pytest.raises(InvalidParameterError, match="kidnap_prior"):
        f.update([0.0, 0.0, 0.0], kidnap_prior=[-np.inf] * 3)
    with pytest.raises(InvalidParameterError, match="increment"):
        f.predict([1.0, 0.0])
    with pytest.raises(InvalidParameterError, match="increments"):
        run_pose_filter(np.zeros((4, 3)), np.zeros((2, 3)), f)


def _corridor(n_places=20, per_place=4, spacing=2.0):
    """A robot driving along a straight corridor of places every ``spacing`` m, then back."""
    xs = np.linspace(0, (n_places - 1) * spacing, (n_places - 1) * per_place + 1)
    there = np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])
    back = np.column_stack([xs[::-1], np.zeros_like(xs), np.full_like(xs, math.pi - 1e-9)])
    poses = np.vstack([there, back])
    centres = np.column_stack([np.arange(n_places) * spacing, np.zeros(n_places)])
    dist = np.linalg.norm(poses[:, None, :2] - centres[None], axis=2)
    truth = np.argmin(dist, axis=1)
    truth[dist[np.arange(truth.size), truth] > 0.5] = -1
    return poses, centres, truth


def test_odometry_carries_the_belief_where_the_sensor_is_blind():
    """One sharp observation at the start, then a sensor that cannot tell places apart.

    The pose filter follows the robot by dead reckoning (direction included);
    the discrete filter over places only knows how far it went and spreads
    over both directions. Fails if the increments' direction were ignored.
    """
    poses, centres, truth = _corridor()
    p = centres.shape[0]
    ll = np.full((truth.size, p), np.nan)
    ll[0] = np.where(np.arange(p) == 0, 0.0, -20.0)  # at place 0
    obs = np.flatnonzero(truth >= 0)[1:]
    ll[obs] = 0.0  # uninformative views
    f = PoseFilter(centres, 0.5, n_particles=800, kidnap=0.0, start=centres, random_state=0)
    res = run_pose_filter(ll, odometry_increments(poses), f)
    right = res.best[obs] == truth[obs]
    assert right.mean() >= 0.9
    g = PlaceGraph.from_sequence([str(i) for i in range(p)], [str(i) for i in truth[truth >= 0]])
    t = TransitionModel.from_graph(g, metres_per_move=2.0)
    dist = np.r_[0, np.hypot(*np.diff(poses[:, :2], axis=0).T)]
    discrete = run_filter(ll, t, distances=dist)
    assert (discrete.best[obs] == truth[obs]).mean() < 0.5


def test_tracks_with_noisy_odometry_and_a_noisy_sensor():
    poses, centres, truth = _corridor()
    p = centres.shape[0]
    rng = np.random.default_rng(4)
    ll = np.full((truth.size, p), np.nan)
    q = truth >= 0
    ll[q] = rng.normal(size=(int(q.sum()), p))
    ll[np.flatnonzero(q), truth[q]] += 1.5  # right place first only about half the time
    single = (np.argmax(ll[q], axis=1) == truth[q]).mean()
    f = PoseFilter(centres, 0.5, n_particles=1500, start=centres, random_state=1)
    inc = simulate_odometry(poses, random_state=2)
    res = run_pose_filter(ll, inc, f, weights=observation_weights(inc, q, metres=2.0))
    filtered = (res.best[q] == truth[q]).mean()
    assert filtered >= single + 0.2
    assert np.allclose(np.exp(res.log_posterior).sum(axis=1), 1.0)


def test_place_filter_prior_speeds_up_relocalization():
    """After an unobserved jump the place filter's belief tells the pose filter where to look."""
    poses, centres, truth = _corridor(n_places=30)
    p = centres.shape[0]
    g = PlaceGraph.from_sequence([str(i) for i in range(p)], [str(i) for i in truth[truth >= 0]])
    t = TransitionModel.from_graph(g, metres_per_move=2.0)
    rng = np.random.default_rng(0)
    q = truth >= 0
    ll = np.full((truth.size, p), np.nan)
    ll[q] = rng.normal(size=(int(q.sum()), p))
    ll[np.flatnonzero(q), truth[q]] += 2.5
    inc = np.vstack([np.zeros((1, 3)), odometry_increments(poses)])
    # splice: the first 30 steps, then from step 80 on (about 40 m away), with step 80's own odometry
    idx = np.r_[0:30, 80:116]
    obs_after = np.flatnonzero(q[idx][30:])
    steps = []
    for pf in (None, MarkovFilter(t)):
        f = PoseFilter(centres, 0.5, n_particles=1000, kidnap=0.01, start=centres, random_state=3)
        res = run_pose_filter(ll[idx], inc[idx][1:], f, place_filter=pf)
        right = res.best[30:][obs_after] == truth[idx][30:][obs_after]
        steps.append(next(int(obs_after[k]) for k in range(right.size) if right[k:].all()))
    assert steps[1] <= 10
    assert steps[1] <= steps[0]


def _chain_pose_data(p=30, per_place=3):
    """A 30-place corridor, one metre a step, a synthetic sensor at every step, the pose filter on top."""
    truth = np.repeat(np.arange(p), per_place)
    pos = np.column_stack([np.arange(truth.size) * 1.0, np.zeros(truth.size)])
    poses = np.column_stack([pos, np.zeros(truth.size)])
    centres = np.column_stack([np.arange(p) * 3.0 + 1.0, np.zeros(p)])
    g = PlaceGraph.from_sequence([str(i) for i in range(p)], [str(i) for i in truth])

    class Fitted(PoseFilteredMethod):
        def __init__(self) -> None:
            # the kidnapping path as it was pinned (the start from the first observation changes the random
            # stream; over seeds 0-2 both starts recover in 4-6 of the 6 trials within 20 steps)
            super().__init__("fingerprint")
            self.transition_ = TransitionModel.from_graph(g, metres_per_move=3.0)
            f = PoseFilter(centres, 1.5, n_particles=1000, kidnap=0.01, random_state=0)
            self.tracking_ = PoseTracking(
                f, place_filter=MarkovFilter(self.transition_), temper=(2.0, math.pi), hold_margin=0.05, tie_break=0.02
            )
            self.scan_map_ = None

    rng = np.random.default_rng(0)
    ll = rng.normal(size=(truth.size, p))
    ll[np.arange(truth.size), truth] += 2.5
    inc = np.vstack([np.zeros((1, 3)), odometry_increments(poses)])
    dist = np.r_[0, np.ones(truth.size - 1)]
    return TrackingData(Fitted(), ll, dist, truth, pos, inc)


def test_kidnap_experiment_runs_the_pose_filter():
    """Kidnapped along the corridor (often backwards), the pose filter finds the robot again within the stretch.

    Slower than the discrete filter (the tempered observations count half
    here, and fresh particles must also guess the heading): within 20 steps,
    not 10.
    """
    res = kidnap_experiment(_chain_pose_data(), name="chain", n_trials=6, stretch=20, min_jump_m=20.0)
    s = res.summary()
    assert s["trials"] == 6 and s["recovered"] == 6
    assert s["max_recover_steps"] <= 19
    assert all(t["recover_observed_steps"] is not None for t in res.trials)


def test_pose_filtered_benchmark_end_to_end(rooms_log):
    run = run_benchmark([rooms_log], ["baseline-histogram", "baseline-histogram-odometry"])
    js = json.loads(json.dumps(run.to_json()))
    figs = js["logs"]["rooms"]["methods"]["baseline-histogram-odometry"]
    assert figs["top1"] >= js["logs"]["rooms"]["methods"]["baseline-histogram"]["top1"] - 1e-9
    with pytest.raises(InvalidParameterError, match="odometry"):
        PoseFilteredMethod("fingerprint", odometry="wheels")


def test_cli_track_pose_filter(rooms_log, tmp_path, capsys):
    from tests._cli import run_cli

    db = tmp_path / "rooms.sqlite"
    out = tmp_path / "t.json"
    code, text, err = run_cli(
        capsys, "track", str(rooms_log), "--db", str(db), "--map", "--filter", "pose", "--json", str(out), "-q"
    )
    assert code == 0, err
    js = json.loads(out.read_text())
    s = js["summary"]
    assert s["filter"] == "pose" and s["steps"] == 11 and s["filtered"]["labelled"] == 9
    assert np.isfinite(s["filtered"]["top1"])
    assert "pose filter" in text
    code, _, err = run_cli(capsys, "track", str(rooms_log), "--db", str(db), "--filter", "wheels")
    assert code == 2 and err.startswith("error:") and "--filter" in err
    code, _, err = run_cli(capsys, "track", str(rooms_log), "--db", str(db), "--filter", "pose", "--radius", "-1")
    assert code == 2 and "--radius" in err


def test_cli_track_pose_filter_jsonl(tmp_path, capsys):
    """JSON Lines: the places' positions are the mean poses of their views in --graph-from."""
    from fingerloc.io.jsonl import write_observations
    from fingerloc.map.database import save_model
    from fingerloc.model import PlaceModel
    from fingerloc.observation import Observation
    from tests._cli import run_cli

    rng = np.random.default_rng(0)
    bearings = {"a": [10, 100, 200], "b": [40, 150, 300], "c": [70, 220, 330]}
    where = {"a": 0.0, "b": 4.0, "c": 8.0}

    def obs(lab, dx=0.0, pose=True):
        return Observation.from_degrees(
            {"VE": (np.array(bearings[lab]) + rng.normal(0, 3, 3)).tolist()},
            label=lab,
            pose=[where[lab] + dx, 0.0, 0.0] if pose else None,
        )

    train = [obs(lab, dx) for lab in "abc" for dx in (-0.3, 0.3)]
    db = tmp_path / "p.sqlite"
    save_model(PlaceModel(n_components=2, terms=("VE",)).fit(train), db)
    tr = tmp_path / "train.jsonl"
    write_observations(tr, train)
    q = tmp_path / "q.jsonl"
    write_observations(q, [obs(lab) for lab in "abcba"])
    out = tmp_path / "t.json"
    code, _, err = run_cli(
        capsys, "track", str(q), "--db", str(db), "--graph-from", str(tr), "--filter", "pose", "--json", str(out)
    )
    assert code == 0, err
    js = json.loads(out.read_text())
    assert js["summary"]["filter"] == "pose" and js["summary"]["filtered"]["top1"] >= 0.8
    # without the views' positions the pose filter cannot run: one line, exit 2
    code, _, err = run_cli(capsys, "track", str(q), "--db", str(db), "--filter", "pose")
    assert code == 2 and err.startswith("error:") and "--graph-from" in err
    write_observations(q, [obs("a", pose=False)])
    code, _, err = run_cli(capsys, "track", str(q), "--db", str(db), "--graph-from", str(tr), "--filter", "pose")
    assert code == 2 and "pose" in err


def test_speed_section_times_both_filters():
    from fingerloc.experiments.speed_markov import _pose_filter_times

    figs = _pose_filter_times(quick=True)
    assert set(figs) == {
        f"pose_filter_us_per_{kind}_{p}_places" for kind in ("prediction", "observed_step") for p in (50, 500)
    }
    assert all(v > 0 for v in figs.values())


def test_pose_filtered_method_options_are_checked():
    with pytest.raises(InvalidParameterError, match="kidnap"):
        PoseFilteredMethod("fingerprint", Config().with_(calibration={"kidnap": 1.0}))
    with pytest.raises(InvalidParameterError, match="odometry_error"):
        PoseFilteredMethod("fingerprint", odometry_error=-1.0)
    m = PoseFilteredMethod("fingerprint")
    with pytest.raises(InvalidParameterError, match="fit_log"):
        m.fit([], np.zeros(0))


def test_parameters_of_the_wrong_type_are_errors():
    with pytest.raises(InvalidParameterError, match="kidnap"):
        _filter(kidnap="often")
    with pytest.raises(InvalidParameterError, match="n_particles"):
        _filter(n_particles=100.5)
    with pytest.raises(InvalidParameterError, match="radius"):
        PoseFilter(np.zeros((2, 2)), None)


def test_odometry_error_scaled():
    e = OdometryError().scaled(2.0)
    assert e.scale == pytest.approx(0.04) and e.bias_per_metre == pytest.approx(0.01)
    assert OdometryError().scaled(0.0) == OdometryError(0, 0, 0, 0, 0)
    with pytest.raises(InvalidParameterError):
        OdometryError().scaled(-1.0)


def test_one_step_from_the_uniform_prior_is_the_single_shot_posterior():
    """Particles spread evenly over the places, one observation, no kidnapping, no outliers: the softmax of the row."""
    centres = np.array([[0.0, 0.0], [5.0, 0.0], [0.0, 5.0], [5.0, 5.0]])
    f = PoseFilter(centres, 1.0, n_particles=40000, kidnap=0.0, outlier=0.0, random_state=5)
    row = np.array([0.3, -1.2, 2.0, 0.0])
    post = np.exp(f.update(row))
    want = np.exp(row - logsumexp(row))
    assert np.allclose(post, want, atol=0.01)
