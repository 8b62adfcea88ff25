"""The ROS 2 transport (fingerloc.ros.node2) wired to a recording stand-in of rclpy, fed ROS 2 messages built with
rosbags' types: what it subscribes, what it publishes, with which quality of service."""

from __future__ import annotations

import sys
import types
from types import SimpleNamespace

import numpy as np
import pytest

from fingerloc.ros.live import NodeConfig

from ._bags import odom_msg, scan_msg, store, tf_msg
from ._live import StandInTracker


class _Msg(SimpleNamespace):
    pass


def _pose_with_covariance_stamped():
    pose = _Msg(position=_Msg(x=0.0, y=0.0, z=0.0), orientation=_Msg(x=0.0, y=0.0, z=0.0, w=1.0))
    return _Msg(header=_Msg(stamp=None, frame_id=""), pose=_Msg(pose=pose, covariance=np.zeros(36)))


class FakeNode:
    def __init__(self):
        self.publishers, self.subscriptions, self.timers = {}, {}, []
        self.published: dict[str, list] = {}

    def create_publisher(self, typ, topic, qos):
        self.publishers[topic] = (typ, qos)
        out = self.published.setdefault(topic, [])
        return SimpleNamespace(publish=out.append)

    def create_subscription(self, typ, topic, cb, qos):
        self.subscriptions[topic] = (typ, cb, qos)

    def create_timer(self, period, cb):
        self.timers.append((period, cb))

    def get_logger(self):
        return SimpleNamespace(info=lambda *a, **k: None, warning=lambda *a, **k: None)


@pytest.fixture
def fake_rclpy(monkeypatch):
    def module(name, **attrs):
        m = types.ModuleType(name)
        m.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, m)
        return m

    module("rclpy", spin=lambda node: None)
    module("rclpy.qos", DurabilityPolicy=SimpleNamespace(TRANSIENT_LOCAL="transient_local"),
           QoSProfile=lambda **kw: ("qos", tuple(sorted(kw.items()))), qos_profile_sensor_data="sensor_data")  # fmt: skip
    module("builtin_interfaces.msg", Time=lambda sec, nanosec: _Msg(sec=sec, nanosec=nanosec))
    module("std_msgs.msg", String=lambda data="": _Msg(data=data))
    module("geometry_msgs.msg", PoseWithCovarianceStamped=_pose_with_covariance_stamped)
    for name, cls in (("nav_msgs.msg", "Odometry"), ("sensor_msgs.msg", "LaserScan"), ("tf2_msgs.msg", "TFMessage")):
        module(name, **{cls: cls})


def test_the_ros2_node_subscribes_publishes_and_answers(fake_rclpy):
    from fingerloc.ros import node2

    node = FakeNode()
    config = NodeConfig("db", scan_topics=("/scan",), pose_source="odom", odom_topic="/odom", map_frame="world")
    tracker = StandInTracker()
    loc = node2.run(node, config, tracker, spin=True)
    assert set(node.subscriptions) == {"/tf", "/tf_static", "/odom", "/scan"}
    assert node.subscriptions["/scan"][2] == "sensor_data"
    assert ("durability", "transient_local") in node.subscriptions["/tf_static"][2][1]
    assert ("durability", "transient_local") in node.publishers["~/current_place"][1][1]
    assert set(node.publishers) == {"~/current_place", "~/posterior", "~/pose"}
    ts = store(False)
    node.subscriptions["/tf_static"][1](tf_msg(ts, 1.0, [("base_link", "laser", (0.1, 0.0, 0.0))], False))
    for k in range(3):
        t = 10.0 + 0.1 * k
        node.subscriptions["/odom"][1](odom_msg(ts, t, (0.5 * k, 0.0, 0.1 * k), False))
        node.subscriptions["/scan"][1](scan_msg(ts, t, False, n=50 + 7 * k, fov_deg=180.0))
    node.timers[0][1]()
    assert loc.answers == 3 and len(node.published["~/posterior"]) == 3
    assert [m.data for m in node.published["~/current_place"]] == [tracker.steps[0].place] + [
        a.place for i, a in enumerate(tracker.steps[1:], 1) if a.place != tracker.steps[i - 1].place
    ]
    poses = node.published["~/pose"]
    assert len(poses) == 3 and poses[2].header.frame_id == "world"
    assert (poses[2].header.stamp.sec, poses[2].header.stamp.nanosec) == (10, 200_000_000)
    assert poses[2].pose.pose.position.x == pytest.approx(tracker.steps[2].pose[0])
    assert poses[2].pose.covariance[35] == pytest.approx(tracker.steps[2].covariance[2][2])
