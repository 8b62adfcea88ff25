import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import logsumexp

from fingerloc.errors import InvalidParameterError
from fingerloc.map.filter import (
    MarkovFilter,
    TransitionModel,
    entropy_bits,
    fit_likelihood_scale,
    metres_per_move,
    run_filter,
)
from fingerloc.map.graph import PlaceGraph


def chain_model(p, stay=0.5, eps=0.0, metres=None):
    """Places 0..p-1 on a line; leave to either neighbour evenly."""
    move = np.zeros((p, p))
    for i in range(p):
        nb = [j for j in (i - 1, i + 1) if 0 <= j < p] or [i]
        move[i, nb] = 1.0 / len(nb)
    return TransitionModel(stay=np.full(p, stay), move=move, uniform_mix=eps, metres_per_move=metres)


def test_uniform_transition_one_step_is_single_shot():
    rng = np.random.default_rng(0)
    ll = rng.normal(size=(1, 7)) * 5
    res = run_filter(ll, TransitionModel.uniform(7))
    assert np.allclose(res.log_posterior[0], ll[0] - logsumexp(ll[0]))


def test_uniform_transition_every_step_is_single_shot():
    rng = np.random.default_rng(1)
    ll = rng.normal(size=(6, 5)) * 3
    res = run_filter(ll, TransitionModel.uniform(5))
    assert np.allclose(res.log_posterior, ll - logsumexp(ll, axis=1, keepdims=True))


def test_single_shot_posterior_of_a_place_model():
    from fingerloc.model import PlaceModel
    from fingerloc.observation import Observation

    rng = np.random.default_rng(2)
    obs = [
        Observation.from_degrees({"VE": (c + rng.normal(0, 5, 4)).tolist()}, label=f"p{k}")
        for k, c in enumerate(([10, 100, 200, 300], [50, 140, 230, 330], [0, 90, 180, 270]))
        for _ in range(3)
    ]
    model = PlaceModel(n_components=2, terms=("VE",)).fit(obs)
    ll = model.joint_log_likelihood(obs[:1])
    res = run_filter(ll, TransitionModel.uniform(3))
    assert np.allclose(res.log_posterior, model.predict_log_proba(obs[:1]))


def test_hand_computed_three_places():
    # T = [[.5 .5 0], [.25 .5 .25], [0 .5 .5]]
    t = chain_model(3)
    assert np.allclose(t.matrix(), [[0.5, 0.5, 0], [0.25, 0.5, 0.25], [0, 0.5, 0.5]])
    ll = np.log([[0.6, 0.3, 0.1], [0.2, 0.2, 0.8]])
    post = np.exp(run_filter(ll, t).log_posterior)
    assert np.allclose(post[0], [0.6, 0.3, 0.1])
    # predicted: [.6*.5 + .3*.25, .5, .3*.25 + .1*.5] = [.375, .5, .125]; times [.2 .2 .8] -> [.075 .1 .1] / .275
    assert np.allclose(post[1], [3 / 11, 4 / 11, 4 / 11])


def test_prediction_only_steps():
    t = chain_model(3)
    ll = np.array([np.log([1.0, 1e-300, 1e-300]), [np.nan] * 3, [np.nan] * 3])
    post = np.exp(run_filter(ll, t).log_posterior)
    assert np.allclose(post[1], [0.5, 0.5, 0], atol=1e-12)
    assert np.allclose(post[2], [0.375, 0.5, 0.125], atol=1e-12)
    # the observed= mask does the same whatever the rows hold
    ll2 = np.array([ll[0], [0.0, 5.0, 9.0], [1.0, 2.0, 3.0]])
    post2 = np.exp(run_filter(ll2, t, observed=[True, False, False]).log_posterior)
    assert np.allclose(post2, post)


def test_from_graph_hand_computed():
    g = PlaceGraph.from_sequence(["a", "b", "c"], ["a", "a", "b", "b", "b", "c", "b"])
    t = TransitionModel.from_graph(g, alpha=1.0)
    # stay = (C_ii + 1) / (C_ii + out_i + 2)
    assert np.allclose(t.stay, [2 / 4, 3 / 5, 1 / 3])
    # S = C + C^T off-diagonal: a-b 1, b-c 2; move = (S + 1) over the neighbours
    assert np.allclose(t.move, [[0, 1, 0], [0.4, 0, 0.6], [0, 1, 0]])
    assert t.uniform_mix == pytest.approx(1 / (6 + 2))
    m = t.matrix()
    assert np.allclose(m.sum(axis=1), 1)
    assert m[0, 2] == pytest.approx(0.125 / 3)  # only the uniform term reaches a non-neighbour


