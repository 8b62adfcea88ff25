import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hs

from fingerloc.errors import DataFormatError, InvalidParameterError
from fingerloc.io.carmen import ReadStats
from fingerloc.io.rosbag import bag_info, is_bag_path, iter_bag_scans, read_bag_scans, scan_topics

from ._bags import (
    BACK_STAMPS,
    FRONT_STAMPS,
    bag_path,
    odom_msg,
    odom_pose,
    on_walls,
    rot,
    scan_msg,
    store,
    tf3,
    true_corner_bearings,
    truth_pose,
    write_bag,
    write_robot_bag,
)
from ._cli import run_cli as _run


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_scans_with_odometry_round_trip(tmp_path, ros1):
    p = write_bag(
        bag_path(tmp_path, ros1),
        ros1,
        scans=[(10.0, "/scan", {}), (11.0, "/scan", {})],
        odom=[(9.95, (1.0, 2.0, 0.3)), (10.5, (5.0, 5.0, 0.0)), (11.02, (3.0, 4.0, -1.0))],
    )
    assert is_bag_path(p)
    assert scan_topics(p) == ["/scan"]
    st = ReadStats()
    scans = list(iter_bag_scans(p, stats=st))
    assert len(scans) == 2 and st.scans == 2
    s = scans[0]
    assert s.ranges.size == 271 and s.max_range == pytest.approx(30.0)
    assert np.degrees(s.bearings[0]) == pytest.approx(-135.0, abs=1e-4)
    assert np.degrees(s.bearings[-1]) == pytest.approx(135.0, abs=1e-4)
    assert np.degrees(s.fov[0][1]) == pytest.approx(271.0, abs=1e-3)
    assert np.isinf(s.ranges[3:6]).all()  # inf, below range_min, above range_max
    assert s.ranges[0] == pytest.approx(1.0)
    assert np.allclose(s.intensities[:3], [0, 100, 200])
    assert s.timestamp == pytest.approx(10.0)
    # poses interpolated to the stamp between the two odometry samples around it (heading the short way)
    f = 0.05 / 0.55
    assert s.pose == pytest.approx((1.0 + 4.0 * f, 2.0 + 3.0 * f, 0.3 - 0.3 * f))
    f = 0.5 / 0.52
    assert scans[1].pose == pytest.approx((5.0 - 2.0 * f, 5.0 - f, -f))


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_poses_from_tf_chain_and_sensor_offset(tmp_path, ros1):
    p = write_bag(
        bag_path(tmp_path, ros1),
        ros1,
        scans=[(20.0, "/scan", {"intensities": False})],
        tf=[
            (19.99, [("map", "odom", (1.0, 0.0, math.pi / 2)), ("odom", "base_link", (2.0, 0.0, 0.0))]),
        ],
        tf_static=[(0.5, [("base_link", "laser", (0.3, 0.0, math.pi))])],
    )
    (s,) = read_bag_scans(p)
    # base_link in map: map->odom (1, 0, 90 deg) then odom->base_link (2, 0, 0): (1, 2, 90 deg)
    assert s.pose == pytest.approx((1.0, 2.0, math.pi / 2))
    assert s.sensor_offset[:2] == pytest.approx((0.3, 0.0))
    assert abs(abs(s.sensor_offset[2]) - math.pi) < 1e-9
    assert s.intensities is None
    (s2,) = read_bag_scans(p, pose_source="none")
    assert s2.pose is None


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_topic_choice(tmp_path, ros1):
    p = write_bag(
        bag_path(tmp_path, ros1),
        ros1,
        scans=[(1.0, "/front/scan", {}), (1.5, "/rear/scan", {"n": 181, "fov_deg": 180.0})],
    )
    with pytest.raises(InvalidParameterError, match="/front/scan, /rear/scan"):
        read_bag_scans(p)
    (s,) = read_bag_scans(p, topic="/rear/scan")
    assert s.ranges.size == 181
    with pytest.raises(InvalidParameterError, match=r"no topic '/nope'.*laser topics: /front/scan, /rear/scan"):
        read_bag_scans(p, topic="/nope")
    assert s.pose is None  # no pose source in this bag


