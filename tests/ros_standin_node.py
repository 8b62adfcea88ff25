"""The fingerloc ROS 1 node with the tests' stand-in tracker (tests/_live.py), run by the ROS tests::

    python3 tests/ros_standin_node.py SCAN_TOPIC [SCAN_TOPIC ...]

The node is ``fingerloc.ros.node.run`` as ``fingerloc-ros`` runs it; only the
tracker differs, so that what it publishes can be checked answer by answer.
"""

import sys

from fingerloc.ros.live import NodeConfig
from fingerloc.ros.node import run
from tests._live import StandInTracker

if __name__ == "__main__":
    config = NodeConfig("stand-in", scan_topics=tuple(sys.argv[1:]) or ("/scan",), pose_source="odom",
                        odom_topic="/odom", base_frame="base_link", queue_size=1000)  # fmt: skip
    run(config, StandInTracker(), name="fingerloc")
