# mypy: disable-error-code="no-untyped-def"
"""``numpy.random.default_rng(seed).random(n)`` inside compiled code (private).

:meth:`fingerloc.mog.AngularMixture.fit` with an int ``random_state`` needs a
handful of uniforms from ``default_rng(seed)``; building that Generator costs
more than a quarter of a small fit. These kernels compute the very same
numbers, bit for bit, from numpy's published algorithms:

* :class:`numpy.random.SeedSequence` with the default pool of four 32-bit
  words (its ``hashmix``/``mix`` construction) turns the seed into the words
  of ``generate_state(4, np.uint64)``;
* :class:`numpy.random.PCG64` is seeded from them (the 128-bit state and
  increment, two steps of the LCG) and steps its 128-bit LCG, output
  XSL-RR, with 64-bit halves here;
* ``Generator.random`` takes the top 53 bits of each 64-bit output.

Only seeds ``0 <= seed < 2**63`` are handled (two entropy words). numpy
keeps these streams stable across versions, and :mod:`fingerloc.mog` checks
once per process that the numbers equal numpy's before using them.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_U = np.uint64
_M32 = _U(0xFFFFFFFF)
_INIT_A = _U(0x43B0D7E5)
_MULT_A = _U(0x931E8875)
_INIT_B = _U(0x8B51F9DD)
_MULT_B = _U(0x58F38DED)
_MIX_L = _U(0xCA01F9DD)
_MIX_R = _U(0x4973F715)
_S16 = _U(16)
_S32 = _U(32)
# PCG's default 128-bit multiplier, high and low words
_PCG_MUL_HI = _U(2549297995355413924)
_PCG_MUL_LO = _U(4865540595714422341)
_TO_UNIT = 1.0 / 9007199254740992.0  # 2^-53


@njit(cache=True, inline="always")
def _hashmix(value, hc):  # pragma: no cover - compiled
    """SeedSequence's hashmix on 32-bit words held in uint64: returns (mixed value, next hash constant)."""
    value = (value ^ hc) & _M32
    hc = (hc * _MULT_A) & _M32
    value = (value * hc) & _M32
    value ^= value >> _S16
    return value, hc


@njit(cache=True, inline="always")
def _mix(x, y):  # pragma: no cover - compiled
    r = (_MIX_L * x - _MIX_R * y) & _M32
    return r ^ (r >> _S16)


@njit(cache=True, inline="always")
def _mulhi(a, b):  # pragma: no cover - compiled
    """High 64 bits of the 128-bit product of two uint64."""
    a0 = a & _M32
    a1 = a >> _S32
    b0 = b & _M32
    b1 = b >> _S32
    p00 = a0 * b0
    p01 = a0 * b1
    p10 = a1 * b0
    mid = (p00 >> _S32) + (p01 & _M32) + (p10 & _M32)
    return a1 * b1 + (p01 >> _S32) + (p10 >> _S32) + (mid >> _S32)


@njit(cache=True, inline="always")
def _step(sh, sl, ih, il):  # pragma: no cover - compiled
    """One PCG LCG step: (state * multiplier + increment) mod 2^128, in (high, low) words."""
    hi = _mulhi(sl, _PCG_MUL_LO) + sl * _PCG_MUL_HI + sh * _PCG_MUL_LO
    lo = sl * _PCG_MUL_LO
    lo2 = lo + il
    hi = hi + ih + (_U(1) if lo2 < lo else _U(0))
    return hi, lo2


@njit(cache=True)
def default_rng_random(seed, out):  # pragma: no cover - compiled
    """Fill the C-contiguous float64 array ``out`` as ``np.random.default_rng(seed).random(out.shape)`` does.

    ``seed`` is an int in ``[0, 2**63)``.
    """
    s = _U(seed)
    entropy = (s & _M32, s >> _S32, _U(0), _U(0))
    pool = np.empty(4, dtype=np.uint64)
    hc = _INIT_A
    for i in range(4):
        pool[i], hc = _hashmix(entropy[i], hc)
    for i_src in range(4):
        for i_dst in range(4):
            if i_src != i_dst:
                h, hc = _hashmix(pool[i_src], hc)
                pool[i_dst] = _mix(pool[i_dst], h)
    # generate_state(4, uint64): eight 32-bit words, paired little-endian
    words = np.empty(4, dtype=np.uint64)
    hb = _INIT_B
    for i in range(4):
        pair = _U(0)
        for half in range(2):
            v = pool[(2 * i + half) % 4] ^ hb
            hb = (hb * _MULT_B) & _M32
            v = (v * hb) & _M32
            v ^= v >> _S16
            pair |= v << _U(32 * half)
        words[i] = pair
    # PCG64 seeding: state = words[0:2], sequence = words[2:4] (high word first)
    ih = (words[2] << _U(1)) | (words[3] >> _U(63))
    il = (words[3] << _U(1)) | _U(1)
    sh, sl = _step(_U(0), _U(0), ih, il)
    sl2 = sl + words[1]
    sh = sh + words[0] + (_U(1) if sl2 < sl else _U(0))
    sh, sl = _step(sh, sl2, ih, il)
    flat = out.reshape(out.size)
    for i in range(flat.shape[0]):
        sh, sl = _step(sh, sl, ih, il)
        v = sh ^ sl
        rot = sh >> _U(58)
        v = (v >> rot) | (v << ((_U(64) - rot) & _U(63)))
        flat[i] = np.float64(v >> _U(11)) * _TO_UNIT
