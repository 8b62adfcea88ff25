"""Fingerprints: circular strings of features around the robot (docs/METHOD.md §1-2).

A fingerprint lists the features an observation holds by increasing bearing,
one letter each, with ``n`` letters for empty space:

==========  ============================================================
letter      meaning
==========  ============================================================
``v``       vertical edge
``A``-``P`` colour patch, hue bin ``floor(hue / 22.5 deg)``, ``A`` = 0
``c``       corner
``b``       beacon
``f``       a corner and a vertical edge at (nearly) the same bearing
``n``       one per ``empty_step_deg`` (20 deg) of seen, empty bearing
==========  ============================================================

Extremities (``Ex``) enter the Bayesian program but never the paper's string.

Laser letters (our extension, ``laser_letters=True``; off by default). A 2D
laser alone gives few of the paper's letters (a corner now and then), so the
string says little. With the option on, two more kinds of laser feature
become letters, in the same bearing order:

* ``e``: an extremity (a line end next to a depth jump: door frames,
  furniture ends);
* a wall segment (observation feature type ``W``), one letter by its length
  class (short < 1 m, medium 1-3 m, long >= 3 m) and the range class of its
  midpoint (near < 1.5 m, mid 1.5-3 m, far 3-6 m, very far >= 6 m):

  ===========  =====  ======  ====
  range        short  medium  long
  ===========  =====  ======  ====
  near         ``h``  ``i``   ``j``
  mid          ``k``  ``l``   ``m``
  far          ``o``  ``p``   ``q``
  very far     ``r``  ``s``   ``t``
  ===========  =====  ======  ====

The class edges are indoor scales (a door or a desk, an office wall, a
corridor), fixed before any benchmark and not tuned per log.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .angles import TWO_PI, fov_pieces_deg, rad_to_deg360, wrap, wrap_deg360
from .errors import InvalidParameterError, UnknownLetterError
from .observation import Observation

__all__ = [
    "ALPHABET",
    "HUE_LETTERS",
    "PAPER_ALPHABET",
    "WALL_LETTERS",
    "Fingerprint",
    "hue_letter",
    "make_fingerprint",
    "parse_fingerprint",
    "wall_letter",
]

#: Colour-patch letters, hue bin 0 (``A``, hue 0-22.5 deg) to 15 (``P``).
HUE_LETTERS = "ABCDEFGHIJKLMNOP"
#: Laser extension: extremity letter.
EXTREMITY_LETTER = "e"
#: Laser extension: wall letters, row = range class, column = length class.
WALL_LETTERS = "hijklmopqrst"
#: Edges of the wall length classes, metres.
WALL_LENGTH_EDGES_M = (1.0, 3.0)
#: Edges of the wall range classes, metres.
WALL_RANGE_EDGES_M = (1.5, 3.0, 6.0)
#: Every letter a fingerprint may hold (the paper's 21, then the laser extension).
ALPHABET = "v" + HUE_LETTERS + "cbfn" + EXTREMITY_LETTER + WALL_LETTERS
#: The paper's letters.
PAPER_ALPHABET = "v" + HUE_LETTERS + "cbfn"
#: Hue bin width in degrees.
HUE_BIN_DEG = 22.5
#: Tolerance (degrees) when counting empty-space steps: a seen gap of exactly 40 deg gives two ``n``.
GAP_TOL_DEG = 1e-6

# Order of letters at one bearing (ties), so generation is deterministic.
_TIE_ORDER = {ch: i for i, ch in enumerate(ALPHABET)}


def _tie_ordered(feats: list[tuple[float, str]]) -> list[tuple[float, str]]:
    """Features by bearing (degrees, ``[0, 360)``); bearings within GAP_TOL_DEG of each other are a tie, in
    :data:`_TIE_ORDER`.

    A rotation of the view moves bearings by round-off: two features at one bearing (a merged ``f`` midway
    between a corner and an edge, and a beacon there) must keep their order whichever comes out a hair
    first, also when the tie straddles 0 (the features just below 360 then come first, 360 degrees lower).
    """
    feats = sorted(feats, key=lambda t: (t[0], _TIE_ORDER[t[1]]))
    groups: list[list[tuple[float, str]]] = []
    for f in feats:
        if groups and f[0] - groups[-1][-1][0] <= GAP_TOL_DEG:
            groups[-1].append(f)
        else:
            groups.append([f])
    if len(groups) > 1 and groups[0][0][0] + 360.0 - groups[-1][-1][0] <= GAP_TOL_DEG:
        groups[0] = [(b - 360.0, ch) for b, ch in groups.pop()] + groups[0]
    return [f for g in groups for f in sorted(g, key=lambda t: _TIE_ORDER[t[1]])]


def hue_letter(hue_deg: float) -> str:
    """The colour-patch letter of a hue in degrees, ``[0, 360)``."""
    h = float(hue_deg)
    if not (0.0 <= h < 360.0):
        raise InvalidParameterError(f"hue must be in [0, 360) degrees, got {hue_deg!r}")
    return HUE_LETTERS[min(int(h // HUE_BIN_DEG), len(HUE_LETTERS) - 1)]


def wall_letter(length_m: float, range_m: float) -> str:
    """The laser-extension letter of a wall segment of a length and midpoint range (metres)."""
    li = sum(length_m >= e for e in WALL_LENGTH_EDGES_M)
    ri = sum(range_m >= e for e in WALL_RANGE_EDGES_M)
    return WALL_LETTERS[ri * (len(WALL_LENGTH_EDGES_M) + 1) + li]


_ALPHABET_SET = frozenset(ALPHABET)


def _check_letters(letters: str) -> None:
    if _ALPHABET_SET.issuperset(letters):  # the common case, without a Python loop
        return
    for i, ch in enumerate(letters):
        if ch not in ALPHABET:
            raise UnknownLetterError(
                f"unknown fingerprint letter {ch!r} at position {i} of {letters!r} (alphabet: {ALPHABET})"
            )


@dataclass(frozen=True, slots=True, eq=False)
class Fingerprint:
    """A circular fingerprint string and the bearing of each letter.

    Parameters
    ----------
    letters : str
        Letters of :data:`ALPHABET`, in increasing bearing from the first
        feature at or after bearing 0.
    bearings : array_like of float, shape (len(letters),)
        Bearing of each letter in radians (wrapped to ``[-pi, pi)``). ``n``
        letters sit evenly inside the seen part of their gap.
    """

    letters: str
    bearings: NDArray[np.float64]

    def __post_init__(self) -> None:
        if not isinstance(self.letters, str):
            raise InvalidParameterError(f"letters: must be a string, got {type(self.letters).__name__}")
        _check_letters(self.letters)
        b = wrap(np.array(self.bearings, dtype=np.float64, copy=True).reshape(-1))
        if b.size != len(self.letters):
            raise InvalidParameterError(
                f"bearings: one bearing per letter is needed, got {b.size} for {len(self.letters)} letters"
            )
        if not np.all(np.isfinite(b)):
            raise InvalidParameterError("bearings: must be finite")
        b.setflags(write=False)
        object.__setattr__(self, "bearings", b)

    def __str__(self) -> str:
        return self.letters

    def __repr__(self) -> str:
        return f"Fingerprint({self.letters!r})"

    def __len__(self) -> int:
        return len(self.letters)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Fingerprint):
            return NotImplemented
        return self.letters == other.letters and np.allclose(self.bearings, other.bearings, atol=1e-12)

    __hash__ = None  # type: ignore[assignment]

    @property
    def bearings_deg(self) -> NDArray[np.float64]:
        """Bearing of each letter in degrees, ``[0, 360)``."""
        return rad_to_deg360(self.bearings)

    def rotate(self, k: int) -> Fingerprint:
        """The same circular string started at letter ``k`` (letters keep their bearings)."""
        n = len(self.letters)
        if n == 0:
            return self
        k %= n
        return Fingerprint(self.letters[k:] + self.letters[:k], np.roll(self.bearings, -k))

    def turned(self, angle: float) -> Fingerprint:
        """The fingerprint seen by a robot whose bearings all moved by ``angle`` radians.

        Bearings shift by ``angle`` and the string restarts at the first letter
        whose new bearing is at or after 0 degrees.
        """
        if not self.letters:
            return self
        deg = wrap_deg360(np.rad2deg(self.bearings + angle))
        k = int(np.argmin(deg))
        return Fingerprint(self.letters[k:] + self.letters[:k], np.roll(self.bearings + angle, -k))

    def to_dict(self) -> dict[str, object]:
        """JSON-ready form: the string and bearings in degrees."""
        return {"fingerprint": self.letters, "bearings_deg": [round(float(x), 6) for x in self.bearings_deg]}


def parse_fingerprint(text: str, bearings_deg: ArrayLike | None = None) -> Fingerprint:
    """Parse a fingerprint string.

    Parameters
    ----------
    text : str
        Letters of :data:`ALPHABET`; surrounding white space is ignored.
    bearings_deg : array_like of float, optional
        Bearing of each letter in degrees. When omitted the letters are
        spread evenly around the circle from 0 deg (a string alone does not
        carry its bearings).

    Raises
    ------
    UnknownLetterError
        On a letter outside the alphabet, naming it and its position.
    """
    letters = text.strip()
    _check_letters(letters)
    if bearings_deg is None:
        b = np.arange(len(letters), dtype=np.float64) * (TWO_PI / max(len(letters), 1))
    else:
        b = np.deg2rad(np.asarray(bearings_deg, dtype=np.float64))
    return Fingerprint(letters, b)


# -- field of view in degrees -----------------------------------------------


#: Disjoint, sorted ``[lo, hi)`` degree pieces of ``[0, 360)`` covered by a field of view (:func:`fingerloc.angles.fov_pieces_deg`).
_seen_pieces_deg = fov_pieces_deg


@functools.lru_cache(maxsize=64)
def _seen_pieces_cached(fov: tuple[tuple[float, float], ...]) -> tuple[list[tuple[float, float]], bool]:
    """:func:`_seen_pieces_deg` of a field of view (cached: observations share a few), and whether it is the full circle.

    Callers must not change the list.
    """
    pieces = _seen_pieces_deg(fov)
    return pieces, pieces == [(0.0, 360.0)]


def _seen_intervals(a: float, b: float, pieces: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Parts of ``[a, b]`` (degrees, ``0 <= a < 360``, ``a <= b <= a + 360``) inside the seen pieces."""
    out: list[tuple[float, float]] = []
    for shift in (0.0, 360.0):
        for lo, hi in pieces:
            lo2, hi2 = max(a, lo + shift), min(b, hi + shift)
            if hi2 > lo2:
                out.append((lo2, hi2))
    return out


