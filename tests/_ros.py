"""ROS 1 for the tests: a real ``roscore`` on a free local port, processes under the system Python, bags of logs.

Debian's rospy lives in the system Python (``/usr/bin/python3``); the test
processes that need it run there with this environment's packages first on
their path (what ``fingerloc-ros`` itself does, :func:`fingerloc.ros.node.system_python_path`).
Where ROS or a system Python of this version is missing, the calling test is
skipped with the reason.
"""

from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys
import time
import xmlrpc.client
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from fingerloc.ros.node import SYSTEM_PYTHON, system_python_path

from ._bags import store

ROOT = Path(__file__).resolve().parents[1]
ROSCORE = Path("/usr/bin/roscore")
DIST_PACKAGES = Path("/usr/lib/python3/dist-packages")


def require_ros() -> None:
    """Skip unless roscore, Debian's rospy and rosbag, and a system Python of this version are here."""
    if not ROSCORE.exists():
        pytest.skip("no ROS 1: /usr/bin/roscore not found (apt-get install ros-core)")
    for pkg, deb in (("rospy", "python3-rospy"), ("rosbag", "python3-rosbag"), ("sensor_msgs", "python3-sensor-msgs"),
                     ("nav_msgs", "python3-nav-msgs"), ("tf2_msgs", "python3-tf2-ros")):  # fmt: skip
        if not (DIST_PACKAGES / pkg).is_dir():
            pytest.skip(f"no {pkg} in {DIST_PACKAGES} (apt-get install {deb})")
    try:
        out = subprocess.run([SYSTEM_PYTHON, "-c", "import sys; print('%d.%d' % sys.version_info[:2])"],
                             capture_output=True, text=True, timeout=30, check=True).stdout.strip()  # fmt: skip
    except (OSError, subprocess.SubprocessError) as err:
        pytest.skip(f"cannot run {SYSTEM_PYTHON}: {err}")
    here = f"{sys.version_info[0]}.{sys.version_info[1]}"
    if out != here:
        pytest.skip(f"{SYSTEM_PYTHON} is Python {out}, these tests run on {here}: its rospy cannot load our packages")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def ros_env(home: Path, port: int) -> dict[str, str]:
    """The environment of every ROS process of one test: its own master, logs under ``home``, loopback only."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS")}
    env.update(
        ROS_MASTER_URI=f"http://127.0.0.1:{port}",
        ROS_IP="127.0.0.1",
        ROS_HOME=str(home),
        ROS_LOG_DIR=str(home / "log"),
        PYTHONPATH=os.pathsep.join([system_python_path(), str(ROOT)]),
        PYTHONUNBUFFERED="1",
    )
    return env


def _master_up(uri: str) -> bool:
    try:
        code, _, _ = xmlrpc.client.ServerProxy(uri).getSystemState("/fingerloc_test")
    except (OSError, xmlrpc.client.Error):
        return False
    return code == 1


def stop(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    """SIGINT to the process group the test started (a ROS process shuts down cleanly on it), then SIGKILL."""
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=timeout)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=timeout)


@contextmanager
def roscore(home: Path, timeout: float = 60.0):
    """A real ``roscore`` on a free port of 127.0.0.1; yields its environment."""
    require_ros()
    home.mkdir(parents=True, exist_ok=True)
    port = _free_port()
    env = ros_env(home, port)
    log = open(home / "roscore.out", "wb")
    proc = subprocess.Popen([str(ROSCORE), "-p", str(port)], env=env, stdout=log, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
    try:
        deadline = time.monotonic() + timeout
        while not _master_up(env["ROS_MASTER_URI"]):
            if proc.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(
                    f"roscore did not start: {(home / 'roscore.out').read_text(errors='replace')[-2000:]}"
                )
            time.sleep(0.05)
        yield env
    finally:
        stop(proc)
        log.close()


def start(args: list[str], env: dict[str, str], out: Path) -> subprocess.Popen:
    """Start a process in its own session (so that :func:`stop` reaches its children), output to ``out``."""
    fh = open(out, "wb")
    try:
        return subprocess.Popen(args, env=env, stdout=fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True)  # fmt: skip
    finally:
        fh.close()


def replay(bag: Path, out: Path, env: dict[str, str], *, node: str = "/fingerloc", scan_topic: str = "/scan",
           timeout: float = 60.0) -> subprocess.CompletedProcess:  # fmt: skip
    """Run tests/ros_replay.py under the system Python (see there)."""
    cmd = [SYSTEM_PYTHON, str(ROOT / "tests" / "ros_replay.py"), str(bag), str(out), "--node", node,
           "--scan-topic", scan_topic, "--timeout", str(timeout)]  # fmt: skip
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout + 30)


def write_scans_bag(path: Path, scans, *, frame: str = "laser", t_offset: float = 0.0, mount=(0.0, 0.0, 0.0)) -> Path:
    """A ROS 1 bag of scans with poses (a log's): per scan, ``/odom`` (the scan's pose, child ``base_link``) and
    ``/scan`` (frame ``frame``) at its stamp (plus ``t_offset``), and one ``/tf_static`` mount base_link -> frame."""
    from rosbags.rosbag1 import Writer

    ts = store(True)
    T = ts.types
    LS, OD, TF = "sensor_msgs/msg/LaserScan", "nav_msgs/msg/Odometry", "tf2_msgs/msg/TFMessage"

    def header(t, fr):
        sec = math.floor(t)
        return T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=min(
            round((t - sec) * 1e9), 999_999_999)), frame_id=fr)  # fmt: skip

    def quat(yaw):
        return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))

    t0 = float(scans[0].timestamp) + t_offset
    zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    with Writer(path) as w:
        c_tf = w.add_connection("/tf_static", TF, typestore=ts, latching=1)
        c_od = w.add_connection("/odom", OD, typestore=ts)
        c_ls = w.add_connection("/scan", LS, typestore=ts)
        mx, my, myaw = mount
        link = T["geometry_msgs/msg/TransformStamped"](
            header=header(t0, "base_link"), child_frame_id=frame,
            transform=T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=mx, y=my, z=0.0),
                                                       rotation=quat(myaw)))  # fmt: skip
        w.write(c_tf, int(t0 * 1e9), ts.serialize_ros1(T[TF](transforms=[link]), TF))
        for s in scans:
            t = float(s.timestamp) + t_offset
            x, y, th = s.pose
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0), orientation=quat(th)
            )
            od = T[OD](header=header(t, "odom"), child_frame_id="base_link",
                       pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                       twist=T["geometry_msgs/msg/TwistWithCovariance"](
                           twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)))  # fmt: skip
            w.write(c_od, int(t * 1e9), ts.serialize_ros1(od, OD))
            b = s.bearings
            inc = float(b[1] - b[0])
            ranges = np.where(np.isfinite(s.ranges), s.ranges, np.inf).astype(np.float32)
            ls = T[LS](header=header(t, frame), angle_min=float(b[0]), angle_max=float(b[0]) + inc * (b.size - 1),
                       angle_increment=inc, time_increment=0.0, scan_time=0.0, range_min=0.0,
                       range_max=float(s.max_range), ranges=ranges, intensities=np.zeros(0, np.float32))  # fmt: skip
            w.write(c_ls, int(t * 1e9) + 1, ts.serialize_ros1(ls, LS))  # just after its odometry
    return path
