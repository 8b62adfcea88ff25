"""Development benchmark on real 360 deg photographs (``fingerloc bench panorama``).

Data: a folder of equirectangular photos (one per spot of a virtual campus
tour) and the tour's area definitions, TypeScript files that list each area's
photos (``id: '...'``, ``imageUrl: '...'``, ``buildingBlock``, ``floorLevel``),
and optionally a table of hand-placed map positions per photo id
(``'photo-id': { x: 0.5, y: 0.7 }``). Nothing of the data ships with
fingerloc: the command reads it from the paths the user gives.

Protocol:

1. Every photo is read, the band of elevations ``band`` (parts of the height,
   default 0.25..0.75, i.e. -45..+45 deg, as ``fingerloc features``) is resampled to ``width`` columns,
   and :func:`fingerloc.features.vision.observation_from_views` gives VE, CP
   and the appearance descriptor. The observations are cached as JSON Lines
   (``cache``), keyed by the photo's relative path.
2. Places are defined two ways: ``area`` (the tour's areas), and ``position``
   (greedy place centres ``spacing`` apart, in map units, per building and
   floor, in file order; each photo goes to its nearest centre; photos
   without a position are left out).
3. Leave-one-out over the photos whose place has two or more: the query's
   photo is removed, every other photo is a reference. Scores per place for
   each method; top-1 and mean rank (ties counted against) of the true place.

Methods: the single terms ``VE``, ``CP`` (angle-space mixtures, heading as
recorded), ``Fp`` (cyclic alignment, feature-aware costs, ``exp`` likelihood),
``A`` (:class:`~fingerloc.terms.appearance.AppearanceTerm`), sums of their
log-likelihoods, and an independent baseline: rotation-invariant hue,
saturation and value histograms compared by the Jeffrey divergence (after
Ulrich and Nourbakhsh, "Appearance-based place recognition for topological
localization", ICRA 2000), nearest reference photo.
"""

from __future__ import annotations

import json
import math
import re
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

__all__ = [
    "HEADING_ESTIMATORS",
    "PANORAMA_METHODS",
    "CampusPhoto",
    "PhotoFeatures",
    "TourLink",
    "band_signature",
    "extract_features",
    "feature_heading_deg",
    "fingerprint_heading_deg",
    "heading_link_errors",
    "hsv_histogram",
    "image_rotation_deg",
    "jeffrey_divergence",
    "keypoint_distances",
    "load_edge_labels",
    "load_photo_band",
    "load_tour_layout",
    "load_tour_links",
    "places_by_area",
    "places_by_position",
    "profile_distances",
    "run_edge_bench",
    "run_panorama_bench",
    "signature_rotation_deg",
]


#: Default band of elevations (parts of the image height, top = 0) and width.
DEFAULT_BAND = (0.25, 0.75)
DEFAULT_WIDTH = 1440


@dataclass(frozen=True, slots=True)
class CampusPhoto:
    """One photo of the tour.

    Attributes
    ----------
    photo_id : str
    file : str
        Path relative to the photo folder (``/``-separated).
    area : str
        Area id.
    floor : str
        ``"<building>-<floor>"``.
    position : (x, y) or None
        Map position (map units), when known.
    """

    photo_id: str
    file: str
    area: str
    floor: str
    position: tuple[float, float] | None


_AREA = re.compile(r":\s*Area\s*=\s*\{")
_PHOTO = re.compile(r"\bid:\s*'([^']+)',\s*imageUrl:\s*'([^']+)'")
_FIRST_ID = re.compile(r"\bid:\s*'([^']+)'")
_BLOCK = re.compile(r"\bbuildingBlock:\s*'([^']+)'")
_FLOOR = re.compile(r"\bfloorLevel:\s*(\d+)")
_POS = re.compile(r"'([^']+)':\s*\{\s*x:\s*([0-9.]+|null),\s*y:\s*([0-9.]+|null)\s*\}")