def _place_empty(intervals: list[tuple[float, float]], count: int) -> list[float]:
    """Bearings (degrees) of ``count`` empty-space letters spread evenly over the seen intervals."""
    total = sum(hi - lo for lo, hi in intervals)
    out: list[float] = []
    for j in range(count):
        target = (j + 0.5) * total / count
        for lo, hi in intervals:
            if target <= hi - lo:
                out.append(lo + target)
                break
            target -= hi - lo
        else:  # round-off at the very end
            out.append(intervals[-1][1])
    return out


def _degrees(rad: NDArray[np.float64]) -> list[float]:
    """Bearings in radians to degrees in ``[0, 360)`` as Python floats (see :func:`wrap_deg360`)."""
    return [float(x) for x in wrap_deg360(np.rad2deg(rad))] if rad.size else []


#: Smallest ``empty_step_deg``: bounds a fingerprint to 3,600 ``n`` letters (memory and alignment time).
MIN_EMPTY_STEP_DEG = 0.1


def make_fingerprint(
    obs: Observation,
    *,
    empty_step_deg: float = 20.0,
    merge_tol_deg: float = 5.0,
    laser_letters: bool = False,
) -> Fingerprint:
    """Generate the fingerprint of an observation (docs/METHOD.md §2).

    1. Vertical edges give ``v``, colour patches their hue letter, corners
       ``c``, beacons ``b``; extremities give nothing.
    2. A corner and a vertical edge within ``merge_tol_deg`` of each other
       (closest pairs first, each feature used once; of two pairs equally
       close, the one whose edge is counter-clockwise of its corner) become one ``f`` at their
       circular mean bearing.
    3. Letters are listed by increasing bearing in ``[0, 360)`` deg, from the
       first at or after 0. After each letter, ``floor(s / empty_step_deg)``
       letters ``n`` follow, ``s`` being the part of the gap to the next letter
       (circularly; the wrap-around gap's ``n`` come last) that lies inside the
       field of view, computed in degrees with a tolerance of 1e-6 deg. With no
       feature at all the string is ``floor(seen / empty_step_deg)`` ``n``.

    Parameters
    ----------
    obs : Observation
    empty_step_deg : float, default 20
        Degrees of seen, empty bearing per ``n`` letter; positive.
    merge_tol_deg : float, default 5
        Largest corner-to-edge angle (degrees) merged into ``f``; ``>= 0``.
    laser_letters : bool, default False
        Also write extremities (``e``) and wall segments (their length/range
        letter) into the string: our extension for laser-only robots (module
        docstring). False gives exactly the paper's string.

    Returns
    -------
    Fingerprint
    """
    if not (math.isfinite(empty_step_deg) and empty_step_deg >= MIN_EMPTY_STEP_DEG):
        raise InvalidParameterError(
            f"empty_step_deg must be a number of degrees >= {MIN_EMPTY_STEP_DEG:g} "
            f"(at most {round(360 / MIN_EMPTY_STEP_DEG)} 'n' letters), got {empty_step_deg!r}"
        )
    if not (math.isfinite(merge_tol_deg) and merge_tol_deg >= 0):
        raise InvalidParameterError(f"merge_tol_deg must be >= 0 degrees, got {merge_tol_deg!r}")

    feats: list[tuple[float, str]] = []
    ve = _degrees(obs.ve)
    cs = _degrees(obs.c)
    # Step 2: merge corner/edge pairs, closest first.
    # Distances equal within GAP_TOL_DEG are a tie (a rotation of the view moves them by round-off);
    # a tie goes to the edge counter-clockwise of its corner, an order a rotation keeps.
    pairs = []
    for i, cb in enumerate(cs):
        for j, vb in enumerate(ve):
            signed = (vb - cb + 180.0) % 360.0 - 180.0
            d = abs(signed)
            if d <= merge_tol_deg + GAP_TOL_DEG:
                pairs.append((round(d / GAP_TOL_DEG), 0 if signed > 0 else 1, i, j))
    pairs.sort()
    used_c: set[int] = set()
    used_v: set[int] = set()
    for _, _, i, j in pairs:
        if i in used_c or j in used_v:
            continue
        used_c.add(i)
        used_v.add(j)
        mid = cs[i] + ((ve[j] - cs[i] + 180.0) % 360.0 - 180.0) / 2.0
        feats.append((float(wrap_deg360(mid)), "f"))
    feats += [(v, "v") for j, v in enumerate(ve) if j not in used_v]
    feats += [(c, "c") for i, c in enumerate(cs) if i not in used_c]
    feats += [(x, hue_letter(h)) for x, h in zip(_degrees(obs.cp), obs.cp_hue.tolist(), strict=True)]
    feats += [(x, "b") for x in _degrees(obs.b)]
    if laser_letters:
        feats += [(x, EXTREMITY_LETTER) for x in _degrees(obs.ex)]
        feats += [
            (x, wall_letter(ln, r))
            for x, ln, r in zip(_degrees(obs.w), obs.w_length.tolist(), obs.w_range.tolist(), strict=True)
        ]
    feats = _tie_ordered(feats)

    pieces, full = _seen_pieces_cached(obs.fov)

    def empty_space(a: float, b: float) -> list[float]:
        # bearings (deg) of the n letters of the gap [a, b]
        if full:  # _place_empty([(a, b)], count) without the loop over intervals: the same floats
            width = b - a
            count = math.floor((width + GAP_TOL_DEG) / empty_step_deg)
            return [a + t if t <= width else b for t in [(j + 0.5) * width / count for j in range(count)]]
        intervals = _seen_intervals(a, b, pieces)
        seen = sum(hi - lo for lo, hi in intervals)
        return _place_empty(intervals, math.floor((seen + GAP_TOL_DEG) / empty_step_deg))

    letters: list[str] = []
    bearings: list[float] = []
    if not feats:
        bearings = empty_space(0.0, 360.0)
        letters = ["n"] * len(bearings)
    for k, (bearing, letter) in enumerate(feats):
        nxt = feats[k + 1][0] if k + 1 < len(feats) else feats[0][0] + 360.0
        empty = empty_space(bearing, nxt)
        letters += [letter] + ["n"] * len(empty)
        bearings += [bearing, *empty]
    return Fingerprint("".join(letters), np.deg2rad(np.asarray(bearings, dtype=np.float64)))