def test_no_laser_topic(tmp_path):
    p = write_bag(tmp_path / "o.bag", True, odom=[(1.0, (0.0, 0.0, 0.0))])
    with pytest.raises(DataFormatError, match=r"no sensor_msgs/msg/LaserScan topic.*topics: /odom"):
        read_bag_scans(p)
    assert bag_info(p).topics == {"/odom": ("nav_msgs/msg/Odometry", 1)}


def test_pose_gap(tmp_path):
    p = write_bag(tmp_path / "g.bag", True, scans=[(10.0, "/scan", {})], odom=[(5.0, (1.0, 1.0, 0.0))])
    (s,) = read_bag_scans(p)
    assert s.pose is None
    (s,) = read_bag_scans(p, max_pose_gap=10.0)
    assert s.pose == pytest.approx((1.0, 1.0, 0.0))


def test_pose_source_errors(tmp_path):
    p = write_bag(tmp_path / "e.bag", True, scans=[(10.0, "/scan", {})])
    with pytest.raises(InvalidParameterError, match="no /tf"):
        read_bag_scans(p, pose_source="tf")
    with pytest.raises(InvalidParameterError, match="pose_source"):
        read_bag_scans(p, pose_source="gps")
    with pytest.raises(InvalidParameterError, match="odometry topics: none"):
        read_bag_scans(p, odom_topic="/odom")


def test_not_a_bag(tmp_path):
    p = tmp_path / "x.bag"
    p.write_bytes(b"this is not a bag")
    with pytest.raises(DataFormatError, match="not a readable ROS bag"):
        read_bag_scans(p)
    with pytest.raises(DataFormatError, match="no such file"):
        read_bag_scans(tmp_path / "missing.bag")


def test_is_bag_path(tmp_path):
    for name in ["a.bag", "b.db3", "c.mcap"]:
        assert is_bag_path(name)
    assert not is_bag_path("a.log.gz")
    d = tmp_path / "ros2"
    d.mkdir()
    assert not is_bag_path(d)
    (d / "metadata.yaml").write_text("x")
    assert is_bag_path(d)


def test_ros2_storage_file_directly(tmp_path):
    p = write_bag(tmp_path / "r2", False, scans=[(1.0, "/scan", {})])
    (db,) = [f for f in p.iterdir() if f.suffix in (".db3", ".mcap")]
    assert is_bag_path(db)
    assert len(read_bag_scans(db)) == 1


# ---- fingerloc features on bags ------------------------------------------------------------------


def _box_with_beacons(n=271, fov_deg=270.0):
    """A 270 deg scan from the middle of a 6 x 4 m box; two bright 4-beam stripes on the walls."""
    a = -math.radians(fov_deg) / 2 + math.radians(fov_deg) / (n - 1) * np.arange(n)
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(c > 1e-12, 3.0 / c, np.where(c < -1e-12, -3.0 / c, np.inf))
        ty = np.where(s > 1e-12, 2.0 / s, np.where(s < -1e-12, -2.0 / s, np.inf))
    r = np.minimum(tx, ty).astype(np.float32)
    inten = np.full(n, 400.0, np.float32) + np.random.default_rng(0).normal(0, 20, n).astype(np.float32)
    inten[100:104] = 9000.0
    inten[200:204] = 3000.0
    return r, inten


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_features_command_on_a_bag(tmp_path, capsys, ros1):
    ts = store(ros1)
    r, inten = _box_with_beacons()
    p = bag_path(tmp_path, ros1)
    write_bag(p, ros1, scans=[(1.0, "/front/scan", {"ranges": r.copy()}), (1.0, "/rear/scan", {"ranges": r.copy()})])
    # write_bag puts its own intensities; rewrite with the beacon intensities in a second bag
    p2 = bag_path(tmp_path, ros1, "beacons")
    if ros1:
        from rosbags.rosbag1 import Writer

        w, ser = Writer(p2), ts.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer

        w, ser = Writer(p2, version=9), ts.serialize_cdr
    with w:
        conn = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        msg = scan_msg(ts, 2.0, ros1, ranges=r.copy())
        msg.ranges[3:6] = r[3:6]  # keep the walls whole
        msg.intensities = inten
        w.write(conn, int(2e9), ser(msg, "sensor_msgs/msg/LaserScan"))
    out = tmp_path / "o.jsonl"
    code, text, err = _run(capsys, "features", p2, "--json", out)
    assert code == 0, err
    assert "base frame: none (no /tf_static mount for lidar frame 'laser'" in err  # the choice is reported
    (row,) = text.strip().splitlines()
    assert " B(2): " in row and " c(2): " in row and " Ex(0): " in row  # two corners within 270 deg, two beacons
    from fingerloc.io.jsonl import read_observations

    (obs,) = read_observations(out)
    assert obs.b.size == 2 and np.degrees(obs.fov[0][1]) == pytest.approx(271.0, abs=0.01)
    # an absolute threshold above the dimmer stripe keeps only the bright one
    code, text, err = _run(capsys, "features", p2, "--beacon-threshold", "5000")
    assert code == 0, err
    assert " B(1): " in text
    # two laser topics: --topic is required and the error lists them
    code, _, err = _run(capsys, "features", p)
    assert code == 2 and "/front/scan, /rear/scan" in err
    code, text, err = _run(capsys, "features", p, "--topic", "/rear/scan")
    assert code == 0 and len(text.strip().splitlines()) == 1


