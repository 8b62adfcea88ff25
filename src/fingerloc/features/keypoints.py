"""Local features of a panorama: upright keypoints and gradient-histogram descriptors (term ``K``).

Two panoramas taken at different spots of one room share many distinctive
local patches (picture frames, furniture corners, window mullions, door
handles) that a global histogram blurs. This module finds such patches and
describes each one, so that :mod:`fingerloc.terms.keypoints` can count the
patches two views share.

Pipeline (numpy / scipy only; written for this project):

1. **Grey band at a fixed resolution.** The panorama (the band of elevations
   that ``fingerloc features`` reads, -45..+45 deg for a full 2:1 photo) is
   resampled to ``width`` columns (default 1440: 4 px per degree) so that
   scales mean the same angles whatever the photo's size; luminance, then an
   exposure normalisation: a percentile stretch (1st..99th) followed by a
   square root, so that a dark or a bright exposure of one scene gives about
   the same grey image.
2. **Detector: difference of Gaussians.** Gaussian blurs at ``sigmas``
   (pixels; rows clamp at the band's edges, columns wrap around the 360 deg
   seam), differences of consecutive blurs, and the local extrema of the
   absolute difference over 3 x 3 x 3 neighbours (scale, row, column) at the
   inner scales. Edge-like responses are dropped (ratio of the principal
   curvatures of the difference image above ``edge_ratio``, as in SIFT). The
   ``n_keypoints`` strongest are kept, at most ``ceil(2 n / sectors)`` per
   sector of ``360 / sectors`` degrees, so that one busy wall does not take
   them all.
3. **Upright descriptor** (panoramas are upright: no orientation
   assignment): a ``grid x grid`` array of cells around the keypoint, each
   ``cell_factor * sigma`` pixels wide, holding a histogram of gradient
   orientations (``orientations`` bins, linear interpolation between bins,
   weighted by the gradient magnitude, pooled over the cell by a Gaussian),
   weighted by a Gaussian window over the cells; the vector is L2-normalised,
   clipped at 0.2, renormalised and quantised to ``uint8`` (x 512, as SIFT).
   With the defaults: 4 x 4 cells x 8 orientations = 128 numbers.

Keypoint positions are stored as bearings (radians, the panorama's
convention: counter-clockwise from the robot's bearing 0, whatever the
column order) and elevations as a fraction of the band's height (0 = top).
"""

from __future__ import annotations

import base64
import itertools
import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._types import FArray
from ..errors import DataFormatError, InvalidParameterError
from ..keypoints import Keypoints

