"""Local features of a panorama: OpenCV SIFT keypoints with RootSIFT descriptors (term ``K``).

Two panoramas taken at different spots of one room share many distinctive
local patches (picture frames, furniture corners, window mullions, door
handles) that a global histogram blurs. This module finds such patches with
OpenCV's SIFT detector and descriptor (``opencv-python-headless``), keeps
where each one is on the sphere, and matches two views' patches;
:mod:`fingerloc.features.sphere` then checks that the matches agree with one
relative pose of the two cameras, and :mod:`fingerloc.terms.keypoints`
scores places by those verified matches.

Extraction (:func:`extract_keypoints`):

1. **Grey band at a fixed resolution.** The panorama's band of elevations
   (what ``fingerloc features`` reads: -45..+45 deg of a full 2:1 photo) is
   turned grey and resampled (area averaging) to ``width`` columns (default
   1024), so that a 2048 or a 5760 px wide photo gives keypoints at the same
   angular scales; its 1st..99th percentiles are stretched to the full range
   (SIFT's contrast threshold is absolute: a dark exposure would lose most
   keypoints). SIFT doubles the image internally before its first
   octave, so the finest scale is that of a 2048 px photo.
2. **SIFT** on the band directly (near the horizon an equirectangular image
   is hardly distorted: at +-45 deg a patch is stretched sideways by 1.41),
   the ``n_keypoints`` strongest kept; the 360 deg seam is handled by
   padding the band with ``pad`` columns from its other end and dropping
   the keypoints detected in the padding.
3. **Positions on the sphere**: bearing from the column (the panorama's
   convention: counter-clockwise from the robot's bearing 0, whatever the
   column order) and elevation (radians, positive up) from the row and the
   band's elevation range (``Panorama.meta["elevation_deg"]``, else a band
   of square pixels centred on the horizon).
4. Descriptors: SIFT's 128 numbers as ``uint8``;
   :meth:`Keypoints.unit_descriptors` gives their RootSIFT form (square
   roots of the L1-normalised vector: unit L2 norm, the Hellinger kernel as
   a dot product).

The stored form (:func:`encode_keypoints`) is versioned (:data:`KEYPOINT_VERSION`):
keypoints of the former hand-written detector (no version) are refused with
a message that says to run ``fingerloc features`` again.
"""

from __future__ import annotations

import base64
import math
from dataclasses import dataclass, fields
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from .._types import IArray
from ..errors import DataFormatError, InvalidParameterError
from ..keypoints import Keypoints

__all__ = [
    "KEYPOINT_VERSION",
    "OLD_KEYPOINTS_MESSAGE",
    "KeypointParams",
    "Keypoints",
    "band_elevations",
    "decode_keypoints",
    "encode_keypoints",
    "extract_keypoints",
    "keypoint_arrays",
    "keypoints_from_arrays",
    "match_keypoints",
]

#: Version of the stored keypoints (positions as angles on the sphere, OpenCV SIFT descriptors).
KEYPOINT_VERSION = 2
#: What a reader says of keypoints stored by an older fingerloc.
OLD_KEYPOINTS_MESSAGE = (
    "keypoints of an older fingerloc version (the hand-written detector); "
    "run `fingerloc features` again on the photos (and `fingerloc learn` a new database)"
)
_ELEV_UNIT = 180.0 / 65535.0  # degrees per stored unit, from -90
_SCALE_UNIT = 0.01  # degrees per stored unit


@dataclass(frozen=True, slots=True)
class KeypointParams:
    """Parameters of :func:`extract_keypoints` (module docstring).

    Attributes
    ----------
    width : int, default 1024
        Columns the band is resampled to before detection.
    n_keypoints : int, default 1000
        Keep at most this many keypoints (the strongest).
    contrast : float, default 0.04
        SIFT's contrast threshold (``contrastThreshold``).
    edge : float, default 10
        SIFT's edge threshold (``edgeThreshold``).
    pad : int, default 32
        Columns of the band's other end added on each side before detection (the seam).
    """

    width: int = 1024
    n_keypoints: int = 1000
    contrast: float = 0.04
    edge: float = 10.0
    pad: int = 32

    def __post_init__(self) -> None:
        for name in ("width", "n_keypoints", "pad"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < (0 if name == "pad" else 1):
                raise InvalidParameterError(f"{name} must be an integer >= {0 if name == 'pad' else 1}, got {v!r}")
        if self.width < 64:
            raise InvalidParameterError(f"width must be >= 64 columns, got {self.width}")
        if self.pad > self.width // 4:
            raise InvalidParameterError(f"pad must be at most a quarter of width, got {self.pad}")
        for name in ("contrast", "edge"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating)) or not (math.isfinite(v) and v > 0):
                raise InvalidParameterError(f"{name} must be a positive number, got {v!r}")


