"""Simulated worlds: immutable 2.5D office geometry and the ray caster shared by the sensors.

A :class:`World` is a set of vertical wall *segments* (2D line segments in the
floor plane, each with a height range ``[z_lo, z_hi]`` in metres) carrying a
:class:`Material` (albedo colour, laser remission, beacon and patch flags). A
segment may carry one *decal*: a height band ``[z0, z1]`` painted with another
material (a coloured poster, a strip of retro-reflective tape). Sun patches and
shadows are soft 3D boxes that scale the brightness of whatever surface lies
inside them.

World frame: metres, x to the east, y to the north, angles counter-clockwise
from +x. A pose is ``(x, y, theta)`` with ``theta`` the robot's heading;
bearings are relative to the heading, counter-clockwise positive.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._types import FArray, IArray
from ..errors import InvalidParameterError

__all__ = ["PARTS", "Material", "World", "cast_rays", "cast_rays_k"]


#: Names of the structural parts a segment can belong to (``World.part`` indexes this).
PARTS: tuple[str, ...] = ("wall", "door_frame", "lintel", "furniture", "pillar", "corridor", "door_leaf", "chair", "person")

#: Rays hitting closer than this (metres) are ignored, so a ray does not hit the surface it starts on.
_MIN_HIT = 1e-6


def _ro(a: ArrayLike, dtype: type = np.float64) -> NDArray:  # type: ignore[type-arg]
    arr: NDArray = np.array(a, dtype=dtype, copy=True)  # type: ignore[type-arg]
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, slots=True)
class Material:
    """Surface properties of a segment or a decal.

    Parameters
    ----------
    rgb : (r, g, b)
        Albedo colour, each in ``[0, 1]`` (linear).
    reflectivity : float
        Laser remission of a diffuse surface at normal incidence, in ``[0, 2]``
        (normalised: matt white paint is about 0.6; retro-reflective tape 1.5).
    beacon : bool
        Retro-reflective target: bright to the laser at any incidence.
    patch : bool
        A saturated coloured patch (poster, sign): a ground-truth ``CP`` feature.
    gloss : float
        Specular share of the laser remission near normal incidence, ``[0, 1]``.
    emission : float
        Camera brightness of a light source (a window, a lamp), replacing the
        shading of diffuse surfaces; above 1 it overexposes. 0 for ordinary surfaces.
    """

    rgb: tuple[float, float, float]
    reflectivity: float = 0.4
    beacon: bool = False
    patch: bool = False
    gloss: float = 0.0
    emission: float = 0.0

    def __post_init__(self) -> None:
        rgb = tuple(float(v) for v in self.rgb)
        if len(rgb) != 3 or not all(0.0 <= v <= 1.0 for v in rgb):
            raise InvalidParameterError(f"rgb must be three values in [0, 1], got {self.rgb!r}")
        if not 0.0 <= self.reflectivity <= 2.0:
            raise InvalidParameterError(f"reflectivity must be in [0, 2], got {self.reflectivity!r}")
        if not 0.0 <= self.gloss <= 1.0:
            raise InvalidParameterError(f"gloss must be in [0, 1], got {self.gloss!r}")
        if not 0.0 <= self.emission <= 5.0:
            raise InvalidParameterError(f"emission must be in [0, 5], got {self.emission!r}")
        object.__setattr__(self, "rgb", rgb)

    @property
    def hue_deg(self) -> float:
        """HSV hue of the albedo, degrees in ``[0, 360)``."""
        h, _, _ = colorsys.rgb_to_hsv(*self.rgb)
        return float(h * 360.0) % 360.0

    @property
    def saturation(self) -> float:
        """HSV saturation of the albedo, ``[0, 1]``."""
        return float(colorsys.rgb_to_hsv(*self.rgb)[1])


@dataclass(frozen=True, slots=True, eq=False)
class World:
    """An immutable simulated office.

    Parameters
    ----------
    segments : array_like, shape (m, 4)
        ``x0, y0, x1, y1`` of each vertical segment, metres.
    z_range : array_like, shape (m, 2)
        Bottom and top height of each segment, metres.
    material : array_like of int, shape (m,)
        Index into ``materials`` of each segment's surface.
    materials : tuple of Material
        The materials used.
    decal_z : array_like, shape (m, 2), optional
        Height band of each segment's decal, NaN where there is none.
    decal_material : array_like of int, shape (m,), optional
        Material index of each decal, -1 where there is none.
    part : array_like of int, shape (m,), optional
        Index into :data:`PARTS` of each segment (default all walls).
    height : float
        Ceiling height, metres.
    floor_rgb, ceiling_rgb : (r, g, b)
        Albedo of floor and ceiling.
    light_angle : float
        Direction (radians, world frame) the main light comes from; sets the
        brightness of each wall orientation.
    sun : array_like, shape (k, 7)
        Soft light boxes ``cx, cy, cz, hx, hy, hz, gain``: a surface point inside
        gets its brightness multiplied by ``1 + gain`` (gain < 0: a shadow).
    room : array_like, shape (n, 2)
        Vertices of the room polygon (counter-clockwise), metres.
    anchor : (x, y)
        A free point well inside the room (where measurements are taken).
    name : str
        A label, e.g. ``"office-3"``.
    """

    segments: FArray
    z_range: FArray
    material: IArray
    materials: tuple[Material, ...]
    decal_z: FArray = field(default_factory=lambda: np.empty((0, 2)))
    decal_material: IArray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    part: IArray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    height: float = 2.7
    floor_rgb: tuple[float, float, float] = (0.45, 0.45, 0.47)
    ceiling_rgb: tuple[float, float, float] = (0.9, 0.9, 0.9)
    light_angle: float = 0.5
    sun: FArray = field(default_factory=lambda: np.empty((0, 7)))
    room: FArray = field(default_factory=lambda: np.empty((0, 2)))
    anchor: tuple[float, float] = (0.0, 0.0)
    name: str = "world"
    _adjacent: NDArray[np.bool_] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        seg = np.array(self.segments, dtype=np.float64).reshape(-1, 4)
        m = seg.shape[0]
        if m == 0:
            raise InvalidParameterError("a world needs at least one segment")
        if not np.all(np.isfinite(seg)):
            raise InvalidParameterError("segments must hold finite coordinates")
        z = np.array(self.z_range, dtype=np.float64).reshape(-1, 2)
        if z.shape[0] != m:
            raise InvalidParameterError(f"z_range needs one row per segment, got {z.shape[0]} for {m}")
        if np.any(z[:, 1] <= z[:, 0]):
            raise InvalidParameterError("z_range: each segment needs z_lo < z_hi")
        mat = np.array(self.material, dtype=np.int64).reshape(-1)
        if mat.shape[0] != m or mat.min() < 0 or mat.max() >= len(self.materials):
            raise InvalidParameterError("material: one valid index into materials per segment is needed")
        dz = np.array(self.decal_z, dtype=np.float64).reshape(-1, 2)
        dm = np.array(self.decal_material, dtype=np.int64).reshape(-1)
        if dz.size == 0 and dm.size == 0:
            dz, dm = np.full((m, 2), np.nan), np.full(m, -1, dtype=np.int64)
        if dz.shape != (m, 2) or dm.shape != (m,) or dm.max() >= len(self.materials):
            raise InvalidParameterError("decal_z must be (m, 2) and decal_material (m,) with valid indices")
        part = np.array(self.part, dtype=np.int64).reshape(-1)
        if part.size == 0:
            part = np.zeros(m, dtype=np.int64)
        if part.shape != (m,) or part.min() < 0 or part.max() >= len(PARTS):
            raise InvalidParameterError("part: one index into PARTS per segment is needed")
        if not (np.isfinite(self.height) and self.height > 0):
            raise InvalidParameterError(f"height must be a positive number of metres, got {self.height!r}")
        sun = np.array(self.sun, dtype=np.float64).reshape(-1, 7)
        room = np.array(self.room, dtype=np.float64).reshape(-1, 2)
        # Segments sharing an end point (within 1 mm) are "connected": no depth jump between them.
        ends = np.stack([seg[:, :2], seg[:, 2:]], axis=1)  # (m, 2, 2)
        d = np.linalg.norm(ends[:, None, :, None, :] - ends[None, :, None, :, :], axis=-1)  # (m, m, 2, 2)
        adj = (d < 1e-3).any(axis=(2, 3))
        adj.setflags(write=False)
        object.__setattr__(self, "segments", _ro(seg))
        object.__setattr__(self, "z_range", _ro(z))
        object.__setattr__(self, "material", _ro(mat, np.int64))
        object.__setattr__(self, "materials", tuple(self.materials))
        object.__setattr__(self, "decal_z", _ro(dz))
        object.__setattr__(self, "decal_material", _ro(dm, np.int64))
        object.__setattr__(self, "part", _ro(part, np.int64))
        object.__setattr__(self, "sun", _ro(sun))
        object.__setattr__(self, "room", _ro(room))
        object.__setattr__(self, "height", float(self.height))
        object.__setattr__(self, "anchor", (float(self.anchor[0]), float(self.anchor[1])))
        object.__setattr__(self, "_adjacent", adj)

    # ------------------------------------------------------------------ queries
    @property
    def n_segments(self) -> int:
        """Number of segments."""
        return int(self.segments.shape[0])

    def emission_table(self) -> FArray:
        """Per-material camera emission, shape (k,)."""
        return np.array([m.emission for m in self.materials], dtype=np.float64)

    def material_table(self) -> tuple[FArray, FArray, NDArray[np.bool_], NDArray[np.bool_], FArray]:
        """Per-material arrays: rgb (k, 3), reflectivity (k,), beacon (k,), patch (k,), gloss (k,)."""
        mats = self.materials
        return (
            np.array([m.rgb for m in mats], dtype=np.float64),
            np.array([m.reflectivity for m in mats], dtype=np.float64),
            np.array([m.beacon for m in mats], dtype=bool),
            np.array([m.patch for m in mats], dtype=bool),
            np.array([m.gloss for m in mats], dtype=np.float64),
        )

    def surface_material(self, seg: ArrayLike, z: ArrayLike) -> IArray:
        """Material index seen on segment(s) ``seg`` at height(s) ``z`` (the decal where it covers ``z``)."""
        s = np.asarray(seg, dtype=np.int64)
        zz = np.asarray(z, dtype=np.float64)
        dz = self.decal_z[s]
        on_decal = (zz >= dz[..., 0]) & (zz <= dz[..., 1])  # NaN compares False
        return np.where(on_decal, self.decal_material[s], self.material[s])

    def connected(self, a: ArrayLike, b: ArrayLike) -> NDArray[np.bool_]:
        """True where segments ``a`` and ``b`` share an end point (or are the same)."""
        ia = np.asarray(a, dtype=np.int64)
        ib = np.asarray(b, dtype=np.int64)
        return np.asarray((ia == ib) | self._adjacent[ia, ib])

    def blocking(self, z: float) -> NDArray[np.bool_]:
        """Mask of segments a horizontal ray at height ``z`` (metres) hits, shape (m,)."""
        return np.asarray((self.z_range[:, 0] <= z) & (self.z_range[:, 1] >= z))

    def contains(self, points: ArrayLike) -> NDArray[np.bool_]:
        """True for the points (shape (..., 2), metres) inside the room polygon."""
        p = np.asarray(points, dtype=np.float64)
        if self.room.shape[0] < 3:
            return np.ones(p.shape[:-1], dtype=bool)
        return point_in_polygon(self.room, p)

    def clearance(self, points: ArrayLike, *, z: float | None = None) -> FArray:
        """Distance (metres) from each point (shape (..., 2)) to the nearest segment.

        With ``z`` given, only segments spanning that height count.
        """
        p = np.asarray(points, dtype=np.float64)
        seg = self.segments if z is None else self.segments[self.blocking(z)]
        a = seg[:, :2]
        e = seg[:, 2:] - a
        ee = np.maximum((e * e).sum(axis=1), 1e-18)
        w = p[..., None, :] - a
        t = np.clip((w * e).sum(axis=-1) / ee, 0.0, 1.0)
        d = w - t[..., None] * e
        return np.asarray(np.sqrt((d * d).sum(axis=-1)).min(axis=-1))


def point_in_polygon(poly: ArrayLike, points: ArrayLike) -> NDArray[np.bool_]:
    """True for the points (shape (..., 2)) inside the polygon (vertices (k, 2), metres), by ray crossing (even-odd)."""
    poly = np.asarray(poly, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    x, y = p[..., 0, None], p[..., 1, None]
    x0, y0 = poly[:, 0], poly[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    cond = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return np.asarray((cond & (x < xi)).sum(axis=-1) % 2 == 1)


# ---------------------------------------------------------------- ray casting
def _intersections(
    world: World, origin: tuple[float, float], angles: FArray, mask: NDArray[np.bool_] | None
) -> tuple[FArray, FArray, IArray]:
    """Distance and segment parameter of every ray x segment crossing.

    Returns ``dist`` (n, m') with ``inf`` where the ray misses, ``t`` (n, m')
    in ``[0, 1]`` along the segment, and the indices (m',) of the segments used.
    """
    idx = np.arange(world.n_segments) if mask is None else np.flatnonzero(mask)
    seg = world.segments[idx]
    px, py = seg[:, 0], seg[:, 1]
    ex, ey = seg[:, 2] - px, seg[:, 3] - py
    dx, dy = np.cos(angles)[:, None], np.sin(angles)[:, None]
    wx, wy = px - origin[0], py - origin[1]
    # o + u d = p + t e  =>  u = (w x e) / (d x e),  t = (w x d) / (d x e)
    den = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv = 1.0 / den
        u = (wx * ey - wy * ex) * inv
        t = (wx * dy - wy * dx) * inv
    ok = (np.abs(den) > 1e-12) & (u > _MIN_HIT) & (t >= -1e-9) & (t <= 1.0 + 1e-9)
    dist = np.where(ok, u, np.inf)
    return dist, np.clip(t, 0.0, 1.0), idx


def cast_rays(
    world: World, origin: tuple[float, float], angles: ArrayLike, *, z: float | None = None
) -> tuple[FArray, IArray, FArray]:
    """Nearest hit of each horizontal ray (vectorised over rays x segments).

    Parameters
    ----------
    world : World
    origin : (x, y)
        Ray origin, metres, world frame.
    angles : array_like of float, shape (n,)
        Ray directions, radians, world frame.
    z : float, optional
        Height of the rays (metres): only segments spanning it are hit.

    Returns
    -------
    dist : ndarray, shape (n,)
        Distance to the hit, metres (``inf`` for no hit).
    seg : ndarray of int, shape (n,)
        Index of the segment hit (-1 for no hit).
    t : ndarray, shape (n,)
        Position of the hit along the segment, ``[0, 1]`` (NaN for no hit).
    """
    a = np.asarray(angles, dtype=np.float64).reshape(-1)
    mask = None if z is None else world.blocking(z)
    if mask is not None and not mask.any():
        return np.full(a.size, np.inf), np.full(a.size, -1, dtype=np.int64), np.full(a.size, np.nan)
    dist, t, idx = _intersections(world, origin, a, mask)
    j = np.argmin(dist, axis=1)
    rows = np.arange(a.size)
    d = dist[rows, j]
    hit = np.isfinite(d)
    return d, np.where(hit, idx[j], -1), np.where(hit, t[rows, j], np.nan)


def cast_rays_k(world: World, origin: tuple[float, float], angles: ArrayLike, k: int) -> tuple[FArray, IArray, FArray]:
    """The ``k`` nearest hits of each ray, sorted by distance (for the camera, which sees over low segments).

    Returns ``dist`` (n, k) (``inf`` pads), ``seg`` (n, k) (-1 pads), ``t`` (n, k).
    """
    a = np.asarray(angles, dtype=np.float64).reshape(-1)
    dist, t, idx = _intersections(world, origin, a, None)
    m = dist.shape[1]
    kk = min(k, m)
    part = np.argpartition(dist, kk - 1, axis=1)[:, :kk] if kk < m else np.broadcast_to(np.arange(m), (a.size, m))
    dk = np.take_along_axis(dist, part, axis=1)
    order = np.argsort(dk, axis=1)
    cols = np.take_along_axis(part, order, axis=1)
    dk = np.take_along_axis(dist, cols, axis=1)
    tk = np.take_along_axis(t, cols, axis=1)
    sk = np.where(np.isfinite(dk), idx[cols], -1)
    if kk < k:
        pad = k - kk
        dk = np.pad(dk, ((0, 0), (0, pad)), constant_values=np.inf)
        sk = np.pad(sk, ((0, 0), (0, pad)), constant_values=-1)
        tk = np.pad(tk, ((0, 0), (0, pad)), constant_values=np.nan)
    return dk, sk, tk