def load_tour_layout(areas_dir: str | Path, minimap: str | Path | None = None) -> list[CampusPhoto]:
    """The tour's photos with their area, floor and map position.

    Parameters
    ----------
    areas_dir : path
        Folder searched recursively for ``*.ts`` files holding ``... : Area = {``
        objects.
    minimap : path, optional
        File of ``'photo-id': { x: .., y: .. }`` entries; default: the first
        ``minimap/minimapLocations.ts`` next to ``areas_dir`` or above it.

    Returns
    -------
    list of CampusPhoto
        In the order of the sorted file names, then of the files' text; one per
        image file (the first area listing it wins).
    """
    root = Path(areas_dir)
    if not root.is_dir():
        raise DataFormatError("not a folder of area definitions (*.ts)", path=root)
    if minimap is None:
        for cand in (root.parent / "minimap" / "minimapLocations.ts", root / "minimap" / "minimapLocations.ts"):
            if cand.is_file():
                minimap = cand
                break
    positions: dict[str, tuple[float, float]] = {}
    if minimap is not None:
        try:
            text = Path(minimap).read_text(encoding="utf-8")
        except OSError as err:
            raise DataFormatError(f"cannot read: {err.strerror or err}", path=Path(minimap)) from err
        for pid, x, y in _POS.findall(text):
            if x != "null" and y != "null":
                positions[pid] = (float(x), float(y))
    out: list[CampusPhoto] = []
    seen: set[str] = set()
    for ts in sorted(root.rglob("*.ts")):
        text = ts.read_text(encoding="utf-8")
        starts = [m.end() for m in _AREA.finditer(text)]
        for k, s in enumerate(starts):
            chunk = text[s : starts[k + 1] if k + 1 < len(starts) else len(text)]
            area = _FIRST_ID.search(chunk)
            if area is None:
                continue
            block = _BLOCK.search(chunk)
            floor = _FLOOR.search(chunk)
            floor_key = f"{block.group(1) if block else '?'}-{floor.group(1) if floor else '?'}"
            for pid, url in _PHOTO.findall(chunk):
                rel = url.split("360_photos_compressed/", 1)[-1].lstrip("/")
                if rel in seen:
                    continue
                seen.add(rel)
                out.append(CampusPhoto(pid, rel, area.group(1), floor_key, positions.get(pid)))
    if not out:
        raise DataFormatError("no area with photos found in the *.ts files", path=root)
    return out


#: Bearing of each tour arrow relative to the photo's ``startingAngle`` (the tour's ``DIRECTION_ANGLES``).
_ARROW_OFFSETS: dict[str, float] = {
    "forward": 0.0,
    "forwardRight": 45.0,
    "right": 90.0,
    "backRight": 135.0,
    "back": 180.0,
    "backLeft": 225.0,
    "left": 270.0,
    "forwardLeft": 315.0,
}
#: The tour's explicit arrow angles for horizontal moves (its ``ARROW_OVERRIDES``).
_ARROW_OVERRIDES: dict[tuple[str, str], float] = {
    ("w-f1-main-entrance", "forwardLeft"): 155.0,
    ("w-gym-entry", "forward"): 220.0,
}
_START = re.compile(r"\bstartingAngle:\s*(-?[0-9.]+)")
_ARROW = re.compile(
    r"\b(forward|forwardRight|right|backRight|back|backLeft|left|forwardLeft):\s*\{\s*connection:\s*'([^']+)'\s*\}"
)


@dataclass(frozen=True, slots=True)
class TourLink:
    """Two photos the tour links both ways, with the heading between them from the tour's arrows.

    Attributes
    ----------
    a, b : str
        Photo files (relative, as :attr:`CampusPhoto.file`).
    heading_deg : float
        A feature at bearing ``x`` in ``a`` is at bearing ``x + heading_deg``
        in ``b`` (bearings counter-clockwise, the image's columns clockwise).
    same_area : bool
    """

    a: str
    b: str
    heading_deg: float
    same_area: bool


