"""Development benchmark on real 360 deg photographs (``fingerloc bench panorama``).

Data: a folder of equirectangular photos and their places, from a virtual
tour's source files or a labels CSV (:mod:`.panorama_tour`). Nothing of the
data ships with fingerloc: the command reads it from the paths the user gives.

Protocol:

1. Every photo is read, the band of elevations ``band`` (parts of the height,
   default 0.25..0.75, i.e. -45..+45 deg, as ``fingerloc features``) is resampled to ``width`` columns,
   and :func:`fingerloc.features.vision.observation_from_views` gives VE, CP,
   the appearance descriptor and the column profile,
   :func:`fingerloc.features.keypoints.extract_keypoints` the keypoints. The
   observations are cached as JSON Lines (``cache``), keyed by the photo's
   relative path, with the extraction's CPU time.
2. Places are defined two ways: ``area`` (the tour's areas, or the labels'
   places), and ``position`` (greedy place centres ``spacing`` apart, in map
   units, per building and floor, in file order; each photo goes to its
   nearest centre; photos without a position are left out).
3. Leave-one-out over the photos whose place has two or more: the query's
   photo is removed, every other photo is a reference. Scores per place for
   each method; top-1 and mean rank (ties counted against) of the true place,
   and the calibration of each method's posterior (softmax of its scores):
   expected calibration error of the top answer and the share of wrong
   answers above 0.9 (:func:`calibration`).

Methods: the single terms ``VE``, ``CP`` (angle-space mixtures, heading as
recorded), ``Fp`` (cyclic alignment, feature-aware costs, ``exp`` likelihood),
``A`` (:class:`~fingerloc.terms.appearance.AppearanceTerm`), ``AP`` (the
aligned column profiles), ``K`` (verified keypoint inliers,
:mod:`fingerloc.terms.keypoints`, the relative-pose model chosen as the term
chooses it) and ``K unverified`` (the descriptor matches alone), sums of their
log-likelihoods (``weighted``: one weight per term fit on the other queries;
``tempered``: one common factor fit on the other queries), and an
independent baseline: rotation-invariant hue, saturation and value
histograms compared by the Jeffrey divergence (after Ulrich and Nourbakhsh,
"Appearance-based place recognition for topological localization", ICRA
2000), nearest reference photo. The ``PlaceModel`` path (a model fit per
query, as ``learn`` / ``localize`` run it) is :mod:`.panorama_model`.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._types import FArray
from ..errors import DataFormatError, InvalidParameterError
from ..features.vision import PHOTO_EDGE_PARAMS
from ..metrics import min_per_place, true_place_ranks
from ..observation import Observation
from .panorama_heading import (
    HEADING_ESTIMATORS,
    band_signature,
    feature_heading_deg,
    fingerprint_heading_deg,
    heading_closure,
    heading_errors,
    heading_link_errors,
    image_rotation_deg,
    load_edge_labels,
    run_edge_bench,
    signature_rotation_deg,
)
from .panorama_tour import (
    DEFAULT_BAND,
    DEFAULT_WIDTH,
    CampusPhoto,
    TourLink,
    load_labels_csv,
    load_photo_band,
    load_tour_layout,
    load_tour_links,
    places_by_area,
    places_by_position,
)

__all__ = [
    "HEADING_ESTIMATORS",
    "KEYPOINT_PARAMS",
    "PANORAMA_METHODS",
    "CampusPhoto",
    "KeypointPairs",
    "PhotoFeatures",
    "TourLink",
    "band_signature",
    "calibration",
    "extract_features",
    "feature_heading_deg",
    "fingerprint_heading_deg",
    "heading_closure",
    "heading_errors",
    "heading_link_errors",
    "hsv_histogram",
    "image_rotation_deg",
    "jeffrey_divergence",
    "keypoint_pairs",
    "load_edge_labels",
    "load_labels_csv",
    "load_photo_band",
    "load_tour_layout",
    "load_tour_links",
    "places_by_area",
    "places_by_position",
    "profile_distances",
    "retrieval_recall",
    "run_edge_bench",
    "run_panorama_bench",
    "signature_rotation_deg",
]

#: Keypoint extraction parameters of the benchmark (those of ``fingerloc features``: the defaults).
KEYPOINT_PARAMS: dict[str, Any] = {}


def _extract(pano: Any, source: str) -> Observation:
    from dataclasses import replace

    from ..features.keypoints import extract_keypoints
    from ..features.vision import observation_from_views

    obs = observation_from_views(panorama=pano, appearance=True, profile=True, source=source, **PHOTO_EDGE_PARAMS)
    return replace(obs, keypoints=extract_keypoints(pano, **KEYPOINT_PARAMS))


@dataclass(frozen=True, slots=True)
class PhotoFeatures:
    """What the benchmark keeps of one photo.

    Attributes
    ----------
    observation : Observation
        VE, CP, the appearance descriptor, the column profile, the keypoints; ``source`` = the relative file.
    hsv_hist : ndarray, shape (96,)
        The baseline's histograms (:func:`hsv_histogram`).
    signature : ndarray, shape (360, 12)
        :func:`band_signature`, for the image-to-image rotation.
    extract_cpu_s : float
        CPU seconds of the observation's extraction from the band (NaN when unknown).
    """

    observation: Observation
    hsv_hist: FArray
    signature: FArray
    extract_cpu_s: float = math.nan


def _features_to_record(f: PhotoFeatures) -> dict[str, Any]:
    from ..io.jsonl import observation_to_record

    rec = observation_to_record(f.observation, ndigits=6)
    rec["hsv_hist"] = [round(float(x), 8) for x in f.hsv_hist]
    rec["signature"] = np.round(f.signature, 3).tolist()
    rec["extract_cpu_s"] = round(f.extract_cpu_s, 4)
    return rec


def _features_from_record(rec: dict[str, Any]) -> PhotoFeatures:
    from ..io.jsonl import observation_from_record

    return PhotoFeatures(
        observation_from_record(rec),
        np.asarray(rec["hsv_hist"], dtype=np.float64),
        np.asarray(rec["signature"], dtype=np.float64),
        float(rec.get("extract_cpu_s", math.nan)),
    )


def extract_features(
    photo_dir: str | Path,
    photos: Sequence[CampusPhoto],
    *,
    cache: str | Path | None = None,
    band: tuple[float, float] = DEFAULT_BAND,
    width: int = DEFAULT_WIDTH,
    on_step: Callable[[int, int], None] | None = None,
) -> list[PhotoFeatures | None]:
    """The :class:`PhotoFeatures` of each photo (None for a missing file).

    With ``cache``, results of earlier runs with the same settings are read
    from that JSON Lines file (a header line holds the settings), and the file
    is rewritten with every result when something new was extracted.
    """
    root = Path(photo_dir)
    if not root.is_dir():
        raise DataFormatError("not a folder of photos", path=root)
    known: dict[str, PhotoFeatures] = {}
    key = {"band": list(band), "width": width, "edges": PHOTO_EDGE_PARAMS, "version": 6, "keypoints": KEYPOINT_PARAMS}
    cpath = Path(cache) if cache is not None else None
    if cpath is not None and not cpath.parent.is_dir():
        raise InvalidParameterError(f"--cache: no folder {str(cpath.parent)!r} to write {cpath.name!r} into")
    if cpath is not None and cpath.is_file():
        lineno = 1
        try:
            with cpath.open(encoding="utf-8") as fh:
                header = fh.readline()
                if header.strip() and json.loads(header) == key:
                    for lineno, line in enumerate(fh, start=2):  # noqa: B007  (lineno: for the error)
                        f = _features_from_record(json.loads(line))
                        known[str(f.observation.source)] = f
        except (json.JSONDecodeError, KeyError, TypeError, ValueError, UnicodeDecodeError) as err:
            raise DataFormatError(
                f"not a feature cache of this benchmark ({err}); delete it or give another --cache",
                path=cpath,
                line=lineno,
            ) from err
    n_new = 0
    out: list[PhotoFeatures | None] = []
    for i, ph in enumerate(photos):
        if ph.file not in known and (root / ph.file).is_file():
            pano = load_photo_band(root / ph.file, band=band, width=width)
            t0 = time.process_time()
            obs = _extract(pano, ph.file)
            got = PhotoFeatures(obs, hsv_histogram(pano.image), band_signature(pano), time.process_time() - t0)
            # as the cache stores it (rounded), so that a run from the cache gives the same figures
            known[ph.file] = _features_from_record(json.loads(json.dumps(_features_to_record(got))))
            n_new += 1
        out.append(known.get(ph.file))
        if on_step is not None:
            on_step(i + 1, len(photos))
    if cpath is not None and n_new:
        tmp = cpath.with_name(cpath.name + ".tmp")
        with tmp.open("w", encoding="utf-8") as fh:
            fh.write(json.dumps(key) + "\n")
            for f in known.values():
                fh.write(json.dumps(_features_to_record(f)) + "\n")
        tmp.replace(cpath)
    return out


# ---------------------------------------------------------------------------
# the independent baseline


def hsv_histogram(image: Any, *, bins: int = 32) -> FArray:
    """Hue, saturation and value histograms of an RGB image, concatenated, each summing to 1.

    Rotation-invariant (a histogram ignores where the pixels are). Shape
    ``(3 * bins,)``. Written apart from the feature extractors on purpose: an
    independent baseline.
    """
    a = np.asarray(image, dtype=np.float64).reshape(-1, 3)
    if a.max(initial=0.0) > 1.0:
        a = a / 255.0
    mx, mn = a.max(axis=1), a.min(axis=1)
    c = mx - mn
    r, g, b = a.T
    with np.errstate(invalid="ignore", divide="ignore"):
        hr = np.where(c > 0, ((g - b) / c) % 6.0, 0.0)
        hg = np.where(c > 0, (b - r) / c + 2.0, 0.0)
        hb = np.where(c > 0, (r - g) / c + 4.0, 0.0)
        hue = np.where(mx == r, hr, np.where(mx == g, hg, hb)) / 6.0
        sat = np.where(mx > 0, c / mx, 0.0)
    out = []
    for ch in (np.clip(hue, 0, 1 - 1e-9), np.clip(sat, 0, 1 - 1e-9), np.clip(mx, 0, 1 - 1e-9)):
        h = np.bincount((ch * bins).astype(np.int64), minlength=bins).astype(np.float64)
        out.append(h / max(h.sum(), 1.0))
    return np.concatenate(out)


def jeffrey_divergence(h: FArray, k: FArray) -> FArray:
    """Jeffrey divergence between histogram rows: ``sum h log(h/m) + k log(k/m)``, ``m = (h + k) / 2``.

    ``h`` of shape ``(n, d)``, ``k`` of shape ``(m, d)``; returns ``(n, m)``.
    """
    hh = h[:, None, :]
    kk = k[None, :, :]
    m = 0.5 * (hh + kk)
    with np.errstate(invalid="ignore", divide="ignore"):
        t1 = np.where(hh > 0, hh * np.log(hh / m), 0.0)
        t2 = np.where(kk > 0, kk * np.log(kk / m), 0.0)
    out: FArray = (t1 + t2).sum(axis=2)
    return out



# ---------------------------------------------------------------------------
# keypoints: every pair verified once


@dataclass(frozen=True, slots=True)
class KeypointPairs:
    """Every pair of photos verified once (:func:`keypoint_pairs`), as symmetric ``(n, n)`` matrices.

    Attributes
    ----------
    model : str
        The relative-pose model (chosen by :func:`fingerloc.terms.keypoints.choose_model`).
    tilt_deg : float or None
        The median tilt of the training pairs it was chosen by.
    matches, inliers : ndarray of int, shape (n, n)
        Descriptor matches and verified inliers (0 on the diagonal).
    heading_deg : ndarray, shape (n, n)
        ``[a, b]``: a feature at bearing ``x`` in ``a`` is at ``x + heading`` in ``b`` (NaN without a pose).
    sizes : ndarray of int, shape (n,)
        Keypoints per photo.
    """

    model: str
    tilt_deg: float | None
    matches: NDArray[np.int64]
    inliers: NDArray[np.int64]
    heading_deg: FArray
    sizes: NDArray[np.int64]

    def distances(self, *, verified: bool = True) -> FArray:
        """The ``K`` term's distance between every two photos (:func:`fingerloc.terms.keypoints.keypoint_distance`)."""
        from ..terms.keypoints import keypoint_distance

        counts = self.inliers if verified else self.matches
        return np.stack([keypoint_distance(counts[i], int(self.sizes[i]), self.sizes) for i in range(self.sizes.size)])


