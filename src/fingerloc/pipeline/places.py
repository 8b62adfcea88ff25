"""Places from a trajectory: the real-log protocol as a library function.

A recorded run is a sequence of scans (or observations) with poses. Its first
part maps, the rest may be queried:

1. The *mapping part*: scans ``0 .. n_mapping - 1``, ``n_mapping =
   floor(mapping_part * n)`` (default: the first half), or the scans taken
   before ``until`` seconds after the first one.
2. Places: walk the mapping part in order; a scan whose position is strictly
   farther than ``spacing`` (2 m) from every existing place centre creates a
   place centred at its position.
3. Every mapping scan within ``radius`` (1 m, inclusive) of some centre is a
   training scan of the nearest centre; every later scan within ``radius``
   of some centre is a query whose true place is the nearest centre (ties in
   distance go to the lower place index).

With the defaults this is exactly the protocol of the real-log benchmark
(:mod:`fingerloc.experiments.carmen`), which calls :func:`places_from_trajectory`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._types import FArray, IArray
from ..errors import InvalidParameterError

__all__ = [
    "PLACE_RADIUS_M",
    "PLACE_SPACING_M",
    "PlaceSplit",
    "mapping_count",
    "nearest_within",
    "place_label",
    "places_from_trajectory",
    "visit_folds",
]

#: A mapping scan strictly farther than this from every centre makes a new place, metres.
PLACE_SPACING_M = 2.0
#: Scans within this distance (inclusive) of a centre train / query it, metres.
PLACE_RADIUS_M = 1.0



def place_label(j: int) -> str:
    """The label of place ``j`` of a map made from a trajectory: its creation index as text (``"0"``, ``"1"``...)."""
    return str(int(j))


@dataclass(frozen=True, slots=True)
class PlaceSplit:
    """Places, training scans and queries of one run (indices into the run's scan list).

    Attributes
    ----------
    centres : ndarray, shape (n_places, 2)
        Place centres, metres, in creation order (place ``j`` is row ``j``).
    centre_scans : ndarray of int, shape (n_places,)
        Index of the scan that created each place.
    train_idx, train_labels : ndarray of int, shape (n_train,)
        Training scans (mapping part, in order) and their place.
    query_idx, query_labels : ndarray of int, shape (n_queries,)
        Query scans (after the mapping part, in order) and their true place.
    n_scans, n_mapping : int
        Scans in the run, and in its mapping part.
    """

    centres: FArray
    centre_scans: IArray
    train_idx: IArray
    train_labels: IArray
    query_idx: IArray
    query_labels: IArray
    n_scans: int
    n_mapping: int

    @property
    def n_places(self) -> int:
        """Number of places."""
        return int(self.centres.shape[0])

    @property
    def n_train(self) -> int:
        """Number of training scans."""
        return int(self.train_idx.size)

    @property
    def n_queries(self) -> int:
        """Number of queries."""
        return int(self.query_idx.size)


def _positive(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (value > 0 and math.isfinite(value)):
        raise InvalidParameterError(f"{name} must be a positive number of metres, got {value!r}")
    return float(value)


def mapping_count(
    n: int, *, mapping_part: float | None = 0.5, until: float | None = None, timestamps: Any = None
) -> int:
    """How many of ``n`` scans form the mapping part.

    ``until`` (seconds after the first timestamp, inclusive) wins over
    ``mapping_part`` (a fraction in ``(0, 1]``: ``floor(mapping_part * n)``).
    """
    if until is not None:
        if not (isinstance(until, (int, float)) and math.isfinite(until) and until >= 0):
            raise InvalidParameterError(f"until must be a number of seconds >= 0, got {until!r}")
        t = None if timestamps is None else np.asarray(timestamps, dtype=np.float64).reshape(-1)
        if t is None or t.size != n or not np.all(np.isfinite(t)):
            raise InvalidParameterError("until needs a timestamp on every scan")
        return int(np.count_nonzero(t - (t[0] if n else 0.0) <= until))
    part = 0.5 if mapping_part is None else mapping_part
    if not (isinstance(part, (int, float)) and 0 < part <= 1):
        raise InvalidParameterError(f"mapping_part must be a fraction in (0, 1], got {part!r}")
    return n // 2 if part == 0.5 else math.floor(part * n)


def nearest_within(positions: Any, centres: Any, radius: float) -> tuple[IArray, IArray]:
    """Rows of ``positions`` within ``radius`` (inclusive) of some centre, and that nearest centre.

    Returns
    -------
    idx : ndarray of int, shape (m,)
        Row indices, ascending.
    nearest : ndarray of int, shape (m,)
        Nearest centre of each (the lowest index among equal distances).
    """
    from ..map.graph import nearest_place_sequence

    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    if c.shape[0] == 0 or pos.shape[0] == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    near = nearest_place_sequence(pos, c, radius=radius)
    idx = np.flatnonzero(near >= 0).astype(np.int64)
    return idx, near[idx]


def places_from_trajectory(
    positions: Any,
    *,
    mapping_part: float | None = 0.5,
    until: float | None = None,
    timestamps: Any = None,
    n_mapping: int | None = None,
    spacing: float = PLACE_SPACING_M,
    radius: float = PLACE_RADIUS_M,
) -> PlaceSplit:
    """Places, training scans and queries of a run (module docstring, steps 1-3).

    Parameters
    ----------
    positions : array_like, shape (n, 2)
        Robot positions of the scans in recording order, metres.
    mapping_part : float, default 0.5
        Fraction of the scans that maps (``floor(mapping_part * n)``).
    until : float, optional
        Seconds after the first scan (inclusive): the mapping part instead of
        ``mapping_part``; needs ``timestamps``.
    timestamps : array_like, shape (n,), optional
        Seconds of each scan.
    n_mapping : int, optional
        The number of mapping scans, directly (wins over both).
    spacing : float, default 2.0
        Metres; a new place needs a distance strictly greater.
    radius : float, default 1.0
        Metres (inclusive).

    Returns
    -------
    PlaceSplit
    """
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] != 2:
        raise InvalidParameterError(f"positions must have shape (n, 2), got {pos.shape}")
    if not np.all(np.isfinite(pos)):
        raise InvalidParameterError("positions must be finite")
    spacing = _positive("spacing", spacing)
    radius = _positive("radius", radius)
    n = pos.shape[0]
    if n_mapping is None:
        n_map = mapping_count(n, mapping_part=mapping_part, until=until, timestamps=timestamps)
    else:
        if not (0 <= int(n_mapping) <= n):
            raise InvalidParameterError(f"n_mapping must be in [0, {n}], got {n_mapping!r}")
        n_map = int(n_mapping)
    centres: list[FArray] = []
    creators: list[int] = []
    for i in range(n_map):
        p = pos[i]
        if not centres or float(np.min(np.hypot(*(np.asarray(centres) - p).T))) > spacing:
            centres.append(p)
            creators.append(i)
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    tr_rows, tr_lab = nearest_within(pos[:n_map], c, radius)
    q_rows, q_lab = nearest_within(pos[n_map:], c, radius)
    return PlaceSplit(
        centres=c,
        centre_scans=np.asarray(creators, dtype=np.int64),
        train_idx=tr_rows,
        train_labels=tr_lab,
        query_idx=(q_rows + n_map).astype(np.int64),
        query_labels=q_lab,
        n_scans=n,
        n_mapping=n_map,
    )


def visit_folds(train_idx: Any, labels: Any) -> IArray:
    """Fold (0 / 1) of each training scan: alternate *visits* of its place.

    A visit is a run of consecutive scans (consecutive indices) of one place;
    a place's first visit is fold 0, its second fold 1, and so on, so that a
    held-out scan was not taken a second before a training one.

    Parameters
    ----------
    train_idx, labels : array_like of int, shape (n,)

    Returns
    -------
    ndarray of int, shape (n,)
    """
    idx = np.asarray(train_idx, dtype=np.int64).reshape(-1)
    lab = np.asarray(labels, dtype=np.int64).reshape(-1)
    fold = np.zeros(lab.size, dtype=np.int64)
    visits: dict[int, int] = {}
    prev_lab, prev_idx = -1, -10
    for k, (i, y) in enumerate(zip(idx.tolist(), lab.tolist(), strict=True)):
        if y != prev_lab or i != prev_idx + 1:
            visits[y] = visits.get(y, -1) + 1
        fold[k] = visits[y] % 2
        prev_lab, prev_idx = y, i
    return fold