__all__ = [
    "KeypointParams",
    "Keypoints",
    "decode_keypoints",
    "encode_keypoints",
    "extract_keypoints",
    "grey_band",
    "keypoint_arrays",
    "keypoints_from_arrays",
    "match_keypoints",
]

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, slots=True)
class KeypointParams:
    """Parameters of :func:`extract_keypoints` (module docstring).

    Attributes
    ----------
    width : int, default 1440
        Columns the band is resampled to before detection (4 px per degree).
    n_keypoints : int, default 500
        Keep at most this many keypoints.
    sigmas : tuple of float
        Blur levels (pixels at ``width``); extrema are searched at the
        differences between inner levels.
    edge_ratio : float, default 10
        Drop a keypoint whose principal curvatures differ by more than this ratio.
    min_contrast : float, default 0.004
        Least absolute difference of Gaussians (grey in [0, 1]).
    sectors : int, default 36
        Bearing sectors for spreading the keypoints.
    grid : int, default 4
        Cells per side of the descriptor.
    orientations : int, default 8
        Orientation bins per cell.
    cell_factor : float, default 3.0
        Cell width in units of the keypoint's sigma.
    """

    width: int = 1440
    n_keypoints: int = 500
    sigmas: tuple[float, ...] = (1.6, 2.26, 3.2, 4.53, 6.4, 9.05)
    edge_ratio: float = 10.0
    min_contrast: float = 0.004
    sectors: int = 36
    grid: int = 4
    orientations: int = 8
    cell_factor: float = 3.0

    def __post_init__(self) -> None:
        for name in ("width", "n_keypoints", "sectors", "grid", "orientations"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise InvalidParameterError(f"{name} must be an integer >= 1, got {v!r}")
        if self.width < 64:
            raise InvalidParameterError(f"width must be >= 64 columns, got {self.width}")
        s = tuple(float(x) for x in self.sigmas)
        if len(s) < 4 or any(not (math.isfinite(x) and x > 0) for x in s) or any(b <= a for a, b in itertools.pairwise(s)):
            raise InvalidParameterError(f"sigmas must be at least 4 increasing positive numbers, got {self.sigmas!r}")
        object.__setattr__(self, "sigmas", s)
        for name in ("edge_ratio", "cell_factor"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise InvalidParameterError(f"{name} must be a positive number, got {getattr(self, name)!r}")
        if not (math.isfinite(self.min_contrast) and self.min_contrast >= 0):
            raise InvalidParameterError(f"min_contrast must be >= 0, got {self.min_contrast!r}")

    @property
    def size(self) -> int:
        """Length of one descriptor."""
        return self.grid * self.grid * self.orientations


def _params(params: dict[str, Any]) -> KeypointParams:
    known = {f.name for f in fields(KeypointParams)}
    for k in params:
        if k not in known:
            raise InvalidParameterError(f"unknown keypoint parameter {k!r} (known: {', '.join(sorted(known))})")
    return KeypointParams(**params)


# ---------------------------------------------------------------------------
# grey band


def grey_band(image: Any, width: int = 1440) -> FArray:
    """Exposure-normalised grey image of a panorama band at ``width`` columns, float64 in [0, 1].

    ``image``: RGB ``(h, w, 3)`` (uint8 or float in [0, 1]) or grey ``(h, w)``.
    Resampled (bilinear, the columns wrapping around) so that the output has
    ``width`` columns and ``round(h * width / w)`` rows; then the luminance
    is stretched between its 1st and 99th percentiles and square-rooted.
    """
    from scipy import ndimage

    img = np.asarray(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (3, 4)):
        raise DataFormatError(f"expected an RGB or grey image, got an array of shape {img.shape}")
    f = img.astype(np.float64)
    if img.dtype == np.uint8 or (f.size and f.max() > 1.0):
        f = f / 255.0
    lum = f[:, :, :3] @ np.array([0.299, 0.587, 0.114]) if f.ndim == 3 else f
    h, w = lum.shape
    if w < 16 or h < 4:
        raise DataFormatError(f"panorama band too small for keypoints: {w}x{h} pixels")
    if not np.all(np.isfinite(lum)):
        raise DataFormatError("the image holds non-finite values")
    new_h = max(8, round(h * width / w))
    if (new_h, width) != (h, w):
        if w > width and w % width == 0 and h % (w // width) == 0:  # whole-factor shrink: block means
            k = w // width
            lum = lum.reshape(h // k, k, width, k).mean(axis=(1, 3))
        else:
            if w > width:  # anti-alias before sampling
                s = 0.5 * w / width
                lum = ndimage.gaussian_filter(lum, (s * h / new_h * width / w, s), mode=("nearest", "wrap"))
            rows = (np.arange(new_h) + 0.5) * h / new_h - 0.5
            cols = (np.arange(width) + 0.5) * w / width - 0.5
            rr, cc = np.meshgrid(rows, cols, indexing="ij")
            # pad one column on each side so that bilinear sampling wraps
            padded = np.concatenate([lum[:, -1:], lum, lum[:, :1]], axis=1)
            lum = ndimage.map_coordinates(padded, [rr, cc + 1.0], order=1, mode="nearest")
    lo, hi = np.percentile(lum, [1.0, 99.0])
    if hi - lo < 1e-6:
        return np.zeros_like(lum)
    out: FArray = np.sqrt(np.clip((lum - lo) / (hi - lo), 0.0, 1.0))
    return out


# ---------------------------------------------------------------------------
# detector and descriptor


_MODES = ("nearest", "wrap")


def _detect(g: FArray, p: KeypointParams) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], FArray, list[FArray]]:
    """DoG extrema: rows, columns, level (index of the inner difference), response; and the blurred images."""
    from scipy import ndimage

    blurs = [ndimage.gaussian_filter(g, s, mode=_MODES) for s in p.sigmas]
    dog = np.stack([b1 - b0 for b0, b1 in itertools.pairwise(blurs)])  # (L, h, w)
    a = np.abs(dog)
    mx = ndimage.maximum_filter(a, size=(3, 3, 3), mode=("constant", "nearest", "wrap"), cval=np.inf)
    cand = (a == mx) & (a > p.min_contrast)
    cand[0] = cand[-1] = False
    cand[:, :2] = cand[:, -2:] = False  # the band's top and bottom rows: no full neighbourhood
    lev, r, c = np.nonzero(cand)
    if lev.size == 0:
        e = np.empty(0, dtype=np.int64)
        return e, e, e, np.empty(0), blurs
    # principal-curvature ratio of the difference image (SIFT's edge test)
    w = g.shape[1]
    cm, cp = (c - 1) % w, (c + 1) % w
    D = dog
    dxx = D[lev, r, cp] + D[lev, r, cm] - 2 * D[lev, r, c]
    dyy = D[lev, r + 1, c] + D[lev, r - 1, c] - 2 * D[lev, r, c]
    dxy = 0.25 * (D[lev, r + 1, cp] - D[lev, r + 1, cm] - D[lev, r - 1, cp] + D[lev, r - 1, cm])
    tr, det = dxx + dyy, dxx * dyy - dxy * dxy
    er = p.edge_ratio
    ok = (det > 0) & (tr * tr * er < (er + 1) ** 2 * det)
    return r[ok], c[ok], lev[ok], a[lev[ok], r[ok], c[ok]], blurs


def _spread(cols: NDArray[np.int64], resp: FArray, width: int, n: int, sectors: int) -> NDArray[np.int64]:
    """Indices of the ``n`` strongest, at most ``ceil(2 n / sectors)`` per bearing sector."""
    order = np.argsort(-resp, kind="stable")
    sector = (cols[order] * sectors) // width
    # rank of each candidate within its sector, in order of response
    rank = np.empty(order.size, dtype=np.int64)
    counts = np.zeros(sectors, dtype=np.int64)
    for i, s in enumerate(sector):
        rank[i] = counts[s]
        counts[s] += 1
    quota = math.ceil(2 * n / sectors)
    keep = order[rank < quota]
    return keep[:n]


def _describe(
    blur: FArray, rows: FArray, cols: FArray, sigma: float, p: KeypointParams
) -> FArray:
    """Descriptors (float, unnormalised) of keypoints detected at ``sigma`` on the blurred image ``blur``."""
    from scipy import ndimage

    h, w = blur.shape
    gx = 0.5 * (np.roll(blur, -1, axis=1) - np.roll(blur, 1, axis=1))
    gy = np.zeros_like(blur)
    gy[1:-1] = 0.5 * (blur[2:] - blur[:-2])
    mag = np.hypot(gx, gy)
    ang = np.mod(np.arctan2(gy, gx), TWO_PI) * (p.orientations / TWO_PI)  # in bins
    b0 = np.floor(ang).astype(np.int64) % p.orientations
    frac = ang - np.floor(ang)
    cell = p.cell_factor * sigma
    gpos = (np.arange(p.grid) - (p.grid - 1) / 2.0) * cell  # cell centres, pixels from the keypoint
    win = np.exp(-0.5 * (gpos / (0.5 * p.grid * cell)) ** 2)
    weight = (win[:, None] * win[None, :]).reshape(-1)  # (grid * grid,)
    rr = np.clip(np.round(rows[:, None, None] + gpos[None, :, None]), 0, h - 1).astype(np.int64)
    cc = np.round(cols[:, None, None] + gpos[None, None, :]).astype(np.int64) % w
    rr, cc = np.broadcast_arrays(rr, cc)
    out = np.empty((rows.size, p.grid * p.grid, p.orientations))
    for o in range(p.orientations):
        chan = np.where(b0 == o, mag * (1.0 - frac), 0.0) + np.where((b0 + 1) % p.orientations == o, mag * frac, 0.0)
        pooled = ndimage.gaussian_filter(chan, 0.5 * cell, mode=_MODES)
        out[:, :, o] = pooled[rr, cc].reshape(rows.size, -1)
    out *= weight[None, :, None]
    return out.reshape(rows.size, -1)


def _quantise(v: FArray) -> NDArray[np.uint8]:
    v = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    v = np.minimum(v, 0.2)
    v = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    return np.minimum(np.round(v * 512.0), 255).astype(np.uint8)


def extract_keypoints(pano: Any, **params: Any) -> Keypoints:
    """Keypoints and descriptors of a panorama band (module docstring).

    Parameters
    ----------
    pano : Panorama
        The band (``fingerloc.sensors.Panorama``): its columns give the
        bearings through ``column_bearing``.
    **params
        Fields of :class:`KeypointParams`.
    """
    p = _params(params)
    img = np.asarray(pano.image)
    w0 = img.shape[1]
    g = grey_band(img, p.width)
    h, w = g.shape
    r, c, lev, resp, blurs = _detect(g, p)
    keep = _spread(c, resp, w, p.n_keypoints, p.sectors)
    r, c, lev = r[keep], c[keep], lev[keep]
    desc = np.zeros((r.size, p.size))
    for L in np.unique(lev):
        sel = lev == L
        # the difference between blur L and L + 1: its scale is about the geometric mean
        sigma = math.sqrt(p.sigmas[L] * p.sigmas[L + 1])
        desc[sel] = _describe(blurs[L + 1], r[sel].astype(np.float64), c[sel].astype(np.float64), sigma, p)
    q = _quantise(desc) if r.size else np.zeros((0, p.size), dtype=np.uint8)
    order = np.lexsort((r, c))
    col0 = (c[order] + 0.5) * w0 / w
    sig = np.array([math.sqrt(p.sigmas[L] * p.sigmas[L + 1]) for L in lev[order]]) * 360.0 / w
    kps = Keypoints(
        bearing=np.asarray(pano.column_bearing(col0)) if r.size else np.empty(0),
        elevation=(r[order] + 0.5) / h,
        scale=sig,
        desc=q[order],
    )
    # positions on the grid of the stored encoding, so that writing and reading back changes nothing
    return decode_keypoints(encode_keypoints(kps))


# ---------------------------------------------------------------------------
# matching


def match_keypoints(a: Keypoints, b: Keypoints, *, ratio: float = 0.8, max_elevation: float = 0.1) -> NDArray[np.int64]:
    """Matches between two views, shape ``(m, 2)``: index pairs ``(i in a, j in b)``.

    Distances are Euclidean between root-normalised descriptors
    (:meth:`Keypoints.unit_descriptors`). A pair is kept when ``j`` is
    ``i``'s nearest neighbour in ``b``, ``i`` is ``j``'s nearest in ``a``,
    ``i``'s nearest distance is below ``ratio`` times its second nearest (any
    distance passes when ``b`` has a single keypoint), and their elevations
    (band fractions) differ by at most ``max_elevation`` (a loose geometric
    check: the camera height hardly changes between spots; bearings are not
    checked, parallax moves them). The term ``K`` counts these matches
    (:func:`fingerloc.terms.keypoints.match_counts`, the same rule on many views at once).
    """
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if a.dim != b.dim:
        raise InvalidParameterError(f"keypoints: descriptors of length {a.dim} and {b.dim} cannot be matched")
    d = np.sqrt(np.maximum(2.0 - 2.0 * (a.unit_descriptors().astype(np.float64) @ b.unit_descriptors().T), 0.0))
    j = np.argmin(d, axis=1)
    i_back = np.argmin(d, axis=0)
    rows = np.arange(len(a))
    d1 = d[rows, j]
    d2 = np.partition(d, 1, axis=1)[:, 1] if len(b) > 1 else np.full(len(a), np.inf)
    ok = (i_back[j] == rows) & (d1 < ratio * d2) & (np.abs(a.elevation - b.elevation[j]) <= max_elevation)
    i = np.flatnonzero(ok)
    return np.stack([i, j[i]], axis=1).astype(np.int64)


# ---------------------------------------------------------------------------
# compact encoding (JSON Lines, the place database)


def keypoint_arrays(k: Keypoints) -> tuple[NDArray[np.uint16], NDArray[np.uint8]]:
    """The stored arrays of :func:`encode_keypoints`: positions ``(n, 3)`` little-endian uint16, descriptors ``(n, dim)``."""
    bdeg = np.mod(np.rad2deg(k.bearing), 360.0)
    pos = np.stack(
        [
            np.round(bdeg * 65536.0 / 360.0).astype(np.int64) % 65536,
            np.clip(np.round(k.elevation * 65535.0), 0, 65535).astype(np.int64),
            np.clip(np.round(k.scale * 1000.0), 0, 65535).astype(np.int64),
        ],
        axis=1,
    ).astype("<u2")
    return pos, np.ascontiguousarray(k.desc, dtype=np.uint8)


def keypoints_from_arrays(pos: Any, desc: Any, n: int, dim: int) -> Keypoints:
    """The inverse of :func:`keypoint_arrays` (flat buffers of ``3 n`` uint16 and ``n dim`` uint8)."""
    pos = np.asarray(pos, dtype="<u2").reshape(-1)
    desc = np.asarray(desc, dtype=np.uint8).reshape(-1)
    if n < 0 or dim < 0 or pos.size != 3 * n or desc.size != n * dim:
        raise DataFormatError(f"keypoints: {n} keypoints of {dim} numbers do not fit the stored arrays")
    p = pos.reshape(n, 3).astype(np.float64)
    bdeg = p[:, 0] * 360.0 / 65536.0
    return Keypoints(
        bearing=np.deg2rad(np.where(bdeg >= 180.0, bdeg - 360.0, bdeg)),
        elevation=p[:, 1] / 65535.0,
        scale=p[:, 2] / 1000.0,
        desc=desc.reshape(n, dim),
    )


def encode_keypoints(k: Keypoints) -> dict[str, Any]:
    """A JSON-ready dict: ``{"n", "dim", "pos", "desc"}`` (docs/FORMATS.md).

    ``pos``: base64 of little-endian uint16 triples per keypoint: bearing in
    units of 360/65536 deg (``[0, 360)``), elevation in units of 1/65535 of the
    band, scale in units of 1/1000 deg; ``desc``: base64 of the ``n x dim``
    uint8 descriptors, row by row.
    """
    pos, desc = keypoint_arrays(k)
    return {
        "n": len(k),
        "dim": k.dim,
        "pos": base64.b64encode(pos.tobytes()).decode("ascii"),
        "desc": base64.b64encode(desc.tobytes()).decode("ascii"),
    }


def decode_keypoints(rec: Any) -> Keypoints:
    """The inverse of :func:`encode_keypoints` (positions rounded as stored)."""
    try:
        n, dim = int(rec["n"]), int(rec["dim"])
        pos = np.frombuffer(base64.b64decode(rec["pos"], validate=True), dtype="<u2")
        desc = np.frombuffer(base64.b64decode(rec["desc"], validate=True), dtype=np.uint8)
    except (KeyError, TypeError, ValueError) as err:
        raise DataFormatError(f'keypoints: expected {{"n", "dim", "pos", "desc"}} with base64 arrays ({err})') from err
    return keypoints_from_arrays(pos, desc, n, dim)
