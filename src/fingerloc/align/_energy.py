"""The minimum-energy fingerprint matcher (Lamon et al., ICRA 2001): the baseline of the paper's Table III.

Lamon, Nourbakhsh, Jensen and Siegwart matched fingerprint sequences with a
"minimum energy" algorithm borrowed from stereo vision: the dynamic
programming search of Ohta and Kanade, which finds the cheapest monotone path
through a 2-D plane whose axes are the two scanlines, every step either
matching one element of each or leaving one element unmatched (an occlusion).
For fingerprints the elements are the letters with their bearings. The 2001
paper gives the structure but not every constant; our choices, each a
keyword parameter:

1. **Match energy** of letter ``x`` at bearing ``alpha`` with letter ``y`` at
   bearing ``beta``: ``type(x, y) + (distAS(alpha, beta) / bearing_scale)^2``.
   ``type`` is 0 for equal letters and ``mismatch`` otherwise; the default
   ``mismatch = inf`` only pairs features of the same kind (stereo matches an
   edge only with an edge of the same sign). The quadratic bearing term is
   the usual disparity-smoothness energy; with ``bearing_scale_deg = 20`` (the
   ``n`` step) a pair 20 deg apart costs as much as one occlusion, and pairs
   more than ``sqrt(2) * 20 = 28`` deg apart are never matched (two
   occlusions are cheaper).
2. **Occlusion energy**: a letter left unmatched costs ``occlusion`` (1).
3. **Empty space**: ``n`` letters are kept and matched like features; their
   bearings sit evenly in their gap, so matching them compares gap widths.
4. **Heading**: the robot keeps its heading between training and test (as in
   the paper's experiment), so bearings are compared as absolute angles and
   are never shifted.
5. **The cut at 0 deg**: the string starts at bearing 0, so a feature at 359
   deg and its twin at 1 deg sit at opposite ends. With ``wrap=True``
   (default) the energy is the minimum over every rotation of ``b``'s letter
   order (bearings unchanged), which lets such pairs match; the bearing term
   keeps wrong rotations expensive.
6. **Bearings of plain strings**: a string carries no bearings; its letters
   are spread evenly around the circle from 0 deg, as
   :func:`~fingerloc.fingerprint.parse_fingerprint` does.

The energy is ``>= 0``, 0 for identical fingerprints and symmetric in its
two arguments.

References
----------
.. [1] P. Lamon, I. Nourbakhsh, B. Jensen, R. Siegwart, "Deriving and matching
   image fingerprint sequences for mobile robot localization", ICRA 2001.
.. [2] Y. Ohta, T. Kanade, "Stereo by intra- and inter-scanline search using
   dynamic programming", IEEE TPAMI 7(2), 1985.
.. [3] R. Siegwart, I. Nourbakhsh, "Introduction to Autonomous Mobile Robots",
   MIT Press, 2004, chapter 4, p. 180 (fingerprint string differencing: the minimum
   energy to transform one sequence into the other, insensitive to single
   added or missing features). Where [1] could not be read in full, [2] and
   this summary fixed the structure; the constants are ours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from ..errors import InvalidParameterError
from ._costs import N_LETTERS
from ._kernels import LANES

__all__ = ["EnergyParams", "energy_batch_lanes", "energy_pair", "pack_energy_lanes"]


@dataclass(frozen=True, slots=True)
class EnergyParams:
    """Validated parameters of the minimum-energy matcher (see the module docstring)."""

    occlusion: float = 1.0
    mismatch: float = math.inf
    bearing_scale_deg: float = 20.0
    wrap: bool = True

    def __post_init__(self) -> None:
        if not (isinstance(self.occlusion, (int, float)) and math.isfinite(self.occlusion) and self.occlusion >= 0):
            raise InvalidParameterError(f"occlusion: must be a finite energy >= 0, got {self.occlusion!r}")
        if not (isinstance(self.mismatch, (int, float)) and not math.isnan(self.mismatch) and self.mismatch >= 0):
            raise InvalidParameterError(f"mismatch: must be an energy >= 0 (inf forbids), got {self.mismatch!r}")
        if not (
            isinstance(self.bearing_scale_deg, (int, float))
            and math.isfinite(self.bearing_scale_deg)
            and self.bearing_scale_deg > 0
        ):
            raise InvalidParameterError(
                f"bearing_scale_deg: must be a positive number of degrees, got {self.bearing_scale_deg!r}"
            )
        if not isinstance(self.wrap, (bool, np.bool_)):
            raise InvalidParameterError(f"wrap: must be True or False, got {self.wrap!r}")

    def type_table(self) -> NDArray[np.float64]:
        """Type energy of every pair of letters, shape ``(N_LETTERS, N_LETTERS)``: 0 on the diagonal, ``mismatch`` elsewhere."""
        t = np.full((N_LETTERS, N_LETTERS), float(self.mismatch))
        np.fill_diagonal(t, 0.0)
        return t


@njit(cache=True)
def _energy_linear(
    a: NDArray[np.uint8],
    ba: NDArray[np.float64],
    b: NDArray[np.uint8],
    bb: NDArray[np.float64],
    start: int,
    typ: NDArray[np.float64],
    occ: float,
    inv_scale2: float,
    row: NDArray[np.float64],
) -> float:  # pragma: no cover - compiled
    """Minimum energy of ``a`` against ``b`` read from letter ``start`` (circularly); bearings in radians."""
    n, m = a.shape[0], b.shape[0]
    for j in range(m + 1):
        row[j] = j * occ
    two_pi = 2.0 * np.pi
    for i in range(n):
        ca = a[i]
        diag = row[0]
        row[0] = (i + 1) * occ
        for j in range(1, m + 1):
            jj = start + j - 1
            if jj >= m:
                jj -= m
            # distAS in degrees, squared and scaled: the disparity energy
            d = bb[jj] - ba[i]
            d = d - two_pi * np.floor((d + np.pi) / two_pi)
            dd = d * (180.0 / np.pi)
            v = diag + typ[ca, b[jj]] + dd * dd * inv_scale2
            up = row[j]
            w = up + occ
            if w < v:
                v = w
            w = row[j - 1] + occ
            if w < v:
                v = w
            diag = up
            row[j] = v
    return float(row[m])


@njit(cache=True)
def energy_pair(
    a: NDArray[np.uint8],
    ba: NDArray[np.float64],
    b: NDArray[np.uint8],
    bb: NDArray[np.float64],
    typ: NDArray[np.float64],
    occ: float,
    inv_scale2: float,
    wrap: bool,
) -> float:  # pragma: no cover - compiled
    """Minimum energy of two fingerprints (letters and bearings in radians)."""
    m = b.shape[0]
    row = np.empty(m + 1)
    best = _energy_linear(a, ba, b, bb, 0, typ, occ, inv_scale2, row)
    if wrap:
        for r in range(1, m):
            e = _energy_linear(a, ba, b, bb, r, typ, occ, inv_scale2, row)
            if e < best:
                best = e
    return best


@njit(cache=True)
def _fill_lanes(
    codes: NDArray[np.uint8],
    bear: NDArray[np.float64],
    off: NDArray[np.int64],
    order: NDArray[np.int64],
    letters: NDArray[np.uint8],
    bearings: NDArray[np.float64],
    lens: NDArray[np.int64],
) -> None:  # pragma: no cover - compiled
    """Scatter strings ``order[pos]`` into lane ``pos % LANES`` of block ``pos // LANES``."""
    lanes = letters.shape[2]
    for pos in range(order.shape[0]):
        s = order[pos]
        k = pos // lanes
        lane = pos - k * lanes
        m = off[s + 1] - off[s]
        lens[k, lane] = m
        for j in range(m):
            letters[k, j, lane] = codes[off[s] + j]
            bearings[k, j, lane] = bear[off[s] + j]


