"""Turning strings and fingerprints into letter codes for the kernels."""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence

import numpy as np
from numpy.typing import NDArray

from ..errors import InvalidParameterError, UnknownLetterError
from ..fingerprint import ALPHABET, Fingerprint

__all__ = ["FingerprintBatch", "FingerprintLike", "as_letters", "encode", "encode_many", "letters_many"]

FingerprintLike = str | Fingerprint

_BAD = re.compile(f"[^{re.escape(ALPHABET)}]")
_ALPHABET_BYTES = ALPHABET.encode("ascii")
_LUT = np.full(256, 255, dtype=np.uint8)
for _i, _ch in enumerate(ALPHABET):
    _LUT[ord(_ch)] = _i


def _unknown(s: str, name: str) -> UnknownLetterError:
    m = _BAD.search(s)
    pos = -1 if m is None else m.start()
    ch = "" if m is None else m.group()
    return UnknownLetterError(
        f"{name}: unknown fingerprint letter {ch!r} at position {pos} of {s!r} (alphabet: {ALPHABET})"
    )


def _all_in_alphabet(s: str) -> bool:
    try:
        raw = s.encode("ascii")
    except UnicodeEncodeError:
        return False
    return not raw.translate(None, _ALPHABET_BYTES)


def as_letters(x: object, name: str) -> tuple[str, NDArray[np.float64] | None]:
    """Letters of ``x`` (validated) and its bearings (radians) when ``x`` is a :class:`Fingerprint`."""
    if isinstance(x, Fingerprint):
        return x.letters, x.bearings
    if isinstance(x, str):
        if not _all_in_alphabet(x):
            raise _unknown(x, name)
        return x, None
    raise InvalidParameterError(f"{name}: expected a fingerprint string or Fingerprint, got {type(x).__name__}")


def encode(s: str) -> NDArray[np.uint8]:
    """Letter codes (positions in the alphabet) of an already validated string, shape ``(len(s),)``."""
    return _LUT[np.frombuffer(s.encode("ascii"), dtype=np.uint8)]


class FingerprintBatch:
    """A batch of fingerprints validated once, for repeated batch calls.

    Pass it as ``queries`` or ``references`` of
    :func:`~fingerloc.align.alignment_costs` (or the minimum-energy batch) to
    skip the per-call conversion and validation of every string: a place
    database of 8,000 stored fingerprints costs milliseconds to re-validate
    on every query otherwise.

    Parameters
    ----------
    items : sequence of (str or Fingerprint)

    Attributes
    ----------
    letters : list of str
        The validated letters of each item.
    bearings : list of (ndarray of float64 or None)
        Each item's bearings in radians (``None`` for a plain string), for
        the minimum-energy matcher.
    """

    __slots__ = ("_packed", "bearings", "letters")

    def __init__(self, items: object) -> None:
        seq = list(items) if isinstance(items, Iterable) and not isinstance(items, (str, Fingerprint)) else [items]
        self.letters: list[str] = letters_many(seq, "items")
        self.bearings: list[NDArray[np.float64] | None] = [
            x.bearings if isinstance(x, Fingerprint) else None for x in seq
        ]
        # The references packed for a kernel, by the kernel's cost tables (see fingerloc.align.alignment_costs):
        # at most one entry, so a batch holds at most one packed copy. A batch is not meant to change; its
        # owner makes a new one when its references change (FingerprintTerm does when places are added).
        self._packed: dict[object, object] = {}

    def __len__(self) -> int:
        return len(self.letters)

    def __getstate__(self) -> dict[str, object]:
        # the packed form is left out of pickles (megabytes, and page alignment does not survive a copy)
        return {"letters": self.letters, "bearings": self.bearings}

    def __setstate__(self, state: object) -> None:
        if isinstance(state, tuple):  # pickled before __getstate__ existed: (None, slots)
            state = state[1]
        assert isinstance(state, dict)
        self.letters = state["letters"]
        self.bearings = state["bearings"]
        self._packed = {}


def letters_many(xs: object, name: str) -> list[str]:
    """Validated letters of a batch: a sequence of strings/fingerprints, or one of them alone."""
    if isinstance(xs, FingerprintBatch):
        return xs.letters
    if isinstance(xs, (str, Fingerprint)):
        items: Sequence[object] = [xs]
    elif isinstance(xs, Iterable):
        items = list(xs)
    else:
        raise InvalidParameterError(f"{name}: expected a sequence of fingerprint strings, got {type(xs).__name__}")
    out: list[str] = []
    for x in items:
        if isinstance(x, str):
            out.append(x)
        elif isinstance(x, Fingerprint):
            out.append(x.letters)
        else:
            raise InvalidParameterError(f"{name}: expected fingerprint strings or Fingerprints, got {type(x).__name__}")
    # One C-speed scan of everything; locate the culprit only on failure.
    if not _all_in_alphabet("".join(out)):
        for k, s in enumerate(out):
            if _BAD.search(s) is not None:
                raise _unknown(s, f"{name}[{k}]")
    return out


def encode_many(strs: Sequence[str]) -> tuple[NDArray[np.uint8], NDArray[np.int64]]:
    """Concatenated codes and offsets (``codes[off[k]:off[k+1]]`` is string ``k``) of validated strings."""
    lens = np.fromiter((len(s) for s in strs), dtype=np.int64, count=len(strs))
    off = np.zeros(len(strs) + 1, dtype=np.int64)
    np.cumsum(lens, out=off[1:])
    codes = encode("".join(strs)) if strs else np.zeros(0, dtype=np.uint8)
    return codes, off
