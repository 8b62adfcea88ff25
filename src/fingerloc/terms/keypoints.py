"""The local-feature term ``K``: how many of the view's keypoints one relative pose explains, per place.

Each observation may carry keypoints (``Observation.keypoints``, from
:func:`fingerloc.features.keypoints.extract_keypoints`: SIFT descriptors and
positions on the sphere). Two panoramas of one room from different spots
share many local patches (furniture, pictures, windows); chance look-alikes
(ceiling tiles, shelves, the same poster in two corridors) match too, but
they do not agree with one motion of the camera. The term keeps, for each
training view, the matches that one relative pose explains:

    matches(o, v)     = mutual nearest RootSIFT neighbours passing the ratio test ``ratio`` from both sides
    inliers(o, v)     = matches within ``threshold_deg`` of the epipolar planes of the best relative pose
                        (:func:`fingerloc.features.sphere.ransac_pose`, model ``model_``)
    d(o, v)           = -log((inliers + 1) / (sqrt(n_o n_v) + 1))      (n: keypoints of each view)
    d(o, place)       = min over the place's training views v of d(o, v)
    log P(K | place)  = -lambda * d(o, place)          (up to a constant shared by the places)

``lambda`` and ``unknown_cost_`` are calibrated leave-one-out on the training
views, as for ``A`` (:mod:`.distance`). Observations without keypoints get a
zero row (the term says nothing); a training view without keypoints is never
a nearest view.

**The relative-pose model** (``model="auto"``, fitted ``model_``): the
``"upright"`` model (level cameras, horizontal motion) is faster and stricter,
the ``"general"`` one fits any tilt. At fitting, pairs of training views of
one place are verified with the general model and the median tilt of their
relative rotations (``tilt_deg_``) decides: above ``max_tilt_deg`` the
panoramas are not levelled and the general model is used.

**Retrieval** (``shortlist``, ``shortlist_appearance``): verifying a view
against every stored view costs a descriptor match and a RANSAC each; with
more than ``shortlist + shortlist_appearance`` stored views, only a
shortlist is verified (the others count as 0 inliers): the ``shortlist``
best by a bag of visual words (a vocabulary of the training descriptors,
:class:`Vocabulary`) and the ``shortlist_appearance`` nearest by the views'
appearance descriptors (``Observation.appearance``, L1 distance, where the
query and every stored view carry one).

**Headings**: the verified rotation between the query and the best view of a
place gives the heading (:meth:`KeypointTerm.heading_at`) when at least
``min_inliers`` matches support it.

Verified pairs are memoised (keyed by a digest of both views' keypoints and
the parameters, up to ``CACHE_SIZE`` pairs), so that refitting a model on the
same views (leave-one-out experiments) does not verify them again.
"""

from __future__ import annotations

import hashlib
import math
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Self

import numpy as np
from numpy.typing import NDArray

from .._types import FArray, IArray
from ..errors import InvalidParameterError
from ..features.keypoints import Keypoints, match_descriptors
from ..features.sphere import (
    MODELS,
    SAMPLE_SIZE,
    PoseFit,
    heading_of_rotation,
    ransac_pose,
    refine_pose,
    tilt_of_rotation,
)
from ..observation import Observation
from .indexed import IndexedTerm

__all__ = [
    "CACHE_SIZE",
    "REFINE_MAX",
    "KeypointTerm",
    "PairCheck",
    "Vocabulary",
    "check_pair",
    "choose_model",
    "clear_pair_cache",
    "keypoint_distance",
]

#: Pairs of views whose verification is memoised (process-wide).
CACHE_SIZE = 400_000
_CACHE: OrderedDict[tuple[Any, ...], PairCheck] = OrderedDict()
#: The matches and RANSAC fits of the last pairs verified without refinement (query first), so that a
#: heading refines its view's rotation without matching again.
_FITS_SIZE = 256
_FITS: OrderedDict[tuple[Any, ...], tuple[PairCheck, IArray, PoseFit | None]] = OrderedDict()
#: Most inliers the rotation is refined on (evenly spread among them).
REFINE_MAX = 100
#: Seed of every RANSAC (the same pair gives the same answer).
_SEED = 0


