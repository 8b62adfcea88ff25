"""Headings between two panoramas, and the vertical-edge extractor against hand labels (``fingerloc bench panorama``).

Heading estimators between two photos (a feature at bearing ``x`` in photo
``a`` is at bearing ``x + heading`` in photo ``b``), judged against the
tour's navigation arrows (:func:`heading_link_errors`):

* ``keypoints``: the rotation of the relative pose that the verified
  keypoint matches give (:func:`fingerloc.terms.keypoints.check_pair`), where
  at least ``min_inliers`` matches support it;
* ``keypoints or profile``: the same, and the column profile's heading for the
  other pairs (what ``localize`` reports with the ``panorama`` preset);
* ``profile``, ``Fp``, ``features``, ``signature``: the column profiles'
  correlation, the fingerprint's cyclic alignment, the feature bearings'
  correlation, the band signature's correlation.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .._types import FArray
from ..errors import DataFormatError, InvalidParameterError
from ..features.vision import PHOTO_EDGE_PARAMS
from ..observation import Observation
from .panorama_tour import DEFAULT_BAND, DEFAULT_WIDTH, CampusPhoto, TourLink, load_photo_band

if TYPE_CHECKING:
    from ..terms.keypoints import PairCheck
    from .panorama import PhotoFeatures

__all__ = [
    "HEADING_ESTIMATORS",
    "band_signature",
    "feature_heading_deg",
    "fingerprint_heading_deg",
    "heading_closure",
    "heading_errors",
    "heading_link_errors",
    "image_rotation_deg",
    "load_edge_labels",
    "run_edge_bench",
    "signature_rotation_deg",
]


# ---------------------------------------------------------------------------
# vertical edges against hand labels


def _match_count(found: FArray, truth: FArray, tol: float) -> int:
    """Greedy one-to-one matches within ``tol`` degrees on the circle, closest pairs first."""
    if found.size == 0 or truth.size == 0:
        return 0
    d = np.abs((found[:, None] - truth[None, :] + 180.0) % 360.0 - 180.0)
    pairs = sorted((float(d[i, j]), i, j) for i in range(found.size) for j in range(truth.size) if d[i, j] <= tol)
    used_f: set[int] = set()
    used_t: set[int] = set()
    for _, i, j in pairs:
        if i not in used_f and j not in used_t:
            used_f.add(i)
            used_t.add(j)
    return len(used_f)


def load_edge_labels(path: str | Path) -> dict[str, Any]:
    """Read and check a hand-label file (see ``tests/data/campus_edges.json`` for the format)."""
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except OSError as err:
        raise DataFormatError(f"cannot read: {err.strerror or err}", path=p) from err
    except json.JSONDecodeError as err:
        raise DataFormatError(f"malformed JSON ({err.msg})", path=p) from err
    try:
        tol = float(data["tolerance_deg"])
        photos = data["photos"]
        for ph in photos:
            lo, hi = (float(v) for v in ph["range_deg"])
            cols = [float(v) for v in ph["column_deg"]]
            if not (0 <= lo < hi <= 360) or any(not lo <= c <= hi for c in cols) or not isinstance(ph["file"], str):
                raise ValueError(ph.get("file"))
    except (KeyError, TypeError, ValueError) as err:
        raise DataFormatError(
            f'expected {{"tolerance_deg": x, "photos": [{{"file", "range_deg", "column_deg"}}, ...]}} ({err})', path=p
        ) from err
    if not (math.isfinite(tol) and tol > 0):
        raise DataFormatError(f"tolerance_deg must be > 0, got {tol!r}", path=p)
    return dict(data)


def run_edge_bench(
    labels: str | Path,
    photo_dir: str | Path,
    *,
    band: tuple[float, float] = DEFAULT_BAND,
    width: int = DEFAULT_WIDTH,
    edge_params: dict[str, Any] | None = None,
    tol_deg: float | None = None,
) -> dict[str, Any]:
    """Precision and recall of :func:`~fingerloc.features.vision.vertical_edges` against hand labels.

    Only detections inside each photo's labelled ``range_deg`` count.
    ``edge_params`` default to :data:`PHOTO_EDGE_PARAMS`. Detected bearings
    are turned into column degrees (``column_deg = -bearing``, the panorama's
    default orientation).
    """
    from ..features.vision import vertical_edges

    data = load_edge_labels(labels)
    tol = float(data["tolerance_deg"]) if tol_deg is None else float(tol_deg)
    params = dict(PHOTO_EDGE_PARAMS if edge_params is None else edge_params)
    root = Path(photo_dir)
    per: list[dict[str, Any]] = []
    tp = n_found = n_true = 0
    for ph in data["photos"]:
        pano = load_photo_band(root / ph["file"], band=band, width=width)
        cols = np.mod(-np.rad2deg(vertical_edges(pano, **params)), 360.0)
        lo, hi = (float(v) for v in ph["range_deg"])
        cols = cols[(cols >= lo) & (cols <= hi)]
        truth = np.asarray(ph["column_deg"], dtype=np.float64)
        m = _match_count(cols, truth, tol)
        per.append({"file": ph["file"], "found": int(cols.size), "true": int(truth.size), "matched": m})
        tp, n_found, n_true = tp + m, n_found + cols.size, n_true + truth.size
    return {
        "tolerance_deg": tol,
        "band": list(band),
        "width": width,
        "edge_params": params,
        "photos": per,
        "precision": tp / n_found if n_found else None,
        "recall": tp / n_true if n_true else None,
        "matched": tp,
        "found": int(n_found),
        "true": int(n_true),
    }


# ---------------------------------------------------------------------------
# heading between two panoramas


def band_signature(pano: Any, *, columns: int = 360, strips: int = 4) -> FArray:
    """Per-bearing signature of a panorama for the image-to-image rotation, shape ``(columns, 3 * strips)``.

    The band is averaged into ``columns`` columns and ``strips`` horizontal
    strips; each cell holds its mean log luminance and two chromaticities;
    each channel is standardised over the columns.
    """
    img = np.asarray(pano.image, dtype=np.float64)
    h, w, _ = img.shape
    lum = img @ np.array([0.299, 0.587, 0.114])
    tot = img.sum(axis=2) + 0.06
    chans = np.stack([np.log(lum + 0.02), img[:, :, 0] / tot, img[:, :, 1] / tot], axis=2)
    # cell means by cumulative sums over the strip and column boundaries
    rb = np.linspace(0, h, strips + 1).round().astype(np.int64)
    cb = np.linspace(0, w, columns + 1).round().astype(np.int64)
    cum = np.zeros((h + 1, w + 1, 3))
    cum[1:, 1:] = chans.cumsum(axis=0).cumsum(axis=1)
    box = cum[rb[1:]][:, cb[1:]] - cum[rb[:-1]][:, cb[1:]] - cum[rb[1:]][:, cb[:-1]] + cum[rb[:-1]][:, cb[:-1]]
    area = np.maximum(np.diff(rb)[:, None] * np.diff(cb)[None, :], 1)[:, :, None]
    sig = (box / area).transpose(1, 0, 2).reshape(columns, strips * 3)  # (columns, strips * channels)
    sig -= sig.mean(axis=0)
    sig /= np.maximum(sig.std(axis=0), 1e-9)
    return sig


def image_rotation_deg(a: Any, b: Any, *, columns: int = 360) -> tuple[float, float]:
    """Rotation between two panoramas by brute-force circular cross-correlation of their band signatures.

    Returns ``(heading_deg, peak)``: a feature at bearing ``x`` in ``a`` is at
    bearing ``x + heading_deg`` in ``b`` (degrees, ``[0, 360)``), and the
    correlation at the best shift (1: identical up to rotation). Both
    panoramas must share the column orientation (``clockwise``).
    """
    if a.clockwise != b.clockwise:
        raise InvalidParameterError("both panoramas must have the same column orientation (clockwise)")
    return signature_rotation_deg(
        band_signature(a, columns=columns), band_signature(b, columns=columns), clockwise=a.clockwise
    )


def signature_rotation_deg(sa: FArray, sb: FArray, *, clockwise: bool = True) -> tuple[float, float]:
    """:func:`image_rotation_deg` on two :func:`band_signature` arrays of one shape ``(columns, c)``."""
    columns = sa.shape[0]
    # corr[s] = mean over columns of <sa[j], sb[j + s]>
    fa, fb = np.fft.rfft(sa, axis=0), np.fft.rfft(sb, axis=0)
    corr = np.fft.irfft(np.conj(fa) * fb, n=columns, axis=0).sum(axis=1) / (columns * sa.shape[1])
    s = int(np.argmax(corr))
    sign = -1.0 if clockwise else 1.0  # b's column j + s holds a's column j
    return float(np.mod(sign * s * 360.0 / columns, 360.0)), float(corr[s])


def fingerprint_heading_deg(a: Observation, b: Observation) -> float | None:
    """Heading from the cyclic alignment of the fingerprints (feature-aware costs), same convention as above."""
    from ..align import CostModel, cyclic_alignment
    from ..fingerprint import make_fingerprint

    r = cyclic_alignment(make_fingerprint(a), make_fingerprint(b), costs=CostModel.feature_aware())
    if r.heading_deg is None:
        return None
    # cyclic_alignment: bearing_a = bearing_b + heading_deg  ->  bearing_b = bearing_a - heading_deg
    return float(np.mod(-r.heading_deg, 360.0))


def feature_heading_deg(a: Observation, b: Observation, *, sigma_deg: float = 2.0, bins: int = 720) -> float | None:
    """Heading by brute-force circular correlation of the feature bearings (same convention as above).

    Each feature type becomes a circular density on ``bins`` bins (a Gaussian
    of ``sigma_deg`` per feature; colour patches one density per hue letter,
    so that only patches of one letter pair up); the heading maximises the sum
    over the types of the correlation of ``a``'s densities with ``b``'s. None
    when the two share no feature type.
    """
    from ..fingerprint import hue_letter

    grid = np.arange(bins) * 360.0 / bins

    def density(bearings_rad: FArray) -> FArray:
        deg = np.mod(np.rad2deg(bearings_rad), 360.0)
        d = (grid[None, :] - deg[:, None] + 180.0) % 360.0 - 180.0
        out: FArray = np.exp(-0.5 * (d / sigma_deg) ** 2).sum(axis=0)
        return out

    def groups(o: Observation) -> dict[str, FArray]:
        g = {"VE": o.ve}
        letters = [hue_letter(float(h)) for h in o.cp_hue]
        for letter in sorted(set(letters)):
            g["CP" + letter] = o.cp[[k for k, x in enumerate(letters) if x == letter]]
        return g

    ga, gb = groups(a), groups(b)
    corr = np.zeros(bins)
    shared = False
    for key in ga.keys() & gb.keys():
        if ga[key].size and gb[key].size:
            shared = True
            fa, fb = np.fft.rfft(density(ga[key])), np.fft.rfft(density(gb[key]))
            corr += np.fft.irfft(np.conj(fa) * fb, n=bins)  # corr[s] = sum_j da[j] db[j + s]
    if not shared:
        return None
    return float(grid[int(np.argmax(corr))])


def heading_errors(photos: Sequence[CampusPhoto], feats: Sequence[PhotoFeatures | None]) -> dict[str, Any]:
    """Fingerprint heading against the image-to-image rotation, on consecutive photos of one area.

    Returns the number of pairs, the median absolute error (degrees) and the
    share of pairs within 30 deg, over all pairs and over the pairs whose
    signature correlation peak is at least 0.5 (the oracle is then clear),
    and the median error of a random heading (90 deg) for reference.
    """
    errs: list[float] = []
    errs_f: list[float] = []
    peaks: list[float] = []
    rows: list[dict[str, Any]] = []
    for k in range(len(photos) - 1):
        a, b = photos[k], photos[k + 1]
        fa, fb = feats[k], feats[k + 1]
        if a.area != b.area or fa is None or fb is None:
            continue
        truth, peak = signature_rotation_deg(fa.signature, fb.signature)
        h = fingerprint_heading_deg(fa.observation, fb.observation)
        err = 180.0 if h is None else abs((h - truth + 180.0) % 360.0 - 180.0)
        hf = feature_heading_deg(fa.observation, fb.observation)
        errf = 180.0 if hf is None else abs((hf - truth + 180.0) % 360.0 - 180.0)
        errs.append(err)
        errs_f.append(errf)
        peaks.append(peak)
        rows.append(
            {
                "a": a.file,
                "b": b.file,
                "oracle_deg": truth,
                "peak": peak,
                "fp_deg": h,
                "error_deg": err,
                "features_deg": hf,
                "features_error_deg": errf,
            }
        )
    pk = np.asarray(peaks)

    def summary(e: FArray, sel: NDArray[np.bool_]) -> dict[str, Any]:
        if not sel.any():
            return {"pairs": 0, "median_error_deg": None, "within_30": None}
        return {
            "pairs": int(sel.sum()),
            "median_error_deg": float(np.median(e[sel])),
            "within_30": float(np.mean(e[sel] <= 30.0)),
        }

    out: dict[str, Any] = {}
    for name, e in (("Fp", np.asarray(errs)), ("features", np.asarray(errs_f))):
        out[f"{name}, all pairs"] = summary(e, np.ones(e.size, dtype=bool))
        out[f"{name}, clear oracle"] = summary(e, pk >= 0.5)
    out["pairs"] = rows
    return out


def heading_closure(
    inliers: NDArray[np.int64], heading_deg: FArray, labels: Sequence[Any], *, min_inliers: int = 8
) -> dict[str, Any]:
    """How well headings add up around triples of photos of one place: an exact check that needs no ground truth.

    For photos ``a, b, c`` of one label whose three pairs each have at least
    ``min_inliers`` inliers, ``heading[a, b] + heading[b, c]`` must equal
    ``heading[a, c]`` (a feature at ``x`` in ``a`` is at ``x + h_ab`` in ``b``).
    With independent errors of spread ``s`` per pair, the closure error has
    spread ``s sqrt(3)``.

    Parameters
    ----------
    inliers : ndarray of int, shape (n, n)
    heading_deg : ndarray, shape (n, n)
        Degrees, NaN without a pose.
    labels : sequence, length n
        Place of each photo (None: left out).

    Returns
    -------
    dict
        ``triples``, ``median_deg`` (median absolute closure error, None
        without triples), ``within_2_deg`` (share), ``per_pair_deg``
        (``median_deg / sqrt(3)``), ``min_inliers``.
    """
    import itertools

    inl = np.asarray(inliers)
    h = np.asarray(heading_deg, dtype=np.float64)
    by: dict[Any, list[int]] = {}
    for i, lab in enumerate(labels):
        if lab is not None:
            by.setdefault(lab, []).append(i)
    errs = []
    for ids in by.values():
        for a, b, c in itertools.combinations(ids, 3):
            if min(inl[a, b], inl[b, c], inl[a, c]) >= min_inliers and np.isfinite([h[a, b], h[b, c], h[a, c]]).all():
                errs.append(abs((h[a, b] + h[b, c] - h[a, c] + 180.0) % 360.0 - 180.0))
    med = float(np.median(errs)) if errs else None
    return {
        "min_inliers": int(min_inliers),
        "triples": len(errs),
        "median_deg": med,
        "within_2_deg": float(np.mean(np.asarray(errs) < 2.0)) if errs else None,
        "per_pair_deg": med / math.sqrt(3.0) if med is not None else None,
    }


#: Heading estimators of :func:`heading_link_errors`.
HEADING_ESTIMATORS: tuple[str, ...] = ("keypoints", "keypoints or profile", "profile", "Fp", "features", "signature")


def heading_link_errors(
    links: Sequence[TourLink],
    photos: Sequence[CampusPhoto],
    feats: Sequence[PhotoFeatures | None],
    *,
    keypoint_check: Callable[[Observation, Observation], PairCheck | None] | None = None,
    min_inliers: int = 8,
) -> dict[str, Any]:
    """Heading estimators against the tour's arrows (:func:`load_tour_links`), on the photos linked both ways.

    Estimators: ``profile`` (:func:`fingerloc.features.vision.profile_rotation_deg`
    on the observations' column profiles, what ``localize`` reports with the
    ``AP`` term), ``Fp`` (the fingerprint's cyclic alignment), ``features``
    (:func:`feature_heading_deg`) and ``signature`` (the former oracle,
    :func:`signature_rotation_deg`); with ``keypoint_check`` (two
    observations -> their :class:`~fingerloc.terms.keypoints.PairCheck`),
    ``keypoints`` (the verified rotation, where at least ``min_inliers``
    inliers support it; no estimate elsewhere) and ``keypoints or profile``.
    Per estimator, over all linked pairs and over the pairs of one area: the
    number of pairs, how many have an estimate, the median absolute error
    (degrees; a pair without an estimate counts 180) and over the pairs with
    one, the shares within 10 and 30 deg; ``pairs`` lists every pair.
    """
    from ..features.vision import profile_rotation_deg

    by_file = {p.file: f for p, f in zip(photos, feats, strict=True)}
    names = HEADING_ESTIMATORS if keypoint_check is not None else HEADING_ESTIMATORS[2:]
    errs: dict[str, list[float]] = {k: [] for k in names}
    have: dict[str, list[bool]] = {k: [] for k in names}
    same: list[bool] = []
    rows: list[dict[str, Any]] = []

    def err(h: float | None, truth: float) -> float:
        return 180.0 if h is None else abs((h - truth + 180.0) % 360.0 - 180.0)

    for ln in links:
        fa, fb = by_file.get(ln.a), by_file.get(ln.b)
        if fa is None or fb is None:
            continue
        oa, ob = fa.observation, fb.observation
        prof = None if oa.profile is None or ob.profile is None else profile_rotation_deg(oa.profile, ob.profile)[0]
        kp: float | None = None
        if keypoint_check is not None:
            c = keypoint_check(oa, ob)
            if c is not None and c.inliers >= min_inliers and math.isfinite(c.heading):
                kp = float(np.mod(math.degrees(c.heading), 360.0))
        est: dict[str, float | None] = {
            "keypoints": kp,
            "keypoints or profile": kp if kp is not None else prof,
            "profile": prof,
            "Fp": fingerprint_heading_deg(oa, ob),
            "features": feature_heading_deg(oa, ob),
            "signature": signature_rotation_deg(fa.signature, fb.signature)[0],
        }
        est = {k: est[k] for k in names}
        for k, h in est.items():
            errs[k].append(err(h, ln.heading_deg))
            have[k].append(h is not None)
        same.append(ln.same_area)
        rows.append({"a": ln.a, "b": ln.b, "truth_deg": ln.heading_deg, "same_area": ln.same_area, **est})
    sel_same = np.asarray(same, dtype=bool)
    out: dict[str, Any] = {}
    for k, e in errs.items():
        arr = np.asarray(e)
        got = np.asarray(have[k], dtype=bool)
        for name, sel in (("all links", np.ones(arr.size, dtype=bool)), ("same area", sel_same)):
            est_sel = sel & got
            out[f"{k}, {name}"] = {
                "pairs": int(sel.sum()),
                "estimated": int(est_sel.sum()),
                "median_error_deg": float(np.median(arr[sel])) if sel.any() else None,
                "median_error_estimated_deg": float(np.median(arr[est_sel])) if est_sel.any() else None,
                "within_10": float(np.mean(arr[est_sel] <= 10.0)) if est_sel.any() else None,
                "within_30": float(np.mean(arr[est_sel] <= 30.0)) if est_sel.any() else None,
            }
    out["pairs"] = rows
    return out