# ---- two lidars back to back, one upside down: mounts, poses, merging ----------------


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_two_lidars_back_to_back_merged(tmp_path, ros1):
    from fingerloc.angles import dist_as
    from fingerloc.features.laser import observation_from_scan
    from fingerloc.io.rosbag import BagReadStats

    p = write_robot_bag(bag_path(tmp_path, ros1), ros1)
    plans = []
    st = BagReadStats()
    scans = read_bag_scans(p, topic=["/scan_front", "/scan_back"], stats=st, on_plan=plans.append)
    (plan,) = plans
    assert plan.base_frame == "base_footprint" and "root of the static transforms" in plan.base_frame_origin
    assert plan.pose_source == "tf:map"
    assert plan.pair_tolerance == pytest.approx(0.05)  # half the 0.1 s scan period
    front, back = plan.mounts
    assert not front.mirrored and back.mirrored and back.tilt == pytest.approx(0.0, abs=1e-9)
    assert back.xyz == pytest.approx((-0.30, -0.05, 0.25))
    assert "upside down" in plan.describe()
    assert len(scans) == 3 and st.unpaired == 1 and st.lines == 7  # 10.3 has no back scan within 0.05 s
    for t, s in zip(FRONT_STAMPS, scans, strict=False):
        truth = truth_pose(t)
        assert s.timestamp == pytest.approx(t)
        assert s.pose[:2] == pytest.approx(truth[:2], abs=1e-6)
        assert math.remainder(s.pose[2] - truth[2], 2 * math.pi) == pytest.approx(0.0, abs=1e-6)
        assert s.sensor_offset == (0.0, 0.0, 0.0)
        assert s.fov == ((-math.pi, 2 * math.pi),)  # two 270 deg lidars: the full circle
        assert np.all(np.diff(s.bearings) > 0)
        # every return, seen from the robot's origin at the front stamp, lies on a wall
        # (the back scan, 20 ms later, is moved by the robot's motion in between)
        assert np.isfinite(s.ranges).all() and s.ranges.size > 700  # 360 deg at 0.5 deg, overlaps split
        assert on_walls(s, truth).max() < 2e-3
        # the four room corners, at their true bearings within 0.5 deg
        obs = observation_from_scan(s)
        err = np.abs(np.degrees(dist_as(obs.c[:, None], true_corner_bearings(truth)[None, :])))
        assert obs.c.size == 4 and err.min(axis=1).max() < 0.5 and err.min(axis=0).max() < 0.5
        assert obs.full_fov


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_upside_down_lidar_alone_is_mirrored(tmp_path, ros1):
    p = write_robot_bag(bag_path(tmp_path, ros1), ros1)
    scans = read_bag_scans(p, topic="/scan_back")
    assert len(scans) == 3
    for t, s in zip(BACK_STAMPS, scans, strict=True):
        assert s.sensor_offset[:2] == pytest.approx((-0.30, -0.05))
        assert abs(abs(s.sensor_offset[2]) - math.pi) < 1e-9
        assert np.all(np.diff(s.bearings) > 0)
        assert on_walls(s, truth_pose(t)).max() < 2e-3
        # the raw (mirrored) bearings would put the returns off the walls
    (raw,) = read_bag_scans(p, topic="/scan_back", base_frame="laser_back", pose_source="none")[:1]
    assert raw.sensor_offset == (0.0, 0.0, 0.0) and raw.pose is None


