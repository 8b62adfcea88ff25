"""Tests of the simulated worlds and the 360 deg laser on tiny worlds with closed-form ranges."""

from __future__ import annotations

import time

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from fingerloc.errors import InvalidParameterError
from fingerloc.sensors import Scan
from fingerloc.sim import Material, World, make_offices, simulate_scan
from fingerloc.sim.world import cast_rays

WALL = Material((0.8, 0.8, 0.78), reflectivity=0.5)
BEACON = Material((0.7, 0.7, 0.7), reflectivity=1.5, beacon=True)


def square_room(half: float = 2.0) -> World:
    """A square room of side ``2 half`` centred on the origin."""
    c = [(-half, -half), (half, -half), (half, half), (-half, half)]
    seg = [(*c[i], *c[(i + 1) % 4]) for i in range(4)]
    return World(segments=seg, z_range=[(0.0, 2.5)] * 4, material=[0] * 4, materials=(WALL,), room=c)


def single_wall(x: float = 3.0, half_len: float = 2.0, mat: Material = WALL) -> World:
    return World(segments=[(x, -half_len, x, half_len)], z_range=[(0.0, 2.5)], material=[0], materials=(mat,))


def test_square_room_ranges_closed_form() -> None:
    half = 2.0
    scan = simulate_scan(square_room(half), (0.0, 0.0, 0.0), n_beams=720, range_noise=0.0)
    b = scan.bearings
    # From the centre of a square, range = half / max(|cos b|, |sin b|).
    expected = half / np.maximum(np.abs(np.cos(b)), np.abs(np.sin(b)))
    np.testing.assert_allclose(scan.ranges, expected, rtol=1e-9)
    assert scan.valid.all()
    assert scan.fov == ((-np.pi, 2 * np.pi),)


def test_heading_rotates_the_scan() -> None:
    w = square_room(2.0)
    a = simulate_scan(w, (0.3, -0.2, 0.0), n_beams=360, range_noise=0.0)
    b = simulate_scan(w, (0.3, -0.2, np.pi / 2), n_beams=360, range_noise=0.0)
    # Turning the robot by 90 deg (= 90 beams) shifts the scan by 90 beams.
    np.testing.assert_allclose(b.ranges, np.roll(a.ranges, -90), rtol=1e-9)


def test_single_wall_distance_and_max_range() -> None:
    w = single_wall(3.0, 2.0)
    scan = simulate_scan(w, (0.0, 0.0, 0.0), n_beams=720, range_noise=0.0, max_range=10.0)
    b = scan.bearings
    seen = np.abs(np.tan(b)) * 3.0 <= 2.0
    seen &= np.cos(b) > 0
    np.testing.assert_allclose(scan.ranges[seen], 3.0 / np.cos(b[seen]), rtol=1e-9)
    assert not scan.valid[~seen].any()
    # Beyond max_range: no return.
    far = simulate_scan(w, (0.0, 0.0, 0.0), n_beams=720, range_noise=0.0, max_range=2.9)
    assert not far.valid.any()
    assert np.all(far.intensities == 0)


def test_range_noise_statistics() -> None:
    w = single_wall(3.0, 50.0)
    scan = simulate_scan(w, (0.0, 0.0, 0.0), n_beams=720, range_noise=0.02, max_range=100.0, random_state=3)
    b = scan.bearings
    front = np.abs(b) < np.deg2rad(30)
    err = scan.ranges[front] - 3.0 / np.cos(b[front])
    assert abs(err.mean()) < 0.01
    assert 0.014 < err.std() < 0.026


def test_beacon_intensity() -> None:
    x = 2.0
    plain = simulate_scan(single_wall(x, 5.0), (0.0, 0.0, 0.0), range_noise=0.0, intensity_noise=0.0)
    bright = simulate_scan(single_wall(x, 5.0, mat=BEACON), (0.0, 0.0, 0.0), range_noise=0.0, intensity_noise=0.0)
    i0 = int(np.argmin(np.abs(plain.bearings - np.deg2rad(0.25))))
    # Diffuse: rho cos(a) / (1 + 0.05 r); retro-reflector: rho (0.8 + 0.2 cos a) / (1 + 0.02 r).
    a = plain.bearings[i0]
    r = x / np.cos(a)
    assert plain.intensities is not None and bright.intensities is not None
    assert plain.intensities[i0] == pytest.approx(0.5 * np.cos(a) / (1 + 0.05 * r), abs=0.006)
    assert bright.intensities[i0] == pytest.approx(1.5 * (0.8 + 0.2 * np.cos(a)) / (1 + 0.02 * r), abs=0.006)
    # At 60 deg incidence the beacon stays bright, the wall fades.
    j = int(np.argmin(np.abs(plain.bearings - np.deg2rad(60))))
    assert bright.intensities[j] > 3 * plain.intensities[j]


