"""The compiled vertical-edge and HSV kernels against whole-array NumPy versions of the same steps."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from fingerloc.errors import InvalidParameterError
from fingerloc.features import vision
from fingerloc.features._vision_kernels import hsv
from fingerloc.features.colour import rgb_to_hsv
from fingerloc.features.vision import PHOTO_EDGE_PARAMS, EdgeParams, vertical_edges
from fingerloc.sensors import Panorama

from ._panoramas import render_room, wall_textures
from .features_world import paint_panorama


def _smooth_cols(a, sigma):
    return ndimage.gaussian_filter1d(a, sigma, axis=1, mode="wrap"), 1.0 / math.erf(0.5 / (np.sqrt(2.0) * sigma))


def edge_support_numpy(pano: Panorama, p: EdgeParams) -> tuple[np.ndarray, np.ndarray]:
    """The vertical-edge score and strength with whole-array NumPy operations (independent oracle)."""
    img = pano.image.astype(np.float64)
    h, w, _ = img.shape
    lum = img @ np.array([0.299, 0.587, 0.114])
    loglum = np.log(lum + 0.02)
    chrom = img[:, :, :2] / (img.sum(axis=2) + 0.06)[:, :, None]
    sigma = p.smooth_px * max(w / 720.0, 0.5)
    loglum, gl = _smooth_cols(loglum, sigma)
    chrom, gc = _smooth_cols(chrom, 2.0 * sigma)
    if p.vertical_smooth > 0:
        sv = p.vertical_smooth * h
        loglum = ndimage.gaussian_filter1d(loglum, sv, axis=0, mode="nearest")
        chrom = ndimage.gaussian_filter1d(chrom, sv, axis=0, mode="nearest")
    dl = gl * (np.roll(loglum, -1, axis=1) - loglum)
    dc = gc * (np.roll(chrom, -1, axis=1) - chrom)
    gvec = np.concatenate([dl[:, :, None], p.chroma_weight * dc], axis=2)
    mean_dir = gvec.sum(axis=0)
    mean_dir /= np.maximum(np.linalg.norm(mean_dir, axis=1, keepdims=True), 1e-12)
    g = np.maximum(np.einsum("hwc,wc->hw", gvec, mean_dir), 0.0)
    mag = np.linalg.norm(gvec, axis=2)
    med = np.median(mag, axis=1, keepdims=True)
    mad = 1.4826 * np.median(np.abs(mag - med), axis=1, keepdims=True)
    thr = np.maximum(p.min_contrast, med + p.noise_k * mad)
    peak = (g >= np.roll(g, 1, axis=1)) & (g >= np.roll(g, -1, axis=1)) & (g > thr)
    near = max(2, round(p.relative_deg / 360.0 * w))
    peak &= g >= p.relative_min * ndimage.maximum_filter1d(g, 2 * near + 1, axis=1, mode="wrap")
    slant = max(1, round(p.slant_deg / 360.0 * w))
    peak = ndimage.maximum_filter1d(peak, 2 * slant + 1, axis=1, mode="wrap")
    support = peak.mean(axis=0)
    gap = max(1, round(0.01 * h))
    filled = ndimage.binary_closing(peak, structure=np.ones((2 * gap + 1, 1), dtype=bool), border_value=0) | peak
    run = np.zeros(w)
    best = np.zeros(w)
    for row in filled:
        run = (run + 1.0) * row
        np.maximum(best, run, out=best)
    strength = np.where(peak, g, 0.0).sum(axis=0) / h
    return np.maximum(best / h / p.min_extent, support / p.min_support), strength


def _panoramas() -> list[tuple[str, Panorama]]:
    out = []
    for k, case in enumerate(
        ({"shading": False, "sun": False, "noise": 0.0}, {}, {"jpeg": 35, "noise": 0.03, "seed": 2})
    ):
        img, _, _, _ = paint_panorama(**case)
        out.append((f"painted{k}", Panorama(img.astype(np.float32))))
    tex = wall_textures(3)
    out.append(("room", render_room(tex, (2.0, 1.5, 1.2), 30.0, width=720)))
    rng = np.random.default_rng(5)
    noise = ndimage.gaussian_filter(rng.random((90, 360, 3)), (0.0, 2.0, 0.0), mode="wrap")
    out.append(("noise", Panorama(np.clip(noise, 0, 1).astype(np.float32))))
    return out


@pytest.mark.parametrize("name,pano", _panoramas())
@pytest.mark.parametrize("params", [{}, PHOTO_EDGE_PARAMS, {"relative_min": 0.0, "slant_deg": 0.0, "noise_k": 1.0}])
def test_compiled_edge_support_matches_numpy(name, pano, params):
    p = EdgeParams(**params)
    score, strength = vision._edge_support(pano, p)
    ref_score, ref_strength = edge_support_numpy(pano, p)
    # last-bit differences (the smoothing's order of sums) change no decision: the scores agree exactly
    # up to rounding (a pixel more or less would move a score by 1 / (h min_support) > 0.01)
    np.testing.assert_allclose(score, ref_score, rtol=0, atol=1e-9)
    np.testing.assert_allclose(strength, ref_strength, rtol=1e-9, atol=1e-12)
    assert np.count_nonzero(ref_score >= 1.0) > 0 or name == "noise"


@pytest.mark.parametrize("name,pano", _panoramas())
def test_vertical_edges_same_as_with_numpy_support(name, pano, monkeypatch):
    found = vertical_edges(pano, **PHOTO_EDGE_PARAMS)
    monkeypatch.setattr(vision, "_edge_support", edge_support_numpy)
    ref = vertical_edges(pano, **PHOTO_EDGE_PARAMS)
    assert found.size == ref.size and (ref.size > 0 or name == "noise")
    np.testing.assert_allclose(found, ref, rtol=0, atol=1e-9)


def hsv_numpy(a):
    """HSV with whole-array NumPy operations (independent oracle)."""
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    mx = np.maximum(np.maximum(r, g), b)
    mn = np.minimum(np.minimum(r, g), b)
    c = mx - mn
    safe = np.where(c > 0, c, 1.0)
    h = np.where(mx == r, np.mod((g - b) / safe, 6.0), np.where(mx == g, (b - r) / safe + 2.0, (r - g) / safe + 4.0))
    h = np.where(c > 0, h * 60.0, 0.0)
    h = np.where(h >= 360.0, h - 360.0, h)
    s = np.where(mx > 0, c / np.where(mx > 0, mx, 1.0), 0.0)
    return h, s, mx


def test_compiled_hsv_matches_numpy_exactly():
    rng = np.random.default_rng(0)
    img = rng.random((4000, 3))
    img[:500] = np.round(img[:500] * 4) / 4  # ties between channels, greys, black and white
    img[500:510] = 0.0
    img[510:520] = 1.0
    img[520:530] = [1e-300, 0.0, 5e-301]  # tiny values
    for got, want in zip(hsv(img), hsv_numpy(img), strict=True):
        assert np.array_equal(got, want)
    for got, want in zip(rgb_to_hsv(img.reshape(40, 100, 3)), hsv_numpy(img.reshape(40, 100, 3)), strict=True):
        assert got.shape == (40, 100) and np.array_equal(got, want)


def test_rgb_to_hsv_refuses_non_triples():
    with pytest.raises(InvalidParameterError):
        rgb_to_hsv(np.zeros((4, 6)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_closing_is_scipys_binary_closing(seed):
    rng = np.random.default_rng(seed)
    m = rng.random((60, 90)) < (0.3 + 0.2 * seed)
    m[:, :3] = True  # runs touching the border: the empty outside erodes them
    m[0] = True
    want = ndimage.binary_closing(m, structure=np.ones((3, 3)))
    got = vision._close3(m)
    assert got.dtype == bool and np.array_equal(got, want) and want.sum() > m.sum() // 2


@pytest.mark.parametrize("shape", [(360, 1440), (512, 2048), (90, 720), (101, 1500), (40, 2900), (20, 2900)])
def test_appearance_and_profile_together_are_the_separate_calls(shape):
    from fingerloc.features.appearance import appearance_and_profile, appearance_descriptor, column_profile

    rng = np.random.default_rng(shape[1])
    img = ndimage.gaussian_filter(rng.random((*shape, 3)), (2.0, 3.0, 0.0), mode="wrap")
    pano = Panorama(np.clip(img, 0, 1).astype(np.float32), bearing_offset=0.4, clockwise=True)
    desc, prof = appearance_and_profile(pano, columns=36, strips=4)
    assert np.array_equal(desc, appearance_descriptor(pano))
    assert np.array_equal(prof, column_profile(pano, columns=36, strips=4))
    assert prof.shape == (36, 20) and np.abs(prof).max() > 0.5
