"""The compiled split of a scan segment into line pieces gives the pieces of the plain recursion."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc.features._laser_kernels import split_pieces


def _split_reference(pts, tol, lo, hi, out):
    """The iterative-end-point split as a NumPy recursion (pieces appended to ``out``)."""
    if hi - lo < 3:
        out.append((lo, hi))
        return
    a, b = pts[lo], pts[hi - 1]
    chord = b - a
    length = float(np.hypot(*chord))
    seg = pts[lo:hi]
    if length < 1e-9:
        dist = np.linalg.norm(seg - a, axis=1)
    else:
        normal = np.array([-chord[1], chord[0]]) / length
        dist = np.abs((seg - a) @ normal)
    t = tol[lo:hi]
    k = int(np.argmax(dist / t))
    if dist[k] - t[k] > 0 and 0 < k < hi - lo - 1:
        _split_reference(pts, tol, lo, lo + k + 1, out)
        _split_reference(pts, tol, lo + k, hi, out)
    else:
        out.append((lo, hi))


def _reference(pts, tol):
    out: list[tuple[int, int]] = []
    _split_reference(pts, tol, 0, pts.shape[0], out)
    return out


def _polyline(rng, n_corners, n, noise):
    """Points along a random polyline (a room's walls seen by a laser), with range noise."""
    corners = np.cumsum(rng.normal(0, 3, (n_corners + 1, 2)), axis=0)
    t = np.sort(rng.uniform(0, n_corners, n))
    i = np.minimum(t.astype(int), n_corners - 1)
    f = (t - i)[:, None]
    return corners[i] * (1 - f) + corners[i + 1] * f + rng.normal(0, noise, (n, 2))


def test_split_pieces_equal_the_recursion_on_polylines():
    rng = np.random.default_rng(3)
    for t in range(400):
        n = int(rng.integers(0, 300))
        pts = _polyline(rng, int(rng.integers(1, 8)), n, [0.0, 0.005, 0.05][t % 3])
        r = np.hypot(pts[:, 0], pts[:, 1])
        tol = 0.03 + 0.02 * r
        got = [tuple(x) for x in split_pieces(np.ascontiguousarray(pts), tol).tolist()]
        assert got == _reference(pts, tol)
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 1.0], [3.0, 0.0], [4.0, 0.0]])
    assert split_pieces(pts, np.full(5, 0.5)).tolist() == [[0, 3], [2, 5]]  # the apex ends one piece, starts the next


@settings(max_examples=150, deadline=None)
@given(
    pts=st.lists(st.tuples(st.integers(-20, 20), st.integers(-20, 20)), min_size=0, max_size=40),
    tol=st.floats(0.05, 5.0),
)
def test_split_pieces_equal_the_recursion_on_grid_points(pts, tol):
    # integer points: repeated points, zero-length chords and exact ties of the farthest point
    p = np.array(pts, dtype=np.float64).reshape(-1, 2)
    t = np.full(p.shape[0], tol)
    assert [tuple(x) for x in split_pieces(p, t).tolist()] == _reference(p, t)
