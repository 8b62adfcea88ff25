"""Heading-free and bearing-by-bearing descriptors of a whole panorama: the appearance descriptor and the column profile.

- :func:`appearance_descriptor`: colour, grey and gradient histograms per
  elevation strip (term ``A``); heading-free.
- :func:`column_profile`: coarse cells of the band around the horizon, rows =
  bearings (term ``AP`` and headings between views:
  :func:`profile_rotation_deg`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._types import FArray
from ..angles import TWO_PI
from ..errors import InvalidParameterError
from ..sensors import Panorama
from ._params import _from_kwargs
from .colour import rgb_to_hsv, white_balance

__all__ = [
    "APPEARANCE_VERSIONS",
    "PROFILE_CHANNELS",
    "PROFILE_DECIMALS",
    "AppearanceParams",
    "appearance_and_profile",
    "appearance_descriptor",
    "column_profile",
    "profile_correlation",
    "profile_rotation_deg",
]


#: Version of :func:`appearance_descriptor`'s layout with its default parameters, by descriptor length.
#: 1: one colour / grey block over the band + layout spectrum (94 numbers; fingerloc's first panorama
#: descriptor); 2: colour / grey and gradient histograms per elevation strip (222 numbers).
APPEARANCE_VERSIONS: dict[int, int] = {94: 1, 222: 2}

#: Images wider than this are block-averaged to about this many columns before the appearance
#: descriptor (gradients at one scale, whatever the photo's resolution).
_APPEARANCE_WIDTH = 720

#: Upper edges of the gradient-magnitude bins (log-luminance change per pixel at ~720 columns,
#: i.e. per half degree); the last bin is open.
_GRADIENT_EDGES = (0.005, 0.01, 0.02, 0.04, 0.08, 0.16, 0.32)


@dataclass(frozen=True, slots=True)
class AppearanceParams:
    """Tuning of :func:`appearance_descriptor`.

    Parameters
    ----------
    hue_bins : int, default 16
        Hue bins of the colour histogram (22.5 deg each, as the CP letters).
    sat_edges : tuple of float, default (0.15, 0.35, 0.6)
        Saturation bin edges: pixels below the first are grey, the others fall
        into ``len(sat_edges)`` saturation bins per hue bin.
    value_bins : int, default 8
        Brightness bins of the grey pixels (after exposure normalisation).
    strips : int, default 3
        Horizontal strips of the band (elevation ranges, top first), each with
        its own histograms: in a ``-45..+45`` deg band, the upper walls and
        ceiling edge, eye level, the lower walls and furniture.
    gradients : bool, default True
        Add the gradient histograms of each strip (orientation and magnitude
        of the log-luminance gradient).
    orientation_bins : int, default 8
        Gradient-orientation bins over ``[0, 180)`` deg (22.5 deg each).
    harmonics : int, default 0
        Fourier harmonics (1..harmonics) of the column profiles kept in the
        layout block; 0: no layout block (version 1 used 12).
    white_balance : bool, default True
        Robust white balance first (:func:`colour_patches` uses the same).
    """

    hue_bins: int = 16
    sat_edges: tuple[float, ...] = (0.15, 0.35, 0.6)
    value_bins: int = 8
    strips: int = 3
    gradients: bool = True
    orientation_bins: int = 8
    harmonics: int = 0
    white_balance: bool = True

    def __post_init__(self) -> None:
        for name in ("hue_bins", "value_bins", "strips", "orientation_bins"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InvalidParameterError(f"{name} must be an integer >= 1, got {v!r}")
        h = self.harmonics
        if isinstance(h, bool) or not isinstance(h, int) or h < 0:
            raise InvalidParameterError(f"harmonics must be an integer >= 0, got {h!r}")
        for name in ("gradients", "white_balance"):
            if not isinstance(getattr(self, name), bool):
                raise InvalidParameterError(f"{name} must be True or False, got {getattr(self, name)!r}")
        edges = tuple(self.sat_edges)
        if not edges or any(not 0 < e < 1 for e in edges) or any(b <= a for a, b in itertools.pairwise(edges)):
            raise InvalidParameterError(f"sat_edges must increase strictly inside (0, 1), got {self.sat_edges!r}")

    @property
    def strip_size(self) -> int:
        """Numbers per strip: colour, grey and exposure shares, then (with ``gradients``) the gradient bins."""
        grad = self.orientation_bins + len(_GRADIENT_EDGES) + 1 if self.gradients else 0
        return self.hue_bins * len(self.sat_edges) + self.value_bins + 2 + grad

    @property
    def size(self) -> int:
        """Length of the descriptor."""
        return self.strips * self.strip_size + 3 * self.harmonics


def _block_mean(img: FArray, width: int) -> FArray:
    """Block means of an ``(h, w, 3)`` image by the largest whole factor that keeps at least ``width`` columns."""
    h, w, _ = img.shape
    f = w // width
    if f < 2:
        return img
    return _blocks(img, f, max(1, min(f, h // 8)))


def _colour_shares(img: FArray, p: AppearanceParams) -> FArray:
    """Colour (hue x saturation), grey brightness, dark and blown-out shares of an image's pixels (sum 1)."""
    hue, sat, val = rgb_to_hsv(img)
    n = float(val.size)
    raw_v = val
    ref = float(np.quantile(val, 0.95))
    val = np.clip(val / max(ref, 1e-3), 0.0, 1.0)
    dark = raw_v < 0.08
    blown = raw_v > 0.98
    usable = ~dark & ~blown
    edges = np.asarray(p.sat_edges)
    colour = usable & (sat >= edges[0])
    grey = usable & ~colour
    hb = np.minimum((hue[colour] / 360.0 * p.hue_bins).astype(np.int64), p.hue_bins - 1)
    sb = np.searchsorted(edges, sat[colour], side="right") - 1
    block1 = np.bincount(hb * edges.size + sb, minlength=p.hue_bins * edges.size) / n
    vb = np.minimum((val[grey] * p.value_bins).astype(np.int64), p.value_bins - 1)
    return np.r_[block1, np.bincount(vb, minlength=p.value_bins) / n, dark.sum() / n, blown.sum() / n]


