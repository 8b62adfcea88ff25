"""The place filter with a good single shot: the graph's chain lags a place behind at every place change;
the metric kernel over the places' positions follows the views (TransitionModel.from_positions), and
check_place_filter tells which to answer from the mapping part."""

from __future__ import annotations

import numpy as np
import pytest

from fingerloc.errors import FingerlocError
from fingerloc.map.filter import (
    MarkovFilter,
    SharedPlaceSteps,
    TransitionModel,
    check_place_filter,
    run_filter,
)
from fingerloc.map.graph import PlaceGraph
from fingerloc.pipeline.calibration import step_distances
from tests._paths import polyline, truth_places

_CENTRES = np.column_stack([np.arange(0.0, 40.0, 2.0), np.zeros(20)])  # a corridor, a place every 2 m


def _drive(step, seed):
    """The robot drives the corridor at ``step`` metres per scan; rows: right but unsure near a place's edge.

    At each scan the true place gets log-likelihood 0, its neighbours ``-0.4`` (``-0.1`` for the neighbour the
    robot is nearest to when it is more than 0.6 m from the centre: a view of the boundary), others ``-3``,
    plus a little noise: the single shot is right at every scan (as the verified front end nearly is).
    """
    rng = np.random.default_rng(seed)
    poses = polyline([(0.0, 0.0), (38.0, 0.0)], step)
    truth = truth_places(poses, _CENTRES, radius=1.0)
    ll = np.full((truth.size, 20), np.nan)
    for t in np.flatnonzero(truth >= 0):
        j = truth[t]
        row = np.full(20, -3.0)
        row[max(j - 1, 0) : j + 2] = -0.4
        off = poses[t, 0] - _CENTRES[j, 0]
        if abs(off) > 0.6:
            row[min(max(j + int(np.sign(off)), 0), 19)] = -0.1
        row[j] = 0.0
        ll[t] = row + 0.02 * rng.standard_normal(20)
    return poses, truth, ll


def _graph_model(metres_per_move=2.5):
    places = [str(j) for j in range(20)]
    seq = [places[j] for j in np.repeat(np.arange(20), 4)]  # a mapping pass: 4 scans a place, in order
    return TransitionModel.from_graph(PlaceGraph.from_sequence(places, seq), metres_per_move=metres_per_move)


def test_the_graph_chain_lags_at_place_changes_and_the_metric_kernel_does_not():
    poses, truth, ll = _drive(0.5, 0)
    dist = step_distances(poses[:, :2])
    q = truth >= 0
    single = np.mean(np.argmax(ll[q], axis=1) == truth[q])
    graph = np.mean(run_filter(ll, _graph_model(), distances=dist).best[q] == truth[q])
    eps = _graph_model().uniform_mix
    metric = np.mean(run_filter(ll, TransitionModel.from_positions(_CENTRES, 2.0, uniform_mix=eps), distances=dist).best[q] == truth[q])
    assert single == 1.0
    assert graph < single - 0.1  # the failure: a place behind after each change
    assert metric >= single - 1e-12


def test_check_place_filter_steps_aside_when_the_filter_loses():
    poses, truth, ll = _drive(0.5, 1)
    dist = step_distances(poses[:, :2])
    chk = check_place_filter(ll, _graph_model(), truth, distances=dist)
    assert not chk.use_filter and chk.filter_top1 < chk.single_top1 and chk.rows == int((truth >= 0).sum())
    assert "single shot" in chk.reason()
    chk2 = check_place_filter(ll, TransitionModel.from_positions(_CENTRES, 2.0), truth, distances=dist)
    assert chk2.use_filter and "filtering" in chk2.reason()
    with pytest.raises(FingerlocError):  # a scored step must be observed
        check_place_filter(np.full((2, 20), np.nan), _graph_model(), [0, -1])


def test_metric_kernel_by_hand():
    c = np.array([[0.0, 0.0], [2.0, 0.0], [6.0, 0.0]])
    tm = TransitionModel.from_positions(c, 2.0, uniform_mix=0.03)
    assert tm.metric
    for d in (0.0, 1.0, 5.0):
        k = np.exp(-0.5 * np.array([[0, 4, 36], [4, 0, 16], [36, 16, 0]]) / (2.0 + d) ** 2)
        expect = 0.97 * k / k.sum(axis=1, keepdims=True) + 0.01
        assert np.allclose(tm.matrix(d), expect)
        assert np.allclose(MarkovFilter(tm).transition_matrix(d), expect)
    assert np.allclose(tm.matrix(None), tm.matrix(0.0))
    assert tm.matrix(10.0)[0, 2] > tm.matrix(0.0)[0, 2]  # a longer drive reaches farther places


def test_metric_kernel_validation_and_replay():
    with pytest.raises(FingerlocError):
        TransitionModel.from_positions(np.zeros((0, 2)), 2.0)
    with pytest.raises(FingerlocError):
        TransitionModel.from_positions(np.zeros((2, 2)), -1.0)
    tm = TransitionModel.from_positions(_CENTRES, 2.0)
    with pytest.raises(FingerlocError):  # centres and spread go together
        TransitionModel(tm.stay, tm.move, centres=_CENTRES)
    row = -0.5 * (np.arange(20) - 7.0) ** 2
    shared = SharedPlaceSteps()
    a = shared.filter(tm)
    b = shared.filter(TransitionModel.from_positions(_CENTRES, 3.0))  # another kernel: computes its own
    for f in (a, b):
        f.reset()
        f.update(row)
        f.predict(1.0)
    assert not np.allclose(a.log_belief_, b.log_belief_)
    assert np.allclose(b.log_belief_, _fresh(TransitionModel.from_positions(_CENTRES, 3.0), row))
    c = shared.filter(TransitionModel.from_positions(_CENTRES, 2.0))  # the same kernel: replays a's steps
    c.reset()
    c.update(row)
    assert np.array_equal(c.predict(1.0), a.log_belief_)


def _fresh(tm, row):
    f = MarkovFilter(tm)
    f.update(row)
    return f.predict(1.0)
