"""Test helper: an exact 2D ray caster over wall segments, and a tiny CARMEN FLASER parser."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np

from fingerloc.sensors import Scan

CARMEN_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "carmen"


def cast(walls, bearings, *, pose=(0.0, 0.0, 0.0), max_range=10.0, reflect=None):
    """Exact ranges (m) of rays from ``pose`` at ``bearings`` (rad, robot frame) against ``walls``.

    ``walls``: sequence of ((x0, y0), (x1, y1)); ``reflect``: per-wall intensity (default 100).
    Returns (ranges with inf for no hit, intensities).
    """
    x, y, th = pose
    w = np.asarray(walls, dtype=float)  # (m, 2, 2)
    a = np.asarray(bearings, dtype=float) + th
    d = np.column_stack([np.cos(a), np.sin(a)])  # (n, 2)
    p0 = w[:, 0] - [x, y]
    e = w[:, 1] - w[:, 0]  # (m, 2)
    # solve t d = p0 + s e  ->  t d - s e = p0
    den = d[:, None, 0] * (-e[None, :, 1]) - d[:, None, 1] * (-e[None, :, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (p0[None, :, 0] * (-e[None, :, 1]) - p0[None, :, 1] * (-e[None, :, 0])) / den
        s = (d[:, None, 0] * p0[None, :, 1] - d[:, None, 1] * p0[None, :, 0]) / den
    ok = (np.abs(den) > 1e-12) & (t > 1e-9) & (s >= 0) & (s <= 1)
    t = np.where(ok, t, np.inf)
    k = np.argmin(t, axis=1)
    r = t[np.arange(len(a)), k]
    refl = np.full(len(w), 100.0) if reflect is None else np.asarray(reflect, dtype=float)
    inten = np.where(np.isfinite(r), refl[k], 0.0)
    r = np.where(r >= max_range, np.inf, r)
    return r, inten


def make_scan(walls, *, n=720, fov_deg=360.0, pose=(0.0, 0.0, 0.0), noise=0.0, seed=0, reflect=None, max_range=10.0):
    if fov_deg >= 360:
        b = -np.pi + (np.arange(n) + 0.5) * 2 * np.pi / n
    else:
        h = np.deg2rad(fov_deg) / 2
        b = np.linspace(-h, h, n)
    r, inten = cast(walls, b, pose=pose, max_range=max_range, reflect=reflect)
    if noise:
        r = r + np.random.default_rng(seed).normal(0, noise, r.size)
    return Scan(r, b, max_range=max_range, intensities=inten)


def box(cx, cy, hw, hh):
    c = [(cx - hw, cy - hh), (cx + hw, cy - hh), (cx + hw, cy + hh), (cx - hw, cy + hh)]
    return [(c[i], c[(i + 1) % 4]) for i in range(4)]


def read_flaser(name: str, count: int, every: int = 1):
    """Parse up to ``count`` FLASER scans (every ``every``-th) of a CARMEN log in CARMEN_DIR."""
    out = []
    path = CARMEN_DIR / name
    with gzip.open(path, "rt") as fh:
        k = 0
        for line in fh:
            if not line.startswith("FLASER"):
                continue
            k += 1
            if (k - 1) % every:
                continue
            f = line.split()
            n = int(f[1])
            r = np.array(f[2 : 2 + n], dtype=float)
            x, y, th = (float(v) for v in f[2 + n : 5 + n])
            b = np.linspace(-np.pi / 2, np.pi / 2, n)
            mr = float(r.max()) if r.max() > 49 else 81.83
            out.append(Scan(r, b, max_range=mr, pose=(x, y, th)))
            if len(out) >= count:
                break
    return out
