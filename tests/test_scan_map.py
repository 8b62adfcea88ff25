"""The likelihood field of mapped laser end points (fingerloc.map.scan_map) and the pose filter's scan evidence."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from fingerloc.errors import FingerlocError
from fingerloc.map.driver import run_pose_filter
from fingerloc.map.motion import wheel_odometry
from fingerloc.map.pose_filter import PoseFilter
from fingerloc.map.scan_map import SCAN_MAX_CELLS, ScanMap, scan_points
from tests._paths import polyline, truth_places


def _oracle(smap: ScanMap, poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Brute force: each end point's cell, its distance to the nearest occupied cell (a k-d tree over the
    cells, not the distance transform), clipped, through the end-point model, averaged."""
    tree = cKDTree(smap.cells.astype(float))
    out = []
    for x, y, th in poses:
        c, s = math.cos(th), math.sin(th)
        wx = x + c * points[:, 0] - s * points[:, 1]
        wy = y + s * points[:, 0] + c * points[:, 1]
        g = np.floor((np.column_stack([wx, wy]) - smap.origin) / smap.resolution)
        inside = np.all((g >= 0) & (g < np.array(smap.shape)), axis=1)
        d = np.full(g.shape[0], smap.clip)
        if inside.any():
            dd, _ = tree.query(g[inside])
            d[inside] = np.minimum(dd * smap.resolution, smap.clip)
        out.append(np.mean(np.log(np.exp(-0.5 * (d / smap.sigma) ** 2) + smap.floor)))
    return np.array(out)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_log_likelihood_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-5, 5, (int(rng.integers(1, 60)), 2))
    smap = ScanMap.from_points(pts, resolution=float(rng.choice([0.05, 0.1, 0.25])))
    poses = np.column_stack([rng.uniform(-8, 8, (20, 2)), rng.uniform(-math.pi, math.pi, 20)])
    q = rng.uniform(-6, 6, (int(rng.integers(1, 30)), 2))
    np.testing.assert_allclose(smap.log_likelihood(poses, q), _oracle(smap, poses, q), rtol=1e-6, atol=1e-6)  # a float32 table


def test_the_true_pose_scores_best():
    rng = np.random.default_rng(0)
    world = rng.uniform(-6, 6, (300, 2))
    pose = np.array([0.3, -0.2, 0.7])
    c, s = math.cos(pose[2]), math.sin(pose[2])
    rel = world - pose[:2]
    robot = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]])
    smap = ScanMap.from_points(world, resolution=0.05)
    near = pose + np.array([[0, 0, 0], [0.3, 0, 0], [0, -0.3, 0], [0, 0, 0.1]])
    ll = smap.log_likelihood(near, robot)
    assert np.argmax(ll) == 0
    assert ll[0] > ll[1:].max() + 0.5


def test_scan_points_by_hand():
    r = np.array([1.0, np.inf, 2.0, 0.0, 30.0])
    b = np.array([0.0, 0.5, math.pi / 2, 1.0, -math.pi / 2])
    np.testing.assert_allclose(scan_points(r, b, stride=1, max_range=25.0), [[1, 0], [0, 2]], atol=1e-12)
    np.testing.assert_allclose(scan_points(r, b, stride=2), [[1, 0], [0, -30]], atol=1e-12)
    # a sensor 0.5 m ahead of the robot, turned by 90 degrees
    np.testing.assert_allclose(scan_points([1.0], [0.0], sensor_offset=(0.5, 0, math.pi / 2)), [[0.5, 1.0]], atol=1e-12)


def test_from_scans_puts_end_points_in_the_mapping_frame():
    smap = ScanMap.from_scans([np.array([[1.0, 0.0]]), np.zeros((0, 2))], [(2.0, 3.0, math.pi / 2), (0, 0, 0)])
    centre = smap.origin + (smap.cells[0] + 0.5) * smap.resolution
    np.testing.assert_allclose(centre, [2.0, 4.0], atol=smap.resolution)
    assert smap.cells.shape == (1, 2)


def test_a_huge_extent_coarsens_the_grid():
    smap = ScanMap.from_points([[0.0, 0.0], [1000.0, 1000.0]])
    assert smap.shape[0] * smap.shape[1] <= SCAN_MAX_CELLS
    assert smap.resolution > 0.1