def keypoint_pairs(
    obs: Sequence[Observation],
    groups: Sequence[Sequence[int]],
    *,
    model: str = "auto",
    on_step: Callable[[int, int], None] | None = None,
) -> KeypointPairs:
    """Verify every pair of photos once, with the ``K`` term's defaults (:class:`fingerloc.terms.KeypointTerm`).

    ``groups``: indices of the photos of each place, for the model choice
    (``model="auto"``: :func:`fingerloc.terms.keypoints.choose_model` on pairs of one place).
    The checks go through the term's memo, so that ``PlaceModel`` fits on the
    same photos (:mod:`.panorama_model`) do not verify them again.
    """
    from ..features.keypoints import Keypoints
    from ..terms.keypoints import KeypointTerm, choose_model

    empty = Keypoints(np.empty(0), np.empty(0), np.empty(0), np.zeros((0, 128), dtype=np.uint8))
    kps = [o.keypoints if o.keypoints is not None else empty for o in obs]
    defaults = KeypointTerm()
    tilt = None
    if model == "auto":
        model, tilt = choose_model(
            [[kps[i] for i in g if len(kps[i])] for g in groups],
            ratio=defaults.ratio,
            threshold_deg=defaults.threshold_deg,
            max_tilt_deg=defaults.max_tilt_deg,
        )
    term = KeypointTerm(shortlist=0, shortlist_appearance=0).store([[Observation(keypoints=k)] for k in kps], model)
    stored = np.flatnonzero([len(k) > 0 for k in kps])
    n = len(kps)
    matches = np.zeros((n, n), dtype=np.int64)
    inliers = np.zeros((n, n), dtype=np.int64)
    heading = np.full((n, n), np.nan)
    for a_pos, a in enumerate(stored):
        rest = np.arange(a_pos + 1, stored.size)
        for c, b_pos in zip(term.checks(kps[a], rest), rest, strict=True):
            b = stored[b_pos]
            matches[a, b] = matches[b, a] = c.matches
            inliers[a, b] = inliers[b, a] = c.inliers
            heading[a, b] = math.degrees(c.heading)
            heading[b, a] = -math.degrees(c.heading)
        if on_step is not None:
            on_step(a_pos + 1, stored.size)
    return KeypointPairs(model, tilt, matches, inliers, heading, np.array([len(k) for k in kps], dtype=np.int64))


