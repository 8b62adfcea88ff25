"""Measurement poses of the paper's robot protocol (docs/METHOD.md §5, Tables II-IV).

Per office: ``n_train`` training poses on a circle of radius drawn in
``radius`` (metres) around the office's anchor, evenly spread over the circle
with a random phase and a little jitter, and ``n_test`` test poses inside that
circle; all with the same heading. Poses too close to an obstacle are moved
towards the anchor until they are free.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..errors import InvalidParameterError
from ..validation import check_random_state
from .world import World

__all__ = ["protocol_poses"]


def protocol_poses(
    world: World,
    *,
    n_train: int = 8,
    n_test: int = 2,
    radius: tuple[float, float] = (0.4, 0.7),
    heading: float = 0.0,
    min_clearance: float = 0.3,
    random_state: int | np.random.Generator | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Training and test poses for one office.

    Parameters
    ----------
    world : World
    n_train, n_test : int
        Number of training poses (on the circle) and test poses (inside it).
    radius : (low, high)
        Range of the circle's radius, metres; drawn once per office.
    heading : float
        Heading of every pose, radians.
    min_clearance : float
        Smallest distance (metres) from a pose to any segment.
    random_state : int or numpy.random.Generator, optional

    Returns
    -------
    train : ndarray, shape (n_train, 3)
    test : ndarray, shape (n_test, 3)
        Poses ``(x, y, theta)`` in metres and radians.
    """
    if n_train < 0 or n_test < 0:
        raise InvalidParameterError(f"n_train and n_test must be >= 0, got {n_train!r} and {n_test!r}")
    lo, hi = (float(v) for v in radius)
    if not (0 <= lo <= hi):
        raise InvalidParameterError(f"radius must be (low, high) with 0 <= low <= high, got {radius!r}")
    rng = check_random_state(random_state)
    ax, ay = world.anchor
    r = rng.uniform(lo, hi)
    phase = rng.uniform(0, 2 * np.pi)
    ang_train = phase + 2 * np.pi * np.arange(n_train) / max(n_train, 1) + rng.normal(0, 0.1, n_train)
    rad_train = np.full(n_train, r)
    ang_test = rng.uniform(0, 2 * np.pi, n_test)
    rad_test = r * np.sqrt(rng.uniform(0.0, 0.8, n_test))

    def place(ang: NDArray[np.float64], rad: NDArray[np.float64]) -> NDArray[np.float64]:
        out = np.empty((ang.size, 3))
        for i, (a, d) in enumerate(zip(ang, rad, strict=True)):
            for scale in np.linspace(1.0, 0.0, 11):
                p = np.array([ax + scale * d * np.cos(a), ay + scale * d * np.sin(a)])
                if world.contains(p) and world.clearance(p) >= min_clearance:
                    break
            out[i] = (p[0], p[1], heading)
        return out

    return place(ang_train, rad_train), place(ang_test, rad_test)
