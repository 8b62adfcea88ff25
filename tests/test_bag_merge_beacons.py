"""Two lidars merged into one observation keep every beacon each lidar sees, whatever their intensity scales.

The bag is written with rosbags: a robot in a square room with a front and a
back lidar (270 deg each, on ``/tf_static``), the back one seeing a
retro-reflector (six times its wall's intensity, 10 cm wide) in a direction
the front lidar does not cover. The lidars report intensities on scales 25
times apart (two makes of lidar).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fingerloc.pipeline.readers import iter_bag_observations

from ._bags import header, store, tf3

HALF = 3.0  # the room: [-3, 3] x [-3, 3] metres around the robot
N = 541
FOV = math.radians(270.0)
FRONT = ((0.2, 0.0, 0.1), (0.0, 0.0, 0.0))
BACK = ((-0.2, 0.0, 0.1), (0.0, 0.0, math.pi))
BEACON_DEG = -160.0  # base-frame direction of the reflector, seen from the back lidar only


def _cast(origin, directions):
    ox, oy = origin
    dx, dy = directions[:, 0], directions[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(dx > 1e-12, (HALF - ox) / dx, np.where(dx < -1e-12, (-HALF - ox) / dx, np.inf))
        ty = np.where(dy > 1e-12, (HALF - oy) / dy, np.where(dy < -1e-12, (-HALF - oy) / dy, np.inf))
    return np.minimum(tx, ty)


def _lidar(mount, scale, rng, beacon=False):
    (x, y, _), (_, _, yaw) = mount
    phi = -FOV / 2 + FOV / (N - 1) * np.arange(N)
    d = np.column_stack([np.cos(phi + yaw), np.sin(phi + yaw)])
    r = _cast((x, y), d)
    inten = scale * (1.0 + 0.05 * rng.standard_normal(N))
    end = np.column_stack([x + r * d[:, 0], y + r * d[:, 1]])
    hit = np.zeros(N, dtype=bool)
    if beacon:  # a 10 cm reflector on the wall around the direction BEACON_DEG seen from the robot's origin
        b = math.radians(BEACON_DEG)
        centre = np.array([math.cos(b), math.sin(b)]) * _cast((0.0, 0.0), np.array([[math.cos(b), math.sin(b)]]))[0]
        hit = np.linalg.norm(end - centre, axis=1) <= 0.05
        inten[hit] *= 6.0
    return r.astype(np.float32), inten.astype(np.float32), end[hit]


def _write(path, front_scale, back_scale):
    from rosbags.rosbag2 import Writer

    ts = store(False)
    LS, TF = "sensor_msgs/msg/LaserScan", "tf2_msgs/msg/TFMessage"
    rng = np.random.default_rng(4)
    items = []
    reflector = None
    with Writer(path, version=9) as w:
        c_front = w.add_connection("/scan_front", LS, typestore=ts)
        c_back = w.add_connection("/scan_back", LS, typestore=ts)
        c_static = w.add_connection("/tf_static", TF, typestore=ts)
        static = [("base_link", "laser_front", FRONT), ("base_link", "laser_back", BACK)]
        items.append((0.5, c_static, TF, tf3(ts, 0.5, static, False)))
        for k in range(3):
            for conn, mount, frame, scale, dt, beacon in (
                (c_front, FRONT, "laser_front", front_scale, 0.0, False),
                (c_back, BACK, "laser_back", back_scale, 0.01, True),
            ):
                t = 1.0 + 0.1 * k + dt
                r, inten, ends = _lidar(mount, scale, rng, beacon)
                if beacon:
                    reflector = ends
                msg = ts.types[LS](
                    header=header(ts, t, frame, False), angle_min=-FOV / 2, angle_max=FOV / 2,
                    angle_increment=FOV / (N - 1), time_increment=0.0, scan_time=0.1, range_min=0.05,
                    range_max=30.0, ranges=r, intensities=inten,
                )  # fmt: skip
                items.append((t, conn, LS, msg))
        for t, c, typ, msg in sorted(items, key=lambda x: x[0]):
            w.write(c, int(t * 1e9), ts.serialize_cdr(msg, typ))
    c = reflector.mean(axis=0)
    return path, math.atan2(c[1], c[0])  # the reflector's bearing from the robot's origin


@pytest.mark.parametrize("scales", [(1000.0, 40.0), (100.0, 100.0)], ids=["scales-25x-apart", "same-scale"])
def test_merged_lidars_keep_the_beacon_only_the_back_lidar_sees(tmp_path, scales):
    path, bearing = _write(tmp_path / "two-lidars", *scales)
    opts = {"pose_source": "none"}
    back = [o for _, o in iter_bag_observations(path, bag_options={**opts, "topic": "/scan_back"})]
    merged = [o for _, o in iter_bag_observations(path, bag_options={**opts, "topic": ("/scan_front", "/scan_back")})]
    assert len(merged) == 3

    def near(obs):
        return [float(np.min(np.abs(np.angle(np.exp(1j * (o.b + 0.0 - bearing)))))) if o.b.size else np.inf for o in obs]

    # the back lidar alone: bearings in its own frame turned by its mount (pi)
    back_b = [o.b for o in back]
    assert all(b.size for b in back_b), "the back lidar's own scan shows the reflector"
    assert max(near(merged)) < math.radians(1.5), f"merged scans lost the reflector at {math.degrees(bearing):.1f} deg"


def test_merged_intensities_are_each_lidar_over_its_median():
    from fingerloc.io.frames import merge_scans
    from fingerloc.sensors import Scan

    phi = np.linspace(-1.0, 1.0, 11)
    a = Scan(np.full(11, 2.0), phi, max_range=10.0, intensities=np.full(11, 500.0))
    b = Scan(np.full(11, 2.0), phi, max_range=10.0, sensor_offset=(0.0, 0.0, math.pi))  # no intensities
    m = merge_scans([a, b])
    assert m.intensities is not None and m.intensities.size == m.ranges.size
    own = np.abs(np.angle(np.exp(1j * m.bearings))) <= 1.0 + 1e-9
    assert np.allclose(m.intensities[own], 1.0) and np.all(np.isnan(m.intensities[~own]))