def test_merged_error_is_large_without_mirroring(tmp_path):
    """The oracle can fail: the back lidar taken as upright (a yaw of 180 deg only) leaves the walls."""
    from fingerloc.sensors import Scan

    p = write_robot_bag(tmp_path / "m.bag", True)
    (s,) = read_bag_scans(p, topic="/scan_back")[:1]
    wrong = Scan(
        ranges=s.ranges[::-1],
        bearings=-s.bearings[::-1],
        max_range=s.max_range,
        sensor_offset=s.sensor_offset,
    )
    assert on_walls(wrong, truth_pose(BACK_STAMPS[0])).max() > 0.5


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_frame_errors_name_the_frames(tmp_path, ros1):
    p = write_robot_bag(bag_path(tmp_path, ros1), ros1, extra_static=[("world", "marker", ((1.0, 0, 0), (0, 0, 0)))])
    with pytest.raises(DataFormatError, match=r"base frame 'nope' is not in the /tf_static or /tf tree.*base_link"):
        read_bag_scans(p, topic="/scan_front", base_frame="nope")
    with pytest.raises(
        DataFormatError, match=r"no transform chain from lidar frame 'laser_front'.*base frame 'marker'"
    ):
        read_bag_scans(p, topic="/scan_front", base_frame="marker")
    with pytest.raises(DataFormatError, match=r"pose frame 'nope'"):
        read_bag_scans(p, topic="/scan_front", pose_source="tf:nope")
    with pytest.raises(InvalidParameterError, match=r"no nav_msgs/msg/Odometry topic '/odom'"):
        read_bag_scans(p, topic="/scan_front", pose_source="odom:/odom")
    with pytest.raises(InvalidParameterError, match=r"--pose-source must be .* got 'gps:x'"):
        read_bag_scans(p, topic="/scan_front", pose_source="gps:x")
    with pytest.raises(InvalidParameterError, match=r"'/scan_front' given twice"):
        read_bag_scans(p, topic=["/scan_front", "/scan_front"])
    # base_link given: mounts relative to it, poses from the chain map -> ... -> base_link
    scans = read_bag_scans(p, topic="/scan_front", base_frame="base_link", pose_source="tf:odom")
    t = FRONT_STAMPS[0]
    assert scans[0].pose == pytest.approx(odom_pose(t), abs=1e-6)
    assert scans[0].sensor_offset == pytest.approx((0.30, 0.05, 0.0))


def test_cli_features_merges_bag_topics(tmp_path, capsys):
    from fingerloc.io.jsonl import read_observations

    p = write_robot_bag(tmp_path / "r.bag", True)
    out = tmp_path / "o.jsonl"
    code, text, err = _run(capsys, "features", p, "--topic", "/scan_front", "--topic", "/scan_back", "--json", out)
    assert code == 0, err
    assert len(text.strip().splitlines()) == 3 and all(" c(4): " in row for row in text.splitlines())
    assert "base frame 'base_footprint'" in err and "upside down" in err and "dropped 1 time step" in err
    obs = read_observations(out)
    assert len(obs) == 3 and all(o.full_fov for o in obs)
    assert obs[0].pose == pytest.approx(truth_pose(FRONT_STAMPS[0]), abs=1e-4)
    for args, needle in (
        (["--topic", "/scan_front", "--base-frame", "nope"], "base frame 'nope'"),
        (["--topic", "/scan_front", "--topic", "/nope"], "no topic '/nope'"),
        (["--topic", "/scan_front", "--pose-source", "odom:/odom"], "'/odom'"),
        (["--topic", "/scan_front", "--pose-source", "gps"], "--pose-source"),
    ):
        code, _, err = _run(capsys, "features", p, "--kind", "bag", *args)
        assert code == 2 and err.startswith("error: ") and needle in err and len(err.strip().splitlines()) == 1, err


