"""The likelihood field's compiled kernels (fingerloc.map._scan_kernels): serial, parallel and the plain loop agree
bit for bit; ScanMap.log_likelihood gives the same figures on either path and from several threads (issue 17)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from fingerloc.map import _scan_kernels as K
from fingerloc.map import scan_map as sm
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
def test_serial_and_parallel_kernels_equal_the_plain_loop_bit_for_bit(seed, n, m):
    smap, poses, points = _case(seed, n, m)
    want = _plain(smap, poses, points)
    table, ox, oy, inv, outside = smap._field()
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    got = np.full(n, np.nan)
    K.field_mean(poses, c, s, points, table, ox, oy, inv, outside, got)
    assert np.array_equal(got, want)
    for chunks in (1, 2, 3, 5):
        par = np.full(n, np.nan)
        K.field_mean_parallel(poses, c, s, points, table, ox, oy, inv, outside, par, chunks)
        assert np.array_equal(par, want), chunks


def test_log_likelihood_is_the_same_on_either_path(monkeypatch):
    smap, poses, points = _case(5, 301, 23)
    monkeypatch.setattr(sm, "SCAN_PARALLEL_MIN_POINTS", 1)
    par = smap.log_likelihood(poses, points)
    monkeypatch.setattr(sm, "SCAN_PARALLEL_MIN_POINTS", 10**12)
    ser = smap.log_likelihood(poses, points)
    assert np.array_equal(par, ser)
    assert np.array_equal(ser, _plain(smap, poses, points))


SCRIPT = textwrap.dedent(
    """
    import threading
    import numpy as np
    from fingerloc.map import scan_map as sm

    rng = np.random.default_rng(0)
    smap = sm.ScanMap.from_points(rng.uniform(-4, 4, (200, 2)))
    poses = np.column_stack([rng.uniform(-5, 5, (1000, 2)), rng.uniform(-3, 3, 1000)])
    points = rng.uniform(-5, 5, (60, 2))
    sm.SCAN_PARALLEL_MIN_POINTS = 1
    want = smap.log_likelihood(poses, points)
    errors = []

    def worker(t):
        try:
            for _ in range(20):
                if not np.array_equal(smap.log_likelihood(poses, points), want):
                    errors.append(f"thread {t} differs")
        except Exception as err:  # pragma: no cover - reported below
            errors.append(f"thread {t}: {err!r}")

    threads = [threading.Thread(target=worker, args=(t,)) for t in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    import numba
    print(numba.threading_layer())
    print("\\n".join(errors) if errors else "ok")
    """
)


def test_log_likelihood_from_four_threads_workqueue():
    env = {**os.environ, "NUMBA_THREADING_LAYER": "workqueue", "NUMBA_NUM_THREADS": "2"}
    res = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    layer, verdict = res.stdout.strip().splitlines()[-2:]
    assert layer == "workqueue"
    assert verdict == "ok"
