"""Figures about the simulator for docs/RESULTS.md (``python -m fingerloc.experiments.sim_stats``).

1. Ground-truth features per measurement (the paper's protocol poses in ten
   offices), beside the paper's Table II means.
2. How alike the offices are for several ``similarity`` values: the share of
   ground-truth bearings (VE, c, Ex) at one office's anchor that another office
   also has within 5 deg at its anchor (same heading), against the same share
   between two poses of one office.
3. Laser intensities: beams on beacons against all other beams.

``python -m fingerloc.experiments.sim_stats calibrate``: the features the
extractors find per measurement in each world of the robot experiment
(:data:`~fingerloc.experiments.robot.WORLD_PROFILES`), beside Table II; for a
world whose test measurements are taken at a later visit (``"paper"``), the
training and the test pose's counts apart too (``train_VE``, ``test_VE``, ...).
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
from .robot import PAPER_TABLE2

__all__ = ["calibration_counts", "feature_counts", "intensity_stats", "main", "office_likeness"]

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


def calibration_counts(
    *,
    world: str = "paper",
    similarity: float = 0.8,
    templates: int = 5,
    blur: float = 1.5,
    noise: float = 0.025,
    jpeg_quality: int = 75,
    edge_params: dict[str, float] | None = None,
    seed: int = 100,
    session: dict[str, Any] | None = None,
) -> dict[str, float]:
    """Features the extractors find per measurement, for calibrating a world to the paper's Table II.

    ``templates`` sets of ten offices (seeds ``seed``, ``seed + 1``, ...; each set shares one
    template, so several are needed to average over templates), two measurements per office
    (the first training pose and the first test pose of the protocol), the raw sensors (the
    robot experiment's 360 deg laser and 640x480 omnidirectional camera with the given
    ``blur`` (pixels), ``noise`` and JPEG quality), then the extractors: laser ``Ex``, ``B``,
    ``c`` with their defaults, colour patches with theirs, vertical edges with
    ``edge_params`` (fields of :class:`~fingerloc.features.vision.EdgeParams`). With
    ``session`` (:class:`~fingerloc.sim.sessions.SessionChange` fields), the test pose is
    measured at the later visit of the office (changes drawn with seed ``seed + 1000 + t``).

    Returns
    -------
    dict
        Feature type -> mean count per measurement; ``"truth_VE"`` etc.: the simulator's
        ground truth (:func:`~fingerloc.sim.true_features`) at the same poses; ``"train_VE"``,
        ``"test_VE"`` etc.: the extracted counts of the training and the test pose alone; ``"n"``.
    """
    from ..features.laser import extract_laser_features
    from ..features.vision import colour_patches, unwarp_omni, vertical_edges
    from ..sim import render_omni
    from ..sim.sessions import SessionChange, make_office_sessions
    from .robot import RobotProtocol, measurement_poses

    p = RobotProtocol(random_heading=False)
    got: dict[str, list[int]] = {k: [] for k in _TYPES}
    truth: dict[str, list[int]] = {k: [] for k in _TYPES}
    role: list[str] = []
    change = None if session is None else SessionChange(**session)
    for t in range(templates):
        rng = np.random.default_rng(seed + t)
        pairs = make_office_sessions(
            10, random_state=rng, world=world, similarity=similarity, change=change, change_random_state=seed + 1000 + t
        )
        for w0, w1 in pairs:
            train, test = measurement_poses(w0, p, rng)
            for w, pose, r in ((w0, train[0], "train"), (w1, test[0], "test")):
                role.append(r)
                scan = simulate_scan(w, pose, random_state=rng)
                im = render_omni(w, pose, jpeg_quality=jpeg_quality, blur=blur, noise=noise, random_state=rng)
                off = im.forward_angle if im.clockwise else -im.forward_angle
                pano = unwarp_omni(
                    im.image, im.center, im.radii[0], im.radii[1], bearing_offset=off, mirror=im.clockwise, width=720
                )
                lf = extract_laser_features(scan)
                got["Ex"].append(lf.extremities.size)
                got["B"].append(lf.beacons.size)
                got["c"].append(lf.corners.size)
                got["CP"].append(colour_patches(pano)[0].size)
                got["VE"].append(vertical_edges(pano, **(edge_params or {})).size)
                tf = true_features(w, pose)
                for k in _TYPES:
                    truth[k].append(int(tf[k].size))
    out = {k: float(np.mean(v)) for k, v in got.items()}
    out.update({f"truth_{k}": float(np.mean(v)) for k, v in truth.items()})
    roles = np.array(role)
    for r in ("train", "test"):
        out.update({f"{r}_{k}": float(np.mean(np.array(v)[roles == r])) for k, v in got.items()})
    out["n"] = float(len(got["VE"]))
    return out


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Print the figures as JSON; ``calibrate`` as the first argument: :func:`calibration_counts` of both worlds."""
    args = sys.argv[1:] if argv is None else argv
    if args[:1] == ["calibrate"]:
        from .robot import WORLD_PROFILES

        cal: dict[str, Any] = {}
        for world, prof in WORLD_PROFILES.items():
            cal[world] = calibration_counts(
                world=prof["offices"],
                session=prof["session"],
                similarity=prof["similarity"],
                blur=prof["blur"],
                noise=prof["noise"],
                jpeg_quality=prof["jpeg_quality"],
                edge_params=prof["extractor"],
            )
        cal["paper_table2"] = PAPER_TABLE2
        json.dump(cal, sys.stdout, indent=1)
        sys.stdout.write("\n")
        return cal
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
