"""Many fingerprints at once: :func:`make_fingerprints`, the very strings and bearings of :func:`~fingerloc.make_fingerprint`.

:func:`fingerloc.fingerprint.make_fingerprint` builds one string with Python
lists (about 0.1 ms a view); a map of 300,000 views spent more time there
than in everything else it learns. Here the same three steps run for a batch:

* every conversion of a bearing or a hue is done once for the whole batch,
  with the numpy calls the one-view function makes (``wrap_deg360(rad2deg)``,
  the hue bin by floor division, the wall classes by comparison), so each
  value is the same float;
* the merging of corners and edges, the ordering of letters at one bearing
  and the empty-space letters run in one compiled loop over the views, with
  the same floating-point operations in the same order as the Python code
  (``tests/test_fingerprints_batch.py`` checks the strings and bearings bit
  for bit against the one-view function, hypothesis included);
* the bearings go back to radians (``deg2rad``, ``wrap``) for the whole batch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit
from numpy.typing import NDArray

from ._types import FArray
from .angles import wrap, wrap_deg360
from .errors import InvalidParameterError
from .fingerprint import (
    ALPHABET,
    EXTREMITY_LETTER,
    GAP_TOL_DEG,
    HUE_BIN_DEG,
    HUE_LETTERS,
    MIN_EMPTY_STEP_DEG,
    WALL_LENGTH_EDGES_M,
    WALL_LETTERS,
    WALL_RANGE_EDGES_M,
    Fingerprint,
    _seen_pieces_cached,
)
from .observation import Observation

__all__ = ["make_fingerprints"]

_CODE = {ch: i for i, ch in enumerate(ALPHABET)}
_V, _C, _B, _F, _N, _E = (_CODE[ch] for ch in ("v", "c", "b", "f", "n", EXTREMITY_LETTER))
_HUE0 = _CODE[HUE_LETTERS[0]]
_WALL = np.array([_CODE[ch] for ch in WALL_LETTERS], dtype=np.int64)
_LETTERS = np.frombuffer(ALPHABET.encode("ascii"), dtype=np.uint8)


def _deg(x: FArray) -> FArray:
    """``fingerprint._degrees`` for a whole array: ``wrap_deg360(rad2deg(x))``."""
    return np.asarray(wrap_deg360(np.rad2deg(x)), dtype=np.float64)


def make_fingerprints(
    observations: Sequence[Observation],
    *,
    empty_step_deg: float = 20.0,
    merge_tol_deg: float = 5.0,
    laser_letters: bool = False,
) -> list[Fingerprint]:
    """:func:`~fingerloc.make_fingerprint` of each observation (the same letters and bearings), for a batch.

    Parameters
    ----------
    observations : sequence of Observation
    empty_step_deg, merge_tol_deg, laser_letters
        As :func:`~fingerloc.make_fingerprint`.

    Returns
    -------
    list of Fingerprint, one per observation
    """
    if not (math.isfinite(empty_step_deg) and empty_step_deg >= MIN_EMPTY_STEP_DEG):
        raise InvalidParameterError(
            f"empty_step_deg must be a number of degrees >= {MIN_EMPTY_STEP_DEG:g} "
            f"(at most {round(360 / MIN_EMPTY_STEP_DEG)} 'n' letters), got {empty_step_deg!r}"
        )
    if not (math.isfinite(merge_tol_deg) and merge_tol_deg >= 0):
        raise InvalidParameterError(f"merge_tol_deg must be >= 0 degrees, got {merge_tol_deg!r}")
    obs = list(observations)
    n = len(obs)
    if n == 0:
        return []

    def gather(name: str) -> tuple[FArray, NDArray[np.int64]]:
        arrays = [getattr(o, name) for o in obs]
        off = np.zeros(n + 1, dtype=np.int64)
        np.cumsum([a.size for a in arrays], out=off[1:])
        return (np.concatenate(arrays) if off[-1] else np.zeros(0)), off

    ve, ve_off = gather("ve")
    cs, c_off = gather("c")
    cp, cp_off = gather("cp")
    hue, _ = gather("cp_hue")
    bb, b_off = gather("b")
    # every other letter (hue patches, beacons, extremities, walls) in the order make_fingerprint lists them
    parts: list[tuple[FArray, NDArray[np.int64], NDArray[np.int64]]] = []
    hue_bins = np.minimum(np.floor_divide(hue, HUE_BIN_DEG).astype(np.int64), len(HUE_LETTERS) - 1)
    parts.append((_deg(cp), _HUE0 + hue_bins, cp_off))
    parts.append((_deg(bb), np.full(bb.size, _B, dtype=np.int64), b_off))
    if laser_letters:
        ex, ex_off = gather("ex")
        parts.append((_deg(ex), np.full(ex.size, _E, dtype=np.int64), ex_off))
        w, w_off = gather("w")
        length, _ = gather("w_length")
        rng, _ = gather("w_range")
        li = sum((length >= e).astype(np.int64) for e in WALL_LENGTH_EDGES_M)
        ri = sum((rng >= e).astype(np.int64) for e in WALL_RANGE_EDGES_M)
        parts.append((_deg(w), _WALL[ri * (len(WALL_LENGTH_EDGES_M) + 1) + li], w_off))
    other_b = np.concatenate([p[0] for p in parts])
    other_c = np.concatenate([p[1] for p in parts])
    # per view, the start of each part's slice in the concatenation
    bases = np.cumsum([0] + [p[0].size for p in parts[:-1]])
    other_off = np.stack([base + p[2] for base, p in zip(bases, parts, strict=True)])  # (n_parts, n + 1)
    # fields of view: each distinct one's seen pieces once
    fov_index: dict[object, int] = {}
    view_fov = np.empty(n, dtype=np.int64)
    for i, o in enumerate(obs):
        view_fov[i] = fov_index.setdefault(o.fov, len(fov_index))
    piece_lo: list[float] = []
    piece_hi: list[float] = []
    piece_off = [0]
    full = np.zeros(len(fov_index), dtype=np.bool_)
    for fov, k in fov_index.items():
        pieces, is_full = _seen_pieces_cached(fov)  # type: ignore[arg-type]
        full[k] = is_full
        piece_lo += [p[0] for p in pieces]
        piece_hi += [p[1] for p in pieces]
        piece_off.append(len(piece_lo))
    codes, bear, off = _assemble(
        _deg(ve), ve_off, _deg(cs), c_off, other_b, other_c, other_off,
        view_fov, full, np.array(piece_lo), np.array(piece_hi), np.array(piece_off, dtype=np.int64),
        float(empty_step_deg), float(merge_tol_deg),
    )  # fmt: skip
    rad = wrap(np.deg2rad(bear))
    rad.setflags(write=False)
    text = _LETTERS[codes].tobytes().decode("ascii")
    out: list[Fingerprint] = []
    for i in range(n):
        a, b = int(off[i]), int(off[i + 1])
        out.append(_fingerprint(text[a:b], rad[a:b]))
    return out


def _fingerprint(letters: str, bearings: FArray) -> Fingerprint:
    """A :class:`Fingerprint` of letters and wrapped read-only bearings already in its final form."""
    fp = object.__new__(Fingerprint)
    object.__setattr__(fp, "letters", letters)
    object.__setattr__(fp, "bearings", bearings)
    return fp


@njit(cache=True)
def _empty_space(
    a: float, b: float, full: bool, lo: FArray, hi: FArray, step: float, out: FArray, k: int, ilo: FArray, ihi: FArray
) -> int:  # pragma: no cover - compiled
    """``make_fingerprint``'s ``empty_space(a, b)``: the bearings of the gap's ``n`` letters into ``out[k:]``; returns the new ``k``.

    ``ilo``, ``ihi``: scratch of ``2 * lo.size`` floats.
    """
    if full:
        width = b - a
        count = math.floor((width + GAP_TOL_DEG) / step)
        for j in range(count):
            t = (j + 0.5) * width / count
            out[k] = a + t if t <= width else b
            k += 1
        return k
    # _seen_intervals: parts of [a, b] inside the pieces, for shifts 0 and 360
    m = 0
    for shift in (0.0, 360.0):
        for p in range(lo.size):
            lo2 = max(a, lo[p] + shift)
            hi2 = min(b, hi[p] + shift)
            if hi2 > lo2:
                ilo[m] = lo2
                ihi[m] = hi2
                m += 1
    seen = 0.0
    for p in range(m):
        seen = seen + (ihi[p] - ilo[p])
    count = math.floor((seen + GAP_TOL_DEG) / step)
    if count == 0:
        return k
    total = 0.0
    for p in range(m):
        total = total + (ihi[p] - ilo[p])
    for j in range(count):
        target = (j + 0.5) * total / count
        placed = False
        for p in range(m):
            if target <= ihi[p] - ilo[p]:
                out[k] = ilo[p] + target
                placed = True
                break
            target -= ihi[p] - ilo[p]
        if not placed:
            out[k] = ihi[m - 1]
        k += 1
    return k


@njit(cache=True)
def _pymod(x: float, y: float) -> float:  # pragma: no cover - compiled
    """Python's ``x % y`` for floats (``y > 0``)."""
    r = np.fmod(x, y)
    if r != 0.0:
        if (y < 0) != (r < 0):
            r += y
    else:
        r = math.copysign(0.0, y)
    return r


