"""TUM and KITTI trajectories: round trips, the files as evo reads them, APE against a direct computation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fingerloc.errors import DataFormatError, EmptyInputError, InvalidParameterError
from fingerloc.io.trajectory import (
    TrajectoryWriter,
    quaternion_yaw,
    read_kitti,
    read_tum,
    write_kitti,
    write_tum,
    yaw_quaternion,
)

evo_file = pytest.importorskip("evo.tools.file_interface", reason="evo is a test extra (pip install -e '.[test]')")


def _wrap(a):
    return (np.asarray(a) + math.pi) % (2 * math.pi) - math.pi


def _walk(n, seed=0):
    rng = np.random.default_rng(seed)
    xy = np.cumsum(rng.normal(0, 0.3, (n, 2)), axis=0) + np.array([120.5, -33.25])
    th = _wrap(np.cumsum(rng.normal(0, 0.4, n)))
    return np.column_stack([xy, th]), 1.1e9 + np.cumsum(rng.uniform(0.05, 0.2, n))


finite = st.floats(-1e6, 1e6, allow_nan=False)
angle = st.floats(-50.0, 50.0, allow_nan=False)


@given(st.lists(st.tuples(finite, finite, angle), min_size=1, max_size=20))
def test_tum_round_trip_keeps_positions_exactly_and_headings_modulo_a_turn(tmp_path_factory, rows):
    path = tmp_path_factory.mktemp("tum") / "t.txt"
    poses = np.array(rows, dtype=np.float64)
    stamps = 1000.0 + np.arange(len(rows)) * 0.125
    assert write_tum(path, stamps, poses) == len(rows)
    t, back = read_tum(path)
    np.testing.assert_array_equal(t, stamps)
    np.testing.assert_array_equal(back[:, :2], poses[:, :2])
    np.testing.assert_allclose(_wrap(back[:, 2] - poses[:, 2]), 0.0, atol=1e-9)


@given(st.lists(st.tuples(finite, finite, angle), min_size=1, max_size=20))
def test_kitti_round_trip(tmp_path_factory, rows):
    path = tmp_path_factory.mktemp("kitti") / "k.txt"
    poses = np.array(rows, dtype=np.float64)
    write_kitti(path, poses)
    back = read_kitti(path)
    np.testing.assert_array_equal(back[:, :2], poses[:, :2])
    np.testing.assert_allclose(_wrap(back[:, 2] - poses[:, 2]), 0.0, atol=1e-9)


@given(angle)
def test_yaw_quaternion_turns_the_x_axis_by_theta(theta):
    qx, qy, qz, qw = yaw_quaternion(theta)
    assert qx * qx + qy * qy + qz * qz + qw * qw == pytest.approx(1.0)
    # the x axis rotated by q (v' = q v q*), computed from the quaternion product, independent of quaternion_yaw
    x = (1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy + qz * qw))
    assert x[0] == pytest.approx(math.cos(theta), abs=1e-12)
    assert x[1] == pytest.approx(math.sin(theta), abs=1e-12)
    assert quaternion_yaw(*(2.5 * v for v in (qx, qy, qz, qw))) == pytest.approx(float(_wrap(theta)), abs=1e-9)


def test_evo_reads_the_tum_file_as_the_same_planar_poses(tmp_path):
    poses, stamps = _walk(50)
    path = tmp_path / "est.tum"
    write_tum(path, stamps, poses)
    traj = evo_file.read_tum_trajectory_file(str(path))
    valid, details = traj.check()
    assert valid, details
    np.testing.assert_array_equal(traj.timestamps, stamps)
    np.testing.assert_allclose(traj.positions_xyz, np.column_stack([poses[:, :2], np.zeros(50)]), atol=0)
    se3 = np.array(traj.poses_se3)
    np.testing.assert_allclose(se3[:, 0, 0], np.cos(poses[:, 2]), atol=1e-12)
    np.testing.assert_allclose(se3[:, 1, 0], np.sin(poses[:, 2]), atol=1e-12)
    np.testing.assert_allclose(se3[:, 2, 2], 1.0, atol=1e-12)


def test_evo_reads_the_kitti_file_as_the_same_matrices(tmp_path):
    poses, _ = _walk(30, seed=3)
    path = tmp_path / "est.kitti"
    write_kitti(path, poses)
    se3 = np.array(evo_file.read_kitti_poses_file(str(path)).poses_se3)
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    expected = np.zeros((30, 4, 4))
    expected[:, 0, 0], expected[:, 0, 1], expected[:, 1, 0], expected[:, 1, 1] = c, -s, s, c
    expected[:, 2, 2] = expected[:, 3, 3] = 1.0
    expected[:, 0, 3], expected[:, 1, 3] = poses[:, 0], poses[:, 1]
    np.testing.assert_allclose(se3, expected, atol=1e-12)


def test_evo_ape_of_two_tum_files_is_the_rms_of_the_position_errors(tmp_path):
    from evo import main_ape
    from evo.core import metrics, sync

    ref, stamps = _walk(80, seed=5)
    est = ref + np.random.default_rng(6).normal(0, [0.2, 0.1, 0.05], ref.shape)
    write_tum(tmp_path / "ref.tum", stamps, ref)
    write_tum(tmp_path / "est.tum", stamps[::2], est[::2])  # every other step: evo pairs them by time
    r = evo_file.read_tum_trajectory_file(str(tmp_path / "ref.tum"))
    e = evo_file.read_tum_trajectory_file(str(tmp_path / "est.tum"))
    r, e = sync.associate_trajectories(r, e, max_diff=1e-6)
    res = main_ape.ape(r, e, metrics.PoseRelation.translation_part)
    direct = math.sqrt(float(np.mean(np.sum((est[::2, :2] - ref[::2, :2]) ** 2, axis=1))))
    assert res.stats["rmse"] == pytest.approx(direct, rel=1e-9)


def test_writer_puts_the_file_in_place_only_at_close(tmp_path):
    path = tmp_path / "live.tum"
    path.write_text("old\n")
    w = TrajectoryWriter(path, "tum", flush=True)
    w.add((1.0, 2.0, 0.5), 10.0)
    w.add((1.5, 2.0, 0.5), 10.1)
    assert path.read_text() == "old\n"
    assert w.close() == 2
    t, p = read_tum(path)
    np.testing.assert_array_equal(t, [10.0, 10.1])
    np.testing.assert_array_equal(p[:, 0], [1.0, 1.5])
    assert [q.name for q in tmp_path.iterdir()] == ["live.tum"]


def test_a_failed_write_leaves_the_existing_file_byte_identical(tmp_path):
    path = tmp_path / "est.tum"
    path.write_bytes(b"keep me\n")
    with pytest.raises(InvalidParameterError, match="finite"):
        write_tum(path, [1.0, 2.0], [(0.0, 0.0, 0.0), (np.nan, 0.0, 0.0)])
    assert path.read_bytes() == b"keep me\n"
    assert [q.name for q in tmp_path.iterdir()] == ["est.tum"]


def test_tum_refuses_timestamps_that_do_not_increase(tmp_path):
    with pytest.raises(InvalidParameterError, match=r"pose 3 at 1\.0 s follows one at 2\.0 s"):
        write_tum(tmp_path / "t.tum", [1.0, 2.0, 1.0], np.zeros((3, 3)))
    with TrajectoryWriter(tmp_path / "u.tum") as w, pytest.raises(InvalidParameterError, match="no timestamp"):
        w.add((0.0, 0.0, 0.0))


def test_writer_refuses_an_unknown_format_and_a_missing_directory(tmp_path):
    with pytest.raises(InvalidParameterError, match="format must be one of tum, kitti"):
        TrajectoryWriter(tmp_path / "x", "csv")
    with pytest.raises(InvalidParameterError, match=r"directory .* does not exist"):
        TrajectoryWriter(tmp_path / "missing" / "x.tum")


@pytest.mark.parametrize(
    ("text", "reader", "match"),
    [
        ("1 2 3 4 0 0 0 1\n1 2 3\n", read_tum, r"t\.txt:2: TUM line has 3 numbers, expected 8"),
        ("# only a comment\n", read_tum, "no pose"),
        ("1 2 3 4 0 0 0 x\n", read_tum, "got 'x'"),
        ("1 2 3 4 0 0 0 0\n", read_tum, "quaternion is zero"),
        ("1 2 3 nan 0 0 0 1\n", read_tum, "finite"),
        ("1 0 0 0 0 1 0 0 0 0 1\n", read_kitti, r"t\.txt:1: KITTI line has 11 numbers, expected 12"),
    ],
)
def test_readers_name_the_bad_line(tmp_path, text, reader, match):
    path = tmp_path / "t.txt"
    path.write_text(text)
    with pytest.raises((DataFormatError, EmptyInputError), match=match):
        reader(path)


def test_a_lenient_writer_writes_a_repeated_stamp_just_after_the_previous_one(tmp_path):
    with TrajectoryWriter(tmp_path / "t.tum", "tum", strict=False) as w:
        for t in (5.0, 5.0, 4.0, 6.0):
            w.add((0.0, 0.0, 0.0), t)
    assert w.nudged == 2
    t, _ = read_tum(tmp_path / "t.tum")
    np.testing.assert_allclose(t, [5.0, 5.0 + 1e-6, 5.0 + 2e-6, 6.0], rtol=0, atol=1e-9)
    assert evo_file.read_tum_trajectory_file(str(tmp_path / "t.tum")).check()[0]
