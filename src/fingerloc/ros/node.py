"""``fingerloc-ros``: the live localizer as a ROS 1 node (rospy); with ``ROS_VERSION=2``, the ROS 2 node.

Subscribes to ``sensor_msgs/LaserScan`` (``~scan_topics``), ``nav_msgs/Odometry``
(``~odom_topic``) and ``/tf``, ``/tf_static``; publishes

* ``~current_place`` (``std_msgs/String``, latched): the best place, when it changes;
* ``~posterior`` (``std_msgs/String``): every answer as one line of JSON (the
  ``track --json`` step record: best place, probability, entropy, top
  posterior entries, pose and covariance, latency);
* ``~pose`` (``geometry_msgs/PoseWithCovarianceStamped``, frame ``~map_frame``):
  the pose filter's estimate at the scan's stamp.

The parameters are those of :class:`~fingerloc.ros.live.NodeConfig`. Only
this module and :mod:`fingerloc.ros.node2` import a ROS library, inside
their functions.

Debian's ``rospy`` lives in the system Python's ``dist-packages``. When the
Python that runs ``fingerloc-ros`` cannot import ``rospy`` but the system
Python (``/usr/bin/python3``) of the same version can, the command runs itself
again under the system Python with this environment's packages first on its
path (docs/ROBOT.md, "Which Python").
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import sysconfig
from collections.abc import Callable
from pathlib import Path

from ..errors import FingerlocError
from .live import LiveLocalizer, NodeConfig, StepTracker, load_tracker

__all__ = ["SYSTEM_PYTHON", "main", "run", "system_python_path"]

#: The Python of Debian's ROS packages.
SYSTEM_PYTHON = "/usr/bin/python3"

#: Set in the environment of the re-run under the system Python (no second re-run).
_REEXEC_FLAG = "FINGERLOC_ROS_SYSTEM_PYTHON"

#: Seconds between two looks at scans waiting for odometry.
POLL_PERIOD_S = 0.05


def system_python_path() -> str:
    """This interpreter's import path without its standard library, as a ``PYTHONPATH`` value.

    What the system Python needs to import fingerloc and its dependencies
    from this environment (its own standard library stays first).
    """
    std = {os.path.realpath(sysconfig.get_paths()[k]) for k in ("stdlib", "platstdlib")}
    keep = []
    for p in sys.path:
        if not p or not os.path.isdir(p):
            continue
        real = os.path.realpath(p)
        if real in std or any(real.startswith(s + os.sep) and "site-packages" not in real for s in std):
            continue
        keep.append(p)
    return os.pathsep.join(dict.fromkeys(keep))


def _system_python_with_rospy() -> str | None:
    """The system Python when it is another interpreter of this version and Debian's rospy is there."""
    exe = Path(SYSTEM_PYTHON)
    if os.environ.get(_REEXEC_FLAG) or not exe.exists():
        return None
    if os.path.realpath(exe) == os.path.realpath(sys.executable):
        return None
    try:
        out = subprocess.run([str(exe), "-c", "import sys; print('%d.%d' % sys.version_info[:2])"], capture_output=True,
                             text=True, timeout=30, check=True).stdout.strip()  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return None
    if out != f"{sys.version_info[0]}.{sys.version_info[1]}":
        return None
    if not any((Path(p) / "rospy" / "__init__.py").exists() for p in ("/usr/lib/python3/dist-packages",)):
        return None
    return str(exe)


