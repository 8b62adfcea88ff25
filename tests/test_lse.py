"""fingerloc._lse.logsumexp equals scipy.special.logsumexp bit for bit (the filters' hot call)."""

import numpy as np
import pytest
from scipy.special import logsumexp as scipy_lse

from fingerloc._lse import logsumexp


def _same(x, y):
    x, y = np.float64(x), np.float64(y)
    return (np.isnan(x) and np.isnan(y)) or x.tobytes() == y.tobytes()


def _cases():
    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 7, 42, 61, 128, 3000):
        for scale in (1e-3, 1.0, 30.0, 800.0):
            yield rng.normal(size=n) * scale
            a = rng.normal(size=n) * scale
            a[rng.integers(0, n, size=max(1, n // 3))] = -np.inf
            yield a
            b = np.round(rng.normal(size=n) * scale)  # many ties, several maxima
            yield b
        yield np.full(n, -np.inf)
        yield np.full(n, 2.5)
        c = rng.normal(size=n)
        c[0] = np.inf
        yield c
        d = rng.normal(size=n)
        d[-1] = np.nan
        yield d
        yield np.log(rng.dirichlet(np.ones(n)))
    yield np.array([1e308, 1e308])
    yield np.array([-1e308, -1e308, 0.0])


def test_logsumexp_equals_scipy_bit_for_bit():
    n = 0
    for a in _cases():
        assert _same(logsumexp(a), scipy_lse(a)), a
        n += 1
    assert n > 100


def test_logsumexp_other_calls_go_to_scipy():
    a = np.arange(12.0).reshape(3, 4)
    np.testing.assert_array_equal(logsumexp(a, axis=1), scipy_lse(a, axis=1))
    assert _same(logsumexp([1.0, 2.0]), scipy_lse([1.0, 2.0]))
    assert _same(logsumexp(np.array([1, 2])), scipy_lse(np.array([1, 2])))
    assert logsumexp(np.zeros(0)) == -np.inf
    v, sgn = logsumexp(np.array([0.0, 1.0]), return_sign=True)
    assert _same(v, scipy_lse(np.array([0.0, 1.0]))) and sgn == 1.0


def test_a_broken_logsumexp_would_fail():
    # the check above can fail: the naive formula differs from SciPy's on some of the cases
    naive = [np.log(np.sum(np.exp(a - a.max()))) + a.max() for a in _cases() if np.all(np.isfinite(a))]
    ref = [scipy_lse(a) for a in _cases() if np.all(np.isfinite(a))]
    assert not all(_same(x, y) for x, y in zip(naive, ref, strict=True))


@pytest.mark.parametrize("n", [1, 42])
def test_logsumexp_returns_a_numpy_scalar(n):
    assert isinstance(logsumexp(np.zeros(n)), np.float64)
