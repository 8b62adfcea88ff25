"""ROS bags for the tests, written with rosbags' writers (ROS 1 and ROS 2).

* :func:`write_bag`: a small bag of scans, odometry and transforms given message by message;
* :func:`write_robot_bag`: a robot in a rectangular room with two 270 deg lidars back to back,
  the back one upside down, ``/tf_static`` mounts and ``/tf`` poses (``map -> odom -> base_footprint``),
  ray-cast from the true poses (scipy rotations, independent of fingerloc's transforms);
  :func:`truth_pose` and :func:`on_walls` are the oracles.
"""

import math

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

TFMSG = "geometry_msgs/TransformStamped[] transforms"


def store(ros1):
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in ts.types:
        ts.register(get_types_from_msg(TFMSG, "tf2_msgs/msg/TFMessage"))
    return ts


def quat(ts, yaw):
    Q = ts.types["geometry_msgs/msg/Quaternion"]
    return Q(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def header(ts, t, frame, ros1):
    Time = ts.types["builtin_interfaces/msg/Time"]
    H = ts.types["std_msgs/msg/Header"]
    stamp = Time(sec=int(t), nanosec=round((t - int(t)) * 1e9))
    return H(seq=0, stamp=stamp, frame_id=frame) if ros1 else H(stamp=stamp, frame_id=frame)


def scan_msg(ts, t, ros1, n=271, fov_deg=270.0, frame="laser", ranges=None, intensities=True):
    LS = ts.types["sensor_msgs/msg/LaserScan"]
    a0 = -math.radians(fov_deg) / 2
    inc = math.radians(fov_deg) / (n - 1)
    r = np.linspace(1.0, 5.0, n).astype(np.float32) if ranges is None else np.asarray(ranges, np.float32)
    r[3] = np.inf
    r[4] = 0.0  # below range_min: invalid
    r[5] = 40.0  # above range_max
    inten = np.arange(n, dtype=np.float32) * 100 if intensities else np.zeros(0, np.float32)
    return LS(
        header=header(ts, t, frame, ros1),
        angle_min=a0,
        angle_max=a0 + inc * (n - 1),
        angle_increment=inc,
        time_increment=0.0,
        scan_time=0.1,
        range_min=0.05,
        range_max=30.0,
        ranges=r,
        intensities=inten,
    )


def odom_msg(ts, t, pose, ros1, child="base_link"):
    T = ts.types
    P = T["geometry_msgs/msg/Point"](x=pose[0], y=pose[1], z=0.0)
    pose_ = T["geometry_msgs/msg/Pose"](position=P, orientation=quat(ts, pose[2]))
    pwc = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose_, covariance=np.zeros(36))
    V = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    tw = T["geometry_msgs/msg/Twist"](linear=V, angular=V)
    twc = T["geometry_msgs/msg/TwistWithCovariance"](twist=tw, covariance=np.zeros(36))
    return T["nav_msgs/msg/Odometry"](header=header(ts, t, "odom", ros1), child_frame_id=child, pose=pwc, twist=twc)


def tf_msg(ts, t, links, ros1, typ="tf2_msgs/msg/TFMessage"):
    T = ts.types
    out = []
    for parent, child, (x, y, yaw) in links:
        tr = T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.0), rotation=quat(ts, yaw)
        )
        out.append(
            T["geometry_msgs/msg/TransformStamped"](
                header=header(ts, t, parent, ros1), child_frame_id=child, transform=tr
            )
        )
    return T[typ](transforms=out)


