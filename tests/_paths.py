"""Synthetic trajectories and sensor scores for the pose-filter tests (no sensor data: scores drawn directly)."""

from __future__ import annotations

import itertools
import math

import numpy as np


def polyline(points, step):
    """Poses every ``step`` metres along straight segments, heading along each segment."""
    out = []
    for a, b in itertools.pairwise(points):
        a, b = np.asarray(a, float), np.asarray(b, float)
        n = max(round(float(np.hypot(*(b - a))) / step), 1)
        th = math.atan2(b[1] - a[1], b[0] - a[0])
        out += [(*(a + (b - a) * k / n), th) for k in range(n)]
    out.append((*points[-1], out[-1][2]))
    return np.array(out)


def truth_places(poses, centres, radius=1.0):
    """The place within ``radius`` of each pose (nearest centre), -1 off every place."""
    d = np.hypot(poses[:, None, 0] - centres[None, :, 0], poses[:, None, 1] - centres[None, :, 1])
    t = np.argmin(d, axis=1)
    t[d[np.arange(t.size), t] > radius] = -1
    return t


def sensor_scores(truth, n_places, separation, seed):
    """Standard normal scores, the true place raised by ``separation``; NaN rows off the places."""
    rng = np.random.default_rng(seed)
    ll = np.full((truth.size, n_places), np.nan)
    q = np.flatnonzero(truth >= 0)
    ll[q] = rng.normal(size=(q.size, n_places))
    ll[q, truth[q]] += separation
    return ll
