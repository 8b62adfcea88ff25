"""Tests of fingerloc.mog: the angular mixture of SPEC.md §3 and its EM."""

from __future__ import annotations

import functools
import math
import warnings

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy import integrate

from fingerloc.errors import InvalidParameterError, NotFittedError
from fingerloc.mog import (
    PARALLEL_MIN_MIXTURES,
    AngularMixture,
    ConvergenceWarning,
    MixtureSet,
    _em_traces,
    _fit,
    component_log_density,
    fit_mixtures,
    mixture_log_density,
)

D = math.radians


def spec_log_density(x: float, w: list[float], mu: list[float], sg: list[float]) -> float:
    """SPEC.md §3 written out in plain Python: the oracle."""
    total = 0.0
    for wk, mk, sk in zip(w, mu, sg, strict=True):
        if wk == 0:
            continue
        d = (x - mk) % (2 * math.pi)  # distAS(mu, x) in (-pi, pi]
        if d > math.pi:
            d -= 2 * math.pi
        eta = 1.0 / (math.sqrt(2 * math.pi) * sk * math.erf(math.pi / (math.sqrt(2) * sk)))
        total += wk * eta * math.exp(-(d * d) / (2 * sk * sk))
    return math.log(total)


def mixture_sample(rng: np.random.Generator, n: int, w, mu_deg, sg_deg) -> np.ndarray:
    lab = rng.choice(len(w), size=n, p=np.asarray(w) / np.sum(w))
    return np.deg2rad(np.asarray(mu_deg)[lab] + rng.normal(0.0, np.asarray(sg_deg)[lab]))


# --- the density -------------------------------------------------------------------------------


@pytest.mark.parametrize("sigma_deg", [1.0, 3.0, 10.0, 45.0, 90.0, 180.0, 300.0])
@pytest.mark.parametrize("mean_deg", [0.0, 179.0, -120.0])
def test_density_integrates_to_one(sigma_deg, mean_deg):
    mu, s = D(mean_deg), D(sigma_deg)
    # integrate over one turn starting at the antipode so the peak is inside, with the peak as a breakpoint
    a = mu - math.pi
    val, _err = integrate.quad(
        lambda t: math.exp(component_log_density(t, mu, s)), a, a + 2 * math.pi, points=[mu], limit=200
    )
    assert abs(val - 1.0) < 1e-8


def test_mixture_density_integrates_to_one():
    w = np.array([[0.2, 0.5, 0.3, 0.0]])
    mu = np.array([[D(179), D(-10), D(90), 0.0]])
    sg = np.array([[D(4), D(60), D(300), 1.0]])
    val, _ = integrate.quad(
        lambda t: math.exp(mixture_log_density(np.array([t]), w, mu, sg)[0, 0]),
        -math.pi,
        math.pi,
        points=[D(179), D(-10), D(90)],
        limit=400,
    )
    assert abs(val - 1.0) < 1e-8


def test_log_density_matches_spec_formula():
    rng = np.random.default_rng(3)
    m, k, n = 7, 4, 50
    w = rng.dirichlet(np.ones(k), size=m)
    w[0, 1] = 0.0  # a zero-weight component is ignored
    w[0] /= w[0].sum()
    mu = rng.uniform(-math.pi, math.pi, (m, k))
    sg = np.deg2rad(rng.uniform(0.5, 350.0, (m, k)))
    x = rng.uniform(-10, 10, n)  # any real bearing; wrapped inside
    got = mixture_log_density(x, w, mu, sg)
    assert got.shape == (m, n)
    want = np.array([[spec_log_density(xj, list(w[i]), list(mu[i]), list(sg[i])) for xj in x] for i in range(m)])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def test_log_density_far_tail_is_finite():
    # a point at the antipode of a narrow component: log-density very negative but finite
    out = mixture_log_density(np.array([math.pi - 1e-9]), np.array([[1.0]]), np.array([[0.0]]), np.array([[D(0.1)]]))
    assert np.isfinite(out).all() and out[0, 0] < -1e5