def retrieval_recall(
    obs: Sequence[Observation],
    owner: NDArray[np.int64],
    queries: Sequence[int],
    pairs: KeypointPairs,
    shortlist: int,
    shortlist_appearance: int = 0,
) -> dict[str, Any]:
    """How often the bag-of-words shortlist (:class:`fingerloc.terms.keypoints.Vocabulary`) keeps what verification needs.

    Two vocabularies, each learned on the photos of even or odd index, rank
    the other half's queries against every other photo (the query left out);
    the ``shortlist`` best are kept, with the ``shortlist_appearance``
    nearest by the appearance descriptors (L1; the term's rule). Returns the share of queries whose
    best-verified photo is in the shortlist (``best_view``), whose true place
    has a photo in it (``true_place``), and the top-1 of ``K`` when only the
    shortlist is verified (``top1_shortlist``) against every photo (``top1_all``).
    """
    from ..terms.keypoints import Vocabulary

    units = [o.keypoints.unit_descriptors() if o.keypoints is not None else np.zeros((0, 128), np.float32) for o in obs]
    n = len(obs)
    vocabs = [Vocabulary([units[i] for i in range(n) if i % 2 == half]) for half in (0, 1)]
    # each photo's histogram under each vocabulary
    hist = [np.stack([v.histogram(u) for u in units]) for v in vocabs]
    has_app = all(o.appearance is not None for o in obs)
    apps = np.stack([np.asarray(o.appearance, dtype=np.float64) for o in obs]) if has_app and obs else None
    best_in = true_in = hit_short = hit_all = 0
    n_places = int(owner.max()) + 1
    for q in queries:
        voc = 1 - q % 2  # the vocabulary learned without the query
        s = hist[voc] @ hist[voc][q]
        s[q] = -np.inf
        short = np.argsort(-s, kind="stable")[:shortlist]
        if shortlist_appearance and apps is not None:
            da = np.abs(apps - apps[q]).sum(axis=1)
            da[q] = np.inf
            short = np.union1d(short, np.argsort(da, kind="stable")[:shortlist_appearance])
        inl = pairs.inliers[q].astype(np.float64)
        inl[q] = -1.0
        best = int(np.argmax(inl))
        best_in += int(best in short)
        true_in += int(np.any(owner[short] == owner[q]))
        for counts, hits in ((inl, "all"), (np.where(np.isin(np.arange(n), short), inl, 0.0), "short")):
            d = np.where(np.arange(n) == q, np.inf, -counts)
            per = min_per_place(d[None], owner, n_places)[0]
            ok = bool(per[owner[q]] < np.delete(per, owner[q]).min()) if n_places > 1 else True
            if hits == "all":
                hit_all += int(ok)
            else:
                hit_short += int(ok)
    m = max(len(queries), 1)
    return {
        "shortlist": shortlist,
        "shortlist_appearance": shortlist_appearance if apps is not None else 0,
        "queries": len(queries),
        "best_view": best_in / m,
        "true_place": true_in / m,
        "top1_shortlist": hit_short / m,
        "top1_all": hit_all / m,
    }