def test_beacon_decal_on_wall_is_bright_only_at_its_height() -> None:
    w = World(
        segments=[(2.0, -1.0, 2.0, 1.0)],
        z_range=[(0.0, 2.5)],
        material=[0],
        materials=(WALL, BEACON),
        decal_z=[(0.1, 0.9)],
        decal_material=[1],
    )
    low = simulate_scan(w, (0, 0, 0), range_noise=0.0, intensity_noise=0.0, height=0.3)
    high = simulate_scan(w, (0, 0, 0), range_noise=0.0, intensity_noise=0.0, height=1.5)
    assert low.intensities is not None and high.intensities is not None
    assert low.intensities.max() > 1.0 > 0.6 > high.intensities.max()


def test_scan_height_sees_only_spanning_segments() -> None:
    w = World(
        segments=[(1.0, -1, 1.0, 1), (3.0, -1, 3.0, 1)],
        z_range=[(0.0, 0.7), (0.0, 2.5)],
        material=[0, 0],
        materials=(WALL,),
    )
    d_low, s_low, _ = cast_rays(w, (0.0, 0.0), [0.0], z=0.3)
    d_high, s_high, _ = cast_rays(w, (0.0, 0.0), [0.0], z=1.0)
    assert d_low[0] == pytest.approx(1.0) and s_low[0] == 0
    assert d_high[0] == pytest.approx(3.0) and s_high[0] == 1


def test_scan_type_and_determinism() -> None:
    w = make_offices(1, random_state=5)[0]
    pose = (*w.anchor, 0.4)
    a = simulate_scan(w, pose, random_state=11)
    b = simulate_scan(w, pose, random_state=11)
    c = simulate_scan(w, pose, random_state=12)
    assert isinstance(a, Scan) and a.ranges.shape == (720,) and a.intensities is not None
    np.testing.assert_array_equal(a.ranges, b.ranges)
    np.testing.assert_array_equal(a.intensities, b.intensities)
    assert not np.array_equal(a.ranges, c.ranges)
    assert np.all(np.diff(a.bearings) > 0)
    assert a.pose == pytest.approx(pose)


def test_beacons_brighter_than_walls_in_offices() -> None:
    for w in make_offices(4, random_state=2):
        scan = simulate_scan(w, (*w.anchor, 0.0), random_state=0)
        assert scan.intensities is not None
        walls = scan.intensities[scan.valid]
        # Most beams are ordinary surfaces, well below the beacon level.
        assert np.percentile(walls, 90) < 0.7


@pytest.mark.parametrize("bad", [{"n_beams": 7}, {"n_beams": 2}, {"range_noise": -1.0}, {"max_range": 0.0}])
def test_bad_parameters(bad: dict[str, float]) -> None:
    with pytest.raises(InvalidParameterError, match=next(iter(bad))):
        simulate_scan(square_room(), (0, 0, 0), **bad)  # type: ignore[arg-type]


def test_make_offices_similarity_and_seed() -> None:
    a = make_offices(3, similarity=0.7, random_state=4)
    b = make_offices(3, similarity=0.7, random_state=4)
    for wa, wb in zip(a, b, strict=True):
        np.testing.assert_array_equal(wa.segments, wb.segments)
    same = make_offices(3, similarity=1.0, random_state=4)
    for w in same[1:]:
        np.testing.assert_array_equal(w.segments, same[0].segments)
    diff = make_offices(3, similarity=0.0, random_state=4)
    assert diff[0].segments.shape != diff[1].segments.shape or not np.allclose(diff[0].segments, diff[1].segments)
    assert [w.name for w in a] == ["office-0", "office-1", "office-2"]
    for w in a:
        assert w.contains(np.array(w.anchor)) and w.clearance(np.array(w.anchor)) > 0.8
        assert not w.segments.flags.writeable


@pytest.mark.parametrize("bad", [{"n": 0}, {"similarity": 1.5}, {"similarity": -0.1}])
def test_make_offices_bad(bad: dict[str, float]) -> None:
    kw = {"n": 2, **bad}
    with pytest.raises(InvalidParameterError, match=next(iter(bad))):
        make_offices(kw.pop("n"), **kw)  # type: ignore[arg-type]


def test_scan_speed_smoke() -> None:
    w = make_offices(1, random_state=0)[0]
    t0 = time.perf_counter()
    for _ in range(5):
        simulate_scan(w, (*w.anchor, 0.0))
    assert (time.perf_counter() - t0) / 5 < 0.5  # loose: the target (<100 ms) is measured by bench speed


def test_protocol_poses() -> None:
    from fingerloc.sim import protocol_poses

    for w in make_offices(3, random_state=9):
        train, test = protocol_poses(w, random_state=1, heading=0.25)
        assert train.shape == (8, 3) and test.shape == (2, 3)
        d_train = np.hypot(train[:, 0] - w.anchor[0], train[:, 1] - w.anchor[1])
        d_test = np.hypot(test[:, 0] - w.anchor[0], test[:, 1] - w.anchor[1])
        assert np.all(d_train <= 0.7 + 1e-9) and np.all(d_test < d_train.max())
        assert np.all(train[:, 2] == 0.25) and np.all(test[:, 2] == 0.25)
        assert np.all(w.clearance(train[:, :2]) >= 0.3) and np.all(w.contains(train[:, :2]))
        again, _ = protocol_poses(w, random_state=1, heading=0.25)
        np.testing.assert_array_equal(train, again)


