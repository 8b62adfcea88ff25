"""The fingerprint method's scan verification on the real-log benchmark (:mod:`fingerloc.map.scan_verify`).

:class:`~fingerloc.experiments.carmen.FingerprintMethod` with ``verify``
fits the program, then (:func:`fit_verified`):

* the **scan map**: the laser end points of the mapping run at their
  poses. Inside :func:`mapping_context` (the benchmark's runner opens one
  per log with the log's scans and split) that is every mapping-pass scan
  except the training scans the fit was *not* given and every scan within
  :data:`~fingerloc.pipeline.tracker.SCAN_GUARD_M` metres of travel of one
  of them (a fit on part of the training scans, as a filter's calibration
  makes, never sees the left-out scans nor their near duplicates); the fit
  on every training scan gets the whole mapping pass, as ``fingerloc map``
  stores it. Outside, the map is the training scans' own.
* the **weights** of the verified answer
  (:func:`~fingerloc.map.scan_verify.fit_verification`) on held-out
  training scans: two folds by alternate visits (as the filters'
  calibration, :func:`~fingerloc.pipeline.tracker.held_out_calibration`),
  each fold's rows scored by a program fit on the other fold and fitted into
  a scan map without the fold's scans and their neighbours (the same rule
  as above); at most :data:`CALIBRATION_ROWS` rows, evenly spaced.
* the place centres: the split's (inside the context), else each place's
  mean training position.

Nothing is taken from the queries.
"""

from __future__ import annotations

import contextvars
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._types import FArray, IArray
from ..sensors import Scan
from .protocol import PLACE_RADIUS_M, Split

__all__ = ["CALIBRATION_ROWS", "MappingRun", "fit_verified", "mapping_context", "verification_map"]

#: Held-out training scans the verification's weights are fitted on, at most (evenly spaced).
CALIBRATION_ROWS = 120
#: A held-out row's scan map leaves out its fold's scans and every scan within this many metres of travel of one.
MAP_GUARD_M = 0.0


@dataclass(frozen=True, slots=True)
class MappingRun:
    """A log's scans and split as :func:`mapping_context` holds them."""

    scans: list[Scan]
    split: Split
    index: dict[int, int]
    travel: FArray


_RUN: contextvars.ContextVar[MappingRun | None] = contextvars.ContextVar("fingerloc_mapping_run", default=None)


@contextmanager
def mapping_context(scans: Sequence[Scan], split: Split) -> Iterator[MappingRun]:
    """Within, a verifying fingerprint method fit on scans of this log builds its scan map from the mapping pass."""
    from ..pipeline.tracker import step_distances

    run = list(scans)
    n_map = int(split.n_mapping)
    pos = np.array([s.pose[:2] if s.pose is not None else (np.nan, np.nan) for s in run[:n_map]], dtype=np.float64)
    travel = np.cumsum(step_distances(np.nan_to_num(pos.reshape(-1, 2))))
    ctx = MappingRun(run, split, {id(s): i for i, s in enumerate(run)}, travel)
    token = _RUN.set(ctx)
    try:
        yield ctx
    finally:
        _RUN.reset(token)


def _end_points(scans: Sequence[Scan]) -> list[FArray]:
    from ..map.scan_map import end_points
    from .shared import observations

    return observations(scans, "end_points", end_points)


def verification_map(
    points: Sequence[Any], poses: Any, travel: Any, excluded: Any, *, guard: float | None = None
) -> Any:
    """The :class:`~fingerloc.map.scan_map.ScanMap` of a run's scans without the ``excluded`` ones and every scan
    within ``guard`` metres of travel of one of them (default :data:`~fingerloc.pipeline.tracker.SCAN_GUARD_M`).

    ``points``: each scan's end points (robot frame); ``poses``: shape (n, 3);
    ``travel``: metres travelled along the run at each scan (non-decreasing);
    ``excluded``: boolean mask, shape (n,). None when nothing is left.
    """
    from scipy.spatial import cKDTree

    from ..map.scan_map import ScanMap
    from ..pipeline.tracker import SCAN_GUARD_M

    g = SCAN_GUARD_M if guard is None else float(guard)
    ex = np.asarray(excluded, dtype=bool).reshape(-1)
    tv = np.asarray(travel, dtype=np.float64).reshape(-1)
    drop = ex.copy()
    if ex.any() and g > 0:
        d, _ = cKDTree(tv[ex, None]).query(tv[:, None], k=1)
        drop |= np.asarray(d) <= g
    keep = [i for i in np.flatnonzero(~drop).tolist() if np.size(points[i])]
    if not keep:
        return None
    ps = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    return ScanMap.from_scans([points[i] for i in keep], ps[keep])