# ---- the planar reduction and the merge, against independent computations -----------------------


@settings(max_examples=60, deadline=None)
@given(
    roll=hs.sampled_from([0.0, math.pi]),
    d_roll=hs.floats(-0.3, 0.3),
    pitch=hs.floats(-0.3, 0.3),
    yaw=hs.floats(-math.pi, math.pi),
    xyz=hs.tuples(hs.floats(-1, 1), hs.floats(-1, 1), hs.floats(-1, 1)),
    fov_deg=hs.sampled_from([90.0, 270.0, 359.0]),
)
def test_reduce_to_plane_matches_projected_3d_points(roll, d_roll, pitch, yaw, xyz, fov_deg):
    """Oracle: rotate each 3D return with scipy and drop z; bearings must increase, mirrored iff upside down."""
    from fingerloc.io.rosbag import Transform3, reduce_to_plane
    from fingerloc.sensors import Scan

    r3 = rot((roll + d_roll, pitch, yaw))
    q = r3.as_quat()
    mount = Transform3(xyz, tuple(q))
    n = 181
    phi = -math.radians(fov_deg) / 2 + math.radians(fov_deg) / (n - 1) * np.arange(n)
    r = 2.0 + np.sin(3 * phi)
    scan = Scan(ranges=r, bearings=phi, max_range=10.0, intensities=np.arange(n, dtype=float))
    out = reduce_to_plane(scan, mount)
    pts3 = r3.apply(np.column_stack([r * np.cos(phi), r * np.sin(phi), np.zeros(n)])) + np.asarray(xyz)
    want = pts3[:, :2]
    upside_down = r3.as_matrix()[2, 2] < 0
    if upside_down:
        want = want[::-1]
    assert np.allclose(out.points(), want, atol=1e-9)
    assert np.all(np.diff(out.bearings) > 0)
    assert np.allclose(out.intensities, np.arange(n)[::-1] if upside_down else np.arange(n))


def test_reduce_to_plane_refuses_a_steep_lidar():
    from fingerloc.io.rosbag import Transform3, reduce_to_plane
    from fingerloc.sensors import Scan

    scan = Scan(ranges=np.ones(10), bearings=np.linspace(-1, 1, 10))
    steep = Transform3((0, 0, 0), tuple(rot((0.0, math.radians(40), 0.0)).as_quat()))
    with pytest.raises(DataFormatError, match=r"lidar frame 'tilted' is tilted 40.0 deg .*max_tilt_deg=30"):
        reduce_to_plane(scan, steep, frame="tilted")
    phi, c = np.linspace(-1, 1, 10), math.cos(math.radians(40))
    assert reduce_to_plane(scan, steep, max_tilt_deg=45).ranges == pytest.approx(np.hypot(np.cos(phi) * c, np.sin(phi)))


def test_merge_scans_blind_sectors_and_overlap():
    """Two 170 deg lidars back to back leave two 10 deg blind sectors; two 270 deg ones overlap and split."""
    from fingerloc.io.rosbag import merge_scans
    from fingerloc.sensors import Scan

    def lidar(fov_deg, offset, n):
        phi = np.radians(np.linspace(-fov_deg / 2, fov_deg / 2, n))
        return Scan(ranges=np.full(n, 3.0), bearings=phi, max_range=10.0, sensor_offset=offset)

    front, back = lidar(170.0, (0.2, 0.0, 0.0), 171), lidar(170.0, (-0.2, 0.0, math.pi), 171)
    m = merge_scans([front, back], pose=(1.0, 2.0, 0.5))
    assert m.pose == (1.0, 2.0, 0.5) and m.sensor_offset == (0.0, 0.0, 0.0)
    assert m.ranges.size == 342  # no overlap: every beam kept
    fov = sorted((round(math.degrees(s) % 360, 6), round(math.degrees(w), 6)) for s, w in m.fov)
    assert fov == [(94.5, 171.0), (274.5, 171.0)]  # -85.5..85.5 and 94.5..265.5: half a step beyond the ends
    # points are the lidars' points, seen from the robot's origin
    both = np.concatenate([front.points(), back.points()])
    got = m.points()
    assert np.allclose(np.sort(np.round(got, 9), axis=0), np.sort(np.round(both, 9), axis=0))
    # overlap: each bearing from the lidar whose field of view is centred nearer
    f2, b2 = lidar(270.0, (0.0, 0.0, 0.0), 271), lidar(270.0, (0.0, 0.0, math.pi), 271)
    m2 = merge_scans([f2, b2])
    assert m2.fov == ((-math.pi, 2 * math.pi),)
    assert np.all(np.diff(m2.bearings) > 0) and m2.ranges.size in (359, 360, 361)
    with pytest.raises(InvalidParameterError, match="at least one scan"):
        merge_scans([])


