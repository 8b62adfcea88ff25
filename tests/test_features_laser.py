"""Laser feature extraction on synthetic scans with known corners, extremities and beacons."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc.angles import dist_as, wrap
from fingerloc.errors import InvalidParameterError
from fingerloc.features.laser import (
    LaserFeatures,
    extract_laser_features,
    observation_from_scan,
    segment_scan,
)
from fingerloc.sensors import Scan

from .features_world import CARMEN_DIR, DOOR, box, make_scan, read_flaser

TOL = np.deg2rad(2.0)


def assert_bearings(found, expected_deg, tol=TOL):
    exp = np.deg2rad(np.asarray(expected_deg, dtype=float))
    found = np.asarray(found)
    assert found.size == exp.size, (np.rad2deg(found), expected_deg)
    for e in exp:
        assert np.min(np.abs(dist_as(found, e))) < tol, (np.rad2deg(found), expected_deg)


def bearing_deg(x, y):
    return float(np.rad2deg(np.arctan2(y, x)))


# a room 4 m x 3 m, robot off centre
ROOM = box(0.5, 0.3, 2.0, 1.5)
ROOM_CORNERS = [bearing_deg(x, y) for x, y in [(2.5, 1.8), (-1.5, 1.8), (-1.5, -1.2), (2.5, -1.2)]]

DOOR_EX = [bearing_deg(2.5, -0.4), bearing_deg(2.5, 0.5)]


def test_l_corner_and_free_ends():
    walls = [((2, -3), (2, 2)), ((-3, 2), (2, 2))]
    f = extract_laser_features(make_scan(walls))
    assert isinstance(f, LaserFeatures)
    assert_bearings(f.corners, [45.0])
    # the two wall ends border beams without a return
    assert_bearings(f.extremities, [bearing_deg(2, -3), bearing_deg(-3, 2)])
    assert f.beacons.size == 0
    assert f.segments.shape == (2, 2, 2)
    # the fitted lines lie on the walls
    for seg in f.segments:
        assert np.allclose(seg[:, 0], 2.0, atol=0.02) or np.allclose(seg[:, 1], 2.0, atol=0.02)


@pytest.mark.parametrize("noise", [0.0, 0.01, 0.02])
def test_square_room_corners(noise):
    f = extract_laser_features(make_scan(ROOM, noise=noise, seed=3), range_sigma=max(noise, 0.01))
    assert_bearings(f.corners, ROOM_CORNERS)
    assert f.extremities.size == 0
    assert f.segments.shape == (4, 2, 2)


def test_doorway_extremities():
    f = extract_laser_features(make_scan(DOOR, noise=0.01, seed=1))
    assert_bearings(f.corners, ROOM_CORNERS)
    assert_bearings(f.extremities, DOOR_EX)


def test_rotation_moves_bearings():
    turn = np.deg2rad(37.0)
    f0 = extract_laser_features(make_scan(DOOR))
    f1 = extract_laser_features(make_scan(DOOR, pose=(0.0, 0.0, turn)))
    assert_bearings(f1.corners, np.rad2deg(wrap(f0.corners - turn)))
    assert_bearings(f1.extremities, np.rad2deg(wrap(f0.extremities - turn)))


def test_half_scan_sees_only_its_half():
    scan = make_scan(DOOR, n=361, fov_deg=180.0)
    f = extract_laser_features(scan)
    front = [b for b in ROOM_CORNERS if -90 < b < 90]
    assert_bearings(f.corners, front)
    assert_bearings(f.extremities, DOOR_EX)
    obs = observation_from_scan(scan, label="room")
    assert obs.label == "room"
    assert not obs.full_fov
    assert obs.fov == scan.fov
    assert obs.ve.size == 0 and obs.cp.size == 0
    assert np.array_equal(obs.c, f.corners)


def test_coarse_real_like_resolution():
    # 180 beams over 180 deg (1 deg step), 1 cm range quantisation
    scan = make_scan(DOOR, n=180, fov_deg=180.0)
    q = Scan(np.round(scan.ranges, 2), scan.bearings, max_range=scan.max_range)
    f = extract_laser_features(q)
    assert_bearings(f.corners, [b for b in ROOM_CORNERS if -90 < b < 90])
    assert_bearings(f.extremities, DOOR_EX)


def test_occluding_pillar_gives_extremities_not_the_wall_behind():
    walls = [*ROOM, *box(1.2, -0.3, 0.15, 0.15)]
    f = extract_laser_features(make_scan(walls, n=1440))
    # the pillar's two silhouette ends are extremities; the wall it hides has none
    assert f.extremities.size == 2
    mid = np.rad2deg(np.arctan2(-0.3, 1.2))
    assert np.all(np.abs(np.rad2deg(dist_as(np.deg2rad(mid), f.extremities))) < 10)


def test_sensor_offset_gives_robot_frame_bearings():
    scan = make_scan(ROOM)
    # the same beams from a sensor mounted 0.2 m ahead, seen from the robot origin
    shifted = [tuple((x - 0.2, y) for x, y in w) for w in ROOM]
    s2 = make_scan(shifted)
    s2 = Scan(s2.ranges, s2.bearings, max_range=s2.max_range, sensor_offset=(0.2, 0.0, 0.0))
    assert_bearings(extract_laser_features(s2).corners, ROOM_CORNERS)
    assert extract_laser_features(scan).corners.size == 4


def test_beacons_adapt_to_intensity_scale():
    walls = [*ROOM, ((2.49, 0.9), (2.49, 1.0)), ((-1.49, -0.5), (-1.49, -0.4))]
    refl = [100.0] * 4 + [2500.0, 2500.0]
    scan = make_scan(walls, reflect=refl, noise=0.005)
    noise = np.random.default_rng(0).normal(1.0, 0.1, scan.ranges.size)
    inten = np.asarray(scan.intensities) * noise
    exp = [bearing_deg(2.49, 0.95), bearing_deg(-1.49, -0.45)]
    for scale in (1.0, 100.0):
        s = Scan(scan.ranges, scan.bearings, max_range=scan.max_range, intensities=inten * scale)
        f = extract_laser_features(s)
        assert_bearings(f.beacons, exp, tol=np.deg2rad(1.0))
    # the absolute override
    s = Scan(scan.ranges, scan.bearings, max_range=scan.max_range, intensities=inten)
    assert extract_laser_features(s, beacon_threshold=5000.0).beacons.size == 0
    assert extract_laser_features(s, beacon_threshold=1000.0).beacons.size == 2


def test_no_intensities_no_beacons_and_flat_intensities_none():
    scan = make_scan(ROOM)
    assert extract_laser_features(Scan(scan.ranges, scan.bearings)).beacons.size == 0
    flat = Scan(scan.ranges, scan.bearings, intensities=np.full(scan.ranges.size, 7.0))
    assert extract_laser_features(flat).beacons.size == 0


def test_bad_parameters_are_named():
    scan = make_scan(ROOM)
    with pytest.raises(InvalidParameterError, match="split_tol"):
        extract_laser_features(scan, split_tol=-1)
    with pytest.raises(InvalidParameterError, match="no_such"):
        extract_laser_features(scan, no_such=1)


def test_degenerate_scans():
    b = np.linspace(-1, 1, 50)
    assert extract_laser_features(Scan(np.full(50, np.inf), b, max_range=5)).corners.size == 0
    f = extract_laser_features(Scan(np.full(50, 2.0), b))  # an arc: no line, no corner
    assert f.corners.size == 0
    segs, pts = segment_scan(Scan(np.r_[np.full(25, 2.0), np.full(25, 4.0)], b))
    assert len(segs) == 2 and pts.shape == (50, 2)


@pytest.mark.skipif(not CARMEN_DIR.is_dir(), reason="shared CARMEN logs not available")
@pytest.mark.parametrize("name", ["intel-corrected.log.gz", "csail-corrected.log.gz", "freiburg-101-corrected.log.gz"])
def test_real_carmen_scans_give_plausible_features(name):
    scans = read_flaser(name, 8, every=40)
    counts = []
    for s in scans:
        f = extract_laser_features(s)
        assert np.all((f.corners >= -np.pi / 2 - 0.05) & (f.corners <= np.pi / 2 + 0.05))
        counts.append((f.corners.size, f.extremities.size, len(f.segments)))
    c = np.array(counts)
    assert c[:, 2].mean() >= 2  # real walls become lines
    assert c[:, 0].mean() < 10 and c[:, 1].mean() < 15  # and clutter does not explode


def test_surface_seen_edge_on_joins_two_lines_by_corners():
    # a cabinet 0.5 m deep against the far wall, its side seen nearly edge-on from the robot:
    # the side gets only a couple of returns, yet it joins the cabinet front to the wall
    front_x, wall_x = 2.5, 3.0
    y = 0.32
    walls = [((wall_x, -3.0), (wall_x, y)), ((front_x, y), (front_x, 1.5)), ((front_x, y), (wall_x, y))]
    scan = make_scan(walls, n=720, fov_deg=360.0, max_range=8.0)
    # a strict breakpoint rule cuts the side off both lines (it is seen at about 7 deg incidence)
    f = extract_laser_features(scan, breakpoint_angle_deg=10.0)
    exp = [bearing_deg(front_x, y), bearing_deg(wall_x, y)]
    # two corners where the side meets front and wall, and no extremity at the jump between them
    near = [c for c in f.corners if abs(np.rad2deg(c) - 6.7) < 3]
    assert_bearings(near, exp, tol=np.deg2rad(0.8))
    assert not np.any(np.abs(np.rad2deg(f.extremities) - 6.7) < 3)
    # without the bridge rule the near end is (wrongly) an extremity and the corners are lost
    g = extract_laser_features(scan, breakpoint_angle_deg=10.0, bridge_min_points=100)
    assert np.any(np.abs(np.rad2deg(g.extremities) - 6.7) < 3)


@settings(max_examples=25, deadline=None)
@given(scale=st.floats(min_value=1e-3, max_value=1e5), seed=st.integers(0, 10_000))
def test_beacons_invariant_to_intensity_scale(scale, seed):
    walls = [*ROOM, ((2.49, 0.9), (2.49, 1.0))]
    scan = make_scan(walls, reflect=[100.0] * 4 + [2500.0], noise=0.005, seed=seed)
    inten = np.asarray(scan.intensities) * np.random.default_rng(seed).normal(1.0, 0.1, scan.ranges.size)
    a = Scan(scan.ranges, scan.bearings, max_range=scan.max_range, intensities=inten)
    b = Scan(scan.ranges, scan.bearings, max_range=scan.max_range, intensities=inten * scale)
    fa, fb = extract_laser_features(a), extract_laser_features(b)
    assert np.allclose(fa.beacons, fb.beacons)
    assert fa.beacons.size == 1


def test_blind_sectors_between_two_heads_are_borders():
    # two 170 deg heads with 10 deg blind sectors around +-90 deg: walls cut by a blind sector end
    # there without an extremity, and the room's corners are still found
    full = make_scan(DOOR, n=1440)
    keep = np.abs(np.abs(np.rad2deg(full.bearings)) - 90.0) > 5.0
    scan = Scan(full.ranges[keep], full.bearings[keep], max_range=full.max_range)
    f = extract_laser_features(scan)
    assert_bearings(f.corners, ROOM_CORNERS)
    assert_bearings(f.extremities, DOOR_EX)