def write_bag(path, ros1, *, scans=(), odom=(), tf=(), tf_static=(), extra_scan_topic=None, tf_type=None):
    """Write a small bag. scans: list of (t, topic, msg-kwargs); odom: (t, pose); tf: (t, links).

    ``tf_type="tf/msg/tfMessage"`` writes /tf as older ROS 1 bags did."""
    ts = store(ros1)
    if tf_type is not None and tf_type not in ts.types:
        ts.register(get_types_from_msg(TFMSG, tf_type))
    if ros1:
        from rosbags.rosbag1 import Writer

        w = Writer(path)
        ser = ts.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer

        w = Writer(path, version=9)
        ser = ts.serialize_cdr
    LS, OD, TF = "sensor_msgs/msg/LaserScan", "nav_msgs/msg/Odometry", tf_type or "tf2_msgs/msg/TFMessage"
    with w:
        conns = {}

        def conn(topic, typ):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=ts)
            return conns[topic]

        items = []
        for t, topic, kw in scans:
            items.append((t, conn(topic, LS), LS, scan_msg(ts, t, ros1, **kw)))
        for t, pose in odom:
            items.append((t, conn("/odom", OD), OD, odom_msg(ts, t, pose, ros1)))
        for t, links in tf:
            items.append((t, conn("/tf", TF), TF, tf_msg(ts, t, links, ros1, TF)))
        for t, links in tf_static:
            items.append((t, conn("/tf_static", TF), TF, tf_msg(ts, t, links, ros1, TF)))
        for t, c, typ, msg in sorted(items, key=lambda x: x[0]):
            w.write(c, int(t * 1e9), ser(msg, typ))
    return path


def bag_path(tmp_path, ros1, name="b"):
    return tmp_path / (f"{name}.bag" if ros1 else name)


ROOM = (8.0, 6.0)  # a rectangular room [0, 8] x [0, 6], metres
ROOM_CORNERS = np.array([[0.0, 0.0], [8.0, 0.0], [8.0, 6.0], [0.0, 6.0]])
# mounts in base_link: (x, y, z), (roll, pitch, yaw); the back lidar hangs upside down
FRONT = ((0.30, 0.05, 0.15), (0.0, 0.0, 0.0))
BACK = ((-0.30, -0.05, 0.15), (math.pi, 0.0, math.pi))
FOOT_TO_LINK = ((0.0, 0.0, 0.10), (0.0, 0.0, 0.0))
MAP_TO_ODOM = ((0.5, -0.2, 0.0), (0.0, 0.0, 0.1))


def rot(rpy):
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("xyz", rpy)  # extrinsic x, y, z: R = Rz Ry Rx


def truth_pose(t):
    """base_footprint in map, moving on a straight line and turning: (x, y, theta)."""
    return (3.0 + 0.8 * (t - 10.0), 2.5 + 0.3 * (t - 10.0), 0.4 + 0.5 * (t - 10.0))


def odom_pose(t, pose=truth_pose):
    """base_footprint in odom such that map->odom * odom->base is the truth ``pose(t)``."""
    (mx, my, _), (_, _, myaw) = MAP_TO_ODOM
    x, y, th = pose(t)
    c, s = math.cos(myaw), math.sin(myaw)
    dx, dy = x - mx, y - my
    return (c * dx + s * dy, -s * dx + c * dy, th - myaw)


def room_ranges(origin, directions):
    """Distance from origin (2,) along unit directions (n, 2) to the walls of ROOM."""
    ox, oy = origin
    dx, dy = directions[:, 0], directions[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(dx > 1e-12, (ROOM[0] - ox) / dx, np.where(dx < -1e-12, -ox / dx, np.inf))
        ty = np.where(dy > 1e-12, (ROOM[1] - oy) / dy, np.where(dy < -1e-12, -oy / dy, np.inf))
    return np.minimum(tx, ty)


def lidar_ranges(t, mount, n=541, fov_deg=270.0, pose=truth_pose):
    """Ray-cast one lidar (beam angles in its own frame, counter-clockwise) at time t (scipy rotations)."""
    x, y, th = pose(t)
    base = rot((0.0, 0.0, th))
    link_z = FOOT_TO_LINK[0][2]
    (mx, my, mz), rpy = mount
    sensor = base * rot(rpy)
    origin = np.array([x, y, 0.0]) + base.apply([mx, my, mz + link_z])
    phi = -math.radians(fov_deg) / 2 + math.radians(fov_deg) / (n - 1) * np.arange(n)
    d = sensor.apply(np.column_stack([np.cos(phi), np.sin(phi), np.zeros(n)]))
    assert np.allclose(d[:, 2], 0.0)  # both lidars scan the horizontal plane
    return room_ranges(origin[:2], d[:, :2]).astype(np.float32)


def quat3(ts, rpy):
    x, y, z, w = rot(rpy).as_quat()
    return ts.types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)


