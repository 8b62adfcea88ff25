"""Scan-to-place verification (fingerloc.map.scan_verify): the best fit of a scan at each place, the fitted
weights of the verified answer, and the benchmark's verified fingerprint method."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fingerloc.errors import FingerlocError
from fingerloc.map.scan_map import ScanMap
from fingerloc.map.scan_verify import (
    ScanVerifier,
    Verification,
    VerifySearch,
    fit_verification,
    verify_candidates,
)


def _segment(a, b, step=0.05):
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = max(int(np.hypot(*(b - a)) / step), 1)
    return a + (b - a) * np.linspace(0, 1, n + 1)[:, None]


def _world():
    """A 24 m corridor (y in [-1.5, 1.5]) with door gaps and side boxes at irregular places (no two stretches alike)."""
    walls = []
    for y, doors in ((1.5, (2.5, 7.0, 15.5)), (-1.5, (4.5, 12.0, 19.0, 21.0))):
        xs = np.arange(0.0, 24.0, 0.05)
        keep = np.all(np.abs(xs[:, None] - np.array(doors)[None, :]) > 0.45, axis=1)
        walls.append(np.column_stack([xs[keep], np.full(keep.sum(), y)]))
    walls += [_segment((0, -1.5), (0, 1.5)), _segment((24, -1.5), (24, 1.5))]
    for x0, y0, w in ((5.5, 0.9, 0.6), (9.0, -1.1, 1.2), (17.0, 0.8, 0.8)):  # boxes along the walls
        walls += [_segment((x0, y0), (x0 + w, y0)), _segment((x0, y0), (x0, y0 + 0.3 * np.sign(-y0)))]
    return np.vstack(walls)


def _scan(world, pose, rng, fov=math.pi):
    """End points a laser with a ``fov`` field of view sees from ``pose`` within 8 m (the nearest per beam), robot frame."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    rel = world - pose[:2]
    rob = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]])
    r = np.hypot(rob[:, 0], rob[:, 1])
    b = np.arctan2(rob[:, 1], rob[:, 0])
    ok = np.flatnonzero((r < 8.0) & (np.abs(b) <= fov / 2))
    beam = np.round(b[ok] / math.radians(1.0)).astype(int)
    order = np.lexsort((r[ok], beam))  # by beam, nearest first
    first = np.r_[True, np.diff(beam[order]) != 0]
    pts = rob[ok[order[first]]]
    return pts + 0.01 * rng.standard_normal(pts.shape)


_WORLD = _world()
_MAP = ScanMap.from_points(_WORLD, resolution=0.1)
_CENTRES = np.column_stack([np.arange(1.0, 24.0, 2.0), np.zeros(12)])


def test_the_true_place_fits_best_and_the_pose_is_found():
    rng = np.random.default_rng(3)
    v = ScanVerifier(_MAP, _CENTRES, 1.0)
    right, errs = 0, []
    for _ in range(12):
        j = int(rng.integers(0, 12))
        pose = np.array([_CENTRES[j, 0] + rng.uniform(-0.7, 0.7), rng.uniform(-0.5, 0.5), rng.uniform(-math.pi, math.pi)])
        fits, poses = v.fits(_scan(_WORLD, pose, rng))
        right += int(np.argmax(fits) == j)
        if np.argmax(fits) == j:
            errs.append((np.hypot(*(poses[j, :2] - pose[:2])), abs(math.remainder(poses[j, 2] - pose[2], 2 * math.pi))))
        assert fits.shape == (12,) and poses.shape == (12, 3)
    assert right >= 11
    e = np.array(errs)
    assert np.median(e[:, 0]) < 0.1 and np.median(e[:, 1]) < math.radians(2.0)


def test_a_place_the_search_keeps_fits_at_least_as_well_as_its_grid():
    """The refined fit of the best place is no worse than any single pose the grid tried there (hill climb)."""
    rng = np.random.default_rng(5)
    pose = np.array([7.2, 0.3, 2.0])
    q = _scan(_WORLD, pose, rng)
    v = ScanVerifier(_MAP, _CENTRES, 1.0)
    fits, poses = v.fits(q)
    j = int(np.argmax(fits))
    assert fits[j] == pytest.approx(float(_MAP.log_likelihood(poses[j : j + 1], q)[0]))
    grid = np.array([[x, y, t] for x in np.linspace(6.2, 8.2, 11) for y in np.linspace(-0.8, 0.8, 9)
                     for t in np.linspace(-math.pi, math.pi, 72, endpoint=False)])  # fmt: skip
    assert fits[j] >= float(_MAP.log_likelihood(grid, q).max()) - 1e-9


def test_a_scan_without_end_points_gives_no_evidence():
    v = ScanVerifier(_MAP, _CENTRES, 1.0)
    fits, poses = v.fits(np.zeros((0, 2)))
    assert np.all(fits == 0) and np.all(np.isnan(poses))
    lp = np.log(np.full((1, 12), 1 / 12))
    out = verify_candidates(lp, [np.zeros((0, 2))], v, verification=Verification(0.5, 10.0, 3))
    assert np.allclose(out, lp)


