# mypy: disable-error-code="no-untyped-def"
"""numba kernels behind :mod:`fingerloc.mog` (private).

Everything here works on bearings already wrapped to ``[-pi, pi)`` and on
parameters already validated by :mod:`fingerloc.mog`; nothing here checks
its input. The formulas are those of docs/METHOD.md §3:

    log p(x | mu, s) = -distAS(mu, x)^2 / (2 s^2) - log( sqrt(2 pi) s erf(pi / (sqrt(2) s)) )

Array layout: responsibilities and distances are ``(K, n)`` (component
major) so the M-step reads them contiguously.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange, types
from numba.extending import intrinsic

from ._seed_kernels import default_rng_random

_PI = math.pi
_TWO_PI = 2.0 * math.pi
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_SQRT2 = math.sqrt(2.0)

#: A component whose responsibilities sum to less than this many points dies
#: (weight 0 for good): its mean and sigma would be 0/0.
DEAD_MASS = 1e-10
#: A responsibility term below exp(-_SKIP) ~ 4e-18 of the largest is 0: adding
#: it to a sum >= 1 cannot change that sum in double precision.
_SKIP = 40.0

# _exp_neg: exp(t) on [-_SKIP, 0] without a library call, so that the E-step's loops vectorise
_INV_LN2 = 1.0 / math.log(2.0)
#: ln 2 with the low 21 bits of its significand cleared (0x3fe62e42fee00000): k * _LN2_HI is exact for |k| < 2^21.
_LN2_HI = 0.6931471803691238
#: ln 2 - _LN2_HI, from ln 2 to 60 decimal digits (``decimal.Decimal(2).ln()``).
_LN2_LO = 1.9082149292705877e-10
#: 1.5 * 2^52: ``(y + _ROUND) - _ROUND`` is y rounded to the nearest integer (|y| < 2^51).
_ROUND = 6755399441055744.0
# exp on |r| <= 0.347 (> ln 2 / 2) by a polynomial of degree 11: exp's Taylor polynomial of degree 14 with its
# terms of degree 14, 13 and 12 traded for their Chebyshev approximations ("economisation", done in exact
# rationals: tests/test_mog_seeding.py re-derives these constants), then rounded to float64. Error below 3.2e-18
# (0.03 units in the last place), against 4e-18 for the Taylor polynomial of degree 13 used before, in two
# fused multiply-adds fewer. The constant and linear coefficients round to exactly 1.
_E2 = 0.5000000000000019
_E3 = 0.16666666666666702
_E4 = 0.041666666666486316
_E5 = 0.008333333333309335
_E6 = 0.0013888888952787917
_E7 = 0.0001984126990960452
_E8 = 2.4801484976906916e-05
_E9 = 2.7557224637093587e-06
_E10 = 2.763282629384276e-07
_E11 = 2.5114952121245525e-08


@njit(cache=True)
def _dist(a: float, b: float) -> float:  # pragma: no cover - compiled
    """distAS(a, b) for a, b in [-pi, pi): the signed shortest way, in (-pi, pi]."""
    d = b - a
    if d > _PI:
        d -= _TWO_PI
    elif d <= -_PI:
        d += _TWO_PI
    return d


@njit(cache=True)
def _wrap1(a: float) -> float:  # pragma: no cover - compiled
    """Wrap one angle to [-pi, pi), folding the float edge that lands on pi."""
    y = a
    while y >= _PI:
        y -= _TWO_PI
    while y < -_PI:
        y += _TWO_PI
    if y >= _PI:
        y = -_PI
    return y


@njit(cache=True)
def _log_norm(s: float) -> float:  # pragma: no cover - compiled
    """log eta = -log( sqrt(2 pi) s erf(pi / (sqrt(2) s)) )."""
    z = _PI / (_SQRT2 * s)
    # erf(z) rounds to exactly 1.0 from z = 6 on (1 - erf(6) = 2e-17 < 2^-54), and log(1.0) is +0.0: skip both calls
    return -(_LOG_SQRT_2PI + math.log(s) + (0.0 if z >= 6.0 else math.log(math.erf(z))))


@njit(cache=True, inline="always")
def _exp_poly(t: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """(p, k) with exp(t) = p 2^k, k the nearest integer to t / ln 2, p = exp(t - k ln 2) in [0.7, 1.42] (see :func:`_exp_neg`)."""
    kf = (t * _INV_LN2 + _ROUND) - _ROUND
    r = (t - kf * _LN2_HI) - kf * _LN2_LO
    p = _E11 * r + _E10
    p = p * r + _E9
    p = p * r + _E8
    p = p * r + _E7
    p = p * r + _E6
    p = p * r + _E5
    p = p * r + _E4
    p = p * r + _E3
    p = p * r + _E2
    p = p * r + 1.0
    p = p * r + 1.0
    return p, kf


@njit(cache=True, inline="always")
def _exp_neg(t: float) -> float:  # pragma: no cover - compiled
    """exp(t) for t in [-_SKIP, 0], within one unit in the last place of the correctly rounded value.

    Branch-free so a loop of it vectorises (the C library's ``exp`` is a call
    per value): t = k ln 2 + r with k the nearest integer to t / ln 2 (ln 2
    split in two for an exact reduction), a polynomial of degree 11 for
    exp(r) on |r| <= ln 2 / 2 (see the constants ``_E2``...), then the factor 2^k, k in [-58, 0], as one exact
    power-of-two product per bit of -k. Compiled with fused multiply-adds, as
    in :func:`_e_step`: equal to the C library's ``exp`` for 94 % of
    arguments and one ulp away for the rest (tests/test_mog.py).
    """
    p, kf = _exp_poly(t)
    m = -kf
    b = m >= 32.0
    p = p * (2.0**-32 if b else 1.0)
    m = m - 32.0 if b else m
    b = m >= 16.0
    p = p * (2.0**-16 if b else 1.0)
    m = m - 16.0 if b else m
    b = m >= 8.0
    p = p * (2.0**-8 if b else 1.0)
    m = m - 8.0 if b else m
    b = m >= 4.0
    p = p * (2.0**-4 if b else 1.0)
    m = m - 4.0 if b else m
    b = m >= 2.0
    p = p * (2.0**-2 if b else 1.0)
    m = m - 2.0 if b else m
    return p * (0.5 if m >= 1.0 else 1.0)


@intrinsic
def _bits_to_float(typingctx, b):  # pragma: no cover - compiled
    """The float64 whose IEEE bits are the int64 ``b`` (a register bitcast: free, and vectorisable)."""
    if b != types.int64:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.float64))

    return types.float64(types.int64), codegen


@njit(cache=True, fastmath={"contract"})
def _e_terms(x, k, w, mu, sg, d, r, mx, ssum):  # pragma: no cover
    """The E-step up to the normalisation: distances ``d`` = distAS(mu_j, x_i) (K, n) and terms ``r`` (K, n).

    Leaves in ``r`` the unnormalised terms (the largest of each point exactly
    1), in ``ssum`` the reciprocals of their sums, and returns the mean
    log-likelihood; rows of dead components (weight 0) are set to 0 in ``r``
    and ``d``. ``mx`` and ``ssum`` are (n,) scratch. Every loop runs
    component-major and branch-free, so the compiler vectorises all of them
    but the log-likelihood product. The exponentials are those of
    :func:`_exp_neg` (its polynomial on fused multiply-adds: ``fastmath`` is
    ``contract`` only), the factor 2^k made from its bits. A term below
    ``exp(-_SKIP)`` times the largest one is taken as 0 (it could not change
    the sum in double precision).
    """
    n = d.shape[1]
    first = True  # the first live component sets mx and ssum (the same values as max / sum from -inf / 0)
    for j in range(k):
        if w[j] > 0.0:
            cj = math.log(w[j]) + _log_norm(sg[j])
            invj = 0.5 / (sg[j] * sg[j])
            muj = mu[j]
            if first:
                for i in range(n):
                    dj = x[i] - muj
                    dj = dj - _TWO_PI if dj > _PI else dj
                    dj = dj + _TWO_PI if dj <= -_PI else dj
                    d[j, i] = dj
                    a = cj - dj * dj * invj
                    r[j, i] = a
                    mx[i] = a
            else:
                for i in range(n):
                    dj = x[i] - muj
                    dj = dj - _TWO_PI if dj > _PI else dj
                    dj = dj + _TWO_PI if dj <= -_PI else dj
                    d[j, i] = dj
                    a = cj - dj * dj * invj
                    r[j, i] = a
                    mx[i] = a if a > mx[i] else mx[i]
            first = False
    # exp(t) = p 2^k as in _exp_neg, the factor 2^k (k in [-58, 0]) made from its bits: an exact power of
    # two either way, so the same values in fewer instructions. At t = 0 (the largest term) p = 1 and k = 0.
    first = True
    for j in range(k):
        if w[j] > 0.0:
            for i in range(n):
                t = r[j, i] - mx[i]
                p, kf = _exp_poly(t if t > -_SKIP else -_SKIP)
                e = p * _bits_to_float((np.int64(kf) + 1023) << 52)  # type: ignore[call-arg]  # numba intrinsic
                e = e if t > -_SKIP else 0.0
                r[j, i] = e
                ssum[i] = e if first else ssum[i] + e
            first = False
        else:
            for i in range(n):
                r[j, i] = 0.0
                d[j, i] = 0.0
    # log-likelihood: sum_i (mx_i + log s_i) with s_i = ssum_i in [1, K]; one log per many points
    total = _sum(mx)
    p0 = 1.0
    p1 = 1.0
    p2 = 1.0
    p3 = 1.0
    n4 = n - n % 4
    for i in range(0, n4, 4):  # four independent products: a quarter of the latency of one
        p0 *= ssum[i]
        p1 *= ssum[i + 1]
        p2 *= ssum[i + 2]
        p3 *= ssum[i + 3]
        if p0 > 1e70 or p1 > 1e70 or p2 > 1e70 or p3 > 1e70:
            total += math.log((p0 * p1) * (p2 * p3))
            p0 = 1.0
            p1 = 1.0
            p2 = 1.0
            p3 = 1.0
    for i in range(n4, n):
        p0 *= ssum[i]
    for i in range(n):
        ssum[i] = 1.0 / ssum[i]
    return (total + math.log((p0 * p1) * (p2 * p3))) / n


@njit(cache=True)
def _e_step(x, k, w, mu, sg, d, r, mx, ssum, bits):  # pragma: no cover
    """Responsibilities r (K, n), distances d = distAS(mu_j, x_i) (K, n); returns the mean log-likelihood.

    :func:`_e_terms`, then each term times the reciprocal of its point's sum (``ssum`` ends as those reciprocals).
    ``bits`` (n,) int64 is no longer used (the factors 2^k are made in
    registers); it stays in the signature for existing callers.
    """
    n = x.shape[0]
    ll = _e_terms(x, k, w, mu, sg, d, r, mx, ssum)
    for j in range(k):
        if w[j] > 0.0:
            for i in range(n):
                r[j, i] *= ssum[i]
    return ll


@njit(cache=True, fastmath={"reassoc"})
def _sum(a):  # pragma: no cover
    """sum_i a_i in any order (vectorised)."""
    t = 0.0
    for i in range(a.shape[0]):
        t += a[i]
    return t


@njit(cache=True, fastmath={"reassoc"})
def _resp_sums(k, w, r, inv, d, nk, sd):  # pragma: no cover
    """For each live component: r_j *= inv (the responsibilities), nk_j = sum_i r_ji, sd_j = sum_i r_ji d_ji (vectorised)."""
    n = inv.shape[0]
    for j in range(k):
        if w[j] > 0.0:
            a = 0.0
            b = 0.0
            for i in range(n):
                e = r[j, i] * inv[i]
                r[j, i] = e
                a += e
                b += e * d[j, i]
            nk[j] = a
            sd[j] = b


@njit(cache=True, fastmath={"reassoc"})
def _sq_dist_sums(k, w, r, x, m, s2):  # pragma: no cover
    """For each live component: s2_j = sum_i r_ji distAS(m_j, x_i)^2 in any order (vectorised).

    distAS as two selects: as fast as the E-step's; written as products by
    booleans (``e - 2 pi (e > pi)``) this loop took 8 % more of the whole fit.
    """
    n = x.shape[0]
    for j in range(k):
        if w[j] > 0.0:
            a = 0.0
            mj = m[j]
            for i in range(n):
                e = x[i] - mj
                e = e - _TWO_PI if e > _PI else e
                e = e + _TWO_PI if e <= -_PI else e
                a += r[j, i] * e * e
            s2[j] = a


@njit(cache=True, fastmath={"reassoc"})
def _sums(rj, dj):  # pragma: no cover
    """(sum_i rj_i, sum_i rj_i dj_i), in any order (vectorised)."""
    a = 0.0
    b = 0.0
    for i in range(rj.shape[0]):
        a += rj[i]
        b += rj[i] * dj[i]
    return a, b


@njit(cache=True, fastmath={"reassoc"})
def _sum_sq_dist(rj, x, m):  # pragma: no cover
    """sum_i rj_i distAS(m, x_i)^2, in any order (vectorised; distAS branch-free)."""
    a = 0.0
    for i in range(x.shape[0]):
        e = x[i] - m
        e = e - _TWO_PI if e > _PI else e  # _dist(m, x_i), as selects (no branches)
        e = e + _TWO_PI if e <= -_PI else e
        a += rj[i] * e * e
    return a


@njit(cache=True)
def _m_step(x, k, w, mu, sg, d, r, min_sigma):  # pragma: no cover
    """docs/METHOD.md §3 (paper eqs. 9-11) in place, from r and d = distAS(mu_old, x)."""
    n = x.shape[0]
    wsum = 0.0
    for j in range(k):
        if w[j] <= 0.0:
            continue
        nk, sd = _sums(r[j], d[j])
        if nk < DEAD_MASS:
            w[j] = 0.0
            continue
        # mu_k = wrap(mu_k + sum_i r_ik distAS(mu_k, x_i) / sum_i r_ik)
        m = _wrap1(mu[j] + sd / nk)
        # sigma_k = sqrt(sum_i r_ik distAS(mu_k_new, x_i)^2 / sum_i r_ik), floored
        s = math.sqrt(_sum_sq_dist(r[j], x, m) / nk)
        if s < min_sigma:
            s = min_sigma
        w[j] = nk / n  # w_k = (1/N) sum_i r_ik
        mu[j] = m
        sg[j] = s
        wsum += w[j]
    for j in range(k):
        w[j] /= wsum


@njit(cache=True)
def _kmeanspp(x, kmax, u, centers, dmin):  # pragma: no cover
    """k-means++ seeding with the circular distance; returns how many centres it found.

    The first centre is the point at ``floor(u[0] n)``; each next one is drawn
    with probability proportional to the squared circular distance to the
    nearest centre so far, using the uniform ``u[k]``. When every point lies
    on a centre (fewer distinct bearings than ``kmax``) it stops early.
    """
    n = x.shape[0]
    i0 = int(u[0] * n)
    if i0 >= n:
        i0 = n - 1
    centers[0] = x[i0]
    for i in range(n):
        e = _dist(centers[0], x[i])
        dmin[i] = e * e
    k = 1
    while k < kmax:
        tot = 0.0
        last = -1
        for i in range(n):
            tot += dmin[i]
            if dmin[i] > 0.0:
                last = i
        if last < 0:
            break
        target = u[k] * tot
        acc = 0.0
        pick = last
        for i in range(n):
            acc += dmin[i]
            if acc > target and dmin[i] > 0.0:
                pick = i
                break
        centers[k] = x[pick]
        for i in range(n):
            e = _dist(centers[k], x[i])
            e2 = e * e
            if e2 < dmin[i]:
                dmin[i] = e2
        k += 1
    return k


@njit(cache=True)
def _init_params(x, kmax, u, min_sigma, w, mu, sg, d, r, dmin):  # pragma: no cover
    """k-means++ centres, hard assignment to the nearest one, then one M-step."""
    n = x.shape[0]
    centers = np.empty(kmax)
    k = _kmeanspp(x, kmax, u, centers, dmin)
    for j in range(kmax):
        if j < k:
            w[j] = 1.0
            mu[j] = centers[j]
            sg[j] = 1.0
        else:  # padding: never used
            w[j] = 0.0
            mu[j] = 0.0
            sg[j] = 1.0
    # each point to its nearest centre (the first one on ties), component by component so the loops vectorise
    best = np.zeros(n, dtype=np.int64)
    for j in range(k):
        cj = centers[j]
        for i in range(n):
            e = x[i] - cj  # _dist(cj, x_i)
            e = e - _TWO_PI if e > _PI else e
            e = e + _TWO_PI if e <= -_PI else e
            d[j, i] = e
            ae = abs(e)
            closer = j == 0 or ae < dmin[i]
            dmin[i] = ae if closer else dmin[i]
            best[i] = j if closer else best[i]
    for j in range(k):
        for i in range(n):
            r[j, i] = 1.0 if best[i] == j else 0.0
    _m_step(x, k, w, mu, sg, d, r, min_sigma)
    return k


@njit(cache=True)
def _em(x, k, w, mu, sg, tol, max_iter, min_sigma, d, r, mx, ssum, trace):  # pragma: no cover
    """EM from the given parameters, in place. Returns (mean log-lik, converged, n_iter).

    Stops when the gain in mean log-likelihood is below ``tol``. A step that
    lowers it (possible only through round-off or for components so wide that
    the truncation at +-pi matters, which the paper's sigma update ignores) is
    undone: the parameters returned are never worse than any earlier iterate.
    ``trace`` (length max_iter + 1, or empty) receives the raw log-likelihoods.

    Each iteration is :func:`_m_step` then :func:`_e_step`, with one pass over
    the points fewer: the E-step's normalisation also sums the
    responsibilities and their weighted distances (the next M-step's weights
    and means, :func:`_resp_sums`), and each sum over the points runs for all
    components in one call. (Storing the distances to the new means in the
    sigma pass, for the next E-step to read, was slower than computing them
    twice.)
    """
    n = x.shape[0]
    wb = np.empty(k)
    mub = np.empty(k)
    sgb = np.empty(k)
    nk = np.empty(k)
    sd = np.empty(k)
    s2 = np.empty(k)
    ll = _e_terms(x, k, w, mu, sg, d, r, mx, ssum)
    rec = trace.shape[0] > 0
    if rec:
        trace[0] = ll
    converged = False
    it = 0
    while it < max_iter:
        # the E-step's normalisation, with the sums of the M-step
        _resp_sums(k, w, r, ssum, d, nk, sd)
        for j in range(k):
            wb[j] = w[j]
            mub[j] = mu[j]
            sgb[j] = sg[j]
        # M-step (docs/METHOD.md §3, paper eqs. 9-11), as _m_step
        for j in range(k):
            if w[j] > 0.0:
                if nk[j] < DEAD_MASS:
                    w[j] = 0.0
                else:
                    mu[j] = _wrap1(mu[j] + sd[j] / nk[j])
        _sq_dist_sums(k, w, r, x, mu, s2)
        wsum = 0.0
        for j in range(k):
            if w[j] > 0.0:
                s = math.sqrt(s2[j] / nk[j])
                if s < min_sigma:
                    s = min_sigma
                w[j] = nk[j] / n
                sg[j] = s
                wsum += w[j]
        for j in range(k):
            w[j] /= wsum
        it += 1
        ll_new = _e_terms(x, k, w, mu, sg, d, r, mx, ssum)
        if rec:
            trace[it] = ll_new
        gain = ll_new - ll
        if gain < 0.0:
            for j in range(k):
                w[j] = wb[j]
                mu[j] = mub[j]
                sg[j] = sgb[j]
            converged = True
            break
        ll = ll_new
        if gain < tol:
            converged = True
            break
    return ll, converged, it


@njit(cache=True)
def _fit_one(xs, kmax, u_m, tol, max_iter, min_sigma, w_out, mu_out, sg_out, trace_m):  # pragma: no cover
    """Best of ``u_m.shape[0]`` starts on one sample; writes w/mu/sg_out (kmax,), returns (conv, n_iter, ll)."""
    n = xs.shape[0]
    w = np.empty(kmax)
    mu = np.empty(kmax)
    sg = np.empty(kmax)
    d = np.empty((kmax, n))
    r = np.empty((kmax, n))
    scratch = np.empty(n)
    ssum = np.empty(n)
    empty = np.empty(0)
    rec = trace_m.shape[0] > 0
    best = -np.inf
    best_conv = False
    best_it = 0
    for t in range(u_m.shape[0]):
        k = _init_params(xs, kmax, u_m[t], min_sigma, w, mu, sg, d, r, scratch)
        tr = trace_m[t] if rec else empty
        ll, conv, it = _em(xs, k, w, mu, sg, tol, max_iter, min_sigma, d, r, scratch, ssum, tr)
        if ll > best or t == 0:
            best = ll
            best_conv = conv
            best_it = it
            for j in range(kmax):
                w_out[j] = w[j]
                mu_out[j] = mu[j]
                sg_out[j] = sg[j]
    return best_conv, best_it, best


@njit(cache=True)
def fit_batch(
    x, offsets, kmax, u, tol, max_iter, min_sigma, w_out, mu_out, sg_out, conv_out, iter_out, ll_out, trace
):  # pragma: no cover
    """Fit one mixture per slice ``x[offsets[m]:offsets[m+1]]``, keeping the best of ``u.shape[1]`` starts.

    Parameters
    ----------
    x : (total,) float64, radians in [-pi, pi)
    offsets : (M + 1,) int64, increasing, every slice non-empty
    kmax : int, components per mixture
    u : (M, n_init, kmax) float64 uniforms in [0, 1) driving the k-means++ seeding
    tol, max_iter, min_sigma : EM stopping rule and sigma floor (radians)
    w_out, mu_out, sg_out : (M, kmax) float64, written
    conv_out : (M,) bool; iter_out : (M,) int64; ll_out : (M,) float64, written
    trace : (M, n_init, max_iter + 1) float64 or shape (0, 0, 0): raw log-likelihood traces
    """
    rec = trace.shape[0] > 0
    empty = np.empty((0, 0))
    for m in range(offsets.shape[0] - 1):
        tr = trace[m] if rec else empty
        conv, it, ll = _fit_one(
            x[offsets[m] : offsets[m + 1]], kmax, u[m], tol, max_iter, min_sigma, w_out[m], mu_out[m], sg_out[m], tr
        )
        conv_out[m] = conv
        iter_out[m] = it
        ll_out[m] = ll


@njit(cache=True)
def _wrap_as_numpy(a: float) -> float:  # pragma: no cover - compiled
    """:func:`fingerloc.angles.wrap` of one finite value, bit for bit: ``mod(a + pi, 2 pi) - pi``, pi folded to -pi.

    numpy's float ``mod`` is ``fmod`` (exact) moved into ``[0, 2 pi)`` by one
    addition of 2 pi when negative, +0.0 when zero; for ``a + pi`` already in
    ``[0, 2 pi)`` (every wrapped bearing) it is ``a + pi`` itself.
    """
    y = a + _PI
    if not (0.0 <= y < _TWO_PI):
        m = np.fmod(y, _TWO_PI)
        if m < 0.0:
            m += _TWO_PI
        elif m == 0.0:
            m = 0.0
        y = m
    z = y - _PI
    return z - _TWO_PI if z >= _PI else z


@njit(cache=True)
def fit_single(x, kmax, buf, seed, tol, max_iter, min_sigma):  # pragma: no cover
    """One mixture, as :func:`fit_batch` fits mixture 0 of ``[wrap(x)]``: same code, same results, fewer arguments.

    ``x`` (n,), n >= 1, holds the bearings as given (radians, any real
    value); it is left unchanged: a non-finite one returns ``used = -1`` at
    once, the others are wrapped into a new array exactly as
    :func:`fingerloc.angles.wrap` does. ``buf`` (3 + n_init, kmax): rows 3:
    hold the uniforms that drive the seeding; with ``seed >= 0`` (below
    2**63) they are first drawn here as
    ``numpy.random.default_rng(seed).random((n_init, kmax))``
    (:func:`fingerloc._seed_kernels.default_rng_random`). Rows 0, 1, 2
    receive the weights, means and sigmas. Returns (converged, n_iter, mean
    log-lik, components with weight > 0).

    Everything :meth:`fingerloc.mog.AngularMixture.fit` needs after its
    parameter checks happens in this one compiled call.
    """
    n = x.shape[0]
    finite = True
    for i in range(n):
        finite &= math.isfinite(x[i])
    if not finite:
        return False, 0, np.nan, -1
    xs = np.empty(n)
    for i in range(n):
        xs[i] = _wrap_as_numpy(x[i])
    u_m = buf[3:]
    if seed >= 0:
        default_rng_random(seed, u_m)
    conv, it, ll = _fit_one(xs, kmax, u_m, tol, max_iter, min_sigma, buf[0], buf[1], buf[2], np.empty((0, 0)))
    used = 0
    for j in range(kmax):
        used += buf[0, j] > 0.0
    return conv, it, ll, used


@njit(cache=True, parallel=True)
def fit_batch_parallel(
    x, offsets, kmax, u, tol, max_iter, min_sigma, w_out, mu_out, sg_out, conv_out, iter_out, ll_out
):  # pragma: no cover
    """:func:`fit_batch` (without traces) with the mixtures spread over numba's threads; same results."""
    empty = np.empty((0, 0))
    for m in prange(offsets.shape[0] - 1):
        conv, it, ll = _fit_one(
            x[offsets[m] : offsets[m + 1]], kmax, u[m], tol, max_iter, min_sigma, w_out[m], mu_out[m], sg_out[m], empty
        )
        conv_out[m] = conv
        iter_out[m] = it
        ll_out[m] = ll


@njit(cache=True)
def log_density_batch(x, w, mu, sg, out):  # pragma: no cover
    """out[m, i] = log sum_k w[m, k] p(x_i | mu[m, k], sg[m, k]); zero-weight components skipped.

    Component-major like :func:`_e_step`, so all but the exponentials vectorise.
    """
    _log_density_rows(x, w, mu, sg, out, 0, w.shape[0])


@njit(cache=True, parallel=True)
def log_density_batch_parallel(x, w, mu, sg, out, n_chunks):  # pragma: no cover
    """:func:`log_density_batch` with the mixtures split into ``n_chunks`` blocks over numba's threads."""
    m_count = w.shape[0]
    for c in prange(n_chunks):
        _log_density_rows(x, w, mu, sg, out, c * m_count // n_chunks, (c + 1) * m_count // n_chunks)


@njit(cache=True)
def _log_density_rows(x, w, mu, sg, out, lo, hi):  # pragma: no cover
    """Rows ``lo:hi`` of :func:`log_density_batch`."""
    kmax = w.shape[1]
    n = x.shape[0]
    a = np.empty((kmax, n))
    mx = np.empty(n)
    ssum = np.empty(n)
    idx = np.empty(n, dtype=np.int64)
    for m in range(lo, hi):
        for i in range(n):
            mx[i] = -np.inf
            ssum[i] = 0.0
        for j in range(kmax):
            if w[m, j] > 0.0:
                cj = math.log(w[m, j]) + _log_norm(sg[m, j])
                invj = 0.5 / (sg[m, j] * sg[m, j])
                muj = mu[m, j]
                for i in range(n):
                    dj = x[i] - muj
                    dj = dj - _TWO_PI if dj > _PI else dj
                    dj = dj + _TWO_PI if dj <= -_PI else dj
                    t = cj - dj * dj * invj
                    a[j, i] = t
                    mx[i] = t if t > mx[i] else mx[i]
        for j in range(kmax):
            if w[m, j] > 0.0:
                # ssum += 1 where t == 0 (exp(0) == 1 exactly), exp(t) where -_SKIP < t < 0, else 0: the ones
                # and zeros in one branch-free pass that also lists the few bearings needing exp, then those
                # (adding 0.0 first changes nothing: the same sums in the same component order, bit for bit)
                cnt = 0
                for i in range(n):
                    t = a[j, i] - mx[i]
                    ssum[i] += 1.0 if t == 0.0 else 0.0
                    idx[cnt] = i
                    cnt += 1 if (t > -_SKIP and t != 0.0) else 0
                for c in range(cnt):
                    i = idx[c]
                    ssum[i] += math.exp(a[j, i] - mx[i])
        for i in range(n):
            # log(1.0) is exactly +0.0: most bearings are far from all but one component, so skip the call
            out[m, i] = mx[i] + (0.0 if ssum[i] == 1.0 else math.log(ssum[i]))
