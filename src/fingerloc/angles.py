"""Angles on the circle: one wrapping function and the signed angular distance.

Radians inside fingerloc, wrapped to ``[-pi, pi)``; degrees only in files, on
screen and in parameters named ``*_deg``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["TWO_PI", "deg_to_rad", "dist_as", "fov_pieces_deg", "rad_to_deg360", "wrap", "wrap_deg360"]

TWO_PI = 2.0 * np.pi


def wrap(x: ArrayLike) -> NDArray[np.float64]:
    """Wrap angles (radians) to ``[-pi, pi)``.

    ``np.mod`` can round a tiny negative input up to exactly ``2 pi``; such
    values are folded back so the result is always strictly below ``pi``.

    Parameters
    ----------
    x : array_like of float
        Angles in radians, any shape.

    Returns
    -------
    ndarray of float64, same shape as ``x``
        Angles in ``[-pi, pi)``.
    """
    a = np.asarray(x, dtype=np.float64)
    y = np.mod(a + np.pi, TWO_PI) - np.pi
    # np.mod(-1e-17, 2pi) == 2pi in floating point: fold that edge back.
    return np.where(y >= np.pi, y - TWO_PI, y)


def dist_as(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """Signed shortest way from angle ``a`` to angle ``b`` (docs/METHOD.md §3, distAS).

    Parameters
    ----------
    a, b : array_like of float
        Angles in radians; broadcast against each other.

    Returns
    -------
    ndarray of float64
        ``b - a`` reduced to ``(-pi, pi]``, in radians.
    """
    d = wrap(np.asarray(b, dtype=np.float64) - np.asarray(a, dtype=np.float64))
    # wrap gives [-pi, pi); distAS is defined on (-pi, pi].
    return np.where(d <= -np.pi, d + TWO_PI, d)


def wrap_deg360(x: ArrayLike, *, snap_deg: float = 1e-9) -> NDArray[np.float64]:
    """Wrap angles in degrees to ``[0, 360)``.

    Values within ``snap_deg`` of 360 (round-off of a bearing at 0) become 0.
    """
    y = np.mod(np.asarray(x, dtype=np.float64), 360.0)
    return np.where(y >= 360.0 - snap_deg, 0.0, y)


def deg_to_rad(x: ArrayLike) -> NDArray[np.float64]:
    """Degrees to radians wrapped to ``[-pi, pi)``."""
    return wrap(np.deg2rad(np.asarray(x, dtype=np.float64)))


def rad_to_deg360(x: ArrayLike) -> NDArray[np.float64]:
    """Radians to degrees in ``[0, 360)``."""
    return wrap_deg360(np.rad2deg(np.asarray(x, dtype=np.float64)))


def fov_pieces_deg(fov: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """Disjoint, sorted ``[lo, hi)`` pieces of ``[0, 360)`` covered by ``fov`` (radians)."""
    pieces: list[tuple[float, float]] = []
    for start, width in fov:
        s = float(rad_to_deg360(start))
        w = float(np.rad2deg(width))
        if w >= 360.0 - 1e-9:
            return [(0.0, 360.0)]
        e = s + w
        if e <= 360.0:
            pieces.append((s, e))
        else:
            pieces.append((s, 360.0))
            pieces.append((0.0, e - 360.0))
    pieces.sort()
    merged: list[tuple[float, float]] = []
    for lo, hi in pieces:
        if merged and lo <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], hi))
        else:
            merged.append((lo, hi))
    return merged
