"""Figures about the simulator for docs/RESULTS.md (``python -m fingerloc.experiments.sim_stats``).

1. Ground-truth features per measurement (the paper's protocol poses in ten
   offices), beside the paper's Table II means.
2. How alike the offices are for several ``similarity`` values: the share of
   ground-truth bearings (VE, c, Ex) at one office's anchor that another office
   also has within 5 deg at its anchor (same heading), against the same share
   between two poses of one office.
3. Laser intensities: beams on beacons against all other beams.
"""

from __future__ import annotations

import json
import sys
from typing import Any

import numpy as np

from ..angles import dist_as
from ..sim import make_offices, protocol_poses, simulate_scan, true_features
from ..sim.laser import LASER_HEIGHT
from ..sim.world import cast_rays

__all__ = ["feature_counts", "intensity_stats", "main", "office_likeness"]

PAPER_TABLE2 = {"VE": 5.6, "Ex": 5.6, "CP": 2.7, "B": 3.9}
_TYPES = ("VE", "Ex", "c", "CP", "B")


def feature_counts(
    n_offices: int = 10, *, similarity: float = 0.5, seed: int = 0, world: str = "alike"
) -> dict[str, float]:
    """Mean number of ground-truth features per measurement over the protocol poses."""
    rng = np.random.default_rng(seed)
    counts: dict[str, list[int]] = {k: [] for k in _TYPES}
    for w in make_offices(n_offices, similarity=similarity, random_state=rng, world=world):
        train, test = protocol_poses(w, random_state=rng)
        for pose in np.vstack([train, test]):
            f = true_features(w, tuple(pose))
            for k in _TYPES:
                counts[k].append(int(f[k].size))
    return {k: float(np.mean(v)) for k, v in counts.items()}


def _match_share(a: dict[str, np.ndarray], b: dict[str, np.ndarray], tol: float) -> float:
    hit = tot = 0
    for k in ("VE", "c", "Ex"):
        if a[k].size == 0:
            continue
        tot += a[k].size
        if b[k].size:
            hit += int((np.abs(dist_as(a[k][:, None], b[k][None, :])).min(axis=1) <= tol).sum())
    return hit / max(tot, 1)


def office_likeness(similarity: float, *, n_offices: int = 10, seed: int = 0, tol_deg: float = 5.0) -> dict[str, float]:
    """Share of bearings matched across offices (anchors) and within an office (anchor vs a pose 0.55 m away)."""
    tol = np.deg2rad(tol_deg)
    worlds = make_offices(n_offices, similarity=similarity, random_state=seed)
    truths = [true_features(w, (*w.anchor, 0.0)) for w in worlds]
    across = [_match_share(truths[i], truths[j], tol) for i in range(n_offices) for j in range(n_offices) if i != j]
    within = []
    for w, t in zip(worlds, truths, strict=True):
        p = (w.anchor[0] + 0.55, w.anchor[1], 0.0)
        within.append(_match_share(t, true_features(w, p), tol))
    return {"across_offices": float(np.mean(across)), "within_office": float(np.mean(within))}


def intensity_stats(n_offices: int = 10, *, seed: int = 0) -> dict[str, float]:
    """Percentiles of the intensity of beacon beams and of all other beams (720-beam scans at the anchors)."""
    on, off = [], []
    for w in make_offices(n_offices, random_state=seed):
        pose = (*w.anchor, 0.0)
        scan = simulate_scan(w, pose, random_state=seed)
        _, seg, _ = cast_rays(w, pose[:2], scan.bearings + pose[2], z=LASER_HEIGHT)
        beacon = np.zeros(seg.size, dtype=bool)
        hit = (seg >= 0) & scan.valid
        mats = w.surface_material(seg[hit], LASER_HEIGHT)
        beacon[hit] = [w.materials[m].beacon for m in mats]
        assert scan.intensities is not None
        on.append(scan.intensities[beacon])
        off.append(scan.intensities[hit & ~beacon])
    a, b = np.concatenate(on), np.concatenate(off)
    return {
        "beacon_beams": int(a.size),
        "beacon_p5": float(np.percentile(a, 5)),
        "beacon_median": float(np.median(a)),
        "other_p50": float(np.percentile(b, 50)),
        "other_p95": float(np.percentile(b, 95)),
        "other_p99": float(np.percentile(b, 99)),
        "other_max": float(b.max()),
    }


def main() -> dict[str, Any]:
    out: dict[str, Any] = {
        "features_per_measurement": feature_counts(),
        "features_per_measurement_paper_world": feature_counts(similarity=0.8, world="paper"),
        "paper_table2": PAPER_TABLE2,
        "likeness": {str(s): office_likeness(s) for s in (0.0, 0.5, 0.8, 1.0)},
        "intensity": intensity_stats(),
    }
    json.dump(out, sys.stdout, indent=1)
    sys.stdout.write("\n")
    return out


if __name__ == "__main__":
    main()
