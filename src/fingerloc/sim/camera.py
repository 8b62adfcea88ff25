"""The camera: a rendered cylindrical panorama and the raw donut image of an equiangular mirror.

Both come from one vectorised renderer. For every image column (a bearing) the
``k`` nearest wall crossings are found at once (rays x segments); for every
row (an elevation ``e``) the height of the ray at each crossing,
``z = camera_height + d tan(e)``, says which surface stops it first (a low desk
lets the ray pass above it), or whether it reaches the floor or the ceiling.

The colour of a pixel is ``albedo x shading x sun x lighting x vignetting``:

- *shading*: walls facing the room's main light (``World.light_angle``) are
  brighter (``0.62 + 0.38 (1 + n.l) / 2``), and wall bases are darker (contact
  shadow);
- *sun*: the world's soft light boxes (sun patches, shadows) multiply the
  brightness of the surface points inside them;
- *lighting* (random per render, scaled by ``lighting``): global exposure, a
  colour cast, and a brightness gradient over bearing (a window on one side);
- *vignetting*: lens shading, darker towards the top and bottom of the
  panorama (towards the inner and outer rims of the donut);
- pixel noise, and optionally a JPEG round trip through Pillow.

Panorama convention (:class:`~fingerloc.sensors.Panorama`): ``clockwise=True``
and ``bearing_offset = pi``, so the robot's heading is at the centre column and
its left (+90 deg) at the first quarter; row 0 is the highest elevation.
"""

from __future__ import annotations

import functools
import io
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._types import FArray
from ..errors import InvalidParameterError
from ..sensors import Panorama
from ..validation import check_random_state
from .world import World, cast_rays_k

__all__ = ["CAMERA_HEIGHT", "ELEVATION_DEG", "OmniImage", "render_omni", "render_panorama"]


#: Height of the camera's centre of projection above the floor, metres.
CAMERA_HEIGHT = 1.2
#: Default elevation range of the camera (lowest, highest), degrees.
ELEVATION_DEG = (-45.0, 30.0)
#: Surfaces looked through: ``k`` nearest crossings per column.
_K_HITS = 8
#: Softness (metres) of the edges of sun patches and shadows.
_SUN_SOFT = 0.08


@dataclass(frozen=True, slots=True)
class _Render:
    """Noise-free render of a bearing x elevation grid (internal)."""

    albedo: FArray  # (r, c, 3)
    shade: FArray  # (r, c) structural shading
    sun: FArray  # (r, c) sun / shadow gain
    seg: NDArray[np.int64]  # (r, c) segment id, -1 floor, -2 ceiling
    mat: NDArray[np.int64]  # (r, c) material id, -1 floor, -2 ceiling