def pack_energy_lanes(
    codes: NDArray[np.uint8], bear: NDArray[np.float64], off: NDArray[np.int64]
) -> tuple[NDArray[np.uint8], NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """Pack references (letters and bearings) into blocks of ``LANES``, sorted by length.

    Returns ``letters (n_blocks, max_len, LANES)``, ``bearings`` (same shape),
    ``lens (n_blocks, LANES)`` and ``slot (n_strings,)``, the packed position
    of each input string.
    """
    n = off.shape[0] - 1
    lens = np.diff(off)
    order = np.argsort(lens, kind="stable")
    nb = max(1, -(-n // LANES))
    maxlen = max(int(lens.max()) if n else 0, 1)
    letters = np.zeros((nb, maxlen, LANES), dtype=np.uint8)
    bearings = np.zeros((nb, maxlen, LANES))
    blens = np.zeros((nb, LANES), dtype=np.int64)
    _fill_lanes(codes, bear, off, order, letters, bearings, blens)
    slot = np.empty(n, dtype=np.int64)
    slot[order] = np.arange(n)
    return letters, bearings, blens, slot


@njit(parallel=True, cache=True)
def energy_batch_lanes(
    qcodes: NDArray[np.uint8],
    qbear: NDArray[np.float64],
    qoff: NDArray[np.int64],
    letters: NDArray[np.uint8],
    bearings: NDArray[np.float64],
    blens: NDArray[np.int64],
    typ: NDArray[np.float64],
    occ: float,
    inv_scale2: float,
    wrap: bool,
) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """Minimum energies against ``LANES`` references side by side, shape ``(n_queries, n_blocks * LANES)``.

    The same DP as :func:`energy_pair`, vectorised over the lanes. With
    ``wrap`` the minimum runs over every rotation of the *query's* letter
    order rather than the reference's: both minimise over the same cyclic
    matchings (cut a cyclic matching where ``a`` starts, or where ``b``
    starts), so the energy is the same, and every lane then shares one
    rotation. The match energies of a query against a block,
    ``type(a_i, b_j) + (distAS / scale)^2`` for every query letter ``i``,
    reference letter ``j`` and lane, are computed once per query and block
    and read by every rotation, which leaves the DP cell three additions and
    two minima.
    """
    nq = qoff.shape[0] - 1
    nb = letters.shape[0]
    maxlen = letters.shape[1]
    two_pi = 2.0 * np.pi
    inv_two_pi = 1.0 / two_pi
    rad2deg = 180.0 / np.pi
    maxq = 1
    for q in range(nq):
        maxq = max(maxq, qoff[q + 1] - qoff[q])
    out = np.empty((nq, nb * LANES))
    for blk in prange(nb):
        lens = blens[blk]
        big = 0
        for k in range(LANES):
            big = max(big, lens[k])
        energy = np.empty((maxq, maxlen, LANES))  # energy[t, j, k]: query letter t against letter j of lane k
        row = np.empty((maxlen + 1, LANES))
        diag = np.empty(LANES)
        best = np.empty(LANES)
        for q in range(nq):
            q0 = qoff[q]
            n = qoff[q + 1] - q0
            for t in range(n):
                ca = qcodes[q0 + t]
                bai = qbear[q0 + t]
                for j in range(big):
                    for k in range(LANES):
                        # distAS in degrees, squared and scaled: the disparity energy
                        d = bearings[blk, j, k] - bai
                        d = (d - two_pi * np.floor((d + np.pi) * inv_two_pi)) * rad2deg
                        energy[t, j, k] = typ[ca, letters[blk, j, k]] + d * d * inv_scale2
            for k in range(LANES):
                best[k] = np.inf
            n_rot = max(n, 1) if wrap else 1
            for r in range(n_rot):
                for j in range(big + 1):
                    for k in range(LANES):
                        row[j, k] = j * occ
                t = r
                for _ in range(n):
                    en = energy[t]
                    t += 1
                    if t == n:
                        t = 0
                    for k in range(LANES):
                        diag[k] = row[0, k]
                        row[0, k] = diag[k] + occ
                    for j in range(1, big + 1):
                        for k in range(LANES):  # vectorised over the references
                            v = diag[k] + en[j - 1, k]
                            up = row[j, k]
                            v = min(v, up + occ)
                            v = min(v, row[j - 1, k] + occ)
                            diag[k] = up
                            row[j, k] = v
                for k in range(LANES):
                    best[k] = min(best[k], row[lens[k], k])
            for k in range(LANES):
                out[q, blk * LANES + k] = best[k]
    return out