def _slow_cast(segs: np.ndarray, origin: tuple[float, float], angle: float) -> float:
    """Textbook oracle: intersect one ray with each segment in turn."""
    best = np.inf
    o = np.array(origin)
    d = np.array([np.cos(angle), np.sin(angle)])
    for x0, y0, x1, y1 in segs:
        p, e = np.array([x0, y0]), np.array([x1 - x0, y1 - y0])
        m = np.array([[d[0], -e[0]], [d[1], -e[1]]])
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        u, t = np.linalg.solve(m, p - o)
        if u > 1e-6 and -1e-9 <= t <= 1 + 1e-9:
            best = min(best, u)
    return best


@settings(max_examples=40, deadline=None)
@given(
    segs=hnp.arrays(np.float64, st.tuples(st.integers(1, 6), st.just(4)), elements=st.floats(-5, 5)),
    angles=hnp.arrays(np.float64, st.integers(1, 20), elements=st.floats(-np.pi, np.pi)),
)
def test_cast_rays_matches_slow_oracle(segs: np.ndarray, angles: np.ndarray) -> None:
    lengths = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
    assume(np.all(lengths > 1e-3))
    origin = (0.1, -0.2)
    # Keep the origin off the segments (a ray starting on a wall is ill-posed).
    w = World(segments=segs, z_range=[(0.0, 1.0)] * len(segs), material=[0] * len(segs), materials=(WALL,))
    assume(float(w.clearance(np.array(origin))) > 1e-3)
    dist, _, _ = cast_rays(w, origin, angles)
    for a, d in zip(angles, dist, strict=True):
        ref = _slow_cast(segs, origin, float(a))
        if np.isinf(ref):
            assert np.isinf(d)
        else:
            assert d == pytest.approx(ref, rel=1e-7, abs=1e-7)


def _proper_crossings(w: World) -> int:
    """Pairs of segments crossing in both interiors (the generator must never make them)."""
    s = w.segments
    p, r = s[:, :2], s[:, 2:] - s[:, :2]
    den = r[:, None, 0] * r[None, :, 1] - r[:, None, 1] * r[None, :, 0]
    q = p[None, :, :] - p[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (q[..., 0] * r[None, :, 1] - q[..., 1] * r[None, :, 0]) / den
        u = (q[..., 0] * r[:, None, 1] - q[..., 1] * r[:, None, 0]) / den
    eps = 1e-6
    cross = (np.abs(den) > 1e-12) & (t > eps) & (t < 1 - eps) & (u > eps) & (u < 1 - eps)
    return int(cross.sum())


def test_generated_geometry_is_consistent() -> None:
    from fingerloc.sim import PARTS

    inside_parts = [PARTS.index(k) for k in ("furniture", "pillar", "door_leaf")]
    n_leaves = 0
    for seed in (0, 8):
        for w in make_offices(10, random_state=seed):
            assert _proper_crossings(w) == 0, w.name
            mids = (w.segments[:, :2] + w.segments[:, 2:]) / 2
            sel = np.isin(w.part, inside_parts)
            assert np.all(w.contains(mids[sel])), w.name
            corridor = w.part == PARTS.index("corridor")
            assert not np.any(w.contains(mids[corridor])), w.name
            n_leaves += int((w.part == PARTS.index("door_leaf")).sum())
    assert n_leaves > 0


def test_paper_world_has_chairs_and_alike_is_unchanged():
    from fingerloc.sim import PARTS

    chair = PARTS.index("chair")
    paper = make_offices(3, random_state=11, world="paper")
    assert all((w.part == chair).sum() >= 8 for w in paper)  # two chairs or more: seat block + column
    for w in paper:
        seats = w.segments[(w.part == chair) & (w.z_range[:, 0] > 0.3)]
        # chairs stand inside the room
        assert w.contains(seats[:, :2]).all() and w.contains(seats[:, 2:]).all()
    alike = make_offices(3, random_state=11)
    assert not any((w.part == chair).any() for w in alike)
    again = make_offices(3, random_state=11, world="alike")
    assert all(np.array_equal(a.segments, b.segments) for a, b in zip(alike, again, strict=True))
    # the same offices as the generator gave before the "paper" world existed (measured on commit f8aeaf3)
    assert sum(w.n_segments for w in alike) == 124
    assert float(sum(np.abs(w.segments).sum() for w in alike)) == pytest.approx(1224.483013603562, rel=1e-12)


def test_make_offices_bad_world():
    with pytest.raises(InvalidParameterError, match="world"):
        make_offices(2, world="villa")
