"""The keypoints of one view: bearings, elevations, scales and descriptors (a value of an :class:`~fingerloc.Observation`).

Extraction and matching are in :mod:`fingerloc.features.keypoints`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ._types import FArray
from .errors import InvalidParameterError

__all__ = ["Keypoints"]


@dataclass(frozen=True, slots=True, eq=False)
class Keypoints:
    """The keypoints of one view.

    Attributes
    ----------
    bearing : ndarray of float, shape (n,)
        Radians, wrapped to ``[-pi, pi)``.
    elevation : ndarray of float, shape (n,)
        Radians, positive above the horizon, in ``[-pi/2, pi/2]``.
    scale : ndarray of float, shape (n,)
        The keypoint's diameter (SIFT's ``size``), degrees.
    desc : ndarray of uint8, shape (n, d)
        Descriptors.
    """

    bearing: FArray
    elevation: FArray
    scale: FArray
    desc: NDArray[np.uint8] = field(repr=False)

    def __post_init__(self) -> None:
        n = None
        for name in ("bearing", "elevation", "scale"):
            a = np.array(getattr(self, name), dtype=np.float64, copy=True).reshape(-1)
            if not np.all(np.isfinite(a)):
                raise InvalidParameterError(f"keypoints: {name} must be finite")
            a.setflags(write=False)
            object.__setattr__(self, name, a)
            if n is not None and a.size != n:
                raise InvalidParameterError("keypoints: bearing, elevation and scale must have one value per keypoint")
            n = a.size
        if np.any(np.abs(self.elevation) > math.pi / 2 + 1e-9):
            raise InvalidParameterError("keypoints: elevations must be radians in [-pi/2, pi/2]")
        d = np.asarray(self.desc)
        if d.ndim != 2 or d.shape[0] != n or (d.size and d.shape[1] < 1):
            raise InvalidParameterError(f"keypoints: desc must have shape ({n}, d), got {d.shape}")
        if d.dtype != np.uint8:
            if d.size and (np.any(d < 0) or np.any(d > 255) or np.any(d != np.round(d))):
                raise InvalidParameterError("keypoints: descriptors must be integers in 0..255")
            d = d.astype(np.uint8)
        d = np.array(d, dtype=np.uint8, copy=True)
        d.setflags(write=False)
        object.__setattr__(self, "desc", d)

    def __len__(self) -> int:
        return int(self.bearing.size)

    @property
    def dim(self) -> int:
        """Length of one descriptor (0 without keypoints)."""
        return int(self.desc.shape[1]) if self.desc.ndim == 2 else 0

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Keypoints):
            return NotImplemented
        return (
            self.desc.shape == other.desc.shape
            and np.array_equal(self.desc, other.desc)
            and np.array_equal(self.bearing, other.bearing)
            and np.array_equal(self.elevation, other.elevation)
            and np.array_equal(self.scale, other.scale)
        )

    __hash__ = None  # type: ignore[assignment]

    def unit_descriptors(self) -> NDArray[np.float32]:
        """RootSIFT descriptors (square roots of the L1-normalised vector: unit L2 norm), float32, shape ``(n, d)``."""
        d = self.desc.astype(np.float32)
        s = d.sum(axis=1, keepdims=True)
        out: NDArray[np.float32] = np.sqrt(d / np.maximum(s, 1.0)).astype(np.float32)
        return out

    def vectors(self) -> FArray:
        """Unit bearing vectors ``(cos e cos b, cos e sin b, sin e)``, shape ``(n, 3)`` (as
        :func:`fingerloc.features.sphere.bearing_vectors`)."""
        ce = np.cos(self.elevation)
        return np.stack([ce * np.cos(self.bearing), ce * np.sin(self.bearing), np.sin(self.elevation)], axis=1)
