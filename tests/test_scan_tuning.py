"""The scan evidence's power chosen on the mapping part: fold maps, tuning, shared draws.

A synthetic corridor, there and back, with walls whose doors and pillars
differ from place to place: the "fingerprint" rows cannot tell a place from
its neighbours, the end points can.
"""

import math

import numpy as np
import pytest

from fingerloc.config import Config
from fingerloc.map.driver import run_pose_filter
from fingerloc.map.graph import PlaceGraph
from fingerloc.map.heading import HeadingModel
from fingerloc.map.motion import simulate_odometry
from fingerloc.map.pose_filter import PoseFilter
from fingerloc.map.scan_map import ScanMap
from fingerloc.pipeline.calibrate import fold_scan_maps, scan_folds, tune_pose_filter
from fingerloc.pipeline.calibration import Calibration, HeldOut, step_distances
from fingerloc.pipeline.filters import pose_filter_of, pose_tracking, transition_of

SPACING = 2.0
SCAN_GAMMAS = Config().calibration.scan_gammas


def _cfg(n_particles: int, **calibration: object) -> Config:
    return Config().with_(pose_filter={"n_particles": n_particles}, calibration=calibration)


def _world(n_places, rng):
    """Wall points of a corridor about 2.4 m wide whose walls step in and out (alcoves, doors), and a few
    pillars (mapping frame): no two stretches alike."""
    x = np.arange(-3.0, (n_places - 1) * SPACING + 3.0, 0.1)
    pts = []
    for side in (-1.0, 1.0):
        cuts = np.sort(rng.uniform(x[0], x[-1], size=3 * n_places))
        depth = rng.choice([0.0, 0.4, 0.8], size=cuts.size + 1)[np.searchsorted(cuts, x)]
        pts.append(np.column_stack([x, side * (1.2 + depth)]))
        for c in cuts:  # the step's side wall
            pts.append(np.column_stack([np.full(9, c), side * (1.2 + np.linspace(0, 0.8, 9))]))
    pillars = np.column_stack([rng.uniform(x[0], x[-1], n_places // 2), rng.choice([-0.9, 0.9], n_places // 2)])
    return np.vstack([*pts, pillars])


def _scan(world, pose, rng, unique=None):
    """End points (robot frame) of the world points within 5 m, with 2 cm noise; ``unique`` added in the world frame."""
    w = world if unique is None else np.vstack([world, unique])
    near = np.hypot(w[:, 0] - pose[0], w[:, 1] - pose[1]) < 5.0
    d = w[near] - pose[:2]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    local = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
    return local[::2] + 0.02 * rng.standard_normal((local[::2].shape[0], 2))


def _rows(labels, n_places, rng, ambiguous=True):
    """Fingerprint rows: noise, and +2 at the true place and (ambiguous) at the next one."""
    ll = 0.8 * rng.standard_normal((labels.size, n_places))
    for k, j in enumerate(labels.tolist()):
        for nb in (j, j + 1) if ambiguous else (j,):
            if 0 <= nb < n_places:
                ll[k, nb] += 2.0
    return ll


def _corridor(n_places, seed, ambiguous=True):
    """Poses there and back, place truth, ambiguous rows (the true place and the next one score alike), scans."""
    rng = np.random.default_rng(seed)
    xs = np.linspace(0, (n_places - 1) * SPACING, (n_places - 1) * 4 + 1)
    out = np.column_stack([xs, 0.1 * np.sin(xs), np.zeros_like(xs)])
    back = np.column_stack([xs[::-1], 0.1 * np.cos(xs[::-1]), np.full_like(xs, math.pi - 1e-9)])
    poses = np.vstack([out, back])
    centres = np.column_stack([np.arange(n_places) * SPACING, np.zeros(n_places)])
    dist = np.linalg.norm(poses[:, None, :2] - centres[None], axis=2)
    truth = np.argmin(dist, axis=1)
    truth[dist[np.arange(truth.size), truth] > 0.7] = -1
    rows = np.flatnonzero(truth >= 0)
    ll = _rows(truth[rows], n_places, rng, ambiguous)
    world = _world(n_places, np.random.default_rng(seed + 1000))  # the same walls for every run of this seed
    points = [_scan(world, p, rng) for p in poses]
    g = PlaceGraph.from_sequence([str(i) for i in range(n_places)], [str(i) for i in truth[rows]])
    return poses, centres, truth, rows, ll, points, g


def _tuning_inputs(n_places=9, seed=0):
    poses, centres, truth, rows, ll, points, g = _corridor(n_places, seed)
    labels = truth[rows]
    held = HeldOut(beta=1.0, rows=rows.size, scores=ll, labels=labels, index=np.arange(rows.size))
    sfold = scan_folds(rows, labels)
    travel = np.cumsum(step_distances(poses[:, :2]))[rows]
    maps = fold_scan_maps([points[i] for i in rows], poses[rows], sfold, travel=travel)
    return poses, centres, truth, rows, held, points, g, sfold, maps


def test_scan_folds_alternate_visits_in_time_order():
    idx = np.array([3, 4, 5, 9, 10, 11, 12, 20, 21])
    lab = np.array([0, 0, 1, 1, 1, 2, 2, 0, 0])
    assert scan_folds(idx, lab).tolist() == [0, 0, 1, 0, 0, 1, 1, 0, 0]


@pytest.mark.parametrize("along_run", [True, False])
def test_fold_maps_never_hold_a_held_out_rows_own_end_points(along_run):
    rng = np.random.default_rng(1)
    poses, _, truth, rows, *_ = _corridor(7, 1)
    labels = truth[rows]
    # every row sees, besides the walls, one point nobody else sees (100 m away from the corridor, its own spot)
    marks = np.column_stack([rows * 3.0, np.full(rows.size, 100.0)])
    world = _world(7, rng)
    pts = [_scan(world, poses[i], rng) for i in rows]
    pts = [np.vstack([p, _to_robot(marks[k], poses[i])]) for k, (p, i) in enumerate(zip(pts, rows, strict=True))]
    fold = scan_folds(rows, labels)
    travel = np.cumsum(step_distances(poses[:, :2]))[rows] if along_run else None
    maps = fold_scan_maps(pts, poses[rows], fold, travel=travel)
    hit = maps[0].log_likelihood(np.zeros((1, 3)), np.zeros((1, 2)))  # a point far from everything: the floor
    for k, i in enumerate(rows.tolist()):
        own = maps[fold[k]].log_likelihood(poses[i : i + 1], _to_robot(marks[k], poses[i]))[0]
        assert own == pytest.approx(maps[fold[k]].outside), (k, own)  # never mapped in its own fold's map
    # and the other fold's map does hold some of them (the test can fail): rows kept by the guard
    other = [maps[1 - fold[k]].log_likelihood(poses[i : i + 1], _to_robot(marks[k], poses[i]))[0] for k, i in enumerate(rows.tolist())]
    assert max(other) > hit[0] + 1.0


def _to_robot(world_point, pose):
    d = np.asarray(world_point, dtype=np.float64).reshape(-1, 2) - pose[:2]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def test_fold_map_guard_leaves_out_the_same_pass_neighbours():
    poses, _, truth, rows, *_ = _corridor(7, 2)
    labels = truth[rows]
    fold = scan_folds(rows, labels)
    travel = np.cumsum(step_distances(poses[:, :2]))[rows]
    # one end point per scan, right at its own position: the map is the set of scan positions
    pts = [np.zeros((1, 2)) for _ in rows]
    for guard in (0.0, 1.5):  # visits 1 m apart along the run here
        maps = fold_scan_maps(pts, poses[rows], fold, travel=travel, guard=guard)
        for f in (0, 1):
            mine = np.flatnonzero(fold == f)
            others = np.flatnonzero(fold != f)
            near = np.min(np.abs(travel[others, None] - travel[None, mine]), axis=1) <= guard
            at = maps[f].log_likelihood(poses[rows[others]], np.zeros((1, 2)))
            top = math.log(1.0 + maps[f].floor)
            assert np.all(np.isclose(at[~near], top))  # kept
            if guard > 0:
                assert near.any() and np.all(at[near] < top - 1e-9)  # left out (only their neighbours are near)


def test_tuning_without_scan_points_is_the_former_tuning():
    poses, centres, _truth, rows, held, points, g, sfold, maps = _tuning_inputs(7, 3)
    cal = Calibration(radius=0.6, kidnap=0.01, scan_gamma=2.0)
    cfg = _cfg(300)
    a, tried_a = tune_pose_filter(cal, cfg, centres, g, held, rows, poses, odometry_error=1.0, seed=3)
    assert a.scan_gamma == 0.0 and all("scan_gamma" not in t for t in tried_a)
    # the tuning without the scan evidence gives these on the same inputs (pinned: the grid's runs must not move)
    former = [37 / 38, 1.0, 34 / 38, 36 / 38, 37 / 38, 29 / 38, 37 / 38, 1.0, 34 / 38]
    assert [t["top1"] for t in tried_a] == former
    assert (a.outlier, a.temper_metres) == (0.1, 1.0)
    b, tried_b = tune_pose_filter(cal, cfg, centres, g, held, rows, poses, odometry_error=1.0, seed=3,
                                  scan_points=[points[i] for i in rows])  # fmt: skip
    assert (b, tried_b) == (a, tried_a)  # points without maps: ignored
    # with the scan evidence the grid's first runs are the same runs (gamma 0), then one per power
    _c, tried_c = tune_pose_filter(cal, cfg, centres, g, held, rows, poses, odometry_error=1.0, seed=3,
                                  scan_points=[points[i] for i in rows], scan_maps=maps, scan_fold=sfold)  # fmt: skip
    assert [t["top1"] for t in tried_c[: len(former)]] == former
    assert [t["scan_gamma"] for t in tried_c[len(former) :]] == list(SCAN_GAMMAS)


def test_run_without_scan_maps_is_bit_identical():
    poses, centres, truth, rows, held, points, _g, _sfold, maps = _tuning_inputs(6, 4)
    n = poses.shape[0]
    ll = np.full((n, centres.shape[0]), np.nan)
    ll[rows] = held.scores
    inc = simulate_odometry(poses, random_state=1)
    pts = [points[i] if truth[i] >= 0 else None for i in range(n)]

    def run(**kw):
        f = PoseFilter(centres, 0.6, n_particles=200, kidnap=0.01, scan_map=maps[0], scan_gamma=2.0, random_state=5)
        return run_pose_filter(ll, inc, f, points=pts, **kw).log_posterior.tobytes()

    base = run()
    assert run(scan_maps=[None] * n) == base
    assert run(scan_maps=[maps[0]] * n) == base
    assert run(scan_maps=[maps[1]] * n) != base  # the override is used


def _headings(poses, rows, n_places, rng):
    """The heading each row implies at every place: its own, give or take 0.03 rad (the fingerprint's alignment)."""
    return poses[rows, 2:3] + 0.03 * rng.standard_normal((rows.size, n_places))


HEADING = {"heading": HeadingModel(kappa=400.0, intercept=1.0, cap=0.9), "heading_temper_metres": 3.0}


def test_scan_evidence_is_chosen_and_helps_where_the_fingerprint_is_ambiguous():
    poses, centres, truth, rows, held, points, g, sfold, maps = _tuning_inputs(9, 0)
    # the fingerprint's implied headings let fresh particles face the right way (without them 400 particles
    # at random headings rarely fit a scan, on the shared logs as here)
    cal = Calibration(radius=0.6, kidnap=0.01, metres_per_move=SPACING, **HEADING)
    cfg = _cfg(1500)
    kw = {"odometry_error": 1.0, "seed": 2, "headings": _headings(poses, rows, 9, np.random.default_rng(3))}
    without, _ = tune_pose_filter(cal, cfg, centres, g, held, rows, poses, **kw)
    chosen, tried = tune_pose_filter(cal, cfg, centres, g, held, rows, poses, scan_points=[points[i] for i in rows],
                                     scan_maps=maps, scan_fold=sfold, **kw)  # fmt: skip
    assert chosen.scan_gamma > 0, tried
    # later runs along the same corridor (other sensor noise and odometry): the query-time map is the whole first run
    world = _world(9, np.random.default_rng(1000))  # _corridor(9, 0)'s
    full_map = ScanMap.from_scans(points, poses)
    n = poses.shape[0]
    q = np.flatnonzero(truth >= 0)
    top1 = {"without": [], "with": []}
    for run in range(5):
        rng = np.random.default_rng(100 + run)
        ll = np.full((n, centres.shape[0]), np.nan)
        ll[q] = _rows(truth[q], 9, rng)
        hd = np.full(ll.shape, np.nan)
        hd[q] = _headings(poses, q, 9, rng)
        pts = [_scan(world, poses[i], rng) if truth[i] >= 0 else None for i in range(n)]
        inc = np.vstack([np.zeros((1, 3)), simulate_odometry(poses, random_state=200 + run)])
        for name, c in (("without", without), ("with", chosen)):
            drv = pose_tracking(pose_filter_of(centres, c, cfg, seed=run, scan_map=full_map), transition_of(g, c, cfg), c, cfg)
            res = run_pose_filter(c.beta * ll, inc, drv, headings=hd, points=pts)
            top1[name].append(float(np.mean(res.best[q] == truth[q])))
    assert np.mean(top1["with"]) >= np.mean(top1["without"]) + 0.05, top1
    assert min(top1["with"]) >= 0.9, (top1, chosen.scan_gamma)


@pytest.mark.parametrize("starts", [1, 3])
def test_tuning_with_scan_evidence_shares_draws_exactly(starts):
    poses, centres, _truth, rows, held, points, g, sfold, maps = _tuning_inputs(7, 5)
    cal = Calibration(radius=0.6, kidnap=0.05)
    kw = {"odometry_error": 1.0, "seed": 3, "scan_points": [points[i] for i in rows], "scan_maps": maps, "scan_fold": sfold}
    a = tune_pose_filter(cal, _cfg(300, scan_starts=starts), centres, g, held, rows, poses, **kw)
    b = tune_pose_filter(cal, _cfg(300, scan_starts=starts, share_draws=False), centres, g, held, rows, poses, **kw)
    assert a == b
    assert len({t["top1"] for t in a[1] if "scan_gamma" in t}) > 1  # the powers' runs differ


def test_the_lost_rule_pairs_each_fit_with_its_own_rows_answer(monkeypatch):
    """Held-out rows come fold by fold, the filter's fit trace in time order: the lost rule sees them paired in time order."""
    import fingerloc.pipeline.calibrate as calibrate_module

    poses, centres, _truth, rows, held, points, g, sfold, maps = _tuning_inputs(9, 0)
    seen = []
    real = calibrate_module.calibrate_lost

    def spy(fits, right, quantile=None, *, after=1):
        seen.append((np.asarray(fits, dtype=np.float64).copy(), np.asarray(right, dtype=bool).copy()))
        return real(fits, right, quantile, after=after)

    monkeypatch.setattr(calibrate_module, "calibrate_lost", spy)
    cal = Calibration(radius=0.6, kidnap=0.01, metres_per_move=SPACING, **HEADING)
    cfg = _cfg(1500)
    hd = _headings(poses, rows, 9, np.random.default_rng(3))
    labels = held.labels.copy()
    labels[::7] = (labels[::7] + 4) % 9  # rows whose "truth" is another place: answers there count as wrong
    held = HeldOut(beta=1.0, rows=rows.size, scores=held.scores, labels=labels, index=held.index)
    order = np.concatenate([np.flatnonzero(sfold == 0), np.flatnonzero(sfold == 1)])  # the folds' order, as held-out rows come
    assert not np.all(np.diff(rows[order]) > 0)
    fold_held = HeldOut(beta=1.0, rows=rows.size, scores=held.scores[order], labels=held.labels[order], index=order)
    kw = {"odometry_error": 1.0, "seed": 2, "scan_maps": maps, "scan_fold": sfold}
    a, _ = tune_pose_filter(cal, cfg, centres, g, held, rows, poses, headings=hd, scan_points=[points[i] for i in rows], **kw)
    b, _ = tune_pose_filter(cal, cfg, centres, g, fold_held, rows, poses, headings=hd[order],
                            scan_points=[points[i] for i in rows[order]], **kw)  # fmt: skip
    assert len(seen) == 2 and a.scan_gamma == b.scan_gamma > 0
    np.testing.assert_array_equal(seen[0][1], seen[1][1])  # the same right / wrong sequence either way
    assert np.array_equal(seen[0][0], seen[1][0], equal_nan=True)
    assert (a.lost_fit, a.lost_kidnap) == (b.lost_fit, b.lost_kidnap)
    assert 0 < int(np.sum(~seen[0][1])), "every answer right: the pairing would not show"
