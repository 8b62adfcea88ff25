"""Files for ``scripts/hostile.py``'s batteries: place files, CARMEN logs of boxes, PNG images, ROS 2 bags."""

from __future__ import annotations

import json
import math
import struct
import zlib
from pathlib import Path
from typing import Any

__all__ = ["box_ranges", "carmen_log", "places_file", "png", "real_png", "shifted_log", "stripes16", "write_bag"]


def places_file(path: Path, labels: list[str], *, poses: bool = True, offset: int = 0) -> Path:
    """JSON Lines of three views per label (vertical edges and colour bearings), 2 m apart along x with ``poses``."""
    lines = []
    for k, lab in enumerate(labels):
        for j in range(3):
            ve = [(10 + 37 * (k + offset) + 40 * i + 2 * j) % 360 for i in range(5)]
            rec: dict[str, object] = {"place": lab, "features": {"VE": ve, "c": [ve[0] + 5, ve[2] + 7]}}
            if poses:
                rec["pose"] = [2.0 * k + 0.1 * j, 0.0, 0.0]
            lines.append(json.dumps(rec))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def box_ranges(w: float, h: float, x: float, y: float, th: float, n: int = 181) -> list[float]:
    """Ranges (metres, at most 30) of a 180 deg scan of ``n`` beams from ``(x, y, th)`` inside a ``w`` x ``h`` box."""
    out = []
    for i in range(n):
        a = th - math.pi / 2 + math.pi * i / (n - 1)
        dx, dy = math.cos(a), math.sin(a)
        ts = []
        if dx > 1e-12:
            ts.append((w - x) / dx)
        if dx < -1e-12:
            ts.append(-x / dx)
        if dy > 1e-12:
            ts.append((h - y) / dy)
        if dy < -1e-12:
            ts.append(-y / dy)
        out.append(min(min(ts), 30.0))
    return out


def carmen_log(path: Path, *, scans: int | None = None) -> Path:
    """A CARMEN log of 18 scans (FLASER and ODOM) through three boxes 20 m apart, twice; the first ``scans`` only."""
    rooms = [(4.0, 3.0), (6.0, 2.5), (3.0, 3.0)]
    lines = ["# synthetic", "PARAM robot_front_laser_max 30 nohost 0"]
    steps = [(w, h, w / 2 + dx, h / 2, 0.3 * dx) for _ in range(2) for (w, h) in rooms for dx in (-0.3, 0.0, 0.3)]
    if scans is not None:
        steps = steps[:scans]
    for k, (w, h, x, y, th) in enumerate(steps):
        r = " ".join(f"{v:.3f}" for v in box_ranges(w, h, x, y, th))
        wx = x + 20.0 * [r_[0] for r_ in rooms].index(w)
        lines.append(f"FLASER 181 {r} {wx:.3f} {y:.3f} {th:.4f} 0 0 0 {k}.0 host {k}.0")
        lines.append(f"ODOM {wx:.3f} {y:.3f} {th:.4f} 0 0 0 {k}.0 host {k}.0")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def png(path: Path, w: int, h: int) -> Path:
    def chunk(t: bytes, d: bytes) -> bytes:
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))
    return path


def shifted_log(src: Path, dst: Path, dx: float) -> Path:
    out = []
    for line in src.read_text().splitlines():
        p = line.split()
        if p and p[0] == "FLASER":
            n = int(p[1])
            for k in (2 + n, 2 + n + 3):
                p[k] = f"{float(p[k]) + dx:.3f}"
        elif p and p[0] == "ODOM":
            p[1] = f"{float(p[1]) + dx:.3f}"
        out.append(" ".join(p))
    dst.write_text("\n".join(out) + "\n")
    return dst


def real_png(path: Path, w: int, h: int, *, depth: int = 8, rows: Any = None) -> Path:
    """A valid PNG (grey), its rows from ``rows(y)`` (bytes) or zeros."""
    def chunk(t: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + t + data + struct.pack(">I", zlib.crc32(t + data) & 0xFFFFFFFF)

    width = w * depth // 8
    raw = b"".join(b"\0" + (rows(y) if rows else b"\0" * width) for y in range(h))
    ihdr = struct.pack(">IIBBBBB", w, h, depth, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))
    return path