# ---------------------------------------------------------------------------
# calibration of a posterior


def calibration(log_post: FArray, truth: NDArray[np.int64], *, bins: int = 10) -> dict[str, Any]:
    """Reliability of the top answer of posteriors ``(n, P)`` (log, normalised) against the true places.

    Returns ``ece`` (expected calibration error of the top answer: the mean
    over ``bins`` equal-width confidence bins of ``|accuracy - mean
    confidence|``, weighted by the bin's share of queries), ``accuracy``,
    ``mean_confidence``, ``wrong_above_0.9`` (share of the wrong answers whose
    posterior exceeds 0.9), ``wrong_above_0.99`` (the same above 0.99:
    confidently wrong answers) and ``wrong`` (their number).
    """
    p = np.exp(log_post - log_post.max(axis=1, keepdims=True))
    p /= p.sum(axis=1, keepdims=True)
    top = np.argmax(p, axis=1)
    conf = p[np.arange(len(p)), top]
    right = top == truth
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.clip(np.searchsorted(edges, conf, side="right") - 1, 0, bins - 1)
    ece = 0.0
    for b in range(bins):
        sel = which == b
        if sel.any():
            ece += sel.mean() * abs(float(right[sel].mean()) - float(conf[sel].mean()))
    wrong = ~right
    return {
        "ece": float(ece),
        "accuracy": float(right.mean()) if right.size else None,
        "mean_confidence": float(conf.mean()) if conf.size else None,
        "wrong": int(wrong.sum()),
        "wrong_above_0.9": float(np.mean(conf[wrong] > 0.9)) if wrong.any() else None,
        "wrong_above_0.99": float(np.mean(conf[wrong] > 0.99)) if wrong.any() else None,
    }


