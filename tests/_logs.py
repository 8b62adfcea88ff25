"""Synthetic rooms and CARMEN logs shared by the benchmark, filter and hardening tests."""

import numpy as np

from fingerloc.io.carmen import flaser_bearings
from fingerloc.sensors import Scan


def box_scan(w, h, px, py, heading=0.0, n=181, noise=0.0, rng=None):
    """A 180 deg scan from (px, py) inside the axis-aligned box [0, w] x [0, h]."""
    b = flaser_bearings(n)
    a = b + heading
    with np.errstate(divide="ignore"):
        tx = np.where(np.cos(a) > 0, (w - px) / np.cos(a), np.where(np.cos(a) < 0, -px / np.cos(a), np.inf))
        ty = np.where(np.sin(a) > 0, (h - py) / np.sin(a), np.where(np.sin(a) < 0, -py / np.sin(a), np.inf))
    r = np.minimum(tx, ty)
    if noise:
        r = r + (rng or np.random.default_rng(0)).normal(0, noise, r.shape)
    return Scan(r, b, max_range=30.0, pose=(px, py, heading))


ROOMS = [(3.0, 3.0), (8.0, 2.0), (5.0, 12.0)]


def write_log(path, rooms_path):
    """A robot walks a loop through rooms twice (mapping, then query), one FLASER per step."""
    lines = ["# synthetic", "PARAM robot_front_laser_max 30 nohost 0"]
    for k, (w, h, x, y, th) in enumerate(rooms_path):
        s = box_scan(w, h, x, y, th, n=181, noise=0.005, rng=np.random.default_rng(k))
        r = " ".join(f"{v:.3f}" for v in np.minimum(s.ranges, 30.0))
        # the pose in the world: room j is shifted 20 m along x
        wx = x + 20.0 * [r_[0] for r_ in ROOMS].index(w)
        lines.append(f"FLASER 181 {r} {wx:.3f} {y:.3f} {th:.4f} 0 0 0 {k}.0 host {k}.0")
        lines.append(f"ODOM {wx:.3f} {y:.3f} {th:.4f} 0 0 0 {k}.0 host {k}.0")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def rooms_path():
    """Two loops through the three rooms; in rooms 1 and 2 a step 1.4 m off centre (outside R: prediction only)."""
    out = []
    for _ in range(2):
        for j, (w, h) in enumerate(ROOMS):
            for dx in (-0.3, 0.0, 0.3) + ((1.4,) if j else ()):
                out.append((w, h, w / 2 + dx, h / 2, 0.3 * dx))
    return out