def _gradient_shares(ll: FArray, rows: slice, p: AppearanceParams) -> FArray:
    """Orientation (magnitude-weighted, sum 1) and magnitude (pixel shares, sum 1) histograms of the
    log-luminance gradient over ``rows`` (central differences; columns wrap around, rows do not)."""
    h = ll.shape[0]
    lo, hi = max(rows.start, 1), min(rows.stop, h - 1)
    if hi <= lo:  # a strip on the band's border row only: no vertical difference
        lo, hi = rows.start, rows.stop
        gy = np.zeros((hi - lo, ll.shape[1]))
    else:
        gy = 0.5 * (ll[lo + 1 : hi + 1] - ll[lo - 1 : hi - 1])
    part = ll[lo:hi]
    gx = 0.5 * (np.roll(part, -1, axis=1) - np.roll(part, 1, axis=1))
    mag = np.hypot(gx, gy)
    ang = np.mod(np.arctan2(gy, gx), np.pi)
    ob = np.minimum((ang / np.pi * p.orientation_bins).astype(np.int64), p.orientation_bins - 1)
    w = np.where(mag > 0.02, mag, 0.0)  # weaker gradients: noise, JPEG blocks, smooth shading
    orient = np.bincount(ob.ravel(), weights=w.ravel(), minlength=p.orientation_bins)
    tot = orient.sum()
    orient = orient / tot if tot > 0 else np.full(p.orientation_bins, 1.0 / p.orientation_bins)
    mb = np.searchsorted(np.asarray(_GRADIENT_EDGES), mag.ravel())
    magn = np.bincount(mb, minlength=len(_GRADIENT_EDGES) + 1) / float(mag.size)
    return np.r_[orient, magn]