def stripes16(y: int) -> bytes:
    # 16-bit grey stripes between 20000 and 60000 (above 255 everywhere: clipped, all white)
    return b"".join(struct.pack(">H", 20000 if (x // 40) % 2 else 60000) for x in range(1440))


def write_bag(path: Path, *, ranges: Any = None, mount: tuple[float, float, float] = (0.0, 0.0, 0.0),
               topics: tuple[str, ...] = ("/scan",), beacon: bool = False, scales: tuple[float, ...] = (100.0,),
               stamps: int = 4) -> Path:  # fmt: skip
    """A ROS 2 bag: LaserScans (270 deg, 541 beams) of a 6 x 6 m room on ``topics`` (a front lidar, then one
    turned by pi), their mounts on /tf_static, odometry on /odom (the robot moves 0.5 m along x per scan);
    ``ranges`` overrides every range; with ``beacon`` the second lidar sees a 10 cm reflector at -160 deg
    that the first does not cover."""
    import numpy as np
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    n, fov = 541, math.radians(270.0)
    rng = np.random.default_rng(1)

    def header(t: float, frame: str) -> Any:
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=round((t % 1) * 1e9)),
                                        frame_id=frame)  # fmt: skip

    def quat(yaw: float) -> Any:
        return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))

    mounts = [(0.2, 0.0, 0.0), (-0.2, 0.0, math.pi)]
    with Writer(path, version=9) as wr:
        conns = [wr.add_connection(t, "sensor_msgs/msg/LaserScan", typestore=ts) for t in topics]
        c_static = wr.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts)
        c_odom = wr.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        links = []
        for k in range(len(topics)):
            x, y, yaw = mount if (k == 0 and mount != (0.0, 0.0, 0.0)) else mounts[k]
            tr = T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.1),
                                                  rotation=quat(yaw if math.isfinite(yaw) else 0.0))  # fmt: skip
            links.append(T["geometry_msgs/msg/TransformStamped"](header=header(0.5, "base_link"),
                                                                 child_frame_id=f"laser{k}", transform=tr))  # fmt: skip
        wr.write(c_static, int(0.5e9), ts.serialize_cdr(T["tf2_msgs/msg/TFMessage"](transforms=links),
                                                        "tf2_msgs/msg/TFMessage"))  # fmt: skip
        for s in range(stamps):
            zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
            odom = T["nav_msgs/msg/Odometry"](
                header=header(1.0 + 0.1 * s, "odom"), child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=0.5 * s, y=0.0, z=0.0), orientation=quat(0.0)),
                    covariance=np.zeros(36)),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=T["geometry_msgs/msg/Twist"](
                    linear=zero, angular=zero), covariance=np.zeros(36)),
            )  # fmt: skip
            wr.write(c_odom, int((1.0 + 0.1 * s) * 1e9), ts.serialize_cdr(odom, "nav_msgs/msg/Odometry"))
            for k, conn in enumerate(conns):
                x, y, yaw = mounts[k]
                phi = -fov / 2 + fov / (n - 1) * np.arange(n)
                dx, dy = np.cos(phi + yaw), np.sin(phi + yaw)
                with np.errstate(divide="ignore"):
                    tx = np.where(dx > 0, (3 - x) / dx, np.where(dx < 0, (-3 - x) / dx, np.inf))
                    ty = np.where(dy > 0, (3 - y) / dy, np.where(dy < 0, (-3 - y) / dy, np.inf))
                r = np.minimum(tx, ty)
                inten = scales[min(k, len(scales) - 1)] * (1 + 0.05 * rng.standard_normal(n))
                if beacon and k == 1:
                    ex, ey = x + r * dx, y + r * dy
                    bb = math.radians(-160.0)
                    cx, cy = 3.0 * math.cos(bb) / abs(math.cos(bb)), 3.0 * math.tan(bb) * math.copysign(1, math.cos(bb))
                    inten[np.hypot(ex - cx, ey - cy) <= 0.05] *= 6
                rr = np.full(n, ranges, dtype=np.float32) if ranges is not None else r.astype(np.float32)
                t = 1.0 + 0.1 * s + 0.01 * k
                msg = T["sensor_msgs/msg/LaserScan"](header=header(t, f"laser{k}"), angle_min=-fov / 2,
                                                     angle_max=fov / 2, angle_increment=fov / (n - 1),
                                                     time_increment=0.0, scan_time=0.1, range_min=0.05,
                                                     range_max=30.0, ranges=rr,
                                                     intensities=inten.astype(np.float32))  # fmt: skip
                wr.write(conn, int(t * 1e9), ts.serialize_cdr(msg, "sensor_msgs/msg/LaserScan"))
    return path