def test_scan_coverage_validation():
    from fingerloc.sensors import Scan

    s = Scan(ranges=np.ones(3), bearings=[0.0, 0.1, 0.2], coverage=((0.0, 1.0), (2.0, 0.5)))
    assert s.fov == ((0.0, 1.0), (2.0, 0.5))
    with pytest.raises(InvalidParameterError, match="coverage"):
        Scan(ranges=np.ones(3), bearings=[0.0, 0.1, 0.2], coverage=((0.0, 0.0),))


def test_odometry_child_frame_and_a_mount_on_tf(tmp_path):
    """Odometry of base_link composed to base_footprint; a lidar on a /tf link (a turning head) is
    resolved at each scan's stamp, and a scan outside that link's samples is dropped and counted."""
    from fingerloc.io.rosbag import BagReadStats

    ts = store(True)
    p = tmp_path / "h.bag"
    from rosbags.rosbag1 import Writer

    LS, TF, OD = "sensor_msgs/msg/LaserScan", "tf2_msgs/msg/TFMessage", "nav_msgs/msg/Odometry"
    items = []
    with Writer(p) as w:
        c_scan = w.add_connection("/scan", LS, typestore=ts)
        c_tf = w.add_connection("/tf", TF, typestore=ts)
        c_static = w.add_connection("/tf_static", TF, typestore=ts)
        c_od = w.add_connection("/odom", OD, typestore=ts)
        static = [("base_footprint", "base_link", ((0.1, 0.0, 0.2), (0.0, 0.0, 0.0)))]
        items.append((1.0, c_static, TF, tf3(ts, 1.0, static, True)))
        for t, yaw in ((2.0, 0.0), (2.2, 0.4)):  # the head turns from 0 to 0.4 rad
            items.append((t, c_tf, TF, tf3(ts, t, [("base_link", "head", ((0.0, 0.0, 0.3), (0, 0, yaw)))], True)))
        for t in (2.0, 2.2):
            items.append((t, c_od, OD, odom_msg(ts, t, (t, 0.0, 0.0), True)))  # base_link at x = t in odom
        for t in (2.1, 3.0):
            items.append((t, c_scan, LS, scan_msg(ts, t, True, frame="head")))
        for t, c, typ, msg in sorted(items, key=lambda x: x[0]):
            w.write(c, int(t * 1e9), ts.serialize_ros1(msg, typ))
    st = BagReadStats()
    plans = []
    # by default the base frame is the root of the lidar's /tf_static tree: the head itself here
    assert read_bag_scans(p, on_plan=plans.append)[0].sensor_offset == (0.0, 0.0, 0.0)
    assert plans.pop().base_frame == "head"
    (s,) = read_bag_scans(p, base_frame="base_footprint", stats=st, on_plan=plans.append)
    assert st.unmounted == 1  # at 3.0 the head's link is 0.8 s from its last sample
    assert plans[0].base_frame == "base_footprint" and plans[0].pose_source == "odom:/odom"
    assert "mount moving" in plans[0].describe()
    assert s.sensor_offset == pytest.approx((0.1, 0.0, 0.2))  # slerp half way: 0.2 rad
    assert s.pose == pytest.approx((2.1 - 0.1, 0.0, 0.0))  # base_link at 2.1, base_footprint 0.1 m behind


