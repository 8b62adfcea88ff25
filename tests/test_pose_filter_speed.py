"""The pose filter's compiled nearest centre and fast logsumexp change no result."""

import math

import numpy as np
from scipy.spatial import cKDTree

from fingerloc.map import pose_filter as pf
from fingerloc.map._nearest import CentreGrid, nearest_centres
from fingerloc.map.driver import run_pose_filter
from fingerloc.map.filter import MarkovFilter, TransitionModel
from fingerloc.map.graph import PlaceGraph
from fingerloc.map.motion import simulate_odometry
from fingerloc.map.pose_filter import PoseFilter, observation_weights


def test_nearest_equals_the_tree():
    rng = np.random.default_rng(1)
    for t in range(30):
        c = rng.uniform(-30, 30, (int(rng.integers(1, 150)), 2))
        xy = rng.uniform(-35, 35, (int(rng.integers(0, 3000)), 2))
        if t % 3 == 0 and xy.shape[0] >= 50:
            xy[:50] = c[rng.integers(0, len(c), 50)]  # particles exactly on a centre
        d0, j0 = cKDTree(c).query(xy)
        d1, j1 = nearest_centres(xy, c)
        assert np.asarray(d0, dtype=np.float64).tobytes() == d1.tobytes()
        np.testing.assert_array_equal(np.asarray(j0), j1)
    d, j = nearest_centres(np.zeros((3, 2)), np.zeros((0, 2)))
    assert np.all(np.isinf(d)) and j.tolist() == [0, 0, 0]
    c = np.array([[0.0, 0.0], [2.0, 0.0]])
    assert nearest_centres(np.array([[1.0, 0.0]]), c)[1].tolist() == [0]  # an exact tie: the lower index


def _tree_nearest(self, xy):
    d, j = self._tree.query(xy)
    return np.asarray(d, dtype=np.float64), np.asarray(j, dtype=np.int64)


def _run(n_places):
    """A corridor there and back, a noisy sensor, simulated odometry, the place filter alongside."""
    spacing = 2.0
    xs = np.linspace(0, (n_places - 1) * spacing, (n_places - 1) * 3 + 1)
    poses = np.vstack([np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)]),
                       np.column_stack([xs[::-1], np.zeros_like(xs), np.full_like(xs, math.pi - 1e-9)])])  # fmt: skip
    centres = np.column_stack([np.arange(n_places) * spacing, np.zeros(n_places)])
    dist = np.linalg.norm(poses[:, None, :2] - centres[None], axis=2)
    truth = np.argmin(dist, axis=1)
    truth[dist[np.arange(truth.size), truth] > 0.5] = -1
    rng = np.random.default_rng(4)
    q = truth >= 0
    ll = np.full((truth.size, n_places), np.nan)
    ll[q] = rng.normal(size=(int(q.sum()), n_places))
    ll[np.flatnonzero(q), truth[q]] += 1.0
    inc = simulate_odometry(poses, random_state=2)
    g = PlaceGraph.from_sequence([str(i) for i in range(n_places)], [str(i) for i in truth[q]])
    f = PoseFilter(centres, 0.5, n_particles=1000, kidnap=0.02, random_state=1)
    return run_pose_filter(ll, inc, f, weights=observation_weights(inc, q, metres=2.0),
                           place_filter=MarkovFilter(TransitionModel.from_graph(g, metres_per_move=2.0)),
                           start_at_first_observation=True).log_posterior  # fmt: skip


def test_pose_filter_run_is_the_same_with_the_tree_and_scipy(monkeypatch):
    fast = _run(12)
    monkeypatch.setattr(pf.PoseFilter, "_nearest", _tree_nearest)
    from scipy.special import logsumexp

    monkeypatch.setattr(pf, "logsumexp", logsumexp)  # SciPy's own, the reference
    slow = _run(12)
    assert fast.tobytes() == slow.tobytes()
    assert np.all(np.isfinite(fast[~np.all(np.isnan(fast), axis=1)]).any(axis=1))


def test_many_places_give_the_tree_answer():
    rng = np.random.default_rng(2)
    c = rng.uniform(-100, 100, (300, 2))
    f = PoseFilter(c, 1.0, n_particles=500, random_state=0)
    d, j = f._nearest(f.particles_[:, :2])
    d0, j0 = _tree_nearest(f, f.particles_[:, :2])
    assert d.tobytes() == d0.tobytes() and np.array_equal(j, j0)


def test_centre_grid_equals_the_brute_force():
    rng = np.random.default_rng(5)
    for t in range(60):
        n_c = int(rng.integers(1, 400))
        c = rng.uniform(-50, 50, (n_c, 2))
        if t % 5 == 0:
            c *= rng.uniform(0, 1, 2)  # a flat or tiny box
        if t % 7 == 0:
            c[:, 1] = 3.0  # every centre on one line
        if t % 11 == 0:
            c = np.round(c / 10.0) * 10.0  # repeated centres and exact ties
        xy = rng.uniform(-70, 70, (int(rng.integers(0, 2000)), 2))  # some off the grid
        if xy.shape[0] >= 50:
            xy[:50] = c[rng.integers(0, n_c, 50)]  # points exactly on a centre
        d, j = CentreGrid(c).nearest(xy)
        d0, j0 = nearest_centres(xy, c)
        assert d.tobytes() == d0.tobytes()
        np.testing.assert_array_equal(j, j0)
    g = CentreGrid(np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0]]))
    assert g.nearest(np.array([[1.0, 0.0], [1.0, 1.0], [0.4, 1.9]]))[1].tolist() == [0, 0, 2]  # ties: the lower index


def test_centre_grid_cells_list_few_candidates_on_a_spread_map():
    rng = np.random.default_rng(6)
    c = rng.uniform(0, 300, (1000, 2))
    g = CentreGrid(c)
    assert g.cand.size / (g.shape[0] * g.shape[1]) < 20  # not every centre in every cell


def test_centre_grid_mass_within_equals_the_tree_ball_query():
    rng = np.random.default_rng(7)
    for t in range(80):
        n_c = int(rng.integers(1, 600))
        c = rng.uniform(-50, 50, (n_c, 2))
        mid = (np.floor(rng.uniform(-60, 60, (int(rng.integers(1, 300)), 2)) / 0.5) + 0.5) * 0.5
        reach = float(rng.uniform(0.1, 8.0))
        if t % 4 == 0:  # centres exactly at the reach of a point
            c, mid, reach = np.round(c), np.round(mid), 2.0
        w = rng.integers(1, 30, mid.shape[0]).astype(np.float64)
        near = cKDTree(c).query_ball_point(mid, reach)
        found = np.array([j for js in near for j in js], dtype=np.int64)
        expected = np.bincount(found, weights=np.repeat(w, [len(js) for js in near]), minlength=n_c)
        assert CentreGrid(c).mass_within(mid, w, reach).tobytes() == expected.tobytes()