def load_tour_links(areas_dir: str | Path) -> list[TourLink]:
    """Ground-truth headings between linked photos, from the tour's navigation arrows.

    The tour shows, in photo ``a``, an arrow towards each linked photo at the
    viewer angle ``startingAngle + offset(direction)`` (or an explicit
    override); when ``b`` links back to ``a``, the line from ``a`` to ``b``
    is seen at viewer angle ``alpha`` in ``a`` and the opposite direction at
    ``beta`` in ``b``, so the two photos' frames differ by
    ``beta - 180 - alpha`` viewer degrees. The viewer angle grows with the
    image column (checked on the photos: the other sign doubles the median
    disagreement with an image-to-image correlation), i.e. clockwise, so the
    heading in bearings is ``alpha - beta + 180``. The arrows were placed by
    hand, at 45 deg steps from one angle per photo: a few degrees of error
    and sometimes more where a corridor bends.
    """
    root = Path(areas_dir)
    if not root.is_dir():
        raise DataFormatError("not a folder of area definitions (*.ts)", path=root)
    photos: dict[str, tuple[str, str, dict[str, float]]] = {}
    for ts in sorted(root.rglob("*.ts")):
        text = ts.read_text(encoding="utf-8")
        starts = [m.end() for m in _AREA.finditer(text)]
        for k, s0 in enumerate(starts):
            chunk = text[s0 : starts[k + 1] if k + 1 < len(starts) else len(text)]
            area = _FIRST_ID.search(chunk)
            if area is None:
                continue
            found = list(_PHOTO.finditer(chunk))
            for j, m in enumerate(found):
                body = chunk[m.end() : found[j + 1].start() if j + 1 < len(found) else len(chunk)]
                st = _START.search(body)
                start = float(st.group(1)) if st else 0.0
                arrows = {
                    target: _ARROW_OVERRIDES.get((m.group(1), d), (start + _ARROW_OFFSETS[d]) % 360.0)
                    for d, target in _ARROW.findall(body)
                }
                rel = m.group(2).split("360_photos_compressed/", 1)[-1].lstrip("/")
                photos.setdefault(m.group(1), (rel, area.group(1), arrows))
    links: list[TourLink] = []
    for pid, (file_a, area_a, arrows) in photos.items():
        for target, alpha in arrows.items():
            other = photos.get(target)
            if other is None or target <= pid or pid not in other[2]:
                continue
            beta = other[2][pid]
            links.append(TourLink(file_a, other[0], float((alpha - beta + 180.0) % 360.0), area_a == other[1]))
    return links


def places_by_area(photos: Sequence[CampusPhoto]) -> list[str | None]:
    """Place label of each photo: its area id."""
    return [p.area for p in photos]


def places_by_position(photos: Sequence[CampusPhoto], *, spacing: float = 0.03) -> list[str | None]:
    """Place label of each photo from its map position (None without one).

    Per floor, in order, a photo farther than ``spacing`` (map units) from
    every existing centre becomes a new centre; each photo then takes its
    nearest centre (as the laser benchmark's places, :mod:`.carmen`).
    """
    if not (math.isfinite(spacing) and spacing > 0):
        raise InvalidParameterError(f"spacing must be a positive number of map units, got {spacing!r}")
    centres: dict[str, list[tuple[float, float]]] = {}
    for p in photos:
        if p.position is None:
            continue
        cs = centres.setdefault(p.floor, [])
        if not cs or min(math.dist(c, p.position) for c in cs) > spacing:
            cs.append(p.position)
    out: list[str | None] = []
    for p in photos:
        if p.position is None:
            out.append(None)
            continue
        cs = centres[p.floor]
        k = int(np.argmin([math.dist(c, p.position) for c in cs]))
        out.append(f"{p.floor}#{k}")
    return out


# ---------------------------------------------------------------------------
# reading photos and extracting observations


