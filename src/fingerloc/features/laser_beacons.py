"""Beacons of a laser scan from its intensity (remission) channel (step 5 of :mod:`fingerloc.features.laser`).

Narrow runs of beams brighter by a factor than their neighbours (the local
median, which follows the smooth fall of intensity with range and incidence)
and than the scan's median; the neighbourhood is measured in metres at each
beam's range (and at least a few degrees), not in beams. Only ratios are
used, so sensors with intensity scales from hundreds to tens of thousands
give the same beacons; ``beacon_threshold`` overrides this with an absolute
value in the sensor's unit. No intensities, no beacons; a beam whose
intensity is NaN (a merged scan's beams of a lidar without intensities) is
not a candidate.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from .._types import FArray
from ..sensors import Scan
from .laser_params import LaserParams

if TYPE_CHECKING:
    from .laser import _Prepared

__all__ = ["beacon_bearings"]


def _norm(v: FArray) -> float:
    return math.sqrt(float(v.dot(v)))


#: Widest background window of the beacon detector, degrees on each side.
_BEACON_WINDOW_MAX_DEG = 60.0


def _local_background(values: FArray, prep: _Prepared, p: LaserParams) -> FArray:
    """Running median of ``values`` over a window of ``beacon_window_m`` metres at each beam's range.

    The half width in beams, ``max(3, atan(window_m / r) / step, window_deg / step)``,
    is rounded up to a geometric ladder of sizes (ratio 1.25), and one median
    filter runs per size used: a few filters over the scan, whatever its length.
    """
    n = values.size
    step = abs(prep.step) if prep.step else np.pi / 180
    r = prep.r
    finite = np.isfinite(r) & (r > 0)
    r_use = np.where(finite, r, np.median(r[finite]) if np.any(finite) else 1.0)
    half = np.maximum(np.arctan(p.beacon_window_m / r_use), np.deg2rad(p.beacon_window_deg))
    half = np.minimum(half, np.deg2rad(_BEACON_WINDOW_MAX_DEG))
    beams = np.maximum(3, np.ceil(half / step)).astype(np.int64)
    beams = np.minimum(beams, max(3, (n - 1) // 2))
    ladder = np.unique(np.ceil(3 * 1.25 ** np.arange(0, 64)).astype(np.int64))
    ladder = ladder[ladder <= max(3, (n - 1) // 2)]
    if ladder.size == 0 or ladder[-1] < beams.max():
        ladder = np.r_[ladder, beams.max()]
    size_idx = np.searchsorted(ladder, beams)
    mode = "wrap" if prep.circular else "nearest"
    out = np.empty_like(values)
    for j in np.unique(size_idx):
        w = int(ladder[j])
        sel = size_idx == j
        out[sel] = ndimage.median_filter(values, size=2 * w + 1, mode=mode)[sel]
    return out


def _beacons(scan: Scan, prep: _Prepared, p: LaserParams) -> FArray:
    """Step 5: beacon bearings from the intensity channel (narrow runs of bright beams).

    Parameters
    ----------
    scan : Scan
        The raw scan; no ``intensities``, no beacons.
    prep : _Prepared
        The segmented scan (rolled ranges and points).
    p : LaserParams
        ``beacon_threshold`` (sensor's unit) or the adaptive ratios, and the
        beacon widths (metres) and gap (degrees).

    Returns
    -------
    ndarray of float, shape (m,)
        Bearing of each beacon's intensity-weighted centre, radians, robot
        frame, in scan order.
    """
    if scan.intensities is None:
        return np.empty(0)
    inten = np.roll(np.asarray(scan.intensities, dtype=np.float64), -prep.shift)
    valid = np.isfinite(prep.r) & np.isfinite(inten)
    if not np.any(valid):
        return np.empty(0)
    contrast: FArray | None = None
    if p.beacon_threshold is not None:
        bright = valid & (inten > p.beacon_threshold)
    else:
        pos = valid & (inten > 0)
        if np.count_nonzero(pos) < 10:
            return np.empty(0)
        li = np.full(inten.shape, np.nan)
        li[pos] = np.log(inten[pos])
        med = float(np.median(li[pos]))
        # local background: median log intensity of the beams around (beams without a return
        # count as the scan's median); smooth trends with range and incidence cancel out
        filled = np.where(pos, li, med)
        local = _local_background(filled, prep, p)
        contrast = np.minimum(filled - local - np.log(p.beacon_ratio), filled - med - np.log(p.beacon_global_ratio))
        contrast[~pos] = np.nan
        bright = pos & (contrast > 0)
        if np.count_nonzero(bright) > p.beacon_max_fraction * np.count_nonzero(valid):
            return np.empty(0)
    idx = np.flatnonzero(bright)
    if idx.size == 0:
        return np.empty(0)
    # group bright beams closer than beacon_gap_deg (dim or missing beams inside a reflector)
    max_step = max(2, int(np.ceil(np.deg2rad(p.beacon_gap_deg) / abs(prep.step) - 1e-9)))
    groups: list[list[int]] = [[int(idx[0])]]
    for k in idx[1:]:
        if k - groups[-1][-1] <= max_step:
            groups[-1].append(int(k))
        else:
            groups.append([int(k)])
    if prep.circular and len(groups) > 1 and groups[0][0] + prep.r.size - groups[-1][-1] <= max_step:
        groups[0] = groups.pop() + groups[0]
    out = []
    n = prep.r.size
    for g in groups:
        if contrast is not None:
            # the run as a whole, dim beams inside included, must stand out (not only its noisiest beams)
            span = np.arange(g[0], g[-1] + (n if g[-1] < g[0] else 0) + 1) % n
            c_span = contrast[span]
            if not float(np.nanmedian(c_span)) > 0:
                continue
            r_g = float(np.median(prep.r[g]))
            if len(g) < max(1, int(p.beacon_min_width / (r_g * abs(prep.step)))):
                continue
        pts = prep.pts[g]
        width = _norm(pts[-1] - pts[0])
        if width > p.beacon_max_width:
            continue
        w = inten[g]
        c = (pts * w[:, None]).sum(axis=0) / w.sum()
        out.append(float(np.arctan2(c[1], c[0])))
    return np.asarray(out, dtype=np.float64)


def beacon_bearings(scan: Scan, prep: _Prepared, p: LaserParams) -> FArray:
    """The beacons of a scan already segmented (see :func:`_beacons`)."""
    return _beacons(scan, prep, p)
