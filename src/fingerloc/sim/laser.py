"""A 360 deg laser range finder: two 180 deg heads back to back, ray-cast against a :class:`World`.

Head 1 looks forward and covers bearings ``[-90, 90)`` deg, head 2 looks back
and covers ``[90, 270)``; both sit at the robot's origin at ``height`` metres, so
their beams merge into one :class:`~fingerloc.sensors.Scan` of ``n_beams``
evenly spaced bearings ``-pi + (i + 1/2) 2 pi / n``.

Intensity (remission, normalised so matt white paint at 1 m and normal
incidence gives about 0.6) of a diffuse surface with reflectivity ``rho`` seen
at range ``r`` and incidence ``a``::

    I = rho * (cos(a) + gloss * cos(a)**40) / (1 + 0.05 r)

A retro-reflective beacon returns ``I = rho * (0.8 + 0.2 cos a) / (1 + 0.02 r)``
whatever the incidence (``rho`` 1.5: about 1.2-1.5, twice the brightest wall).
Each beam gets multiplicative noise of ``intensity_noise`` and an additive
floor of ``0.1 intensity_noise |N(0, 1)|``.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidParameterError
from ..sensors import Scan
from ..validation import check_random_state
from .world import World, cast_rays

__all__ = ["LASER_HEIGHT", "simulate_scan"]

#: Height of the laser plane above the floor, metres.
LASER_HEIGHT = 0.3


def scan_bearings(n_beams: int) -> np.ndarray:
    """Bearings (radians, robot frame, increasing) of an ``n_beams`` 360 deg scan."""
    return -np.pi + (np.arange(n_beams) + 0.5) * (2 * np.pi / n_beams)


def beam_intensity(
    world: World,
    origin: tuple[float, float],
    angles: np.ndarray,
    dist: np.ndarray,
    seg: np.ndarray,
    *,
    height: float = LASER_HEIGHT,
) -> np.ndarray:
    """Noise-free intensity of beams (world-frame ``angles``) that hit ``seg`` at ``dist``; 0 for misses."""
    hit = seg >= 0
    out = np.zeros(dist.shape)
    if not hit.any():
        return out
    s = seg[hit]
    _, refl, beacon, _, gloss = world.material_table()
    m = world.surface_material(s, height)
    e = world.segments[s, 2:] - world.segments[s, :2]
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    d = np.column_stack([np.cos(angles[hit]), np.sin(angles[hit])])
    cos_inc = np.abs(d[:, 0] * e[:, 1] - d[:, 1] * e[:, 0])  # |sin(angle between beam and segment)|
    r = dist[hit]
    diffuse = refl[m] * (cos_inc + gloss[m] * cos_inc**40) / (1.0 + 0.05 * r)
    retro = refl[m] * (0.8 + 0.2 * cos_inc) / (1.0 + 0.02 * r)
    out[hit] = np.where(beacon[m], retro, diffuse)
    return out


def simulate_scan(
    world: World,
    pose: tuple[float, float, float],
    *,
    n_beams: int = 720,
    range_noise: float = 0.01,
    intensity_noise: float = 0.05,
    max_range: float = 8.0,
    height: float = LASER_HEIGHT,
    random_state: int | np.random.Generator | None = None,
) -> Scan:
    """Simulate one 360 deg scan from two back-to-back 180 deg heads.

    Parameters
    ----------
    world : World
    pose : (x, y, theta)
        Robot pose, metres and radians (world frame).
    n_beams : int, default 720
        Beams over the full turn (even: half per head); 720 is 0.5 deg resolution.
    range_noise : float, default 0.01
        Standard deviation of the Gaussian range noise, metres.
    intensity_noise : float, default 0.05
        Relative standard deviation of the intensity noise.
    max_range : float, default 8.0
        Largest range reported, metres; farther hits and misses become ``inf``.
    height : float, default LASER_HEIGHT
        Height of the scan plane, metres (segments not spanning it are not seen).
    random_state : int or numpy.random.Generator, optional

    Returns
    -------
    Scan
        Bearings increasing from about ``-pi``; ``intensities`` per beam;
        ``pose`` set; ``meta``-free.
    """
    if isinstance(n_beams, bool) or not isinstance(n_beams, int | np.integer) or n_beams < 4 or n_beams % 2:
        raise InvalidParameterError(f"n_beams must be an even integer >= 4 (two heads), got {n_beams!r}")
    if not (np.isfinite(range_noise) and range_noise >= 0):
        raise InvalidParameterError(f"range_noise must be >= 0 metres, got {range_noise!r}")
    if not (np.isfinite(intensity_noise) and intensity_noise >= 0):
        raise InvalidParameterError(f"intensity_noise must be >= 0, got {intensity_noise!r}")
    if not (np.isfinite(max_range) and max_range > 0):
        raise InvalidParameterError(f"max_range must be a positive number of metres, got {max_range!r}")
    x, y, th = (float(v) for v in pose)
    rng = check_random_state(random_state)
    bearings = scan_bearings(int(n_beams))
    angles = bearings + th
    dist, seg, _ = cast_rays(world, (x, y), angles, z=height)
    inten = beam_intensity(world, (x, y), angles, dist, seg, height=height)
    hit = np.isfinite(dist)
    ranges = dist + range_noise * rng.standard_normal(dist.shape)
    ranges = np.where(hit, np.maximum(ranges, 0.0), np.inf)
    # Multiplicative noise plus a small additive floor, both scaled by intensity_noise.
    noise_mul = intensity_noise * rng.standard_normal(dist.shape)
    noise_add = 0.1 * intensity_noise * np.abs(rng.standard_normal(dist.shape))
    inten = inten * (1.0 + noise_mul) + noise_add
    inten = np.where(hit & (ranges < max_range), np.maximum(inten, 0.0), 0.0)
    return Scan(ranges=ranges, bearings=bearings, max_range=max_range, intensities=inten, pose=(x, y, th))