def test_log_density_one_mixture_1d_and_validation():
    out = mixture_log_density([0.1, 0.2], [1.0], [0.0], [0.5])
    assert out.shape == (1, 2)
    with pytest.raises(InvalidParameterError, match="share one"):
        mixture_log_density([0.1], [[1.0, 0.0]], [[0.0]], [[1.0]])
    with pytest.raises(InvalidParameterError, match="weights must be >= 0"):
        mixture_log_density([0.1], [[1.5, -0.5]], [[0.0, 1.0]], [[1.0, 1.0]])
    with pytest.raises(InvalidParameterError, match="at least one component"):
        mixture_log_density([0.1], [[0.0]], [[0.0]], [[1.0]])
    with pytest.raises(InvalidParameterError, match="sigmas"):
        mixture_log_density([0.1], [[1.0]], [[0.0]], [[0.0]])
    with pytest.raises(InvalidParameterError, match="non-finite"):
        mixture_log_density([np.nan], [[1.0]], [[0.0]], [[1.0]])


# --- EM --------------------------------------------------------------------------------------


def test_recovers_known_mixture_across_the_wrap():
    rng = np.random.default_rng(0)
    w, mu_deg, sg_deg = [0.3, 0.45, 0.25], [179.0, 60.0, -80.0], [6.0, 12.0, 20.0]
    x = mixture_sample(rng, 5000, w, mu_deg, sg_deg)
    gm = AngularMixture(3, random_state=1, n_init=3).fit(x)
    assert gm.converged_
    order = [int(np.argmin(np.abs(np.rad2deg(np.angle(np.exp(1j * (gm.means_ - D(m)))))))) for m in mu_deg]
    assert sorted(order) == [0, 1, 2]
    err_mu = np.rad2deg(np.abs(np.angle(np.exp(1j * (gm.means_[order] - np.deg2rad(mu_deg))))))
    assert np.all(err_mu < 2.0), err_mu
    np.testing.assert_allclose(np.rad2deg(gm.sigmas_[order]), sg_deg, rtol=0.1)
    np.testing.assert_allclose(gm.weights_[order], w, atol=0.03)
    # the component at 179 deg straddles the wrap: its mean stays near +-180, not pulled to 0
    assert abs(abs(np.rad2deg(gm.means_[order[0]])) - 179.0) < 2.0


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 4), st.integers(0, 2), st.integers(2, 200))
def test_em_never_decreases_log_likelihood(seed, kk, extra, n):
    # The weight and mean steps never lower the likelihood (the wrapped mean step minimises a quadratic
    # that majorises sum_i r_ik distAS(mu, x_i)^2); the sigma step is exact when the truncation at +-pi
    # is negligible, i.e. for sigmas below ~20 deg. Clusters of 2-8 deg keep every fitted sigma there.
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-180, 180) + 360.0 * np.arange(kk) / kk + rng.uniform(-10, 10, kk)
    x = mixture_sample(rng, n, rng.uniform(0.5, 1.0, kk), centres, rng.uniform(2, 8, kk))
    fit, trace = _em_traces(x, kk + extra, random_state=seed, n_init=1, max_iter=300, tol=0.0)
    assume(np.all(fit.sigmas[fit.weights > 0] < D(20.0)))
    t = trace[0][~np.isnan(trace[0])]
    assert t.size >= 2
    assert np.all(np.diff(t) >= -1e-12), np.diff(t).min()
    assert fit.lower_bound[0] == pytest.approx(t.max(), abs=1e-12)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 5), st.integers(1, 150))
