"""Tests of the simulated camera (panorama and omnidirectional donut) and of the ground-truth features."""

from __future__ import annotations

import time

import numpy as np
import pytest

from fingerloc.angles import dist_as
from fingerloc.errors import InvalidParameterError
from fingerloc.observation import Observation
from fingerloc.sensors import Panorama
from fingerloc.sim import (
    CAMERA_HEIGHT,
    Material,
    OmniImage,
    World,
    make_offices,
    render_omni,
    render_panorama,
    true_features,
    true_observation,
)

WALL = Material((0.8, 0.8, 0.8), reflectivity=0.5)
RED = Material((0.9, 0.1, 0.1), patch=True)
BEACON = Material((0.75, 0.75, 0.75), reflectivity=1.5, beacon=True)
CLEAN = {"lighting": 0.0, "sun": False, "vignetting": 0.0, "noise": 0.0, "blur": 0.0}


def room(
    half: float = 2.0,
    *,
    decal_wall: int | None = None,
    decal: int = 1,
    z: tuple[float, float] = (0.9, 1.6),
    piece: tuple[float, float] | None = None,
) -> World:
    """Square room of side ``2 half`` centred at the origin, walls counter-clockwise from the south.

    With ``decal_wall``, that wall gets a middle piece ``piece`` (from, to along the wall, metres)
    carrying material ``decal`` between heights ``z``.
    """
    c = [(-half, -half), (half, -half), (half, half), (-half, half)]
    seg, dz, dm = [], [], []
    for i in range(4):
        p0, p1 = np.array(c[i]), np.array(c[(i + 1) % 4])
        if i == decal_wall and piece is not None:
            t = (p1 - p0) / np.linalg.norm(p1 - p0)
            pts = [p0, p0 + piece[0] * t, p0 + piece[1] * t, p1]
            for k in range(3):
                seg.append((*pts[k], *pts[k + 1]))
                dz.append(z if k == 1 else (np.nan, np.nan))
                dm.append(decal if k == 1 else -1)
        else:
            seg.append((*p0, *p1))
            dz.append((np.nan, np.nan))
            dm.append(-1)
    m = len(seg)
    return World(
        segments=seg,
        z_range=[(0.0, 2.6)] * m,
        material=[0] * m,
        materials=(WALL, RED, BEACON),
        decal_z=dz,
        decal_material=dm,
        height=2.6,
        floor_rgb=(0.2, 0.2, 0.2),
        ceiling_rgb=(0.95, 0.95, 0.95),
        light_angle=0.3,
        room=c,
    )


# ------------------------------------------------------------------ panorama
def test_panorama_shape_convention_and_determinism() -> None:
    w = make_offices(1, random_state=3)[0]
    pose = (*w.anchor, 0.2)
    a = render_panorama(w, pose, random_state=1)
    b = render_panorama(w, pose, random_state=1)
    c = render_panorama(w, pose, random_state=2)
    assert isinstance(a, Panorama) and a.image.shape == (120, 720, 3)
    assert a.clockwise and a.bearing_offset == pytest.approx(np.pi)
    np.testing.assert_array_equal(a.image, b.image)
    assert not np.array_equal(a.image, c.image)
    small = render_panorama(w, pose, width=360, height=60, random_state=1)
    assert small.image.shape == (60, 360, 3)


def test_panorama_wall_floor_boundary_closed_form() -> None:
    half = 2.0
    pano = render_panorama(room(half), (0.0, 0.0, 0.0), width=720, height=170, elevation_deg=(-45, 40), **CLEAN)
    col = int(pano.bearing_column(0.0))  # looking at the east wall, 2 m away
    lum = pano.image[:, col].mean(axis=1)
    # Rows from the top: the first dark (floor) row; the floor meets the wall at elevation atan(-h / d).
    first_floor = int(np.argmax(lum < 0.3))
    e = np.degrees(np.arctan2(-CAMERA_HEIGHT, half))
    expected = (40 - e) / 85 * 170
    assert abs(first_floor - expected) <= 1.0
    # The ceiling meets the wall at atan((H - h) / d).
    top_wall = int(np.argmax(lum < 0.9))
    e_top = np.degrees(np.arctan2(2.6 - CAMERA_HEIGHT, half))
    assert abs(top_wall - (40 - e_top) / 85 * 170) <= 1.0


