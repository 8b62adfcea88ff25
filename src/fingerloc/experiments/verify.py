"""The fingerprint method's scan verification on the real-log benchmark (:mod:`fingerloc.map.scan_verify`).

:class:`~fingerloc.experiments.carmen.FingerprintMethod` with ``verify``
fits the program, then (:func:`fit_verified`):

* the **scan map**: the laser end points of the mapping run at their
  poses (:func:`~fingerloc.map.scan_verify.map_without`). Inside
  :func:`mapping_context` (the benchmark's runner opens one per log with
  the log's scans and split) that is every mapping-pass scan except the
  training scans the fit was *not* given (a fit on part of the training
  scans, as a filter's calibration makes, never sees the left-out ones); the
  fit on every training scan gets the whole mapping pass, as ``fingerloc
  map`` stores it. Outside, the map is the training scans' own.
* the **weights** of the verified answer
  (:func:`~fingerloc.map.scan_verify.calibrate_verification`) on held-out
  training scans: each scored by a program fit on the other fold of
  alternate visits (as the filters' calibration,
  :func:`~fingerloc.pipeline.calibration.held_out_calibration`) and fitted into
  a scan map without its own fold of alternate visits in time order
  (:func:`~fingerloc.pipeline.calibrate.scan_folds`: its visit goes, the
  neighbouring visits stay); at most
  :data:`~fingerloc.map.scan_verify.CALIBRATION_ROWS` rows, evenly spaced.
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

__all__ = ["CALIBRATION_ROWS", "MappingRun", "fit_verified", "mapping_context"]

#: Held-out training scans the verification's weights are fitted on, at most (evenly spaced).
CALIBRATION_ROWS = 120


@dataclass(frozen=True, slots=True)
class MappingRun:
    """A log's scans and split as :func:`mapping_context` holds them."""

    scans: list[Scan]
    split: Split
    index: dict[int, int]


_RUN: contextvars.ContextVar[MappingRun | None] = contextvars.ContextVar("fingerloc_mapping_run", default=None)


@contextmanager
def mapping_context(scans: Sequence[Scan], split: Split) -> Iterator[MappingRun]:
    """Within, a verifying fingerprint method fit on scans of this log builds its scan map from the mapping pass."""
    run = list(scans)
    ctx = MappingRun(run, split, {id(s): i for i, s in enumerate(run)})
    token = _RUN.set(ctx)
    try:
        yield ctx
    finally:
        _RUN.reset(token)


def _end_points(scans: Sequence[Scan]) -> list[FArray]:
    from ..map.scan_map import end_points
    from .shared import observations

    return observations(scans, "end_points", end_points)


def _pool(scans: Sequence[Scan], y: IArray) -> tuple[list[Scan], FArray, IArray, Any, float, FArray]:
    """The scans a map may hold and how the fit's scans sit among them.

    Returns ``(pool scans, pool poses, fit positions in the pool, excluded
    mask of the pool, radius, place centres (k, 2))``.
    """
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
            return pool, poses, at, excluded, PLACE_RADIUS_M, centres
    poses = np.array([s.pose for s in scans], dtype=np.float64)
    centres = np.array([poses[y == lab, :2].mean(axis=0) for lab in range(k)])
    far = float(np.max(np.hypot(*(poses[:, :2] - centres[y]).T))) if y.size else 0.0
    at_all = np.arange(len(scans), dtype=np.int64)
    return list(scans), poses, at_all, np.zeros(len(scans), bool), max(PLACE_RADIUS_M, far), centres


def fit_verified(method: Any, scans: Sequence[Scan], y: IArray, search: Any = None) -> tuple[Any, Any]:
    """The verifier and the fitted weights of a verifying fingerprint method fit on ``scans`` (module docstring).

    ``method``: the :class:`~fingerloc.experiments.carmen.FingerprintMethod`
    (its program is refit on the folds with ``method._program``).
    Returns ``(ScanVerifier or None, Verification or None)``: None when the
    run has no laser end point to map.
    """
    from ..map.scan_verify import ScanVerifier, Verification, calibrate_verification, map_without
    from ..pipeline.calibrate import scan_folds
    from ..pipeline.calibration import held_out_calibration, posterior_columns

    pool, poses, at, excluded, radius, centres = _pool(scans, y)
    pts = _end_points(pool)
    full = map_without(pts, poses, excluded)
    if full is None:
        return None, None
    verifier = ScanVerifier(full, centres, radius, search)
    k = centres.shape[0]
    fit_list = list(scans)

    def fit_score(tr: IArray, yy: IArray, te: IArray) -> FArray:
        model = method._program([fit_list[i] for i in tr.tolist()], yy)
        return posterior_columns(model, method._observations([fit_list[i] for i in te.tolist()]), int(yy.max()) + 1)

    held = held_out_calibration(fit_score, at, y, k)
    if held.index.size == 0:
        return verifier, Verification()
    fold = np.full(len(pool), -1, dtype=np.int64)
    fold[at] = scan_folds(at, y)  # alternate visits in time order: a row's map keeps the neighbouring visits
    ver = calibrate_verification(held.scores, held.labels, at[held.index], pts, poses, fold, centres, radius,
                                 excluded=excluded, search=search, max_rows=CALIBRATION_ROWS)  # fmt: skip
    return verifier, ver