def test_fit_never_ends_below_an_earlier_iterate(seed, k, n):
    # Any data, wide components included: a raw step may then lose a hair (the paper's sigma update
    # ignores the truncation; measured ~3e-10 nats for a 40 deg component); EM stops there and keeps the
    # parameters before that step, so the result is the best iterate and its likelihood is lower_bound.
    rng = np.random.default_rng(seed)
    x = rng.uniform(-math.pi, math.pi, n) if seed % 2 else mixture_sample(rng, n, [1, 1], [0, 50], [30, 40])
    fit, trace = _em_traces(x, k, random_state=seed, n_init=2, max_iter=200)
    best = np.nanmax(trace, axis=1).max()
    assert fit.lower_bound[0] >= best - 1e-12
    again = float(fit.log_density(x)[0].mean())
    assert again == pytest.approx(fit.lower_bound[0], abs=1e-10)


def test_fit_equals_batch_of_one():
    rng = np.random.default_rng(11)
    x = mixture_sample(rng, 120, [1, 1, 1], [10, 100, -150], [5, 10, 20])
    gm = AngularMixture(4, n_init=2, random_state=7).fit(x)
    ms = fit_mixtures([x], 4, n_init=2, random_state=7)
    np.testing.assert_array_equal(gm.weights_, ms.weights[0])
    np.testing.assert_array_equal(gm.means_, ms.means[0])
    np.testing.assert_array_equal(gm.sigmas_, ms.sigmas[0])
    assert gm.n_iter_ == ms.n_iter[0] and gm.lower_bound_ == ms.lower_bound[0]
    np.testing.assert_allclose(gm.score_samples(x), ms.log_density(x)[0], rtol=1e-13)


def test_batch_parallel_and_serial_agree():
    rng = np.random.default_rng(2)
    samples = [mixture_sample(rng, int(rng.integers(1, 60)), [1, 2], [0, 90], [10, 30]) for _ in range(40)]
    assert len(samples) >= PARALLEL_MIN_MIXTURES
    res = fit_mixtures(samples, 3, n_init=2, random_state=4)
    u = np.random.default_rng(4).random((len(samples), 2, 3))
    for i, s in enumerate(samples):
        one = _fit(
            res_wrap(s),
            np.array([0, s.size], dtype=np.int64),
            3,
            u[i : i + 1],
            1e-6,
            500,
            D(1.0),
        )
        np.testing.assert_array_equal(one.means[0], res.means[i])
        np.testing.assert_array_equal(one.weights[0], res.weights[i])
        assert one.lower_bound[0] == res.lower_bound[i]


def res_wrap(s: np.ndarray) -> np.ndarray:
    from fingerloc.angles import wrap

    return np.ascontiguousarray(wrap(s))


def test_mixture_set_shape_and_readonly():
    rng = np.random.default_rng(1)
    res = fit_mixtures([rng.uniform(-3, 3, 30), rng.uniform(-3, 3, 5)], 5, random_state=0)
    assert isinstance(res, MixtureSet) and len(res) == 2 and res.n_components == 5
    assert res.weights.shape == res.means.shape == res.sigmas.shape == (2, 5)
    np.testing.assert_allclose(res.weights.sum(axis=1), 1.0)
    assert np.all((res.means >= -math.pi) & (res.means < math.pi))
    assert np.all(res.sigmas > 0)
    assert res.converged.dtype == bool and res.n_iter.shape == (2,)
    with pytest.raises(ValueError):
        res.weights[0, 0] = 3.0


@given(st.integers(0, 1000), st.floats(-math.pi, math.pi))
@settings(max_examples=20, deadline=None)
def test_rotation_equivariance(seed, rot):
    rng = np.random.default_rng(seed)
    x = mixture_sample(rng, 80, [1, 1, 1], [0, 120, -120], [8, 8, 8])
    a = fit_mixtures([x], 3, random_state=seed)
    b = fit_mixtures([x + rot], 3, random_state=seed)
    assert abs(a.lower_bound[0] - b.lower_bound[0]) < 1e-6
    da = np.angle(np.exp(1j * (b.means[0] - a.means[0] - rot)))
    assert np.all(np.abs(da[a.weights[0] > 0]) < 1e-6)


