"""Alignment costs: the :class:`CostModel` value and its presets."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InvalidParameterError, UnknownLetterError
from ..fingerprint import ALPHABET, HUE_LETTERS, WALL_LENGTH_EDGES_M, WALL_LETTERS

__all__ = ["CODE", "N_LETTERS", "CostModel"]

#: Number of letters in the fingerprint alphabet.
N_LETTERS = len(ALPHABET)
#: Integer code of each letter: its index in :data:`fingerloc.fingerprint.ALPHABET`.
CODE: dict[str, int] = {ch: i for i, ch in enumerate(ALPHABET)}

# Absolute tolerance when checking that a substitution matrix is symmetric.
_SYMMETRY_TOL = 1e-12


def _letter_code(letter: str, name: str) -> int:
    if not isinstance(letter, str) or len(letter) != 1:
        raise InvalidParameterError(f"{name}: expected one fingerprint letter, got {letter!r}")
    if letter not in CODE:
        raise UnknownLetterError(f"{name}: unknown fingerprint letter {letter!r} (alphabet: {ALPHABET})")
    return CODE[letter]


@dataclass(frozen=True, slots=True, eq=False, init=False)
class CostModel:
    """Costs of the edit operations of a fingerprint alignment.

    An alignment of strings ``a`` and ``b`` pairs letters in order; a pair of
    letters ``(x, y)`` costs ``substitution[x, y]`` (0 when ``x == y``), a
    letter left unpaired (an insertion or a deletion, "indel") costs
    ``indel[x]``. Immutable and hashable; two models are equal when their
    tables are.

    ``CostModel()`` is the unit model: match 0, substitution 1, insertion and
    deletion 1, so that the global alignment cost is the Levenshtein distance
    (the paper's "global alignment", docs/METHOD.md §4). :meth:`feature_aware` is a
    preset that knows which letters are alike.

    Parameters
    ----------
    substitution : float or array_like or mapping, optional
        Cost of pairing two different letters. A number gives every
        mismatch that cost (default 1). An array of shape ``(N_LETTERS, N_LETTERS)`` indexed
        by the letters' positions in :data:`~fingerloc.fingerprint.ALPHABET`
        gives the full table. A mapping ``{"xy": cost}`` overrides single
        pairs (both orders) on top of a mismatch cost of 1.
    indel : float or array_like or mapping, optional
        Cost of leaving a letter unpaired (default 1). A number, an array of
        shape ``(N_LETTERS,)``, or a mapping ``{letter: cost}`` overriding a default
        of 1.

    Raises
    ------
    InvalidParameterError
        If a cost is negative, not finite, a match cost is not 0, or the
        substitution table is not symmetric (the cost of ``a`` against ``b``
        must equal that of ``b`` against ``a``).
    UnknownLetterError
        If a mapping names a letter outside the alphabet.
    """

    substitution: NDArray[np.float64] = field()
    indel: NDArray[np.float64] = field()

    def __init__(
        self,
        substitution: float | ArrayLike | Mapping[str, float] | None = None,
        indel: float | ArrayLike | Mapping[str, float] | None = None,
    ) -> None:
        sub = _substitution_table(substitution)
        ind = _indel_table(indel)
        sub.setflags(write=False)
        ind.setflags(write=False)
        object.__setattr__(self, "substitution", sub)
        object.__setattr__(self, "indel", ind)

    # -- presets -------------------------------------------------------------
    @classmethod
    def unit(cls) -> CostModel:
        """Match 0, substitution 1, insertion and deletion 1 (Levenshtein)."""
        return cls()

    @classmethod
    def feature_aware(
        cls,
        *,
        hue_step: float = 0.25,
        f_partial: float = 0.5,
        n_indel: float = 0.5,
        wall_step: float = 0.5,
        mismatch: float = 1.0,
        indel: float = 1.0,
    ) -> CostModel:
        """Costs that know which letters are alike (our preset; the paper uses unit costs).

        * Two colour patches ``A``..``P`` cost ``min(mismatch, hue_step * d)``,
          ``d`` being the circular distance of their hue bins (0 to 8): with
          the defaults adjacent bins cost 0.25, two bins apart 0.5, three 0.75,
          four or more 1. A patch whose hue lies near a bin edge changes
          letter with the lighting; a far hue is another patch.
        * ``f`` (a corner and an edge at one bearing) against ``c`` or ``v``
          costs ``f_partial`` (0.5): when the corner and the edge drift
          further apart than the merge tolerance, or one of them is missed,
          ``f`` turns into ``c`` or ``v``; half of it still matches.
        * ``n`` (one per 20 deg of empty bearing) is inserted or deleted for
          ``n_indel`` (0.5): the count of ``n`` in a gap is a rounding of the
          gap's width (a 39 deg gap gives one, a 41 deg gap two), so an extra
          ``n`` is weaker evidence than an extra feature.
        * Two wall letters of the laser extension (``h``..``t``, see
          :mod:`fingerloc.fingerprint`) cost ``min(mismatch, wall_step * d)``,
          ``d`` the number of class steps between them (length steps plus
          range steps): a wall seen from a little further, or cut a little
          shorter by an occlusion, changes class; half of it still matches.
        * Every other pair of different letters costs ``mismatch`` (1) and
          every other letter is inserted or deleted for ``indel`` (1).

        Parameters
        ----------
        hue_step : float, default 0.25
            Cost per hue bin (22.5 deg) between two colour patches; ``>= 0``.
        f_partial : float, default 0.5
            Cost of ``f`` against ``c`` or ``v``; ``>= 0``.
        n_indel : float, default 0.5
            Insertion/deletion cost of ``n``; ``>= 0``.
        wall_step : float, default 0.5
            Cost per class step between two wall letters; ``>= 0``.
        mismatch : float, default 1
            Cost of any other pair of different letters; ``>= 0``.
        indel : float, default 1
            Insertion/deletion cost of any other letter; ``>= 0``.
        """
        for name, v in (
            ("hue_step", hue_step),
            ("f_partial", f_partial),
            ("n_indel", n_indel),
            ("wall_step", wall_step),
            ("mismatch", mismatch),
            ("indel", indel),
        ):
            _check_cost(name, v)
        sub = np.full((N_LETTERS, N_LETTERS), float(mismatch))
        k = len(HUE_LETTERS)
        for i, x in enumerate(HUE_LETTERS):
            for j, y in enumerate(HUE_LETTERS):
                d = min(abs(i - j), k - abs(i - j))
                sub[CODE[x], CODE[y]] = min(float(mismatch), hue_step * d)
        for y in "cv":
            sub[CODE["f"], CODE[y]] = sub[CODE[y], CODE["f"]] = f_partial
        ncol = len(WALL_LENGTH_EDGES_M) + 1
        for i, x in enumerate(WALL_LETTERS):
            for j, y in enumerate(WALL_LETTERS):
                d = abs(i // ncol - j // ncol) + abs(i % ncol - j % ncol)
                sub[CODE[x], CODE[y]] = min(float(mismatch), wall_step * d)
        np.fill_diagonal(sub, 0.0)
        ind = np.full(N_LETTERS, float(indel))
        ind[CODE["n"]] = n_indel
        return cls(sub, ind)

    # -- queries ---------------------------------------------------------------
    def cost(self, x: str, y: str) -> float:
        """Cost of pairing letter ``x`` with letter ``y``."""
        return float(self.substitution[_letter_code(x, "x"), _letter_code(y, "y")])

    def indel_cost(self, x: str) -> float:
        """Cost of inserting or deleting letter ``x``."""
        return float(self.indel[_letter_code(x, "x")])

    @property
    def is_unit(self) -> bool:
        """True when this is the unit (Levenshtein) model."""
        return bool(np.all(self.indel == 1.0) and np.all(self.substitution == _UNIT_SUB))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CostModel):
            return NotImplemented
        return bool(np.array_equal(self.substitution, other.substitution) and np.array_equal(self.indel, other.indel))

    def __hash__(self) -> int:
        return hash((self.substitution.tobytes(), self.indel.tobytes()))

    def __repr__(self) -> str:
        if self.is_unit:
            return "CostModel()"
        return f"CostModel(<{N_LETTERS}x{N_LETTERS} substitution>, indel={self.indel.tolist()!r})"


_UNIT_SUB = 1.0 - np.eye(N_LETTERS)


def _check_cost(name: str, v: object) -> float:
    try:
        x = float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InvalidParameterError(f"{name}: a cost must be a number, got {v!r}") from None
    if not math.isfinite(x) or x < 0:
        raise InvalidParameterError(f"{name}: costs must be finite and >= 0, got {v!r}")
    return x


def _substitution_table(spec: float | ArrayLike | Mapping[str, float] | None) -> NDArray[np.float64]:
    if spec is None:
        return _UNIT_SUB.copy()
    if isinstance(spec, Mapping):
        sub = _UNIT_SUB.copy()
        for pair, cost in spec.items():
            if not isinstance(pair, str) or len(pair) != 2:
                raise InvalidParameterError(f"substitution: keys must be two-letter strings like 'fc', got {pair!r}")
            i, j = _letter_code(pair[0], "substitution"), _letter_code(pair[1], "substitution")
            c = _check_cost(f"substitution[{pair!r}]", cost)
            if i == j and c != 0.0:
                raise InvalidParameterError(f"substitution[{pair!r}]: a match must cost 0, got {cost!r}")
            sub[i, j] = sub[j, i] = c
        return sub
    arr = np.asarray(spec, dtype=np.float64)
    if arr.ndim == 0:
        c = _check_cost("substitution", float(arr))
        sub = np.full((N_LETTERS, N_LETTERS), c)
        np.fill_diagonal(sub, 0.0)
        return sub
    if arr.shape != (N_LETTERS, N_LETTERS):
        raise InvalidParameterError(
            f"substitution: a table must have shape ({N_LETTERS}, {N_LETTERS}) (letters of {ALPHABET}), got {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise InvalidParameterError("substitution: costs must be finite")
    if np.any(arr < 0):
        i, j = np.argwhere(arr < 0)[0]
        raise InvalidParameterError(
            f"substitution: costs must be >= 0, got {arr[i, j]!r} for {ALPHABET[i]!r} against {ALPHABET[j]!r}"
        )
    if np.any(np.diag(arr) != 0):
        i = int(np.flatnonzero(np.diag(arr) != 0)[0])
        raise InvalidParameterError(
            f"substitution: a match must cost 0, got {arr[i, i]!r} for {ALPHABET[i]!r} against itself"
        )
    bad = np.abs(arr - arr.T) > _SYMMETRY_TOL
    if np.any(bad):
        i, j = np.argwhere(bad)[0]
        raise InvalidParameterError(
            "substitution: the table must be symmetric (alignment cost must not depend on argument order), "
            f"got {arr[i, j]!r} for {ALPHABET[i]!r}->{ALPHABET[j]!r} but {arr[j, i]!r} for {ALPHABET[j]!r}->{ALPHABET[i]!r}"
        )
    return np.array((arr + arr.T) / 2.0, dtype=np.float64)


def _indel_table(spec: float | ArrayLike | Mapping[str, float] | None) -> NDArray[np.float64]:
    if spec is None:
        return np.ones(N_LETTERS)
    if isinstance(spec, Mapping):
        ind = np.ones(N_LETTERS)
        for letter, cost in spec.items():
            ind[_letter_code(letter, "indel")] = _check_cost(f"indel[{letter!r}]", cost)
        return ind
    arr = np.asarray(spec, dtype=np.float64)
    if arr.ndim == 0:
        return np.full(N_LETTERS, _check_cost("indel", float(arr)))
    if arr.shape != (N_LETTERS,):
        raise InvalidParameterError(
            f"indel: a table must have shape ({N_LETTERS},) (letters of {ALPHABET}), got {arr.shape}"
        )
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise InvalidParameterError(f"indel: costs must be finite and >= 0, got {arr.tolist()!r}")
    return arr.copy()