@pytest.mark.parametrize(("wall", "bearing"), [(0, -np.pi / 2), (1, 0.0), (2, np.pi / 2), (3, np.pi)])
def test_panorama_patch_at_known_bearing(wall: int, bearing: float) -> None:
    # A red patch in the middle of one wall (1.8 .. 2.2 m along a 4 m wall), robot heading 0.
    w = room(2.0, decal_wall=wall, piece=(1.8, 2.2))
    pano = render_panorama(w, (0.0, 0.0, 0.0), **CLEAN)
    img = pano.image
    red = (img[..., 0] > 0.5) & (img[..., 1] < 0.3)
    cols = np.nonzero(red)[1] + 0.5
    got = np.angle(np.exp(1j * pano.column_bearing(cols)).mean())
    assert abs(dist_as(bearing, got)) < np.deg2rad(0.5)


def test_panorama_rotates_with_heading() -> None:
    w = make_offices(1, random_state=4)[0]
    a = render_panorama(w, (*w.anchor, 0.0), **CLEAN)
    b = render_panorama(w, (*w.anchor, np.pi / 2), **CLEAN)
    # Turning left by 90 deg moves the scene a quarter turn to the right (clockwise columns).
    np.testing.assert_allclose(b.image, np.roll(a.image, 180, axis=1), atol=2 / 255)


def test_panorama_effects() -> None:
    w = make_offices(1, random_state=5)[0]
    pose = (*w.anchor, 0.0)
    clean = render_panorama(w, pose, **CLEAN)
    vign = render_panorama(w, pose, **{**CLEAN, "vignetting": 0.5})
    ratio = vign.image.mean(axis=(1, 2)) / np.maximum(clean.image.mean(axis=(1, 2)), 1e-3)
    assert ratio[0] < 0.6 and ratio[-1] < 0.6 and ratio[60] > 0.95
    noisy = render_panorama(w, pose, **{**CLEAN, "noise": 0.03}, random_state=0)
    assert 0.02 < float(np.std(noisy.image - clean.image)) < 0.04
    jpeg = render_panorama(w, pose, **CLEAN, jpeg_quality=50)
    err = np.abs(jpeg.image - clean.image)
    assert 0 < float(err.mean()) < 0.03
    lit = [render_panorama(w, pose, **{**CLEAN, "lighting": 1.0}, random_state=s).image.mean() for s in range(4)]
    assert np.ptp(lit) > 0.01


def test_offices_have_low_saturation_except_patches() -> None:
    for w in make_offices(5, random_state=6):
        for m in w.materials:
            if m.patch:
                assert m.saturation >= 0.45
            else:
                assert m.saturation <= 0.26
        assert w.materials and any(m.patch for m in w.materials)


# ------------------------------------------------------------------ omni
def test_omni_maps_bearing_to_pixel_angle() -> None:
    w = room(2.0, decal_wall=2, piece=(1.8, 2.2))  # red patch on the north wall: bearing +90 deg from heading 0
    for clockwise, fwd in ((False, np.pi / 2), (True, 0.3)):
        o = render_omni(
            w, (0.0, 0.0, 0.0), size=(640, 480), radii=(60, 230), forward_angle=fwd, clockwise=clockwise, **CLEAN
        )
        assert isinstance(o, OmniImage) and o.image.shape == (480, 640, 3) and o.image.dtype == np.uint8
        img = o.image.astype(float) / 255
        red = (img[..., 0] > 0.5) & (img[..., 1] < 0.3)
        ys, xs = np.nonzero(red)
        phi = np.arctan2(-(ys + 0.5 - o.center[1]), xs + 0.5 - o.center[0])
        got_phi = np.angle(np.exp(1j * phi).mean())
        assert abs(dist_as(o.bearing_to_angle(np.pi / 2), got_phi)) < np.deg2rad(1.0)
        got_b = np.angle(np.exp(1j * o.pixel_bearing(xs + 0.5, ys + 0.5)).mean())
        assert abs(dist_as(np.pi / 2, got_b)) < np.deg2rad(1.0)
        # Radius: the patch spans elevations atan((0.9 - h) / 2) .. atan((1.6 - h) / 2).
        r = np.hypot(xs + 0.5 - o.center[0], ys + 0.5 - o.center[1])
        e_lo, e_hi = np.arctan2(0.9 - CAMERA_HEIGHT, 2.0), np.arctan2(1.6 - CAMERA_HEIGHT, 2.0)
        assert abs(r.min() - o.elevation_radius(e_lo)) < 2.5
        assert abs(r.max() - o.elevation_radius(e_hi)) < 4.0


