"""Two-view geometry on unit bearing vectors: solvers against known poses and against OpenCV."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from fingerloc.errors import InvalidParameterError
from fingerloc.features.sphere import (
    bearing_vectors,
    decompose_essential,
    eight_point,
    epipolar_errors,
    essential_from_pose,
    heading_of_rotation,
    inlier_mask,
    ransac_pose,
    refine_pose,
    rotation_about_z,
    tilt_of_rotation,
    upright_three_point,
)


def _rotation(yaw_deg: float, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll), written out (independent of scipy's conventions)."""
    y, p, r = (math.radians(v) for v in (yaw_deg, pitch_deg, roll_deg))
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    return rz @ ry @ rx


def _scene(rng, n, rot, t, *, noise=0.0, outliers=0.0, front=False):
    """Points around the first camera (all directions, or in front along +z), bearings in both views."""
    x = rng.normal(size=(n, 3)) * np.array([4.0, 4.0, 1.5])
    if front:
        x = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), rng.uniform(4, 8, n)])
    x2 = x @ rot.T + t
    f1 = x / np.linalg.norm(x, axis=1, keepdims=True)
    f2 = x2 / np.linalg.norm(x2, axis=1, keepdims=True)
    if noise:
        f1 = f1 + rng.normal(size=f1.shape) * noise
        f2 = f2 + rng.normal(size=f2.shape) * noise
    k = round(outliers * n)
    if k:
        f2[:k] = rng.normal(size=(k, 3))
    f1 /= np.linalg.norm(f1, axis=1, keepdims=True)
    f2 /= np.linalg.norm(f2, axis=1, keepdims=True)
    return f1, f2, x, x2


def _same_up_to_scale(a: np.ndarray, b: np.ndarray) -> float:
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    return float(min(np.abs(a - b).max(), np.abs(a + b).max()))


def test_bearing_vectors_are_unit_and_follow_the_convention():
    f = bearing_vectors([0.0, math.pi / 2, 0.3], [0.0, 0.0, math.pi / 2])
    assert np.allclose(f[0], [1, 0, 0]) and np.allclose(f[1], [0, 1, 0]) and np.allclose(f[2], [0, 0, 1])
    assert np.allclose(np.linalg.norm(bearing_vectors(np.arange(5.0), np.linspace(-1, 1, 5)), axis=1), 1.0)
    with pytest.raises(InvalidParameterError):
        bearing_vectors([0.0, 1.0], [0.0])


def test_epipolar_error_is_the_angle_out_of_the_epipolar_plane():
    rng = np.random.default_rng(0)
    rot, t = _rotation(30), np.array([1.0, 0.5, 0.0])
    f1, f2, _, _ = _scene(rng, 20, rot, t)
    e = essential_from_pose(rot, t)
    assert np.abs(epipolar_errors(e, f1, f2)).max() < 1e-9
    # move f2 out of the plane (normal E f1) by a known angle: the error from f1's side is that angle
    n = f1 @ e.T
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    delta = 0.01
    g2 = np.cos(delta) * f2 + np.sin(delta) * n
    err = epipolar_errors(e, f1, g2)
    assert np.all(err >= delta - 1e-9) and np.all(err < 3 * delta)


def test_eight_point_recovers_the_essential_matrix_of_a_known_pose():
    rng = np.random.default_rng(1)
    rot, t = _rotation(50, 4, -3), np.array([0.3, -1.0, 0.2])
    f1, f2, _, _ = _scene(rng, 30, rot, t)
    assert _same_up_to_scale(eight_point(f1, f2), essential_from_pose(rot, t)) < 1e-8
    r, tt = decompose_essential(eight_point(f1, f2), f1, f2)
    assert np.allclose(r, rot, atol=1e-8) and np.allclose(tt, t / np.linalg.norm(t), atol=1e-8)


def test_upright_three_point_is_exact_on_level_cameras():
    rng = np.random.default_rng(2)
    rot, t = rotation_about_z(math.radians(-120.0)), np.array([-2.0, 0.7, 0.0])
    f1, f2, _, _ = _scene(rng, 3, rot, t)
    e = upright_three_point(f1, f2)
    assert _same_up_to_scale(e, essential_from_pose(rot, t)) < 1e-8
    r, _ = decompose_essential(e, *_scene(rng, 10, rot, t)[:2])
    assert abs(math.degrees(heading_of_rotation(r)) + 120.0) < 1e-6 and tilt_of_rotation(r) < 1e-6