def load_photo_band(path: str | Path, *, band: tuple[float, float] = DEFAULT_BAND, width: int = DEFAULT_WIDTH) -> Any:
    """The band of elevations of an equirectangular photo, resampled to ``width`` columns (a Panorama).

    Column 0's left edge is at bearing 0; bearings decrease to the right (the
    defaults of ``fingerloc features``).
    """
    from PIL import Image, UnidentifiedImageError

    from ..sensors import Panorama

    p = Path(path)
    try:
        with Image.open(p) as im:
            rgb = im.convert("RGB")
    except FileNotFoundError as err:
        raise DataFormatError("no such file", path=p) from err
    except (UnidentifiedImageError, OSError, ValueError) as err:
        raise DataFormatError(f"cannot read image: {err}", path=p) from err
    w, h = rgb.size
    top, bottom = round(band[0] * h), round(band[1] * h)
    crop = rgb.crop((0, top, w, bottom))
    new_h = max(2, round((bottom - top) * width / w))
    small = crop.resize((width, new_h), Image.Resampling.BOX)
    meta = {"source": str(p), "elevation_deg": (90.0 - 180.0 * top / h, 90.0 - 180.0 * bottom / h)}
    return Panorama(np.asarray(small, dtype=np.uint8), meta=meta)


def _extract(pano: Any, source: str) -> Observation:
    from dataclasses import replace

    from ..features.keypoints import extract_keypoints
    from ..features.vision import observation_from_views

    obs = observation_from_views(panorama=pano, appearance=True, profile=True, source=source, **PHOTO_EDGE_PARAMS)
    return replace(obs, keypoints=extract_keypoints(pano))


@dataclass(frozen=True, slots=True)
class PhotoFeatures:
    """What the benchmark keeps of one photo.

    Attributes
    ----------
    observation : Observation
        VE, CP, the appearance descriptor, ``source`` = the relative file.
    hsv_hist : ndarray, shape (96,)
        The baseline's histograms (:func:`hsv_histogram`).
    signature : ndarray, shape (360, 12)
        :func:`band_signature`, for the image-to-image rotation.
    """

    observation: Observation
    hsv_hist: FArray
    signature: FArray


def _features_to_record(f: PhotoFeatures) -> dict[str, Any]:
    from ..io.jsonl import observation_to_record

    rec = observation_to_record(f.observation, ndigits=6)
    rec["hsv_hist"] = [round(float(x), 8) for x in f.hsv_hist]
    rec["signature"] = np.round(f.signature, 3).tolist()
    return rec