def test_deterministic_for_seed():
    x = np.random.default_rng(0).uniform(-3, 3, 50)
    a = fit_mixtures([x], 4, n_init=3, random_state=12)
    b = fit_mixtures([x], 4, n_init=3, random_state=np.random.default_rng(12))
    np.testing.assert_array_equal(a.means, b.means)


# --- what the paper leaves open --------------------------------------------------------------


def test_single_point():
    gm = AngularMixture(3, random_state=0).fit([D(100)])
    assert gm.n_components_ == 1 and gm.converged_
    j = int(np.argmax(gm.weights_))
    assert gm.weights_[j] == 1.0
    assert math.isclose(gm.means_[j], D(100), abs_tol=1e-12)
    assert math.isclose(gm.sigmas_[j], D(1.0))  # at the floor
    np.testing.assert_array_equal(np.delete(gm.weights_, j), 0.0)


def test_all_points_equal_and_sigma_floor():
    gm = AngularMixture(4, min_sigma_deg=2.5, random_state=0).fit(np.full(25, D(-179.5)))
    assert gm.n_components_ == 1
    j = int(np.argmax(gm.weights_))
    assert math.isclose(gm.sigmas_[j], D(2.5))
    assert math.isclose(gm.means_[j], D(-179.5), abs_tol=1e-12)
    assert np.isfinite(gm.lower_bound_)


def test_fewer_distinct_points_than_components():
    x = np.repeat(np.deg2rad([10.0, 20.0, 200.0]), [5, 3, 4])
    gm = AngularMixture(5, random_state=0, min_sigma_deg=1.0).fit(x)
    assert gm.n_components_ == 3
    live = gm.weights_ > 0
    np.testing.assert_allclose(np.sort(gm.weights_[live]), np.sort([5 / 12, 3 / 12, 4 / 12]), atol=1e-9)
    np.testing.assert_allclose(np.sort(np.rad2deg(gm.means_[live]) % 360), [10, 20, 200], atol=1e-6)
    np.testing.assert_allclose(gm.sigmas_[live], D(1.0))
    p = gm.predict_proba(x)
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    assert np.all(p[:, ~live] == 0)


def test_sigmas_never_below_floor():
    rng = np.random.default_rng(9)
    samples = [np.round(rng.uniform(-3, 3, 30), 1) for _ in range(20)]  # many ties
    res = fit_mixtures(samples, 5, min_sigma_deg=3.0, random_state=0)
    live = res.weights > 0
    assert np.all(res.sigmas[live] >= D(3.0) * (1 - 1e-12))


def test_empty_input_is_an_error():
    with pytest.raises(InvalidParameterError, match="empty"):
        AngularMixture(3).fit([])
    with pytest.raises(InvalidParameterError, match=r"samples\[1\] is empty"):
        fit_mixtures([[0.1], []], 2)
    with pytest.raises(InvalidParameterError, match="samples is empty"):
        fit_mixtures([], 2)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_components": 0}, "n_components"),
        ({"n_components": 2.5}, "n_components"),
        ({"tol": -1.0}, "tol"),
        ({"max_iter": 0}, "max_iter"),
        ({"n_init": 0}, "n_init"),
        ({"min_sigma_deg": 0.0}, "min_sigma_deg"),
        ({"min_sigma_deg": float("nan")}, "min_sigma_deg"),
        ({"random_state": "seed"}, "random_state"),
    ],
)
def test_bad_parameters(kwargs, match):
    args = {"n_components": 2, **kwargs}
    with pytest.raises(InvalidParameterError, match=match):
        AngularMixture(**args).fit([0.1, 0.2, 0.3])