@pytest.mark.parametrize("yaw", [-170.0, -35.0, 10.0, 95.0])
def test_against_opencv_find_essential_and_recover_pose(yaw):
    """The same pose from OpenCV's five-point RANSAC on normalised image points (cameras looking along +z)."""
    rng = np.random.default_rng(3)
    rot, t = _rotation(yaw / 20.0, yaw / 10.0, 2.0), np.array([1.0, 0.2, 0.1])
    f1, f2, x1, x2 = _scene(rng, 60, rot, t, front=True)
    ok = x2[:, 2] > 0
    f1, f2, x1, x2 = f1[ok], f2[ok], x1[ok], x2[ok]
    p1 = np.ascontiguousarray(x1[:, :2] / x1[:, 2:])
    p2 = np.ascontiguousarray(x2[:, :2] / x2[:, 2:])
    e_cv, _ = cv2.findEssentialMat(p1, p2, np.eye(3), method=cv2.RANSAC, prob=0.999, threshold=1e-4)
    e_cv = e_cv[:3]
    _, r_cv, t_cv, _ = cv2.recoverPose(e_cv, p1, p2, np.eye(3))
    assert _same_up_to_scale(eight_point(f1, f2), e_cv) < 1e-5
    r, tt = decompose_essential(e_cv, f1, f2)
    assert np.allclose(r, r_cv, atol=1e-6) and np.allclose(tt, t_cv.ravel(), atol=1e-6)
    fit = ransac_pose(f1, f2, model="general", threshold=1e-3)
    assert fit is not None and fit.n_inliers == len(f1)
    assert np.allclose(fit.rotation, r_cv, atol=1e-5) and np.allclose(fit.translation, t_cv.ravel(), atol=1e-5)


def test_upright_ransac_finds_heading_and_inliers_among_outliers():
    rng = np.random.default_rng(4)
    rot, t = rotation_about_z(math.radians(40.0)), np.array([0.5, -0.3, 0.0])
    f1, f2, _, _ = _scene(rng, 200, rot, t, noise=0.002, outliers=0.5)
    fit = ransac_pose(f1, f2, model="upright", threshold=0.01)
    assert fit is not None
    truth = np.arange(200) >= 100
    assert np.sum(fit.inliers & truth) >= 95 and np.sum(fit.inliers & ~truth) <= 5
    assert abs(math.degrees(fit.heading) - 40.0) < 0.3
    assert abs(fit.translation @ (t / np.linalg.norm(t)) - 1.0) < 1e-3


def test_general_ransac_fits_a_tilted_pair_that_the_upright_model_cannot():
    rng = np.random.default_rng(5)
    rot, t = _rotation(40, 3.0, -2.0), np.array([0.3, 0.4, 0.1])
    f1, f2, _, _ = _scene(rng, 200, rot, t, noise=0.002, outliers=0.5)
    gen = ransac_pose(f1, f2, model="general", threshold=0.01, max_iter=3000)
    up = ransac_pose(f1, f2, model="upright", threshold=0.01)
    assert gen is not None and up is not None
    assert gen.n_inliers >= 95 and up.n_inliers < 0.6 * gen.n_inliers
    assert abs(math.degrees(gen.heading) - math.degrees(heading_of_rotation(rot))) < 0.5
    assert abs(math.degrees(gen.tilt) - math.degrees(tilt_of_rotation(rot))) < 0.5


def test_ransac_is_deterministic_and_checks_its_input():
    rng = np.random.default_rng(6)
    f1, f2, _, _ = _scene(rng, 50, rotation_about_z(1.0), np.array([1.0, 0.0, 0.0]), noise=0.003, outliers=0.3)
    a = ransac_pose(f1, f2, seed=3)
    b = ransac_pose(f1, f2, seed=3)
    assert a is not None and b is not None and np.array_equal(a.inliers, b.inliers)
    assert ransac_pose(f1[:2], f2[:2]) is None
    with pytest.raises(InvalidParameterError):
        ransac_pose(f1, f2, model="affine")  # type: ignore[arg-type]
    with pytest.raises(InvalidParameterError):
        ransac_pose(f1, f2[:-1])
    with pytest.raises(InvalidParameterError):
        ransac_pose(f1, f2, threshold=0.0)


def test_few_matches_try_every_minimal_sample_and_find_the_best_one():
    """With 12 matches (495 samples of 8, fewer than max_iter) the fit is at least the best exhaustive sample."""
    import itertools

    rng = np.random.default_rng(11)
    rot, t = _rotation(25.0, 2.0, -1.0), np.array([0.4, 0.2, 0.05])
    f1, f2, _, _ = _scene(rng, 12, rot, t, noise=0.001, outliers=4 / 12)
    thr = 0.01
    best = 0
    for s in itertools.combinations(range(12), 8):
        e = eight_point(f1[list(s)], f2[list(s)])
        best = max(best, int(np.sum(epipolar_errors(e, f1, f2) < thr)))
    for seed in (0, 1, 2):
        fit = ransac_pose(f1, f2, model="general", threshold=thr, max_iter=1000, seed=seed)
        assert fit is not None and fit.n_inliers >= best >= 8
    # the same matches give the same answer whatever the seed: every sample is tried
    a = ransac_pose(f1, f2, model="general", threshold=thr, seed=0)
    b = ransac_pose(f1, f2, model="general", threshold=thr, seed=5)
    assert a is not None and b is not None and np.array_equal(a.inliers, b.inliers)


