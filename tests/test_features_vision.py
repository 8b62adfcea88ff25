"""Vision feature extraction on synthetic panoramas and omnidirectional images with known features."""

from __future__ import annotations

import numpy as np
import pytest

from fingerloc.angles import dist_as
from fingerloc.errors import InvalidParameterError
from fingerloc.features.vision import (
    VisionFeatures,
    colour_patches,
    extract_vision_features,
    observation_from_views,
    rgb_to_hsv,
    unwarp_omni,
    vertical_edges,
)
from fingerloc.fingerprint import hue_letter
from fingerloc.sensors import Panorama

from .features_world import DOOR, make_donut, make_scan, paint_panorama


def match(found, expected, tol):
    """Greedy one-to-one matches within ``tol`` radians: (true positives, misses, extras)."""
    found = list(np.asarray(found))
    tp = 0
    for e in np.asarray(expected):
        if not found:
            break
        d = np.abs(dist_as(np.asarray(found), e))
        k = int(np.argmin(d))
        if d[k] <= tol:
            tp += 1
            found.pop(k)
    return tp, len(expected) - tp, len(found)


CASES = {
    "clean": dict(shading=False, sun=False, noise=0.0),
    "shaded-sun-noise": dict(),
    "jpeg70": dict(jpeg=70),
    "jpeg35-noisy": dict(jpeg=35, noise=0.03, seed=2),
}


@pytest.mark.parametrize("case", list(CASES))
def test_vertical_edges_on_painted_panorama(case):
    img, edge_cols, _, _ = paint_panorama(**CASES[case])
    pano = Panorama(img.astype(np.float32), bearing_offset=0.3)
    found = vertical_edges(pano)
    _tp, miss, extra = match(found, pano.column_bearing(edge_cols), np.deg2rad(1.0))
    assert miss == 0 and extra == 0, (np.sort(pano.bearing_column(found)), np.sort(edge_cols))


@pytest.mark.parametrize("case", list(CASES))
def test_colour_patches_on_painted_panorama(case):
    img, _, centres, hues = paint_panorama(**CASES[case])
    pano = Panorama(img.astype(np.float32))
    b, h = colour_patches(pano)
    assert b.size == centres.size
    exp_b = pano.column_bearing(centres)
    for bb, hh in zip(b, h, strict=True):
        k = int(np.argmin(np.abs(dist_as(exp_b, bb))))
        assert abs(float(dist_as(exp_b[k], bb))) < np.deg2rad(1.0)
        assert abs((hh - hues[k] + 180) % 360 - 180) < 8.0
        assert hue_letter(hh) == hue_letter(hues[k])


def test_low_saturation_walls_and_dark_pixels_give_no_patch():
    rng = np.random.default_rng(0)
    img = np.empty((100, 360, 3))
    img[:] = [0.82, 0.75, 0.64]  # beige paint, saturation 0.22
    img[:, 100:200] = [0.70, 0.74, 0.80]  # a bluish-grey wall, saturation 0.125
    img[:, 250:300] = [0.06, 0.02, 0.03]  # nearly black: saturated but hue is noise
    img = np.clip(img + rng.normal(0, 0.01, img.shape), 0, 1)
    b, h = colour_patches(Panorama(img.astype(np.float32)))
    assert b.size == 0 and h.size == 0


def test_patch_across_the_seam_is_one_patch():
    img, _, _, _ = paint_panorama(patches=((700, 740, 0.0),), sun=False, shading=False, door=None)
    # paint_panorama clips at the image border: paint the wrapped part too
    img[40:104, 0:20] = img[40:104, 705:706]
    b, _h = colour_patches(Panorama(img.astype(np.float32)))
    assert b.size == 1
    pano = Panorama(img.astype(np.float32))
    assert abs(float(dist_as(pano.column_bearing(720.0), b[0]))) < np.deg2rad(1.0)


def test_bearing_convention_and_rotation():
    img, _edge_cols, _, _ = paint_panorama(shading=False, sun=False, noise=0.0)
    e0 = vertical_edges(Panorama(img.astype(np.float32), bearing_offset=0.0))
    e1 = vertical_edges(Panorama(np.roll(img, 90, axis=1).astype(np.float32), bearing_offset=0.0))
    # rolling the image right by 90 columns (45 deg) on a clockwise panorama turns every bearing by -45 deg
    _tp, miss, extra = match(e1, e0 - np.deg2rad(45.0), np.deg2rad(0.6))
    assert miss == 0 and extra == 0


def test_rgb_to_hsv_matches_colorsys():
    import colorsys

    rng = np.random.default_rng(1)
    px = rng.uniform(0, 1, (200, 3))
    h, s, v = rgb_to_hsv(px)
    for k in range(200):
        hh, ss, vv = colorsys.rgb_to_hsv(*px[k])
        assert abs(((h[k] - hh * 360) + 180) % 360 - 180) < 1e-9
        assert abs(s[k] - ss) < 1e-12 and abs(v[k] - vv) < 1e-12


