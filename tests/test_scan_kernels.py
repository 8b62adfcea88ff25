"""The likelihood field's compiled kernel (fingerloc.map._scan_kernels) and ScanMap.log_likelihood equal the kernel's
definition as a plain loop bit for bit (the faster kernel changes no figure)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fingerloc.map import _scan_kernels as K
from fingerloc.map.scan_map import ScanMap


def _plain(smap: ScanMap, poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The kernel's definition as a plain Python loop (IEEE doubles, points summed in order): the figures of the
    first compiled kernel, which the faster ones must reproduce exactly."""
    table = smap.table()
    nx, ny = table.shape
    ox, oy, inv = float(smap.origin[0]), float(smap.origin[1]), 1.0 / smap.resolution
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    out = np.zeros(poses.shape[0])
    for i in range(poses.shape[0]):
        acc = 0.0
        for k in range(points.shape[0]):
            x = float(poses[i, 0]) + float(c[i]) * float(points[k, 0]) - float(s[i]) * float(points[k, 1])
            y = float(poses[i, 1]) + float(s[i]) * float(points[k, 0]) + float(c[i]) * float(points[k, 1])
            fx, fy = (x - ox) * inv, (y - oy) * inv
            if not (math.isfinite(fx) and math.isfinite(fy)):
                acc += smap.outside
                continue
            gx, gy = math.floor(fx), math.floor(fy)
            acc += float(table[gx, gy]) if 0 <= gx < nx and 0 <= gy < ny else smap.outside
        out[i] = acc / points.shape[0]
    return out


def _case(seed: int, n: int, m: int) -> tuple[ScanMap, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    smap = ScanMap.from_points(rng.uniform(-4, 4, (80, 2)), resolution=float(rng.choice([0.05, 0.1, 0.25])))
    # poses inside, at the edge and far off the grid; one exactly on a cell corner
    poses = np.column_stack([rng.uniform(-9, 9, (n, 2)), rng.uniform(-math.pi, math.pi, n)])
    poses[0] = [smap.origin[0] + 3 * smap.resolution, smap.origin[1] + 2 * smap.resolution, 0.0]
    if n > 2:
        poses[1, :2] = [1e300, -1e300]
        poses[2, :2] = [smap.origin[0], smap.origin[1] - 1e-12]
    points = rng.uniform(-5, 5, (m, 2))
    points[0] = [0.0, 0.0]
    return smap, poses, points


@pytest.mark.parametrize(("seed", "n", "m"), [(0, 1, 1), (1, 2, 3), (2, 7, 5), (3, 31, 17), (4, 64, 40)])
def test_kernel_equals_the_plain_loop_bit_for_bit(seed, n, m):
    smap, poses, points = _case(seed, n, m)
    want = _plain(smap, poses, points)
    table, ox, oy, inv, outside = smap._field()
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    got = np.full(n, np.nan)
    K.field_mean(poses, c, s, points, table, ox, oy, inv, outside, got)
    assert np.array_equal(got, want)
    assert np.array_equal(smap.log_likelihood(poses, points), want)


def test_log_likelihood_of_non_contiguous_and_single_inputs():
    smap, poses, points = _case(5, 301, 23)
    want = _plain(smap, poses, points)
    assert np.array_equal(smap.log_likelihood(np.asfortranarray(poses), points[::1].T.copy().T), want)
    assert np.array_equal(smap.log_likelihood(poses[7], points), want[7:8])


def test_from_scans_and_cells_equal_the_scan_by_scan_construction_bit_for_bit():
    from fingerloc.map.scan_map import _to_frame

    rng = np.random.default_rng(7)
    pts = [rng.uniform(-6, 6, (int(k), 2)) for k in rng.integers(0, 40, 30)]  # some scans without end points
    pts[3] = np.zeros((0, 2))
    poses = np.column_stack([rng.uniform(-20, 20, (30, 2)), rng.uniform(-math.pi, math.pi, 30)])
    world = np.vstack([_to_frame(q, poses[i]) for i, q in enumerate(pts) if q.shape[0]])
    want = ScanMap.from_points(world)
    got = ScanMap.from_scans(pts, poses)
    assert np.array_equal(got.origin, want.origin) and got.shape == want.shape
    assert np.array_equal(got.cells, want.cells)
    raw = np.clip(np.floor((world - want.origin) / want.resolution).astype(np.int64), 0, np.array(want.shape) - 1)
    assert np.array_equal(got.cells, np.unique(raw, axis=0))
    assert np.array_equal(got.table(), want.table())
