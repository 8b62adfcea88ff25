"""The local-feature term ``K``: how many distinctive patches the view shares with a place's views.

Each observation may carry keypoints (``Observation.keypoints``, from
:func:`fingerloc.features.keypoints.extract_keypoints`: positions and upright
gradient-histogram descriptors). Two panoramas of one room from different
spots share many local patches (furniture, pictures, windows) that a global
histogram blurs. The term counts the query's keypoints matched in each
training view and keeps the place's best view:

    m(o, v)           = matches between o and v: mutual nearest neighbours of the root-normalised
                        descriptors, nearest distance below ``ratio`` x the second nearest, and
                        elevations (fractions of the band) at most ``max_elevation`` apart; the
                        ratio test is made from o's side and from v's, and m is the larger count
                        (so m(o, v) = m(v, o))
    d(o, v)           = -log((m + 1) / (sqrt(n_o n_v) + 1))          (n: keypoints of each view)
    d(o, place)       = min over the place's training views v of d(o, v)
    log P(K | place)  = -lambda * d(o, place)          (up to a constant shared by the places)

It is heading-free (the descriptors are upright and the matching ignores
bearings: between two spots of one room the bearings of the shared patches
differ by parallax, not by one rotation). ``lambda`` and ``unknown_cost_``
are calibrated leave-one-out on the training views, as for ``A``
(:mod:`.distance`). Observations without keypoints get a zero row (the term
says nothing); a training view without keypoints is never a nearest view.

Match counts are memoised per pair of views (keyed by a digest of both views'
keypoints, up to ``CACHE_SIZE`` pairs), so that refitting a model on the same
views (leave-one-out experiments, ``weights="fit"``) does not match them again.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._types import IArray
from ..errors import InvalidParameterError
from ..features.keypoints import Keypoints
from ..observation import Observation
from .base import FArray
from .indexed import IndexedTerm

__all__ = ["CACHE_SIZE", "KeypointTerm", "keypoint_distance", "match_counts"]

#: Pairs of views whose match counts are memoised (process-wide).
CACHE_SIZE = 2_000_000
_CACHE: OrderedDict[tuple[bytes, bytes, float, float], int] = OrderedDict()
#: Reference views matched per block (bounds the similarity array: n_query x block x n_ref float32).
_BLOCK = 32
_NONE = -4.0  # below any similarity of unit vectors with non-negative entries


def _digest(k: Keypoints) -> bytes:
    h = hashlib.blake2b(digest_size=16)
    h.update(np.ascontiguousarray(k.desc).tobytes())
    h.update(np.ascontiguousarray(k.elevation).tobytes())
    return h.digest()


class _Refs:
    """Training keypoints stacked for block matching: padded unit descriptors and elevations."""

    def __init__(self, kps: Sequence[Keypoints]) -> None:
        self.n = len(kps)
        self.sizes = np.array([len(k) for k in kps], dtype=np.int64)
        width = int(self.sizes.max(initial=0))
        dims = {k.dim for k in kps if len(k)}
        if len(dims) > 1:
            raise InvalidParameterError(f"keypoints: every descriptor must have the same length, got {sorted(dims)}")
        self.dim = dims.pop() if dims else 0
        self.unit = np.zeros((self.n, max(width, 1), max(self.dim, 1)), dtype=np.float32)
        self.elev = np.full((self.n, max(width, 1)), np.inf, dtype=np.float32)
        self.valid = np.zeros((self.n, max(width, 1)), dtype=bool)
        for v, k in enumerate(kps):
            m = len(k)
            if m:
                self.unit[v, :m] = k.unit_descriptors()
                self.elev[v, :m] = k.elevation
                self.valid[v, :m] = True

    def subset(self, views: Sequence[int]) -> _Refs:
        """The references ``views`` only (same padding)."""
        out = object.__new__(_Refs)
        idx = np.asarray(views, dtype=np.int64)
        out.n, out.dim = int(idx.size), self.dim
        out.sizes, out.unit, out.elev, out.valid = self.sizes[idx], self.unit[idx], self.elev[idx], self.valid[idx]
        return out


def match_counts(
    query: Keypoints, refs: Sequence[Keypoints] | _Refs, *, ratio: float = 0.8, max_elevation: float = 0.1
) -> IArray:
    """Number of matches (module docstring) between ``query`` and each reference view, shape ``(n_refs,)``.

    ``max(len(match_keypoints(query, ref)), len(match_keypoints(ref, query)))`` for each reference.
    """
    r = refs if isinstance(refs, _Refs) else _Refs(refs)
    out = np.zeros(r.n, dtype=np.int64)
    nq = len(query)
    if nq == 0 or r.n == 0 or r.dim == 0:
        return out
    if query.dim != r.dim:
        raise InvalidParameterError(f"keypoints: the query's descriptors have length {query.dim}, the references' {r.dim}")
    qu = query.unit_descriptors()
    qe = query.elevation.astype(np.float32)
    width = r.unit.shape[1]
    rows = np.arange(nq)
    for b0 in range(0, r.n, _BLOCK):
        b1 = min(r.n, b0 + _BLOCK)
        nb = b1 - b0
        s = (qu @ r.unit[b0:b1].reshape(nb * width, r.dim).T).reshape(nq, nb, width)
        s[:, ~r.valid[b0:b1]] = np.float32(_NONE)
        j = np.argmax(s, axis=2)  # (nq, nb): nearest reference keypoint
        best = np.take_along_axis(s, j[:, :, None], axis=2)[:, :, 0]
        np.put_along_axis(s, j[:, :, None], np.float32(_NONE), axis=2)
        second = s.max(axis=2)
        np.put_along_axis(s, j[:, :, None], best[:, :, None], axis=2)
        back = np.argmax(s, axis=0)  # (nb, width): nearest query keypoint of each reference keypoint
        mutual = back[np.arange(nb)[None, :], j] == rows[:, None]
        elev = np.take_along_axis(np.broadcast_to(r.elev[None, b0:b1], s.shape), j[:, :, None], axis=2)[:, :, 0]
        ok = mutual & (best > _NONE) & _ratio_ok(best, second, ratio) & (np.abs(qe[:, None] - elev) <= max_elevation)
        # the other way: each reference keypoint against the query's (its own ratio test)
        best_r = np.take_along_axis(s, back[None], axis=0)[0]  # (nb, width)
        np.put_along_axis(s, back[None], np.float32(_NONE), axis=0)
        second_r = s.max(axis=0) if nq > 1 else np.full_like(best_r, _NONE)
        mutual_r = j[back, np.arange(nb)[:, None]] == np.arange(width)[None, :]
        ok_r = (
            mutual_r
            & (best_r > _NONE)
            & _ratio_ok(best_r, second_r, ratio)
            & (np.abs(qe[back] - r.elev[b0:b1]) <= max_elevation)
        )
        out[b0:b1] = np.maximum(ok.sum(axis=0), ok_r.sum(axis=1))
    return out


def _ratio_ok(best: Any, second: Any, ratio: float) -> Any:
    """Nearest distance below ``ratio`` x the second nearest (any distance when there is no second)."""
    d1 = np.sqrt(np.maximum(2.0 - 2.0 * best, 0.0))
    d2 = np.where(second > _NONE, np.sqrt(np.maximum(2.0 - 2.0 * second, 0.0)), np.inf)
    return d1 < ratio * d2


def keypoint_distance(m: FArray | IArray, n_query: int, n_ref: FArray | IArray) -> FArray:
    """``-log((m + 1) / (sqrt(n_query n_ref) + 1))``; ``inf`` where a view has no keypoint."""
    norm = np.sqrt(float(n_query) * np.asarray(n_ref, dtype=np.float64))
    with np.errstate(divide="ignore"):
        d = -np.log((np.asarray(m, dtype=np.float64) + 1.0) / (norm + 1.0))
    return np.where(norm > 0, d, np.inf)


class KeypointTerm(IndexedTerm[Keypoints]):
    """The local-feature term ``K`` of the Bayesian program (module docstring).

    Parameters
    ----------
    ratio : float, default 0.8
        Ratio test on descriptor distances (nearest / second nearest).
    max_elevation : float, default 0.1
        Largest difference of elevation between matched keypoints, as a
        fraction of the band's height (0.1: 9 deg of a -45..+45 deg band).
    max_queries : int, default 300
        At most this many training views (a seeded sample) serve as
        leave-one-out queries when fitting ``lambda_`` (each is matched
        against every training view, about 2.4 ms of CPU a pair of views of
        500 keypoints: 300 queries against 1000 views take about 12 min).

    Attributes
    ----------
    lambda_ : float
    unknown_cost_ : float or None
    n_places_ : int
    """

    name = "K"
    heading_free = True
    likelihood = "exp"
    _label = "keypoint"

    def __init__(self, *, ratio: float = 0.8, max_elevation: float = 0.1, max_queries: int = 300) -> None:
        self.ratio = ratio
        self.max_elevation = max_elevation
        self.max_queries = max_queries

    def __repr__(self) -> str:
        return f"KeypointTerm(ratio={self.ratio!r}, max_elevation={self.max_elevation!r}, max_queries={self.max_queries!r})"

    def _validate(self) -> None:
        r = self.ratio
        if isinstance(r, bool) or not isinstance(r, (int, float, np.floating)) or not (0 < r <= 1.5):
            raise InvalidParameterError(f"ratio must be a number in (0, 1.5], got {r!r}")
        e = self.max_elevation
        if isinstance(e, bool) or not isinstance(e, (int, float, np.floating)) or not (0 < e <= 1):
            raise InvalidParameterError(f"max_elevation must be a number in (0, 1], got {e!r}")
        super()._validate()

    # -- fitting -----------------------------------------------------------------
    def _feature(self, o: Observation) -> Keypoints | None:
        return o.keypoints if o.keypoints is not None and len(o.keypoints) > 0 else None

    def _store(self, features: list[Keypoints]) -> None:
        self.refs_ = _Refs(features)
        self._digests = [_digest(k) for k in features]

    def _counts(self, query: Keypoints) -> IArray:
        """Match counts of ``query`` against every training view (memoised per pair)."""
        dq = _digest(query)
        key = (float(self.ratio), float(self.max_elevation))
        keys = [(dq, dr, *key) for dr in self._digests]
        got = [_CACHE.get(k) for k in keys]
        missing = [i for i, g in enumerate(got) if g is None]
        counts = np.asarray([-1 if g is None else g for g in got], dtype=np.int64)
        if missing:
            refs = self.refs_ if len(missing) == len(keys) else self.refs_.subset(missing)
            new = match_counts(query, refs, ratio=float(self.ratio), max_elevation=float(self.max_elevation))
            counts[missing] = new
            for i, c in zip(missing, new, strict=True):
                _CACHE[keys[i]] = int(c)
            while len(_CACHE) > CACHE_SIZE:
                _CACHE.popitem(last=False)
        return counts

    def _view_distances(self, query: Keypoints) -> FArray:
        return keypoint_distance(self._counts(query), len(query), self.refs_.sizes)

    # -- state -------------------------------------------------------------------
    def _params_state(self) -> dict[str, Any]:
        """``{"ratio", "max_elevation"}``, before ``"lambda"`` and ``"unknown_cost"`` in :meth:`to_state`."""
        return {"ratio": float(self.ratio), "max_elevation": float(self.max_elevation)}

    def _params_from_state(self, state: dict[str, Any]) -> dict[str, Any]:
        return {"ratio": float(state.get("ratio", 0.8)), "max_elevation": float(state.get("max_elevation", 0.1))}