def _fail(msg: str) -> None:
    sys.stderr.write(f"error: {' '.join(str(msg).split())}\n")
    sys.stderr.flush()
    raise SystemExit(2)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``fingerloc-ros`` console script (ROS 1, or ROS 2 when ``ROS_VERSION=2``)."""
    args = sys.argv[1:] if argv is None else list(argv)
    if os.environ.get("ROS_VERSION") == "2":
        from .node2 import main as main2

        main2(args)
        return
    if importlib.util.find_spec("rospy") is None:
        exe = _system_python_with_rospy()
        if exe is None:
            _fail(
                "rospy is not importable here: install ROS 1 (Debian: apt-get install ros-core python3-rospy "
                "python3-sensor-msgs python3-nav-msgs python3-geometry-msgs python3-tf2-ros) and run fingerloc-ros "
                "from a Python that sees it (see docs/ROBOT.md)"
            )
            return
        env = dict(os.environ, PYTHONPATH=system_python_path(), **{_REEXEC_FLAG: "1"})
        sys.stderr.write(f"note: running under {exe} (Debian's rospy) with this environment's packages\n")
        sys.stderr.flush()
        os.execve(exe, [exe, "-m", "fingerloc.ros.node", *args], env)
    import rosgraph
    import rospy

    if not rosgraph.is_master_online():
        _fail(f"no ROS master at {rosgraph.get_master_uri()}: start roscore (or set ROS_MASTER_URI) first")
    try:
        rospy.init_node("fingerloc", argv=[sys.argv[0], *args])
    except rospy.exceptions.ROSException as err:
        _fail(f"cannot start the node: {err}")
    try:
        config = NodeConfig.from_params(rospy.get_param("~", {}))
        tracker = load_tracker(config)
    except FingerlocError as err:
        rospy.logfatal(str(err))
        _fail(str(err))
        return
    run(config, tracker, init=False)


def run(config: NodeConfig, tracker: StepTracker, *, init: bool = True, name: str = "fingerloc",
        until: Callable[[], bool] | None = None) -> LiveLocalizer:  # fmt: skip
    """Run the node with this tracker until ROS shuts down (or ``until()`` is true); returns the localizer.

    ``init``: call ``rospy.init_node(name)`` first (False when the caller did).
    """
    import rospy
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import LaserScan
    from std_msgs.msg import String
    from tf2_msgs.msg import TFMessage

    from .handlers import MessageHandlers

    if init:
        rospy.init_node(name)
    pub_place = rospy.Publisher("~current_place", String, queue_size=1, latch=True)
    pub_answer = rospy.Publisher("~posterior", String, queue_size=100)
    pub_pose = rospy.Publisher("~pose", PoseWithCovarianceStamped, queue_size=100)
    h = MessageHandlers(
        tracker,
        config,
        publish_place=lambda text: pub_place.publish(String(data=text)),
        publish_answer=lambda text: pub_answer.publish(String(data=text)),
        publish_pose=pub_pose.publish,
        pose_message=PoseWithCovarianceStamped,
        stamp=rospy.Time.from_sec,
        warn=lambda text: rospy.logwarn_throttle(5.0, text),
    )
    loc = h.localizer
    subs = [rospy.Subscriber("/tf", TFMessage, h.transforms, callback_args=False, queue_size=100),
            rospy.Subscriber("/tf_static", TFMessage, h.transforms, callback_args=True, queue_size=100)]  # fmt: skip
    if config.pose_source == "odom":
        subs.append(rospy.Subscriber(config.odom_topic, Odometry, h.odometry, queue_size=100))
    for topic in config.scan_topics:
        subs.append(rospy.Subscriber(topic, LaserScan, h.scan, callback_args=topic, queue_size=config.queue_size))
    timer = rospy.Timer(rospy.Duration(POLL_PERIOD_S), lambda _event: h.poll())
    rospy.loginfo(
        f"fingerloc: {config.database}, {config.filter} filter; scans {', '.join(config.scan_topics)}, "
        f"poses {config.pose_source}{' ' + config.odom_topic if config.pose_source == 'odom' else ''}"
    )
    try:
        if until is None:
            rospy.spin()
        else:
            rate = rospy.Rate(1.0 / POLL_PERIOD_S)
            while not rospy.is_shutdown() and not until():
                rate.sleep()
    finally:
        timer.shutdown()
        for s in subs:
            s.unregister()
        st = loc.input.stats
        rospy.loginfo(
            f"fingerloc: {loc.answers} answers from {st.scans} scans; dropped: {st.rate_limited} by the rate limit, "
            f"{st.unpaired} unpaired, {st.unmounted} unmounted, {st.bad} bad; {st.stale} without fresh odometry"
        )
    return loc


if __name__ == "__main__":  # pragma: no cover - the re-run under the system Python
    main()
