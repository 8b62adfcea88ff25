"""Speed section ``sim`` of ``fingerloc bench speed`` (the simulator).

Times, on the first of ten offices generated with seed 20040426 (robot at the
office's anchor, heading 0.3 rad):

- ``scan_720_ms``: one 720-beam 360 deg scan (two heads), ray casting all beams
  against all segments at once (target well under 100 ms);
- ``omni_640x480_ms``: one raw 640x480 omnidirectional image (target well
  under 100 ms), and ``omni_640x480_jpeg_ms`` with a JPEG round trip;
- ``panorama_720x120_ms``: one 720x120 panorama (2 rays per column);
- ``true_features_ms``: the dense ground truth of one pose (evaluation only);
- ``make_offices_10_ms``: generating ten offices.

Best of ``repeat`` rounds of ``number`` calls each, in milliseconds.
"""

from __future__ import annotations

from typing import Any

from ..sim import make_offices, render_omni, render_panorama, simulate_scan, true_features
from .speed import best_time, section

__all__ = ["speed_sim"]


@section("sim")
def speed_sim(quick: bool) -> dict[str, Any]:
    """Time the simulator's sensors; return JSON-ready figures (milliseconds)."""
    repeat, number = (2, 3) if quick else (5, 10)
    worlds = make_offices(10, random_state=20040426)
    w = worlds[0]
    pose = (*w.anchor, 0.3)
    render_omni(w, pose)  # builds the cached pixel lookup table once
    ms = 1000.0
    return {
        "segments": w.n_segments,
        "scan_720_ms": ms
        * best_time(lambda: simulate_scan(w, pose, n_beams=720, random_state=0), repeat=repeat, number=number),
        "omni_640x480_ms": ms
        * best_time(lambda: render_omni(w, pose, size=(640, 480), random_state=0), repeat=repeat, number=number),
        "omni_640x480_jpeg_ms": ms
        * best_time(
            lambda: render_omni(w, pose, size=(640, 480), jpeg_quality=85, random_state=0), repeat=repeat, number=number
        ),
        "panorama_720x120_ms": ms
        * best_time(lambda: render_panorama(w, pose, random_state=0), repeat=repeat, number=number),
        "true_features_ms": ms * best_time(lambda: true_features(w, pose), repeat=repeat, number=max(number // 3, 1)),
        "make_offices_10_ms": ms * best_time(lambda: make_offices(10, random_state=1), repeat=repeat, number=1),
    }