def appearance_descriptor(pano: Panorama, **params: Any) -> FArray:
    """A heading-free appearance descriptor of a panorama (the camera's analogue of the range histogram).

    The image is first block-averaged to about 720 columns when wider (the
    same scale for any photo resolution) and white-balanced (grey world on
    its duller-than-median pixels). Its rows are cut into ``strips``
    horizontal strips (elevation ranges, top first); each strip gives, in
    this order:

    1. colour: the share of the strip's pixels in each (hue, saturation)
       bin, ``hue_bins * len(sat_edges)`` bins;
    2. grey and exposure: the share of grey pixels (saturation below
       ``sat_edges[0]``) in ``value_bins`` brightness bins, brightness divided
       by the strip's 95th percentile (exposure normalisation), then the
       share of dark (value < 0.08) and blown-out (> 0.98 before
       normalisation) pixels. Blocks 1 and 2 sum to 1;
    3. with ``gradients``: the orientation histogram of the log-luminance
       gradient (``orientation_bins`` over ``[0, 180)`` deg, weighted by the
       magnitude, pixels below 0.02 left out; sums to 1, or uniform for a
       flat strip), then the share of pixels in each of 8 gradient-magnitude
       bins (edges 0.005, 0.01, ..., 0.32 log units per pixel; sums to 1).
       Log luminance makes both blind to exposure.

    Each number is the square root of its share divided by ``strips``,
    ``sqrt(share / strips)``: the squares of the colour part sum to 1, those
    of the gradient part to 2. The square root (as in the Hellinger and
    Bhattacharyya distances) evens out the variance of the shares, so that
    the L1 distance of the appearance term ``A`` counts a change of a small
    bin (a red sofa, a window) as much as noise in a large one (a white
    wall) allows. With ``harmonics > 0`` a layout block
    follows: the magnitudes of the Fourier harmonics ``1..harmonics`` of the
    column means of log luminance and of the two chromaticities, each
    channel normalised to sum 1/3. None of it depends on the column where the
    panorama starts (a histogram ignores where its pixels are; the gradient
    wraps around the seam), so turning the robot changes nothing.

    Parameters
    ----------
    pano : Panorama
        Rows: the elevations to describe (e.g. the band around the horizon),
        at least ``strips`` of them.
    **params
        Fields of :class:`AppearanceParams`.

    Returns
    -------
    ndarray of float, shape (AppearanceParams.size,)
        Values ``>= 0``; with the defaults, 222 numbers
        (:data:`APPEARANCE_VERSIONS`: version 2).
    """
    p = _from_kwargs(AppearanceParams, params, "appearance")
    return _appearance_of(_block_mean(np.asarray(pano.image, dtype=np.float64), _APPEARANCE_WIDTH), p)


def _appearance_of(img: FArray, p: AppearanceParams) -> FArray:
    """:func:`appearance_descriptor` of an image already block-averaged, ``(h, w, 3)`` float64."""
    if img.shape[0] < p.strips:
        raise InvalidParameterError(
            f"the panorama has {img.shape[0]} rows, fewer than the {p.strips} strips of its appearance"
        )
    if p.white_balance:
        img = white_balance(img, "grey")
    ll = np.log(img @ np.array([0.299, 0.587, 0.114]) + 0.02)
    rb = np.linspace(0, img.shape[0], p.strips + 1).round().astype(np.int64)
    parts: list[FArray] = []
    for i in range(p.strips):
        parts.append(np.sqrt(_colour_shares(img[rb[i] : rb[i + 1]], p) / p.strips))
        if p.gradients:
            parts.append(np.sqrt(_gradient_shares(ll, slice(int(rb[i]), int(rb[i + 1])), p) / p.strips))
    if p.harmonics:
        tot = img.sum(axis=2) + 0.06
        profiles = [ll.mean(axis=0), (img[:, :, 0] / tot).mean(axis=0), (img[:, :, 1] / tot).mean(axis=0)]
        for prof in profiles:
            mag = np.abs(np.fft.rfft(prof - prof.mean()))[1 : p.harmonics + 1]
            mag = np.r_[mag, np.zeros(p.harmonics - mag.size)]
            total = mag.sum()
            parts.append(mag / (3.0 * total) if total > 0 else np.full(p.harmonics, 1.0 / (3.0 * p.harmonics)))
    return np.concatenate(parts)


