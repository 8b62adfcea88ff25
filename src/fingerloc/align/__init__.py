"""Fingerprint matching: global alignment, cyclic alignment with heading, batch kernels.

The paper scores a fingerprint against a place by the minimal Needleman-Wunsch
global alignment cost (docs/METHOD.md §4, ``P(Fp | loc) = 1 / (cost + 1)``). This
module computes that cost for one pair (:func:`global_alignment`, with the
alignment itself on request), for many pairs at once
(:func:`alignment_costs`), and its cyclic version, the minimum over every
rotation of one string, which removes the unknown heading of the robot
(:func:`cyclic_alignment`, docs/METHOD.md §6). :func:`minimum_energy` is the earlier
matcher of Lamon et al. (2001), the baseline of the paper's Table III.

Strings are validated against :data:`fingerloc.fingerprint.ALPHABET`; a
:class:`~fingerloc.fingerprint.Fingerprint` also brings the bearing of each
letter, used for the heading estimate and by the minimum-energy matcher.
Empty strings are valid: aligning against nothing costs the indels of the
other string. A :class:`FingerprintBatch` holds a collection validated once
(a place database), to pass to the batch functions again and again.

Kernels: unit costs go to RapidFuzz's bit-parallel Levenshtein
(``rapidfuzz.process.cdist``); weighted costs to a numba kernel that runs
32 references side by side; cyclic costs to a numba kernel (see
:func:`alignment_costs`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Literal, TypeVar, overload

import numba
import numpy as np
from numpy.typing import NDArray
from rapidfuzz import process as rf_process
from rapidfuzz.distance import Levenshtein

from .._numba_guard import parallel_region
from ..angles import TWO_PI, rad_to_deg360
from ..errors import InvalidParameterError
from ..fingerprint import Fingerprint
from ._costs import CostModel
from ._cyclic import cyclic_all_rotations, cyclic_batch_unit
from ._cyclic_int import LANES8, ProfileBlocks, cyclic_i8_costs, integer_costs, pack_profiles
from ._encode import FingerprintBatch, FingerprintLike, as_letters, encode, encode_many, letters_many
from ._energy import EnergyParams, energy_batch_lanes, energy_pair, pack_energy_lanes
from ._kernels import nw_batch, nw_batch_cyclic, nw_cost, nw_matrix, pack_lanes, traceback
from ._pairs import paired_cyclic_int

__all__ = [
    "CostModel",
    "CyclicAlignment",
    "FingerprintBatch",
    "alignment_costs",
    "cyclic_alignment",
    "cyclic_heading",
    "global_alignment",
    "minimum_energy",
    "minimum_energy_costs",
    "paired_alignment_costs",
]

_UNIT = CostModel()
_T = TypeVar("_T")


def _costs_or_unit(costs: CostModel | None) -> CostModel:
    if costs is None:
        return _UNIT
    if not isinstance(costs, CostModel):
        raise InvalidParameterError(f"costs: expected a CostModel or None, got {type(costs).__name__}")
    return costs


# -- plain global alignment ------------------------------------------------------


@overload
def global_alignment(
    a: FingerprintLike, b: FingerprintLike, *, costs: CostModel | None = ..., return_alignment: Literal[False] = ...
) -> float: ...
@overload
def global_alignment(
    a: FingerprintLike, b: FingerprintLike, *, costs: CostModel | None = ..., return_alignment: Literal[True]
) -> tuple[float, list[tuple[int | None, int | None]]]: ...
@overload
def global_alignment(
    a: FingerprintLike, b: FingerprintLike, *, costs: CostModel | None = ..., return_alignment: bool
) -> float | tuple[float, list[tuple[int | None, int | None]]]: ...
def global_alignment(
    a: FingerprintLike,
    b: FingerprintLike,
    *,
    costs: CostModel | None = None,
    return_alignment: bool = False,
) -> float | tuple[float, list[tuple[int | None, int | None]]]:
    """Minimal Needleman-Wunsch global alignment cost of two fingerprints (docs/METHOD.md §4).

    ``D[i, j] = min(D[i-1, j-1] + s(a_i, b_j), D[i-1, j] + g(a_i), D[i, j-1] + g(b_j))``
    with ``D[0, 0] = 0``; the cost is ``D[len(a), len(b)]``. With the default
    unit costs (match 0, substitution 1, insertion and deletion 1) it is the
    Levenshtein distance.

    Parameters
    ----------
    a, b : str or Fingerprint
        The two fingerprints (read as linear strings; see
        :func:`cyclic_alignment` for the rotation-free version).
    costs : CostModel, optional
        Edit costs; default ``CostModel()`` (unit costs).
    return_alignment : bool, default False
        Also return one optimal alignment.

    Returns
    -------
    cost : float
        Minimal alignment cost, ``>= 0``.
    alignment : list of (int or None, int or None)
        Only with ``return_alignment``: the aligned pairs in order, ``(i, j)``
        pairs ``a[i]`` with ``b[j]``, ``(i, None)`` leaves ``a[i]`` unpaired
        (a deletion), ``(None, j)`` leaves ``b[j]`` unpaired (an insertion).
        Among optimal alignments, ties prefer a pair, then a deletion, from
        the end of the strings backwards.

    Raises
    ------
    UnknownLetterError
        If a string holds a letter outside the alphabet.
    """
    cm = _costs_or_unit(costs)
    sa, _ = as_letters(a, "a")
    sb, _ = as_letters(b, "b")
    if not return_alignment:
        if cm.is_unit:
            return float(Levenshtein.distance(sa, sb))
        return float(nw_cost(encode(sa), encode(sb), cm.substitution, cm.indel))
    ca, cb = encode(sa), encode(sb)
    d = nw_matrix(ca, cb, cm.substitution, cm.indel)
    return float(d[-1, -1]), traceback(d, ca, cb, cm.substitution, cm.indel)


# -- cyclic alignment ----------------------------------------------------------


@dataclass(frozen=True, slots=True)
class CyclicAlignment:
    """Result of :func:`cyclic_alignment`.

    Attributes
    ----------
    cost : float
        Minimal global alignment cost of ``a`` against every rotation of ``b``.
    rotation : int
        Number of letters ``b`` was rotated by: ``b[rotation:] + b[:rotation]``
        is the best rotation. On ties (periodic strings such as ``nnnn`` or
        ``cncncn``) the tied rotation whose paired letters agree best on one
        bearing offset when both inputs have bearings, else the smallest.
    heading_deg : float or None
        Angle in degrees, ``[0, 360)``, to add to ``b``'s bearings to bring
        them onto ``a``'s: the circular mean of ``bearing(a_i) - bearing(b_j)``
        over the pairs of equal letters of the optimal alignment (``n`` letters
        and substitutions only when there is nothing better). A robot that saw
        ``b`` and then turned by ``-heading_deg`` (counter-clockwise positive)
        would see ``a``. ``None`` when either input has no bearings (a plain
        string) or nothing is paired.
    alignment : list of (int or None, int or None)
        The optimal alignment of ``a`` with the rotated ``b``; ``j`` indexes
        the rotated string, ``(j + rotation) % len(b)`` the original.
    """

    cost: float
    rotation: int
    heading_deg: float | None
    alignment: list[tuple[int | None, int | None]]


def _heading(
    sa: str,
    ba: NDArray[np.float64],
    sb: str,
    bb: NDArray[np.float64],
    pairs: list[tuple[int, int]],
) -> tuple[float, float] | None:
    """Circular mean of ``ba[i] - bb[j]`` over the most trustworthy pairs.

    Returns the mean in degrees, ``[0, 360)``, and the tier-ranked agreement
    of the pairs (``3 - tier + R``, ``R`` the mean resultant length in
    [0, 1]): a higher value means more trustworthy pairs agreeing better.
    ``None`` when nothing is paired.
    """
    tiers = (
        [(i, j) for i, j in pairs if sa[i] == sb[j] and sa[i] != "n"],
        [(i, j) for i, j in pairs if sa[i] == sb[j]],
        pairs,
    )
    for tier, chosen in enumerate(tiers):
        if chosen:
            ii = np.fromiter((p[0] for p in chosen), dtype=np.int64)
            jj = np.fromiter((p[1] for p in chosen), dtype=np.int64)
            diff = ba[ii] - bb[jj]
            sn, cs = float(np.sin(diff).sum()), float(np.cos(diff).sum())
            resultant = math.hypot(sn, cs) / len(chosen)
            return float(rad_to_deg360(math.atan2(sn, cs))), 3.0 - tier + resultant
    return None


def cyclic_alignment(a: FingerprintLike, b: FingerprintLike, *, costs: CostModel | None = None) -> CyclicAlignment:
    """Minimal alignment cost of ``a`` against every rotation of ``b``, with the best rotation.

    A fingerprint is a circular string: turning the robot rotates it. The
    cyclic cost is ``min over r of global_alignment(a, b[r:] + b[:r])``,
    computed exactly (every rotation is tried, so it equals the brute-force
    minimum). It is symmetric and invariant under rotating either string.

    Parameters
    ----------
    a, b : str or Fingerprint
        The two fingerprints. When both are :class:`Fingerprint` their
        bearings give the heading estimate.
    costs : CostModel, optional
        Edit costs; default unit costs.

    Returns
    -------
    CyclicAlignment
        ``cost``, ``rotation`` (letters of ``b`` rotated), ``heading_deg``
        (``None`` without bearings) and the optimal ``alignment``.
    """
    cm = _costs_or_unit(costs)
    sa, bear_a = as_letters(a, "a")
    sb, bear_b = as_letters(b, "b")
    ca, cb = encode(sa), encode(sb)
    per_rot = cyclic_all_rotations(ca, cb, cm.substitution, cm.indel)
    cost = float(per_rot.min())
    with_bearings = bear_a is not None and bear_b is not None and len(sb) > 0
    # Periodic strings (all n, "cncncn") tie over several rotations; with
    # bearings, keep the tied rotation whose pairs agree best on one heading.
    candidates = np.flatnonzero(per_rot == cost) if with_bearings else np.argmin(per_rot).reshape(1)
    best: tuple[float, int, float | None, list[tuple[int | None, int | None]]] | None = None
    m = len(sb)
    for rot in candidates.tolist():
        cbr = np.roll(cb, -rot)
        d = nw_matrix(ca, cbr, cm.substitution, cm.indel)
        alignment = traceback(d, ca, cbr, cm.substitution, cm.indel)
        heading, score = None, -1.0
        if with_bearings:
            assert bear_a is not None and bear_b is not None  # for mypy
            pairs = [(i, (j + rot) % m) for i, j in alignment if i is not None and j is not None]
            h = _heading(sa, bear_a, sb, bear_b, pairs)
            if h is not None:
                heading, score = h
        if best is None or score > best[0]:
            best = (score, rot, heading, alignment)
    assert best is not None  # at least one candidate
    _, rot, heading, alignment = best
    return CyclicAlignment(cost=cost, rotation=int(rot), heading_deg=heading, alignment=alignment)


def cyclic_heading(a: Fingerprint, b: Fingerprint, *, costs: CostModel | None = None) -> tuple[float, float | None]:
    """``(cost, heading_deg)`` of :func:`cyclic_alignment` for two fingerprints with bearings, in one compiled call.

    The same cost and heading (degrees in ``[0, 360)``, ``None`` when
    nothing is paired) as ``cyclic_alignment(a, b, costs=costs)``, without
    building the alignment: for callers that want a heading for many pairs
    (a heading at every place). The heading agrees with
    :func:`cyclic_alignment`'s to rounding (the same pairs, tiers and sums
    in numpy's order).
    """
    from ._heading_kernel import cyclic_cost_heading

    cm = _costs_or_unit(costs)
    if not isinstance(a, Fingerprint) or not isinstance(b, Fingerprint) or len(b) == 0:
        r = cyclic_alignment(a, b, costs=cm)
        return r.cost, r.heading_deg
    cost, _, h = cyclic_cost_heading(
        encode(a.letters), encode(b.letters), np.ascontiguousarray(a.bearings, dtype=np.float64),
        np.ascontiguousarray(b.bearings, dtype=np.float64), cm.substitution, cm.indel, _N_CODE,
    )  # fmt: skip
    return cost, (None if math.isnan(h) else float(rad_to_deg360(h)))


#: The letter code of ``n`` (its pairs rank below other equal letters in a heading).
_N_CODE = int(encode("n")[0])


# -- batch ---------------------------------------------------------------------


def _n_workers(workers: int | None) -> int:
    top = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
    if workers is None or workers == -1:
        return int(top)
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise InvalidParameterError(f"workers: expected a positive int, -1 or None (all cores), got {workers!r}")
    return int(min(int(workers), top))


def _run(n: int, fn: Callable[..., _T], *args: Any) -> _T:
    # one numba parallel region at a time in the process (see fingerloc._numba_guard)
    with parallel_region(n):
        return fn(*args)


#: Fewest queries for which the int8 cyclic kernel spreads its reference blocks over threads (fewer: one thread).
_PARALLEL_MIN_QUERIES = 8
#: Largest packed form (bytes) a :class:`FingerprintBatch` keeps for the int8 cyclic kernel.
_PACKED_MAX_BYTES = 256 << 20


def _profile_blocks(references: Any, rs: list[str], sub8: NDArray[np.int8], indel8: NDArray[np.int8]) -> ProfileBlocks | int:
    """The references packed for the int8 cyclic kernel, or, when too many to keep packed, how many to pack at a time.

    Either is kept by a :class:`FingerprintBatch` (one cost model at a time), so a repeated call neither packs
    nor measures the references again.
    """
    key = (sub8.tobytes(), indel8.tobytes())
    cache = references._packed if isinstance(references, FingerprintBatch) else None
    if cache is not None:
        hit = cache.get(key)
        if isinstance(hit, (ProfileBlocks, int)):
            return hit
    chunk = _reference_chunk(rs, sub8.shape[0])
    if chunk < len(rs):
        if cache is not None:
            cache.clear()
            cache[key] = chunk
        return chunk
    rcodes, roff = encode_many(rs)
    pk = pack_profiles(rcodes, roff, sub8, indel8)
    if cache is not None and pk.nbytes <= _PACKED_MAX_BYTES:
        cache.clear()
        cache[key] = pk
    return pk


#: Most bytes of references packed at once for the int8 cyclic kernel when they are too many to keep packed.
_PACK_CHUNK_BYTES = 64 << 20


def _reference_chunk(rs: list[str], n_letters: int) -> int:
    """How many references the int8 kernel packs at once: all when their packed form may be kept, else a chunk.

    The packed form's profile takes ``n_letters`` bytes a letter of a reference, its length rounded up to 16
    letters (at least: a block rounds its longest): all of them when that is at most :data:`_PACKED_MAX_BYTES`
    (a :class:`FingerprintBatch` may keep it), else as many of the longest as fit :data:`_PACK_CHUNK_BYTES`.
    """
    lens = np.fromiter((len(r) for r in rs), dtype=np.int64, count=len(rs))
    if n_letters * int(np.sum(-(-np.maximum(lens, 1) // 16) * 16)) <= _PACKED_MAX_BYTES:
        return len(rs)
    longest = int(lens.max())
    per_ref = n_letters * (-(-longest // 16) * 16) + 2 * longest  # the profile, the packed letters and their mask
    return max(LANES8, _PACK_CHUNK_BYTES // per_ref)


def alignment_costs(
    queries: Any,
    references: Any,
    *,
    cyclic: bool = False,
    costs: CostModel | None = None,
    workers: int | None = None,
) -> NDArray[np.float64]:
    """Alignment cost of every query against every reference.

    Parameters
    ----------
    queries, references : sequence of (str or Fingerprint), FingerprintBatch, or one fingerprint
        The fingerprints; a single string or Fingerprint counts as a
        sequence of one; a :class:`FingerprintBatch` skips re-validation.
    cyclic : bool, default False
        Cyclic cost (minimum over every rotation of the reference, see
        :func:`cyclic_alignment`) instead of the plain global alignment.
    costs : CostModel, optional
        Edit costs; default unit costs.
    workers : int, optional
        Threads to use; ``None`` or ``-1`` for every core.

    Returns
    -------
    ndarray of float64, shape (n_queries, n_references)
        ``out[q, r]`` equals ``global_alignment(queries[q], references[r])``
        (or ``cyclic_alignment(...).cost``).

    Notes
    -----
    Unit costs, plain: ``rapidfuzz.process.cdist`` with the Levenshtein
    distance (bit-parallel, multi-threaded). Weighted, plain: a numba kernel
    running 32 references side by side (AVX2) in each thread. Cyclic, unit
    costs: a bit-parallel kernel (Myers/Hyyrö) that runs every rotation at
    once in AVX2 lanes; cyclic, weighted: the weighted block kernel for
    every rotation (see :mod:`fingerloc.align._cyclic`); cyclic, weighted
    with small dyadic costs (``CostModel.feature_aware()`` and most hand-made
    models: multiples of 1/64 within a bounded range): an int8 kernel in the
    difference form that runs 256 references side by side and rotates the
    query (see :mod:`fingerloc.align._cyclic_int`). All are exact: they
    equal the brute-force minimum over rotations.
    """
    cm = _costs_or_unit(costs)
    nw = _n_workers(workers)
    qs = letters_many(queries, "queries")
    rs = letters_many(references, "references")
    nq, nr = len(qs), len(rs)
    if nq == 0 or nr == 0:
        return np.zeros((nq, nr))
    if not cyclic and cm.is_unit:
        # equal references (views of one place often give one string) are aligned once, then copied
        first: dict[str, int] = {}
        cols = np.fromiter((first.setdefault(r, len(first)) for r in rs), dtype=np.int64, count=nr)
        # rapidfuzz splits the work by query rows: extra threads for a handful of queries only cost start-up
        res = rf_process.cdist(qs, list(first), scorer=Levenshtein.distance, workers=min(nw, nq), dtype=np.int32)
        out = np.asarray(res, dtype=np.float64)
        return out if len(first) == nr else out[:, cols]
    qcodes, qoff = encode_many(qs)
    if cyclic and not cm.is_unit:
        small = integer_costs(cm.substitution, cm.indel)
        if small is not None:
            sub8, indel8, scale = small
            # a few queries: one thread (threads would cost more than they give on a busy machine)
            threads = nw if nq >= _PARALLEL_MIN_QUERIES else 1
            pk_or_chunk = _profile_blocks(references, rs, sub8, indel8)
            if isinstance(pk_or_chunk, ProfileBlocks):
                packed_int = cyclic_i8_costs(qcodes, qoff, pk_or_chunk, workers=threads)
                return np.ascontiguousarray(packed_int[:, pk_or_chunk.slot], dtype=np.float64) / scale
            # too many references to keep packed: a chunk at a time, the same costs
            chunk = pk_or_chunk
            out = np.empty((nq, nr))
            for a in range(0, nr, chunk):
                pk = pack_profiles(*encode_many(rs[a : a + chunk]), sub8, indel8)
                out[:, a : a + chunk] = cyclic_i8_costs(qcodes, qoff, pk, workers=threads)[:, pk.slot]
                del pk
            out /= scale
            return out
    rcodes, roff = encode_many(rs)
    if cyclic and cm.is_unit:
        return _run(nw, cyclic_batch_unit, qcodes, qoff, rcodes, roff, cm.substitution, cm.indel)
    blocks, blens, block_len, slot = pack_lanes(rcodes, roff)
    kernel = nw_batch_cyclic if cyclic else nw_batch
    packed = _run(nw, kernel, qcodes, qoff, blocks, blens, block_len, cm.substitution, cm.indel)
    return np.ascontiguousarray(packed[:, slot])


def paired_alignment_costs(
    queries: Any,
    references: Any,
    *,
    cyclic: bool = False,
    costs: CostModel | None = None,
) -> NDArray[np.float64]:
    """Alignment cost of ``queries[k]`` against ``references[k]`` for each ``k``.

    What ``alignment_costs(queries, references)`` holds on its diagonal, without the rest
    of the matrix: for many small sets of strings (the views of each place).

    Parameters
    ----------
    queries, references : sequence of (str or Fingerprint), same length
    cyclic : bool, default False
        Cyclic cost (minimum over every rotation).
    costs : CostModel, optional
        Edit costs; default unit costs.

    Returns
    -------
    ndarray of float64, shape (n,)

    Notes
    -----
    Cyclic with integer-scalable costs (unit and feature-aware costs): one
    kernel call whose vector lanes run over the rotations of each pair
    (:mod:`fingerloc.align._pairs`), exact. Plain: RapidFuzz's Levenshtein
    distance (unit costs) or the weighted DP, one pair at a time.
    """
    cm = _costs_or_unit(costs)
    qs = letters_many(queries, "queries")
    rs = letters_many(references, "references")
    if len(qs) != len(rs):
        raise InvalidParameterError(f"paired_alignment_costs: {len(qs)} queries for {len(rs)} references")
    n = len(qs)
    if n == 0:
        return np.zeros(0)
    small = integer_costs(cm.substitution, cm.indel) if cyclic else None
    if small is not None:
        sub8, indel8, scale = small
        codes, off = encode_many(qs + rs)
        ints = paired_cyclic_int(codes, off, np.arange(n), n + np.arange(n), sub8, indel8)
        return np.asarray(ints, dtype=np.float64) / scale
    if not cyclic and cm.is_unit:
        return np.array([float(Levenshtein.distance(q, r)) for q, r in zip(qs, rs, strict=True)])
    if not cyclic:
        return np.array([float(nw_cost(encode(q), encode(r), cm.substitution, cm.indel)) for q, r in zip(qs, rs, strict=True)])
    return np.array(
        [alignment_costs([q], [r], cyclic=True, costs=cm, workers=1)[0, 0] for q, r in zip(qs, rs, strict=True)]
    )


# -- minimum energy (Lamon et al. 2001) --------------------------------------------------


def _even_bearings(n: int) -> NDArray[np.float64]:
    return np.arange(n, dtype=np.float64) * (TWO_PI / max(n, 1))


def _with_bearings(x: Any, name: str) -> tuple[str, NDArray[np.float64]]:
    s, bearings = as_letters(x, name)
    return s, _even_bearings(len(s)) if bearings is None else bearings


def _many_with_bearings(xs: Any, name: str) -> tuple[NDArray[np.uint8], NDArray[np.float64], NDArray[np.int64]]:
    if isinstance(xs, FingerprintBatch):
        strs, given = xs.letters, xs.bearings
    else:
        items = [xs] if isinstance(xs, (str, Fingerprint)) else list(xs) if isinstance(xs, Iterable) else xs
        strs = letters_many(items, name)  # validates (and rejects a non-sequence)
        given = [x.bearings if isinstance(x, Fingerprint) else None for x in items]
    codes, off = encode_many(strs)
    bear = np.empty(codes.shape[0], dtype=np.float64)
    for k, (b, s) in enumerate(zip(given, strs, strict=True)):
        bear[off[k] : off[k + 1]] = _even_bearings(len(s)) if b is None else b
    return codes, bear, off


def minimum_energy(
    a: FingerprintLike,
    b: FingerprintLike,
    *,
    occlusion: float = 1.0,
    mismatch: float = math.inf,
    bearing_scale_deg: float = 20.0,
    wrap: bool = True,
) -> float:
    """Minimum-energy matching cost of two fingerprints (Lamon et al., ICRA 2001; the paper's Table III baseline).

    A dynamic-programming match after Ohta and Kanade's scanline search:
    pairing letter ``x`` at bearing ``alpha`` with ``y`` at ``beta`` costs
    ``type(x, y) + (distAS(alpha, beta) / bearing_scale)^2`` and leaving a
    letter unmatched costs ``occlusion``; the energy is the cheapest
    order-preserving matching. Every choice the 2001 paper leaves open is
    listed in :mod:`fingerloc.align._energy`.

    Parameters
    ----------
    a, b : str or Fingerprint
        The fingerprints; a plain string's letters are spread evenly around
        the circle from 0 deg.
    occlusion : float, default 1
        Energy of a letter left unmatched; ``>= 0``.
    mismatch : float, default inf
        Type energy of pairing two different letters; ``inf`` pairs only equal letters.
    bearing_scale_deg : float, default 20
        Bearing difference (degrees) whose match energy equals 1; ``> 0``.
    wrap : bool, default True
        Minimum over every rotation of ``b``'s letter order (bearings kept
        absolute), so that features either side of 0 deg can match.

    Returns
    -------
    float
        The energy, ``>= 0``; 0 for identical fingerprints; symmetric.
    """
    p = EnergyParams(occlusion, mismatch, bearing_scale_deg, wrap)
    sa, ba = _with_bearings(a, "a")
    sb, bb = _with_bearings(b, "b")
    return float(
        energy_pair(
            encode(sa), ba, encode(sb), bb, p.type_table(), float(occlusion), bearing_scale_deg**-2.0, bool(wrap)
        )
    )


def minimum_energy_costs(
    queries: Any,
    references: Any,
    *,
    occlusion: float = 1.0,
    mismatch: float = math.inf,
    bearing_scale_deg: float = 20.0,
    wrap: bool = True,
    workers: int | None = None,
) -> NDArray[np.float64]:
    """:func:`minimum_energy` of every query against every reference, multi-threaded.

    Parameters
    ----------
    queries, references : sequence of (str or Fingerprint), FingerprintBatch, or one fingerprint
    occlusion, mismatch, bearing_scale_deg, wrap
        As in :func:`minimum_energy`.
    workers : int, optional
        Threads; ``None`` or ``-1`` for every core.

    Returns
    -------
    ndarray of float64, shape (n_queries, n_references)
    """
    p = EnergyParams(occlusion, mismatch, bearing_scale_deg, wrap)
    nw = _n_workers(workers)
    qc, qb, qo = _many_with_bearings(queries, "queries")
    rc, rb, ro = _many_with_bearings(references, "references")
    if qo.shape[0] == 1 or ro.shape[0] == 1:
        return np.zeros((qo.shape[0] - 1, ro.shape[0] - 1))
    letters, bearings, lens, slot = pack_energy_lanes(rc, rb, ro)
    packed = _run(
        nw,
        energy_batch_lanes,
        qc,
        qb,
        qo,
        letters,
        bearings,
        lens,
        p.type_table(),
        float(occlusion),
        bearing_scale_deg**-2.0,
        bool(wrap),
    )
    return np.ascontiguousarray(packed[:, slot])
