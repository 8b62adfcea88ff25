"""Time one ``AngularMixture(5).fit`` and compare fits between two trees (issue 17, docs/RESULTS.md).

    python scripts/mog_single_fit.py time [--samples 300] [--rounds 7]
        thread CPU per call of AngularMixture(5, random_state=i).fit on the
        bench samples of ``fingerloc bench speed --only mog``, best of the
        rounds, and the same for the compiled call alone
    python scripts/mog_single_fit.py ref FILE.npz     # fits of this tree
    python scripts/mog_single_fit.py cmp FILE.npz     # this tree against them

``ref``/``cmp`` fit 600 random cases (k 1-8, n 1-250, 1-3 starts; uniform,
rounded von Mises (ties) and mixture bearings) through ``AngularMixture.fit``
and the 1,000 bench samples through it and through ``fit_mixtures``. To
compare two trees, run ``ref`` with one on ``PYTHONPATH`` and ``cmp`` with
the other.
"""

from __future__ import annotations

import argparse
import math
import time
import warnings

import numpy as np

from fingerloc import _mog_kernels as kernels
from fingerloc.experiments.speed_mog import make_samples
from fingerloc.mog import AngularMixture, ConvergenceWarning, fit_mixtures


def _cases() -> list[tuple[np.ndarray, int, int, int]]:
    out = []
    rng = np.random.default_rng(123)
    for c in range(600):
        k, n, ni = int(rng.integers(1, 9)), int(rng.integers(1, 251)), int(rng.integers(1, 4))
        if c % 3 == 0:
            x = rng.uniform(-4, 4, n)
        elif c % 3 == 1:
            x = np.round(rng.vonmises(0.5, 3.0, n), 1)
        else:
            kk = int(rng.integers(1, 6))
            mu, sg = rng.uniform(-np.pi, np.pi, kk), np.deg2rad(rng.uniform(2, 40, kk))
            lab = rng.integers(0, kk, n)
            x = mu[lab] + rng.normal(0, sg[lab])
        out.append((x, k, ni, c))
    return out


def _row(g: AngularMixture) -> np.ndarray:
    return np.r_[g.weights_, g.means_, g.sigmas_, g.lower_bound_, g.n_iter_, g.converged_]


def _fits() -> tuple[list[np.ndarray], np.ndarray]:
    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        for x, k, ni, seed in _cases():
            rows.append(_row(AngularMixture(k, n_init=ni, random_state=seed).fit(x)))
        samples = make_samples(1000, 100, 5)
        for i, x in enumerate(samples):
            rows.append(_row(AngularMixture(5, random_state=i).fit(x)))
        b = fit_mixtures(samples, 5, random_state=0)
    return rows, np.c_[b.weights, b.means, b.sigmas, b.lower_bound, b.n_iter, b.converged]


def _compare(path: str) -> None:
    rows, batch = _fits()
    ref = np.load(path)
    same = flips = 0
    dpar = dll = 0.0
    for i, r in enumerate(rows):
        q = ref[f"r{i}"]
        k = (r.size - 3) // 3
        same += bool(np.array_equal(r, q))
        if r[-2] != q[-2] or r[-1] != q[-1]:
            flips += 1
            print(f"fit {i}: n_iter, converged {r[-2:]} against {q[-2:]}")
            continue
        a, b = r[: 3 * k].reshape(3, k), q[: 3 * k].reshape(3, k)
        d = np.abs(a - b)
        d[1] = np.minimum(d[1], 2 * np.pi - d[1])
        if d.max() > 1e-9:  # the same mixture with its components in another order
            d = np.abs(a[:, np.lexsort(a[::-1])] - b[:, np.lexsort(b[::-1])])
        dpar, dll = max(dpar, float(d.max())), max(dll, abs(r[-3] - q[-3]))
    print(f"{len(rows)} fits: {same} equal bit for bit, {flips} with another n_iter or converged; "
          f"largest parameter difference {dpar:.3g}, lower bound {dll:.3g}")
    b0 = ref["batch"]
    print(f"fit_mixtures, 1,000 bench samples: n_iter equal {np.array_equal(batch[:, -2], b0[:, -2])}, "
          f"converged equal {np.array_equal(batch[:, -1], b0[:, -1])}, largest difference {np.abs(batch - b0).max():.3g}")


def _time(m: int, rounds: int) -> None:
    samples = make_samples(1000, 100, 5)[:m]

    def fits() -> None:
        for i, x in enumerate(samples):
            AngularMixture(5, random_state=i).fit(x)

    bufs = [np.empty((4, 5)) for _ in samples]
    for i, b in enumerate(bufs):
        b[3:] = np.random.default_rng(i).random((1, 5))

    def compiled() -> None:  # the compiled call alone, uniforms given (seed -1)
        for x, b in zip(samples, bufs, strict=True):
            kernels.fit_single(x, 5, b, -1, 1e-6, 500, math.radians(1.0))

    def best(f, clock=time.thread_time) -> float:  # type: ignore[no-untyped-def]
        t = math.inf
        for _ in range(rounds):
            t0 = clock()
            f()
            t = min(t, clock() - t0)
        return 1e6 * t / m

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        fits()
        compiled()
        print(f"AngularMixture(5).fit: {best(fits):.1f} us CPU per call ({best(fits, time.perf_counter):.1f} us wall)")
        print(f"compiled fit_single alone: {best(compiled):.1f} us CPU per call")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=["time", "ref", "cmp"])
    ap.add_argument("path", nargs="?")
    ap.add_argument("--samples", type=int, default=300)
    ap.add_argument("--rounds", type=int, default=7)
    a = ap.parse_args()
    if a.mode == "time":
        _time(a.samples, a.rounds)
    elif a.mode == "ref":
        rows, batch = _fits()
        np.savez(a.path, batch=batch, **{f"r{i}": r for i, r in enumerate(rows)})
    else:
        _compare(a.path)


if __name__ == "__main__":
    main()
