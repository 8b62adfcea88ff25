"""A synthetic CARMEN log whose laser has a real no-return code (for the streaming tests: the stream reader and the
file reader then agree on which beams see nothing)."""

from pathlib import Path

import numpy as np

from ._logs import ROOMS, box_scan

NO_RETURN = 81.83  # a laser's no-return code: the beams through the door of each room


def rooms_log_with_doors(path: Path, loops: int = 2) -> Path:
    """Three rooms walked ``loops`` times, one FLASER line per step; each room's door (16 beams) sees nothing."""
    lines = ["# synthetic rooms with doors", "PARAM robot_front_laser_max 81.83 nohost 0"]
    k = 0
    for _ in range(loops):
        for j, (w, h) in enumerate(ROOMS):
            for dx in (-0.4, -0.2, 0.0, 0.2, 0.4):
                x, y, th = w / 2 + dx, h / 2, 0.25 * dx
                s = box_scan(w, h, x, y, th, n=181, noise=0.005, rng=np.random.default_rng(k))
                r = np.minimum(s.ranges, 30.0)
                r[60 + 20 * j : 76 + 20 * j] = NO_RETURN
                ranges = " ".join(f"{v:.3f}" for v in r)
                wx = x + 20.0 * j
                lines.append(f"FLASER 181 {ranges} {wx:.3f} {y:.3f} {th:.4f} 0 0 0 {100 + k}.0 host {100 + k}.0")
                lines.append(f"ODOM {wx:.3f} {y:.3f} {th:.4f} 0 0 0 {100 + k}.5 host {100 + k}.5")
                k += 1
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
