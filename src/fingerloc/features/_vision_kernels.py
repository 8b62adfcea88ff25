"""The vertical-edge detector's per-pixel work and HSV, compiled (private; :mod:`fingerloc.features.vision`).

:func:`edge_columns` does, in one pass over a smoothed panorama, what
:func:`fingerloc.features.vision._edge_support` did with whole-array NumPy
operations: column gradients of log luminance and chromaticity, their
projection on each column's mean direction, each row's robust noise
threshold, the row-wise maxima, the suppression beside a stronger gradient,
the slant tolerance, the closing of short gaps along the elevation and the
longest vertical run. Sums are taken in NumPy's order; products of three
terms may differ in the last bit, which changes an edge pixel only where its
gradient lies within that bit of a threshold (``tests/test_vision_kernels.py``
compares the two on photographs and random images).

:func:`hsv` is :func:`fingerloc.features.colour.rgb_to_hsv`'s formula, one
pixel at a time (the same operations: the same numbers).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._types import FArray

__all__ = ["edge_columns", "edge_inputs", "hsv"]


@njit(cache=True, nogil=True)
def edge_inputs(img: FArray) -> tuple[FArray, FArray]:  # pragma: no cover - compiled
    """Log luminance ``log(0.299 r + 0.587 g + 0.114 b + 0.02)`` and chromaticities ``(r, g) / (r + g + b + 0.06)``.

    ``img``: ``(h, w, 3)`` RGB in ``[0, 1]`` (any float type; computed in float64).
    Returns arrays of shape ``(h, w)`` and ``(h, w, 2)``.
    """
    h, w = img.shape[0], img.shape[1]
    loglum = np.empty((h, w))
    chrom = np.empty((h, w, 2))
    for i in range(h):
        for j in range(w):
            r = np.float64(img[i, j, 0])
            g = np.float64(img[i, j, 1])
            b = np.float64(img[i, j, 2])
            loglum[i, j] = math.log(r * 0.299 + g * 0.587 + b * 0.114 + 0.02)
            tot = r + g + b + 0.06
            chrom[i, j, 0] = r / tot
            chrom[i, j, 1] = g / tot
    return loglum, chrom


@njit(cache=True, nogil=True)
def edge_columns(  # pragma: no cover - compiled
    loglum: FArray,
    chrom: FArray,
    gl: float,
    gc: float,
    chroma_weight: float,
    min_contrast: float,
    noise_k: float,
    relative_min: float,
    near: int,
    slant: int,
    gap: int,
) -> tuple[FArray, FArray, FArray]:
    """Support, longest run and strength of each column boundary.

    Parameters
    ----------
    loglum : ndarray of float64, shape (h, w)
        Smoothed log luminance.
    chrom : ndarray of float64, shape (h, w, 2)
        Smoothed red and green chromaticities.
    gl, gc : float
        Gains that restore a step's height after the smoothing (luminance, chromaticity).
    chroma_weight, min_contrast, noise_k, relative_min : float
        As :class:`fingerloc.features.vision.EdgeParams`.
    near, slant, gap : int
        Reach (columns) of the stronger-neighbour test, of the slant
        tolerance, and (rows) of the gaps bridged along the elevation.

    Returns
    -------
    support, extent, strength : ndarray of float64, shape (w,)
        Share of the rows with an edge pixel, longest run of edge pixels
        (part of the rows), sum of the edge pixels' gradients over the rows.
    """
    h, w = loglum.shape
    gvec = np.empty((h, w, 3))
    mean_dir = np.zeros((w, 3))
    for i in range(h):
        for j in range(w):
            jn = j + 1 if j + 1 < w else 0
            gvec[i, j, 0] = gl * (loglum[i, jn] - loglum[i, j])
            gvec[i, j, 1] = chroma_weight * (gc * (chrom[i, jn, 0] - chrom[i, j, 0]))
            gvec[i, j, 2] = chroma_weight * (gc * (chrom[i, jn, 1] - chrom[i, j, 1]))
            mean_dir[j, 0] += gvec[i, j, 0]
            mean_dir[j, 1] += gvec[i, j, 1]
            mean_dir[j, 2] += gvec[i, j, 2]
    for j in range(w):
        nrm = max(
            math.sqrt(
                mean_dir[j, 0] * mean_dir[j, 0] + mean_dir[j, 1] * mean_dir[j, 1] + mean_dir[j, 2] * mean_dir[j, 2]
            ),
            1e-12,
        )
        mean_dir[j, 0] /= nrm
        mean_dir[j, 1] /= nrm
        mean_dir[j, 2] /= nrm
    g = np.empty((h, w))
    peak = np.zeros((h, w), dtype=np.bool_)
    mag = np.empty(w)
    dev = np.empty(w)
    for i in range(h):
        for j in range(w):
            a, b, c = gvec[i, j, 0], gvec[i, j, 1], gvec[i, j, 2]
            g[i, j] = max(a * mean_dir[j, 0] + b * mean_dir[j, 1] + c * mean_dir[j, 2], 0.0)
            mag[j] = math.sqrt(a * a + b * b + c * c)
        med = np.median(mag)
        for j in range(w):
            dev[j] = abs(mag[j] - med)
        thr = max(min_contrast, med + noise_k * (1.4826 * np.median(dev)))
        row = g[i]
        for j in range(w):
            v = row[j]
            if not (v > thr and v >= row[j - 1 if j > 0 else w - 1] and v >= row[j + 1 if j + 1 < w else 0]):
                continue
            top = v
            for k in range(j - near, j + near + 1):
                x = row[k % w]
                if x > top:
                    top = x
            if v >= relative_min * top:
                for k in range(j - slant, j + slant + 1):
                    peak[i, k % w] = True
    support = np.zeros(w)
    extent = np.zeros(w)
    strength = np.zeros(w)
    dil = np.empty(h, dtype=np.bool_)
    for j in range(w):
        count = 0
        for i in range(h):
            if peak[i, j]:
                count += 1
                strength[j] += g[i, j]
        support[j] = count / h
        # closing along the elevation (outside the image counts as no edge), then the original pixels added
        for i in range(h):
            hit = False
            for m in range(max(0, i - gap), min(h, i + gap + 1)):
                if peak[m, j]:
                    hit = True
                    break
            dil[i] = hit
        run = 0.0
        best = 0.0
        for i in range(h):
            on = peak[i, j]
            if not on and i - gap >= 0 and i + gap < h:
                on = True
                for m in range(i - gap, i + gap + 1):
                    if not dil[m]:
                        on = False
                        break
            run = run + 1.0 if on else 0.0
            if run > best:
                best = run
        extent[j] = best / h
        strength[j] /= max(h, 1)
    return support, extent, strength


@njit(cache=True, nogil=True)
def hsv(img: FArray) -> tuple[FArray, FArray, FArray]:  # pragma: no cover - compiled
    """Hue (degrees), saturation and value of an ``(n, 3)`` float64 RGB array in ``[0, 1]``."""
    n = img.shape[0]
    hue = np.empty(n)
    sat = np.empty(n)
    val = np.empty(n)
    for k in range(n):
        r, g, b = img[k, 0], img[k, 1], img[k, 2]
        mx = max(max(r, g), b)
        mn = min(min(r, g), b)
        c = mx - mn
        if c > 0:
            if mx == r:
                x = np.mod((g - b) / c, 6.0)
            elif mx == g:
                x = (b - r) / c + 2.0
            else:
                x = (r - g) / c + 4.0
            x = x * 60.0
            if x >= 360.0:
                x = x - 360.0
        else:
            x = 0.0
        hue[k] = x
        sat[k] = c / mx if mx > 0 else 0.0
        val[k] = mx
    return hue, sat, val