def render_grid(
    world: World,
    pose: tuple[float, float, float],
    bearings: FArray,
    elevations: FArray,
    *,
    camera_height: float = CAMERA_HEIGHT,
) -> _Render:
    """Render a grid of rays without noise.

    Parameters
    ----------
    bearings : ndarray, shape (c,)
        Column bearings, radians (robot frame).
    elevations : ndarray, shape (r,)
        Row elevations, radians (positive up), each in ``(-pi/2, pi/2)``.
    """
    x, y, th = (float(v) for v in pose)
    ang = np.asarray(bearings, dtype=np.float64) + th
    dist, seg, _ = cast_rays_k(world, (x, y), ang, _K_HITS)  # (c, k)
    tan_e = np.tan(np.asarray(elevations, dtype=np.float64))[:, None, None]  # (r, 1, 1)
    H = world.height
    valid = seg >= 0
    n_used = max(int(valid.sum(axis=1).max()), 1)
    dist, seg, valid = dist[:, :n_used], seg[:, :n_used], valid[:, :n_used]
    sidx = np.where(valid, seg, 0)
    # A ray of slope tan(e) is stopped by crossing k when it is within the segment's height range
    # (tan(e) in [(z_lo - h)/d, (z_hi - h)/d]), or it has met the floor or ceiling before (below
    # -h/d or above (H - h)/d). Thresholds per (column, crossing), compared in float32.
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_d = np.where(valid, 1.0 / dist, 0.0)
    t_lo = ((world.z_range[sidx, 0] - camera_height) * inv_d).astype(np.float32)[None]
    t_hi = ((world.z_range[sidx, 1] - camera_height) * inv_d).astype(np.float32)[None]
    t_f = np.where(valid, -camera_height * inv_d, -np.inf).astype(np.float32)[None]
    t_c = np.where(valid, (H - camera_height) * inv_d, np.inf).astype(np.float32)[None]
    T = tan_e.astype(np.float32)
    covered = (T >= t_lo) & (T <= t_hi)
    covered &= valid[None]
    stop = covered | (T < t_f) | (T > t_c)
    first = np.argmax(stop, axis=2)  # (r, c)
    anystop = np.take_along_axis(stop, first[..., None], axis=2)[..., 0]
    surf = anystop & np.take_along_axis(covered, first[..., None], axis=2)[..., 0]
    R, C = first.shape
    cols = np.broadcast_to(np.arange(C), (R, C))
    s_hit = np.where(surf, seg[cols, first], -1)
    d_hit = dist[cols, first]
    with np.errstate(invalid="ignore"):
        z_hit = camera_height + d_hit * tan_e[:, :, 0]
    up = np.broadcast_to(tan_e[:, :, 0] > 0, (R, C))
    s_all = np.where(surf, s_hit, np.where(up, -2, -1))
    s_safe = np.where(surf, s_hit, 0)

    # Materials and albedo: one gather from a table holding the materials, then floor, then ceiling.
    rgb, *_ = world.material_table()
    n_mat = rgb.shape[0]
    dz = world.decal_z[s_safe]
    with np.errstate(invalid="ignore"):
        on_decal = surf & (z_hit >= dz[..., 0]) & (z_hit <= dz[..., 1])
    mat = np.where(on_decal, world.decal_material[s_safe], world.material[s_safe])
    mat = np.where(surf, mat, np.where(up, -2, -1))
    table = np.vstack([rgb, world.floor_rgb, world.ceiling_rgb])
    albedo = table[np.where(surf, mat, np.where(up, n_mat + 1, n_mat))]

    # Structural shading: one value per segment (its normal facing the camera against the main light).
    seg_xy = world.segments
    e = seg_xy[:, 2:] - seg_xy[:, :2]
    e = e / np.linalg.norm(e, axis=1, keepdims=True)
    nrm = np.column_stack([-e[:, 1], e[:, 0]])
    side = np.sign(((np.array([x, y]) - seg_xy[:, :2]) * nrm).sum(axis=1) + 1e-12)
    ndl = side * (nrm[:, 0] * np.cos(world.light_angle) + nrm[:, 1] * np.sin(world.light_angle))
    seg_shade = 0.62 + 0.38 * (1.0 + ndl) / 2.0
    with np.errstate(divide="ignore", invalid="ignore"):
        d_plane = np.where(up, (H - camera_height) / tan_e[:, :, 0], camera_height / -tan_e[:, :, 0])
    d_pix = np.where(surf, d_hit, d_plane)
    d_pix = np.where(np.isfinite(d_pix), d_pix, 50.0)
    z_safe = np.where(surf, z_hit, 1.0)
    wall_shade = seg_shade[s_safe] * (1.0 - 0.25 * np.exp(-np.maximum(z_safe, 0.0) / 0.15))  # contact shadow
    # Floor darkens a little with distance (light falls off away from the lamps); the ceiling is even.
    shade = np.where(surf, wall_shade, np.where(up, 0.95, 0.8 * (1.0 - 0.15 * np.tanh(d_pix / 5.0))))
    emission = world.emission_table()
    if emission.any():
        glow = np.where(surf, emission[np.where(surf, mat, 0)], 0.0)
        shade = np.where(glow > 0, glow, shade)  # windows and lamps: bright whatever their orientation

    # Sun patches and shadows: soft boxes around the 3D point of each pixel.
    sun = np.ones((R, C))
    if world.sun.shape[0]:
        ca, sa = np.cos(ang)[None, :], np.sin(ang)[None, :]
        px, py = x + d_pix * ca, y + d_pix * sa
        pz = np.where(surf, z_hit, np.where(up, H, 0.0))
        for cx, cy, cz, hx, hy, hz, g in world.sun:
            w = np.ones((R, C))
            for pp, c, h in ((px, cx, hx), (py, cy, hy), (pz, cz, hz)):
                w = w * np.clip((h - np.abs(pp - c)) / _SUN_SOFT + 0.5, 0.0, 1.0)
            sun = sun * (1.0 + g * w)
    return _Render(albedo=albedo, shade=shade, sun=sun, seg=s_all, mat=mat)


