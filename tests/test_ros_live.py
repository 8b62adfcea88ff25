"""The live node's robot side without ROS: message conversion (ROS 2 types from rosbags), scans merged and
odometry taken as the bag reader does, waiting, rate limit, parameters, and the answers handed to publishers."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from fingerloc.errors import DataFormatError, InvalidParameterError
from fingerloc.io.frames import Transform3
from fingerloc.io.rosbag import read_bag_scans
from fingerloc.ros.convert import (
    answer_json,
    covariance_6x6,
    fill_pose_with_covariance,
    odometry_from_msg,
    scan_from_msg,
    stamp_seconds,
    transforms_from_msg,
)
from fingerloc.ros.live import LiveInput, LiveLocalizer, NodeConfig
from fingerloc.sensors import Scan

from ._bags import bag_path, odom_msg, scan_msg, store, tf_msg, write_robot_bag
from ._live import StandInTracker


class Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def _bag_messages(path):
    from rosbags.highlevel import AnyReader

    with AnyReader([path], default_typestore=store(False)) as reader:
        for conn, _, raw in reader.messages():
            yield conn.topic, reader.deserialize(raw, conn.msgtype)


def _feed(live, path, topics):
    steps = []
    for topic, msg in _bag_messages(path):
        if topic in topics:
            scan, frame = scan_from_msg(msg)
            steps += live.add_scan(topic, scan, frame)
        elif topic in ("/tf", "/tf_static"):
            live.add_transforms(transforms_from_msg(msg), static=topic == "/tf_static")
            steps += live.ready()
        elif topic == "/odom":
            t, pose, _, child = odometry_from_msg(msg)
            live.add_odometry(t, pose, child)
            steps += live.ready()
    return steps


def _same_scan(a: Scan, b: Scan):
    np.testing.assert_allclose(a.bearings, b.bearings, atol=1e-12)
    np.testing.assert_allclose(a.ranges, b.ranges, rtol=1e-12)
    assert a.sensor_offset == pytest.approx(b.sensor_offset, abs=1e-12)
    assert a.pose == pytest.approx(b.pose, abs=1e-9)
    assert a.timestamp == pytest.approx(b.timestamp, abs=1e-9)


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1-bag", "ros2-bag"])
def test_two_lidars_merge_live_as_the_bag_reader_merges_them(tmp_path, ros1):
    path = write_robot_bag(bag_path(tmp_path, ros1), ros1)
    topics = ("/scan_front", "/scan_back")
    offline = read_bag_scans(path, topic=list(topics), pose_source="tf:odom")
    clock = Clock()
    live = LiveInput(NodeConfig("db", scan_topics=topics, pose_source="tf"), clock=clock)
    steps = _feed(live, path, topics)
    clock.now = 10.0  # the last front scan never gets a back partner: settled (and dropped) after the wait
    steps += live.poll()
    assert len(steps) == len(offline) == 3 and live.stats.unpaired == 1
    assert live.base == "base_footprint"
    for s, b in zip(steps, offline, strict=True):
        _same_scan(s.scan, b)
        assert s.odometry == pytest.approx(b.pose, abs=1e-9) and s.stamp == b.timestamp


def test_odometry_messages_give_the_bag_readers_poses(tmp_path):
    path = write_robot_bag(bag_path(tmp_path, False, "odom"), False, odom_topic="/odom")
    offline = read_bag_scans(path, topic="/scan_back", pose_source="odom:/odom")
    live = LiveInput(NodeConfig("db", scan_topics=("/scan_back",), pose_source="odom", odom_topic="/odom"))
    steps = _feed(live, path, ("/scan_back",))
    assert len(steps) == len(offline) == 3
    for s, b in zip(steps, offline, strict=True):
        _same_scan(s.scan, b)


def _scan(t, n=5):
    return Scan(np.linspace(1.0, 2.0, n), np.linspace(-1.0, 1.0, n), max_range=10.0, timestamp=t)


def _odom(t, x):
    return Transform3.from_planar((x, 0.0, 0.0))


def test_a_scan_waits_for_odometry_at_its_stamp_then_takes_it_interpolated():
    live = LiveInput(NodeConfig("db", pose_source="odom", base_frame="laser"))
    live.add_odometry(0.9, _odom(0.9, 0.9))
    assert live.add_scan("scan", _scan(1.0), "laser") == []
    live.add_odometry(1.1, _odom(1.1, 1.3))
    (step,) = live.ready()
    assert step.odometry == pytest.approx((1.1, 0.0, 0.0)) and step.stamp == 1.0
    assert step.scan.pose == step.odometry and live.base == "laser"


def test_the_first_scan_waits_for_the_static_mount_of_its_frame():
    from fingerloc.ros.convert import TransformLink

    clock = Clock()
    live = LiveInput(NodeConfig("db", pose_source="none"), clock=clock)
    assert live.add_scan("scan", _scan(1.0), "laser") == []  # no /tf_static yet: the base frame cannot be told
    link = TransformLink("base_link", "laser", 0.0, Transform3.from_planar((0.3, 0.0, math.pi / 2)))
    live.add_transforms([TransformLink("base_footprint", "base_link", 0.0, Transform3()), link], static=True)
    (step,) = live.ready()
    assert live.base == "base_footprint" and step.scan.sensor_offset == pytest.approx((0.3, 0.0, math.pi / 2))
    other = LiveInput(NodeConfig("db", pose_source="none"), clock=clock)
    other.add_scan("scan", _scan(1.0), "laser")
    clock.now = 1.0
    (step,) = other.poll()
    assert other.base == "laser" and step.scan.sensor_offset == (0.0, 0.0, 0.0)
    assert "no /tf mount for the lidar frame" in other.stats.notes[0]


def test_a_lidar_without_a_transform_to_the_given_base_frame_is_dropped_and_counted():
    clock = Clock()
    live = LiveInput(NodeConfig("db", pose_source="none", base_frame="base_link"), clock=clock)
    assert live.add_scan("scan", _scan(1.0), "laser") == [] and live.stats.unmounted == 0  # waits for /tf_static
    clock.now = 1.0
    assert live.poll() == []
    assert live.stats.unmounted == 1 and "no transform from lidar frame 'laser'" in live.stats.notes[0]


def test_without_fresh_odometry_a_scan_goes_after_the_wait():
    clock = Clock()
    live = LiveInput(NodeConfig("db", pose_source="odom", max_wait_s=0.5, max_pose_gap=0.2), clock=clock)
    live.add_odometry(0.0, _odom(0.0, 5.0))
    assert live.add_scan("scan", _scan(1.0), "laser") == []
    clock.now = 0.4
    assert live.poll() == []
    clock.now = 0.6
    (step,) = live.poll()
    assert step.odometry is None and live.stats.stale == 1  # the only sample is 1 s old: no pose


def test_the_rate_limit_drops_scans_by_their_stamps():
    live = LiveInput(NodeConfig("db", pose_source="none", rate_hz=4.0, base_frame="laser"))
    stamps = [s.stamp for t in np.arange(0.0, 1.01, 0.1) for s in live.add_scan("scan", _scan(float(t)), "laser")]
    assert stamps == pytest.approx([0.0, 0.3, 0.6, 0.9]) and live.stats.rate_limited == 7


def test_a_scan_on_an_unknown_topic_is_refused():
    live = LiveInput(NodeConfig("db", pose_source="none"))
    with pytest.raises(InvalidParameterError, match="'other' is not one of scan"):
        live.add_scan("other", _scan(0.0), "laser")


def test_node_parameters():
    c = NodeConfig.from_params({"database": "p.sqlite", "scan_topics": "/a, /b", "rate": 10, "pair_tolerance": 0.0,
                                "scan_evidence": False, "pose_source": "tf:odom_combined"})  # fmt: skip
    assert c.scan_topics == ("/a", "/b") and c.rate_hz == 10.0 and c.pair_tolerance is None and not c.scan
    assert c.fixed_frame == "odom_combined" and NodeConfig("x").fixed_frame == "odom"
    assert NodeConfig.from_params({"database": "d", "scan_topics": ["s1", "s2"]}).scan_topics == ("s1", "s2")
    for params, match in [
        ({}, "~database: give the place database"),
        ({"database": "d", "filter": "kalman"}, "~filter must be one of pose, places"),
        ({"database": "d", "rate": "fast"}, "~rate must be a number, got 'fast'"),
        ({"database": "d", "seed": 1.5}, "~seed must be an integer"),
        ({"database": "d", "scan_topics": ["a", "a"]}, "given twice"),
        ({"database": "d", "pose_source": "gps"}, "~pose_source must be odom, tf, tf:FRAME or none"),
        ({"database": "d", "scan_evidence": "yes"}, "~scan_evidence must be true or false"),
        ({"database": "d", "topics": "a"}, "~topics: unknown parameter"),
        ({"database": "d", "max_tilt_deg": 95}, "~max_tilt_deg must be in"),
    ]:
        with pytest.raises(InvalidParameterError, match=match):
            NodeConfig.from_params(params)


def test_the_localizer_publishes_the_place_when_it_changes_and_every_answer():
    places, answers, poses = [], [], []
    tracker = StandInTracker()
    loc = LiveLocalizer(tracker, NodeConfig("db", pose_source="odom", base_frame="laser"), on_place=places.append,
                        on_answer=answers.append, on_pose=poses.append)  # fmt: skip
    n_beams = [5, 5, 6, 11, 7]  # returns 5, 5, 6, 11, 7 -> places p0, p0, p1, p1, p2
    for k, n in enumerate(n_beams):
        loc.odometry(k - 0.01, _odom(0, float(k)))
        loc.scan("scan", _scan(float(k), n), "laser")
        loc.odometry(k + 0.01, _odom(0, float(k)))
    assert [a.place for a in answers] == ["p0", "p0", "p1", "p1", "p2"]
    assert places == ["p0", "p1", "p2"] and len(poses) == 5 and loc.answers == 5


# ---- message conversion with the ROS 2 message types of rosbags ------------------------------------------


def _cdr_round_trip(ts, msg):
    return ts.deserialize_cdr(ts.serialize_cdr(msg, msg.__msgtype__), msg.__msgtype__)


def test_laser_scan_messages_convert_as_the_bag_reader_reads_them(tmp_path):
    from fingerloc.io.rosbag import _scan_from_msg

    ts = store(False)
    msg = _cdr_round_trip(ts, scan_msg(ts, 12.25, False, n=181, fov_deg=180.0, frame="/laser"))
    scan, frame = scan_from_msg(msg)
    assert frame == "laser" and scan.timestamp == 12.25
    ref = _scan_from_msg(msg, 12.25)
    np.testing.assert_array_equal(scan.ranges, ref.ranges)
    assert np.isinf(scan.ranges[3:6]).all()  # inf, below range_min, above range_max: no return
    np.testing.assert_allclose(scan.bearings, np.linspace(-np.pi / 2, np.pi / 2, 181), atol=1e-6)


def test_odometry_and_tf_messages_convert():
    ts = store(False)
    t, pose, frame, child = odometry_from_msg(_cdr_round_trip(ts, odom_msg(ts, 3.5, (1.0, -2.0, 0.75), False)))
    assert (t, frame, child) == (3.5, "odom", "base_link")
    assert pose.planar() == pytest.approx((1.0, -2.0, 0.75))
    links = transforms_from_msg(_cdr_round_trip(ts, tf_msg(ts, 4.0, [("odom", "base", (1.0, 2.0, 0.5)),
                                                                     ("/base", "/laser", (0.2, 0.0, 0.0))], False)))  # fmt: skip
    assert [(ln.parent, ln.child, ln.stamp) for ln in links] == [("odom", "base", 4.0), ("base", "laser", 4.0)]
    assert links[0].transform.planar() == pytest.approx((1.0, 2.0, 0.5))


def test_stamps_of_both_ros_versions():
    assert stamp_seconds(SimpleNamespace(secs=3, nsecs=250_000_000)) == 3.25
    assert stamp_seconds(SimpleNamespace(sec=3, nanosec=500_000_000)) == 3.5
    with pytest.raises(DataFormatError, match="not a ROS time stamp"):
        stamp_seconds(3.0)


def test_a_pose_with_covariance_message_holds_the_planar_pose_and_its_covariance():
    ts = store(False)
    T = ts.types
    zero = T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0)
    q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    pwc = T["geometry_msgs/msg/PoseWithCovariance"](pose=T["geometry_msgs/msg/Pose"](position=zero, orientation=q),
                                                    covariance=np.zeros(36))  # fmt: skip
    Time = T["builtin_interfaces/msg/Time"]
    msg = T["geometry_msgs/msg/PoseWithCovarianceStamped"](
        header=T["std_msgs/msg/Header"](stamp=Time(sec=7, nanosec=0), frame_id="map"), pose=pwc
    )
    cov = ((0.04, 0.01, 0.002), (0.01, 0.09, 0.003), (0.002, 0.003, 0.05))
    fill_pose_with_covariance(msg.pose, (3.0, -4.0, 2.5), cov)
    back = _cdr_round_trip(ts, msg)
    p = back.pose.pose
    assert (p.position.x, p.position.y, p.position.z) == (3.0, -4.0, 0.0)
    o = p.orientation
    assert math.atan2(2 * (o.w * o.z + o.x * o.y), 1 - 2 * (o.y**2 + o.z**2)) == pytest.approx(2.5)
    full = np.array(back.pose.covariance).reshape(6, 6)
    np.testing.assert_array_equal(full[np.ix_([0, 1, 5], [0, 1, 5])], np.array(cov))
    full[np.ix_([0, 1, 5], [0, 1, 5])] = 0.0
    assert not full.any()  # z, roll and pitch: zero
    ros1_like = SimpleNamespace(pose=SimpleNamespace(position=SimpleNamespace(), orientation=SimpleNamespace()),
                                covariance=[0.0] * 36)  # fmt: skip
    fill_pose_with_covariance(ros1_like, (1.0, 2.0, 0.0), None)
    assert ros1_like.covariance == [0.0] * 36 and ros1_like.pose.orientation.w == 1.0
    assert covariance_6x6(cov)[6 * 5 + 1] == 0.003


def test_an_answer_is_one_line_of_strict_json():
    ans = StandInTracker().step(_scan(1.0), odometry=(0.0, 0.0, 0.0), stamp=1.0)
    text = answer_json(SimpleNamespace(to_json=lambda: {**ans.to_json(), "probability": float("nan")}))
    assert "\n" not in text and '"probability":null' in text and '"best":"p0"' in text