def test_bad_input():
    with pytest.raises(FingerlocError, match="at least one end point"):
        ScanMap.from_points(np.zeros((0, 2)))
    with pytest.raises(FingerlocError, match="finite"):
        ScanMap.from_points([[0.0, np.nan]])
    with pytest.raises(FingerlocError, match="one pose per scan"):
        ScanMap.from_scans([np.zeros((1, 2))], np.zeros((2, 3)))
    with pytest.raises(FingerlocError, match="origin"):
        ScanMap([0.0], 0.1, (2, 2), np.zeros((0, 2)))
    with pytest.raises(FingerlocError, match="cells must lie"):
        ScanMap([0.0, 0.0], 0.1, (2, 2), [[2, 0]])
    with pytest.raises(FingerlocError, match="same length"):
        scan_points([1.0, 2.0], [0.0])
    with pytest.raises(FingerlocError, match="scan_map"):
        PoseFilter([[0.0, 0.0]], 1.0, scan_map="grid")  # type: ignore[arg-type]
    f = PoseFilter([[0.0, 0.0]], 1.0, scan_map=ScanMap.from_points([[1.0, 1.0]]), scan_gamma=1.0, n_particles=20)
    with pytest.raises(FingerlocError, match="points"):
        f.update([0.0], points=np.zeros((3, 3)))


# ---- the pose filter with scan evidence: a corridor whose places look alike but whose walls do not ----------


def _corridor():
    """End points of a 30 m corridor (walls at y = +-1.5 with door gaps, pillars), mapping frame."""
    rng = np.random.default_rng(5)
    xs = np.arange(0.0, 30.0, 0.05)
    walls = []
    for y, doors in ((1.5, (2, 5, 13, 14.5, 22)), (-1.5, (8, 18.5, 27))):
        keep = np.all(np.abs(xs[:, None] - np.array(doors)[None, :]) > 0.5, axis=1)
        walls.append(np.column_stack([xs[keep], np.full(keep.sum(), y)]))
    pillars = [np.column_stack([x + 0.1 * np.cos(a), y + 0.1 * np.sin(a)])
               for x, y in zip(rng.uniform(1, 29, 6), rng.choice([-1.2, 1.2], 6), strict=True)
               for a in [np.linspace(0, 2 * np.pi, 12)]]  # fmt: skip
    return np.vstack(walls + pillars)


def _scan_at(world, pose, rng):
    """The end points a 180-degree scanner at ``pose`` would see within 8 m (no occlusion), with 2 cm of noise."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    rel = world - pose[:2]
    rob = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]])
    seen = rob[(rob[:, 0] > 0) & (np.hypot(rob[:, 0], rob[:, 1]) < 8.0)][::4]
    return seen + 0.02 * rng.standard_normal(seen.shape)


def _run(gamma, seed):
    world = _corridor()
    poses = polyline([(0.5, 0.0), (29.5, 0.0)], 0.25)
    centres = np.column_stack([np.arange(1.1, 30.0, 2.0), np.zeros(15)])  # no pose midway between two
    truth = truth_places(poses, centres)
    rng = np.random.default_rng(seed)
    points = [_scan_at(world, p, rng) for p in poses]
    # the fingerprint: it knows the neighbourhood, not the place (neighbours nearly as likely), off places nothing
    ll = -0.4 * np.abs(np.arange(centres.shape[0])[None, :] - truth[:, None]) + 0.4 * rng.standard_normal((truth.size, 15))
    ll[truth < 0] = np.nan
    f = PoseFilter(centres, 1.0, n_particles=1500, scan_map=ScanMap.from_points(world, resolution=0.1),
                   scan_gamma=gamma, random_state=seed)  # fmt: skip
    inc = wheel_odometry(poses, 1.0, random_state=seed + 1)
    res = run_pose_filter(ll, inc, f, temper=(1.0, math.pi), start_at_first_observation=True, points=points)
    q = (truth >= 0) & (poses[:, 0] > 10.0)  # once localized: after the first 10 m
    return float(np.mean(res.best[q] == truth[q]))


@pytest.mark.parametrize("seed", [0, 5])
def test_scan_evidence_places_the_robot_where_the_places_look_alike(seed):
    without, with_scan = _run(0.0, seed), _run(3.0, seed)
    assert without < 0.85  # the fingerprint confuses neighbours: the filter errs along the corridor
    assert with_scan >= 0.94  # the walls' door gaps and pillars place it


def test_gamma_zero_or_no_points_changes_nothing_bit_for_bit():
    centres = np.column_stack([np.arange(0.0, 10.0, 2.0), np.zeros(5)])
    smap = ScanMap.from_points(_corridor())
    rows = np.random.default_rng(3).normal(size=(6, 5))
    pts = np.random.default_rng(4).uniform(-3, 3, (40, 2))
    runs = []
    for kw, p in (({}, None), ({"scan_map": smap, "scan_gamma": 0.0}, pts), ({"scan_map": smap, "scan_gamma": 2.0}, None)):
        f = PoseFilter(centres, 1.0, n_particles=200, random_state=7, **kw)
        out = [f.update(r, 0.7, points=p) for r in rows]
        runs.append((np.array(out), f.particles_.copy()))
    for out, parts in runs[1:]:
        assert np.array_equal(out, runs[0][0]) and np.array_equal(parts, runs[0][1])
