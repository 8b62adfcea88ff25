"""Laser features from one raw 2D scan: corners, extremities and beacons (docs/METHOD.md §1).

The pipeline, after Arras and Siegwart (the paper's reference [1]):

1. **Segmentation** at range jumps. Two consecutive returns belong to one
   segment when the distance between their end points is below an adaptive
   threshold that grows with range and beam step (the "adaptive breakpoint"
   rule: a surface seen at an incidence of at least ``breakpoint_angle_deg``
   never breaks), plus a few range-noise standard deviations. Runs of beams
   without a return also break segments (isolated drop-outs inside a surface
   are bridged).
2. **Line fitting** by split-and-merge on each segment: split at the point
   farthest from the chord while it lies further than a range-dependent
   tolerance, merge neighbouring nearly collinear pieces, and refit every line
   by total least squares (orthogonal regression).
3. **Corners** where two fitted lines of one segment meet at a real angle, or
   where the last line of a segment and the first line of the next one meet
   near both their ends with the apex between the two boundary beams (a
   corner whose apex fell between two beams). A short surface seen almost
   edge-on gets too few, too sparse returns to stay one segment: when at
   least two returns between two lines lie on the straight line joining
   their ends, that "bridge" gives two corners and no extremity.
4. **Extremities**: line ends at segment ends next to a depth jump on the
   near (occluding) side, or next to beams without a return: the ends of
   walls at door frames, of furniture, of pillars. Not at the scan's border,
   not where the next return continues the same line (a grazing wall thinning
   out), not at ragged clutter that no fitted line reaches.
5. **Beacons** from the intensity (remission) channel: narrow runs of beams
   brighter by a factor than their neighbours (the local median, which
   follows the smooth fall of intensity with range and incidence) and than
   the scan's median. The neighbourhood is measured in metres at each
   beam's range (and at least a few degrees), not in beams, so a reflector
   of up to 15 cm stays narrower than its background window at any beam
   density and range: a 9 cm cylinder at 1 m covers 20 beams of a 0.25 deg
   scanner and 5 of a 1 deg one. Only ratios are used, so sensors with intensity scales
   from hundreds to tens of thousands give the same beacons;
   ``beacon_threshold`` overrides this with an absolute value in the sensor's
   unit. No intensities, no beacons.

Every bearing returned is in radians in the robot frame (the sensor offset is
applied), wrapped to ``[-pi, pi)``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._types import FArray
from ..angles import TWO_PI, wrap
from ..errors import InvalidParameterError
from ..observation import Observation
from ..sensors import Scan
from .laser_beacons import beacon_bearings
from .laser_params import LaserParams

__all__ = [
    "LaserFeatures",
    "LaserParams",
    "extract_laser_features",
    "fit_lines",
    "observation_from_scan",
    "segment_scan",
]


#: Consecutive beams further apart than this many median steps border a blind sector.
_MAX_STEP_RATIO = 3.0

# Boundary kinds between two consecutive segments.
_EDGE = 0  # first or last beam of a scan that does not close the circle
_JUMP = 1  # a depth discontinuity between two returns
_GAP = 2  # one or more beams without a return
_SEAM = 3  # artificial cut of a closed scan without any discontinuity


def _ro(a: object, shape_tail: tuple[int, ...] = ()) -> FArray:
    arr = np.array(a, dtype=np.float64, copy=True)
    if arr.size == 0:
        arr = arr.reshape((0, *shape_tail))
    arr.setflags(write=False)
    return arr


_EIGH: Any = None
try:  # the LAPACK routine of np.linalg.eigh, without its per-call checks (same results)
    from numpy.linalg import _umath_linalg

    _EIGH = _umath_linalg.eigh_lo
except (ImportError, AttributeError):  # pragma: no cover - another numpy layout
    pass


def _eigh(a: FArray) -> tuple[FArray, FArray]:
    """``np.linalg.eigh(a)`` of a real symmetric matrix (the same values, less overhead)."""
    if _EIGH is None:  # pragma: no cover
        w, v = np.linalg.eigh(a)
        return w, v
    w, v = _EIGH(a, signature="d->dd")
    return w, v


def _norm(v: FArray) -> float:
    """``float(np.linalg.norm(v))`` of a 1-D float64 vector (the same value: ``sqrt(v . v)``)."""
    return math.sqrt(float(v.dot(v)))


@dataclass(frozen=True, slots=True, eq=False)
class LaserFeatures:
    """Features extracted from one scan.

    Attributes
    ----------
    corners, extremities, beacons : ndarray of float, shape (n,)
        Bearings in radians, robot frame, wrapped to ``[-pi, pi)``, sorted.
    segments : ndarray of float, shape (k, 2, 2)
        End points ``[[x0, y0], [x1, y1]]`` of the fitted lines, metres, robot
        frame, in scan order.
    """

    corners: FArray
    extremities: FArray
    beacons: FArray
    segments: FArray

    def __post_init__(self) -> None:
        for name in ("corners", "extremities", "beacons"):
            a = np.sort(wrap(np.asarray(getattr(self, name), dtype=np.float64).reshape(-1)))
            object.__setattr__(self, name, _ro(a))
        seg = np.asarray(self.segments, dtype=np.float64)
        if seg.size == 0:
            seg = seg.reshape(0, 2, 2)
        if seg.ndim != 3 or seg.shape[1:] != (2, 2):
            raise InvalidParameterError(f"segments must have shape (k, 2, 2), got {seg.shape}")
        object.__setattr__(self, "segments", _ro(seg, (2, 2)))


# ---------------------------------------------------------------------------
# segmentation


@dataclass(frozen=True, slots=True)
class _Segment:
    start: int  # first beam index (in the rolled arrays)
    stop: int  # one past the last beam index
    before: int  # boundary kind before the first beam
    after: int  # boundary kind after the last beam


def _is_circular(b: FArray, step: float | None = None) -> bool:
    step = float(np.median(np.diff(b))) if step is None else step
    return bool(b[-1] - b[0] + step >= TWO_PI - 0.5 * step)


def _break_threshold(r_prev: FArray, dphi: FArray, p: LaserParams) -> FArray:
    """Largest distance (m) between consecutive returns of one surface (adaptive breakpoint)."""
    lam = np.deg2rad(p.breakpoint_angle_deg)
    dphi = np.minimum(dphi, 0.9 * lam)
    # r sin(dphi) / sin(lambda - dphi) + 3 sigma of a difference of two ranges
    return r_prev * np.sin(dphi) / np.sin(lam - dphi) + 3.0 * np.sqrt(2.0) * p.range_sigma


def segment_scan(scan: Scan, **params: Any) -> tuple[list[tuple[int, int]], FArray]:
    """Split a scan into segments of consecutive returns at range jumps and no-return runs.

    Parameters
    ----------
    scan : Scan
    **params
        Fields of :class:`LaserParams`.

    Returns
    -------
    segments : list of (start, stop)
        Beam index ranges ``start:stop`` into the scan; on a closed 360 deg
        scan a segment may run past the end (``stop > n``; take indices
        modulo ``n``).
    points : ndarray, shape (n, 2)
        End point of every beam in the robot frame, metres (``nan`` without a
        return).
    """
    p = LaserParams.from_kwargs(params)
    prep = _prepare(scan, p)
    segs = [(s.start + prep.shift, s.stop + prep.shift) for s in prep.segments]
    return segs, prep.points_orig


@dataclass(frozen=True, slots=True)
class _Prepared:
    r: FArray  # ranges (rolled), inf = no return
    phi: FArray  # sensor-frame bearings, unwrapped, increasing (rolled)
    pts: FArray  # (n, 2) robot-frame points (rolled), nan without return
    step: float
    shift: int  # rolled index i is original index (i + shift) % n
    circular: bool
    segments: list[_Segment]
    points_orig: FArray


def _prepare(scan: Scan, p: LaserParams) -> _Prepared:
    """Step 1: robot-frame points of a scan and its segments (adaptive breakpoints, bridged drop-outs).

    A closed 360 deg scan is rolled so that index 0 starts right after a
    discontinuity; every index of the result refers to the rolled arrays.

    Parameters
    ----------
    scan : Scan
        Ranges in metres (``inf`` = no return) at increasing bearings in radians.
    p : LaserParams

    Returns
    -------
    _Prepared
        Rolled ranges (m) and bearings (rad, sensor frame), shape (n,);
        points (m, robot frame), shape (n, 2); the median beam step (rad);
        the roll; the segments with their boundary kinds; and the unrolled
        points, shape (n, 2).
    """
    r = np.asarray(scan.ranges, dtype=np.float64)
    b = np.asarray(scan.bearings, dtype=np.float64)
    n = r.size
    ox, oy, oth = scan.sensor_offset
    valid = np.isfinite(r)
    with np.errstate(invalid="ignore"):
        pts = np.column_stack([ox + r * np.cos(b + oth), oy + r * np.sin(b + oth)])
    pts[~valid] = np.nan
    points_orig = pts.copy()
    step = float(np.median(np.diff(b)))
    circular = _is_circular(b, step)

    # consecutive-pair "connected" flags, pair k joins beam k and k+1
    def connected(rr: FArray, pp: FArray, phi: FArray) -> NDArray[np.bool_]:
        d = np.linalg.norm(np.diff(pp, axis=0), axis=1)
        dphi = np.diff(phi)
        thr = _break_threshold(np.minimum(rr[:-1], rr[1:]), dphi, p)
        with np.errstate(invalid="ignore"):
            return np.asarray((d <= thr) & (dphi <= _MAX_STEP_RATIO * step))

    shift = 0
    if circular:
        # roll so that index 0 starts right after a discontinuity (or at the farthest return)
        rr = np.concatenate([r, r[:1]])
        pp = np.concatenate([pts, pts[:1]])
        phi = np.concatenate([b, b[:1] + TWO_PI])
        con = connected(rr, pp, phi)
        breaks = np.flatnonzero(~con)
        if breaks.size:
            # prefer a cut at a no-return beam, then the largest jump
            inval = np.flatnonzero(~valid)
            shift = int(inval[0]) if inval.size else int((breaks[np.argmax(np.abs(np.diff(rr)[breaks]))] + 1) % n)
        else:
            shift = int(np.argmax(np.where(valid, r, -np.inf)))
        r = np.roll(r, -shift)
        b = np.roll(b, -shift)
        b = np.where(np.arange(n) >= n - shift, b + TWO_PI, b) if shift else b
        pts = np.roll(pts, -shift, axis=0)
        valid = np.isfinite(r)
    con = connected(r, pts, b)

    segments: list[_Segment] = []
    i = 0
    while i < n:
        if not valid[i]:
            i += 1
            continue
        start = i
        j = i
        while True:
            if j + 1 < n and valid[j + 1] and con[j]:
                j += 1
                continue
            # try to bridge a short run of no-return beams
            if p.max_bridge_beams and j + 1 < n and not valid[j + 1]:
                k = j + 1
                while k < n and not valid[k] and k - j - 1 < p.max_bridge_beams:
                    k += 1
                if k < n and valid[k] and b[k] - b[j] <= _MAX_STEP_RATIO * step * (k - j):
                    d = _norm(pts[k] - pts[j])
                    thr = float(_break_threshold(np.array([min(r[j], r[k])]), np.array([b[k] - b[j]]), p)[0])
                    if d <= thr:
                        j = k
                        continue
            break
        stop = j + 1
        # a hole in the bearings (two heads with a blind sector between them) is a border, not a jump
        blind_before = start > 0 and b[start] - b[start - 1] > _MAX_STEP_RATIO * step
        blind_after = stop < n and b[stop] - b[stop - 1] > _MAX_STEP_RATIO * step
        before = _EDGE if start == 0 or blind_before else (_GAP if not valid[start - 1] else _JUMP)
        after = _EDGE if stop == n or blind_after else (_GAP if not valid[stop] else _JUMP)
        segments.append(_Segment(start, stop, before, after))
        i = stop

    if circular and segments:
        # the boundary across the roll point
        first, last = segments[0], segments[-1]
        if first.start == 0 and last.stop == n:
            # index n-1 and 0 are neighbours
            rr = np.array([min(r[-1], r[0])])
            d = _norm(pts[0] - pts[-1])
            thr = float(_break_threshold(rr, np.array([step]), p)[0])
            kind = _SEAM if d <= thr else _JUMP
        else:
            kind = _GAP
        segments[0] = _Segment(first.start, first.stop, kind, first.after)
        last = segments[-1]
        segments[-1] = _Segment(last.start, last.stop, last.before, kind)
    return _Prepared(r, b, pts, step, shift, circular, segments, points_orig)


# ---------------------------------------------------------------------------
# line fitting


@dataclass(frozen=True, slots=True)
class _Line:
    start: int  # first beam index (rolled arrays)
    stop: int  # one past the last
    centroid: FArray  # (2,)
    direction: FArray  # (2,) unit, pointing from start to stop
    p0: FArray  # projected first point
    p1: FArray  # projected last point


def _tol(r: FArray, p: LaserParams) -> FArray:
    """Split tolerance (m) at ranges ``r``: a floor that covers the range noise, plus a part of the range."""
    return max(p.split_tol, 4.0 * p.range_sigma) + p.split_tol_rel * r


def _tls(pts: FArray) -> tuple[FArray, FArray, float]:
    """Total-least-squares line: centroid, unit direction, RMS orthogonal residual (m)."""
    c = np.add.reduce(pts, axis=0) / len(pts)  # pts.mean(axis=0), without its overhead
    q = pts - c
    cov = q.T @ q
    _, v = _eigh(cov)
    d = v[:, 1]
    if np.dot(pts[-1] - pts[0], d) < 0:
        d = -d
    normal = np.array([-d[1], d[0]])
    rms = float(np.sqrt(np.add.reduce((q @ normal) ** 2) / len(pts))) if len(pts) else 0.0
    return c, d, rms


def _make_line(pts: FArray, start: int, stop: int, margin: int) -> _Line:
    sub = pts[start:stop]
    fit_pts = sub[margin : len(sub) - margin] if len(sub) - 2 * margin >= 3 else sub
    c, d, _ = _tls(fit_pts)
    t0 = float(np.dot(sub[0] - c, d))
    t1 = float(np.dot(sub[-1] - c, d))
    return _Line(start, stop, c, d, c + t0 * d, c + t1 * d)


def _fit_segment(all_pts: FArray, all_rng: FArray, seg: _Segment, p: LaserParams) -> list[_Line]:
    """Split-and-merge lines of one segment; line indices refer to the full (rolled) beam arrays."""
    idx = np.arange(seg.start, seg.stop)
    idx = idx[np.isfinite(all_rng[idx])]  # bridged drop-outs have no point
    pts, rng = all_pts[idx], all_rng[idx]
    from ._laser_kernels import split_pieces

    pieces = split_pieces(np.ascontiguousarray(pts, dtype=np.float64), _tol(rng, p)).tolist()
    # neighbouring pieces share their split point; each fit leaves out its two end points
    lines: list[_Line] = []
    for lo, hi in pieces:
        if hi - lo < p.min_line_points:
            lines.append(_Line(lo, hi, np.zeros(2), np.zeros(2), pts[lo], pts[hi - 1]))  # placeholder: clutter
            continue
        lines.append(_make_line(pts, lo, hi, 1))
    # merge neighbouring collinear lines
    min_cos = np.cos(np.deg2rad(p.merge_angle_deg))
    merged = True
    while merged and len(lines) > 1:
        merged = False
        for i in range(len(lines) - 1):
            a, bl = lines[i], lines[i + 1]
            if not (_is_line(a) and _is_line(bl)):
                continue
            cosang = abs(float(np.dot(a.direction, bl.direction)))
            if cosang < min_cos:
                continue
            lo, hi = a.start, bl.stop
            _, _, rms = _tls(pts[lo:hi])
            if rms <= 0.5 * float(np.max(_tol(rng[lo:hi], p))):
                lines[i : i + 2] = [_make_line(pts, lo, hi, 1)]
                merged = True
                break
    out = []
    for ln in lines:
        if not _is_line(ln):
            continue
        if _norm(ln.p1 - ln.p0) < p.min_line_length:
            continue
        start, stop = int(idx[ln.start]), int(idx[ln.stop - 1]) + 1
        out.append(_Line(start, stop, ln.centroid, ln.direction, ln.p0, ln.p1))
    return out


def _is_line(ln: _Line) -> bool:
    return bool(ln.direction[0] != 0 or ln.direction[1] != 0)


def fit_lines(scan: Scan, **params: Any) -> FArray:
    """Fitted line segments of a scan (split-and-merge, total-least-squares refits).

    Returns
    -------
    ndarray of float, shape (k, 2, 2)
        End points of each line, metres, robot frame, in scan order.
    """
    return extract_laser_features(scan, **params).segments


# ---------------------------------------------------------------------------
# features


def _intersect(a: _Line, b: _Line) -> FArray | None:
    # solve a.c + s a.d = b.c + t b.d
    m = np.column_stack([a.direction, -b.direction])
    det = float(np.linalg.det(m))
    if abs(det) < 1e-9:
        return None
    s, _ = np.linalg.solve(m, b.centroid - a.centroid)
    return np.asarray(a.centroid + s * a.direction)


def _corner(a: _Line, b: _Line, p: LaserParams) -> FArray | None:
    """Intersection of ``a`` (ending) and ``b`` (starting) when they form a corner near their facing ends."""
    cosang = abs(float(np.dot(a.direction, b.direction)))
    if cosang > np.cos(np.deg2rad(p.corner_min_angle_deg)):
        return None
    x = _intersect(a, b)
    if x is None:
        return None
    if _norm(x - a.p1) > p.corner_max_dist or _norm(x - b.p0) > p.corner_max_dist:
        return None
    return x


def _bridge_pairs(prep: _Prepared, seg_lines: list[list[_Line]], p: LaserParams) -> list[tuple[int, int]]:
    """Pairs ``(i, j)`` of segments with lines separated only by jumps and clutter segments."""
    segs = prep.segments
    nseg = len(segs)
    out: list[tuple[int, int]] = []
    for i in range(nseg):
        if not seg_lines[i] or segs[i].after != _JUMP:
            continue
        k = i + 1
        while True:
            if k >= nseg:
                if not prep.circular:
                    break
                k -= nseg
            if k == i:
                break
            if seg_lines[k]:
                out.append((i, k))
                break
            if segs[k].stop - segs[k].start >= p.min_segment_points or segs[k].after != _JUMP:
                break
            k += 1
    return out


def _bridge(a: _Line, b: _Line, prep: _Prepared, p: LaserParams) -> list[FArray] | None:
    """Two corners where a surface seen nearly edge-on joins line ``a`` to line ``b`` across a jump.

    At grazing incidence a short surface (the side of a cabinet, a wall recess)
    gets only a couple of returns, too far apart to stay one segment. When at
    least ``bridge_min_points`` returns between the end of ``a`` and the start
    of ``b`` lie on the straight line from ``a``'s end to ``b``'s start, and
    that line is long enough and meets both at a real angle, the two meeting
    points are corners and neither end is an extremity.
    """
    n = prep.r.size
    stop = b.start if b.start >= a.stop else b.start + n  # across the roll point of a closed scan
    idx = np.arange(a.stop, stop) % n
    idx = idx[np.isfinite(prep.r[idx])]
    if idx.size < p.bridge_min_points:
        return None
    pq = b.p0 - a.p1
    length = _norm(pq)
    if not p.min_line_length <= length <= p.bridge_max_length:
        return None
    d = pq / length
    cos_min = np.cos(np.deg2rad(p.corner_min_angle_deg))
    if abs(float(np.dot(d, a.direction))) > cos_min or abs(float(np.dot(d, b.direction))) > cos_min:
        return None
    normal = np.array([-d[1], d[0]])
    off = np.abs((prep.pts[idx] - a.p1) @ normal)
    along = (prep.pts[idx] - a.p1) @ d
    tol = 2.0 * _tol(prep.r[idx], p)
    if np.any(off > tol) or np.any(along < -tol) or np.any(along > length + tol):
        return None
    # the returns must spread along the bridge, not bunch at one end (a door jamb before a far wall)
    stops = np.sort(np.r_[0.0, along, length])
    if float(np.max(np.diff(stops))) > p.bridge_max_gap * length:
        return None
    return [np.array(a.p1), np.array(b.p0)]


# ---------------------------------------------------------------------------
# the extractor's steps


def _fit_segment_lines(prep: _Prepared, p: LaserParams) -> list[list[_Line]]:
    """Step 2: split-and-merge lines of every segment (clutter segments get none).

    Parameters
    ----------
    prep : _Prepared
        The segmented scan (:func:`_prepare`).
    p : LaserParams

    Returns
    -------
    list of list of _Line
        One list per segment of ``prep.segments`` (same order), the segment's
        fitted lines in scan order; empty for a segment of fewer than
        ``max(min_segment_points, 2)`` beams. Line end points in metres,
        robot frame; beam indices into the rolled arrays.
    """
    seg_lines: list[list[_Line]] = []
    for seg in prep.segments:
        if seg.stop - seg.start < max(p.min_segment_points, 2):
            seg_lines.append([])
            continue
        seg_lines.append(_fit_segment(prep.pts, prep.r, seg, p))
    return seg_lines


def _inner_corners(seg_lines: list[list[_Line]], p: LaserParams) -> list[FArray]:
    """Step 3a: corners where two consecutive fitted lines of one segment meet at a real angle.

    Parameters
    ----------
    seg_lines : list of list of _Line
        Lines per segment (:func:`_fit_segment_lines`).
    p : LaserParams

    Returns
    -------
    list of ndarray, shape (2,)
        Corner apexes ``(x, y)``, metres, robot frame, in scan order.
    """
    corners: list[FArray] = []
    for lines in seg_lines:
        for a, b in itertools.pairwise(lines):
            x = _corner(a, b, p)
            if x is not None:
                corners.append(x)
    return corners


def _bridge_corners(
    prep: _Prepared, seg_lines: list[list[_Line]], p: LaserParams
) -> tuple[list[FArray], set[tuple[int, int]]]:
    """Step 3b: pairs of corners where a short surface seen edge-on joins two segments (:func:`_bridge`).

    Parameters
    ----------
    prep : _Prepared
        The segmented scan.
    seg_lines : list of list of _Line
        Lines per segment (:func:`_fit_segment_lines`).
    p : LaserParams

    Returns
    -------
    corners : list of ndarray, shape (2,)
        Corner apexes ``(x, y)``, metres, robot frame (two per bridge).
    bridged : set of (int, int)
        ``(segment index, end)`` of the segment ends joined by a bridge
        (end 0 the first beam, 1 the last): neither a boundary corner nor an
        extremity.
    """
    corners: list[FArray] = []
    bridged: set[tuple[int, int]] = set()
    for i, j in _bridge_pairs(prep, seg_lines, p):
        bridge = _bridge(seg_lines[i][-1], seg_lines[j][0], prep, p)
        if bridge is not None:
            corners.extend(bridge)
            bridged.update({(i, 1), (j, 0)})
    return corners, bridged


def _boundary_pairs(prep: _Prepared) -> list[tuple[int, int]]:
    """Indices ``(i, j)`` of neighbouring segments: ``j`` follows ``i``, across the roll point of a closed scan."""
    nseg = len(prep.segments)
    pairs = [(i, i + 1) for i in range(nseg - 1)]
    if prep.circular and nseg >= 1 and prep.segments[0].before in (_SEAM, _JUMP):
        pairs.append((nseg - 1, 0))
    return pairs


def _boundary_corners(
    scan: Scan, prep: _Prepared, seg_lines: list[list[_Line]], bridged: set[tuple[int, int]], p: LaserParams
) -> list[FArray]:
    """Step 3c: corners across the boundary between neighbouring segments (apex between two beams).

    The last line of a segment and the first line of the next one, both
    reaching their segment's boundary, make a corner when they meet near both
    their ends and the apex's bearing lies between the two boundary beams
    (within half a beam step); across a seam of a closed scan any meeting counts.

    Parameters
    ----------
    scan : Scan
        The raw scan (its ``sensor_offset``: metres, metres, radians).
    prep : _Prepared
        The segmented scan.
    seg_lines : list of list of _Line
        Lines per segment (:func:`_fit_segment_lines`).
    bridged : set of (int, int)
        Segment ends already joined by a bridge (:func:`_bridge_corners`).
    p : LaserParams

    Returns
    -------
    list of ndarray, shape (2,)
        Corner apexes ``(x, y)``, metres, robot frame, in scan order.
    """
    half = 0.5 * prep.step
    corners: list[FArray] = []
    for i, j in _boundary_pairs(prep):
        si, sj = prep.segments[i], prep.segments[j]
        if si.after not in (_JUMP, _SEAM) or not seg_lines[i] or not seg_lines[j]:
            continue
        if (i, 1) in bridged:
            continue
        a, b = seg_lines[i][-1], seg_lines[j][0]
        if a.stop != si.stop or b.start != sj.start:
            continue  # clutter at the segment end
        if i == j and len(seg_lines[i]) < 2:
            continue
        x = _corner(a, b, p)
        if x is None:
            continue
        # the apex must fall between the two boundary beams; beyond them it is the extension of
        # an occluding surface meeting a wall behind it, not a corner
        ox, oy, oth = scan.sensor_offset
        apex = float(np.arctan2(x[1] - oy, x[0] - ox)) - oth
        lo, hi = prep.phi[si.stop - 1], prep.phi[sj.start]
        if si.after == _SEAM or (float(wrap(apex - lo)) >= -half and float(wrap(hi - apex)) >= -half):
            corners.append(x)
    return corners


def _end_is_hidden(scan: Scan, prep: _Prepared, line: _Line, end: int, kind: int, sign: int, p: LaserParams) -> bool:
    """Whether the nearest return across a segment end keeps that end from being an extremity.

    Looks at the next beam beyond ``end`` (up to ``max_bridge_beams + 1``
    beams across a no-return run). The end is no extremity when that return
    is not farther (``end`` does not occlude it, within three range sigmas)
    or lies on the extension of ``line`` (a grazing wall whose returns thin
    out). No return within reach: not hidden.

    Parameters
    ----------
    scan : Scan
        The raw scan (``sensor_offset`` in metres and radians).
    prep : _Prepared
        The segmented scan.
    line : _Line
        The fitted line at this end of the segment.
    end : int
        Beam index (rolled arrays) of the segment's first or last beam.
    kind : int
        Boundary kind on that side (``_JUMP`` or ``_GAP``).
    sign : {-1, +1}
        Direction across the boundary: -1 before the first beam, +1 after the last.
    p : LaserParams

    Returns
    -------
    bool
    """
    pts, rng = prep.pts, prep.r
    n = rng.size
    look = p.max_bridge_beams + 1  # how far across a no-return run a neighbour may occlude
    for d in range(1, look + 1 if kind == _GAP else 2):
        nb = end + sign * d
        if not prep.circular and not 0 <= nb < n:
            break
        nb %= n
        if np.isfinite(rng[nb]):
            normal = np.array([-line.direction[1], line.direction[0]])
            off = abs(float(np.dot(pts[nb] - line.centroid, normal)))
            # expected spacing of returns along this line at its end: r dphi / sin(incidence)
            beam = pts[end] - np.asarray(scan.sensor_offset[:2])
            u = beam / np.linalg.norm(beam)
            sin_inc = abs(float(u[0] * line.direction[1] - u[1] * line.direction[0]))
            spacing = rng[end] * d * prep.step / max(sin_inc, np.sin(2 * prep.step))
            along = abs(float(np.dot(pts[nb] - pts[end], line.direction)))
            on_extension = off <= 2.0 * float(_tol(rng[nb], p)) and along <= 4.0 * spacing
            return bool(rng[nb] <= rng[end] + 3.0 * p.range_sigma) or on_extension
    return False


def _extremity_bearing(scan: Scan, prep: _Prepared, end: int, sign: int) -> float:
    """Bearing (radians, robot frame, in ``[-pi, pi]``) of a surface's end half a beam step beyond beam ``end``.

    The surface ends between two beams: the point at beam ``end``'s range,
    half a step towards the boundary (``sign`` -1 before, +1 after).
    """
    half = 0.5 * prep.step
    phi = prep.phi[end] + sign * half + scan.sensor_offset[2]
    q = np.array([scan.sensor_offset[0], scan.sensor_offset[1]]) + prep.r[end] * np.array([np.cos(phi), np.sin(phi)])
    return float(np.arctan2(q[1], q[0]))


def _extremities(
    scan: Scan, prep: _Prepared, seg_lines: list[list[_Line]], bridged: set[tuple[int, int]], p: LaserParams
) -> list[float]:
    """Step 4: line extremities at segment ends that occlude what lies beyond them.

    Only segments of at least ``min_segment_points`` beams with a fitted line
    and an extent of at least ``min_extremity_extent`` metres count; an end
    gives no extremity at the scan's border or a seam, when a bridge joins it
    (``bridged``), when no fitted line reaches within ``extremity_max_tail``
    of it, or when the return beyond it hides it (:func:`_end_is_hidden`).

    Parameters
    ----------
    scan : Scan
        The raw scan.
    prep : _Prepared
        The segmented scan.
    seg_lines : list of list of _Line
        Lines per segment (:func:`_fit_segment_lines`).
    bridged : set of (int, int)
        Segment ends joined by a bridge (:func:`_bridge_corners`).
    p : LaserParams

    Returns
    -------
    list of float
        Bearings, radians, robot frame, in scan order (first end before last).
    """
    pts = prep.pts
    extremities: list[float] = []
    for k, seg in enumerate(prep.segments):
        lines = seg_lines[k]
        if seg.stop - seg.start < p.min_segment_points or not lines:
            continue
        first, last = seg.start, seg.stop - 1
        if _norm(pts[last] - pts[first]) < p.min_extremity_extent:
            continue
        for end, kind, sign, line, tip in (
            (first, seg.before, -1, lines[0], lines[0].p0),
            (last, seg.after, +1, lines[-1], lines[-1].p1),
        ):
            if (k, 0 if sign < 0 else 1) in bridged:
                continue  # a surface seen edge-on joins this end to the next segment
            on_line = _norm(tip - pts[end]) <= p.extremity_max_tail
            if kind in (_EDGE, _SEAM) or not on_line:
                continue  # the scan's border, or a ragged (non-line) end
            if _end_is_hidden(scan, prep, line, end, kind, sign, p):
                continue
            extremities.append(_extremity_bearing(scan, prep, end, sign))
    return extremities


def _wall_segments(seg_lines: list[list[_Line]]) -> FArray:
    """End points of all fitted lines, ndarray of shape (k, 2, 2), metres, robot frame, in scan order."""
    segments = np.array([[ln.p0, ln.p1] for lines in seg_lines for ln in lines], dtype=np.float64)
    return segments.reshape(-1, 2, 2)


def _assemble(corners: list[FArray], extremities: list[float], beacons: FArray, segments: FArray) -> LaserFeatures:
    """Step 6: the :class:`LaserFeatures` of one scan.

    Parameters
    ----------
    corners : list of ndarray, shape (2,)
        Corner apexes ``(x, y)``, metres, robot frame; turned into bearings.
    extremities : list of float
        Extremity bearings, radians, robot frame.
    beacons : ndarray, shape (m,)
        Beacon bearings, radians, robot frame.
    segments : ndarray, shape (k, 2, 2)
        Fitted lines, metres, robot frame.

    Returns
    -------
    LaserFeatures
        Bearings wrapped to ``[-pi, pi)`` and sorted.
    """
    cb = np.array([np.arctan2(x[1], x[0]) for x in corners], dtype=np.float64)
    return LaserFeatures(
        corners=cb,
        extremities=np.asarray(extremities, dtype=np.float64),
        beacons=beacons,
        segments=segments,
    )


def extract_laser_features(scan: Scan, **params: Any) -> LaserFeatures:
    """Corners, extremities and beacons of one raw scan (see the module docstring).

    Parameters
    ----------
    scan : Scan
        Ranges in metres (``inf`` = no return), increasing bearings; any
        field of view up to 360 deg; intensities optional.
    **params
        Fields of :class:`LaserParams` (e.g. ``range_sigma=0.01``,
        ``beacon_threshold=5000``).

    Returns
    -------
    LaserFeatures
        Bearings in radians, robot frame, wrapped; fitted lines in metres.
    """
    p = LaserParams.from_kwargs(params)
    prep = _prepare(scan, p)
    seg_lines = _fit_segment_lines(prep, p)
    bridge_corners, bridged = _bridge_corners(prep, seg_lines, p)
    corners = _inner_corners(seg_lines, p) + bridge_corners + _boundary_corners(scan, prep, seg_lines, bridged, p)
    extremities = _extremities(scan, prep, seg_lines, bridged, p)
    return _assemble(corners, extremities, beacon_bearings(scan, prep, p), _wall_segments(seg_lines))


def observation_from_scan(
    scan: Scan, *, label: str | None = None, walls: bool = True, ranges: bool = True, **params: Any
) -> Observation:
    """A laser-only :class:`Observation` of one scan: corners ``c``, extremities ``Ex``, beacons ``B``.

    With ``walls`` (default) the fitted line segments become wall features
    ``W`` (midpoint bearing, length, midpoint range), and with ``ranges``
    (default) the scan's raw range profile is kept (``Observation.ranges``):
    both feed our laser extensions (laser letters in the fingerprint, the
    range term ``R``) and cost nothing to the paper's terms. The field of view
    is the scan's own (``scan.fov``); pose and timestamp are copied from the
    scan.
    """
    f = extract_laser_features(scan, **params)
    seg = f.segments
    if walls and seg.shape[0]:
        mid = seg.mean(axis=1)
        w = np.arctan2(mid[:, 1], mid[:, 0])
        w_length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)
        w_range = np.linalg.norm(mid, axis=1)
        keep = (w_length > 0) & (w_range > 0)
        w, w_length, w_range = w[keep], w_length[keep], w_range[keep]
    else:
        w = w_length = w_range = np.empty(0)
    return Observation(
        c=f.corners,
        ex=f.extremities,
        b=f.beacons,
        w=w,
        w_length=w_length,
        w_range=w_range,
        ranges=scan.ranges if ranges else None,
        range_bearings=scan.bearings + scan.sensor_offset[2] if ranges else None,
        fov=scan.fov,
        label=label,
        pose=scan.pose,
        timestamp=scan.timestamp,
    )
