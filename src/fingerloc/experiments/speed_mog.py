"""``fingerloc bench speed --only mog``: batched angular EM against scikit-learn.

1,000 samples of 100 bearings each, every one drawn from its own random
5-component angular mixture (sigmas 5-30 deg), are fit with k = 5:

* by :func:`fingerloc.mog.fit_mixtures` in one call (defaults: tol 1e-6,
  max_iter 500, n_init :data:`~fingerloc.mog.DEFAULT_N_INIT`), once on all
  numba threads and once on one; then with 3 restarts, and with
  scikit-learn's looser tolerance 1e-3 (all threads);
* one by one, one :meth:`~fingerloc.mog.AngularMixture.fit` call per
  sample (``AngularMixture(5, random_state=i)``: what a user fitting one
  place does, Python overhead included);
* one by one by scikit-learn's ``GaussianMixture(5)`` (its defaults: k-means
  init, tol 1e-3, max_iter 100, n_init 1) on the same bearings as a column,
  with its thread pools as they come and capped at one thread
  (``threadpoolctl``); the faster of the two is the reference.

The figure of merit is the ratio of the times per fit. scikit-learn models
the line, not the circle, and stops at a looser tolerance: the comparison is
of cost per fit, not of the fits. ``--quick`` uses 100 mixtures.
"""

from __future__ import annotations

import contextlib
import time
import warnings
from typing import Any

import numpy as np

from ..angles import wrap
from ..mog import DEFAULT_N_INIT, AngularMixture, fit_mixtures, mixture_log_density
from .speed import best_time, section


def make_samples(n_mixtures: int, n_points: int = 100, k: int = 5, seed: int = 0) -> list[np.ndarray]:
    """``n_mixtures`` bearing arrays (radians), each from its own random k-component mixture."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_mixtures):
        mu = rng.uniform(-np.pi, np.pi, k)
        sg = np.deg2rad(rng.uniform(5.0, 30.0, k))
        lab = rng.integers(0, k, n_points)
        out.append(wrap(mu[lab] + rng.normal(0.0, sg[lab])))
    return out


def _sklearn_per_fit(
    samples: list[np.ndarray], k: int, *, one_thread: bool = False
) -> tuple[float, float, float] | None:
    """scikit-learn's wall seconds per fit, mean EM iterations, and this thread's CPU seconds per fit.

    ``one_thread`` caps its BLAS/OpenMP pools at 1 (then all its work runs on this thread).
    """
    try:
        from sklearn.mixture import GaussianMixture
    except ImportError:  # the optional "bench" extra
        return None
    limits: Any = contextlib.nullcontext()
    if one_thread:
        from threadpoolctl import threadpool_limits  # a dependency of scikit-learn

        limits = threadpool_limits(1)
    iters = []
    with warnings.catch_warnings(), limits:
        warnings.simplefilter("ignore")
        t0, c0 = time.perf_counter(), time.thread_time()
        for i, x in enumerate(samples):
            gm = GaussianMixture(k, random_state=i).fit(x[:, None])
            iters.append(gm.n_iter_)
        dt, dc = time.perf_counter() - t0, time.thread_time() - c0
    return dt / len(samples), float(np.mean(iters)), dc / len(samples)


@section("mog")
def speed_mog(quick: bool) -> dict[str, Any]:
    """Time per fit of k=5 on 100 bearings: fingerloc batched EM vs scikit-learn one by one.

    ``log_density_ms_M_by_10`` is one :func:`mixture_log_density` call for the
    M fitted mixtures on 10 bearings.
    """
    import numba

    m = 100 if quick else 1000
    k = 5
    samples = make_samples(m, 100, k)
    fit_mixtures(samples[:20], k, random_state=0)  # compile (numba cache) outside the timing
    fit_mixtures(samples[:2], k, random_state=0)
    res = fit_mixtures(samples, k, random_state=0)
    t_par = best_time(lambda: fit_mixtures(samples, k, random_state=0), repeat=3)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        t_one = best_time(lambda: fit_mixtures(samples, k, random_state=0), repeat=3)
    finally:
        numba.set_num_threads(threads)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a few samples reach max_iter: ConvergenceWarning

        def one_by_one() -> None:
            for i, xs in enumerate(samples):
                AngularMixture(k, random_state=i).fit(xs)

        one_by_one()
        t_single = best_time(one_by_one, repeat=3)
        c_single = best_time(one_by_one, repeat=3, clock=time.thread_time)
    t_n3 = best_time(lambda: fit_mixtures(samples, k, n_init=3, random_state=0), repeat=1)
    loose = fit_mixtures(samples, k, tol=1e-3, random_state=0)
    t_loose = best_time(lambda: fit_mixtures(samples, k, tol=1e-3, random_state=0), repeat=3)
    x = np.random.default_rng(1).uniform(-np.pi, np.pi, 10)
    t_dens = best_time(lambda: mixture_log_density(x, res.weights, res.means, res.sigmas), repeat=5, number=10)
    figs: dict[str, Any] = {
        "mixtures": m,
        "points_per_mixture": 100,
        "k": k,
        "n_init": DEFAULT_N_INIT,
        "numba_threads": threads,
        "fingerloc_ms_per_fit": 1e3 * t_par / m,
        "fingerloc_1thread_ms_per_fit": 1e3 * t_one / m,
        "fingerloc_mean_em_iterations": float(res.n_iter.mean()),
        "fingerloc_converged_share": float(res.converged.mean()),
        "fingerloc_single_fit_call_ms": 1e3 * t_single / m,
        "fingerloc_single_fit_call_cpu_ms": 1e3 * c_single / m,
        "fingerloc_n_init3_ms_per_fit": 1e3 * t_n3 / m,
        "fingerloc_tol1e-3_ms_per_fit": 1e3 * t_loose / m,
        "fingerloc_tol1e-3_mean_em_iterations": float(loose.n_iter.mean()),
        "log_density_ms_M_by_10": 1e3 * t_dens,
    }
    sk = _sklearn_per_fit(samples, k)
    if sk is None:
        figs["sklearn"] = "unavailable (pip install scikit-learn)"
    else:
        # on a loaded machine scikit-learn's thread pools can slow it down: time it on one thread too, keep the faster
        sk1 = _sklearn_per_fit(samples, k, one_thread=True)
        assert sk1 is not None
        figs["sklearn_threads_ms_per_fit"] = 1e3 * sk[0]
        figs["sklearn_1thread_ms_per_fit"] = 1e3 * sk1[0]
        figs["sklearn_1thread_cpu_ms_per_fit"] = 1e3 * sk1[2]
        figs["speedup_single_fit_call_vs_sklearn_1thread_cpu"] = sk1[2] / (c_single / m)
        sk = min(sk, sk1)
        figs["sklearn_ms_per_fit"] = 1e3 * sk[0]
        figs["sklearn_mean_em_iterations"] = sk[1]
        figs["speedup_vs_sklearn"] = sk[0] / (t_par / m)
        figs["speedup_single_fit_call_vs_sklearn"] = sk[0] / (t_single / m)
        figs["speedup_vs_sklearn_1thread"] = sk[0] / (t_one / m)
        figs["speedup_vs_sklearn_n_init3"] = sk[0] / (t_n3 / m)
        figs["speedup_vs_sklearn_same_tol"] = sk[0] / (t_loose / m)
    return figs