def _loo_tempered(ll: FArray, truth: NDArray[np.int64]) -> FArray:
    """``tau * ll`` per query, one factor ``tau`` fit on the *other* queries (maximum mean log-probability of the right place)."""
    from scipy.optimize import minimize_scalar
    from scipy.special import logsumexp

    x = np.where(np.isfinite(ll), ll, -1e6)
    rows = np.arange(truth.size)
    right = x[rows, truth]
    out = np.empty_like(x)
    for k in range(truth.size):
        keep = rows != k

        def nll(log_tau: float, keep: NDArray[np.bool_] = keep) -> float:
            z = math.exp(log_tau) * x[keep]
            return float(-(math.exp(log_tau) * right[keep] - logsumexp(z, axis=1)).mean())

        res = minimize_scalar(nll, bounds=(-6.0, 3.0), method="bounded")
        out[k] = math.exp(res.x) * x[k]
    return out


# ---------------------------------------------------------------------------
# leave-one-out


#: Methods reported by :func:`run_panorama_bench`: single terms, sums of terms, the baseline.
PANORAMA_METHODS: tuple[str, ...] = (
    "VE",
    "CP",
    "Fp",
    "A",
    "AP",
    "K",
    "K unverified",
    "VE+CP+Fp",
    "Fp+A",
    "VE+CP+Fp+A weighted",
    "A+AP",
    "Fp+A+AP weighted",
    "A+K",
    "A+K unverified",
    "A+AP+K",
    "A+K weighted",
    "Fp+A+AP+K weighted",
    "A+K tempered",
    "hsv-baseline",
)

#: Terms whose weights :func:`_loo_weighted_sum` fits in ``"VE+CP+Fp+A weighted"``.
WEIGHTED_TERMS: tuple[str, ...] = ("VE", "CP", "Fp", "A")


def _loo_distance_ll(d: FArray, owner: NDArray[np.int64], n_places: int, queries: Sequence[int]) -> FArray:
    """Log-likelihoods ``-lambda d`` of each query (rows of ``queries``), query left out of the references.

    ``d`` is the all-against-all distance matrix (n, n); ``lambda`` is fit for
    each query on the leave-one-out distances of the *other* photos.
    """
    from ..terms.appearance import fit_lambda

    dd = d.copy()
    np.fill_diagonal(dd, np.inf)
    out = np.empty((len(queries), n_places))
    for k, q in enumerate(queries):
        keep = np.arange(d.shape[0]) != q
        sub = dd[np.ix_(keep, keep)]
        per = min_per_place(sub, owner[keep], n_places)
        t = owner[keep]
        ok = np.isfinite(per[np.arange(t.size), t])
        lam = fit_lambda(per[ok], t[ok]) if ok.any() else 1.0
        row = min_per_place(dd[q : q + 1][:, keep], owner[keep], n_places)[0]
        row = np.where(np.isfinite(row), row, np.nanmax(np.where(np.isfinite(row), row, np.nan)))
        out[k] = -lam * row
    return out