@pytest.mark.parametrize("mirror", [False, True])
def test_unwarp_recovers_the_panorama(mirror):
    img, _edge_cols, _centres, _hues = paint_panorama(w=720, h=90, shading=False, sun=False, noise=0.0)
    donut, center = make_donut(img, size=600, r_in=60.0, r_out=290.0, bearing_offset=0.7, mirror=mirror)
    pano = unwarp_omni(
        (donut * 255).astype(np.uint8), center, 60.0, 290.0, width=720, height=90, bearing_offset=0.7, mirror=mirror
    )
    assert pano.image.shape == (90, 720, 3)
    # pixel agreement away from the edges (interpolation blurs them)
    diff = np.abs(pano.image - img.astype(np.float32)).mean(axis=2)
    assert np.median(diff) < 0.01
    # the features come back at the same bearings
    ref = Panorama(img.astype(np.float32), bearing_offset=0.7)
    _tp, miss, extra = match(vertical_edges(pano), vertical_edges(ref), np.deg2rad(1.0))
    assert miss == 0 and extra == 0
    b, _h = colour_patches(pano)
    rb, _rh = colour_patches(ref)
    assert b.size == rb.size == 3
    assert np.all(np.abs(dist_as(np.sort(b), np.sort(rb))) < np.deg2rad(1.0))


def test_unwarp_validates_geometry():
    img = np.zeros((100, 100, 3), dtype=np.uint8)
    with pytest.raises(InvalidParameterError, match="r_in"):
        unwarp_omni(img, (50, 50), 40, 30)
    with pytest.raises(InvalidParameterError, match="outside"):
        unwarp_omni(img, (500, 50), 10, 30)
    with pytest.raises(InvalidParameterError, match="width"):
        unwarp_omni(img, (50, 50), 10, 30, width=3)
    pano = unwarp_omni(img[:, :, 0], (50, 50), 10, 30)  # grey images are fine
    assert pano.image.shape == (20, 360, 3)


def test_extract_and_observation_from_views():
    img, edge_cols, _centres, _hues = paint_panorama()
    pano = Panorama(img.astype(np.float32), meta={"pose": (1.0, 2.0, 0.5)})
    vf = extract_vision_features(pano)
    assert isinstance(vf, VisionFeatures)
    assert vf.edges.size == edge_cols.size and vf.patches.size == 3
    obs = observation_from_views(panorama=pano, label="office")
    assert obs.full_fov and obs.label == "office" and obs.pose == (1.0, 2.0, 0.5)
    assert obs.ve.size == vf.edges.size and obs.cp.size == 3 and obs.c.size == 0
    scan = make_scan(DOOR, n=361, fov_deg=180.0)
    both = observation_from_views(scan=scan, panorama=pano, range_sigma=0.01, min_support=0.3)
    assert both.full_fov and both.c.size == 2 and both.ex.size == 2 and both.ve.size == vf.edges.size
    laser_only = observation_from_views(scan=scan)
    assert laser_only.fov == scan.fov and laser_only.ve.size == 0
    with pytest.raises(InvalidParameterError, match="needs a scan"):
        observation_from_views()
    with pytest.raises(InvalidParameterError, match="bogus"):
        observation_from_views(panorama=pano, bogus=1)
    with pytest.raises(InvalidParameterError, match="min_support"):
        vertical_edges(pano, min_support=2.0)


def test_colour_cast_is_white_balanced():
    # a warm colour cast makes the beige walls look saturated; the patches must still come out alone
    img, _, centres, hues = paint_panorama(seed=4)
    cast = np.clip(img * np.array([1.0, 0.78, 0.62]), 0, 1)
    pano = Panorama(cast.astype(np.float32))
    b, h = colour_patches(pano)
    assert b.size == centres.size
    assert np.all(np.abs(dist_as(np.sort(b), np.sort(pano.column_bearing(centres)))) < np.deg2rad(1.0))
    # hue letters survive the cast for these clearly separated hues
    order = np.argsort(pano.column_bearing(centres))
    exp = np.asarray(hues)[order]
    got = h[np.argsort(b)]
    assert np.all(np.abs((got - exp + 180) % 360 - 180) < 15)


def test_textures_give_no_false_edges():
    # a speckled carpet and a wood-grain panel (horizontal streaks): only the panel's two sides are edges
    from scipy import ndimage

    rng = np.random.default_rng(0)
    img, edge_cols, _, _ = paint_panorama(seed=3)
    h, w, _ = img.shape
    floor = int(0.8 * h)
    tex = ndimage.gaussian_filter(rng.normal(0, 1, (h - floor, w)), 0.8)
    img[floor:] *= (1 + 0.25 * tex / tex.std())[:, :, None]
    grain = ndimage.gaussian_filter1d(rng.normal(0, 1, h), 1.0)[int(0.2 * h) : int(0.8 * h)]
    img[int(0.2 * h) : int(0.8 * h), 160:240] = np.array([0.55, 0.40, 0.25]) * (1 + 0.15 * grain[:, None, None])
    pano = Panorama(np.clip(img, 0, 1).astype(np.float32))
    _, miss, extra = match(vertical_edges(pano), pano.column_bearing(np.r_[edge_cols, 160, 240]), np.deg2rad(1.0))
    assert miss == 0 and extra == 0