def tf3(ts, t, links, ros1):
    T = ts.types
    out = []
    for parent, child, ((x, y, z), rpy) in links:
        tr = T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z), rotation=quat3(ts, rpy)
        )
        out.append(
            T["geometry_msgs/msg/TransformStamped"](
                header=header(ts, t, parent, ros1), child_frame_id=child, transform=tr
            )
        )
    return T["tf2_msgs/msg/TFMessage"](transforms=out)


FRONT_STAMPS = (10.0, 10.1, 10.2, 10.3)
BACK_STAMPS = (10.02, 10.12, 10.22)  # none near 10.3: that time step has no partner


def write_robot_bag(
    path,
    ros1,
    *,
    front_stamps=FRONT_STAMPS,
    back_stamps=BACK_STAMPS,
    pose=truth_pose,
    odom_topic=None,
    extra_static=(),
):
    """A robot in ROOM: base_footprint -> base_link -> laser_front / laser_back (upside down) on
    /tf_static; map -> odom -> base_footprint on /tf at 50 Hz (and, with ``odom_topic``, the same
    odom -> base_footprint as nav_msgs/Odometry); 270 deg lidars (541 beams) ray-cast from the true
    pose ``pose(t)`` (x, y, theta of base_footprint in map) at their stamps. By default the lidars run
    at 10 Hz, the back one 20 ms after the front one, with no back scan near the last front one."""
    ts = store(ros1)
    if ros1:
        from rosbags.rosbag1 import Writer

        w, ser = Writer(path), ts.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer

        w, ser = Writer(path, version=9), ts.serialize_cdr
    LS, TF, OD = "sensor_msgs/msg/LaserScan", "tf2_msgs/msg/TFMessage", "nav_msgs/msg/Odometry"
    items = []
    with w:
        c_front = w.add_connection("/scan_front", LS, typestore=ts)
        c_back = w.add_connection("/scan_back", LS, typestore=ts)
        c_tf = w.add_connection("/tf", TF, typestore=ts)
        c_static = w.add_connection("/tf_static", TF, typestore=ts)
        static = [
            ("base_footprint", "base_link", FOOT_TO_LINK),
            ("base_link", "laser_front", FRONT),
            ("base_link", "laser_back", BACK),
            *extra_static,
        ]
        items.append((9.0, c_static, TF, tf3(ts, 9.0, static, ros1)))
        c_odom = w.add_connection(odom_topic, OD, typestore=ts) if odom_topic else None
        t0 = min(front_stamps + back_stamps) - 0.1
        for k in range(round((max(front_stamps + back_stamps) + 0.2 - t0) / 0.02) + 1):
            t = t0 + 0.02 * k
            x, y, th = odom_pose(t, pose)
            links = [("map", "odom", MAP_TO_ODOM), ("odom", "base_footprint", ((x, y, 0.0), (0.0, 0.0, th)))]
            items.append((t, c_tf, TF, tf3(ts, t, links, ros1)))
            if c_odom is not None:
                items.append((t, c_odom, OD, odom_msg(ts, t, (x, y, th), ros1, child="base_footprint")))
        for stamps, conn, mount, frame in (
            (front_stamps, c_front, FRONT, "laser_front"),
            (back_stamps, c_back, BACK, "laser_back"),
        ):
            for t in stamps:
                ranges = lidar_ranges(t, mount, pose=pose)
                msg = scan_msg(ts, t, ros1, n=541, frame=frame, ranges=ranges.copy())
                msg.ranges[3:6] = ranges[3:6]  # scan_msg spoils three beams; restore them
                items.append((t, conn, LS, msg))
        for t, c, typ, msg in sorted(items, key=lambda x: x[0]):
            w.write(c, int(t * 1e9), ser(msg, typ))
    return path


def on_walls(scan, pose):
    """Distance (m) of each return of a scan (robot frame, with its sensor offset) to the room's walls."""
    pts = scan.points()
    x, y, th = pose
    c, s = math.cos(th), math.sin(th)
    wx, wy = x + c * pts[:, 0] - s * pts[:, 1], y + s * pts[:, 0] + c * pts[:, 1]
    return np.minimum.reduce([np.abs(wx), np.abs(wx - ROOM[0]), np.abs(wy), np.abs(wy - ROOM[1])])


def true_corner_bearings(pose):
    x, y, th = pose
    return np.arctan2(ROOM_CORNERS[:, 1] - y, ROOM_CORNERS[:, 0] - x) - th