# ---------------------------------------------------------------------------
# column profile: what the view looks like at each bearing (for headings between views)

#: Channels of :func:`column_profile`, per horizontal strip.
PROFILE_CHANNELS: tuple[str, ...] = (
    "log_luminance",
    "red_chromaticity",
    "green_chromaticity",
    "column_gradient",
    "row_gradient",
)


#: Images wider than this are block-averaged to about this many columns first (gradients at one scale).
_PROFILE_WIDTH = 720

#: Decimals of the profiles :func:`observation_from_views` stores (standardised values: 0.01 is far below
#: their noise; 36 x 20 numbers at two decimals are about 3 KB of JSON a view).
PROFILE_DECIMALS = 2


def column_profile(pano: Panorama, *, columns: int = 36, strips: int = 4) -> FArray:
    """The view at each bearing: coarse cells of the band, shape ``(columns, strips * 5)``.

    Row ``k`` describes the bearings ``[k, k + 1) * 360 / columns`` degrees
    (counter-clockwise from the robot's bearing 0, whatever the panorama's
    column order and ``bearing_offset``); the band's rows are cut into
    ``strips`` horizontal strips (top first), and each cell holds the mean
    over its pixels of :data:`PROFILE_CHANNELS`: log luminance, the red and
    green chromaticities, and the absolute differences of log luminance
    across the columns (vertical structure) and across the rows (horizontal
    structure), after block means by the largest whole factor that keeps at
    least 720 columns (so that a 1440 or a 5760 px photo give about the same
    gradients). Each of the ``strips * 5`` channels is then standardised over
    the rows (mean 0, standard deviation 1; a flat channel stays 0), so that
    exposure, white balance and contrast do not count.

    Turning the robot on the spot rolls the rows; two photos taken a few
    metres apart in one room keep most of the coarse layout (walls, windows,
    doors, floor), which is what :func:`profile_rotation_deg` matches.
    """
    if isinstance(columns, bool) or not isinstance(columns, (int, np.integer)) or columns < 4:
        raise InvalidParameterError(f"columns must be an integer >= 4, got {columns!r}")
    if isinstance(strips, bool) or not isinstance(strips, (int, np.integer)) or strips < 1:
        raise InvalidParameterError(f"strips must be an integer >= 1, got {strips!r}")
    img = np.asarray(pano.image, dtype=np.float64)  # float in [0, 1]
    h, w, _ = img.shape
    if w > _PROFILE_WIDTH:  # the same cells whatever the image's resolution: block means down to ~720 columns
        f = w // _PROFILE_WIDTH
        img = _blocks(img, f, max(1, min(f, h // max(strips, 1))))
    return _profile_of(img, pano, columns, strips)


def _blocks(img: FArray, f: int, fh: int) -> FArray:
    """Means of ``fh`` x ``f`` blocks of an ``(h, w, 3)`` image (the last partial rows and columns dropped)."""
    h, w, _ = img.shape
    w2, h2 = (w // f) * f, (h // fh) * fh
    return np.asarray(img[:h2, :w2].reshape(h2 // fh, fh, w2 // f, f, 3).mean(axis=(1, 3)), dtype=np.float64)


def _profile_of(img: FArray, pano: Panorama, columns: int, strips: int) -> FArray:
    """:func:`column_profile` of ``img`` (float64, block-averaged or not), the bearings of ``pano``."""
    h, w, _ = img.shape
    if w != pano.width:  # block-averaged: the same bearings on fewer columns (only its bearings are used)
        pano = Panorama(img, bearing_offset=pano.bearing_offset, clockwise=pano.clockwise)  # type: ignore[arg-type]
    if h < strips:
        raise InvalidParameterError(f"the panorama has {h} rows, fewer than the {strips} strips of its profile")
    lum = img @ np.array([0.299, 0.587, 0.114])
    tot = img.sum(axis=2) + 0.02
    ll = np.log(lum + 0.02)
    gcol = np.abs(np.roll(ll, -1, axis=1) - np.roll(ll, 1, axis=1)) * 0.5
    grow = np.abs(np.diff(ll, axis=0, append=ll[-1:]))
    chans = np.stack([ll, img[:, :, 0] / tot, img[:, :, 1] / tot, gcol, grow], axis=2)  # (h, w, 5)
    rb = np.linspace(0, h, strips + 1).round().astype(np.int64)
    per_col = np.stack([chans[rb[i] : rb[i + 1]].mean(axis=0) for i in range(strips)], axis=1)  # (w, strips, 5)
    per_col = per_col.reshape(w, -1)
    # resample on bearings: `sub` samples per cell, each the image column at that bearing
    sub = max(1, math.ceil(w / columns))
    fine = (np.arange(columns * sub) + 0.5) * TWO_PI / (columns * sub)
    col = np.minimum(np.floor(pano.bearing_column(fine)).astype(np.int64), w - 1)
    prof = per_col[col].reshape(columns, sub, -1).mean(axis=1)
    prof -= prof.mean(axis=0)
    sd = prof.std(axis=0)
    prof = np.where(sd > 1e-9, prof / np.where(sd > 1e-9, sd, 1.0), 0.0)
    return np.asarray(prof, dtype=np.float64)


def appearance_and_profile(
    pano: Panorama, *, columns: int = 36, strips: int = 4, **params: Any
) -> tuple[FArray, FArray]:
    """``(appearance_descriptor(pano, **params), column_profile(pano, columns=columns, strips=strips))``.

    The same numbers, with the block means of a wide panorama computed once when both use the same blocks.
    """
    p = _from_kwargs(AppearanceParams, params, "appearance")
    if isinstance(strips, bool) or not isinstance(strips, (int, np.integer)) or strips < 1:
        raise InvalidParameterError(f"strips must be an integer >= 1, got {strips!r}")
    h, w = pano.image.shape[:2]
    f = w // _APPEARANCE_WIDTH
    if _APPEARANCE_WIDTH != _PROFILE_WIDTH or f < 2 or max(1, min(f, h // 8)) != max(1, min(f, h // strips)):
        return appearance_descriptor(pano, **params), column_profile(pano, columns=columns, strips=strips)
    if isinstance(columns, bool) or not isinstance(columns, (int, np.integer)) or columns < 4:
        raise InvalidParameterError(f"columns must be an integer >= 4, got {columns!r}")
    img = _blocks(np.asarray(pano.image, dtype=np.float64), f, max(1, min(f, h // 8)))
    return _appearance_of(img, p), _profile_of(img, pano, columns, strips)


def profile_correlation(a: FArray, b: FArray) -> FArray:
    """Circular correlation of two column profiles at every shift, shape ``(columns,)``.

    ``out[s]`` is the mean over rows ``k`` and channels of ``a[k] * b[k + s]``
    (1 when ``b`` is ``a`` rolled by ``s`` rows, for standardised profiles).
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2:
        raise InvalidParameterError(f"profiles must share one shape (columns, channels), got {a.shape} and {b.shape}")
    n = a.shape[0]
    spec = (np.conj(np.fft.rfft(a, axis=0)) * np.fft.rfft(b, axis=0)).sum(axis=1)
    return np.asarray(np.fft.irfft(spec, n=n) / a.size, dtype=np.float64)


def profile_rotation_deg(a: FArray, b: FArray) -> tuple[float, float]:
    """Heading between two views from their column profiles: ``(heading_deg, peak)``.

    A feature at bearing ``x`` in view ``a`` is at bearing ``x + heading_deg``
    in view ``b`` (degrees, ``[0, 360)``); ``peak`` is the correlation at that
    shift (1: identical up to a rotation). The shift maximises
    :func:`profile_correlation`, refined between rows by a parabola through
    the peak and its neighbours.
    """
    c = profile_correlation(a, b)
    n = c.size
    k = int(np.argmax(c))
    y0, y1, y2 = c[k - 1], c[k], c[(k + 1) % n]
    den = y0 - 2.0 * y1 + y2
    frac = 0.5 * (y0 - y2) / den if den < 0 else 0.0
    return float(np.mod((k + frac) * 360.0 / n, 360.0)), float(y1)