def _lighting(rng: np.random.Generator, amount: float, bearings: FArray, theta: float) -> tuple[float, FArray, FArray]:
    """Random exposure, colour cast (3,) and per-column gain (c,) for one render."""
    gain = float(np.exp(0.25 * amount * rng.normal()))
    cast = 1.0 + 0.06 * amount * rng.normal(size=3)
    phase = rng.uniform(-np.pi, np.pi)
    col = 1.0 + 0.15 * amount * rng.uniform() * np.cos(bearings + theta - phase)
    return gain, cast, col


def _finish(
    img: NDArray[np.floating[Any]],
    rng: np.random.Generator,
    noise: float,
    jpeg_quality: int | None,
    blur: float = 0.0,
    wrap_columns: bool = False,
) -> NDArray[np.uint8]:
    img32 = np.asarray(img, dtype=np.float32) * np.float32(255.0)
    if blur > 0:
        from scipy.ndimage import gaussian_filter

        # Defocus: a Gaussian of ``blur`` pixels; a panorama's columns wrap around.
        img32 = gaussian_filter(
            img32, sigma=(blur, blur, 0.0), mode=("nearest", "wrap" if wrap_columns else "nearest", "nearest")
        )
    if noise > 0:
        img32 = img32 + np.float32(255.0 * noise) * rng.standard_normal(img32.shape, dtype=np.float32)
    out = np.clip(np.rint(img32), 0, 255).astype(np.uint8)
    if jpeg_quality is not None:
        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(out).save(buf, format="JPEG", quality=int(jpeg_quality))
        buf.seek(0)
        out = np.asarray(Image.open(buf).convert("RGB"), dtype=np.uint8)
    return out


def _check_common(
    lighting: float, noise: float, vignetting: float, jpeg_quality: int | None, elevation_deg: tuple[float, float]
) -> tuple[float, float]:
    if not (np.isfinite(lighting) and lighting >= 0):
        raise InvalidParameterError(f"lighting must be >= 0, got {lighting!r}")
    if not (np.isfinite(noise) and noise >= 0):
        raise InvalidParameterError(f"noise must be >= 0, got {noise!r}")
    if not (np.isfinite(vignetting) and 0 <= vignetting < 1):
        raise InvalidParameterError(f"vignetting must be in [0, 1), got {vignetting!r}")
    if jpeg_quality is not None and not (isinstance(jpeg_quality, int) and 1 <= jpeg_quality <= 100):
        raise InvalidParameterError(f"jpeg_quality must be an integer in [1, 100] or None, got {jpeg_quality!r}")
    lo, hi = (float(v) for v in elevation_deg)
    if not (-89.0 < lo < hi < 89.0):
        raise InvalidParameterError(
            f"elevation_deg must be (low, high) with -89 < low < high < 89, got {elevation_deg!r}"
        )
    return np.deg2rad(lo), np.deg2rad(hi)


