"""The ROS 1 node end to end against a real roscore: a bag of a log's scans and odometry replayed to it step by
step, and what it publishes (current place, answers, poses) checked against the same tracker run offline."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

from fingerloc.io.rosbag import read_bag_scans
from fingerloc.pipeline.readers import load_log_scans

from ._live import StandInTracker
from ._ros import ROOT, SYSTEM_PYTHON, replay, roscore, start, stop, write_scans_bag

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def ros(tmp_path_factory):
    with roscore(tmp_path_factory.mktemp("ros")) as env:
        yield env


def test_the_node_publishes_every_answer_the_place_changes_and_the_pose(ros, rooms_log, tmp_path):
    scans, _ = load_log_scans(rooms_log)
    bag = write_scans_bag(tmp_path / "rooms.bag", scans, t_offset=1000.0, mount=(0.2, 0.0, 0.0))
    node = start([SYSTEM_PYTHON, str(ROOT / "tests" / "ros_standin_node.py"), "/scan"], ros, tmp_path / "node.out")
    try:
        res = replay(bag, tmp_path / "got.json", ros, timeout=60.0)
    finally:
        stop(node)
    assert res.returncode == 0, res.stderr[-2000:] + (tmp_path / "node.out").read_text(errors="replace")[-3000:]
    got = json.loads((tmp_path / "got.json").read_text())
    # the same tracker offline, over the bag as fingerloc's bag reader reads it (odometry poses, the mount)
    offline = StandInTracker()
    expected = [offline.step(s, odometry=s.pose, stamp=s.timestamp) for s in read_bag_scans(bag, pose_source="odom")]
    assert got["steps"] == len(scans) == len(expected)
    assert [a["best"] for a in got["answers"]] == [e.place for e in expected]
    assert [a["returns"] for a in got["answers"]] == [e.returns for e in expected]
    assert [a["stamp"] for a in got["answers"]] == pytest.approx([e.stamp for e in expected], abs=1e-6)
    changes = [e.place for k, e in enumerate(expected) if k == 0 or e.place != expected[k - 1].place]
    assert got["places"] == changes  # latched topic: only when the place changes
    assert len(got["poses"]) == len(expected)
    for p, e in zip(got["poses"], expected, strict=True):
        assert p["frame"] == "map" and p["stamp"] == pytest.approx(e.stamp, abs=1e-6)
        assert p["xyz"] == pytest.approx([e.pose[0], e.pose[1], 0.0], abs=1e-9)
        _, _, qz, qw = p["q"]
        assert math.remainder(2 * math.atan2(qz, qw) - e.pose[2], 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
        cov = np.array(p["covariance"]).reshape(6, 6)
        np.testing.assert_allclose(cov[np.ix_([0, 1, 5], [0, 1, 5])], np.array(e.covariance), atol=1e-15)


def test_fingerloc_ros_without_a_database_fails_with_one_line(ros, tmp_path):
    import subprocess
    import sys

    t0 = time.monotonic()
    res = subprocess.run([sys.executable, "-m", "fingerloc.ros.node", "__name:=fingerloc_nodb"], env=ros,
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert res.returncode == 2, res.stderr[-2000:]
    assert res.stderr.strip().splitlines()[-1] == "error: ~database: give the place database made by 'fingerloc map'"
    assert time.monotonic() - t0 < 60


def test_fingerloc_ros_without_a_master_fails_with_one_line(tmp_path):
    import subprocess
    import sys

    from ._ros import require_ros, ros_env

    require_ros()
    env = ros_env(tmp_path, 1)  # nothing listens on port 1
    res = subprocess.run([sys.executable, "-m", "fingerloc.ros.node", "_database:=places.sqlite"], env=env,
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert res.returncode == 2
    assert res.stderr.strip().splitlines()[-1].startswith("error: no ROS master at http://127.0.0.1:1: start roscore")


def test_the_node_on_a_place_database_publishes_the_places_of_offline_track(ros, tmp_path, capsys):
    """fingerloc-ros as a user runs it (this environment's Python; it re-runs itself under Debian's rospy), on a
    map of the rooms' first loop; the second loop replayed as a bag: the places equal ``track BAG --observe all``."""
    import sys

    import fingerloc as fl

    from ._cli import run_cli
    from ._doors import rooms_log_with_doors

    full = rooms_log_with_doors(tmp_path / "rooms-corrected.log")
    pm = fl.make_map(fl.read_run(full), fl.Config().with_(calibration={"tune": False, "scan_gamma": 1.0}))
    db = tmp_path / "rooms.sqlite"
    pm.save(db)
    scans = fl.read_run(full).scans
    bag = write_scans_bag(tmp_path / "held.bag", scans[len(scans) // 2 :], t_offset=1000.0, mount=(0.0, 0.0, 0.0))
    code, _, err = run_cli(capsys, "track", bag, "--db", db, "--filter", "pose", "--observe", "all", "--seed", "2",
                           "--json", tmp_path / "off.json", "-q")  # fmt: skip
    assert code == 0, err
    off = json.loads((tmp_path / "off.json").read_text())["steps"]
    node = start([sys.executable, "-m", "fingerloc.ros.node", f"_database:={db}", "_scan_topics:=/scan",
                  "_odom_topic:=/odom", "_base_frame:=base_link", "_seed:=2", "_queue_size:=1000"], ros,
                 tmp_path / "node.out")  # fmt: skip
    try:
        res = replay(bag, tmp_path / "got.json", ros, timeout=90.0)
    finally:
        stop(node)
    log = (tmp_path / "node.out").read_text(errors="replace")
    assert res.returncode == 0, res.stderr[-2000:] + log[-3000:]
    got = json.loads((tmp_path / "got.json").read_text())
    assert [a["best"] for a in got["answers"]] == [s["best"] for s in off]
    for a, s in zip(got["answers"], off, strict=True):
        assert a["pose"] == pytest.approx(s["pose"], abs=1e-9) and a["probability"] == pytest.approx(s["probability"])
    assert got["places"] == [s["best"] for k, s in enumerate(off) if k == 0 or s["best"] != off[k - 1]["best"]]
    assert len(got["poses"]) == len(off) and got["poses"][-1]["frame"] == "map"
    assert "note: running under /usr/bin/python3 (Debian's rospy)" in log