def test_bad_input():
    with pytest.raises(InvalidParameterError, match="non-finite"):
        AngularMixture(2).fit([0.1, np.inf])
    with pytest.raises(InvalidParameterError, match="1-D"):
        AngularMixture(2).fit(np.zeros((3, 2)))
    with pytest.raises(InvalidParameterError, match="one 1-D array"):
        fit_mixtures(np.zeros(4), 2)


def test_convergence_warning():
    x = mixture_sample(np.random.default_rng(0), 200, [1, 1], [0, 40], [20, 20])
    with pytest.warns(ConvergenceWarning, match="max_iter=1"):
        gm = AngularMixture(2, max_iter=1, tol=0.0, random_state=0).fit(x)
    assert not gm.converged_ and gm.n_iter_ == 1


# --- the estimator surface -------------------------------------------------------------------


def test_estimator_methods():
    rng = np.random.default_rng(4)
    x = mixture_sample(rng, 300, [1, 1], [-90, 90], [10, 10])
    gm = AngularMixture(2, random_state=0)
    assert "n_components=2" in repr(gm)
    with pytest.raises(NotFittedError):
        gm.score_samples(x)
    assert gm.fit(x[:, None]) is gm  # (n, 1) accepted
    s = gm.score_samples(x)
    assert s.shape == (300,)
    assert math.isclose(gm.score(x), float(s.mean()))
    assert math.isclose(gm.lower_bound_, gm.score(x), rel_tol=1e-9)
    p = gm.predict_proba(x)
    assert p.shape == (300, 2)
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    lab = gm.predict(x)
    assert set(np.unique(lab)) == {0, 1}
    xs, ys = gm.sample(2000, random_state=1)
    assert xs.shape == ys.shape == (2000,)
    assert np.all((xs >= -math.pi) & (xs < math.pi))
    # samples come from the fitted mixture: refitting them finds the same means
    gm2 = AngularMixture(2, random_state=0).fit(xs)
    assert np.allclose(np.sort(gm2.means_), np.sort(gm.means_), atol=D(2))


def test_sample_wide_component_is_truncated_gaussian():
    gm = AngularMixture(1, random_state=0).fit([0.0])
    gm.sigmas_ = np.array([D(300.0)])  # near uniform: rejection sampling still terminates
    xs, _ = gm.sample(20000, random_state=3)
    hist, _ = np.histogram(xs, bins=8, range=(-math.pi, math.pi))
    expected = [
        20000 * integrate.quad(lambda t: math.exp(component_log_density(t, 0.0, D(300.0))), a, a + math.pi / 4)[0]
        for a in np.linspace(-math.pi, math.pi, 9)[:-1]
    ]
    assert np.all(np.abs(hist - expected) < 5 * np.sqrt(expected))


def test_no_warning_on_normal_fit():
    x = mixture_sample(np.random.default_rng(0), 100, [1], [0], [10])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        AngularMixture(1, random_state=0).fit(x)


def test_get_set_params():
    gm = AngularMixture(4, tol=1e-4, random_state=3)
    params = gm.get_params()
    assert params == {
        "n_components": 4,
        "tol": 1e-4,
        "max_iter": 500,
        "n_init": gm.n_init,
        "min_sigma_deg": gm.min_sigma_deg,
        "random_state": 3,
    }
    assert AngularMixture(**params).get_params() == params
    assert gm.set_params(n_components=2) is gm and gm.n_components == 2
    with pytest.raises(InvalidParameterError, match="no parameter 'k'"):
        gm.set_params(k=2)


def test_fit_from_several_threads():
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(8)
    samples = [rng.uniform(-3, 3, 40) for _ in range(3 * PARALLEL_MIN_MIXTURES)]
    ref = fit_mixtures(samples, 3, random_state=1)
    with ThreadPoolExecutor(4) as pool:
        outs = list(pool.map(lambda _: fit_mixtures(samples, 3, random_state=1), range(8)))
    for o in outs:
        np.testing.assert_array_equal(o.means, ref.means)


