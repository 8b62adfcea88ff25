"""One home for the localization metrics: ranks with ties, top-1, recall@k, per-place reductions.

Convention everywhere: a higher score is better, and **ties count against**:
the rank of a place is the number of places scoring at least as high as it
(itself included), so a true place tied with another ranks 2, and a query
scoring ``-inf`` for every place ranks last. NaN scores count as ``-inf``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._types import FArray, IArray
from .errors import InvalidParameterError

__all__ = [
    "max_per_place",
    "min_per_place",
    "min_per_place_groups",
    "rank_metrics",
    "rank_scores",
    "recall_at_k",
    "top1",
    "true_place_ranks",
]



def _scores(scores: Any) -> FArray:
    s = np.asarray(scores, dtype=np.float64)
    if s.ndim != 2:
        raise InvalidParameterError(f"scores must have shape (n_queries, n_places), got {s.shape}")
    return np.where(np.isnan(s), -np.inf, s)


def rank_scores(scores: Any) -> IArray:
    """Rank of every column of each row, shape ``(n, P)``; 1 = highest score, ties count against."""
    s = _scores(scores)
    if s.size == 0:
        return np.zeros(s.shape, dtype=np.int64)
    order = np.sort(s, axis=1)  # ascending
    n = s.shape[1]
    ge = n - np.stack([np.searchsorted(order[i], s[i], side="left") for i in range(s.shape[0])])
    return np.asarray(ge, dtype=np.int64)


def true_place_ranks(scores: Any, labels: Any) -> IArray:
    """Rank (1 = best) of each query's true place, shape ``(n,)``; ties count against.

    ``rank_i = #{j : scores[i, j] >= scores[i, labels[i]]}``.

    Parameters
    ----------
    scores : array_like, shape (n_queries, n_places)
        Higher is better.
    labels : array_like of int, shape (n_queries,)
        Column of each query's true place.
    """
    s = _scores(scores)
    y = np.asarray(labels, dtype=np.int64).reshape(-1)
    if s.shape[0] != y.size:
        raise InvalidParameterError(f"scores must have shape (n_queries, n_places) = ({y.size}, ...), got {s.shape}")
    if y.size and (y.min() < 0 or y.max() >= s.shape[1]):
        raise InvalidParameterError(f"labels must be place indices in [0, {s.shape[1]}), got {y.min()}..{y.max()}")
    true = s[np.arange(y.size), y]
    return (s >= true[:, None]).sum(axis=1).astype(np.int64)


def top1(ranks: Any) -> float:
    """Fraction of ranks equal to 1 (NaN for no rank)."""
    r = np.asarray(ranks).reshape(-1)
    return float(np.mean(r == 1)) if r.size else float("nan")


def recall_at_k(ranks: Any, k: int) -> float:
    """Fraction of ranks ``<= k`` (NaN for no rank)."""
    r = np.asarray(ranks).reshape(-1)
    return float(np.mean(r <= k)) if r.size else float("nan")


def rank_metrics(ranks: Any) -> dict[str, float]:
    """``top1``, ``mean_rank`` and ``recall5`` of true-place ranks (NaN each for no rank)."""
    r = np.asarray(ranks, dtype=np.float64).reshape(-1)
    return {
        "top1": top1(r),
        "mean_rank": float(np.mean(r)) if r.size else float("nan"),
        "recall5": recall_at_k(r, 5),
    }


def min_per_place_groups(d: FArray, starts: IArray) -> FArray:
    """Column-group minima ``out[:, j] = d[:, starts[j]:starts[j+1]].min(axis=1)``, shape ``(n, P)``.

    Columns must be grouped by place, each group non-empty, ``starts`` ascending.
    """
    if d.shape[0] == 0:
        return np.zeros((0, starts.size))
    return np.minimum.reduceat(d, starts, axis=1)


def _reduce_per_place(d: Any, owner: Any, n_places: int, fill: float, op: Any) -> FArray:
    a = np.asarray(d, dtype=np.float64)
    own = np.asarray(owner, dtype=np.int64).reshape(-1)
    if a.ndim != 2 or a.shape[1] != own.size:
        raise InvalidParameterError(f"owner must give one place per column of d, got {own.size} for {a.shape}")
    out = np.full((a.shape[0], n_places), fill)
    for j in range(n_places):
        cols = own == j
        if cols.any():
            out[:, j] = op(a[:, cols], axis=1)
    return out


def min_per_place(d: Any, owner: Any, n_places: int) -> FArray:
    """Least value per place: ``d`` (n, m) with ``owner[c]`` the place of column c -> (n, n_places); ``inf`` for no column."""
    return _reduce_per_place(d, owner, n_places, np.inf, np.min)


def max_per_place(s: Any, owner: Any, n_places: int) -> FArray:
    """Largest value per place, as :func:`min_per_place`; ``-inf`` for a place without columns."""
    return _reduce_per_place(s, owner, n_places, -np.inf, np.max)
