"""Two alike corridors 10 m apart and a robot driving along one of them: the scene of the lost-rule tests (a
pose filter locked on the twin corridor), its scans and confusing fingerprint rows."""

from __future__ import annotations

import math

import numpy as np

from fingerloc.map.scan_map import ScanMap
from tests._paths import polyline, truth_places

__all__ = ["CENTRES", "MAP", "POSES", "TRUTH", "TWIN", "WORLD", "inputs"]


def _wall(x0, x1, y, doors):
    xs = np.arange(x0, x1, 0.05)
    keep = np.all(np.abs(xs[:, None] - np.array(doors)[None, :]) > 0.5, axis=1)
    return np.column_stack([xs[keep], np.full(keep.sum(), y)])


def _world():
    """Two closed 20 m corridors 10 m apart (A at y = 0, B at y = 10), alike but for one wall (20 cm off, other doors)."""
    a = [_wall(0, 20, 1.5, (3, 9, 15)), _wall(0, 20, -1.5, (5, 12, 18))]
    b = [_wall(0, 20, 11.5, (3, 9, 15)), _wall(0, 20, 8.3, (8, 15))]
    ends = [np.column_stack([np.full(60, x), y0 + np.linspace(-1.5, 1.5, 60)]) for x in (0, 20) for y0 in (0, 10)]
    return np.vstack(a + b + ends)


def _scan_at(world, pose, rng):
    """End points a 360-degree scanner at ``pose`` sees within 8 m (no occlusion), 2 cm of noise, robot frame."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    rel = world - pose[:2]
    rob = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]])
    seen = rob[np.hypot(rob[:, 0], rob[:, 1]) < 8.0][::4]
    return seen + 0.02 * rng.standard_normal(seen.shape)


TWIN = np.array([0.0, 10.0, 0.0])  # from corridor A to its twin B
WORLD = _world()
MAP = ScanMap.from_points(WORLD, resolution=0.1)
POSES = polyline([(1.0, 0.0), (19.0, 0.0)], 0.25)  # the robot drives along corridor A
_CA = np.column_stack([np.arange(1.0, 20.0, 2.0), np.zeros(10)])
CENTRES = np.vstack([_CA, _CA + TWIN[:2]])  # places 0-9 in A, their twins 10-19 in B
TRUTH = truth_places(POSES, CENTRES)


def inputs(seed):
    """Scans along A; fingerprint rows that confuse neighbours and the twin corridor, B slightly favoured."""
    rng = np.random.default_rng(seed)
    pts = [_scan_at(WORLD, p, rng) for p in POSES]
    k = np.arange(20) % 10
    ll = -0.4 * np.abs(k[None, :] - (TRUTH % 10)[:, None]) + 0.3 * rng.standard_normal((TRUTH.size, 20))
    ll[:, 10:] += 0.2
    return ll, pts