def test_tf_pose_source_needs_a_moving_base(tmp_path):
    p = write_bag(
        tmp_path / "s.bag",
        True,
        scans=[(1.0, "/scan", {})],
        tf=[(1.0, [("odom", "other", (1.0, 0.0, 0.0))])],
        tf_static=[(0.5, [("base_link", "laser", (0.3, 0.0, 0.0))])],
    )
    with pytest.raises(DataFormatError, match=r"base frame 'base_link' does not move in /tf"):
        read_bag_scans(p, pose_source="tf")
    (s,) = read_bag_scans(p)  # auto: no odometry, the base does not move in /tf: no pose
    assert s.pose is None and s.sensor_offset == pytest.approx((0.3, 0.0, 0.0))


def test_empty_bag_topic(tmp_path):
    ts = store(True)
    from rosbags.rosbag1 import Writer

    p = tmp_path / "e.bag"
    with Writer(p) as w:
        w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        c = w.add_connection("/scan2", "sensor_msgs/msg/LaserScan", typestore=ts)
        w.write(c, int(1e9), ts.serialize_ros1(scan_msg(ts, 1.0, True), "sensor_msgs/msg/LaserScan"))
    assert read_bag_scans(p, topic="/scan") == []
    with pytest.raises(DataFormatError, match="scan topic /scan has no messages"):
        read_bag_scans(p, topic=["/scan2", "/scan"])


@settings(max_examples=40, deadline=None)
@given(
    links=hs.lists(
        hs.tuples(
            hs.tuples(hs.floats(-2, 2), hs.floats(-2, 2), hs.floats(-2, 2)),
            hs.tuples(hs.floats(-3.2, 3.2), hs.floats(-1.5, 1.5), hs.floats(-3.2, 3.2)),
        ),
        min_size=4,
        max_size=4,
    )
)
def test_transform_tree_matches_scipy_chain(links):
    """Tree a <- b <- c and a <- d <- e: T_e_c through the common ancestor a, against scipy's composition."""
    from scipy.spatial.transform import Rotation

    from fingerloc.io.frames import Transform3, TransformTree

    tree = TransformTree()
    mats = {}
    for (parent, child), (xyz, rpy) in zip([("a", "b"), ("b", "c"), ("a", "d"), ("d", "e")], links, strict=True):
        rot = Rotation.from_euler("xyz", rpy)
        tree.add(parent, child, 0.0, Transform3(xyz, tuple(rot.as_quat())), static=True)
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = rot.as_matrix(), xyz
        mats[child] = m
    a_c = mats["b"] @ mats["c"]
    a_e = mats["d"] @ mats["e"]
    want = np.linalg.inv(a_e) @ a_c
    got = tree.transform("e", "c", 5.0, 0.1)
    assert got is not None
    assert np.allclose(got.matrix(), want[:3, :3], atol=1e-9) and np.allclose(got.t, want[:3, 3], atol=1e-9)
    assert tree.transform("c", "nowhere", 0.0, 0.1) is None


def test_transform_series_interpolation_rule():
    from fingerloc.io.frames import Transform3, TransformSeries

    s = TransformSeries()
    s.add(2.0, Transform3.from_planar((2.0, 0.0, 1.0)))
    s.add(1.0, Transform3.from_planar((0.0, 0.0, 3.0)))  # out of order; 3 rad -> 1 rad the short way
    s.freeze()
    assert s.at(1.5, 0.5).planar() == pytest.approx((1.0, 0.0, 2.0))
    assert s.at(1.1, 0.5).planar() == pytest.approx((0.2, 0.0, 2.8))
    assert s.at(2.3, 0.5).planar() == pytest.approx((2.0, 0.0, 1.0))  # nearest within the gap
    assert s.at(1.5, 0.4) is None and s.at(2.6, 0.5) is None
    wrap = TransformSeries()
    wrap.add(0.0, Transform3.from_planar((0.0, 0.0, 3.0)))
    wrap.add(1.0, Transform3.from_planar((0.0, 0.0, -3.0)))  # across +-pi: through pi, not through 0
    wrap.freeze()
    assert abs(wrap.at(0.5, 1.0).planar()[2]) == pytest.approx(math.pi)


def test_merged_full_circle_bearings_start_at_minus_pi(tmp_path):
    p = write_robot_bag(tmp_path / "c.bag", True)
    for s in read_bag_scans(p, topic=["/scan_back", "/scan_front"]):  # the upside-down lidar as reference
        assert -math.pi <= s.bearings[0] < -math.pi + 0.02 and math.pi - 0.02 < s.bearings[-1] < math.pi
        assert on_walls(s, s.pose).max() < 2e-3


