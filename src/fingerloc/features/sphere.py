"""Two-view geometry of spherical (360 deg) cameras on unit bearing vectors.

A panorama sees every direction: a keypoint at bearing ``b`` (radians,
counter-clockwise, the panorama's convention) and elevation ``e`` (radians,
positive up) is the unit vector ``f = (cos e cos b, cos e sin b, sin e)``
(x forward, y left, z up). Two views ``1`` and ``2`` of one scene are related
by a rotation ``R`` and a translation ``t``: a point at ``X1`` in view 1's
frame is at ``X2 = R X1 + t`` in view 2's. Matched bearings obey the epipolar
constraint ``f2^T E f1 = 0`` with the essential matrix ``E = [t]_x R``.

Two models of the relative pose, each fit by RANSAC (:func:`ransac_pose`):

``"general"``
    Any rotation and translation (5 degrees of freedom). Minimal sample: 8
    matches, the linear eight-point solution on bearings (unit vectors need
    no normalisation), projected on the essential manifold (singular values
    1, 1, 0). For panoramas that are not levelled.
``"upright"``
    Both cameras level (their z axes vertical), the motion horizontal: ``R``
    turns about z by the heading ``theta``, ``t = (cos a, sin a, 0)``. Then
    ``E = [[0, 0, ty], [0, 0, -tx], [c, d, 0]]`` with ``(c, d)`` the vector
    ``(ty, -tx)`` turned by ``pi - theta``: four unknowns up to scale, so
    three matches give the linear minimal solution; the estimate is then put
    on the model's manifold (``|(c, d)| = |(ty, -tx)|``).

A match's error is the angle between each bearing and the epipolar plane the
other bearing defines, the larger of the two (radians). Among the hypotheses,
the one with the most matches within ``threshold`` wins; it is then refit on
its inliers (least squares of the same linear system, twice), and the
rotation and translation come from the essential matrix's decomposition,
choosing among the four candidates the one that puts the inliers in front of
both cameras.

Headings: a far point at bearing ``x`` in view 1 is at bearing
``x + heading`` in view 2, ``heading = atan2(R[1, 0], R[0, 0])``; the tilt of
the relative rotation is the angle between ``R``'s z column and the vertical.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any, Literal

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._types import FArray, IArray
from ..errors import InvalidParameterError

__all__ = [
    "MODELS",
    "PROBE",
    "PoseFit",
    "bearing_vectors",
    "decompose_essential",
    "eight_point",
    "epipolar_errors",
    "essential_from_pose",
    "heading_of_rotation",
    "inlier_mask",
    "ransac_pose",
    "refine_pose",
    "rotation_about_z",
    "skew",
    "tilt_of_rotation",
    "upright_three_point",
]

Model = Literal["general", "upright"]
#: The relative-pose models of :func:`ransac_pose`.
MODELS: tuple[str, ...] = ("upright", "general")
#: With more than twice this many matches, RANSAC ranks each batch's hypotheses on this many (a fixed random subset).
PROBE = 100
#: Matches in a minimal sample, per model.
SAMPLE_SIZE = {"upright": 3, "general": 8}


def bearing_vectors(bearing: ArrayLike, elevation: ArrayLike) -> FArray:
    """Unit vectors of bearings and elevations (radians), shape ``(n, 3)`` (module docstring)."""
    b = np.asarray(bearing, dtype=np.float64).reshape(-1)
    e = np.asarray(elevation, dtype=np.float64).reshape(-1)
    if b.shape != e.shape:
        raise InvalidParameterError(f"bearing_vectors: {b.size} bearings and {e.size} elevations")
    ce = np.cos(e)
    return np.stack([ce * np.cos(b), ce * np.sin(b), np.sin(e)], axis=1)


def skew(t: ArrayLike) -> FArray:
    """The cross-product matrix ``[t]_x`` (``[t]_x v = t x v``), shape ``(..., 3, 3)``."""
    v = np.asarray(t, dtype=np.float64)
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], axis=-1),
            np.stack([v[..., 2], z, -v[..., 0]], axis=-1),
            np.stack([-v[..., 1], v[..., 0], z], axis=-1),
        ],
        axis=-2,
    )


def rotation_about_z(theta: float) -> FArray:
    """The rotation by ``theta`` radians about the vertical axis, shape ``(3, 3)``."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def essential_from_pose(rotation: ArrayLike, translation: ArrayLike) -> FArray:
    """``E = [t]_x R`` with ``t`` scaled to unit length, shape ``(3, 3)``."""
    t = np.asarray(translation, dtype=np.float64)
    n = float(np.linalg.norm(t))
    if not n > 0:
        raise InvalidParameterError("essential_from_pose: the translation must not be zero")
    return skew(t / n) @ np.asarray(rotation, dtype=np.float64)


