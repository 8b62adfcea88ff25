"""Scan-to-place verification: which place a laser scan was taken at, by fitting it into the mapping run's scan map.

The fingerprint program answers *which place* from a scan's features; on a
2D laser those are few (corners, wall ends) and its single-shot answer is
right about two times in five on real logs. A map made from a run with
poses also holds the run's laser end points (:class:`~fingerloc.map.scan_map.ScanMap`,
a likelihood field). A query scan taken at place ``j`` fits that map well
at some pose inside ``j``'s disc (its radius around the centre) and at some
heading; taken elsewhere, it fits worse. :class:`ScanVerifier` finds, for
every place, the best mean end-point log-likelihood over the poses of its
disc and every heading (the scan map's score,
:meth:`~fingerloc.map.scan_map.ScanMap.log_likelihood`):

1. a coarse grid (every ``step`` metres of the disc, every ``turn``
   degrees) on a blurred copy of the field (its end points' spread
   ``sigma`` wider, so that a grid pose near the best one already scores
   well), every ``stride``-th end point; first over every place on a coarse
   grid (``prune``), then over the ``keep`` best places on a finer one;
2. a hill climb of the best grid poses of the ``refine`` best places on
   the sharp field (0.1 m, 2 deg, then half, then a quarter), the position
   kept within the disc (plus ``margin``).

The verified answer combines both (:class:`Verification`)::

    log P(place j | scan) = program * log P_program(j | scan) + scan * fit_j - log Z

with the two weights fitted on the mapping part's held-out rows
(:func:`fit_verification`: each row scored by a program fit without it and
against a scan map without it, the weights maximise the held-out
log-probability of the right place). :func:`verify_candidates` is the whole
front end for a map: the program's log-posterior in, the verified one out.

Units: metres, radians inside (``turn_deg`` in degrees); points in the robot frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .._lse import logsumexp
from .._types import FArray
from ..errors import InvalidParameterError
from .scan_map import ScanMap

__all__ = [
    "CALIBRATION_ROWS",
    "MAX_PROGRAM_WEIGHT",
    "MAX_SCAN_WEIGHT",
    "ScanVerifier",
    "Verification",
    "VerifySearch",
    "calibrate_verification",
    "fit_verification",
    "map_without",
    "verify_candidates",
]

#: Largest weight :func:`fit_verification` gives the program's log-posterior (it is a log-probability already).
MAX_PROGRAM_WEIGHT = 4.0
#: Largest weight of the scan fit (nats per unit of mean end-point log-likelihood).
MAX_SCAN_WEIGHT = 60.0
#: Held-out rows :func:`calibrate_verification` fits the weights on, at most (evenly spaced).
CALIBRATION_ROWS = 120


@dataclass(frozen=True, slots=True)
class VerifySearch:
    """How :class:`ScanVerifier` searches a place's disc (module docstring).

    Attributes
    ----------
    prune_step, prune_turn_deg, prune_sigma, prune_stride
        The first grid, over every place: metres between positions, degrees
        between headings, the blurred field's sigma (metres), every how many
        end points are scored.
    keep : int
        Places kept for the finer grid (every place when there are no more).
    step, turn_deg, sigma, stride
        The finer grid over the kept places.
    refine : int
        Places whose best grid poses are refined on the sharp field.
    starts : int
        Grid poses refined per place.
    margin : float
        Metres beyond the place radius a pose may lie.
    """

    prune_step: float = 0.4
    prune_turn_deg: float = 6.0
    prune_sigma: float = 0.5
    prune_stride: int = 2
    keep: int = 12
    step: float = 0.2
    turn_deg: float = 4.0
    sigma: float = 0.3
    stride: int = 2
    refine: int = 6
    starts: int = 2
    margin: float = 0.1

    def __post_init__(self) -> None:
        for name in ("prune_step", "prune_turn_deg", "prune_sigma", "step", "turn_deg", "sigma"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidParameterError(f"{name} must be a finite number > 0, got {v!r}")
        for name in ("prune_stride", "keep", "stride", "refine", "starts"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise InvalidParameterError(f"{name} must be an integer >= 1, got {v!r}")
        if not (isinstance(self.margin, (int, float)) and math.isfinite(self.margin) and self.margin >= 0):
            raise InvalidParameterError(f"margin must be a finite number >= 0 (metres), got {self.margin!r}")


def _blurred(scan_map: ScanMap, sigma: float) -> ScanMap:
    """The same end points with a wider spread (the grid search's field)."""
    return ScanMap(scan_map.origin, scan_map.resolution, scan_map.shape, scan_map.cells, sigma=float(sigma),
                   floor=scan_map.floor, clip=max(scan_map.clip, 3.0 * float(sigma)))  # fmt: skip


class ScanVerifier:
    """The best fit of a scan into a scan map at each place (module docstring).

    Parameters
    ----------
    scan_map : ScanMap
        The mapping run's end points (mapping frame).
    centres : array_like, shape (P, 2)
        Place centres, metres.
    radius : float
        Metres: a scan taken at place ``j`` was taken within this of its centre.
    search : VerifySearch, optional
    """

    def __init__(self, scan_map: ScanMap, centres: Any, radius: float, search: VerifySearch | None = None) -> None:
        if not isinstance(scan_map, ScanMap):
            raise InvalidParameterError(f"scan_map must be a ScanMap, got {scan_map!r}")
        c = np.asarray(centres, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] != 2 or c.shape[0] == 0 or not np.all(np.isfinite(c)):
            raise InvalidParameterError(f"centres must be a finite array of shape (P >= 1, 2), got {c.shape}")
        r = float(radius)
        if not (math.isfinite(r) and r > 0):
            raise InvalidParameterError(f"radius must be a finite number of metres > 0, got {radius!r}")
        self.scan_map = scan_map
        self.centres = c
        self.radius = r
        self.search = VerifySearch() if search is None else search
        s = self.search
        self.limit = r + s.margin
        res = scan_map.resolution
        self._cells = np.floor((c - scan_map.origin) / res).astype(np.int64)
        self._grid_centres = scan_map.origin + (self._cells + 0.5) * res  # positions are cell centres
        self._levels = []
        for step, turn, sigma, stride in ((s.prune_step, s.prune_turn_deg, s.prune_sigma, s.prune_stride),
                                          (s.step, s.turn_deg, s.sigma, s.stride)):  # fmt: skip
            k = max(1, round(step / res))
            n = math.ceil(self.limit / (k * res))
            g = np.arange(-n, n + 1) * k
            ii, jj = np.meshgrid(g, g, indexing="ij")
            inside = (ii * res) ** 2 + (jj * res) ** 2 <= self.limit**2 + 1e-9
            th = np.radians(np.arange(0.0, 360.0, turn))
            self._levels.append((ii[inside].astype(np.int64), jj[inside].astype(np.int64), th, _blurred(scan_map, sigma),
                                 int(stride)))  # fmt: skip

    @property
    def n_places(self) -> int:
        """Number of places ``P``."""
        return int(self.centres.shape[0])

    def _grid(self, level: int, points: FArray, places: Any) -> FArray:
        from ._verify_kernels import grid_fits

        oi, oj, th, field, stride = self._levels[level]
        q = np.ascontiguousarray(points[::stride])
        table, _, _, inv_res, outside = field._field()
        out = np.empty((len(places), oi.size, th.size))
        pl = np.asarray(places, dtype=np.int64)
        grid_fits(np.ascontiguousarray(q[:, 0]), np.ascontiguousarray(q[:, 1]), np.cos(th), np.sin(th),
                  np.ascontiguousarray(self._cells[pl, 0]), np.ascontiguousarray(self._cells[pl, 1]), oi, oj, table,
                  inv_res, outside, out)  # fmt: skip
        return out.reshape(len(places), -1)

    def _pose(self, level: int, place: int, flat_index: Any) -> FArray:
        oi, oj, th, _, _ = self._levels[level]
        k, h = np.divmod(np.asarray(flat_index, dtype=np.int64), th.size)
        res = self.scan_map.resolution
        gc = self._grid_centres[place]
        return np.column_stack([gc[0] + oi[k] * res, gc[1] + oj[k] * res, th[h]])

    def fits(self, points: Any) -> tuple[FArray, FArray]:
        """The best fit of one scan at every place, and the pose where it was found.

        Parameters
        ----------
        points : array_like, shape (m, 2)
            The scan's end points, robot frame, metres
            (:func:`~fingerloc.map.scan_map.end_points`).

        Returns
        -------
        fits : ndarray, shape (P,)
            The mean end-point log-likelihood on the sharp field at the best
            pose found (0 everywhere for a scan without end points).
        poses : ndarray, shape (P, 3)
            Those poses (x, y metres, theta radians, mapping frame; NaN for
            a scan without end points).
        """
        from ._verify_kernels import refine

        q = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        P = self.n_places
        if q.shape[0] == 0:
            return np.zeros(P), np.full((P, 3), np.nan)
        if not np.all(np.isfinite(q)):
            raise InvalidParameterError("end points must be finite")
        s = self.search
        allp = np.arange(P)
        g0 = self._grid(0, q, allp)
        best0 = g0.max(axis=1)
        kept = np.sort(np.argsort(-best0, kind="stable")[: min(s.keep, P)])
        g1 = self._grid(1, q, kept)
        best1 = g1.max(axis=1)
        order = kept[np.argsort(-best1, kind="stable")]
        n_ref = min(s.refine, kept.size)
        row_of = {int(p): r for r, p in enumerate(kept.tolist())}
        starts: list[FArray] = []
        owner: list[int] = []
        levels: list[int] = []
        for rank, p in enumerate(order.tolist()):
            g = g1[row_of[p]]
            ns = s.starts if rank < n_ref else 1
            top = np.argpartition(-g, ns - 1)[:ns] if ns < g.size else np.arange(g.size)
            starts.append(self._pose(1, p, top))
            owner += [p] * top.size
            levels += [3 if rank < n_ref else 0] * top.size
        dropped = np.setdiff1d(allp, kept)
        if dropped.size:
            starts.append(np.vstack([self._pose(0, int(p), [int(np.argmax(g0[p]))]) for p in dropped.tolist()]))
            owner += dropped.tolist()
            levels += [0] * dropped.size
        st = np.vstack(starts)
        own = np.asarray(owner, dtype=np.int64)
        lev = np.asarray(levels, dtype=np.int64)
        table, ox, oy, inv_res, outside = self.scan_map._field()
        qx, qy = np.ascontiguousarray(q[:, 0]), np.ascontiguousarray(q[:, 1])
        val = np.empty(st.shape[0])
        pose = np.empty((st.shape[0], 3))
        steps = np.array([0.1, 0.05, 0.025])
        turns = np.radians([2.0, 1.0, 0.5])
        for n_lev in (3, 0):
            sel = np.flatnonzero(lev == n_lev)
            if sel.size == 0:
                continue
            v = np.empty(sel.size)
            ps = np.empty((sel.size, 3))
            refine(qx, qy, np.ascontiguousarray(st[sel]), np.ascontiguousarray(self.centres[own[sel], 0]),
                   np.ascontiguousarray(self.centres[own[sel], 1]), self.limit + self.scan_map.resolution,
                   steps[:n_lev], turns[:n_lev], table, ox, oy, inv_res, outside, v, ps)  # fmt: skip
            val[sel], pose[sel] = v, ps
        fits = np.full(P, -np.inf)
        poses = np.full((P, 3), np.nan)
        for i in range(own.size):  # the best start of each place
            p = int(own[i])
            if val[i] > fits[p]:
                fits[p], poses[p] = val[i], pose[i]
        return fits, poses

    def fit_rows(self, points: Sequence[Any]) -> tuple[FArray, FArray]:
        """:meth:`fits` of each scan: ``(n, P)`` fits and ``(n, P, 3)`` poses (``None`` entries: no end points)."""
        out = np.zeros((len(points), self.n_places))
        poses = np.full((len(points), self.n_places, 3), np.nan)
        for i, q in enumerate(points):
            if q is not None:
                out[i], poses[i] = self.fits(q)
        return out, poses


@dataclass(frozen=True, slots=True)
class Verification:
    """The weights of the verified answer ``program * log P_program + scan * fit`` (module docstring).

    Attributes
    ----------
    program : float
        Weight of the program's log-posterior (>= 0).
    scan : float
        Weight of the scan fit (>= 0; 0: the program's answer alone).
    rows : int
        Held-out rows the weights were fitted on (0: not fitted).
    """

    program: float = 1.0
    scan: float = 0.0
    rows: int = 0

    def __post_init__(self) -> None:
        for name in ("program", "scan"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InvalidParameterError(f"{name} must be a finite weight >= 0, got {v!r}")
        if isinstance(self.rows, bool) or not isinstance(self.rows, (int, np.integer)) or self.rows < 0:
            raise InvalidParameterError(f"rows must be an integer >= 0, got {self.rows!r}")

    def combine(self, log_posterior: Any, fits: Any) -> FArray:
        """The verified log-posterior, shape (n, P), from the program's log-posterior and the scan fits (both (n, P)).

        ``-inf`` in the program's row (a place it does not know) stays
        ``-inf`` when ``program > 0``; a row of NaN (no observation) stays NaN.
        """
        lp = np.asarray(log_posterior, dtype=np.float64)
        f = np.asarray(fits, dtype=np.float64)
        if lp.shape != f.shape or lp.ndim != 2:
            raise InvalidParameterError(f"log_posterior and fits must have the same (n, P) shape, got {lp.shape}, {f.shape}")
        empty = np.all(np.isnan(lp), axis=1)
        prog = np.where(np.isnan(lp), -np.inf, lp)
        with np.errstate(invalid="ignore"):
            z = (self.program * prog if self.program > 0 else np.where(np.isfinite(prog), 0.0, -np.inf)) + self.scan * np.where(np.isfinite(f), f, 0.0)
        out = np.full(z.shape, np.nan)
        ok = ~empty & np.any(np.isfinite(z), axis=1)
        if np.any(ok):
            out[ok] = z[ok] - logsumexp(z[ok], axis=1, keepdims=True)
        bad = ~empty & ~ok
        out[bad] = prog[bad]
        return out

    def to_json(self) -> dict[str, Any]:
        """Every field."""
        return asdict(self)

    @classmethod
    def from_json(cls, data: Any) -> Verification:
        """Inverse of :meth:`to_json` (unknown keys ignored)."""
        try:
            return cls(**{k: v for k, v in dict(data).items() if k in ("program", "scan", "rows")})
        except (TypeError, ValueError) as err:
            raise InvalidParameterError(f"invalid stored verification ({err})") from err


def fit_verification(
    program_scores: Any,
    fits: Any,
    labels: Any,
    *,
    max_program: float = MAX_PROGRAM_WEIGHT,
    max_scan: float = MAX_SCAN_WEIGHT,
) -> Verification:
    """The weights of :class:`Verification` that maximise the held-out log-probability of the right place.

    Parameters
    ----------
    program_scores : array_like, shape (n, P)
        Each held-out row's log-posterior from a program fit without it
        (``-inf``: a place that fit does not know; such places are left out of
        the row's softmax).
    fits : array_like, shape (n, P)
        Each row's scan fit (:meth:`ScanVerifier.fits`) against a scan map
        without it (nor its near duplicates).
    labels : array_like of int, shape (n,)
        The rows' true places.
    max_program, max_scan : float
        Bounds of the weights (a perfectly separated calibration set would
        drive them to infinity).

    Returns
    -------
    Verification
        ``rows``: the rows used (their true place known to the program fit);
        ``Verification()`` (the program alone) without such a row.
    """
    s = np.asarray(program_scores, dtype=np.float64)
    f = np.asarray(fits, dtype=np.float64)
    y = np.asarray(labels, dtype=np.int64).reshape(-1)
    if s.ndim != 2 or s.shape != f.shape or s.shape[0] != y.size:
        raise InvalidParameterError(f"program_scores and fits must have shape (n, P) with n = {y.size}, got {s.shape}, {f.shape}")
    if y.size and (y.min() < 0 or y.max() >= s.shape[1]):
        raise InvalidParameterError("labels must be place indices 0 .. P - 1")
    s = np.where(np.isnan(s), -np.inf, s)
    keep = np.isfinite(s[np.arange(y.size), y]) & np.all(np.isfinite(f), axis=1) if y.size else np.zeros(0, bool)
    s, f, y = s[keep], f[keep], y[keep]
    if y.size == 0:
        return Verification()
    s = s - np.max(s, axis=1, keepdims=True)
    f = f - np.max(f, axis=1, keepdims=True)
    known = np.isfinite(s)
    s0 = np.where(known, s, 0.0)
    rows = np.arange(y.size)
    hi = np.array([max_program, max_scan], dtype=np.float64)

    def nll(w: FArray) -> float:
        z = np.where(known, w[0] * s0 + w[1] * f, -np.inf)
        return float(-np.mean(z[rows, y] - logsumexp(z, axis=1)))

    from scipy.optimize import minimize

    best = None
    for w0 in ((1.0, 1.0), (0.3, 10.0), (0.1, 30.0)):
        r = minimize(nll, np.minimum(np.array(w0), hi), method="L-BFGS-B", bounds=[(0.0, hi[0]), (0.0, hi[1])])
        if best is None or r.fun < best.fun:
            best = r
    assert best is not None
    w = np.clip(best.x, 0.0, hi)
    return Verification(program=float(w[0]), scan=float(w[1]), rows=int(y.size))


def verify_candidates(
    model_log_posterior: Any,
    scan_points: Sequence[Any],
    scan_map: ScanMap | ScanVerifier,
    centres: Any = None,
    verification: Verification | None = None,
    *,
    radius: float = 1.0,
    search: VerifySearch | None = None,
) -> FArray:
    """The verified single-shot log-posterior of scans (module docstring): the fingerprint program's answer
    combined with each scan's best fit at every place.

    Parameters
    ----------
    model_log_posterior : array_like, shape (n, P)
        The program's ``log P(place | observation)``, column ``j`` = place ``j``.
    scan_points : sequence of (m, 2) arrays or None, length n
        Each scan's end points (robot frame, metres); ``None``: the row is the program's.
    scan_map : ScanMap or ScanVerifier
        The map's end points (a verifier built once can be passed instead;
        then ``centres``, ``radius`` and ``search`` are its own).
    centres : array_like, shape (P, 2)
        Place centres (needed with a ScanMap).
    verification : Verification, optional
        The weights (the map's, fitted by :func:`fit_verification`);
        default ``Verification()``: the program's answer unchanged.
    radius : float, default 1.0
    search : VerifySearch, optional

    Returns
    -------
    ndarray, shape (n, P)
        Log-posterior rows (normalised; NaN rows stay NaN).
    """
    lp = np.asarray(model_log_posterior, dtype=np.float64)
    if lp.ndim != 2:
        raise InvalidParameterError(f"model_log_posterior must have shape (n, P), got {lp.shape}")
    pts = list(scan_points)
    if len(pts) != lp.shape[0]:
        raise InvalidParameterError(f"scan_points must have one entry per row ({lp.shape[0]}), got {len(pts)}")
    ver = Verification() if verification is None else verification
    if isinstance(scan_map, ScanVerifier):
        verifier = scan_map
    else:
        if centres is None:
            raise InvalidParameterError("verify_candidates needs the place centres with a ScanMap")
        verifier = ScanVerifier(scan_map, centres, radius, search)
    if verifier.n_places != lp.shape[1]:
        raise InvalidParameterError(f"the verifier has {verifier.n_places} places, the rows {lp.shape[1]}")
    fits = np.zeros(lp.shape)
    if ver.scan > 0:
        fits = verifier.fit_rows(pts)[0]
    return ver.combine(lp, fits)


def map_without(
    points: Sequence[Any], poses: Any, excluded: Any, *, travel: Any = None, guard: float = 0.0
) -> ScanMap | None:
    """The :class:`~fingerloc.map.scan_map.ScanMap` of a run's scans without the ``excluded`` ones.

    Parameters
    ----------
    points : sequence of (m, 2) arrays, length n
        Each scan's end points, robot frame.
    poses : array_like, shape (n, 3)
        The scans' poses, mapping frame.
    excluded : array_like of bool, shape (n,)
    travel : array_like, shape (n,), optional
        Metres travelled along the run at each scan (non-decreasing): with
        ``guard`` > 0 every scan within ``guard`` metres of travel of an
        excluded one is left out too.
    guard : float, default 0.0

    Returns
    -------
    ScanMap or None
        None when no end point is left.
    """
    ex = np.asarray(excluded, dtype=bool).reshape(-1)
    pts = list(points)
    ps = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    if not len(pts) == ps.shape[0] == ex.size:
        raise InvalidParameterError(f"points, poses and excluded need one entry per scan, got {len(pts)}, {ps.shape[0]}, {ex.size}")
    drop = ex.copy()
    if guard > 0 and ex.any():
        if travel is None:
            raise InvalidParameterError("a guard needs the travel along the run")
        from scipy.spatial import cKDTree

        tv = np.asarray(travel, dtype=np.float64).reshape(-1)
        d, _ = cKDTree(tv[ex, None]).query(tv[:, None], k=1)
        drop |= np.asarray(d) <= float(guard)
    keep = [i for i in np.flatnonzero(~drop).tolist() if pts[i] is not None and np.size(pts[i])]
    if not keep:
        return None
    return ScanMap.from_scans([pts[i] for i in keep], ps[keep])


def calibrate_verification(
    held_scores: Any,
    held_labels: Any,
    held_scans: Any,
    points: Sequence[Any],
    poses: Any,
    fold: Any,
    centres: Any,
    radius: float,
    *,
    excluded: Any = None,
    search: VerifySearch | None = None,
    max_rows: int = CALIBRATION_ROWS,
) -> Verification:
    """The verification's weights for a map, from its mapping part (:func:`fit_verification` on held-out rows).

    Each held-out row was scored by a program fit without it (``held_scores``,
    e.g. :func:`fingerloc.pipeline.calibration.held_out_calibration`'s); here it
    is also fitted into a scan map without its fold: the mapping part's
    scans minus ``excluded`` minus every scan of the row's ``fold``
    (alternate visits in time order, :func:`fingerloc.pipeline.calibrate.scan_folds`:
    the row's own visit goes, the neighbouring visits stay). At most
    ``max_rows`` rows, evenly spaced in the held-out order.

    Parameters
    ----------
    held_scores : array_like, shape (n, P)
    held_labels : array_like of int, shape (n,)
    held_scans : array_like of int, shape (n,)
        Each held-out row's scan among ``points`` / ``poses``.
    points : sequence of (m, 2) arrays, length N
        The mapping part's scans' end points (robot frame).
    poses : array_like, shape (N, 3)
    fold : array_like of int, shape (N,)
        Each scan's map fold (0 / 1; -1: in every fold's map).
    centres : array_like, shape (P, 2)
    radius : float
    excluded : array_like of bool, shape (N,), optional
        Scans no map holds.
    search : VerifySearch, optional
    max_rows : int, default CALIBRATION_ROWS

    Returns
    -------
    Verification
    """
    sc = np.asarray(held_scores, dtype=np.float64)
    y = np.asarray(held_labels, dtype=np.int64).reshape(-1)
    at = np.asarray(held_scans, dtype=np.int64).reshape(-1)
    fd = np.asarray(fold, dtype=np.int64).reshape(-1)
    n_scans = len(points)
    if sc.ndim != 2 or sc.shape[0] != y.size or at.size != y.size:
        raise InvalidParameterError(f"held_scores (n, P), held_labels and held_scans (n,) must agree, got {sc.shape}, {y.size}, {at.size}")
    if fd.size != n_scans or (at.size and (at.min() < 0 or at.max() >= n_scans)):
        raise InvalidParameterError("fold needs one entry per scan and held_scans must index the scans")
    ex = np.zeros(n_scans, dtype=bool) if excluded is None else np.asarray(excluded, dtype=bool).reshape(-1)
    if y.size == 0:
        return Verification()
    rows = np.arange(y.size)
    if rows.size > max_rows:
        rows = np.unique(np.linspace(0, rows.size - 1, max_rows).round().astype(np.int64))
    fits = np.zeros((rows.size, sc.shape[1]))
    for f in np.unique(fd[at[rows]]).tolist():
        mine = np.flatnonzero(fd[at[rows]] == f)
        fmap = map_without(points, poses, ex | (fd == f))
        if fmap is None:
            return Verification()
        v = ScanVerifier(fmap, centres, radius, search)
        for r in mine.tolist():
            fits[r] = v.fits(points[int(at[rows[r]])])[0]
    return fit_verification(sc[rows], fits, y[rows])