def test_from_graph_isolated_place_stays():
    g = PlaceGraph(["a", "b"], {("a", "a"): 3})
    t = TransitionModel.from_graph(g, alpha=0.0, uniform_mix=0.0)
    assert np.allclose(t.matrix(), np.eye(2))


def test_odometry_zero_distance_stays_long_distance_spreads():
    t = chain_model(5, stay=0.2, eps=0.0, metres=1.0)
    assert np.allclose(t.matrix(0.0), np.eye(5))
    far = t.matrix(50.0)
    assert np.allclose(far.sum(axis=1), 1)
    assert np.all(far > 0.05)  # many moves: close to the chain's stationary spread
    near = t.matrix(0.1)
    # no jump with probability exp(-d / L), plus leaving and coming back (second order)
    assert math.exp(-0.1) < near[2, 2] < math.exp(-0.1) + 0.01
    # without metres_per_move the distance is ignored
    assert np.allclose(chain_model(5, stay=0.2).matrix(3.0), chain_model(5, stay=0.2).matrix())


def test_metres_per_move():
    pos = [[0, 0], [1, 0], [2, 0], [3, 0], [4, 0]]
    assert metres_per_move(pos, [0, 0, 1, 1, 2]) == pytest.approx(2.0)
    assert metres_per_move(pos, [0, 0, 0, 0, 0]) == pytest.approx(4.0)


def test_zero_likelihood_gives_no_nan():
    t = chain_model(3, eps=0.0)
    ll = np.array([[0.0, -np.inf, -np.inf], [-np.inf, -np.inf, 0.0], [-np.inf] * 3, [0.0, 0.0, 0.0]])
    res = run_filter(ll, t)
    assert not np.any(np.isnan(res.log_posterior))
    assert np.allclose(np.exp(logsumexp(res.log_posterior, axis=1)), 1)
    # step 1: place 2 is unreachable from 0 in one step and the only one possible -> observation ignored
    assert np.allclose(np.exp(res.log_posterior[1]), [0.5, 0.5, 0])
    assert np.all(np.isfinite(res.entropy_bits))


def test_bad_rows_rejected():
    f = MarkovFilter(chain_model(3))
    with pytest.raises(InvalidParameterError, match="3 entries"):
        f.update([0.0, 0.0])
    with pytest.raises(InvalidParameterError, match="NaN"):
        f.update([0.0, np.nan, 0.0])
    with pytest.raises(InvalidParameterError, match="uniform_mix"):
        TransitionModel(stay=[0.5], move=[[1.0]], uniform_mix=1.0)
    with pytest.raises(InvalidParameterError, match="rows summing to 1"):
        TransitionModel(stay=[0.5, 0.5], move=[[0.0, 0.5], [1.0, 0.0]])


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    p=st.integers(1, 8),
    n=st.integers(1, 12),
    eps=st.floats(0.0, 0.5),
    odo=st.booleans(),
)
def test_sums_to_one_every_step(seed, p, n, eps, odo):
    rng = np.random.default_rng(seed)
    ll = rng.normal(size=(n, p)) * 20
    ll[rng.random((n, p)) < 0.3] = -np.inf
    ll[rng.random(n) < 0.2] = np.nan
    t = chain_model(p, stay=float(rng.random()), eps=eps, metres=1.0 if odo else None)
    res = run_filter(ll, t, distances=rng.random(n) * 3)
    assert not np.any(np.isnan(res.log_posterior))
    assert np.allclose(np.exp(logsumexp(res.log_posterior, axis=1)), 1.0)
    assert np.all(res.entropy_bits >= 0) and np.all(res.entropy_bits <= math.log2(p) + 1e-9)


def test_entropy_bits():
    assert entropy_bits(np.log([0.5, 0.5])) == pytest.approx(1.0)
    assert entropy_bits([0.0, -np.inf]) == pytest.approx(0.0)


