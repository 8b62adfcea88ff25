"""``fingerloc bench features``: precision and recall of the feature extractors in simulation.

Protocol: ``n_offices`` simulated offices (:func:`fingerloc.sim.make_offices`,
default similarity); in each, ``n_poses`` poses drawn uniformly within
``radius`` metres of the office's anchor (rejecting poses closer than 0.3 m to
an obstacle), with a uniform random heading. At each pose the simulator
produces a 360 deg scan, a cylindrical panorama (optionally JPEG-compressed)
and a raw omnidirectional donut image; the extractors of
:mod:`fingerloc.features` run on these raw data only (the donut is unwarped
with :func:`~fingerloc.features.vision.unwarp_omni` from its mirror geometry).
Their bearings are matched one-to-one with the simulator's ground truth
(:func:`fingerloc.sim.true_features`) by a minimum-cost assignment, a pair
counting when its bearings differ by at most ``tol_deg``.

Reported per feature type: true and extracted features per measurement,
precision ``TP / extracted``, recall ``TP / true``, the mean absolute bearing
error of the matched pairs (degrees) and, for colour patches, the part of
matched patches with the right hue letter and their mean absolute hue error
(degrees; the truth is the poster's albedo hue).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from .._types import FArray
from ..angles import dist_as
from ..errors import InvalidParameterError
from ..fingerprint import hue_letter
from .speed import best_time, section

__all__ = ["ExtractorCounts", "match_bearings", "run_extractor_bench"]


#: Feature types evaluated, in report order ("VE/omni", "CP/omni": from the unwarped donut).
TYPES = ("c", "Ex", "B", "VE", "CP", "VE/omni", "CP/omni")


def match_bearings(found: FArray, truth: FArray, tol: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """One-to-one matching of two bearing sets within ``tol`` radians (minimum total distance).

    Returns
    -------
    i_found, i_truth : ndarray of int, shape (k,)
        Indices of the matched pairs.
    """
    f = np.asarray(found, dtype=np.float64).reshape(-1)
    t = np.asarray(truth, dtype=np.float64).reshape(-1)
    if f.size == 0 or t.size == 0:
        return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
    d = np.abs(dist_as(f[:, None], t[None, :]))
    big = 1e6
    cost = np.where(d <= tol, d, big)
    ri, ci = linear_sum_assignment(cost)
    ok = cost[ri, ci] < big
    return ri[ok].astype(np.int64), ci[ok].astype(np.int64)


@dataclass
class ExtractorCounts:
    """Running totals of one feature type."""

    true: int = 0
    found: int = 0
    tp: int = 0
    err_sum_deg: float = 0.0
    hue_right: int = 0
    hue_err_sum_deg: float = 0.0
    measurements: int = 0
    per_measurement: list[tuple[int, int]] = field(default_factory=list)
    with_hue: bool = False

    def add(
        self,
        found: FArray,
        truth: FArray,
        tol: float,
        found_hue: FArray | None = None,
        true_hue: FArray | None = None,
    ) -> None:
        i, j = match_bearings(found, truth, tol)
        self.true += int(truth.size)
        self.found += int(found.size)
        self.tp += int(i.size)
        self.measurements += 1
        self.per_measurement.append((int(truth.size), int(found.size)))
        if i.size:
            self.err_sum_deg += float(np.rad2deg(np.abs(dist_as(found[i], truth[j]))).sum())
            if found_hue is not None and true_hue is not None:
                self.with_hue = True
                herr = np.abs((found_hue[i] - true_hue[j] + 180.0) % 360.0 - 180.0)
                self.hue_err_sum_deg += float(herr.sum())
                self.hue_right += sum(
                    hue_letter(float(a)) == hue_letter(float(b)) for a, b in zip(found_hue[i], true_hue[j], strict=True)
                )

    def summary(self) -> dict[str, Any]:
        m = max(self.measurements, 1)
        out: dict[str, Any] = {
            "true_per_measurement": self.true / m,
            "found_per_measurement": self.found / m,
            "precision": self.tp / self.found if self.found else None,
            "recall": self.tp / self.true if self.true else None,
            "mean_abs_error_deg": self.err_sum_deg / self.tp if self.tp else None,
            "true": self.true,
            "found": self.found,
            "matched": self.tp,
        }
        if self.with_hue:
            out["hue_letter_right"] = self.hue_right / self.tp if self.tp else None
            out["mean_abs_hue_error_deg"] = self.hue_err_sum_deg / self.tp if self.tp else None
        return out


def _poses(world: Any, n: int, radius: float, rng: np.random.Generator) -> list[tuple[float, float, float]]:
    ax, ay = world.anchor
    out: list[tuple[float, float, float]] = []
    tries = 0
    while len(out) < n and tries < 200 * n:
        tries += 1
        r = radius * np.sqrt(rng.uniform())
        a = rng.uniform(-np.pi, np.pi)
        p = np.array([[ax + r * np.cos(a), ay + r * np.sin(a)]])
        if not bool(world.contains(p)[0]) or float(world.clearance(p)[0]) < 0.3:
            continue
        out.append((float(p[0, 0]), float(p[0, 1]), float(rng.uniform(-np.pi, np.pi))))
    return out


def run_extractor_bench(
    *,
    n_offices: int = 10,
    n_poses: int = 10,
    radius: float = 0.7,
    tol_deg: float = 5.0,
    jpeg_quality: int | None = 85,
    omni: bool = True,
    seed: int = 0,
    laser_params: dict[str, Any] | None = None,
    vision_params: dict[str, Any] | None = None,
    on_step: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Precision and recall of every extractor against the simulator's ground truth.

    Parameters
    ----------
    n_offices, n_poses : int
        Offices, and poses per office.
    radius : float
        Poses lie within this distance (metres) of each office's anchor.
    tol_deg : float
        Largest bearing difference of a match, degrees.
    jpeg_quality : int or None
        JPEG quality of the rendered panoramas and donuts (None: no compression).
    omni : bool
        Also evaluate the vision extractors on unwarped omnidirectional images.
    seed : int
        Seed of offices, poses and sensor noise.
    laser_params, vision_params : dict, optional
        Extra keyword parameters of the extractors.
    on_step : callable(done, total), optional
        Progress callback.

    Returns
    -------
    dict
        ``{"protocol": {...}, "types": {type: summary}}``; see the module docstring.
    """
    from .. import sim
    from ..features.laser import extract_laser_features
    from ..features.vision import extract_vision_features, unwarp_omni

    for name, v in (("n_offices", n_offices), ("n_poses", n_poses)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise InvalidParameterError(f"{name} must be a positive integer, got {v!r}")
    if not (np.isfinite(tol_deg) and tol_deg > 0):
        raise InvalidParameterError(f"tol_deg must be > 0, got {tol_deg!r}")
    # separate streams: offices and poses do not depend on which sensors are simulated
    ss = np.random.SeedSequence(seed)
    world_ss, pose_ss, sensor_ss = ss.spawn(3)
    worlds = sim.make_offices(n_offices, random_state=np.random.default_rng(world_ss))
    pose_rng = np.random.default_rng(pose_ss)
    tol = float(np.deg2rad(tol_deg))
    counts = {t: ExtractorCounts() for t in TYPES}
    lp = dict(laser_params or {})
    vp = dict(vision_params or {})
    total = n_offices * n_poses
    done = 0
    for world in worlds:
        for pose in _poses(world, n_poses, radius, pose_rng):
            rng = np.random.default_rng(sensor_ss.spawn(1)[0])
            truth = sim.true_features(world, pose)
            scan = sim.simulate_scan(world, pose, random_state=rng)
            lf = extract_laser_features(scan, **lp)
            counts["c"].add(lf.corners, truth["c"], tol)
            counts["Ex"].add(lf.extremities, truth["Ex"], tol)
            counts["B"].add(lf.beacons, truth["B"], tol)
            pano = sim.render_panorama(world, pose, jpeg_quality=jpeg_quality, random_state=rng)
            vf = extract_vision_features(pano, **vp)
            counts["VE"].add(vf.edges, truth["VE"], tol)
            counts["CP"].add(vf.patches, truth["CP"], tol, vf.patch_hues, truth["CP_hue_deg"])
            if omni:
                im = sim.render_omni(world, pose, jpeg_quality=jpeg_quality, random_state=rng)
                # OmniImage: bearing = phi - forward (counter-clockwise) or forward - phi (clockwise)
                offset = im.forward_angle if im.clockwise else -im.forward_angle
                op = unwarp_omni(
                    im.image, im.center, im.radii[0], im.radii[1], bearing_offset=offset, mirror=im.clockwise
                )
                of = extract_vision_features(op, **vp)
                counts["VE/omni"].add(of.edges, truth["VE"], tol)
                counts["CP/omni"].add(of.patches, truth["CP"], tol, of.patch_hues, truth["CP_hue_deg"])
            done += 1
            if on_step is not None:
                on_step(done, total)
    types = {t: c.summary() for t, c in counts.items() if c.measurements}
    return {
        "protocol": {
            "n_offices": n_offices,
            "n_poses": n_poses,
            "radius_m": radius,
            "tol_deg": tol_deg,
            "jpeg_quality": jpeg_quality,
            "seed": seed,
            "measurements": done,
        },
        "types": types,
    }


# ---------------------------------------------------------------------------
# speed section of ``fingerloc bench speed``


@section("features")
def _speed_features(quick: bool) -> dict[str, Any]:
    """Milliseconds per call of each extractor on simulated raw data (720-beam scan, 720x120 panorama, 640x480 omni)."""
    from .. import sim
    from ..features.laser import extract_laser_features
    from ..features.vision import colour_patches, unwarp_omni, vertical_edges

    world = sim.make_offices(1, random_state=0)[0]
    pose = (world.anchor[0], world.anchor[1], 0.3)
    scan = sim.simulate_scan(world, pose, random_state=1)
    pano = sim.render_panorama(world, pose, random_state=1)
    omni = sim.render_omni(world, pose, random_state=1)
    offset = omni.forward_angle if omni.clockwise else -omni.forward_angle
    repeat = 2 if quick else 5

    def unwarp() -> object:
        return unwarp_omni(omni.image, omni.center, *omni.radii, bearing_offset=offset, mirror=omni.clockwise)

    return {
        "laser_ms_720_beams": 1000 * best_time(lambda: extract_laser_features(scan), repeat=repeat, number=3),
        "vertical_edges_ms_720x120": 1000 * best_time(lambda: vertical_edges(pano), repeat=repeat, number=3),
        "colour_patches_ms_720x120": 1000 * best_time(lambda: colour_patches(pano), repeat=repeat, number=3),
        "unwarp_omni_ms_640x480": 1000 * best_time(unwarp, repeat=repeat, number=3),
    }