def test_fixed_joints_on_tf_count_as_static(tmp_path):
    """Older bags send fixed joints on /tf (as tf/tfMessage) again and again: base_link -> laser is a
    mount, odom -> base_link (even while the robot stands still) is not."""
    tf = [
        (1.0 + 0.1 * k, [("base_link", "laser", (0.2, 0.0, 0.5)), ("odom", "base_link", (0.0, 0.0, 0.0))])
        for k in range(5)
    ]
    p = write_bag(tmp_path / "old.bag", True, scans=[(1.2, "/scan", {})], tf=tf, tf_type="tf/msg/tfMessage")
    plans = []
    (s,) = read_bag_scans(p, on_plan=plans.append)
    assert plans[0].base_frame == "base_link" and plans[0].mounts[0].static
    assert s.sensor_offset == pytest.approx((0.2, 0.0, 0.5))
    assert s.pose == pytest.approx((0.0, 0.0, 0.0)) and plans[0].pose_source == "tf:odom"


def test_robot_bag_with_odometry_along_a_trajectory(tmp_path):
    """The shared robot bag on a longer run with an odometry topic: auto picks it, poses follow the truth."""

    def pose(t):
        return (1.5 + 0.5 * (t - 10.0), 3.0 + 0.2 * math.sin(t - 10.0), 0.1 * (t - 10.0))

    stamps = tuple(10.0 + 0.5 * k for k in range(11))
    p = write_robot_bag(tmp_path / "run", False, front_stamps=stamps, back_stamps=stamps, pose=pose, odom_topic="/odom")
    plans = []
    scans = read_bag_scans(p, topic=["/scan_front", "/scan_back"], on_plan=plans.append)
    assert plans[0].pose_source == "odom:/odom" and len(scans) == 11
    for t, s in zip(stamps, scans, strict=True):
        assert s.pose == pytest.approx(odom_pose(t, pose), abs=1e-6)  # odometry: base_footprint in odom
        assert on_walls(s, pose(t)).max() < 2e-3


@settings(max_examples=50, deadline=None)
@given(
    offsets=hs.lists(
        hs.tuples(hs.floats(-0.5, 0.5), hs.floats(-0.5, 0.5), hs.floats(-math.pi, math.pi)), min_size=1, max_size=3
    ),
    fov_deg=hs.sampled_from([90.0, 180.0, 270.0]),
    seed=hs.integers(0, 1000),
)
def test_merge_scans_keeps_points_and_orders_bearings(offsets, fov_deg, seed):
    """Every merged return is one of the lidars' returns, seen from the robot's origin; bearings increase;
    the coverage is the union of the fields of view; without overlap nothing is dropped."""
    from fingerloc.io.rosbag import merge_scans
    from fingerloc.observation import Observation
    from fingerloc.sensors import Scan

    rng = np.random.default_rng(seed)
    n = 91
    scans = []
    for off in offsets:
        phi = np.radians(np.linspace(-fov_deg / 2, fov_deg / 2, n))
        r = rng.uniform(1.0, 5.0, n)
        r[rng.random(n) < 0.1] = np.inf
        scans.append(Scan(ranges=r, bearings=phi, max_range=10.0, sensor_offset=off))
    m = merge_scans(scans)
    assert np.all(np.diff(m.bearings) > 0) and m.bearings[-1] - m.bearings[0] < 2 * math.pi
    pts = np.concatenate([s.points() for s in scans])
    got = m.points()
    d = np.min(np.linalg.norm(got[:, None, :] - pts[None, :, :], axis=2), axis=1)
    assert d.max() < 1e-9
    # coverage: the union of the lidars' fields of view, as Observation measures it
    want = Observation(fov=tuple(f for s in scans for f in s.fov)).fov_coverage()
    assert Observation(fov=m.fov).fov_coverage() == pytest.approx(want, abs=1e-9)
    if len(scans) == 1:
        assert m.ranges.size == n and np.isfinite(m.ranges).sum() == np.isfinite(scans[0].ranges).sum()