def _params(params: dict[str, Any]) -> KeypointParams:
    known = {f.name for f in fields(KeypointParams)}
    for k in params:
        if k not in known:
            raise InvalidParameterError(f"unknown keypoint parameter {k!r} (known: {', '.join(sorted(known))})")
    return KeypointParams(**params)


def band_elevations(pano: Any) -> tuple[float, float]:
    """Elevations (radians) of the top and bottom edges of a panorama's band.

    ``pano.meta["elevation_deg"]`` = ``(top, bottom)`` in degrees when the
    reader knew them (``fingerloc features`` on a 2:1 photo); otherwise the
    band is taken as square pixels (``360 / w`` degrees a row) centred on the horizon.
    """
    meta = getattr(pano, "meta", None) or {}
    got = meta.get("elevation_deg")
    if got is not None:
        try:
            top, bottom = (float(v) for v in got)
        except (TypeError, ValueError) as err:
            raise InvalidParameterError(
                f"panorama meta elevation_deg must be (top, bottom) degrees, got {got!r}"
            ) from err
        if not (-90.0 <= bottom < top <= 90.0):
            raise InvalidParameterError(
                f"panorama meta elevation_deg must satisfy -90 <= bottom < top <= 90, got {got!r}"
            )
        return math.radians(top), math.radians(bottom)
    h, w = np.asarray(pano.image).shape[:2]
    half = min(math.pi / 2, math.pi * h / w)
    return half, -half


def _grey(image: Any, width: int) -> NDArray[np.uint8]:
    """The band as uint8 grey at ``width`` columns (area averaging when shrinking, bilinear when enlarging)."""
    import cv2

    img = np.asarray(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (3, 4)):
        raise DataFormatError(f"expected an RGB or grey image, got an array of shape {img.shape}")
    if img.dtype != np.uint8:
        f = np.asarray(img, dtype=np.float32)
        if not np.all(np.isfinite(f)):
            raise DataFormatError("the image holds non-finite values")
        if f.size and f.max() <= 1.0:
            f = f * 255.0
        img = np.clip(np.rint(f), 0, 255).astype(np.uint8)
    grey = img if img.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(img[:, :, :3]), cv2.COLOR_RGB2GRAY)
    h, w = grey.shape
    if w < 16 or h < 4:
        raise DataFormatError(f"panorama band too small for keypoints: {w}x{h} pixels")
    new_h = max(8, round(h * width / w))
    if (new_h, width) != (h, w):
        interp = cv2.INTER_AREA if w > width else cv2.INTER_LINEAR
        grey = cv2.resize(grey, (width, new_h), interpolation=interp)
    # exposure: stretch the 1st..99th percentiles to the full range (SIFT's contrast threshold is absolute)
    lo, hi = np.percentile(grey, [1.0, 99.0])
    if hi - lo >= 1.0:
        lut = np.clip(np.rint((np.arange(256) - lo) * 255.0 / (hi - lo)), 0, 255).astype(np.uint8)
        grey = lut[grey]
    return np.ascontiguousarray(grey)