def clear_pair_cache() -> None:
    """Forget every memoised pair verification (a new process starts without them)."""
    _CACHE.clear()
    _FITS.clear()


@dataclass(frozen=True, slots=True)
class _View:
    """What the term keeps of a view: its keypoints and, when it has one, its appearance descriptor."""

    kp: Keypoints
    app: FArray | None


@dataclass(frozen=True, slots=True)
class PairCheck:
    """The verification of two views' keypoints.

    Attributes
    ----------
    matches : int
        Descriptor matches (mutual, ratio test from both sides).
    inliers : int
        Matches the relative pose explains (0 with fewer matches than a minimal sample; a minimal sample always
        fits: with few matches this count is close to ``matches``).
    heading : float
        Radians: a far feature at bearing ``x`` in the first view is at
        ``x + heading`` in the second; NaN without a pose.
    tilt : float
        Radians: tilt of the relative rotation; NaN without a pose.
    """

    matches: int
    inliers: int
    heading: float
    tilt: float

    def swapped(self) -> PairCheck:
        """The same check seen from the second view (heading negated)."""
        return PairCheck(self.matches, self.inliers, -self.heading, self.tilt)


_NONE = PairCheck(0, 0, math.nan, math.nan)


def check_pair(
    unit_a: NDArray[np.float32],
    vec_a: FArray,
    unit_b: NDArray[np.float32],
    vec_b: FArray,
    *,
    ratio: float = 0.8,
    model: str = "upright",
    threshold_deg: float = 0.6,
    max_iter: int | None = None,
    refine_min_inliers: int | None = 8,
) -> PairCheck:
    """Match two views' RootSIFT descriptors and verify the matches by one relative pose.

    Parameters
    ----------
    unit_a, unit_b : ndarray of float32, shapes (n_a, d), (n_b, d)
        Unit descriptors (:meth:`Keypoints.unit_descriptors`).
    vec_a, vec_b : ndarray, shapes (n_a, 3), (n_b, 3)
        Unit bearing vectors (:meth:`Keypoints.vectors`).
    ratio : float
        Ratio test of :func:`fingerloc.features.keypoints.match_descriptors`.
    model : {"upright", "general"}
    threshold_deg : float
        Largest epipolar error of an inlier, degrees.
    max_iter : int, optional
        RANSAC hypotheses (default 300; fewer when there are fewer distinct minimal samples).
    refine_min_inliers : int or None, default 8
        With at least this many inliers, the rotation (hence the heading) is
        refined on them by :func:`fingerloc.features.sphere.refine_pose`
        (None: never; at most :data:`REFINE_MAX` of them, evenly spread); the inliers stay the RANSAC's.
    """
    check, m, fit = _verify(unit_a, vec_a, unit_b, vec_b, ratio=ratio, model=model, threshold_deg=threshold_deg,
                            max_iter=max_iter)  # fmt: skip
    return _refined(check, m, fit, vec_a, vec_b, model, refine_min_inliers)


def _verify(
    unit_a: NDArray[np.float32],
    vec_a: FArray,
    unit_b: NDArray[np.float32],
    vec_b: FArray,
    *,
    ratio: float,
    model: str,
    threshold_deg: float,
    max_iter: int | None,
) -> tuple[PairCheck, IArray, PoseFit | None]:
    """:func:`check_pair` without the refinement: the check, the matches ``(m, 2)`` and the RANSAC's fit (or None)."""
    m = match_descriptors(unit_a, unit_b, ratio=ratio)
    k = SAMPLE_SIZE[model]
    if len(m) < k:
        return PairCheck(len(m), 0, math.nan, math.nan), m, None
    it = max_iter if max_iter is not None else 300
    fit = ransac_pose(
        vec_a[m[:, 0]],
        vec_b[m[:, 1]],
        model=model,  # type: ignore[arg-type]
        threshold=math.radians(threshold_deg),
        max_iter=it,
        seed=_SEED,
    )
    if fit is None:
        return PairCheck(len(m), 0, math.nan, math.nan), m, None
    rot = fit.rotation
    return PairCheck(len(m), fit.n_inliers, heading_of_rotation(rot), tilt_of_rotation(rot)), m, fit