def _pool(scans: Sequence[Scan], y: IArray) -> tuple[list[Scan], FArray, FArray, IArray, Any, float, FArray]:
    """The scans a map may hold and how the fit's scans sit among them.

    Returns ``(pool scans, pool poses, pool travel, fit positions in the pool,
    excluded mask of the pool, radius, place centres (k, 2))``.
    """
    from ..pipeline.tracker import step_distances

    ctx = _RUN.get()
    k = int(y.max()) + 1
    if ctx is not None and all(id(s) in ctx.index for s in scans):
        n_map = int(ctx.split.n_mapping)
        at = np.array([ctx.index[id(s)] for s in scans], dtype=np.int64)
        if at.size and int(at.max()) < n_map:
            pool = ctx.scans[:n_map]
            poses = np.array([s.pose for s in pool], dtype=np.float64)
            train = np.zeros(n_map, dtype=bool)
            train[ctx.split.train_idx] = True
            excluded = train.copy()
            excluded[at] = False
            place = np.full(n_map, -1, dtype=np.int64)
            place[ctx.split.train_idx] = ctx.split.train_labels
            centres = np.zeros((k, 2))
            for lab in range(k):
                centres[lab] = ctx.split.centres[int(place[at[y == lab][0]])]
            return pool, poses, ctx.travel, at, excluded, PLACE_RADIUS_M, centres
    poses = np.array([s.pose for s in scans], dtype=np.float64)
    travel = np.cumsum(step_distances(poses[:, :2]))
    centres = np.array([poses[y == lab, :2].mean(axis=0) for lab in range(k)])
    far = float(np.max(np.hypot(*(poses[:, :2] - centres[y]).T))) if y.size else 0.0
    at_all = np.arange(len(scans), dtype=np.int64)
    return list(scans), poses, travel, at_all, np.zeros(len(scans), bool), max(PLACE_RADIUS_M, far), centres


def fit_verified(method: Any, scans: Sequence[Scan], y: IArray, search: Any = None) -> tuple[Any, Any]:
    """The verifier and the fitted weights of a verifying fingerprint method fit on ``scans`` (module docstring).

    ``method``: the :class:`~fingerloc.experiments.carmen.FingerprintMethod`
    (its program is refit on the folds with ``method._program``).
    Returns ``(ScanVerifier or None, Verification or None)``: None when the
    run has no laser end point to map.
    """
    from ..map.scan_verify import ScanVerifier, Verification, fit_verification
    from ..pipeline.tracker import held_out_calibration, posterior_columns

    pool, poses, travel, at, excluded, radius, centres = _pool(scans, y)
    pts = _end_points(pool)
    full = verification_map(pts, poses, travel, excluded)
    if full is None:
        return None, None
    verifier = ScanVerifier(full, centres, radius, search)
    k = centres.shape[0]
    fit_list = list(scans)

    def fit_score(tr: IArray, yy: IArray, te: IArray) -> FArray:
        model = method._program([fit_list[i] for i in tr.tolist()], yy)
        return posterior_columns(model, method._observations([fit_list[i] for i in te.tolist()]), int(yy.max()) + 1)

    held = held_out_calibration(fit_score, at, y, k)
    if held.index.size == 0 or held.fold is None:
        return verifier, Verification()
    rows = np.arange(held.index.size)
    if rows.size > CALIBRATION_ROWS:
        rows = np.unique(np.linspace(0, rows.size - 1, CALIBRATION_ROWS).round().astype(np.int64))
    from ..pipeline.tracker import scan_folds

    sfold = scan_folds(at, y)  # alternate visits in time order: a row's map keeps the neighbouring visits
    fits = np.zeros((rows.size, k))
    for f in (0, 1):
        mine = rows[sfold[held.index[rows]] == f]
        if mine.size == 0:
            continue
        ex = excluded.copy()
        ex[at[sfold == f]] = True
        fmap = verification_map(pts, poses, travel, ex, guard=MAP_GUARD_M)
        if fmap is None:
            return verifier, Verification()
        fv = ScanVerifier(fmap, centres, radius, search)
        pos = np.searchsorted(rows, mine)
        for r, i in zip(pos.tolist(), mine.tolist(), strict=True):
            fits[r] = fv.fits(pts[int(at[held.index[i]])])[0]
    return verifier, fit_verification(held.scores[rows], fits, held.labels[rows])
