"""AngularMixture.fit's single compiled call: numpy's seeding and fingerloc.angles.wrap, bit for bit."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from numba import njit

from fingerloc import _mog_kernels as _k
from fingerloc import mog
from fingerloc._seed_kernels import default_rng_random
from fingerloc.angles import wrap
from fingerloc.mog import AngularMixture, ConvergenceWarning, fit_mixtures


@pytest.mark.parametrize("shape", [(1, 5), (3, 4), (17,), (0, 3)])
def test_default_rng_random_equals_numpy(shape):
    seeds = [0, 1, 2, 2**32 - 1, 2**32, 2**32 + 1, 2**62 + 7, 2**63 - 1]
    seeds += [int(s) for s in np.random.default_rng(5).integers(0, 2**63 - 1, 300, dtype=np.int64)]
    for seed in seeds:
        got = np.full(shape, np.nan)
        default_rng_random(seed, got)
        np.testing.assert_array_equal(got, np.random.default_rng(seed).random(shape), err_msg=f"seed {seed}")


def test_compiled_seeding_is_used():
    # the check against numpy passes here, so fit() draws in the compiled call (the fast path is taken)
    assert mog._compiled_seeding_ok()
    assert mog._seeding_matches_numpy is True


@njit
def _wrap_all(a, out):  # pragma: no cover - compiled
    for i in range(a.shape[0]):
        out[i] = _k._wrap_as_numpy(a[i])


def test_compiled_wrap_equals_wrap():
    rng = np.random.default_rng(3)
    edges = [0.0, -0.0, math.pi, -math.pi, 2 * math.pi, -2 * math.pi, 1e-17, -1e-17, 1e-300, -1e-300]
    edges += [2 * math.pi - 1e-17, math.pi - 1e-16, -math.pi + 1e-16, 3 * math.pi, -3 * math.pi, 1e300, -1e300, 1e17]
    edges += [np.nextafter(math.pi, 0.0), np.nextafter(-math.pi, 0.0), np.nextafter(-math.pi, -4.0)]
    a = np.concatenate(
        [
            edges,
            rng.uniform(-math.pi, math.pi, 20_000),
            rng.uniform(-50, 50, 20_000),
            rng.normal(0, 1e6, 5_000),
            k_pi := np.arange(-40, 41) * math.pi,
            np.nextafter(k_pi, np.inf),
            np.nextafter(k_pi, -np.inf),
        ]
    )
    got = np.empty_like(a)
    _wrap_all(a, got)
    np.testing.assert_array_equal(got.view(np.int64), wrap(a).view(np.int64))  # signs of zeros too


@pytest.mark.parametrize("seed", [0, 9, 2**32 + 5, 2**63 - 2, 2**63, 2**70, np.int64(12)])
def test_fit_equals_fit_mixtures_for_any_int_seed(seed):
    # seeds below 2**63 are drawn in the compiled call, others by numpy: the fits equal fit_mixtures' either way
    x = np.random.default_rng(1).vonmises(0.3, 1.5, 80)
    gm = AngularMixture(4, n_init=2, random_state=seed).fit(x)
    ms = fit_mixtures([x], 4, n_init=2, random_state=seed)
    np.testing.assert_array_equal(np.stack([gm.weights_, gm.means_, gm.sigmas_]), np.stack([ms.weights[0], ms.means[0], ms.sigmas[0]]))
    assert (gm.converged_, gm.n_iter_, gm.lower_bound_) == (ms.converged[0], ms.n_iter[0], ms.lower_bound[0])


def test_fit_generator_and_none_seeds():
    x = np.random.default_rng(2).vonmises(-1.0, 2.0, 60)
    a = AngularMixture(3, random_state=np.random.default_rng(4)).fit(x)
    b = fit_mixtures([x], 3, random_state=np.random.default_rng(4))
    np.testing.assert_array_equal(a.means_, b.means[0])
    c = AngularMixture(3).fit(x)  # fresh entropy: a valid fit
    assert c.weights_.sum() == pytest.approx(1.0)


@pytest.mark.parametrize(
    "make",
    [
        lambda x: x[::-1].copy()[::-1],  # negative stride
        lambda x: x[:, None],  # scikit-learn's column
        lambda x: x.tolist(),
        lambda x: x.astype(np.float32).astype(np.float64),
        lambda x: np.asfortranarray(np.stack([x, x]))[0],  # strided view
    ],
)
def test_fit_input_layouts_and_input_left_unchanged(make):
    x = np.random.default_rng(8).uniform(-9, 9, 70)  # not wrapped: the kernel wraps a copy
    xin = make(x)
    before = np.array(xin, dtype=np.float64, copy=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        gm = AngularMixture(3, random_state=6).fit(xin)
    ms = fit_mixtures([np.asarray(xin, dtype=np.float64).ravel()], 3, random_state=6)
    np.testing.assert_array_equal(gm.means_, ms.means[0])
    np.testing.assert_array_equal(np.asarray(xin, dtype=np.float64), before)


def test_fit_read_only_input():
    x = np.random.default_rng(8).uniform(-3, 3, 50)
    ref = AngularMixture(2, random_state=1).fit(x)
    x.flags.writeable = False
    gm = AngularMixture(2, random_state=1).fit(x)
    np.testing.assert_array_equal(gm.sigmas_, ref.sigmas_)


def _economised_exp_coefficients() -> list[float]:
    """exp's Taylor polynomial of degree 14 on |r| <= 0.347, economised to degree 11, in exact rationals."""
    from fractions import Fraction

    def cheb(n: int) -> list[int]:  # integer coefficients of the Chebyshev polynomial T_n, ascending powers
        t0, t1 = [1], [0, 1]
        for _ in range(n - 1):
            t2 = [0] + [2 * c for c in t1]
            for i, c in enumerate(t0):
                t2[i] -= c
            t0, t1 = t1, t2
        return t1

    h = Fraction(347, 1000)
    a = [Fraction(1, math.factorial(i)) * h**i for i in range(15)]  # in x = r / h, |x| <= 1
    for n in (14, 13, 12):
        tn = cheb(n)
        c = a[n] / tn[n]
        for i, tc in enumerate(tn):
            a[i] -= c * tc
    return [float(a[i] / h**i) for i in range(12)]


def test_exp_polynomial_constants_are_the_economised_taylor_polynomial():
    coef = _economised_exp_coefficients()
    assert coef[0] == 1.0 and coef[1] == 1.0
    assert coef[2:] == [getattr(_k, f"_E{i}") for i in range(2, 12)]
    assert 0.347 > math.log(2) / 2


def test_bad_x_leaves_a_generator_untouched():
    rng = np.random.default_rng(3)
    state = rng.bit_generator.state
    with pytest.raises(mog.InvalidParameterError, match="non-finite"):
        AngularMixture(2, random_state=rng).fit(np.array([0.1, np.nan]))
    assert rng.bit_generator.state == state
