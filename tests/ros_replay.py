"""Replay a ROS 1 bag to a running fingerloc node step by step, and record what the node publishes.

Run by the ROS tests with the system Python (Debian's rospy and rosbag)::

    python3 tests/ros_replay.py BAG OUT.json --node /fingerloc --scan-topic /scan [--timeout 30]

Every message of the bag is published in the bag's order on its own topic
(``/tf_static`` latched); after each message of the reference scan topic the
replay waits until the node has published that step's answer on
``NODE/posterior``, so that no scan is dropped and the node answers every one.
OUT.json gets ``{"answers": [...], "places": [...], "poses": [...], "steps": N}``.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("bag")
    ap.add_argument("out")
    ap.add_argument("--node", default="/fingerloc")
    ap.add_argument("--scan-topic", default="/scan")
    ap.add_argument("--timeout", type=float, default=30.0)
    args = ap.parse_args()

    import rosbag
    import rospy
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from std_msgs.msg import String

    rospy.init_node("fingerloc_replay", anonymous=True, disable_signals=True)
    got: dict[str, list] = {"answers": [], "places": [], "poses": []}
    cond = threading.Condition()

    def on_answer(msg):
        with cond:
            got["answers"].append(json.loads(msg.data))
            cond.notify_all()

    def on_place(msg):
        with cond:
            got["places"].append(msg.data)

    def on_pose(msg):
        p = msg.pose.pose
        with cond:
            got["poses"].append({
                "stamp": msg.header.stamp.to_sec(), "frame": msg.header.frame_id,
                "xyz": [p.position.x, p.position.y, p.position.z],
                "q": [p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w],
                "covariance": list(msg.pose.covariance),
            })  # fmt: skip

    subs = [
        rospy.Subscriber(f"{args.node}/posterior", String, on_answer, queue_size=10000),
        rospy.Subscriber(f"{args.node}/current_place", String, on_place, queue_size=10000),
        rospy.Subscriber(f"{args.node}/pose", PoseWithCovarianceStamped, on_pose, queue_size=10000),
    ]
    bag = rosbag.Bag(args.bag)
    pubs = {}
    for topic in bag.get_type_and_topic_info().topics:
        cls = None
        for _, msg, _ in bag.read_messages(topics=[topic]):
            cls = type(msg)
            break
        pubs[topic] = rospy.Publisher(topic, cls, queue_size=10000, latch=topic == "/tf_static")
    deadline = time.monotonic() + args.timeout
    # wait for the node: its subscriptions to the bag's topics, and ours to its outputs
    while time.monotonic() < deadline and not (
        all(p.get_num_connections() > 0 for t, p in pubs.items() if t != "/tf")
        and all(s.get_num_connections() > 0 for s in subs)
    ):
        time.sleep(0.05)
    if time.monotonic() >= deadline:
        sys.stderr.write("replay: the node did not connect in time\n")
        return 3
    # A subscriber counts its connection once the publisher's handshake header arrives, but rospy's publisher
    # writes that header before it adds the connection to the ones it sends to: a message published in between
    # is lost. The node's own publishers are the ones that matter here, and they cannot be asked; let them settle.
    time.sleep(0.5)
    steps = 0
    for topic, msg, _ in bag.read_messages():
        pubs[topic].publish(msg)
        if topic == args.scan_topic:
            steps += 1
            want = steps
            with cond:
                if not cond.wait_for(
                    lambda want=want: len(got["answers"]) >= want, timeout=max(0.0, deadline - time.monotonic())
                ):
                    sys.stderr.write(f"replay: no answer to scan {steps} in time\n")
                    return 4
    time.sleep(0.3)  # the last place and pose messages
    bag.close()
    with open(args.out, "w", encoding="utf-8") as fh:
        json.dump({**got, "steps": steps}, fh)
    rospy.signal_shutdown("done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