def test_verified_answer_is_the_weighted_combination():
    rng = np.random.default_rng(1)
    q = [_scan(_WORLD, np.array([c[0] + 0.3, -0.2, 0.4 + k]), rng) for k, c in enumerate(_CENTRES[[2, 7]])]
    lp = np.log(rng.dirichlet(np.ones(12), size=2))
    ver = Verification(program=0.7, scan=12.0, rows=40)
    v = ScanVerifier(_MAP, _CENTRES, 1.0)
    fits = np.vstack([v.fits(x)[0] for x in q])
    z = 0.7 * lp + 12.0 * fits
    expect = z - np.log(np.exp(z).sum(axis=1, keepdims=True))
    assert np.allclose(verify_candidates(lp, q, _MAP, _CENTRES, ver, radius=1.0), expect)
    assert np.allclose(verify_candidates(lp, q, v, verification=ver), expect)
    nan = np.full((1, 12), np.nan)
    assert np.all(np.isnan(ver.combine(nan, np.zeros((1, 12)))))  # no observation stays no observation


def test_fitted_weights_follow_the_informative_score():
    """Held-out rows whose scan fits name the place and whose program scores are noise: the scan weighs more."""
    rng = np.random.default_rng(0)
    n, p = 200, 15
    y = rng.integers(0, p, n)
    fits = -0.3 + 0.05 * rng.standard_normal((n, p))
    fits[np.arange(n), y] += 0.15
    prog = np.log(rng.dirichlet(np.ones(p), size=n))
    w = fit_verification(prog, fits, y)
    assert w.rows == n and w.scan > 10 and w.program < 0.3
    w2 = fit_verification(prog, -fits, y)  # a fit that points away: not used
    assert w2.scan < 1.0


def test_fit_verification_bounds_and_unknown_true_places():
    y = np.array([0, 1, 2, 0])
    fits = np.eye(3)[y] * 1.0 - 1.0  # perfectly separating: the weight goes to its bound
    prog = np.zeros((4, 3))
    prog[3, 0] = -np.inf  # this row's program fit did not know its true place: left out
    w = fit_verification(prog, fits, y, max_scan=25.0)
    assert w.rows == 3 and w.scan == pytest.approx(25.0)
    assert fit_verification(np.full((2, 3), -np.inf), np.zeros((2, 3)), [0, 1]) == Verification()


def test_verification_json_and_bad_input():
    v = Verification(0.25, 8.5, 77)
    assert Verification.from_json(v.to_json()) == v
    for bad in ({"program": -1.0}, {"scan": math.inf}, {"rows": -2}):
        with pytest.raises(FingerlocError):
            Verification(**bad)
    with pytest.raises(FingerlocError):
        Verification.from_json({"program": "x"})
    with pytest.raises(FingerlocError):
        VerifySearch(keep=0)
    with pytest.raises(FingerlocError):
        ScanVerifier(_MAP, np.zeros((0, 2)), 1.0)
    with pytest.raises(FingerlocError):
        verify_candidates(np.zeros((1, 3)), [np.zeros((1, 2))], _MAP)  # centres needed
    with pytest.raises(FingerlocError):
        verify_candidates(np.zeros((1, 3)), [np.zeros((1, 2))], ScanVerifier(_MAP, _CENTRES, 1.0))  # 3 != 12 places


def test_the_benchmark_fingerprint_is_verified_and_better_than_the_program(small_rooms_log):
    from fingerloc.experiments.carmen import run_benchmark

    run = run_benchmark([small_rooms_log], ["fingerprint-program", "fingerprint"]).to_json()
    figs = next(iter(run["logs"].values()))["methods"]
    assert figs["fingerprint"]["top1"] >= figs["fingerprint-program"]["top1"]
    assert figs["fingerprint"]["top1"] >= 0.9


@pytest.fixture(scope="module")
def small_rooms_log(tmp_path_factory):
    from tests._logs import rooms_path, write_log

    return write_log(tmp_path_factory.mktemp("verify") / "rooms-corrected.log", rooms_path())


def test_calibrate_verification_fits_rows_against_maps_without_their_fold():
    """Scans along the corridor, two folds of alternate stretches: each row's map lacks its own stretch; the scan
    fits still name the places (the neighbouring stretches see the same walls), so the scan weight dominates."""
    from fingerloc.map.scan_verify import calibrate_verification, map_without

    rng = np.random.default_rng(2)
    poses = np.array([[x, 0.2 * math.sin(x), 0.3 * math.cos(x)] for x in np.arange(0.5, 23.5, 0.4)])
    pts = [_scan(_WORLD, p, rng) for p in poses]
    near = np.argmin(np.abs(poses[:, None, 0] - _CENTRES[None, :, 0]), axis=1)
    fold = near % 2  # a place's stretch is one fold, its neighbours the other
    m = map_without(pts, poses, fold == 0)
    assert m is not None and map_without(pts, poses, np.ones(len(pts), bool)) is None
    rows = np.arange(0, len(pts), 2)
    held = np.log(rng.dirichlet(np.ones(12), size=rows.size))  # a program that knows nothing
    ver = calibrate_verification(held, near[rows], rows, pts, poses, fold, _CENTRES, 1.0, max_rows=20)
    assert ver.rows == 20 and ver.scan > 5 * max(ver.program, 0.1)
