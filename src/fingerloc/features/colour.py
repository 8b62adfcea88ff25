"""Colour helpers shared by the camera features: HSV and a robust white balance."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .._types import FArray
from ..errors import InvalidParameterError
from ._vision_kernels import hsv

__all__ = ["rgb_to_hsv", "white_balance"]


def rgb_to_hsv(img: ArrayLike) -> tuple[FArray, FArray, FArray]:
    """HSV of an RGB image in ``[0, 1]``: hue in degrees ``[0, 360)``, saturation and value in ``[0, 1]``.

    Parameters
    ----------
    img : array_like, shape (..., 3)

    Returns
    -------
    hue, sat, val : ndarray, shape (...)

    Notes
    -----
    Per pixel, with ``mx``, ``mn`` the largest and smallest channel and ``c = mx - mn``: hue
    ``60 ((g - b) / c mod 6)`` where ``mx == r``, ``60 ((b - r) / c + 2)`` where ``mx == g``,
    ``60 ((r - g) / c + 4)`` otherwise (0 for greys); saturation ``c / mx`` (0 for black);
    value ``mx`` (compiled).
    """
    a = np.asarray(img, dtype=np.float64)
    if a.shape[-1:] != (3,):
        raise InvalidParameterError(f"expected an array of RGB triples, shape (..., 3), got shape {a.shape}")
    h, s, v = hsv(np.ascontiguousarray(a.reshape(-1, 3)))
    return h.reshape(a.shape[:-1]), s.reshape(a.shape[:-1]), v.reshape(a.shape[:-1])


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
    out = img * gain
    return np.clip(out, 0.0, 1.0, out=out)