def heading_of_rotation(rotation: ArrayLike) -> float:
    """Heading (radians, wrapped to ``[-pi, pi)``) of a relative rotation: its turn about the vertical."""
    r = np.asarray(rotation, dtype=np.float64)
    h = math.atan2(float(r[1, 0]), float(r[0, 0]))
    return h - 2.0 * math.pi if h >= math.pi else h


def tilt_of_rotation(rotation: ArrayLike) -> float:
    """Angle (radians) between the rotated vertical axis ``R e_z`` and the vertical."""
    r = np.asarray(rotation, dtype=np.float64)
    return math.acos(min(1.0, max(-1.0, float(r[2, 2]))))


def epipolar_errors(essential: ArrayLike, f1: FArray, f2: FArray) -> FArray:
    """Angular epipolar error of each match (radians), shape ``(..., n)`` for ``E`` of shape ``(..., 3, 3)``.

    ``max(asin |f2 . E f1| / |E f1|, asin |f1 . E^T f2| / |E^T f2|)``: the
    angle between each bearing and the epipolar plane of the other.
    """
    e = np.asarray(essential, dtype=np.float64)
    ef1 = np.einsum("...ij,nj->...ni", e, f1)  # (..., n, 3)
    etf2 = np.einsum("...ji,nj->...ni", e, f2)
    num = np.abs(np.einsum("...ni,ni->...n", ef1, f2))
    n1 = np.linalg.norm(ef1, axis=-1)
    n2 = np.linalg.norm(etf2, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.maximum(num / n1, num / n2)
    s = np.where(np.isfinite(s), s, 1.0)
    return np.asarray(np.arcsin(np.minimum(s, 1.0)))


@numba.njit(cache=True, nogil=True)
def _inlier_kernel(e: Any, f1: Any, f2: Any, threshold: float) -> Any:  # pragma: no cover - compiled
    """:func:`epipolar_errors` ``< threshold`` for each of ``s`` essential matrices, shape ``(s, n)``, one pass."""
    s, n = e.shape[0], f1.shape[0]
    out = np.zeros((s, n), dtype=np.bool_)
    for h in range(s):
        for k in range(n):
            a0, a1, a2 = f1[k, 0], f1[k, 1], f1[k, 2]
            b0, b1, b2 = f2[k, 0], f2[k, 1], f2[k, 2]
            x0 = e[h, 0, 0] * a0 + e[h, 0, 1] * a1 + e[h, 0, 2] * a2
            x1 = e[h, 1, 0] * a0 + e[h, 1, 1] * a1 + e[h, 1, 2] * a2
            x2 = e[h, 2, 0] * a0 + e[h, 2, 1] * a1 + e[h, 2, 2] * a2
            y0 = e[h, 0, 0] * b0 + e[h, 1, 0] * b1 + e[h, 2, 0] * b2
            y1 = e[h, 0, 1] * b0 + e[h, 1, 1] * b1 + e[h, 2, 1] * b2
            y2 = e[h, 0, 2] * b0 + e[h, 1, 2] * b1 + e[h, 2, 2] * b2
            num = abs(x0 * b0 + x1 * b1 + x2 * b2)
            n1 = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
            n2 = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
            r = max(num / n1 if n1 > 0 else math.inf, num / n2 if n2 > 0 else math.inf)
            if not math.isfinite(r):
                r = 1.0
            out[h, k] = math.asin(min(r, 1.0)) < threshold
    return out


def inlier_mask(essential: ArrayLike, f1: FArray, f2: FArray, threshold: float) -> NDArray[np.bool_]:
    """``epipolar_errors(essential, f1, f2) < threshold`` (compiled, no temporary arrays), shape ``(..., n)``.

    The same formula, summed in a fixed order (a last-bit difference from the
    NumPy version can move a match lying exactly on ``threshold``).
    """
    e = np.asarray(essential, dtype=np.float64)
    flat = np.ascontiguousarray(e.reshape(-1, 3, 3))
    out = _inlier_kernel(flat, np.ascontiguousarray(f1, dtype=np.float64), np.ascontiguousarray(f2, dtype=np.float64),
                         float(threshold))  # fmt: skip
    return np.asarray(out).reshape(*e.shape[:-2], len(f1))


def _null_vectors(a: FArray) -> FArray:
    """The right singular vector of the smallest singular value of each matrix of ``a`` (..., m, k)."""
    if a.shape[-2] < a.shape[-1]:  # pad with zero rows: svd's last row of vh is then the null vector
        pad = np.zeros((*a.shape[:-2], a.shape[-1] - a.shape[-2], a.shape[-1]))
        a = np.concatenate([a, pad], axis=-2)
    _, _, vh = np.linalg.svd(a, full_matrices=False)  # m >= k rows: vh is (k, k); no (m, m) u for many matches
    return np.asarray(vh[..., -1, :])


def _to_manifold(e: FArray) -> FArray:
    """The nearest essential matrices (singular values 1, 1, 0), shape ``(..., 3, 3)``."""
    u, _, vh = np.linalg.svd(e)
    return np.asarray(u @ (np.array([1.0, 1.0, 0.0])[:, None] * vh))


def eight_point(f1: FArray, f2: FArray) -> FArray:
    """Essential matrices from 8 or more matches by linear least squares, projected on the manifold.

    ``f1``, ``f2``: bearing vectors of shape ``(..., m, 3)`` (``m >= 8``; a
    batch of samples may lead). Returns ``(..., 3, 3)``.
    """
    a = (f2[..., :, :, None] * f1[..., :, None, :]).reshape(*f1.shape[:-1], 9)  # row: f2_i f1_j
    return _to_manifold(_null_vectors(a).reshape(*f1.shape[:-2], 3, 3))


def _upright_manifold(p: FArray) -> FArray:
    """Upright essential matrices from the four numbers ``(ty, -tx, c, d)`` of each row of ``p`` (..., 4)."""
    ab = p[..., :2]
    cd = p[..., 2:]
    nab = np.linalg.norm(ab, axis=-1, keepdims=True)
    ncd = np.linalg.norm(cd, axis=-1, keepdims=True)
    ab = ab / np.maximum(nab, 1e-300)
    cd = cd / np.maximum(ncd, 1e-300)
    e = np.zeros((*p.shape[:-1], 3, 3))
    e[..., 0, 2] = ab[..., 0]
    e[..., 1, 2] = ab[..., 1]
    e[..., 2, 0] = cd[..., 0]
    e[..., 2, 1] = cd[..., 1]
    return e / math.sqrt(2.0)  # singular values 1, 1, 0 like the general model's


def upright_three_point(f1: FArray, f2: FArray) -> FArray:
    """Upright essential matrices (module docstring) from 3 or more matches, shape ``(..., 3, 3)``.

    ``f2^T E f1 = ty f2x f1z - tx f2y f1z + f2z (c f1x + d f1y)``: the linear
    system in ``(ty, -tx, c, d)``, its least-squares null vector, then the model's manifold.
    """
    a = np.stack(
        [f2[..., 0] * f1[..., 2], f2[..., 1] * f1[..., 2], f2[..., 2] * f1[..., 0], f2[..., 2] * f1[..., 1]], axis=-1
    )
    return _upright_manifold(_null_vectors(a))


_SOLVERS = {"general": eight_point, "upright": upright_three_point}


def _triangulated_depths(r: FArray, t: FArray, f1: FArray, f2: FArray) -> tuple[FArray, FArray]:
    """Depths ``l1, l2`` along the bearings with ``l2 f2 ~ l1 R f1 + t`` (least squares per match)."""
    g = f1 @ r.T  # R f1
    # minimise |l1 g + t - l2 f2|^2: normal equations of the 2 x 2 system
    gg = np.ones(len(f1))
    ff = np.ones(len(f1))
    gf = np.einsum("ni,ni->n", g, f2)
    gt = g @ t
    ft = f2 @ t
    det = gg * ff - gf * gf
    with np.errstate(divide="ignore", invalid="ignore"):
        l1 = (-gt * ff + gf * ft) / det
        l2 = (gg * ft - gf * gt) / det
    return l1, l2


def decompose_essential(
    essential: ArrayLike, f1: FArray | None = None, f2: FArray | None = None
) -> tuple[FArray, FArray]:
    """The rotation and unit translation of an essential matrix, ``(R (3, 3), t (3,))``.

    Of the four decompositions, the one with the most matches (``f1``,
    ``f2``) triangulated in front of both cameras; without matches, the
    first (``R = U W V^T``, ``t = u_3``).
    """
    u, _, vh = np.linalg.svd(np.asarray(essential, dtype=np.float64))
    if np.linalg.det(u) < 0:
        u = -u
    if np.linalg.det(vh) < 0:
        vh = -vh
    w = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    cands = [(u @ w @ vh, u[:, 2]), (u @ w @ vh, -u[:, 2]), (u @ w.T @ vh, u[:, 2]), (u @ w.T @ vh, -u[:, 2])]
    if f1 is None or f2 is None or len(f1) == 0:
        return cands[0]
    best, score = cands[0], -1.0
    for r, t in cands:
        l1, l2 = _triangulated_depths(r, t, f1, f2)
        s = float(np.sum((l1 > 0) & (l2 > 0)))
        if s > score:
            best, score = (r, t), s
    return best


@dataclass(frozen=True, slots=True)
class PoseFit:
    """The result of :func:`ransac_pose`.

    Attributes
    ----------
    model : str
        ``"upright"`` or ``"general"``.
    inliers : ndarray of bool, shape (m,)
        Matches within the threshold of the refit model.
    essential : ndarray, shape (3, 3)
    rotation : ndarray, shape (3, 3)
        ``X2 = R X1 + t``.
    translation : ndarray, shape (3,)
        Unit vector.
    """

    model: str
    inliers: np.ndarray
    essential: FArray
    rotation: FArray
    translation: FArray

    @property
    def n_inliers(self) -> int:
        """Number of inliers."""
        return int(np.count_nonzero(self.inliers))

    @property
    def heading(self) -> float:
        """:func:`heading_of_rotation` of the rotation (radians)."""
        return heading_of_rotation(self.rotation)

    @property
    def tilt(self) -> float:
        """:func:`tilt_of_rotation` of the rotation (radians)."""
        return tilt_of_rotation(self.rotation)


def _refine(solve: Any, e: FArray, f1: FArray, f2: FArray, threshold: float, k: int) -> tuple[FArray, int]:
    """Local optimisation of a hypothesis: refit on its inliers (a looser threshold first) while that gains inliers."""
    inl = inlier_mask(e, f1, f2, threshold)
    count = int(inl.sum())
    for thr in (2.0 * threshold, threshold, threshold):
        sel = inlier_mask(e, f1, f2, thr)
        if sel.sum() < k:
            break
        e2 = solve(f1[sel], f2[sel])
        inl2 = inlier_mask(e2, f1, f2, threshold)
        if inl2.sum() <= count:
            break
        e, count = e2, int(inl2.sum())
    return e, count


def _rodrigues(w: FArray) -> FArray:
    """The rotation matrix of a rotation vector ``w`` (axis times angle, radians), shape ``(3, 3)``."""
    a = float(np.linalg.norm(w))
    if a < 1e-12:
        return np.eye(3) + skew(w)
    k = skew(w / a)
    return np.eye(3) + math.sin(a) * k + (1.0 - math.cos(a)) * (k @ k)


def refine_pose(
    f1: FArray, f2: FArray, rotation: FArray, translation: FArray, *, model: Model = "general"
) -> tuple[FArray, FArray]:
    """The relative pose that minimises the angular epipolar errors of matches (all inliers), from a first guess.

    Non-linear least squares (:func:`scipy.optimize.least_squares`) of the
    sines of the angles between each bearing and the other's epipolar plane
    (both sides), over the rotation (a rotation vector applied to
    ``rotation``; for ``"upright"`` only its turn about z) and the direction
    of the translation (two angles about ``translation``; for ``"upright"``
    horizontal). The linear fit on the inliers weighs matches by the lengths
    of ``E f1`` and ``E^T f2``; this one does not.

    Parameters
    ----------
    f1, f2 : ndarray, shape (m, 3)
        Unit bearing vectors of the inlier matches.
    rotation : ndarray, shape (3, 3)
    translation : ndarray, shape (3,)
    model : {"general", "upright"}

    Returns
    -------
    rotation : ndarray, shape (3, 3)
    translation : ndarray, shape (3,)
        Unit vector.
    """
    from scipy.optimize import least_squares

    r0 = np.asarray(rotation, dtype=np.float64)
    t0 = np.asarray(translation, dtype=np.float64)
    t0 = t0 / max(float(np.linalg.norm(t0)), 1e-300)
    u = np.cross(t0, [0.0, 0.0, 1.0] if abs(t0[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(t0, u)
    upright = model == "upright"

    def pose(x: FArray) -> tuple[FArray, FArray]:
        if upright:
            r = rotation_about_z(float(x[0])) @ r0
            t = rotation_about_z(float(x[1])) @ t0
        else:
            r = _rodrigues(x[:3]) @ r0
            t = t0 + x[3] * u + x[4] * v
            t = t / np.linalg.norm(t)
        return r, t

    def cross(t: FArray, g: FArray) -> FArray:  # np.cross(t, g) for one t, spelt out (its per-call cost dominated)
        return np.stack(
            [t[1] * g[:, 2] - t[2] * g[:, 1], t[2] * g[:, 0] - t[0] * g[:, 2], t[0] * g[:, 1] - t[1] * g[:, 0]], axis=1
        )

    def residuals(x: FArray) -> FArray:
        r, t = pose(x)
        g = f1 @ r.T
        n1 = cross(t, g)  # normal of the epipolar plane of f1 in view 2
        n2 = cross(t, f2)
        num = np.einsum("ni,ni->n", f2, n1)
        return np.concatenate([num / np.maximum(np.linalg.norm(n1, axis=1), 1e-12),
                               num / np.maximum(np.linalg.norm(n2, axis=1), 1e-12)])  # fmt: skip

    x0 = np.zeros(2 if upright else 5)
    if len(f1) < len(x0):
        return r0, t0
    sol = least_squares(residuals, x0, method="lm" if 2 * len(f1) >= len(x0) else "trf")
    return pose(sol.x)


def _samples(rng: np.random.Generator, m: int, k: int, size: int) -> IArray:
    """``size`` random index sets of ``k`` distinct matches among ``m``, shape ``(size, k)``."""
    # the k smallest of m random keys, in increasing order of key: distinct indices per row (the
    # partition first: the order of a full argsort without sorting all m keys)
    keys = rng.random((size, m))
    if k >= m:
        return np.argsort(keys, axis=1)[:, :k].astype(np.int64)
    part = np.argpartition(keys, k - 1, axis=1)[:, :k]
    order = np.argsort(np.take_along_axis(keys, part, axis=1), axis=1)
    return np.take_along_axis(part, order, axis=1).astype(np.int64)


def ransac_pose(
    f1: FArray,
    f2: FArray,
    *,
    model: Model = "upright",
    threshold: float = 0.01,
    max_iter: int = 500,
    confidence: float = 0.999,
    seed: int = 0,
    refine: bool = False,
) -> PoseFit | None:
    """The relative pose of two spherical views from matched bearings, by RANSAC (module docstring).

    Parameters
    ----------
    f1, f2 : ndarray, shape (m, 3)
        Unit bearing vectors of the matches in view 1 and view 2.
    model : {"upright", "general"}
    threshold : float
        Largest epipolar error of an inlier, radians.
    max_iter : int
        Most hypotheses drawn (in batches; stops early once ``confidence``
        says a better one is unlikely). With no more distinct minimal
        samples than this, each is tried once instead. With more than
        ``2 PROBE`` matches, each batch's hypotheses are ranked on
        :data:`PROBE` of them and only the best is counted on all.
    confidence : float
        Probability of drawing at least one all-inlier sample that stops the search.
    seed : int
        Seeds the sampling (the same matches give the same answer).
    refine : bool
        Refine the rotation and translation on the inliers by
        :func:`refine_pose` (the inliers and the essential matrix stay the RANSAC's).

    Returns
    -------
    PoseFit or None
        None with fewer matches than the minimal sample.
    """
    if model not in _SOLVERS:
        raise InvalidParameterError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
    if not (threshold > 0 and math.isfinite(threshold)):
        raise InvalidParameterError(f"threshold must be a positive angle in radians, got {threshold!r}")
    f1 = np.asarray(f1, dtype=np.float64)
    f2 = np.asarray(f2, dtype=np.float64)
    if f1.shape != f2.shape or f1.ndim != 2 or f1.shape[1] != 3:
        raise InvalidParameterError(
            f"ransac_pose: f1 and f2 must both have shape (m, 3), got {f1.shape} and {f2.shape}"
        )
    k = SAMPLE_SIZE[model]
    m = len(f1)
    if m < k:
        return None
    solve = _SOLVERS[model]
    rng = np.random.default_rng(seed)
    best_count, best_e = -1, np.eye(3)
    # few matches: every minimal sample once (no more than the draws would be) instead of random draws
    every = np.array(list(itertools.combinations(range(m), k)), dtype=np.int64) if math.comb(m, k) <= max_iter else None
    if every is not None:
        max_iter = len(every)
    drawn, needed, batch = 0, max_iter, 64
    probe = np.sort(rng.choice(m, PROBE, replace=False)) if m > 2 * PROBE else None
    while drawn < min(max_iter, needed):
        size = min(batch, max_iter - drawn)
        idx = every[drawn : drawn + size] if every is not None else _samples(rng, m, k, size)
        es = solve(f1[idx], f2[idx])  # (size, 3, 3)
        drawn += size
        if probe is not None:  # many matches: hypotheses ranked on a fixed subset, the best one counted on all
            j = int(np.argmax(inlier_mask(es, f1[probe], f2[probe], threshold).sum(axis=1)))
            count_j = int(inlier_mask(es[j], f1, f2, threshold).sum())
            if count_j <= best_count:
                continue
            counts = np.zeros(size, dtype=np.int64)
            counts[j] = count_j
        else:
            counts = inlier_mask(es, f1, f2, threshold).sum(axis=1)
            j = int(np.argmax(counts))
        if counts[j] <= best_count:
            continue
        e, count = _refine(solve, es[j], f1, f2, threshold, k)
        if count <= best_count:
            continue
        best_count, best_e = count, e
        p_good = (best_count / m) ** k
        if p_good >= 1.0:
            needed = 0
        elif p_good > 0.0:
            needed = math.ceil(math.log(1.0 - confidence) / math.log1p(-p_good))
    inl = inlier_mask(best_e, f1, f2, threshold)
    r, t = decompose_essential(best_e, f1[inl], f2[inl])
    if model == "upright":  # exactly about z (the decomposition of an upright E is, up to round-off)
        r = rotation_about_z(heading_of_rotation(r))
        t = np.array([t[0], t[1], 0.0]) / max(math.hypot(t[0], t[1]), 1e-300)
    if refine and inl.sum() >= k:
        r, t = refine_pose(f1[inl], f2[inl], r, t, model=model)
    return PoseFit(model, inl, best_e, r, t)