def test_omni_geometry_helpers_roundtrip() -> None:
    o = OmniImage(image=np.zeros((100, 120, 3), dtype=np.uint8), center=(60, 50), radii=(10, 45))
    e = np.linspace(*o.elevation_range, 7)
    np.testing.assert_allclose(o.radius_elevation(o.elevation_radius(e)), e)
    b = np.linspace(-3, 3, 11)
    phi = o.bearing_to_angle(b)
    x, y = o.center[0] + 30 * np.cos(phi), o.center[1] - 30 * np.sin(phi)
    np.testing.assert_allclose(dist_as(b, o.pixel_bearing(x, y)), 0, atol=1e-12)
    assert not o.image.flags.writeable
    with pytest.raises(InvalidParameterError, match="radii"):
        OmniImage(image=np.zeros((10, 10, 3), dtype=np.uint8), center=(5, 5), radii=(6, 3))


def test_omni_determinism_center_and_rims() -> None:
    w = make_offices(1, random_state=7)[0]
    pose = (*w.anchor, 0.1)
    a = render_omni(w, pose, random_state=3)
    b = render_omni(w, pose, random_state=3)
    np.testing.assert_array_equal(a.image, b.image)
    c = render_omni(w, pose, size=(320, 240), center=(150.0, 130.0), radii=(30.0, 100.0), random_state=3)
    assert c.image.shape == (240, 320, 3) and c.center == (150.0, 130.0)
    # Outside the mirror the image is near black; inside the ring it is lit.
    assert a.image[0, 0].mean() < 30 and a.image[240, 320 + 150].mean() > 40


@pytest.mark.parametrize(
    ("fn", "kw", "match"),
    [
        (render_panorama, {"width": 4}, "width"),
        (render_panorama, {"noise": -1.0}, "noise"),
        (render_panorama, {"jpeg_quality": 0}, "jpeg_quality"),
        (render_panorama, {"elevation_deg": (10, -10)}, "elevation_deg"),
        (render_omni, {"radii": (100, 50)}, "radii"),
        (render_omni, {"vignetting": 1.5}, "vignetting"),
        (render_omni, {"blur": -1.0}, "blur"),
    ],
)
def test_camera_bad_parameters(fn: object, kw: dict[str, object], match: str) -> None:
    with pytest.raises(InvalidParameterError, match=match):
        fn(room(), (0, 0, 0), **kw)  # type: ignore[operator]


def test_camera_speed_smoke() -> None:
    w = make_offices(1, random_state=0)[0]
    pose = (*w.anchor, 0.0)
    render_omni(w, pose)
    t0 = time.perf_counter()
    for _ in range(3):
        render_omni(w, pose)
        render_panorama(w, pose)
    assert (time.perf_counter() - t0) / 3 < 2.0  # loose; the <100 ms target is measured by bench speed


# ------------------------------------------------------------------ ground truth
def _close(a: np.ndarray, b: list[float], tol_deg: float = 0.3) -> bool:
    a = np.sort(np.asarray(a))
    if a.size != len(b):
        return False
    bb = np.sort(np.asarray(b, dtype=float))
    return bool(np.all(np.abs(dist_as(a, bb)) < np.deg2rad(tol_deg)))


def test_truth_square_room_corners_and_edges() -> None:
    f = true_features(room(2.0), (0.0, 0.0, 0.0))
    corners = [-3 * np.pi / 4, -np.pi / 4, np.pi / 4, 3 * np.pi / 4]
    assert _close(f["c"], corners)
    assert _close(f["VE"], corners)
    assert f["Ex"].size == 0 and f["B"].size == 0 and f["CP"].size == 0
    # Heading pi/4 turns every bearing by -pi/4.
    g = true_features(room(2.0), (0.0, 0.0, np.pi / 4))
    assert _close(g["c"], [-np.pi, -np.pi / 2, 0.0, np.pi / 2])


def test_truth_single_wall_extremities() -> None:
    w = World(segments=[(3.0, -1.0, 3.0, 1.0)], z_range=[(0.0, 2.5)], material=[0], materials=(WALL,))
    f = true_features(w, (0.0, 0.0, 0.0))
    a = float(np.arctan2(1.0, 3.0))
    assert _close(f["Ex"], [-a, a])
    assert f["c"].size == 0
    # Out of range: nothing from the laser.
    assert true_features(w, (0.0, 0.0, 0.0), max_range=2.5)["Ex"].size == 0


