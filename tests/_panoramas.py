"""Synthetic equirectangular panoramas of textured box rooms, rendered here by ray casting (no real photo)."""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from fingerloc.sensors import Panorama


def wall_textures(seed: int, n: int = 6, size: int = 256) -> np.ndarray:
    """``n`` random blob textures in [0, 1], shape ``(n, size, size)`` (four walls, floor, ceiling)."""
    rng = np.random.default_rng(seed)
    out = np.zeros((n, size, size))
    for k in range(n):
        img = np.zeros((size, size))
        for s in (1.5, 3.0, 6.0):
            img += ndimage.gaussian_filter(rng.normal(size=(size, size)), s, mode="wrap") * s
        out[k] = (img - img.min()) / (img.max() - img.min())
    return out


def render_room(
    textures: np.ndarray,
    position: tuple[float, float, float],
    heading_deg: float = 0.0,
    *,
    room: tuple[float, float, float] = (6.0, 4.0, 3.0),
    width: int = 1024,
    band_deg: float = 45.0,
    tilt_deg: float = 0.0,
) -> Panorama:
    """The band ``-band_deg .. +band_deg`` of an equirectangular panorama taken at ``position`` in a box room.

    The room spans ``[0, room[0]] x [0, room[1]] x [0, room[2]]`` metres; the
    camera's bearing 0 points along ``heading_deg`` (counter-clockwise from
    +x); ``tilt_deg`` pitches the camera about its y axis. Columns run
    clockwise (bearing decreasing, the usual photo), rows from the top. Each
    wall, the floor and the ceiling show one texture (bilinear sampling,
    ``textures[k]`` spread over the surface).
    """
    rows = round(width * 2 * band_deg / 360.0)
    col = (np.arange(width) + 0.5) / width
    row = (np.arange(rows) + 0.5) / rows
    bearing = -2.0 * math.pi * col  # clockwise columns
    elev = np.radians(band_deg) - np.radians(2 * band_deg) * row
    b, e = np.meshgrid(bearing, elev)
    d = np.stack([np.cos(e) * np.cos(b), np.cos(e) * np.sin(b), np.sin(e)], axis=-1)
    t = math.radians(tilt_deg)
    pitch = np.array([[math.cos(t), 0, math.sin(t)], [0, 1, 0], [-math.sin(t), 0, math.cos(t)]])
    h = math.radians(heading_deg)
    yaw = np.array([[math.cos(h), -math.sin(h), 0], [math.sin(h), math.cos(h), 0], [0, 0, 1]])
    d = d @ (yaw @ pitch).T
    p = np.asarray(position, dtype=np.float64)
    size = np.asarray(room, dtype=np.float64)
    # distance to the first plane hit along each ray, per axis
    with np.errstate(divide="ignore", invalid="ignore"):
        tt = np.where(d > 0, (size - p) / d, np.where(d < 0, -p / d, np.inf))
    axis = np.argmin(tt, axis=-1)
    dist = np.take_along_axis(tt, axis[..., None], axis=-1)[..., 0]
    hit = p + d * dist[..., None]
    pos_side = np.take_along_axis(d, axis[..., None], axis=-1)[..., 0] > 0
    face = axis * 2 + pos_side.astype(int)  # 0..5
    # the two coordinates along the face
    u = np.where(axis == 0, hit[..., 1] / size[1], hit[..., 0] / size[0])
    v = np.where(axis == 2, hit[..., 1] / size[1], hit[..., 2] / size[2])
    n = textures.shape[1]
    img = np.zeros(u.shape)
    for k in range(6):
        sel = face == k
        img[sel] = ndimage.map_coordinates(
            textures[k % len(textures)], [v[sel] * (n - 1), u[sel] * (n - 1)], order=1, mode="nearest"
        )
    rgb = np.repeat((img * 255).round().astype(np.uint8)[..., None], 3, axis=2)
    return Panorama(rgb, meta={"elevation_deg": (band_deg, -band_deg)})