def test_refine_pose_recovers_the_pose_from_a_perturbed_guess():
    rng = np.random.default_rng(21)
    rot, t = _rotation(70.0, 3.0, -2.0), np.array([0.3, -0.6, 0.1])
    f1, f2, _, _ = _scene(rng, 60, rot, t)
    guess = _rotation(2.0, 1.0, 0.5) @ rot
    r, tt = refine_pose(f1, f2, guess, t + np.array([0.1, 0.05, -0.05]))
    assert np.allclose(r, rot, atol=1e-6) and np.allclose(tt, t / np.linalg.norm(t), atol=1e-6)
    # upright: only the turn about z and a horizontal translation
    rot_u, t_u = rotation_about_z(math.radians(-120.0)), np.array([0.7, 0.2, 0.0])
    f1, f2, _, _ = _scene(rng, 40, rot_u, t_u)
    r, tt = refine_pose(f1, f2, rotation_about_z(math.radians(-117.0)), np.array([0.6, 0.3, 0.0]), model="upright")
    assert abs(math.degrees(heading_of_rotation(r)) + 120.0) < 1e-6 and abs(tt[2]) < 1e-12


def test_many_matches_are_ranked_on_a_probe_and_still_fit():
    rng = np.random.default_rng(8)
    rot, t = _rotation(-65.0, 2.0, 1.0), np.array([0.2, 0.7, -0.1])
    f1, f2, _, _ = _scene(rng, 800, rot, t, noise=0.001, outliers=0.3)
    fit = ransac_pose(f1, f2, model="general", threshold=0.01, max_iter=300)
    truth = np.arange(800) >= 240
    assert fit is not None and np.sum(fit.inliers & truth) >= 540 and np.sum(fit.inliers & ~truth) <= 10
    assert abs(math.degrees(fit.heading) + 65.0) < 0.3


def test_inlier_mask_matches_the_epipolar_errors():
    rng = np.random.default_rng(11)
    f1 = bearing_vectors(rng.uniform(-np.pi, np.pi, 400), rng.uniform(-0.8, 0.8, 400))
    f2 = bearing_vectors(rng.uniform(-np.pi, np.pi, 400), rng.uniform(-0.8, 0.8, 400))
    es = rng.normal(size=(7, 3, 3))
    es[0] = essential_from_pose(rotation_about_z(0.4), [1.0, 0.2, 0.0])
    es[1] = 0.0  # degenerate: every error is 90 deg
    f1[:3] = f2[:3] = [0.0, 0.0, 1.0]  # E f1 = 0 for an upright pose: an error of 90 deg
    for thr in (0.01, 0.3, 1.0):
        want = epipolar_errors(es, f1, f2) < thr
        got = inlier_mask(es, f1, f2, thr)
        assert got.shape == (7, 400) and want.sum() > 0
        # equal except for errors within a last bit of the threshold
        err = epipolar_errors(es, f1, f2)
        differ = got != want
        assert np.all(np.abs(err[differ] - thr) < 1e-12)
        assert np.array_equal(inlier_mask(es[2], f1, f2, thr), got[2])


def test_null_vector_of_a_tall_system_is_the_full_svds():
    from fingerloc.features.sphere import _null_vectors

    rng = np.random.default_rng(4)
    for rows, cols in ((900, 9), (40, 4), (9, 9), (3, 4)):
        a = rng.normal(size=(rows, cols))
        full = np.linalg.svd(np.vstack([a, np.zeros((max(0, cols - rows), cols))]))[2][-1]
        got = _null_vectors(a)
        assert got.shape == (cols,)
        np.testing.assert_allclose(np.abs(got @ full), 1.0, atol=1e-12)


@pytest.mark.parametrize("m,k", [(8, 8), (9, 8), (40, 3), (900, 8), (900, 3)])
def test_samples_are_the_k_smallest_random_keys_in_order(m, k):
    from fingerloc.features.sphere import _samples

    got = _samples(np.random.default_rng(3), m, k, 64)
    keys = np.random.default_rng(3).random((64, m))
    assert np.array_equal(got, np.argsort(keys, axis=1)[:, :k])
    assert all(len(set(row)) == k for row in got.tolist())