def _refined(
    check: PairCheck, m: IArray, fit: PoseFit | None, vec_a: FArray, vec_b: FArray, model: str,
    refine_min_inliers: int | None,
) -> PairCheck:  # fmt: skip
    """``check`` with the rotation refined on the fit's inliers (:func:`check_pair`'s ``refine_min_inliers``)."""
    if fit is None or refine_min_inliers is None or fit.n_inliers < max(refine_min_inliers, SAMPLE_SIZE[model]):
        return check
    sel = m[fit.inliers]
    if len(sel) > REFINE_MAX:  # a spread subset bounds the cost (many inliers pin the rotation anyway)
        sel = sel[np.linspace(0, len(sel) - 1, REFINE_MAX).round().astype(np.int64)]
    rot, _ = refine_pose(vec_a[sel[:, 0]], vec_b[sel[:, 1]], fit.rotation, fit.translation, model=model)  # type: ignore[arg-type]
    return PairCheck(check.matches, check.inliers, heading_of_rotation(rot), tilt_of_rotation(rot))


def keypoint_distance(inliers: FArray | IArray, n_query: int, n_ref: FArray | IArray) -> FArray:
    """``-log((inliers + 1) / (sqrt(n_query n_ref) + 1))``; ``inf`` where a view has no keypoint."""
    norm = np.sqrt(float(n_query) * np.asarray(n_ref, dtype=np.float64))
    with np.errstate(divide="ignore"):
        d = -np.log((np.asarray(inliers, dtype=np.float64) + 1.0) / (norm + 1.0))
    return np.where(norm > 0, d, np.inf)


def _digest(k: Keypoints) -> bytes:
    h = hashlib.blake2b(digest_size=16)
    h.update(np.ascontiguousarray(k.desc).tobytes())
    h.update(np.ascontiguousarray(k.bearing).tobytes())
    h.update(np.ascontiguousarray(k.elevation).tobytes())
    return h.digest()


# ---------------------------------------------------------------------------
# retrieval: a bag of visual words


class Vocabulary:
    """A bag of visual words over RootSIFT descriptors, to rank stored views before verifying them.

    Words: k-means centres (``words`` of them, Lloyd's iterations on at most
    ``sample`` descriptors drawn with a fixed seed) of the training views'
    unit descriptors. A view is the L2-normalised tf-idf histogram of its
    descriptors' nearest words; views are ranked by the dot product of their
    histograms (cosine).

    Parameters
    ----------
    descriptors : sequence of ndarray of float32, each (n_i, d)
        The unit descriptors of each stored view.
    words : int
    sample : int
    iterations : int
    """

    def __init__(
        self, descriptors: Sequence[NDArray[np.float32]], *, words: int = 256, sample: int = 20000, iterations: int = 6
    ) -> None:
        allx = np.concatenate([d for d in descriptors if len(d)]) if any(len(d) for d in descriptors) else None
        if allx is None or len(allx) < 2:
            raise InvalidParameterError("a vocabulary needs descriptors")
        rng = np.random.default_rng(0)
        x = allx[rng.choice(len(allx), min(sample, len(allx)), replace=False)] if len(allx) > sample else allx
        k = min(words, len(x))
        c = x[rng.choice(len(x), k, replace=False)].copy()
        for _ in range(iterations):
            lab = np.argmax(x @ c.T, axis=1)
            sums = np.zeros_like(c)
            np.add.at(sums, lab, x)
            cnt = np.bincount(lab, minlength=k)
            live = cnt > 0
            c[live] = sums[live] / cnt[live, None]
            c /= np.maximum(np.linalg.norm(c, axis=1, keepdims=True), 1e-12)
        self.words_ = c.astype(np.float32)
        counts = np.stack([self._counts(d) for d in descriptors])
        df = np.count_nonzero(counts, axis=0)
        self.idf_ = (np.log((len(descriptors) + 1.0) / (df + 1.0)) + 1.0).astype(np.float32)  # smoothed: never 0
        self.views_ = np.stack([self._vector(c_) for c_ in counts])

    def _counts(self, d: NDArray[np.float32]) -> NDArray[np.float32]:
        if len(d) == 0:
            return np.zeros(len(self.words_), dtype=np.float32)
        return np.bincount(np.argmax(d @ self.words_.T, axis=1), minlength=len(self.words_)).astype(np.float32)

    def _vector(self, counts: NDArray[np.float32]) -> NDArray[np.float32]:
        v = counts * self.idf_
        n = float(np.linalg.norm(v))
        return (v / n if n > 0 else v).astype(np.float32)

    def histogram(self, d: NDArray[np.float32]) -> NDArray[np.float32]:
        """The L2-normalised tf-idf histogram of one view's unit descriptors ``d``, shape ``(words,)``."""
        return self._vector(self._counts(d))

    def scores(self, d: NDArray[np.float32]) -> NDArray[np.float32]:
        """Cosine of the query's histogram (its unit descriptors ``d``) with each stored view's, shape ``(m,)``."""
        out: NDArray[np.float32] = self.views_ @ self.histogram(d)
        return out


