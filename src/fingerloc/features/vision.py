"""Vision features from a raw panoramic image: vertical edges and colour patches (docs/METHOD.md §1).

- :func:`unwarp_omni` turns the donut image of an omnidirectional camera with
  an equiangular mirror (image radius linear in elevation) into a
  :class:`~fingerloc.sensors.Panorama` (columns = bearing, rows = elevation).
- :func:`vertical_edges` finds bearings where the image changes across the
  columns consistently over a large part of the elevation range: wall
  corners, door frames, furniture and poster sides. It works on log
  luminance plus chromaticity (smooth lens shading and soft lighting give no
  gradient; an edge between two equally bright colours still counts),
  smoothed along the elevation (vertical edges stay sharp, noise and JPEG
  blocks average out). A pixel is an edge pixel when its column gradient is
  a row-wise maximum above a threshold that adapts to each row's noise (dark
  floors are noisier in log units), not much weaker than a nearby stronger
  gradient (ringing), and of the column's dominant polarity. A column is an
  edge when such pixels form an unbroken vertical run over ``min_extent`` of
  the rows, or cover ``min_support`` of them in all; slanted edges of sun
  patches and shadows, text and noise do not. Non-maximum suppression keeps
  one bearing per edge.
- :func:`colour_patches` segments saturated regions by hue (after a robust
  white balance on the brightest dull pixels) and reports each region's
  bearing and hue. Low-saturation walls, dark pixels (unreliable hue) and
  blown-out pixels are ignored; regions of one hue overlapping in bearing
  merge; regions join across the panorama's seam.

Every bearing is in radians, robot frame, wrapped to ``[-pi, pi)``; hues are
in degrees, ``[0, 360)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from .._types import FArray
from ..angles import TWO_PI, wrap
from ..errors import InvalidParameterError
from ..observation import FULL_FOV, Observation
from ..sensors import Panorama, Scan
from ._params import _check_positive, _from_kwargs
from ._vision_kernels import edge_columns, edge_inputs
from .appearance import (
    APPEARANCE_VERSIONS,
    PROFILE_CHANNELS,
    PROFILE_DECIMALS,
    AppearanceParams,
    appearance_and_profile,
    appearance_descriptor,
    column_profile,
    profile_correlation,
    profile_rotation_deg,
)
from .colour import rgb_to_hsv, white_balance

__all__ = [
    "APPEARANCE_VERSIONS",
    "PHOTO_EDGE_PARAMS",
    "PROFILE_CHANNELS",
    "PROFILE_DECIMALS",
    "AppearanceParams",
    "EdgeParams",
    "PatchParams",
    "VisionFeatures",
    "appearance_descriptor",
    "colour_patches",
    "column_profile",
    "extract_vision_features",
    "observation_from_views",
    "profile_correlation",
    "profile_rotation_deg",
    "rgb_to_hsv",
    "unwarp_omni",
    "vertical_edges",
]


#: Vertical-edge parameters for real photographs (full equirectangular panoramas): one edge per
#: 3 deg, the 12 strongest. Chosen on hand-labelled campus photos (docs/RESULTS.md, "Real panoramas").
PHOTO_EDGE_PARAMS: dict[str, Any] = {"nms_deg": 3.0, "max_edges": 12}


# ---------------------------------------------------------------------------
# omnidirectional image -> panorama


def unwarp_omni(
    image: ArrayLike,
    center: tuple[float, float],
    r_in: float,
    r_out: float,
    *,
    width: int | None = None,
    height: int | None = None,
    bearing_offset: float = 0.0,
    mirror: bool = False,
    outer_is_up: bool = True,
) -> Panorama:
    """Unwarp the donut image of an equiangular omnidirectional camera into a panorama.

    With an equiangular mirror every pixel covers the same view angle, so the
    image radius grows linearly with elevation: the ring ``r_in..r_out`` maps
    linearly onto the rows of the panorama.

    Parameters
    ----------
    image : array_like, shape (H, W, 3) or (H, W)
        The raw image, ``uint8`` or float in ``[0, 1]``; grey images are
        repeated over three channels.
    center : (x, y)
        Mirror centre in pixel coordinates (``x`` = column, ``y`` = row; pixel
        ``(i, j)`` has its centre at ``x = j + 0.5``, ``y = i + 0.5``).
    r_in, r_out : float
        Inner and outer radius of the useful ring, pixels, ``0 <= r_in < r_out``.
    width : int, optional
        Panorama columns; default: the circumference of the middle of the
        ring rounded to a multiple of 360, between 360 and 1440.
    height : int, optional
        Panorama rows; default ``round(r_out - r_in)`` (one row per pixel of
        radius).
    bearing_offset : float, default 0
        Bearing (radians) seen along the image's ``+x`` axis (to the right of
        the centre).
    mirror : bool, default False
        False: bearings grow counter-clockwise on the image as displayed (row
        axis pointing down), i.e. the image shows the scene as seen from
        above. True: they grow clockwise (the scene as seen from below, the
        usual view of a camera looking up into the mirror).
    outer_is_up : bool, default True
        True when the outer ring sees the highest elevations (the top row of
        the panorama).

    Returns
    -------
    Panorama
        ``clockwise=True``: column 0's left edge at ``bearing_offset`` ... see
        :class:`~fingerloc.sensors.Panorama`; ``meta`` records the geometry.
    """
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise InvalidParameterError(f"image must be (H, W, 3) RGB or (H, W) grey, got shape {img.shape}")
    img = img[:, :, :3]
    if img.dtype == np.uint8:
        f = img.astype(np.float32) / 255.0
    else:
        f = np.clip(img.astype(np.float32), 0.0, 1.0)
    cx, cy = (float(v) for v in center)
    if not (np.isfinite(cx) and np.isfinite(cy)):
        raise InvalidParameterError(f"center must be two finite pixel coordinates, got {center!r}")
    if not (np.isfinite(r_in) and np.isfinite(r_out) and 0 <= r_in < r_out):
        raise InvalidParameterError(f"radii must satisfy 0 <= r_in < r_out, got r_in={r_in!r}, r_out={r_out!r}")
    hh, ww = f.shape[:2]
    if cx - r_out < -0.5 * ww or cx + r_out > 1.5 * ww or cy - r_out < -0.5 * hh or cy + r_out > 1.5 * hh:
        raise InvalidParameterError(
            f"the mirror ring (center {cx:g}, {cy:g}, r_out {r_out:g}) lies mostly outside the {ww}x{hh} image"
        )
    if width is None:
        width = int(np.clip(round(np.pi * (r_in + r_out) / 360.0) * 360, 360, 1440))
    if isinstance(width, bool) or not isinstance(width, (int, np.integer)) or width < 8:
        raise InvalidParameterError(f"width must be an integer >= 8, got {width!r}")
    h = round(r_out - r_in) if height is None else height
    if isinstance(h, bool) or not isinstance(h, (int, np.integer)) or h < 2:
        raise InvalidParameterError(f"height must be an integer >= 2, got {height!r}")
    # column centres: bearing decreases with the column (clockwise panorama)
    beta = bearing_offset - TWO_PI * (np.arange(width) + 0.5) / width
    # image angle psi, counter-clockwise on the displayed image (y down -> minus sign)
    psi = (beta - bearing_offset) * (-1.0 if mirror else 1.0)
    frac = (np.arange(h) + 0.5) / h  # 0 at the top row
    rad = r_out - frac * (r_out - r_in) if outer_is_up else r_in + frac * (r_out - r_in)
    xs = cx + rad[:, None] * np.cos(psi)[None, :] - 0.5
    ys = cy - rad[:, None] * np.sin(psi)[None, :] - 0.5
    out = np.empty((h, width, 3), dtype=np.float32)
    for c in range(3):
        out[:, :, c] = ndimage.map_coordinates(f[:, :, c], [ys, xs], order=1, mode="nearest")
    np.clip(out, 0.0, 1.0, out=out)
    meta: dict[str, object] = {
        "source": "omni",
        "center": (cx, cy),
        "r_in": float(r_in),
        "r_out": float(r_out),
        "mirror": bool(mirror),
    }
    return Panorama(out, bearing_offset=float(bearing_offset), clockwise=True, meta=meta)


# ---------------------------------------------------------------------------
# vertical edges


@dataclass(frozen=True, slots=True)
class EdgeParams:
    """Tuning of :func:`vertical_edges`.

    Parameters
    ----------
    min_extent : float, default 0.12
        An edge is a vertical run of edge pixels over at least this part of
        the rows (``0..1``)...
    min_support : float, default 0.3
        ...or edge pixels (not necessarily contiguous, e.g. a door frame
        partly hidden by a desk) over at least this part of the rows.
    vertical_smooth : float, default 0.015
        Gaussian smoothing along the elevation, as a part of the height,
        before differentiating (noise and JPEG blocks average out).
    min_contrast : float, default 0.08
        Smallest step counted across an edge, in log-luminance units (0.08:
        about 8 % brightness change), after undoing the smoothing.
    noise_k : float, default 4
        The gradient threshold is at least this many robust standard
        deviations of the image's column gradients.
    chroma_weight : float, default 2
        Weight of the chromaticity (r, g) gradient beside the log-luminance one.
    smooth_px : float, default 1
        Gaussian smoothing along the rows before differentiating, pixels
        (scaled with the panorama width relative to 720 columns).
    slant_deg : float, default 0.5
        An edge pixel counts for columns up to this far in bearing (slightly
        slanted or aliased edges); at least one column.
    nms_deg : float, default 1.25
        Two edges closer than this keep only the stronger one.
    relative_min : float, default 0.25
        In each row, a gradient maximum weaker than this part of the strongest
        gradient within ``relative_deg`` is ignored (ringing, JPEG blocks).
    relative_deg : float, default 4
        Reach of that comparison, degrees.
    max_edges : int, default 0
        Keep only this many edges, the strongest (largest support, then
        gradient); 0 keeps every edge. Real photographs show many weak edges
        (shelves, posters, mullions); the strongest are the stable ones.
    """

    min_extent: float = 0.12
    min_support: float = 0.3
    vertical_smooth: float = 0.015
    min_contrast: float = 0.08
    noise_k: float = 4.0
    chroma_weight: float = 2.0
    smooth_px: float = 1.0
    slant_deg: float = 0.5
    nms_deg: float = 1.25
    relative_min: float = 0.25
    relative_deg: float = 4.0
    max_edges: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.max_edges, bool) or not isinstance(self.max_edges, int) or self.max_edges < 0:
            raise InvalidParameterError(f"max_edges must be an integer >= 0, got {self.max_edges!r}")
        _check_positive(self, ("min_extent", "min_support", "min_contrast", "nms_deg", "relative_deg"))
        _check_positive(self, ("vertical_smooth",), allow_zero=True)
        if self.min_extent > 1:
            raise InvalidParameterError(f"min_extent must be in (0, 1], got {self.min_extent!r}")
        if not 0 <= self.relative_min < 1:
            raise InvalidParameterError(f"relative_min must be in [0, 1), got {self.relative_min!r}")
        _check_positive(self, ("noise_k", "chroma_weight", "smooth_px", "slant_deg"), allow_zero=True)
        if self.min_support > 1:
            raise InvalidParameterError(f"min_support must be in (0, 1], got {self.min_support!r}")


def _gauss_taps(sigma: float) -> FArray:
    """The taps of :func:`scipy.ndimage.gaussian_filter1d` (truncated at 4 sigma), shape (2 r + 1,)."""
    r = int(4.0 * sigma + 0.5)
    x = np.arange(-r, r + 1, dtype=np.float64)
    k = np.exp(-0.5 / (sigma * sigma) * x * x)
    return np.asarray(k / k.sum())


def _smooth(a: FArray, sigma: float, sigma_rows: float) -> tuple[FArray, float]:
    """Gaussian smoothing along the columns (circular, ``sigma``) and the rows (``sigma_rows``, edge
    rows repeated) in one OpenCV pass, and the gain that restores a step's
    height: a step of height ``A`` gives a forward difference of ``A erf(1 / (2 sqrt(2) sigma))``
    after the column smoothing; multiplied by the gain it is ``A`` again.

    The same filters as :func:`scipy.ndimage.gaussian_filter1d` (``mode="wrap"``, then
    ``"nearest"``), summed in a different order (a last-bit difference).
    """
    import cv2

    if sigma <= 0 and sigma_rows <= 0:
        return a, 1.0
    kx = _gauss_taps(sigma) if sigma > 0 else np.ones(1)
    ky = _gauss_taps(sigma_rows) if sigma_rows > 0 else np.ones(1)
    r = kx.size // 2
    w = a.shape[1]
    idx = np.arange(-r, w + r) % w
    out = cv2.sepFilter2D(np.ascontiguousarray(a[:, idx]), cv2.CV_64F, kx, ky, borderType=cv2.BORDER_REPLICATE)
    gain = 1.0 / math.erf(0.5 / (np.sqrt(2.0) * sigma)) if sigma > 0 else 1.0
    return np.asarray(out[:, r : r + w]), gain


def _slant_cols(p: EdgeParams, w: int) -> int:
    return max(1, round(p.slant_deg / 360.0 * w))


def _edge_support(pano: Panorama, p: EdgeParams) -> tuple[FArray, FArray]:
    """Edge score of each column boundary (>= 1: an edge) and its mean gradient strength."""
    h, w = pano.image.shape[:2]
    loglum, chrom = edge_inputs(np.ascontiguousarray(pano.image))
    # chroma is smoothed twice as much: cameras and JPEG sample it at half resolution; vertical
    # edges are vertical: averaging along the elevation removes pixel and JPEG noise without
    # blurring them
    sigma = p.smooth_px * max(w / 720.0, 0.5)
    loglum, gl = _smooth(loglum, sigma, p.vertical_smooth * h)
    chrom, gc = _smooth(chrom, 2.0 * sigma, p.vertical_smooth * h)
    # forward differences across column boundaries (circular), projected on each column's mean
    # direction (an edge keeps its polarity along the elevation, noise does not); per-row noise
    # thresholds, row maxima, the slant tolerance, gaps bridged along the elevation (compiled)
    support, extent, strength = edge_columns(
        np.ascontiguousarray(loglum),
        np.ascontiguousarray(chrom),
        float(gl),
        float(gc),
        float(p.chroma_weight),
        float(p.min_contrast),
        float(p.noise_k),
        float(p.relative_min),
        max(2, round(p.relative_deg / 360.0 * w)),
        _slant_cols(p, w),
        max(1, round(0.01 * h)),
    )
    # a column passes with a long unbroken run, or with enough edge rows in all
    score = np.maximum(extent / p.min_extent, support / p.min_support)
    return score, strength


def vertical_edges(pano: Panorama, **params: Any) -> FArray:
    """Bearings of vertical edges in a panorama.

    Parameters
    ----------
    pano : Panorama
    **params
        Fields of :class:`EdgeParams`.

    Returns
    -------
    ndarray of float, shape (n,)
        Bearings in radians, wrapped to ``[-pi, pi)``, sorted.
    """
    p = _from_kwargs(EdgeParams, params, "vertical-edge")
    support, strength = _edge_support(pano, p)
    w = support.size
    score = support + 1e-3 * strength / max(float(strength.max()), 1e-12)  # break plateaus by strength
    half = max(1, round(np.deg2rad(p.nms_deg) / TWO_PI * w))
    local_max = score >= ndimage.maximum_filter1d(score, 2 * half + 1, mode="wrap")
    cand = np.flatnonzero(local_max & (support >= 1.0))
    # plateaus of equal score: keep one per run
    keep: list[int] = []
    for jj in cand:
        j = int(jj)
        if keep and (j - keep[-1]) <= half and score[keep[-1]] >= score[j]:
            continue
        keep.append(j)
    if len(keep) > 1 and (keep[0] + w - keep[-1]) <= half:
        keep.pop() if score[keep[-1]] <= score[keep[0]] else keep.pop(0)
    if p.max_edges and len(keep) > p.max_edges:
        strongest = sorted(keep, key=lambda j: -score[j])[: p.max_edges]
        keep = sorted(strongest)
    cols = []
    for j in keep:
        # sub-column position: strength-weighted centre over the slant window
        slant = _slant_cols(p, w)
        idx = np.arange(j - slant - 1, j + slant + 2)
        wts = strength[idx % w]
        pos = float((idx * wts).sum() / wts.sum()) if wts.sum() > 0 else float(j)
        cols.append(pos + 1.0)  # boundary between column pos and pos + 1
    out = pano.column_bearing(np.asarray(cols, dtype=np.float64))
    return np.sort(wrap(out))


# ---------------------------------------------------------------------------
# colour patches


@dataclass(frozen=True, slots=True)
class PatchParams:
    """Tuning of :func:`colour_patches`.

    Parameters
    ----------
    min_saturation : float, default 0.35
        Pixels below this HSV saturation are not colour (walls, floor).
    min_value, max_value : float, default 0.12, 0.99
        Dark pixels (unreliable hue) and blown-out pixels are ignored.
    hue_tol_deg : float, default 20
        Largest hue distance of a pixel from its region's hue mode, degrees.
    min_height : float, default 0.04
        Smallest height of a patch, as a part of the panorama's rows.
    min_width_deg : float, default 1.5
        Narrowest patch, degrees of bearing.
    min_fill : float, default 0.3
        Smallest part of its bounding box a patch must fill.
    white_balance : bool, default True
        Apply a robust grey-world white balance first.
    """

    min_saturation: float = 0.35
    min_value: float = 0.12
    max_value: float = 0.99
    hue_tol_deg: float = 20.0
    min_height: float = 0.04
    min_width_deg: float = 1.5
    min_fill: float = 0.3
    white_balance: bool = True

    def __post_init__(self) -> None:
        _check_positive(self, ("min_saturation", "hue_tol_deg", "min_height", "min_width_deg", "min_fill"))
        _check_positive(self, ("min_value",), allow_zero=True)
        if not self.min_value < self.max_value <= 1.0:
            raise InvalidParameterError(
                f"max_value must be in (min_value, 1], got min_value={self.min_value!r}, max_value={self.max_value!r}"
            )
        if self.min_saturation >= 1 or self.min_height > 1 or self.min_fill > 1:
            raise InvalidParameterError("min_saturation must be < 1 and min_height, min_fill <= 1")


def _hue_modes(hue: FArray, tol_deg: float) -> FArray:
    """Peaks of the circular hue histogram, at least ``tol_deg`` apart, degrees."""
    bins = 72
    hist, _ = np.histogram(hue, bins=bins, range=(0.0, 360.0))
    sm = ndimage.gaussian_filter1d(hist.astype(np.float64), 1.0, mode="wrap")
    half = max(1, round(tol_deg / (360.0 / bins)))
    is_max = (sm >= ndimage.maximum_filter1d(sm, 2 * half + 1, mode="wrap")) & (sm > 0)
    centres = (np.arange(bins) + 0.5) * 360.0 / bins
    out: list[float] = []
    for k in np.flatnonzero(is_max):
        if out and abs(centres[k] - out[-1]) <= tol_deg:
            continue
        out.append(float(centres[k]))
    return np.asarray(out)


def _circ_mean_deg(a: FArray, w: FArray | None = None) -> float:
    r = np.deg2rad(a)
    wts = np.ones_like(r) if w is None else w
    return float(np.rad2deg(np.arctan2((wts * np.sin(r)).sum(), (wts * np.cos(r)).sum())) % 360.0)


def _bearing_extent(pano: Any, cols: NDArray[np.int64], w: int) -> tuple[float, float]:
    """Circular mean bearing of pixels in columns ``cols`` and the half width (radians) of their bearings' span.

    Per column (pixel counts as weights), not per pixel: the same sums, in
    a different order.
    """
    counts = np.bincount(cols, minlength=w)
    present = np.flatnonzero(counts)
    cb = pano.column_bearing(present.astype(np.float64) + 0.5)
    n = counts[present].astype(np.float64)
    centre = float(np.arctan2((n * np.sin(cb)).sum(), (n * np.cos(cb)).sum()))
    return centre, float(np.abs(wrap(cb - centre)).max()) + np.pi / w


def _close3(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Binary closing by a 3x3 square, outside the array counting as empty for both steps.

    :func:`scipy.ndimage.binary_closing` with ``structure=np.ones((3, 3))`` (its
    default ``border_value=0``), through OpenCV's morphology (exact on binary images).
    """
    import cv2

    u8 = mask.astype(np.uint8)
    k = np.ones((3, 3), dtype=np.uint8)
    grown = cv2.dilate(u8, k, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return np.asarray(cv2.erode(grown, k, borderType=cv2.BORDER_CONSTANT, borderValue=0), dtype=bool)


def colour_patches(pano: Panorama, **params: Any) -> tuple[FArray, FArray]:
    """Saturated colour regions of a panorama: their bearings and hues.

    Parameters
    ----------
    pano : Panorama
    **params
        Fields of :class:`PatchParams`.

    Returns
    -------
    bearings : ndarray of float, shape (m,)
        Bearing of each patch's centre, radians, wrapped, sorted.
    hues : ndarray of float, shape (m,)
        Hue of each patch, degrees in ``[0, 360)``.
    """
    p = _from_kwargs(PatchParams, params, "colour-patch")
    img = pano.image.astype(np.float64)
    h, w, _ = img.shape
    if p.white_balance:
        img = white_balance(img)
    img = ndimage.uniform_filter(img, size=(3, 3, 1), mode=("nearest", "wrap", "nearest"))  # JPEG / pixel noise
    hue, sat, val = rgb_to_hsv(img)
    mask = (sat >= p.min_saturation) & (val >= p.min_value) & (val <= p.max_value)
    if not np.any(mask):
        return np.empty(0), np.empty(0)
    modes = _hue_modes(hue[mask], p.hue_tol_deg)
    # nearest mode of every coloured pixel, within tolerance
    d = np.abs(((hue[mask][:, None] - modes[None, :]) + 180.0) % 360.0 - 180.0)
    which = np.full(mask.shape, -1, dtype=np.int64)
    which[mask] = np.where(d.min(axis=1) <= p.hue_tol_deg, np.argmin(d, axis=1), -1)
    ok = which >= 0
    min_rows = p.min_height * h
    min_cols = np.deg2rad(p.min_width_deg) / TWO_PI * w
    found_b: list[float] = []
    found_h: list[float] = []
    for k in range(modes.size):
        m = ok & (which == k)
        if np.count_nonzero(m) < min_rows * min_cols:
            continue
        # close pin holes (JPEG, text), circularly in columns; rows keep their border
        padded = np.pad(m, ((1, 1), (2, 2)), mode="wrap")
        padded[0], padded[-1] = padded[1], padded[-2]
        m = _close3(padded)[1:-1, 2:-2] | m
        lab, nlab = ndimage.label(m)
        if nlab == 0:
            continue
        # join labels across the 0 / w-1 column seam
        parent = np.arange(nlab + 1)

        def find(a: int, parent: NDArray[np.int64] = parent) -> int:
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = int(parent[a])
            return a

        for la, lb in zip(lab[:, 0], lab[:, -1], strict=True):
            if la and lb:
                ra, rb = find(int(la)), find(int(lb))
                if ra != rb:
                    parent[max(ra, rb)] = min(ra, rb)
        roots = np.array([find(i) for i in range(nlab + 1)])
        lab = roots[lab]
        # regions with their circular bearing extent (centre, half width)
        regions: list[list[Any]] = []
        flat = lab.ravel()
        counts = np.bincount(flat)
        # stable: pixels of a region in raster order (16-bit labels sort by radix, much faster)
        order = np.argsort(flat.astype(np.uint16) if nlab < 65536 else flat, kind="stable")
        starts = np.r_[0, np.cumsum(counts)]
        min_pixels = p.min_fill * min_rows * min_cols
        for r in np.flatnonzero(counts):
            if r == 0 or counts[r] < 0.5 * min_pixels:  # specks (noise); halves may still merge
                continue
            pix = order[starts[r] : starts[r + 1]]
            rows, cols = np.divmod(pix, w)
            centre, half = _bearing_extent(pano, cols, w)
            regions.append([rows, cols, centre, half])
        # merge regions of this hue that overlap in bearing (a poster split by a bar or a frame)
        merged = True
        while merged and len(regions) > 1:
            merged = False
            for i in range(len(regions)):
                for j in range(i + 1, len(regions)):
                    a, b = regions[i], regions[j]
                    if abs((a[2] - b[2] + math.pi) % TWO_PI - math.pi) < a[3] + b[3]:  # scalar wrap
                        rows = np.concatenate([a[0], b[0]])
                        cols = np.concatenate([a[1], b[1]])
                        centre, half = _bearing_extent(pano, cols, w)
                        regions[i] = [rows, cols, centre, half]
                        regions.pop(j)
                        merged = True
                        break
                if merged:
                    break
        for rows, cols, centre, half in regions:
            width_cols = 2.0 * half / TWO_PI * w
            height_rows = float(rows.max() - rows.min() + 1)
            if height_rows < min_rows or width_cols < min_cols:
                continue
            if rows.size < p.min_fill * height_rows * width_cols:
                continue
            sel = ok[rows, cols] & (which[rows, cols] == k)
            if not np.any(sel):
                continue
            found_b.append(centre)
            found_h.append(_circ_mean_deg(hue[rows[sel], cols[sel]], sat[rows[sel], cols[sel]]))
    if not found_b:
        return np.empty(0), np.empty(0)
    bearings = wrap(np.asarray(found_b))
    hues_deg = np.asarray(found_h) % 360.0
    order = np.argsort(bearings)
    return bearings[order], hues_deg[order]


# ---------------------------------------------------------------------------
# both, and observations


@dataclass(frozen=True, slots=True, eq=False)
class VisionFeatures:
    """Features of one panorama.

    Attributes
    ----------
    edges : ndarray of float, shape (n,)
        Vertical-edge bearings, radians, wrapped, sorted.
    patches : ndarray of float, shape (m,)
        Colour-patch bearings, radians, wrapped.
    patch_hues : ndarray of float, shape (m,)
        Hue of each patch, degrees in ``[0, 360)``.
    """

    edges: FArray
    patches: FArray
    patch_hues: FArray

    def __post_init__(self) -> None:
        for name in ("edges", "patches", "patch_hues"):
            a = np.array(getattr(self, name), dtype=np.float64, copy=True).reshape(-1)
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        if self.patches.shape != self.patch_hues.shape:
            raise InvalidParameterError("one hue per colour patch is needed")


def _split_params(params: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    from .laser import LaserParams

    edge_names = {f.name for f in fields(EdgeParams)}
    patch_names = {f.name for f in fields(PatchParams)}
    laser_names = {f.name for f in fields(LaserParams)}
    e, c, la = {}, {}, {}
    for k, v in params.items():
        if k in edge_names:
            e[k] = v
        elif k in patch_names:
            c[k] = v
        elif k in laser_names:
            la[k] = v
        else:
            known = ", ".join(sorted(edge_names | patch_names | laser_names))
            raise InvalidParameterError(f"unknown feature parameter {k!r} (known: {known})")
    return e, c, la


def extract_vision_features(pano: Panorama, **params: Any) -> VisionFeatures:
    """Vertical edges and colour patches of a panorama.

    Parameters
    ----------
    pano : Panorama
    **params
        Fields of :class:`EdgeParams` and :class:`PatchParams`.
    """
    e, c, la = _split_params(params)
    if la:
        raise InvalidParameterError(f"laser parameter {sorted(la)[0]!r} given to a vision extractor")
    edges = vertical_edges(pano, **e)
    pb, ph = colour_patches(pano, **c)
    return VisionFeatures(edges=edges, patches=pb, patch_hues=ph)


def observation_from_views(
    *,
    scan: Scan | None = None,
    panorama: Panorama | None = None,
    label: str | None = None,
    appearance: bool = False,
    profile: bool = False,
    source: str | None = None,
    **params: Any,
) -> Observation:
    """One :class:`Observation` from the laser scan and/or the panorama taken at one pose.

    Parameters
    ----------
    scan : Scan, optional
        Gives corners ``c``, extremities ``Ex`` and beacons ``B``.
    panorama : Panorama, optional
        Gives vertical edges ``VE`` and colour patches ``CP``.
    label : str, optional
        Place label.
    appearance : bool, default False
        Also compute the panorama's :func:`appearance_descriptor` (with
        default :class:`AppearanceParams`) into ``Observation.appearance``.
    profile : bool, default False
        Also compute the panorama's :func:`column_profile` (default size: 36
        sectors of 10 deg x 4 strips x 5 channels), rounded to
        :data:`PROFILE_DECIMALS` decimals, into ``Observation.profile``
        (headings between views, term ``AP``).
    source : str, optional
        The file the views came from, kept in ``Observation.source``.
    **params
        Fields of :class:`~fingerloc.features.laser.LaserParams`,
        :class:`EdgeParams` and :class:`PatchParams`, routed by name.

    Returns
    -------
    Observation
        Field of view: the full circle when a panorama is given, else the
        scan's. Pose and timestamp from the scan, else from the panorama's
        ``meta`` (keys ``"pose"``, ``"timestamp"``) when present.
    """
    from .laser import extract_laser_features

    if scan is None and panorama is None:
        raise InvalidParameterError("observation_from_views needs a scan, a panorama or both")
    e, c, la = _split_params(params)
    ve = cp = cp_hue = corners = ex = beacons = np.empty(0)
    pose: tuple[float, float, float] | None = None
    timestamp: float | None = None
    desc: FArray | None = None
    prof: FArray | None = None
    if panorama is not None:
        vf = extract_vision_features(panorama, **e, **c)
        if appearance and profile:  # the band's block means once for both
            desc, prof = appearance_and_profile(panorama)
            prof = np.round(prof, PROFILE_DECIMALS)
        elif appearance:
            desc = appearance_descriptor(panorama)
        elif profile:
            prof = np.round(column_profile(panorama), PROFILE_DECIMALS)
        ve, cp, cp_hue = vf.edges, vf.patches, vf.patch_hues
        mp = panorama.meta.get("pose")
        if mp is not None:
            pose = tuple(float(v) for v in mp)  # type: ignore[attr-defined, assignment]
        mt = panorama.meta.get("timestamp")
        if mt is not None:
            timestamp = float(mt)  # type: ignore[arg-type]
    if scan is not None:
        lf = extract_laser_features(scan, **la)
        corners, ex, beacons = lf.corners, lf.extremities, lf.beacons
        pose = scan.pose if scan.pose is not None else pose
        timestamp = scan.timestamp if scan.timestamp is not None else timestamp
    fov = FULL_FOV if panorama is not None else scan.fov  # type: ignore[union-attr]
    return Observation(
        ve=ve,
        cp=cp,
        cp_hue=cp_hue,
        ex=ex,
        c=corners,
        b=beacons,
        fov=fov,
        label=label,
        pose=pose,
        timestamp=timestamp,
        appearance=desc,
        profile=prof,
        source=source,
    )