def test_docstring_examples():
    import doctest

    import fingerloc.mog

    res = doctest.testmod(fingerloc.mog)
    assert res.attempted > 0 and res.failed == 0


def test_bic_aic_choose_the_true_number_of_components():
    rng = np.random.default_rng(6)
    x = mixture_sample(rng, 600, [1, 1, 1], [0, 120, -120], [8, 8, 8])
    bics = {k: AngularMixture(k, n_init=3, random_state=0).fit(x).bic(x) for k in (1, 2, 3, 4, 5)}
    assert min(bics, key=bics.__getitem__) == 3
    gm = AngularMixture(3, random_state=0).fit(x)
    n_params = 3 * 3 - 1
    assert gm.aic(x) == pytest.approx(-2 * gm.score_samples(x).sum() + 2 * n_params)
    assert gm.bic(x) == pytest.approx(-2 * gm.score_samples(x).sum() + n_params * math.log(x.size))


def test_log_density_threads_equal_serial():
    from fingerloc import _mog_kernels as k

    rng = np.random.default_rng(3)
    m, kk, n = 700, 5, 9
    w = rng.dirichlet(np.ones(kk), size=m)
    w[::7, 3] = 0.0
    w /= w.sum(axis=1, keepdims=True)
    mu = rng.uniform(-np.pi, np.pi, (m, kk))
    sg = rng.uniform(0.02, 2.0, (m, kk))
    x = rng.uniform(-np.pi, np.pi, n)
    serial = np.empty((m, n))
    k.log_density_batch(x, w, mu, sg, serial)
    threaded = np.empty((m, n))
    k.log_density_batch_parallel(x, w, mu, sg, threaded, 3)
    np.testing.assert_array_equal(serial, threaded)
    np.testing.assert_array_equal(mixture_log_density(x, w, mu, sg), serial)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 90), st.integers(1, 6), st.integers(1, 3), st.integers(0, 2**32 - 1))
def test_fit_fast_path_equals_fit_mixtures(n, k, n_init, seed):
    # AngularMixture.fit takes a shorter path than fit_mixtures; the fits must be identical
    x = np.random.default_rng(seed).vonmises(0.7, 2.0, n) * 1.3
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        gm = AngularMixture(k, n_init=n_init, max_iter=60, random_state=seed).fit(x)
    ms = fit_mixtures([x], k, n_init=n_init, max_iter=60, random_state=seed)
    np.testing.assert_array_equal(gm.weights_, ms.weights[0])
    np.testing.assert_array_equal(gm.means_, ms.means[0])
    np.testing.assert_array_equal(gm.sigmas_, ms.sigmas[0])
    assert (gm.converged_, gm.n_iter_, gm.lower_bound_) == (ms.converged[0], ms.n_iter[0], ms.lower_bound[0])


@functools.cache
def _exp_neg_loop():
    from numba import njit

    from fingerloc import _mog_kernels as k

    @njit(fastmath={"contract"})  # as the E-step, which inlines it: the polynomial runs on fused multiply-adds
    def many(t, out):  # pragma: no cover - compiled
        for i in range(t.shape[0]):
            out[i] = k._exp_neg(t[i])

    return many


def _exp_neg(t):
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    out = np.empty_like(t)
    _exp_neg_loop()(t, out)
    return out


def test_exp_neg_within_one_ulp_of_the_c_library():
    # the E-step's branch-free exp, against math.exp (the C library) on many values and at the edges
    rng = np.random.default_rng(0)
    t = np.concatenate([-rng.uniform(0, 40.0, 200_000), -rng.uniform(0, 1e-6, 1000), [0.0, -40.0, -math.log(2)]])
    got = _exp_neg(t)
    ref = np.array([math.exp(v) for v in t])
    ulps = np.abs(got.view(np.int64) - ref.view(np.int64))
    assert ulps.max() <= 1
    assert (ulps == 0).mean() > 0.8
    assert got[-3] == 1.0