# ---------------------------------------------------------------------------
# the model choice


def choose_model(
    groups: Sequence[Sequence[Keypoints]],
    *,
    ratio: float = 0.8,
    threshold_deg: float = 0.6,
    max_tilt_deg: float = 1.0,
    max_pairs: int = 40,
    min_inliers: int = 30,
) -> tuple[str, float | None]:
    """The relative-pose model for these training views, and the median tilt (degrees) it was chosen by.

    Pairs of consecutive views of one place (at most ``max_pairs``, spread
    over the places) are verified with the general model; the tilts of the
    pairs with at least ``min_inliers`` inliers give the median. Above
    ``max_tilt_deg``: ``"general"``; else, or with fewer than three such
    pairs (the tilt is then None), ``"upright"``.
    """
    pairs = [(g[i], g[i + 1]) for g in groups for i in range(len(g) - 1)]
    if len(pairs) > max_pairs:
        pick = np.linspace(0, len(pairs) - 1, max_pairs).round().astype(int)
        pairs = [pairs[i] for i in pick]
    tilts = []
    for a, b in pairs:
        if len(a) == 0 or len(b) == 0:
            continue
        c = check_pair(a.unit_descriptors(), a.vectors(), b.unit_descriptors(), b.vectors(),
                       ratio=ratio, model="general", threshold_deg=threshold_deg)  # fmt: skip
        if c.inliers >= min_inliers:
            tilts.append(math.degrees(c.tilt))
    if len(tilts) < 3:
        return "upright", None
    tilt = float(np.median(tilts))
    return ("general" if tilt > max_tilt_deg else "upright"), tilt


# ---------------------------------------------------------------------------
# the term