def test_truth_pillar_in_front_of_wall() -> None:
    # A 0.4 m pillar 2 m ahead, turned 45 deg: its near corner faces the robot.
    s = 0.2 * np.sqrt(2)
    p = [(2.0 - s, 0.0), (2.0, -s), (2.0 + s, 0.0), (2.0, s)]
    seg = [(-5.0, 5.0, 5.0, 5.0), (5.0, 5.0, 5.0, -5.0), (5.0, -5.0, -5.0, -5.0), (-5.0, -5.0, -5.0, 5.0)]
    seg += [(*p[i], *p[(i + 1) % 4]) for i in range(4)]
    w = World(segments=seg, z_range=[(0.0, 2.5)] * 8, material=[0] * 8, materials=(WALL,), light_angle=0.5)
    f = true_features(w, (0.0, 0.0, 0.0))
    side = float(np.arctan2(s, 2.0))
    ex_front = f["Ex"][np.abs(f["Ex"]) < 0.5]
    assert _close(ex_front, [-side, side])
    assert np.any(np.abs(f["c"]) < np.deg2rad(0.3))  # the convex corner at bearing 0
    assert np.any(np.abs(f["VE"]) < np.deg2rad(0.5))  # two faces lit differently meet at bearing 0


def test_truth_beacon_and_patch() -> None:
    w = room(2.0, decal_wall=2, piece=(1.95, 2.05), decal=2, z=(0.1, 0.9))  # a beacon strip at bearing +90 deg
    f = true_features(w, (0.0, 0.0, 0.0))
    assert _close(f["B"], [np.pi / 2])
    w2 = room(2.0, decal_wall=1, piece=(1.5, 2.5))  # a red poster at bearing 0
    g = true_features(w2, (0.0, 0.0, 0.0))
    assert _close(g["CP"], [0.0])
    assert g["CP_hue_deg"][0] == pytest.approx(0.0, abs=1.0)
    assert _close(
        g["VE"], [-np.arctan2(0.5, 2), np.arctan2(0.5, 2), -3 * np.pi / 4, -np.pi / 4, np.pi / 4, 3 * np.pi / 4]
    )


def test_truth_in_offices_and_observation() -> None:
    w = make_offices(1, random_state=8)[0]
    pose = (*w.anchor, 0.5)
    f = true_features(w, pose)
    for k in ("c", "Ex", "B", "VE", "CP"):
        assert np.all(f[k] >= -np.pi) and np.all(f[k] < np.pi)
    assert f["c"].size >= 3 and f["VE"].size >= 4
    obs = true_observation(w, pose, label=w.name)
    assert isinstance(obs, Observation) and obs.label == w.name
    np.testing.assert_allclose(obs.ve, f["VE"])


def test_emissive_window_is_bright_whatever_its_orientation() -> None:
    window = Material((0.93, 0.95, 1.0), emission=1.3)
    w = World(
        segments=[(2.0, -1.0, 2.0, 1.0), (-1.0, 2.0, 1.0, 2.0)],
        z_range=[(0.0, 2.5)] * 2,
        material=[0, 0],
        materials=(WALL, window),
        decal_z=[(0.9, 2.2), (0.9, 2.2)],
        decal_material=[1, 1],
        light_angle=2.0,
    )
    pano = render_panorama(w, (0.0, 0.0, 0.0), **CLEAN)
    row = int(pano.image.shape[0] * 0.35)  # elevation about +4 deg: inside both windows
    for b in (0.0, np.pi / 2):
        px = pano.image[row, int(pano.bearing_column(b))]
        assert px.min() > 0.95


def _spread(similarity: float) -> float:
    """Mean absolute difference of room sizes between offices generated together."""
    out = []
    for seed in range(4):
        sizes = np.array([np.ptp(w.room, axis=0) for w in make_offices(6, similarity=similarity, random_state=seed)])
        out.append(np.abs(sizes[:, None] - sizes[None]).mean())
    return float(np.mean(out))


def test_similarity_controls_how_alike_offices_are() -> None:
    assert _spread(1.0) == 0.0
    assert _spread(0.9) < _spread(0.5) < _spread(0.0)