@njit(cache=True)
def _assemble(
    ve: FArray, ve_off: NDArray[np.int64], cs: FArray, c_off: NDArray[np.int64],
    ob: FArray, oc: NDArray[np.int64], o_off: NDArray[np.int64],
    view_fov: NDArray[np.int64], full: NDArray[np.bool_], plo: FArray, phi: FArray, p_off: NDArray[np.int64],
    step: float, merge_tol: float,
) -> tuple[NDArray[np.int64], FArray, NDArray[np.int64]]:  # pragma: no cover - compiled
    n = view_fov.size
    cap = 16
    codes = np.empty(cap, dtype=np.int64)
    bear = np.empty(cap)
    off = np.zeros(n + 1, dtype=np.int64)
    total = 0
    for i in range(n):
        v0, v1 = ve_off[i], ve_off[i + 1]
        c0, c1 = c_off[i], c_off[i + 1]
        nv, nc = v1 - v0, c1 - c0
        # step 2: corner/edge pairs within the tolerance, closest first (ties: edge counter-clockwise first)
        npairs = 0
        pk = np.empty(nv * nc, dtype=np.int64)
        ps = np.empty(nv * nc, dtype=np.int64)
        pi = np.empty(nv * nc, dtype=np.int64)
        pj = np.empty(nv * nc, dtype=np.int64)
        for a in range(nc):
            cb = cs[c0 + a]
            for b in range(nv):
                vb = ve[v0 + b]
                signed = _pymod(vb - cb + 180.0, 360.0) - 180.0
                d = abs(signed)
                if d <= merge_tol + GAP_TOL_DEG:
                    pk[npairs] = np.int64(np.rint(d / GAP_TOL_DEG))
                    ps[npairs] = 0 if signed > 0 else 1
                    pi[npairs] = a
                    pj[npairs] = b
                    npairs += 1
        # sort the pairs by (distance key, side, corner, edge): insertion sort (few pairs)
        for x in range(1, npairs):
            y = x
            while y > 0 and (
                pk[y - 1] > pk[y]
                or (pk[y - 1] == pk[y] and (ps[y - 1] > ps[y] or (ps[y - 1] == ps[y] and (pi[y - 1] > pi[y] or (pi[y - 1] == pi[y] and pj[y - 1] > pj[y])))))
            ):
                pk[y - 1], pk[y] = pk[y], pk[y - 1]
                ps[y - 1], ps[y] = ps[y], ps[y - 1]
                pi[y - 1], pi[y] = pi[y], pi[y - 1]
                pj[y - 1], pj[y] = pj[y], pj[y - 1]
                y -= 1
        used_c = np.zeros(nc, dtype=np.bool_)
        used_v = np.zeros(nv, dtype=np.bool_)
        nother = 0
        for q in range(o_off.shape[0]):
            nother += o_off[q, i + 1] - o_off[q, i]
        fb = np.empty(nv + nc + nother)
        fc = np.empty(nv + nc + nother, dtype=np.int64)
        nf = 0
        for x in range(npairs):
            a, b = pi[x], pj[x]
            if used_c[a] or used_v[b]:
                continue
            used_c[a] = True
            used_v[b] = True
            mid = cs[c0 + a] + (_pymod(ve[v0 + b] - cs[c0 + a] + 180.0, 360.0) - 180.0) / 2.0
            mm = _pymod(mid, 360.0)  # wrap_deg360
            fb[nf] = 0.0 if mm >= 360.0 - 1e-9 else mm
            fc[nf] = _F
            nf += 1
        for b in range(nv):
            if not used_v[b]:
                fb[nf] = ve[v0 + b]
                fc[nf] = _V
                nf += 1
        for a in range(nc):
            if not used_c[a]:
                fb[nf] = cs[c0 + a]
                fc[nf] = _C
                nf += 1
        for q in range(o_off.shape[0]):
            for x in range(o_off[q, i], o_off[q, i + 1]):
                fb[nf] = ob[x]
                fc[nf] = oc[x]
                nf += 1
        # _tie_ordered: by (bearing, letter), stable; ties (chains within GAP_TOL_DEG) by letter
        for x in range(1, nf):
            y = x
            while y > 0 and (fb[y - 1] > fb[y] or (fb[y - 1] == fb[y] and fc[y - 1] > fc[y])):
                fb[y - 1], fb[y] = fb[y], fb[y - 1]
                fc[y - 1], fc[y] = fc[y], fc[y - 1]
                y -= 1
        group = np.empty(nf, dtype=np.int64)
        ng = 0
        for x in range(nf):
            if x > 0 and fb[x] - fb[x - 1] <= GAP_TOL_DEG:
                group[x] = ng - 1
            else:
                group[x] = ng
                ng += 1
        gb = np.empty(nf)
        gc = np.empty(nf, dtype=np.int64)
        start = 0
        if ng > 1 and fb[0] + 360.0 - fb[nf - 1] <= GAP_TOL_DEG:
            # the last group joins the first, 360 degrees lower, in front of it
            last = nf - 1
            while last > 0 and group[last - 1] == ng - 1:
                last -= 1
            k = 0
            for x in range(last, nf):
                gb[k] = fb[x] - 360.0
                gc[k] = fc[x]
                k += 1
            end0 = 0
            while end0 < nf and group[end0] == 0:
                end0 += 1
            for x in range(0, end0):
                gb[k] = fb[x]
                gc[k] = fc[x]
                k += 1
            _sort_by_letter(gb, gc, 0, k)
            start = k
            x = end0
            stop = last
        else:
            x = 0
            stop = nf
        k = start
        while x < stop:
            g0 = k
            gid = group[x]
            while x < stop and group[x] == gid:
                gb[k] = fb[x]
                gc[k] = fc[x]
                k += 1
                x += 1
            _sort_by_letter(gb, gc, g0, k)
        nf = k
        # step 3: letters by bearing, each followed by its gap's n letters
        lo = plo[p_off[view_fov[i]] : p_off[view_fov[i] + 1]]
        hi = phi[p_off[view_fov[i]] : p_off[view_fov[i] + 1]]
        is_full = full[view_fov[i]]
        ilo = np.empty(2 * lo.size)
        ihi = np.empty(2 * lo.size)
        # each gap holds at most (width + GAP_TOL_DEG) / step letters n, the gaps span 360 degrees
        need = total + 2 * nf + int(360.0 / step) + 3
        if need > codes.size:
            grow = max(need, 2 * codes.size)
            c2 = np.empty(grow, dtype=np.int64)
            b2 = np.empty(grow)
            c2[:total] = codes[:total]
            b2[:total] = bear[:total]
            codes, bear = c2, b2
        k = total
        if nf == 0:
            k2 = _empty_space(0.0, 360.0, is_full, lo, hi, step, bear, k, ilo, ihi)
            for y in range(k, k2):
                codes[y] = _N
            k = k2
        for x in range(nf):
            nxt = gb[x + 1] if x + 1 < nf else gb[0] + 360.0
            codes[k] = gc[x]
            bear[k] = gb[x]
            k += 1
            k2 = _empty_space(gb[x], nxt, is_full, lo, hi, step, bear, k, ilo, ihi)
            for y in range(k, k2):
                codes[y] = _N
            k = k2
        total = k
        off[i + 1] = total
    return codes[:total], bear[:total], off


@njit(cache=True)
def _sort_by_letter(b: FArray, c: NDArray[np.int64], lo: int, hi: int) -> None:  # pragma: no cover - compiled
    """Stable insertion sort of ``b[lo:hi]``, ``c[lo:hi]`` by ``c``."""
    for x in range(lo + 1, hi):
        y = x
        while y > lo and c[y - 1] > c[y]:
            b[y - 1], b[y] = b[y], b[y - 1]
            c[y - 1], c[y] = c[y], c[y - 1]
            y -= 1