class KeypointTerm(IndexedTerm[_View]):
    """The local-feature term ``K`` of the Bayesian program (module docstring).

    Parameters
    ----------
    ratio : float, default 0.8
        Ratio test on descriptor distances (nearest / second nearest), from both sides.
    threshold_deg : float, default 0.6
        Largest epipolar error of a verified match, degrees.
    model : {"auto", "upright", "general"}, default "auto"
        The relative-pose model; ``"auto"`` chooses it on the training views.
    max_tilt_deg : float, default 1.0
        ``"auto"``: the median tilt above which the general model is used.
    shortlist : int, default 8
        With more stored views than ``shortlist + shortlist_appearance``, only
        the ``shortlist`` best-ranked by the bag of words are verified, with
        the ``shortlist_appearance`` nearest by appearance (0 and 0: verify every view).
    shortlist_appearance : int, default 5
        Views nearest to the query by their appearance descriptors (L1) added
        to the shortlist (when the query and every stored view carry one).
    min_inliers : int, default 8
        Fewest inliers for a heading from the verified rotation.
    max_queries : int, default 200
        At most this many training views (a seeded sample) serve as
        leave-one-out queries when fitting ``lambda_``.

    Attributes
    ----------
    lambda_ : float
    unknown_cost_ : float or None
    model_ : str
        The relative-pose model used.
    tilt_deg_ : float or None
        Median tilt of the training pairs (``model="auto"``).
    n_places_ : int
    """

    name = "K"
    heading_free = True
    likelihood = "exp"
    _label = "keypoint"
    model_: str
    tilt_deg_: float | None

    def __init__(
        self,
        *,
        ratio: float = 0.8,
        threshold_deg: float = 0.6,
        model: str = "auto",
        max_tilt_deg: float = 1.0,
        shortlist: int = 8,
        shortlist_appearance: int = 5,
        min_inliers: int = 8,
        max_queries: int = 200,
    ) -> None:
        self.ratio = ratio
        self.threshold_deg = threshold_deg
        self.model = model
        self.max_tilt_deg = max_tilt_deg
        self.shortlist = shortlist
        self.shortlist_appearance = shortlist_appearance
        self.min_inliers = min_inliers
        self.max_queries = max_queries

    def __repr__(self) -> str:
        return (
            f"KeypointTerm(ratio={self.ratio!r}, threshold_deg={self.threshold_deg!r}, model={self.model!r}, "
            f"shortlist={self.shortlist!r}, shortlist_appearance={self.shortlist_appearance!r})"
        )

    def _validate(self) -> None:
        r = self.ratio
        if isinstance(r, bool) or not isinstance(r, (int, float, np.floating)) or not (0 < r <= 1):
            raise InvalidParameterError(f"ratio must be a number in (0, 1], got {r!r}")
        for name in ("threshold_deg", "max_tilt_deg"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating)) or not (0 < v < 90):
                raise InvalidParameterError(f"{name} must be a number of degrees in (0, 90), got {v!r}")
        if self.model not in ("auto", *MODELS):
            raise InvalidParameterError(f"model must be one of auto, {', '.join(MODELS)}, got {self.model!r}")
        for name in ("shortlist", "shortlist_appearance", "min_inliers"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise InvalidParameterError(f"{name} must be an integer >= 0, got {v!r}")
        super()._validate()

    # -- fitting -----------------------------------------------------------------
    def _feature(self, o: Observation) -> _View | None:
        if o.keypoints is None or len(o.keypoints) == 0:
            return None
        return _View(o.keypoints, None if o.appearance is None else np.asarray(o.appearance, dtype=np.float64))

    def _store(self, views: list[_View]) -> None:
        apps = [v.app for v in views]
        lengths = {a.shape for a in apps if a is not None}
        self._apps = np.stack(apps) if views and all(a is not None for a in apps) and len(lengths) == 1 else None  # type: ignore[arg-type]
        features = [v.kp for v in views]
        dims = {k.dim for k in features}
        if len(dims) > 1:
            raise InvalidParameterError(f"keypoints: every descriptor must have the same length, got {sorted(dims)}")
        self.dim_ = dims.pop() if dims else 0
        self.sizes_ = np.array([len(k) for k in features], dtype=np.int64)
        self._units = [k.unit_descriptors() for k in features]
        self._vecs = [k.vectors() for k in features]
        self._digests = [_digest(k) for k in features]
        self._vocab: Vocabulary | None = None

    def fit(self, groups: Sequence[Sequence[Observation]]) -> Self:
        """Store the keypoints, choose the relative-pose model, calibrate ``lambda_`` / ``unknown_cost_``."""
        self._validate()
        self._index(groups)
        self._choose(groups)
        self.calibrate(groups)
        return self

    def store(self, groups: Sequence[Sequence[Observation]], model: str) -> Self:
        """Store the training views' keypoints with a given relative-pose model, without calibrating.

        For experiments that verify pairs themselves (:meth:`checks`);
        ``lambda_`` stays 1 and ``unknown_cost_`` None.
        """
        if model not in MODELS:
            raise InvalidParameterError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
        self._validate()
        self._index(groups)
        self.model_ = model
        self.tilt_deg_ = None
        self._reset_calibration()
        return self

    def _choose(self, groups: Sequence[Sequence[Observation]]) -> None:
        self.tilt_deg_ = None
        if self.model != "auto":
            self.model_ = str(self.model)
            return
        kps = [[f.kp for o in g if (f := self._feature(o)) is not None] for g in groups]
        self.model_, self.tilt_deg_ = choose_model(
            kps, ratio=float(self.ratio), threshold_deg=float(self.threshold_deg), max_tilt_deg=float(self.max_tilt_deg)
        )

    def _short(self) -> bool:
        """Whether a query is verified against a shortlist only (more stored views than it holds)."""
        k = int(self.shortlist) + int(self.shortlist_appearance)
        return k > 0 and len(self._units) > k

    def _vocabulary(self) -> Vocabulary | None:
        if not self.shortlist or not self._short():
            return None
        if self._vocab is None:
            self._vocab = Vocabulary(self._units)
        return self._vocab

    def candidates(self, query: Keypoints, appearance: FArray | None = None) -> IArray:
        """Indices of the stored views to verify for ``query`` (every view, or the retrieval's shortlist).

        ``appearance``: the query's appearance descriptor, shape ``(d,)``
        (its ``shortlist_appearance`` nearest stored views join the shortlist).
        """
        self._check_fitted()
        n = len(self._units)
        if not self._short():
            return np.arange(n, dtype=np.int64)
        picked = []
        vocab = self._vocabulary()
        # one more than each depth: a stored copy of the query itself takes a place
        if vocab is not None:
            s = vocab.scores(query.unit_descriptors())
            k = min(n, int(self.shortlist) + 1)
            picked.append(np.argpartition(-s, k - 1)[:k])
        if self.shortlist_appearance and self._apps is not None and appearance is not None:
            a = np.asarray(appearance, dtype=np.float64).reshape(-1)
            if a.shape[0] == self._apps.shape[1]:
                d = np.abs(self._apps - a[None, :]).sum(axis=1)
                k = min(n, int(self.shortlist_appearance) + 1)
                picked.append(np.argpartition(d, k - 1)[:k])
        if not picked:
            return np.arange(n, dtype=np.int64)
        return np.unique(np.concatenate(picked)).astype(np.int64)

    def checks(self, query: Keypoints, views: IArray | None = None, *, refine: bool = True) -> list[PairCheck]:
        """:class:`PairCheck` of ``query`` against the stored views ``views`` (default: every stored view; memoised).

        ``refine``: headings from the rotation refined on the inliers (:func:`check_pair`); False
        skips that refinement (the inliers and matches are the same; what the likelihood needs).
        """
        self._check_fitted()
        if query.dim != self.dim_ and len(query) and len(self._units):
            raise InvalidParameterError(
                f"keypoints: the query's descriptors have length {query.dim}, the references' {self.dim_}"
            )
        idx = np.arange(len(self._units)) if views is None else np.asarray(views, dtype=np.int64)
        dq = _digest(query)
        params = (float(self.ratio), self.model_, float(self.threshold_deg))
        uq = vq = None
        out: list[PairCheck] = []
        for v in idx:
            dr = self._digests[int(v)]
            pair = (dq, dr) if dq <= dr else (dr, dq)
            key = (*pair, *params, True)
            got = _CACHE.get(key)
            if got is None and not refine:
                key = (*pair, *params, False)
                got = _CACHE.get(key)
            if got is None:
                if uq is None:
                    uq, vq = query.unit_descriptors(), query.vectors()
                assert vq is not None
                ordered = (dq, dr, *params)
                kept = _FITS.get(ordered) if refine else None
                if kept is not None:  # verified without refinement: refine that fit
                    got = _refined(*kept, vq, self._vecs[int(v)], self.model_, 8)
                else:
                    got, m, fit = _verify(uq, vq, self._units[int(v)], self._vecs[int(v)], ratio=float(self.ratio),
                                          model=self.model_, threshold_deg=float(self.threshold_deg), max_iter=None)  # fmt: skip
                    if refine:
                        got = _refined(got, m, fit, vq, self._vecs[int(v)], self.model_, 8)
                    else:
                        _FITS[ordered] = (got, m, fit)
                        while len(_FITS) > _FITS_SIZE:
                            _FITS.popitem(last=False)
                _CACHE[key] = got if dq <= dr else got.swapped()
                while len(_CACHE) > CACHE_SIZE:
                    _CACHE.popitem(last=False)
            elif dq > dr:
                got = got.swapped()
            out.append(got)
        return out

    def inliers(self, query: Keypoints, appearance: FArray | None = None) -> IArray:
        """Verified inliers of ``query`` against every stored view, shape ``(m,)`` (0 outside the shortlist)."""
        cand = self.candidates(query, appearance)
        out = np.zeros(len(self._units), dtype=np.int64)
        out[cand] = [c.inliers for c in self.checks(query, cand, refine=False)]
        return out

    def _view_distances(self, query: _View) -> FArray:
        return keypoint_distance(self.inliers(query.kp, query.app), len(query.kp), self.sizes_)

    # -- headings ----------------------------------------------------------------
    def heading_at(self, observation: Observation, place: int) -> tuple[float | None, int, int]:
        """Heading of ``observation`` against the best-verified training view of place index ``place``.

        The views looked at are the place's views in the query's shortlist
        (:meth:`candidates`), or all of them when the shortlist holds none.

        Returns ``(heading_deg, view, inliers)``: a feature at bearing ``b``
        in the observation is at bearing ``b + heading_deg`` in that view
        (degrees, ``[0, 360)``, from the verified relative rotation), ``view``
        its index among the place's training observations, and the inliers
        that support it; ``(None, view, inliers)`` with fewer than
        ``min_inliers`` inliers, ``(None, -1, 0)`` without keypoints.
        """
        self._check_fitted()
        f = self._feature(observation)
        sel = np.flatnonzero(self.owner_ == place)
        if f is None or sel.size == 0:
            return None, -1, 0
        # the views the likelihood verified (its memo answers at once); every view of the place if none of them was
        short = np.intersect1d(sel, self.candidates(f.kp, f.app))
        sel = short if short.size else sel
        checks = self.checks(f.kp, sel, refine=False)
        k = int(np.argmax([c.inliers for c in checks]))
        best = self.checks(f.kp, sel[k : k + 1])[0]  # the rotation refined for this view only
        view = int(self.view_[sel[k]])
        if best.inliers < max(1, int(self.min_inliers)) or not math.isfinite(best.heading):
            return None, view, best.inliers
        return float(np.mod(math.degrees(best.heading), 360.0)), view, best.inliers

    # -- state -------------------------------------------------------------------
    def _params_state(self) -> dict[str, Any]:
        """The parameters and the fitted model choice, before ``"lambda"`` and ``"unknown_cost"`` in :meth:`to_state`."""
        return {
            "ratio": float(self.ratio),
            "threshold_deg": float(self.threshold_deg),
            "model": str(self.model),
            "max_tilt_deg": float(self.max_tilt_deg),
            "shortlist": int(self.shortlist),
            "shortlist_appearance": int(self.shortlist_appearance),
            "min_inliers": int(self.min_inliers),
            "fitted_model": self.model_,
            "tilt_deg": self.tilt_deg_,
        }

    def _params_from_state(self, state: dict[str, Any]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for key, cast in (("ratio", float), ("threshold_deg", float), ("model", str), ("max_tilt_deg", float),
                          ("shortlist", int), ("shortlist_appearance", int), ("min_inliers", int)):  # fmt: skip
            if key in state:
                out[key] = cast(state[key])
        fitted = state.get("fitted_model")
        if fitted is not None and fitted not in MODELS:
            raise ValueError(f"fitted_model {fitted!r}")
        tilt = state.get("tilt_deg")
        out["_fitted"] = (fitted, None if tilt is None else float(tilt))
        return out

    def set_state(self, state: dict[str, Any], groups: Sequence[Sequence[Observation]]) -> Self:
        """Restore from :meth:`to_state` and the places' stored observations (``groups``).

        A state without the fitted model choice (a database that did not
        store it) chooses again on the stored views.
        """
        super().set_state(state, groups)
        fitted, tilt = self.__dict__.pop("_fitted", (None, None))
        if fitted is None:
            self._choose(groups)
        else:
            self.model_, self.tilt_deg_ = fitted, tilt
        return self
