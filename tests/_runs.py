"""Synthetic recorded runs for the library-layer tests: a robot walking through box rooms."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fingerloc.io.carmen import flaser_bearings

#: Rooms (width, height, metres); room j lies 20 m * j along x in the world.
BOXES = [(3.0, 3.0), (8.0, 2.0), (5.0, 12.0), (4.0, 6.0)]


def box_ranges(w: float, h: float, px: float, py: float, heading: float, n: int = 181) -> np.ndarray:
    """Ranges of a 180 deg scan from (px, py) inside the box [0, w] x [0, h]."""
    a = flaser_bearings(n) + heading
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(c > 1e-12, (w - px) / c, np.where(c < -1e-12, -px / c, np.inf))
        ty = np.where(s > 1e-12, (h - py) / s, np.where(s < -1e-12, -py / s, np.inf))
    return np.minimum(tx, ty)


def walk(passes: int = 2) -> list[tuple[int, float, float, float]]:
    """(room, x, y, heading) per step: in every room three spots 0.3 m apart, every pass the same tour."""
    out = []
    for _ in range(passes):
        for j, (w, h) in enumerate(BOXES):
            for dx in (-0.3, 0.0, 0.3):
                out.append((j, w / 2 + dx, h / 2, 0.3 * dx))
    return out


def write_carmen(path: Path, steps: list[tuple[int, float, float, float]] | None = None) -> Path:
    """A CARMEN log, one FLASER per step (world pose: room j shifted 20 m along x), with a little noise."""
    lines = ["# synthetic", "PARAM robot_front_laser_max 30 nohost 0"]
    for k, (j, x, y, th) in enumerate(walk() if steps is None else steps):
        w, h = BOXES[j]
        r = box_ranges(w, h, x, y, th) + np.random.default_rng(k).normal(0, 0.005, 181)
        rs = " ".join(f"{v:.3f}" for v in np.minimum(r, 30.0))
        wx = x + 20.0 * j
        lines.append(f"FLASER 181 {rs} {wx:.3f} {y:.3f} {th:.4f} 0 0 0 {k}.0 host {k}.0")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