def _loo_weighted_sum(terms: Sequence[FArray], truth: NDArray[np.int64]) -> FArray:
    """``sum_t w_t LL_t`` per query, the weights ``w_t >= 0`` fit on the *other* queries.

    The weights maximise the mean log-probability of the right place
    (softmax over the places) of every other query: a term that many
    features make overconfident gets a small weight, a reliable one a large
    weight (the terms' calibration, learned without the query).
    """
    from scipy.optimize import minimize
    from scipy.special import logsumexp

    stack = np.stack([np.where(np.isfinite(t), t, -1e6) for t in terms])  # (T, n, P)
    # scale each term to unit spread first, so that one step size suits every weight
    spread = np.array([max(float(np.std(t)), 1e-9) for t in stack])
    stack = stack / spread[:, None, None]
    n = truth.size
    out = np.empty(stack.shape[1:])

    def nll(theta: FArray, rows: NDArray[np.int64]) -> tuple[float, FArray]:
        w = np.exp(theta)
        sub = stack[:, rows]  # (T, m, P)
        z = np.tensordot(w, sub, axes=1)  # (m, P)
        lse = logsumexp(z, axis=1)
        r = np.arange(rows.size)
        value = float(-(z[r, truth[rows]] - lse).mean())
        prob = np.exp(z - lse[:, None])
        # d value / d theta_t = -w_t mean_i (LL_t[i, truth_i] - sum_p prob[i, p] LL_t[i, p])
        grad = -w * (sub[:, r, truth[rows]] - (sub * prob[None]).sum(axis=2)).mean(axis=1)
        return value, grad

    theta0 = np.zeros(stack.shape[0])
    for k in range(n):
        rows = np.delete(np.arange(n), k)
        res = minimize(nll, theta0, args=(rows,), jac=True, method="L-BFGS-B", bounds=[(-8.0, 5.0)] * stack.shape[0])
        out[k] = np.tensordot(np.exp(res.x), stack[:, k], axes=1)
    return out


def profile_distances(obs: Sequence[Observation]) -> FArray:
    """``1 - rho`` between every two observations' profiles (the ``AP`` term's distance), shape ``(n, n)``."""
    from ..terms.profile import profile_peaks

    prof = np.stack([o.profile for o in obs])  # type: ignore[misc]
    ffts = np.fft.rfft(prof, axis=1)
    return np.stack([1.0 - profile_peaks(p, ffts, prof.shape[1])[0] for p in prof])


def _loo_scores(
    obs: list[Observation],
    labels: list[str],
    hists: list[FArray],
    queries: Sequence[int],
    n_components: int,
    kdist: dict[str, FArray],
) -> tuple[dict[str, FArray], NDArray[np.int64]]:
    """Per-method scores ``(n_queries, P)`` and the true place of each query."""
    from scipy.spatial.distance import cdist

    from ..align import CostModel, alignment_costs
    from ..fingerprint import make_fingerprint
    from ..model import PlaceModel

    classes = sorted(set(labels))
    owner = np.array([classes.index(lab) for lab in labels], dtype=np.int64)
    n_places = len(classes)
    out: dict[str, FArray] = {}

    # mixtures: places other than the query's are fit once on all their photos; the query's place
    # is refit without the query
    def mixture_model(sub: list[Observation], sub_labels: list[str]) -> Any:
        return PlaceModel(n_components, terms=("VE", "CP")).fit(sub, sub_labels)

    full = mixture_model([o.with_label(lab) for o, lab in zip(obs, labels, strict=True)], labels)
    full_cols = [classes.index(str(c)) for c in full.classes_]
    qobs = [obs[q] for q in queries]
    all_ll = full.term_log_likelihoods(qobs)
    for term in ("VE", "CP"):
        mat = np.empty((len(queries), n_places))
        mat[:, full_cols] = all_ll[term]
        out[term] = mat
    for k, q in enumerate(queries):
        mates = [i for i in range(len(obs)) if i != q and owner[i] == owner[q]]
        own = mixture_model([obs[i].with_label(labels[q]) for i in mates], [labels[q]] * len(mates))
        ll = own.term_log_likelihoods([obs[q]])
        for term in ("VE", "CP"):
            out[term][k, owner[q]] = ll[term][0, 0]
    fps = [make_fingerprint(o) for o in obs]
    d_fp = alignment_costs(fps, fps, cyclic=True, costs=CostModel.feature_aware())
    out["Fp"] = _loo_distance_ll(d_fp, owner, n_places, queries)
    app = np.stack([o.appearance for o in obs])  # type: ignore[misc]
    out["A"] = _loo_distance_ll(cdist(app, app, metric="cityblock"), owner, n_places, queries)
    out["AP"] = _loo_distance_ll(profile_distances(obs), owner, n_places, queries)
    out["K"] = _loo_distance_ll(kdist["K"], owner, n_places, queries)
    out["K unverified"] = _loo_distance_ll(kdist["K unverified"], owner, n_places, queries)
    truth = owner[list(queries)]
    for combo in ("VE+CP+Fp", "Fp+A", "A+AP", "A+K", "A+AP+K"):
        out[combo] = np.sum([out[t] for t in combo.split("+")], axis=0)
    out["A+K unverified"] = out["A"] + out["K unverified"]
    out["VE+CP+Fp+A weighted"] = _loo_weighted_sum([out[t] for t in WEIGHTED_TERMS], truth)
    out["Fp+A+AP weighted"] = _loo_weighted_sum([out[t] for t in ("Fp", "A", "AP")], truth)
    out["A+K weighted"] = _loo_weighted_sum([out["A"], out["K"]], truth)
    out["Fp+A+AP+K weighted"] = _loo_weighted_sum([out[t] for t in ("Fp", "A", "AP", "K")], truth)
    out["A+K tempered"] = _loo_tempered(out["A+K"], truth)
    h = np.stack(hists)
    dj = jeffrey_divergence(h, h)
    np.fill_diagonal(dj, np.inf)
    out["hsv-baseline"] = -min_per_place(dj[list(queries)], owner, n_places)
    return out, truth


