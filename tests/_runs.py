"""Synthetic recorded runs for the library-layer tests: a robot walking through box rooms."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fingerloc.io.carmen import flaser_bearings

#: Rooms (width, height, metres); room j lies 20 m * j along x in the world.
BOXES = [(3.0, 3.0), (8.0, 2.0), (5.0, 12.0), (4.0, 6.0)]


def box_ranges(w: float, h: float, px: float, py: float, heading: float, n: int = 181) -> np.ndarray:
    """Ranges of a 180 deg scan from (px, py) inside the box [0, w] x [0, h]."""
    a = flaser_bearings(n) + heading
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(c > 1e-12, (w - px) / c, np.where(c < -1e-12, -px / c, np.inf))
        ty = np.where(s > 1e-12, (h - py) / s, np.where(s < -1e-12, -py / s, np.inf))
    return np.minimum(tx, ty)


def walk(passes: int = 2) -> list[tuple[int, float, float, float]]:
    """(room, x, y, heading) per step: in every room three spots 0.3 m apart, every pass the same tour."""
    out = []
    for _ in range(passes):
        for j, (w, h) in enumerate(BOXES):
            for dx in (-0.3, 0.0, 0.3):
                out.append((j, w / 2 + dx, h / 2, 0.3 * dx))
    return out


def write_carmen(path: Path, steps: list[tuple[int, float, float, float]] | None = None) -> Path:
    """A CARMEN log, one FLASER per step (world pose: room j shifted 20 m along x), with a little noise."""
    lines = ["# synthetic", "PARAM robot_front_laser_max 30 nohost 0"]
    for k, (j, x, y, th) in enumerate(walk() if steps is None else steps):
        w, h = BOXES[j]
        r = box_ranges(w, h, x, y, th) + np.random.default_rng(k).normal(0, 0.005, 181)
        rs = " ".join(f"{v:.3f}" for v in np.minimum(r, 30.0))
        wx = x + 20.0 * j
        lines.append(f"FLASER 181 {rs} {wx:.3f} {y:.3f} {th:.4f} 0 0 0 {k}.0 host {k}.0")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def write_bag(path: Path, steps: list[tuple[int, float, float, float]] | None = None) -> Path:
    """The same walk as a ROS 2 bag: ``/scan`` (180 deg LaserScan) and ``/odom`` (the world pose), 1 s apart."""
    import math

    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types

    def header(t: float, frame: str) -> object:
        stamp = T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=round((t - int(t)) * 1e9))
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    ls_t, od_t = "sensor_msgs/msg/LaserScan", "nav_msgs/msg/Odometry"
    with Writer(path, version=9) as w:
        c_scan = w.add_connection("/scan", ls_t, typestore=ts)
        c_odom = w.add_connection("/odom", od_t, typestore=ts)
        for k, (j, x, y, th) in enumerate(walk() if steps is None else steps):
            t = 10.0 + k
            w_, h_ = BOXES[j]
            r = (box_ranges(w_, h_, x, y, th) + np.random.default_rng(k).normal(0, 0.005, 181)).astype(np.float32)
            inc = math.pi / 180
            scan = T[ls_t](header=header(t, "base_link"), angle_min=-math.pi / 2, angle_max=math.pi / 2,
                           angle_increment=inc, time_increment=0.0, scan_time=0.1, range_min=0.05,
                           range_max=30.0, ranges=r, intensities=np.zeros(0, np.float32))  # fmt: skip
            q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(th / 2), w=math.cos(th / 2))
            pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x + 20.0 * j, y=y, z=0.0),
                                               orientation=q)  # fmt: skip
            v = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
            odom = T[od_t](
                header=header(t - 0.01, "odom"),
                child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](linear=v, angular=v), covariance=np.zeros(36)
                ),
            )
            w.write(c_odom, int((t - 0.01) * 1e9), ts.serialize_cdr(odom, od_t))
            w.write(c_scan, int(t * 1e9), ts.serialize_cdr(scan, ls_t))
    return path
