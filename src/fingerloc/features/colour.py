"""Colour helpers shared by the camera features: HSV and a robust white balance."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .._types import FArray

__all__ = ["rgb_to_hsv", "white_balance"]


def rgb_to_hsv(img: ArrayLike) -> tuple[FArray, FArray, FArray]:
    """HSV of an RGB image in ``[0, 1]``: hue in degrees ``[0, 360)``, saturation and value in ``[0, 1]``.

    Parameters
    ----------
    img : array_like, shape (..., 3)

    Returns
    -------
    hue, sat, val : ndarray, shape (...)
    """
    a = np.asarray(img, dtype=np.float64)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    mx = np.maximum(np.maximum(r, g), b)  # faster than a reduction over a length-3 axis
    mn = np.minimum(np.minimum(r, g), b)
    c = mx - mn
    safe = np.where(c > 0, c, 1.0)
    h = np.where(
        mx == r,
        np.mod((g - b) / safe, 6.0),
        np.where(mx == g, (b - r) / safe + 2.0, (r - g) / safe + 4.0),
    )
    h = np.where(c > 0, h * 60.0, 0.0)
    h = np.where(h >= 360.0, h - 360.0, h)
    s = np.where(mx > 0, c / np.where(mx > 0, mx, 1.0), 0.0)
    return h, s, mx


def white_balance(img: FArray, mode: str = "bright") -> FArray:
    """Robust white balance: scale the channels so that a presumably grey reference becomes grey.

    ``mode="bright"``: the reference is the median colour of the brightest
    unclipped, duller-than-median pixels (white ceilings and paint show the
    illuminant best); ``"grey"``: of all duller-than-median pixels (grey world).
    """
    v = np.maximum(np.maximum(img[..., 0], img[..., 1]), img[..., 2])
    s = (v - np.minimum(np.minimum(img[..., 0], img[..., 1]), img[..., 2])) / np.maximum(v, 1e-12)
    dull = (s <= np.median(s)) & (v > 0.1) & (v < 0.98)
    if np.count_nonzero(dull) < 100:
        return img
    if mode == "bright":
        dull &= v >= np.quantile(v[dull], 0.8)
    med = np.median(img[dull], axis=0)
    if np.any(med <= 1e-3):
        return img
    gain = med.mean() / med
    return np.clip(img * gain, 0.0, 1.0)