def render_panorama(
    world: World,
    pose: tuple[float, float, float],
    *,
    width: int = 720,
    height: int = 120,
    elevation_deg: tuple[float, float] = ELEVATION_DEG,
    camera_height: float = CAMERA_HEIGHT,
    lighting: float = 1.0,
    sun: bool = True,
    vignetting: float = 0.25,
    noise: float = 0.015,
    jpeg_quality: int | None = None,
    blur: float = 0.5,
    supersample: int = 2,
    random_state: int | np.random.Generator | None = None,
) -> Panorama:
    """Render the 360 deg cylindrical panorama seen from ``pose``.

    Parameters
    ----------
    world : World
    pose : (x, y, theta)
        Robot pose, metres and radians.
    width, height : int
        Image size in pixels; columns span 360 deg of bearing, rows span ``elevation_deg``.
    elevation_deg : (low, high)
        Elevation of the bottom and top image edges, degrees.
    camera_height : float
        Height of the camera, metres.
    lighting : float, default 1
        Scale of the random lighting variation of this render (0: the world's nominal lighting).
    sun : bool, default True
        Apply the world's sun patches and shadows.
    vignetting : float in [0, 1), default 0.25
        Brightness lost at the top and bottom edges (lens shading).
    noise : float, default 0.015
        Standard deviation of the Gaussian pixel noise (image values in [0, 1]).
    jpeg_quality : int, optional
        Round-trip the image through JPEG at this quality (1-100) to add compression artefacts.
    blur : float, default 0.5
        Standard deviation (pixels) of a Gaussian defocus applied before the noise; 0 for none.
    supersample : int, default 2
        Rays per column (averaged), for anti-aliased vertical edges.
    random_state : int or numpy.random.Generator, optional

    Returns
    -------
    Panorama
        uint8-derived float32 image, shape (height, width, 3); ``clockwise=True``,
        ``bearing_offset=pi`` (the heading is the centre column); ``meta`` holds
        ``elevation_deg``, ``camera_height`` and ``pose``.
    """
    for name, v, lo in (("width", width, 8), ("height", height, 2), ("supersample", supersample, 1)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < lo:
            raise InvalidParameterError(f"{name} must be an integer >= {lo}, got {v!r}")
    e_lo, e_hi = _check_common(lighting, noise, vignetting, jpeg_quality, elevation_deg)
    if not (np.isfinite(blur) and 0 <= blur <= 10):
        raise InvalidParameterError(f"blur must be in [0, 10] pixels, got {blur!r}")
    rng = check_random_state(random_state)
    ss = int(supersample)
    sub = (np.arange(width * ss) + 0.5) / ss  # fractional column coordinates
    bearings = np.pi - 2 * np.pi * sub / width  # clockwise, offset pi
    elev = e_hi - (np.arange(height) + 0.5) * (e_hi - e_lo) / height
    r = render_grid(world, pose, bearings, elev, camera_height=camera_height)
    gain, cast, colgain = _lighting(rng, lighting, bearings, float(pose[2]))
    lum = r.shade * (r.sun if sun else 1.0) * gain * colgain[None, :]
    u = (elev - (e_hi + e_lo) / 2) / ((e_hi - e_lo) / 2)
    lum = lum * (1.0 - vignetting * u**2)[:, None]
    img = r.albedo * lum[..., None] * cast
    if ss > 1:
        img = img.reshape(height, width, ss, 3).mean(axis=2)
    out = _finish(img, rng, noise, jpeg_quality, blur, wrap_columns=True)
    meta: dict[str, object] = {
        "elevation_deg": (float(elevation_deg[0]), float(elevation_deg[1])),
        "camera_height": float(camera_height),
        "pose": tuple(float(v) for v in pose),
    }
    return Panorama(image=out, bearing_offset=np.pi, clockwise=True, meta=meta)  # type: ignore[arg-type]  # uint8 accepted


@dataclass(frozen=True, slots=True, eq=False)
class OmniImage:
    """The raw image of an omnidirectional camera with an equiangular mirror (a donut).

    A pixel at distance ``r`` from ``center`` and image angle ``phi`` sees the
    elevation that grows linearly with ``r`` (``elevation_range[0]`` at
    ``radii[0]``, ``elevation_range[1]`` at ``radii[1]``) and the bearing
    ``forward_angle - phi`` (``clockwise=True``) or ``phi - forward_angle``.
    ``phi = atan2(-(y - cy), x - cx)``: counter-clockwise on screen, 0 to the right.

    Parameters
    ----------
    image : ndarray of uint8, shape (h, w, 3)
        RGB pixels.
    center : (cx, cy)
        Mirror axis in pixel coordinates (x = column, y = row; pixel ``j`` spans ``[j, j + 1)``).
    radii : (r_in, r_out)
        Inner and outer radius of the useful ring, pixels.
    elevation_range : (e_in, e_out)
        Elevations (radians) seen at ``r_in`` and ``r_out``.
    forward_angle : float, default pi/2
        Image angle ``phi`` (radians) where bearing 0 (the robot's heading) appears: up.
    clockwise : bool, default False
        False: bearings grow counter-clockwise on screen (a map seen from above).
    meta : dict
        Free-form information (pose, camera height).
    """

    image: NDArray[np.uint8]
    center: tuple[float, float]
    radii: tuple[float, float]
    elevation_range: tuple[float, float] = (float(np.deg2rad(ELEVATION_DEG[0])), float(np.deg2rad(ELEVATION_DEG[1])))
    forward_angle: float = float(np.pi / 2)
    clockwise: bool = False
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        img = np.array(self.image, dtype=np.uint8, copy=True)
        if img.ndim != 3 or img.shape[2] != 3:
            raise InvalidParameterError(f"an omni image must be an (h, w, 3) RGB array, got shape {img.shape}")
        r_in, r_out = (float(v) for v in self.radii)
        if not (0 <= r_in < r_out):
            raise InvalidParameterError(f"radii must satisfy 0 <= r_in < r_out, got {self.radii!r}")
        e0, e1 = (float(v) for v in self.elevation_range)
        if not e0 < e1:
            raise InvalidParameterError(f"elevation_range must increase, got {self.elevation_range!r}")
        img.setflags(write=False)
        object.__setattr__(self, "image", img)
        object.__setattr__(self, "center", (float(self.center[0]), float(self.center[1])))
        object.__setattr__(self, "radii", (r_in, r_out))
        object.__setattr__(self, "elevation_range", (e0, e1))
        object.__setattr__(self, "forward_angle", float(self.forward_angle))

    def bearing_to_angle(self, bearing: FArray | float) -> FArray:
        """Image angle ``phi`` (radians, wrapped to [-pi, pi)) where a bearing appears."""
        from ..angles import wrap

        b = np.asarray(bearing, dtype=np.float64)
        return wrap(self.forward_angle - b if self.clockwise else self.forward_angle + b)

    def pixel_bearing(self, x: FArray | float, y: FArray | float) -> FArray:
        """Bearing (radians, wrapped) seen at pixel coordinates ``(x, y)``."""
        from ..angles import wrap

        phi = np.arctan2(
            -(np.asarray(y, dtype=np.float64) - self.center[1]), np.asarray(x, dtype=np.float64) - self.center[0]
        )
        return wrap(self.forward_angle - phi if self.clockwise else phi - self.forward_angle)

    def radius_elevation(self, r: FArray | float) -> FArray:
        """Elevation (radians) seen at radius ``r`` pixels (linear: the equiangular mirror)."""
        (r0, r1), (e0, e1) = self.radii, self.elevation_range
        return np.asarray(e0 + (np.asarray(r, dtype=np.float64) - r0) * (e1 - e0) / (r1 - r0))

    def elevation_radius(self, e: FArray | float) -> FArray:
        """Radius (pixels) at which elevation ``e`` (radians) appears."""
        (r0, r1), (e0, e1) = self.radii, self.elevation_range
        return np.asarray(r0 + (np.asarray(e, dtype=np.float64) - e0) * (r1 - r0) / (e1 - e0))


@dataclass(frozen=True, slots=True)
class _OmniLUT:
    ring: NDArray[np.int64]  # flat pixel indices inside the ring, (p,)
    idx: NDArray[np.int64]  # (4, p) flat grid indices of the bilinear neighbours
    w: NDArray[np.float32]  # (4, p) bilinear weights times vignetting
    background: NDArray[np.float32]  # (h, w, 3) image outside the ring


@functools.lru_cache(maxsize=8)
def _omni_lookup(
    w_px: int,
    h_px: int,
    cx: float,
    cy: float,
    r_in: float,
    r_out: float,
    forward_angle: float,
    clockwise: bool,
    n_b: int,
    n_e: int,
    vignetting: float,
) -> _OmniLUT:
    """Pixel -> (bearing, elevation) grid resampling table of one omni geometry (cached)."""
    ys, xs = np.mgrid[0:h_px, 0:w_px]
    dx, dy = xs + 0.5 - cx, ys + 0.5 - cy
    r = np.hypot(dx, dy)
    ring = ((r >= r_in) & (r <= r_out)).ravel()
    rf = r.ravel()[ring]
    phi = np.arctan2(-dy.ravel()[ring], dx.ravel()[ring])
    bearing = (forward_angle - phi) if clockwise else (phi - forward_angle)
    fb = np.mod(bearing + np.pi, 2 * np.pi) / (2 * np.pi) * n_b  # fractional grid column
    fe = np.clip((rf - r_in) / (r_out - r_in) * (n_e - 1), 0, n_e - 1)  # fractional grid row
    b0 = np.floor(fb).astype(np.int64)
    wb = fb - b0
    b0 %= n_b
    b1 = (b0 + 1) % n_b
    e0 = np.minimum(np.floor(fe).astype(np.int64), n_e - 2)
    we = fe - e0
    u = 2.0 * (rf - r_in) / (r_out - r_in) - 1.0
    vig = 1.0 - vignetting * u**2
    idx = np.stack([e0 * n_b + b0, e0 * n_b + b1, (e0 + 1) * n_b + b0, (e0 + 1) * n_b + b1])
    w = (np.stack([(1 - we) * (1 - wb), (1 - we) * wb, we * (1 - wb), we * wb]) * vig[None, :]).astype(np.float32)
    bg = np.full((h_px, w_px, 3), 0.03, dtype=np.float32)  # black rim outside the mirror
    bg[r < r_in] = 0.12  # the robot's own body reflected at the centre
    ring_idx = np.flatnonzero(ring)
    for a in (idx, w, bg, ring_idx):
        a.setflags(write=False)
    return _OmniLUT(ring=ring_idx, idx=idx, w=w, background=bg)


def render_omni(
    world: World,
    pose: tuple[float, float, float],
    *,
    size: tuple[int, int] = (640, 480),
    center: tuple[float, float] | None = None,
    radii: tuple[float, float] = (60.0, 230.0),
    elevation_deg: tuple[float, float] = ELEVATION_DEG,
    forward_angle: float = float(np.pi / 2),
    clockwise: bool = False,
    camera_height: float = CAMERA_HEIGHT,
    lighting: float = 1.0,
    sun: bool = True,
    vignetting: float = 0.3,
    noise: float = 0.015,
    jpeg_quality: int | None = None,
    blur: float = 0.7,
    random_state: int | np.random.Generator | None = None,
) -> OmniImage:
    """Render the raw donut image of an omnidirectional camera (equiangular mirror).

    Parameters
    ----------
    size : (width, height)
        Image size, pixels.
    center : (cx, cy), optional
        Mirror centre in pixel coordinates; default the image centre.
    radii : (r_in, r_out)
        Inner radius (the lowest elevation, inside it the robot's own body)
        and outer radius (the highest elevation, outside it the black rim), pixels.
    elevation_deg : (low, high)
        Elevations seen at ``r_in`` and ``r_out``, degrees.
    forward_angle, clockwise
        Orientation of the bearings in the image, see :class:`OmniImage`.
    lighting, sun, vignetting, noise, jpeg_quality, random_state
        As in :func:`render_panorama`; vignetting darkens towards both rims.
    blur : float, default 0.7
        Defocus of the mirror image, pixels (Gaussian standard deviation).

    Returns
    -------
    OmniImage
    """
    w_px, h_px = (int(v) for v in size)
    if w_px < 16 or h_px < 16:
        raise InvalidParameterError(f"size must be at least 16x16 pixels, got {size!r}")
    cx, cy = (w_px / 2.0, h_px / 2.0) if center is None else (float(center[0]), float(center[1]))
    r_in, r_out = (float(v) for v in radii)
    if not (0 <= r_in < r_out):
        raise InvalidParameterError(f"radii must satisfy 0 <= r_in < r_out, got {radii!r}")
    e_lo, e_hi = _check_common(lighting, noise, vignetting, jpeg_quality, elevation_deg)
    if not (np.isfinite(blur) and 0 <= blur <= 10):
        raise InvalidParameterError(f"blur must be in [0, 10] pixels, got {blur!r}")
    rng = check_random_state(random_state)

    # Render an internal (bearing x elevation) grid at the ring's resolution (mid radius), then resample.
    n_b = int(np.ceil(np.pi * (r_in + r_out)))
    n_e = max(int(np.ceil(r_out - r_in)) + 1, 2)
    grid_b = -np.pi + 2 * np.pi * np.arange(n_b) / n_b
    grid_e = np.linspace(e_lo, e_hi, n_e)
    rr = render_grid(world, pose, grid_b, grid_e, camera_height=camera_height)
    gain, cast, colgain = _lighting(rng, lighting, grid_b, float(pose[2]))
    lum = rr.shade * (rr.sun if sun else 1.0) * gain * colgain[None, :]
    # Colour planes, each (n_e * n_b,): one contiguous gather per plane and neighbour is fastest.
    planes = np.ascontiguousarray(np.moveaxis(rr.albedo * lum[..., None] * cast, 2, 0).reshape(3, -1), dtype=np.float32)
    if blur > 0:
        from scipy.ndimage import gaussian_filter

        # Defocus on the (elevation x bearing) grid, whose cells are about one image pixel; bearings wrap.
        planes = gaussian_filter(
            planes.reshape(3, n_e, n_b), sigma=(0.0, blur, blur), mode=("nearest", "nearest", "wrap")
        ).reshape(3, -1)

    lut = _omni_lookup(
        w_px, h_px, cx, cy, r_in, r_out, float(forward_angle), bool(clockwise), n_b, n_e, float(vignetting)
    )
    img = lut.background.copy()
    flat = img.reshape(-1, 3)
    i0, i1, i2, i3 = lut.idx
    w0, w1, w2, w3 = lut.w
    for c in range(3):
        p = planes[c]
        flat[lut.ring, c] = w0 * p[i0] + w1 * p[i1] + w2 * p[i2] + w3 * p[i3]
    out = _finish(img, rng, noise, jpeg_quality)
    return OmniImage(
        image=out,
        center=(cx, cy),
        radii=(r_in, r_out),
        elevation_range=(e_lo, e_hi),
        forward_angle=forward_angle,
        clockwise=clockwise,
        meta={"camera_height": float(camera_height), "pose": tuple(float(v) for v in pose)},
    )