def _features_from_record(rec: dict[str, Any]) -> PhotoFeatures:
    from ..io.jsonl import observation_from_record

    return PhotoFeatures(
        observation_from_record(rec),
        np.asarray(rec["hsv_hist"], dtype=np.float64),
        np.asarray(rec["signature"], dtype=np.float64),
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
    key = {"band": list(band), "width": width, "edges": PHOTO_EDGE_PARAMS, "version": 5}
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
            known[ph.file] = PhotoFeatures(_extract(pano, ph.file), hsv_histogram(pano.image), band_signature(pano))
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
# leave-one-out


#: Methods reported by :func:`run_panorama_bench`: single terms, sums of terms, the baseline.
PANORAMA_METHODS: tuple[str, ...] = (
    "VE",
    "CP",
    "Fp",
    "A",
    "VE+CP+Fp",
    "Fp+A",
    "VE+CP+Fp+A",
    "VE+CP+Fp+A weighted",
    "hsv-baseline",
    "AP",
    "A+AP",
    "Fp+A+AP",
    "A+AP weighted",
    "Fp+A+AP weighted",
    "K",
    "A+K",
    "A+K weighted",
    "Fp+A+AP+K weighted",
)

#: Terms whose weights :func:`_loo_weighted_sum` fits.
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


def keypoint_distances(obs: Sequence[Observation]) -> FArray:
    """The ``K`` term's distance from every observation (row) to every other (column), shape ``(n, n)``.

    :func:`fingerloc.terms.keypoints.match_counts` of each view against all
    (query -> reference, as the term matches), turned into
    :func:`fingerloc.terms.keypoints.keypoint_distance`; inf where a view has
    no keypoints.
    """
    from ..features.keypoints import Keypoints
    from ..terms.keypoints import _Refs, keypoint_distance, match_counts

    empty = Keypoints(np.empty(0), np.empty(0), np.empty(0), np.zeros((0, 1), dtype=np.uint8))
    kps = [o.keypoints if o.keypoints is not None else empty for o in obs]
    refs = _Refs(kps)
    return np.stack([keypoint_distance(match_counts(k, refs), len(k), refs.sizes) for k in kps])


def _loo_scores(
    obs: list[Observation], labels: list[str], hists: list[FArray], queries: Sequence[int], n_components: int
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
    out["K"] = _loo_distance_ll(keypoint_distances(obs), owner, n_places, queries)
    for combo in PANORAMA_METHODS:
        if "+" in combo and " " not in combo:
            out[combo] = np.sum([out[t] for t in combo.split("+")], axis=0)
    out["VE+CP+Fp+A weighted"] = _loo_weighted_sum([out[t] for t in WEIGHTED_TERMS], owner[list(queries)])
    out["A+AP weighted"] = _loo_weighted_sum([out["A"], out["AP"]], owner[list(queries)])
    out["Fp+A+AP weighted"] = _loo_weighted_sum([out[t] for t in ("Fp", "A", "AP")], owner[list(queries)])
    out["A+K weighted"] = _loo_weighted_sum([out["A"], out["K"]], owner[list(queries)])
    out["Fp+A+AP+K weighted"] = _loo_weighted_sum([out[t] for t in ("Fp", "A", "AP", "K")], owner[list(queries)])
    h = np.stack(hists)
    dj = jeffrey_divergence(h, h)
    np.fill_diagonal(dj, np.inf)
    out["hsv-baseline"] = -min_per_place(dj[list(queries)], owner, n_places)
    return out, owner[list(queries)]


def run_panorama_bench(
    photo_dir: str | Path,
    areas_dir: str | Path,
    *,
    minimap: str | Path | None = None,
    cache: str | Path | None = None,
    spacing: float = 0.03,
    n_components: int = 3,
    width: int = DEFAULT_WIDTH,
    max_queries: int | None = None,
    on_step: Callable[[str, int, int], None] | None = None,
) -> dict[str, Any]:
    """Leave-one-out top-1 and mean rank per method, places by area and by position (module docstring).

    Returns
    -------
    dict
        ``{"photos": n, "features": {...}, "places": {"area": {...}, "position": {...}}}``;
        per definition: ``n_places``, ``n_queries``, and per method ``top1``, ``mean_rank``.
    """
    photos = load_tour_layout(areas_dir, minimap)
    feats = extract_features(
        photo_dir,
        photos,
        cache=cache,
        width=width,
        on_step=None if on_step is None else lambda i, n: on_step("extract", i, n),
    )
    have = [i for i, f in enumerate(feats) if f is not None]
    obs = [None if f is None else f.observation for f in feats]
    hists = [None if f is None else f.hsv_hist for f in feats]
    if len(have) < 3:
        raise DataFormatError(f"only {len(have)} of the tour's photos were found", path=Path(photo_dir))
    res: dict[str, Any] = {
        "photos": len(have),
        "photos_listed": len(photos),
        "features": {
            "VE_per_photo": float(np.mean([obs[i].ve.size for i in have])),  # type: ignore[union-attr]
            "CP_per_photo": float(np.mean([obs[i].cp.size for i in have])),  # type: ignore[union-attr]
        },
        "places": {},
    }
    res["heading"] = heading_errors(photos, feats)
    res["heading_links"] = heading_link_errors(load_tour_links(areas_dir), photos, feats)
    for name, labels_all in (
        ("area", places_by_area(photos)),
        ("position", places_by_position(photos, spacing=spacing)),
    ):
        idx = [i for i in have if labels_all[i] is not None]
        sub_obs = [obs[i] for i in idx]
        sub_lab = [str(labels_all[i]) for i in idx]
        sub_h = [hists[i] for i in idx]
        counts: dict[str, int] = {}
        for lab in sub_lab:
            counts[lab] = counts.get(lab, 0) + 1
        queries = [k for k, lab in enumerate(sub_lab) if counts[lab] >= 2]
        if max_queries is not None and len(queries) > max_queries:
            queries = sorted(np.random.default_rng(0).choice(queries, max_queries, replace=False).tolist())
        if on_step is not None:
            on_step(name, 0, len(queries))
        scores, truth = _loo_scores(sub_obs, sub_lab, sub_h, queries, n_components)  # type: ignore[arg-type]
        ranks = {m: true_place_ranks(scores[m], truth).tolist() for m in PANORAMA_METHODS}
        res["places"][name] = {
            "n_places": len(counts),
            "n_queries": len(queries),
            "methods": {
                m: {
                    "top1": float(np.mean(np.asarray(r) == 1)) if r else None,
                    "mean_rank": float(np.mean(r)) if r else None,
                }
                for m, r in ranks.items()
            },
        }
    return res


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


#: Heading estimators of :func:`heading_link_errors`.
HEADING_ESTIMATORS: tuple[str, ...] = ("profile", "Fp", "features", "signature")


def heading_link_errors(
    links: Sequence[TourLink], photos: Sequence[CampusPhoto], feats: Sequence[PhotoFeatures | None]
) -> dict[str, Any]:
    """Heading estimators against the tour's arrows (:func:`load_tour_links`), on the photos linked both ways.

    Estimators: ``profile`` (:func:`fingerloc.features.vision.profile_rotation_deg`
    on the observations' column profiles, what ``localize`` reports with the
    ``AP`` term), ``Fp`` (the fingerprint's cyclic alignment), ``features``
    (:func:`feature_heading_deg`) and ``signature`` (the former oracle,
    :func:`signature_rotation_deg`). Per estimator, over all linked pairs and
    over the pairs of one area: the number of pairs, the median absolute
    error (degrees) and the share within 30 deg; ``pairs`` lists every pair.
    """
    from ..features.vision import profile_rotation_deg

    by_file = {p.file: f for p, f in zip(photos, feats, strict=True)}
    errs: dict[str, list[float]] = {k: [] for k in HEADING_ESTIMATORS}
    same: list[bool] = []
    rows: list[dict[str, Any]] = []

    def err(h: float | None, truth: float) -> float:
        return 180.0 if h is None else abs((h - truth + 180.0) % 360.0 - 180.0)

    for ln in links:
        fa, fb = by_file.get(ln.a), by_file.get(ln.b)
        if fa is None or fb is None:
            continue
        oa, ob = fa.observation, fb.observation
        est: dict[str, float | None] = {
            "profile": None
            if oa.profile is None or ob.profile is None
            else profile_rotation_deg(oa.profile, ob.profile)[0],
            "Fp": fingerprint_heading_deg(oa, ob),
            "features": feature_heading_deg(oa, ob),
            "signature": signature_rotation_deg(fa.signature, fb.signature)[0],
        }
        for k, h in est.items():
            errs[k].append(err(h, ln.heading_deg))
        same.append(ln.same_area)
        rows.append({"a": ln.a, "b": ln.b, "truth_deg": ln.heading_deg, "same_area": ln.same_area, **est})
    sel_same = np.asarray(same, dtype=bool)
    out: dict[str, Any] = {}
    for k, e in errs.items():
        arr = np.asarray(e)
        for name, sel in (("all links", np.ones(arr.size, dtype=bool)), ("same area", sel_same)):
            out[f"{k}, {name}"] = {
                "pairs": int(sel.sum()),
                "median_error_deg": float(np.median(arr[sel])) if sel.any() else None,
                "within_30": float(np.mean(arr[sel] <= 30.0)) if sel.any() else None,
            }
    out["pairs"] = rows
    return out