@settings(max_examples=200, deadline=None)
@given(st.floats(-40.0, 0.0))
def test_exp_neg_property(t):
    e = float(_exp_neg(t)[0])
    assert abs(e - math.exp(t)) <= 2.3e-16 * math.exp(t)


@pytest.mark.parametrize(
    "x",
    [
        np.array([0.1, 2 * np.pi - 1e-17, -1e-17, 7.0, -3.2]),  # values that wrap, one onto the edge at pi
        np.array([0.5, np.pi, -np.pi, 1.0])[::-1],  # a negative stride, and pi itself
        np.linspace(-9, 9, 31)[::2],
    ],
)
def test_fit_fast_path_wraps_like_wrap(x):
    # AngularMixture.fit folds pi onto -pi inside the compiled call: the fit must equal fit_mixtures,
    # which wraps with fingerloc.angles.wrap, and fit on the wrapped bearings given as a list
    from fingerloc.angles import wrap

    gm = AngularMixture(2, random_state=3).fit(x)
    ms = fit_mixtures([x], 2, random_state=3)
    other = AngularMixture(2, random_state=3).fit(list(wrap(x)))
    for a in (ms.means[0], other.means_):
        np.testing.assert_array_equal(gm.means_, a)
    np.testing.assert_array_equal(gm.sigmas_, ms.sigmas[0])
    assert gm.n_components_ == int(np.count_nonzero(ms.weights[0] > 0))


@pytest.mark.parametrize("bad", [np.array([0.1, np.nan]), np.array([np.inf, 0.2]), np.array([], dtype=float)])
def test_fit_fast_path_rejects_non_finite_and_empty(bad):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # and no numpy RuntimeWarning on the way
        with pytest.raises(InvalidParameterError, match=r"non-finite|empty"):
            AngularMixture(2).fit(bad)


def test_e_step_equals_its_exp_and_an_oracle():
    # the E-step builds 2^k from its bits: its responsibilities must be those written with _exp_neg,
    # and agree with a plain numpy computation (math.exp) to rounding
    from numba import njit

    from fingerloc import _mog_kernels as k
    from fingerloc.angles import wrap

    @njit(fastmath={"contract"})
    def resp(x, w, mu, sg, out):  # pragma: no cover - compiled
        for j in range(w.shape[0]):
            cj = math.log(w[j]) + k._log_norm(sg[j])
            for i in range(x.shape[0]):
                out[j, i] = cj - k._dist(mu[j], x[i]) ** 2 * (0.5 / (sg[j] * sg[j]))
        for i in range(x.shape[0]):
            m = out[:, i].max()
            s = 0.0
            for j in range(w.shape[0]):
                t = out[j, i] - m
                out[j, i] = 1.0 if t == 0.0 else (k._exp_neg(t) if t > -k._SKIP else 0.0)
                s += out[j, i]
            for j in range(w.shape[0]):
                out[j, i] *= 1.0 / s

    rng = np.random.default_rng(4)
    for _ in range(20):
        kk, n = int(rng.integers(1, 7)), int(rng.integers(1, 120))
        x = wrap(rng.uniform(-4, 4, n))
        w = rng.dirichlet(np.ones(kk))
        mu = wrap(rng.uniform(-4, 4, kk))
        sg = rng.uniform(0.01, 3.0, kk)
        d, r = np.empty((kk, n)), np.empty((kk, n))
        ll = k._e_step(x, kk, w, mu, sg, d, r, np.empty(n), np.empty(n), np.empty(n, dtype=np.int64))
        want = np.empty((kk, n))
        resp(x, w, mu, sg, want)
        np.testing.assert_allclose(r, want, rtol=1e-14, atol=1e-300)
        dens = sum(w[j] * np.exp(component_log_density(x, mu[j], sg[j])) for j in range(kk))
        assert ll == pytest.approx(np.log(dens).mean(), rel=1e-12, abs=1e-12)