def test_fit_likelihood_scale_recovers_a_temperature():
    rng = np.random.default_rng(3)
    logits = rng.normal(size=(4000, 6)) * 2
    probs = np.exp(logits - logsumexp(logits, axis=1, keepdims=True))
    y = np.array([rng.choice(6, p=row) for row in probs])
    assert fit_likelihood_scale(logits / 3, y) == pytest.approx(3.0, rel=0.1)
    with pytest.raises(InvalidParameterError, match="at least one row"):
        fit_likelihood_scale([[0.0, -np.inf]], [1])


def test_recovers_from_a_kidnapping_on_a_chain():
    """20 places on a line, a noisy sensor that favours the true place; kidnapped from 5 to 15."""
    rng = np.random.default_rng(4)
    p = 20
    path = [min(k // 3, 9) for k in range(30)]  # walk 0 -> 9, three steps per place
    path += [15 + min(k // 3, 4) for k in range(30)]  # kidnapped: continue from 15
    truth = np.array(path)
    ll = rng.normal(0.0, 1.0, size=(truth.size, p))
    ll[np.arange(truth.size), truth] += 2.0  # right place ~2 sigma above the others
    g = PlaceGraph.from_sequence([str(i) for i in range(p)], [str(i) for i in np.repeat(np.arange(p), 3)])
    t = TransitionModel.from_graph(g)
    res = run_filter(ll, t)
    single = np.argmax(ll, axis=1)
    assert np.mean(res.best[6:30] == truth[6:30]) >= 0.8 > np.mean(single[6:30] == truth[6:30]) + 0.2
    # recovered: the best place is the true one from then on (up to one lag step at each place change)
    right = res.best[30:] == truth[30:]
    recovered = next(k for k in range(30) if np.mean(right[k:]) >= 0.8)
    assert recovered <= 10, (recovered, res.best[30:], truth[30:])


def test_cached_odometry_matrix_equals_expm():
    g = PlaceGraph.from_sequence([str(i) for i in range(6)], list("0011223344553322110"))
    t = TransitionModel.from_graph(g, metres_per_move=2.0)
    f = MarkovFilter(t)
    for d in (0.0, 0.3, 1.0, 7.5):
        assert np.allclose(f.transition_matrix(d), t.matrix(d), atol=1e-10)
    assert np.allclose(f.transition_matrix(None), t.matrix())
    with pytest.raises(InvalidParameterError, match="distance"):
        f.transition_matrix(-1.0)


def test_large_map_vector_prediction_equals_matrix():
    p = 130  # above EIG_VECTOR_MIN_PLACES: the belief vector is propagated directly
    g = PlaceGraph.from_sequence([str(i) for i in range(p)], [str(i) for i in np.repeat(np.arange(p), 2)])
    t = TransitionModel.from_graph(g, metres_per_move=1.5)
    rng = np.random.default_rng(5)
    ll = rng.normal(size=(6, p)) * 3
    dist = [0.0, 0.5, 2.0, 0.0, 4.0, 1.0]
    fast = run_filter(ll, t, distances=dist).log_posterior
    slow = MarkovFilter(t)
    for k in range(6):
        if k:
            b = slow.log_belief_
            slow.log_belief_ = np.log(np.exp(b) @ t.matrix(dist[k]))
        slow.update(ll[k])
        assert np.allclose(fast[k], slow.log_belief_, atol=1e-8)


def test_sparse_series_prediction_equals_expm_on_a_branching_graph():
    # a corridor with side branches, 150 places: the move matrix is sparse, the prediction sums its powers
    p = 150
    seq = [str(i) for i in range(100)] + [str(i) for i in range(40, 0, -1)] + [str(i) for i in range(100, p)]
    g = PlaceGraph.from_sequence([str(i) for i in range(p)], seq)
    t = TransitionModel.from_graph(g, metres_per_move=1.2)
    rng = np.random.default_rng(11)
    b = rng.dirichlet(np.full(p, 0.3))
    for d in (0.0, 0.05, 0.7, 6.0, 30.0, 90.0):  # 90 m: 75 expected changes, past the series' range
        f = MarkovFilter(t, prior=b)
        got = f.predict(d)
        want = np.log(b @ t.matrix(d))
        assert np.allclose(got, want - np.logaddexp.reduce(want), atol=1e-9), d