def run_panorama_bench(
    photo_dir: str | Path,
    areas_dir: str | Path | None = None,
    *,
    labels: str | Path | None = None,
    minimap: str | Path | None = None,
    cache: str | Path | None = None,
    spacing: float = 0.03,
    n_components: int = 3,
    width: int = DEFAULT_WIDTH,
    max_queries: int | None = None,
    shortlist: int = 8,
    shortlist_appearance: int = 5,
    on_step: Callable[[str, int, int], None] | None = None,
) -> dict[str, Any]:
    """Leave-one-out top-1, mean rank and calibration per method, places by area and by position (module docstring).

    Give the tour's area definitions (``areas_dir``, with ``minimap``) or a
    labels CSV (``labels``: ``file,place[,x,y]``, files relative to
    ``photo_dir``).

    Returns
    -------
    dict
        ``{"photos", "features", "keypoints", "places": {"area": {...}, "position": {...}}, "heading_links"}``;
        per definition: ``n_places``, ``n_queries``, per method ``top1``,
        ``mean_rank`` and ``calibration``, and the shortlist's ``retrieval`` recall.
    """
    if (areas_dir is None) == (labels is None):
        raise InvalidParameterError("give the tour's area definitions (--areas) or a labels CSV (--labels), one of them")
    photos = load_tour_layout(areas_dir, minimap) if areas_dir is not None else load_labels_csv(labels)  # type: ignore[arg-type]
    step = (lambda name: (lambda i, n: on_step(name, i, n))) if on_step is not None else (lambda name: None)
    feats = extract_features(photo_dir, photos, cache=cache, width=width, on_step=step("extract"))
    have = [i for i, f in enumerate(feats) if f is not None]
    if len(have) < 3:
        raise DataFormatError(f"only {len(have)} of the tour's photos were found", path=Path(photo_dir))
    obs_all: list[Observation | None] = [None if f is None else f.observation for f in feats]
    obs = [obs_all[i] for i in have]
    cpu = np.array([feats[i].extract_cpu_s for i in have])  # type: ignore[union-attr]
    res: dict[str, Any] = {
        "photos": len(have),
        "photos_listed": len(photos),
        "features": {
            "VE_per_photo": float(np.mean([o.ve.size for o in obs])),  # type: ignore[union-attr]
            "CP_per_photo": float(np.mean([o.cp.size for o in obs])),  # type: ignore[union-attr]
            "keypoints_per_photo": float(np.mean([len(o.keypoints or ()) for o in obs])),  # type: ignore[union-attr, arg-type]
            "extract_cpu_s_per_photo": float(np.nanmean(cpu)) if np.isfinite(cpu).any() else None,
        },
        "places": {},
    }
    by_area = places_by_area(photos)
    groups: dict[str, list[int]] = {}
    for k, i in enumerate(have):
        groups.setdefault(str(by_area[i]), []).append(k)
    pairs = keypoint_pairs(obs, list(groups.values()), on_step=step("verify"))  # type: ignore[arg-type]
    res["keypoints"] = {
        "model": pairs.model,
        "tilt_deg": pairs.tilt_deg,
        "inliers_same_area_median": _median_pairs(pairs.inliers, [by_area[i] for i in have], True),
        "inliers_other_area_p99": _quantile_pairs(pairs.inliers, [by_area[i] for i in have], 0.99),
    }
    kd = {"K": pairs.distances(), "K unverified": pairs.distances(verified=False)}
    res["heading"] = heading_errors(photos, feats)
    res["heading_closure"] = heading_closure(pairs.inliers, pairs.heading_deg, [by_area[i] for i in have])
    if areas_dir is not None:
        pos = {i: k for k, i in enumerate(have)}

        def check(a: Observation, b: Observation) -> Any:
            from ..terms.keypoints import PairCheck

            ia, ib = pos[_index_of(feats, a)], pos[_index_of(feats, b)]
            h = pairs.heading_deg[ia, ib]
            return PairCheck(int(pairs.matches[ia, ib]), int(pairs.inliers[ia, ib]), math.radians(h) if np.isfinite(h) else math.nan, math.nan)

        res["heading_links"] = heading_link_errors(load_tour_links(areas_dir), photos, feats, keypoint_check=check)
    for name, labels_all in (("area", by_area), ("position", places_by_position(photos, spacing=spacing))):
        idx = [k for k, i in enumerate(have) if labels_all[i] is not None]
        sub_obs = [obs[k] for k in idx]
        sub_lab = [str(labels_all[have[k]]) for k in idx]
        sub_h = [feats[have[k]].hsv_hist for k in idx]  # type: ignore[union-attr]
        counts: dict[str, int] = {}
        for lab in sub_lab:
            counts[lab] = counts.get(lab, 0) + 1
        queries = [k for k, lab in enumerate(sub_lab) if counts[lab] >= 2]
        if max_queries is not None and len(queries) > max_queries:
            queries = sorted(np.random.default_rng(0).choice(queries, max_queries, replace=False).tolist())
        if len(counts) < 2 or not queries:
            continue
        if on_step is not None:
            on_step(name, 0, len(queries))
        sub = np.ix_(idx, idx)
        scores, truth = _loo_scores(
            sub_obs, sub_lab, sub_h, queries, n_components, {k: v[sub] for k, v in kd.items()}  # type: ignore[arg-type]
        )
        ranks = {m: true_place_ranks(scores[m], truth).tolist() for m in PANORAMA_METHODS}
        classes = sorted(set(sub_lab))
        owner = np.array([classes.index(lab) for lab in sub_lab], dtype=np.int64)
        sub_pairs = KeypointPairs(pairs.model, pairs.tilt_deg, pairs.matches[sub], pairs.inliers[sub],
                                  pairs.heading_deg[sub], pairs.sizes[idx])  # fmt: skip
        res["places"][name] = {
            "n_places": len(counts),
            "n_queries": len(queries),
            "methods": {
                m: {
                    "top1": float(np.mean(np.asarray(r) == 1)) if r else None,
                    "mean_rank": float(np.mean(r)) if r else None,
                    "calibration": calibration(_normalised(scores[m]), truth),
                }
                for m, r in ranks.items()
            },
            "retrieval": retrieval_recall(sub_obs, owner, queries, sub_pairs, shortlist, shortlist_appearance),  # type: ignore[arg-type]
        }
    return res


def _normalised(scores: FArray) -> FArray:
    from scipy.special import logsumexp

    x = np.where(np.isfinite(scores), scores, -1e6)
    return np.asarray(x - logsumexp(x, axis=1, keepdims=True))


def _index_of(feats: Sequence[PhotoFeatures | None], o: Observation) -> int:
    for i, f in enumerate(feats):
        if f is not None and f.observation is o:
            return i
    raise KeyError(o.source)


def _median_pairs(m: NDArray[np.int64], labels: Sequence[Any], same: bool) -> float | None:
    iu = np.triu_indices(len(labels), 1)
    lab = np.asarray([str(x) for x in labels])
    sel = (lab[iu[0]] == lab[iu[1]]) == same
    return float(np.median(m[iu][sel])) if sel.any() else None


def _quantile_pairs(m: NDArray[np.int64], labels: Sequence[Any], q: float) -> float | None:
    iu = np.triu_indices(len(labels), 1)
    lab = np.asarray([str(x) for x in labels])
    sel = lab[iu[0]] != lab[iu[1]]
    return float(np.quantile(m[iu][sel], q)) if sel.any() else None