def extract_keypoints(pano: Any, **params: Any) -> Keypoints:
    """SIFT keypoints of a panorama band with their positions on the sphere (module docstring).

    Parameters
    ----------
    pano : Panorama
        The band (``fingerloc.sensors.Panorama``): its columns give the
        bearings through ``column_bearing``, :func:`band_elevations` the elevations.
    **params
        Fields of :class:`KeypointParams`.
    """
    import cv2

    p = _params(params)
    g = _grey(pano.image, p.width)
    h, w = g.shape
    pad = min(p.pad, w // 4)
    padded = np.concatenate([g[:, w - pad :], g, g[:, :pad]], axis=1) if pad else g
    # every candidate described in one pass (one image pyramid instead of two); those in the padding
    # are dropped, then the strongest kept
    sift = cv2.SIFT_create(contrastThreshold=float(p.contrast), edgeThreshold=float(p.edge))  # type: ignore[attr-defined]
    found, all_desc = sift.detectAndCompute(padded, None)
    x = np.array([k.pt[0] for k in found]) - pad
    resp = np.array([k.response for k in found])
    keep = np.flatnonzero((x >= -0.5) & (x < w - 0.5))
    keep = keep[np.argsort(-resp[keep], kind="stable")[: p.n_keypoints]]
    dim = 128
    kps, desc = ([found[i] for i in keep], all_desc[keep]) if keep.size and all_desc is not None else ((), None)
    if not kps or desc is None:
        return Keypoints(np.empty(0), np.empty(0), np.empty(0), np.zeros((0, dim), dtype=np.uint8))
    x = np.array([k.pt[0] for k in kps]) - pad
    y = np.array([k.pt[1] for k in kps])
    size = np.array([k.size for k in kps])
    idx = np.arange(len(kps))
    top, bottom = band_elevations(pano)
    w0 = np.asarray(pano.image).shape[1]
    cols = (x[idx] + 0.5) * w0 / w  # fractional columns of the panorama (j + 0.5: column j's centre)
    elev = top - (top - bottom) * (y[idx] + 0.5) / h
    d = np.clip(np.rint(desc[idx]), 0, 255).astype(np.uint8)
    order = np.lexsort((elev, cols))
    kp = Keypoints(
        bearing=np.asarray(pano.column_bearing(cols[order])),
        elevation=np.clip(elev[order], -math.pi / 2, math.pi / 2),
        scale=size[idx][order] * 360.0 / w,
        desc=d[order],
    )
    # positions on the grid of the stored encoding, so that writing and reading back changes nothing
    return decode_keypoints(encode_keypoints(kp))


# ---------------------------------------------------------------------------
# matching


@numba.njit(cache=True, nogil=True)
def _mutual_ratio(s: Any, r2: float) -> Any:  # pragma: no cover - compiled
    """One pass over the similarity matrix: best and second-best per row and column, then the mutual ratio test."""
    na, nb = s.shape
    b1 = np.full(na, -4.0, np.float32)
    b2 = np.full(na, -4.0, np.float32)
    bj = np.full(na, -1, np.int64)
    c1 = np.full(nb, -4.0, np.float32)
    c2 = np.full(nb, -4.0, np.float32)
    ci = np.full(nb, -1, np.int64)
    for i in range(na):
        top1 = np.float32(-4.0)
        top2 = np.float32(-4.0)
        top_j = -1
        for j in range(nb):
            v = s[i, j]
            if v > top1:
                top2 = top1
                top1 = v
                top_j = j
            elif v > top2:
                top2 = v
            if v > c2[j]:  # c1 >= c2: the rare case first
                if v > c1[j]:
                    c2[j] = c1[j]
                    c1[j] = v
                    ci[j] = i
                else:
                    c2[j] = v
        b1[i] = top1
        b2[i] = top2
        bj[i] = top_j
    out = np.empty((na, 2), np.int64)
    m = 0
    for i in range(na):
        j = bj[i]
        if j < 0 or ci[j] != i:
            continue
        d1 = max(np.float32(2.0) - np.float32(2.0) * b1[i], np.float32(0.0))
        da = max(np.float32(2.0) - np.float32(2.0) * b2[i], np.float32(0.0))
        db = max(np.float32(2.0) - np.float32(2.0) * c2[j], np.float32(0.0))
        if d1 < r2 * da and d1 < r2 * db:
            out[m, 0] = i
            out[m, 1] = j
            m += 1
    return out[:m]


def match_descriptors(ua: NDArray[np.float32], ub: NDArray[np.float32], *, ratio: float = 0.8) -> IArray:
    """Mutual nearest neighbours of two sets of unit descriptors passing the ratio test from both sides, ``(m, 2)``.

    A pair ``(i, j)`` is kept when ``j`` is ``i``'s nearest in ``ub``, ``i``
    is ``j``'s nearest in ``ua``, and the distance is below ``ratio`` times
    ``i``'s second-nearest distance in ``ub`` and ``j``'s second-nearest in
    ``ua`` (a side with a single descriptor passes). Brute force: one
    float32 matrix product (BLAS), then one compiled pass over it for the
    two nearest of every row and column; rows in increasing ``i``.
    """
    if len(ua) == 0 or len(ub) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    a = np.ascontiguousarray(ua, dtype=np.float32)
    b = np.ascontiguousarray(ub, dtype=np.float32)
    s = a @ b.T  # cosine similarities; distance^2 = 2 - 2 s
    out: IArray = _mutual_ratio(s, np.float32(ratio * ratio))  # type: ignore[arg-type]
    return out


def match_keypoints(a: Keypoints, b: Keypoints, *, ratio: float = 0.8) -> IArray:
    """Matches between two views' keypoints, shape ``(m, 2)``: index pairs ``(i in a, j in b)``.

    :func:`match_descriptors` on the RootSIFT descriptors: mutual nearest
    neighbours passing the ratio test from both sides. Positions are not
    looked at: :func:`fingerloc.features.sphere.ransac_pose` checks them.
    """
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if a.dim != b.dim:
        raise InvalidParameterError(f"keypoints: descriptors of length {a.dim} and {b.dim} cannot be matched")
    return match_descriptors(a.unit_descriptors(), b.unit_descriptors(), ratio=ratio)


# ---------------------------------------------------------------------------
# compact encoding (JSON Lines, the place database)


def keypoint_arrays(k: Keypoints) -> tuple[NDArray[np.uint16], NDArray[np.uint8]]:
    """The stored arrays of :func:`encode_keypoints`: positions ``(n, 3)`` little-endian uint16, descriptors ``(n, dim)``."""
    bdeg = np.mod(np.rad2deg(k.bearing), 360.0)
    pos = np.stack(
        [
            np.round(bdeg * 65536.0 / 360.0).astype(np.int64) % 65536,
            np.clip(np.round((np.rad2deg(k.elevation) + 90.0) / _ELEV_UNIT), 0, 65535).astype(np.int64),
            np.clip(np.round(k.scale / _SCALE_UNIT), 0, 65535).astype(np.int64),
        ],
        axis=1,
    ).astype("<u2")
    return pos, np.ascontiguousarray(k.desc, dtype=np.uint8)


def keypoints_from_arrays(pos: Any, desc: Any, n: int, dim: int) -> Keypoints:
    """The inverse of :func:`keypoint_arrays` (flat buffers of ``3 n`` uint16 and ``n dim`` uint8)."""
    pos = np.asarray(pos, dtype="<u2").reshape(-1)
    desc = np.asarray(desc, dtype=np.uint8).reshape(-1)
    if n < 0 or dim < 0 or pos.size != 3 * n or desc.size != n * dim:
        raise DataFormatError(f"keypoints: {n} keypoints of {dim} numbers do not fit the stored arrays")
    p = pos.reshape(n, 3).astype(np.float64)
    bdeg = p[:, 0] * 360.0 / 65536.0
    return Keypoints(
        bearing=np.deg2rad(np.where(bdeg >= 180.0, bdeg - 360.0, bdeg)),
        elevation=np.clip(np.deg2rad(p[:, 1] * _ELEV_UNIT - 90.0), -math.pi / 2, math.pi / 2),
        scale=p[:, 2] * _SCALE_UNIT,
        desc=desc.reshape(n, dim),
    )


def encode_keypoints(k: Keypoints) -> dict[str, Any]:
    """A JSON-ready dict: ``{"version", "n", "dim", "pos", "desc"}`` (docs/FORMATS.md).

    ``version``: :data:`KEYPOINT_VERSION`. ``pos``: base64 of little-endian
    uint16 triples per keypoint: bearing in units of 360/65536 deg
    (``[0, 360)``), elevation in units of 180/65535 deg from -90 deg, the
    keypoint's diameter in hundredths of a degree; ``desc``: base64 of the
    ``n x dim`` uint8 descriptors, row by row.
    """
    pos, desc = keypoint_arrays(k)
    return {
        "version": KEYPOINT_VERSION,
        "n": len(k),
        "dim": k.dim,
        "pos": base64.b64encode(pos.tobytes()).decode("ascii"),
        "desc": base64.b64encode(desc.tobytes()).decode("ascii"),
    }


def decode_keypoints(rec: Any) -> Keypoints:
    """The inverse of :func:`encode_keypoints` (positions rounded as stored).

    Raises
    ------
    DataFormatError
        Malformed, or stored by an older fingerloc (:data:`OLD_KEYPOINTS_MESSAGE`).
    """
    try:
        version = rec.get("version")
    except AttributeError as err:
        raise DataFormatError('keypoints: expected {"version", "n", "dim", "pos", "desc"}') from err
    if version is None:
        raise DataFormatError(OLD_KEYPOINTS_MESSAGE)
    if version != KEYPOINT_VERSION:
        raise DataFormatError(f"keypoints of version {version!r}: this fingerloc reads version {KEYPOINT_VERSION}")
    try:
        n, dim = int(rec["n"]), int(rec["dim"])
        pos = np.frombuffer(base64.b64decode(rec["pos"], validate=True), dtype="<u2")
        desc = np.frombuffer(base64.b64decode(rec["desc"], validate=True), dtype=np.uint8)
    except (KeyError, TypeError, ValueError) as err:
        raise DataFormatError(
            f'keypoints: expected {{"version", "n", "dim", "pos", "desc"}} with base64 arrays ({err})'
        ) from err
    return keypoints_from_arrays(pos, desc, n, dim)
