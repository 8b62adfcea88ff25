"""Test helper: an exact 2D ray caster over wall segments, and a tiny CARMEN FLASER parser."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np

from fingerloc.sensors import Scan

CARMEN_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "carmen"


def cast(walls, bearings, *, pose=(0.0, 0.0, 0.0), max_range=10.0, reflect=None):
    """Exact ranges (m) of rays from ``pose`` at ``bearings`` (rad, robot frame) against ``walls``.

    ``walls``: sequence of ((x0, y0), (x1, y1)); ``reflect``: per-wall intensity (default 100).
    Returns (ranges with inf for no hit, intensities).
    """
    x, y, th = pose
    w = np.asarray(walls, dtype=float)  # (m, 2, 2)
    a = np.asarray(bearings, dtype=float) + th
    d = np.column_stack([np.cos(a), np.sin(a)])  # (n, 2)
    p0 = w[:, 0] - [x, y]
    e = w[:, 1] - w[:, 0]  # (m, 2)
    # solve t d = p0 + s e  ->  t d - s e = p0
    den = d[:, None, 0] * (-e[None, :, 1]) - d[:, None, 1] * (-e[None, :, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (p0[None, :, 0] * (-e[None, :, 1]) - p0[None, :, 1] * (-e[None, :, 0])) / den
        s = (d[:, None, 0] * p0[None, :, 1] - d[:, None, 1] * p0[None, :, 0]) / den
    ok = (np.abs(den) > 1e-12) & (t > 1e-9) & (s >= 0) & (s <= 1)
    t = np.where(ok, t, np.inf)
    k = np.argmin(t, axis=1)
    r = t[np.arange(len(a)), k]
    refl = np.full(len(w), 100.0) if reflect is None else np.asarray(reflect, dtype=float)
    inten = np.where(np.isfinite(r), refl[k], 0.0)
    r = np.where(r >= max_range, np.inf, r)
    return r, inten


def make_scan(walls, *, n=720, fov_deg=360.0, pose=(0.0, 0.0, 0.0), noise=0.0, seed=0, reflect=None, max_range=10.0):
    if fov_deg >= 360:
        b = -np.pi + (np.arange(n) + 0.5) * 2 * np.pi / n
    else:
        h = np.deg2rad(fov_deg) / 2
        b = np.linspace(-h, h, n)
    r, inten = cast(walls, b, pose=pose, max_range=max_range, reflect=reflect)
    if noise:
        r = r + np.random.default_rng(seed).normal(0, noise, r.size)
    return Scan(r, b, max_range=max_range, intensities=inten)


def box(cx, cy, hw, hh):
    c = [(cx - hw, cy - hh), (cx + hw, cy - hh), (cx + hw, cy + hh), (cx - hw, cy + hh)]
    return [(c[i], c[(i + 1) % 4]) for i in range(4)]


def read_flaser(name: str, count: int, every: int = 1):
    """Parse up to ``count`` FLASER scans (every ``every``-th) of a CARMEN log in CARMEN_DIR."""
    out = []
    path = CARMEN_DIR / name
    with gzip.open(path, "rt") as fh:
        k = 0
        for line in fh:
            if not line.startswith("FLASER"):
                continue
            k += 1
            if (k - 1) % every:
                continue
            f = line.split()
            n = int(f[1])
            r = np.array(f[2 : 2 + n], dtype=float)
            x, y, th = (float(v) for v in f[2 + n : 5 + n])
            b = np.linspace(-np.pi / 2, np.pi / 2, n)
            mr = float(r.max()) if r.max() > 49 else 81.83
            out.append(Scan(r, b, max_range=mr, pose=(x, y, th)))
            if len(out) >= count:
                break
    return out


# ---------------------------------------------------------------------------
# synthetic panoramas


def hsv_rgb(h_deg, s, v):
    import colorsys

    return np.array(colorsys.hsv_to_rgb((h_deg % 360) / 360.0, s, v))


def paint_panorama(
    *,
    w=720,
    h=160,
    wall_cols=(60, 250, 430, 610),
    wall_gains=(1.0, 0.78, 0.92, 0.66),
    door=(300, 318),
    patches=((120, 150, 10.0), (480, 500, 210.0), (660, 690, 120.0)),
    shading=True,
    sun=True,
    noise=0.015,
    jpeg=None,
    seed=0,
):
    """A synthetic indoor panorama with known vertical edges and colour patches.

    Columns are bearings (720 columns: 0.5 deg each). Walls of a beige, low-saturation paint change
    brightness at ``wall_cols`` (vertical edges over the full height); a darker door frame spans
    ``door`` columns from the floor to 80 % of the height (two more edges); ``patches`` are
    saturated posters ``(col0, col1, hue_deg)`` between 25 % and 65 % of the height (their sides are
    vertical edges too).
    Returns (image float (h, w, 3), edge columns (boundaries), patch centre columns, patch hues).
    """
    rng = np.random.default_rng(seed)
    base = np.array([0.80, 0.76, 0.68])  # beige, saturation 0.15
    img = np.empty((h, w, 3))
    gains = np.empty(w)
    cols = list(wall_cols)
    for k in range(len(cols)):
        a, b = cols[k], cols[(k + 1) % len(cols)]
        idx = np.arange(a, b if b > a else b + w) % w
        gains[idx] = wall_gains[k]
    img[:] = base * gains[None, :, None]
    ceil = int(0.15 * h)
    floor = int(0.8 * h)
    img[:ceil] = [0.92, 0.92, 0.92]
    img[floor:] = [0.35, 0.33, 0.32]
    edges = list(cols)
    if door is not None:
        d0, d1 = door
        img[int(0.25 * h) : floor, d0:d1] = [0.45, 0.38, 0.30]
        edges += [d0, d1]
    centres, hues = [], []
    for c0, c1, hue in patches:
        img[int(0.25 * h) : int(0.65 * h), c0:c1] = hsv_rgb(hue, 0.75, 0.75)
        edges += [c0, c1]
        centres.append((c0 + c1) / 2)
        hues.append(hue)
    if sun:
        # a bright sun patch with slanted sides on floor and wall, and a soft slanted shadow
        yy, xx = np.mgrid[0:h, 0:w]
        par = (xx - 0.8 * yy > 330) & (xx - 0.8 * yy < 390) & (yy > 0.45 * h)
        img[par] *= 1.45
        sh = (xx + 0.7 * yy > 520) & (xx + 0.7 * yy < 600) & (yy > 0.5 * h)
        img[sh] *= 0.7
    if shading:
        yy = (np.arange(h) - h / 2) / (h / 2)
        xx = np.arange(w) / w * 2 * np.pi
        img *= (1 - 0.35 * yy**2)[:, None, None] * (1 + 0.2 * np.sin(xx + 1.0))[None, :, None]
    img = img + rng.normal(0, noise, img.shape)
    img = np.clip(img, 0, 1)
    if jpeg is not None:
        import io

        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray((img * 255).round().astype(np.uint8)).save(buf, format="JPEG", quality=jpeg)
        img = np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGB"), dtype=np.float64) / 255.0
    return img, np.array(edges, dtype=float), np.array(centres), np.array(hues)


def make_donut(pano_img, *, size=480, r_in=40.0, r_out=220.0, bearing_offset=0.0, mirror=False):
    """Forward-render the donut image an equiangular mirror would give of a panorama (nearest pixel).

    Same convention as ``unwarp_omni``: top panorama row at ``r_out``; column ``j`` centre at bearing
    ``offset - 2 pi (j + 0.5) / w``; bearing ``b`` at image angle ``psi = +-(b - offset)`` counter-clockwise
    on the displayed image.
    """
    h, w, _ = pano_img.shape
    cx = cy = size / 2
    yy, xx = np.mgrid[0:size, 0:size] + 0.5
    dx, dy = xx - cx, -(yy - cy)
    rad = np.hypot(dx, dy)
    psi = np.arctan2(dy, dx)
    beta = (-psi if mirror else psi) + bearing_offset
    col = np.mod(-(beta - bearing_offset) / (2 * np.pi) * w, w)
    row = (r_out - rad) / (r_out - r_in) * h
    ok = (rad >= r_in) & (rad <= r_out)
    out = np.zeros((size, size, 3))
    ci = np.clip(np.floor(col).astype(int), 0, w - 1)
    ri = np.clip(np.floor(row).astype(int), 0, h - 1)
    out[ok] = pano_img[ri[ok], ci[ok]]
    return out, (cx, cy)


# the same room with a doorway in its right wall (y in [-0.4, 0.5]) and a corridor wall behind it
DOOR = [
    ((-1.5, -1.2), (2.5, -1.2)),
    ((2.5, -1.2), (2.5, -0.4)),
    ((2.5, 0.5), (2.5, 1.8)),
    ((2.5, 1.8), (-1.5, 1.8)),
    ((-1.5, 1.8), (-1.5, -1.2)),
    ((4.0, -5.0), (4.0, 5.0)),
]
