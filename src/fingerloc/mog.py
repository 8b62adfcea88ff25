"""Mixtures of Gaussians in angle space, fit by EM (docs/METHOD.md §3).

One component is a Gaussian over the circle, truncated to one turn around its
mean and normalised::

    p(x | mu, sigma) = eta * exp(-distAS(mu, x)^2 / (2 sigma^2))
    eta = 1 / ( sqrt(2 pi) * sigma * erf( pi / (sqrt(2) sigma) ) )

and a mixture is ``p_MOG(x | theta) = sum_k w_k p(x | mu_k, sigma_k)``. EM
follows the paper's equations 9-11 (see :func:`fit_mixtures`).

What the paper leaves open, and our answers
-------------------------------------------
Initialisation
    k-means++ seeding on the circle: the first centre is a data point drawn
    uniformly, each next one a data point drawn with probability proportional
    to its squared circular distance (distAS) to the nearest centre so far.
    Every point is then given to its nearest centre and one M-step turns these
    hard responsibilities into the starting weights, means and sigmas.
Restarts
    ``n_init`` seedings (default :data:`DEFAULT_N_INIT`); the run with the
    highest final log-likelihood is kept (the first one on ties).
Sigma floor
    ``min_sigma_deg`` (default :data:`DEFAULT_MIN_SIGMA_DEG`): after each
    sigma update, ``sigma = max(sigma, min_sigma)``. Without it a component
    that owns one point (or several equal ones) collapses to sigma -> 0 and the
    likelihood diverges. One degree is about the bearing resolution of the
    features we extract; below it a narrower component models nothing real.
Fewer distinct points than components
    The seeding stops when every point lies on a centre, so a sample with
    ``d < n_components`` distinct bearings (exact equality after wrapping)
    gets ``d`` components; the others are *padding*: weight exactly 0, mean 0,
    sigma 1 rad, ignored by every density. A single point, or all points
    equal, thus gives one component at that bearing with sigma at the floor.
Dying components
    A component whose responsibilities sum to less than 1e-10 points gets
    weight 0 for good (its mean and sigma would be 0/0).
Stopping
    On the *mean* log-likelihood per sample (as scikit-learn does): EM stops
    when one iteration gains less than ``tol``. A step that lowers it, which
    only round-off or a component so wide that the truncation at +-pi matters
    can cause (the paper's sigma update ignores the truncation), is undone and
    ends the run: the returned parameters are never worse than an earlier
    iterate. Reaching ``max_iter`` first leaves ``converged`` False and
    :class:`AngularMixture` emits a :class:`ConvergenceWarning`.
Empty input
    :class:`~fingerloc.errors.InvalidParameterError`.

References
----------
.. [1] A. Tapus, S. Heinzer, R. Siegwart, "Bayesian Programming for
   Topological Global Localization with Fingerprints", ICRA 2004, eqs. 9-11.
.. [2] D. Arthur, S. Vassilvitskii, "k-means++: the advantages of careful
   seeding", SODA 2007.
"""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _mog_kernels as _k
from . import _seed_kernels as _sk
from ._estimator import ParamsMixin
from ._numba_guard import try_parallel
from .angles import wrap
from .errors import InvalidParameterError, NotFittedError
from .validation import check_random_state

__all__ = [
    "DEFAULT_MIN_SIGMA_DEG",
    "DEFAULT_N_INIT",
    "AngularMixture",
    "ConvergenceWarning",
    "MixtureSet",
    "component_log_density",
    "fit_mixtures",
    "mixture_log_density",
]

#: Default number of k-means++ restarts of EM.
DEFAULT_N_INIT = 1
#: Default floor of every component's sigma, in degrees.
DEFAULT_MIN_SIGMA_DEG = 1.0
#: From this many mixtures on, :func:`fit_mixtures` spreads them over numba's
#: threads (``NUMBA_NUM_THREADS``); the results are the same either way.
PARALLEL_MIN_MIXTURES = 16
#: Fewest (mixtures x components x bearings) for which :func:`mixture_log_density` uses threads.
PARALLEL_MIN_DENSITY_CELLS = 8192

Float64Array = NDArray[np.float64]


class ConvergenceWarning(UserWarning):
    """EM reached ``max_iter`` before its log-likelihood gain fell below ``tol``."""


def _check_int(name: str, value: object, minimum: int) -> int:
    if not isinstance(value, numbers.Integral) or isinstance(value, bool) or int(value) < minimum:
        raise InvalidParameterError(f"{name} must be an int >= {minimum}, got {value!r}")
    return int(value)


def _check_params(
    n_components: object, tol: object, max_iter: object, n_init: object, min_sigma_deg: object
) -> tuple[int, float, int, int, float]:
    if (  # the common case, plain ints and floats in range, checked at the cost of one call
        type(n_components) is int
        and type(max_iter) is int
        and type(n_init) is int
        and type(tol) is float
        and (type(min_sigma_deg) is float or type(min_sigma_deg) is int)
        and n_components >= 1
        and max_iter >= 1
        and n_init >= 1
        and 0.0 <= tol < math.inf
        and 0.0 < min_sigma_deg <= 360.0
    ):
        return n_components, tol, max_iter, n_init, float(min_sigma_deg)
    k = _check_int("n_components", n_components, 1)
    it = _check_int("max_iter", max_iter, 1)
    ni = _check_int("n_init", n_init, 1)
    if not isinstance(tol, numbers.Real) or not (float(tol) >= 0.0) or not math.isfinite(float(tol)):
        raise InvalidParameterError(f"tol must be a finite float >= 0, got {tol!r}")
    if (
        not isinstance(min_sigma_deg, numbers.Real)
        or not math.isfinite(float(min_sigma_deg))
        or not (0.0 < float(min_sigma_deg) <= 360.0)
    ):
        raise InvalidParameterError(f"min_sigma_deg must be in (0, 360] degrees, got {min_sigma_deg!r}")
    return k, float(tol), it, ni, float(min_sigma_deg)


def _as_vector(x: ArrayLike, name: str) -> Float64Array:
    """``x`` as a C-contiguous 1-D float64 array (shape (n,) or scikit-learn's (n, 1)); not wrapped, not checked for nan."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise InvalidParameterError(f"{name} must be an array of bearings in radians: {err}") from err
    if a.ndim == 2 and a.shape[1] == 1:  # scikit-learn's (n_samples, 1) column
        a = a[:, 0]
    if a.ndim != 1:
        raise InvalidParameterError(f"{name} must be 1-D (n,) or (n, 1), got shape {a.shape}")
    return np.ascontiguousarray(a)


def _as_bearings(x: ArrayLike, name: str) -> Float64Array:
    """Validate a 1-D array of bearings (radians) and wrap it to [-pi, pi)."""
    a = _as_vector(x, name)
    if not np.all(np.isfinite(a)):
        raise InvalidParameterError(f"{name} holds a non-finite bearing (nan or inf)")
    return np.ascontiguousarray(wrap(a))


#: Whether :func:`fingerloc._seed_kernels.default_rng_random` draws numpy's numbers (checked on first use).
_seeding_matches_numpy: bool | None = None


def _compiled_seeding_ok() -> bool:
    """Check once per process that the compiled ``default_rng(seed).random`` equals numpy's, bit for bit."""
    global _seeding_matches_numpy
    if _seeding_matches_numpy is None:
        ok = True
        for seed in (0, 12345, 2**40 + 3):
            got = np.empty(6)
            _sk.default_rng_random(seed, got)
            ok &= bool(np.array_equal(got, np.random.default_rng(seed).random(6)))
        _seeding_matches_numpy = ok
    return _seeding_matches_numpy


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True)
    a.flags.writeable = False
    return a


@dataclass(frozen=True, slots=True)
class MixtureSet:
    """M fitted angular mixtures with up to K components each.

    Attributes
    ----------
    weights : ndarray of float64, shape (M, K)
        Rows sum to 1; padding and dead components have weight exactly 0.
    means : ndarray of float64, shape (M, K)
        Component means in radians, in ``[-pi, pi)``.
    sigmas : ndarray of float64, shape (M, K)
        Component standard deviations in radians, > 0 (padding: 1.0).
    converged : ndarray of bool, shape (M,)
        Whether EM stopped on ``tol`` rather than on ``max_iter``.
    n_iter : ndarray of int64, shape (M,)
        EM iterations of the kept run.
    lower_bound : ndarray of float64, shape (M,)
        Final mean log-likelihood per sample (nats) of the kept run.
    """

    weights: np.ndarray
    means: np.ndarray
    sigmas: np.ndarray
    converged: np.ndarray
    n_iter: np.ndarray
    lower_bound: np.ndarray

    def __post_init__(self) -> None:
        w = np.asarray(self.weights, dtype=np.float64)
        if w.ndim != 2:
            raise InvalidParameterError(f"weights must be (M, K), got shape {w.shape}")
        for name in ("weights", "means", "sigmas"):
            a = np.asarray(getattr(self, name), dtype=np.float64)
            if a.shape != w.shape:
                raise InvalidParameterError(f"{name} must have shape {w.shape}, got {a.shape}")
            object.__setattr__(self, name, _readonly(a))
        per_mixture: tuple[tuple[str, type[np.generic]], ...] = (
            ("converged", np.bool_),
            ("n_iter", np.int64),
            ("lower_bound", np.float64),
        )
        for name, dtype in per_mixture:
            a = np.asarray(getattr(self, name), dtype=dtype)
            if a.shape != (w.shape[0],):
                raise InvalidParameterError(f"{name} must have shape ({w.shape[0]},), got {a.shape}")
            object.__setattr__(self, name, _readonly(a))
        if np.any(self.weights < 0) or np.any(self.sigmas <= 0):
            raise InvalidParameterError("weights must be >= 0 and sigmas > 0")

    def __len__(self) -> int:
        return int(self.weights.shape[0])

    @property
    def n_components(self) -> int:
        """K, the number of component slots per mixture."""
        return int(self.weights.shape[1])

    def log_density(self, x: ArrayLike) -> Float64Array:
        """``log p_MOG(x_j | theta_m)``, shape (M, n); see :func:`mixture_log_density`."""
        return mixture_log_density(np.asarray(x, dtype=np.float64), self.weights, self.means, self.sigmas)


def fit_mixtures(
    samples: Sequence[ArrayLike],
    n_components: int,
    *,
    tol: float = 1e-6,
    max_iter: int = 500,
    n_init: int = DEFAULT_N_INIT,
    min_sigma_deg: float = DEFAULT_MIN_SIGMA_DEG,
    random_state: int | np.random.Generator | None = None,
) -> MixtureSet:
    """Fit one angular mixture per sample array by EM, all in one compiled loop.

    EM (docs/METHOD.md §3, the paper's eqs. 9-11), with responsibilities
    ``r_ik = w_k p(x_i | theta_k) / sum_j w_j p(x_i | theta_j)``::

        w_k     = (1/N) sum_i r_ik
        mu_k    = wrap( mu_k + sum_i r_ik distAS(mu_k, x_i) / sum_i r_ik )
        sigma_k = max( sqrt( sum_i r_ik distAS(mu_k_new, x_i)^2 / sum_i r_ik ), min_sigma )

    Initialisation, restarts, the sigma floor, degenerate samples and the
    stopping rule are described in the module docstring.

    Parameters
    ----------
    samples : sequence of array_like, each of shape (n_m,)
        Bearings in radians (any real value; wrapped to ``[-pi, pi)``). Each
        must hold at least one finite bearing.
    n_components : int
        K >= 1, components per mixture (fewer are used when a sample has fewer
        distinct bearings).
    tol : float, default 1e-6
        Stop when the mean log-likelihood per sample gains less than this.
    max_iter : int, default 500
        Maximum EM iterations per start.
    n_init : int, default :data:`DEFAULT_N_INIT`
        k-means++ starts per mixture; the best final log-likelihood is kept.
    min_sigma_deg : float, default :data:`DEFAULT_MIN_SIGMA_DEG`
        Floor of every sigma, degrees, in (0, 360].
    random_state : int, numpy.random.Generator or None
        Seeds the k-means++ draws. For a given int the result is fixed, and
        mixture m depends only on its own sample and on m.

    Returns
    -------
    MixtureSet
        ``M = len(samples)`` mixtures with K component slots each.

    Raises
    ------
    InvalidParameterError
        A bad parameter, an empty, non-1-D or non-finite sample, or no samples.

    Notes
    -----
    Never warns: a mixture that reached ``max_iter`` has ``converged`` False.
    From :data:`PARALLEL_MIN_MIXTURES` mixtures on, the fits run on numba's
    threads; the results do not depend on it.
    """
    k, tol_f, it, ni, msd = _check_params(n_components, tol, max_iter, n_init, min_sigma_deg)
    rng = check_random_state(random_state)
    if isinstance(samples, np.ndarray) and samples.ndim == 1 and samples.dtype != object:
        raise InvalidParameterError(
            "samples must be a sequence of bearing arrays, got one 1-D array (wrap it in a list)"
        )
    arrays = [_as_bearings(s, f"samples[{i}]") for i, s in enumerate(samples)]
    for i, a in enumerate(arrays):
        if a.size == 0:
            raise InvalidParameterError(f"samples[{i}] is empty: a mixture needs at least one bearing")
    m = len(arrays)
    if m == 0:
        raise InvalidParameterError("samples is empty: give at least one array of bearings")
    offsets = np.zeros(m + 1, dtype=np.int64)
    offsets[1:] = np.cumsum([a.size for a in arrays])
    x = np.concatenate(arrays)
    u = rng.random((m, ni, k))
    return _fit(x, offsets, k, u, tol_f, it, math.radians(msd))


def _fit(
    x: Float64Array,
    offsets: NDArray[np.int64],
    k: int,
    u: Float64Array,
    tol: float,
    max_iter: int,
    min_sigma: float,
    trace: Float64Array | None = None,
) -> MixtureSet:
    m = offsets.size - 1
    w = np.empty((m, k))
    mu = np.empty((m, k))
    sg = np.empty((m, k))
    conv = np.zeros(m, dtype=np.bool_)
    n_iter = np.zeros(m, dtype=np.int64)
    ll = np.empty(m)
    # numba's default threading layer must not be entered by two Python threads at once:
    # a caller that finds it busy runs the serial kernel instead (same results).
    with try_parallel() as free:
        if trace is None and m >= PARALLEL_MIN_MIXTURES and free:
            _k.fit_batch_parallel(x, offsets, k, u, tol, max_iter, min_sigma, w, mu, sg, conv, n_iter, ll)
        else:
            tr = np.empty((0, 0, 0)) if trace is None else trace
            _k.fit_batch(x, offsets, k, u, tol, max_iter, min_sigma, w, mu, sg, conv, n_iter, ll, tr)
    return MixtureSet(weights=w, means=mu, sigmas=sg, converged=conv, n_iter=n_iter, lower_bound=ll)


def _em_traces(
    x: ArrayLike,
    n_components: int,
    *,
    tol: float = 1e-6,
    max_iter: int = 500,
    n_init: int = 1,
    min_sigma_deg: float = DEFAULT_MIN_SIGMA_DEG,
    random_state: int | np.random.Generator | None = None,
) -> tuple[MixtureSet, Float64Array]:
    """Fit one mixture and return the raw per-iteration log-likelihoods (for tests).

    Returns the fit and an array (n_init, max_iter + 1): entry ``[t, i]`` is
    the mean log-likelihood after ``i`` M-steps of start ``t`` (nan after the
    run stopped).
    """
    k, tol_f, it, ni, msd = _check_params(n_components, tol, max_iter, n_init, min_sigma_deg)
    rng = check_random_state(random_state)
    xa = _as_bearings(x, "x")
    if xa.size == 0:
        raise InvalidParameterError("x is empty")
    trace = np.full((1, ni, it + 1), np.nan)
    u = rng.random((1, ni, k))
    fit = _fit(xa, np.array([0, xa.size], dtype=np.int64), k, u, tol_f, it, math.radians(msd), trace)
    return fit, trace[0]


def _as_params(weights: ArrayLike, means: ArrayLike, sigmas: ArrayLike) -> tuple[Float64Array, ...]:
    w = np.asarray(weights, dtype=np.float64)
    mu = np.asarray(means, dtype=np.float64)
    sg = np.asarray(sigmas, dtype=np.float64)
    if w.ndim == 1:  # one mixture
        w, mu, sg = w[None], np.atleast_2d(mu), np.atleast_2d(sg)
    if w.ndim != 2 or mu.shape != w.shape or sg.shape != w.shape:
        raise InvalidParameterError(
            f"weights, means and sigmas must share one (M, K) shape, got {w.shape}, {mu.shape}, {sg.shape}"
        )
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(mu)) and np.all(np.isfinite(sg))):
        raise InvalidParameterError("weights, means and sigmas must be finite")
    if np.any(w < 0):
        raise InvalidParameterError("weights must be >= 0")
    if w.shape[1] == 0 or np.any(w.max(axis=1) <= 0):
        raise InvalidParameterError("every mixture needs at least one component with weight > 0")
    if np.any(sg[w > 0] <= 0):
        raise InvalidParameterError("sigmas of weighted components must be > 0")
    return np.ascontiguousarray(w), np.ascontiguousarray(wrap(mu)), np.ascontiguousarray(np.where(w > 0, sg, 1.0))


def mixture_log_density(x: ArrayLike, weights: ArrayLike, means: ArrayLike, sigmas: ArrayLike) -> Float64Array:
    """``log p_MOG(x_j | theta_m)`` for every bearing and every mixture (docs/METHOD.md §3).

    Parameters
    ----------
    x : array_like, shape (n,)
        Bearings in radians (wrapped internally).
    weights : array_like, shape (M, K) (or (K,) for one mixture)
        Component weights, >= 0, used as given (not renormalised);
        zero-weight components are ignored.
    means : array_like, shape (M, K)
        Component means, radians.
    sigmas : array_like, shape (M, K)
        Component sigmas, radians, > 0 where the weight is > 0.

    Returns
    -------
    ndarray of float64, shape (M, n)
        Log-densities in nats per radian (log of a density over one turn).
    """
    xa = _as_bearings(x, "x")
    w, mu, sg = _as_params(weights, means, sigmas)
    out = np.empty((w.shape[0], xa.size))
    if not xa.size:
        return out
    threads = numba.get_num_threads()
    # Threads pay off from a few thousand component-bearing pairs (a place database against one view).
    with try_parallel() as free:
        if threads > 1 and w.size * xa.size >= PARALLEL_MIN_DENSITY_CELLS and free:
            _k.log_density_batch_parallel(xa, w, mu, sg, out, threads)
        else:
            _k.log_density_batch(xa, w, mu, sg, out)
    return out


def component_log_density(x: ArrayLike, mean: float, sigma: float) -> Float64Array:
    """``log p(x | mu, sigma)`` of one truncated angular Gaussian (docs/METHOD.md §3), shape of ``x``.

    Plain numpy; the reference the compiled kernels are tested against.
    """
    if not (sigma > 0 and math.isfinite(sigma)):
        raise InvalidParameterError(f"sigma must be a finite float > 0, got {sigma!r}")
    xa = np.asarray(x, dtype=np.float64)
    d = wrap(xa - mean)
    d = np.where(d <= -np.pi, d + 2 * np.pi, d)
    log_eta = -(0.5 * math.log(2 * math.pi) + math.log(sigma) + math.log(math.erf(math.pi / (math.sqrt(2) * sigma))))
    return np.asarray(log_eta - d * d / (2.0 * sigma * sigma), dtype=np.float64)


class AngularMixture(ParamsMixin):
    """A mixture of truncated Gaussians on the circle, fit by EM (docs/METHOD.md §3).

    scikit-learn-like: the constructor only stores its arguments; :meth:`fit`
    learns the attributes ending in ``_``. Bearings are radians; ``X`` may be
    of shape (n,) or (n, 1).

    Parameters
    ----------
    n_components : int, default 3
        K, component slots (fewer are used on samples with fewer distinct bearings).
    tol : float, default 1e-6
        Stop when the mean log-likelihood per sample gains less than this.
    max_iter : int, default 500
        Maximum EM iterations per start.
    n_init : int, default :data:`DEFAULT_N_INIT`
        k-means++ starts; the best final log-likelihood is kept.
    min_sigma_deg : float, default :data:`DEFAULT_MIN_SIGMA_DEG`
        Floor of every sigma, degrees.
    random_state : int, numpy.random.Generator or None
        Seeds the k-means++ draws (and :meth:`sample` when it gets none).

    Attributes
    ----------
    weights_ : ndarray, shape (K,)
        Component weights, sum 1; padding components have 0.
    means_ : ndarray, shape (K,)
        Means, radians in ``[-pi, pi)``.
    sigmas_ : ndarray, shape (K,)
        Sigmas, radians.
    converged_ : bool
    n_iter_ : int
    lower_bound_ : float
        Mean log-likelihood per sample of the fit (nats).
    n_components_ : int
        Components with weight > 0.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> x = np.deg2rad(np.r_[rng.normal(179, 5, 300), rng.normal(60, 10, 300)])
    >>> gm = AngularMixture(2, random_state=0).fit(x)
    >>> sorted(np.round(np.rad2deg(gm.means_)).tolist())
    [60.0, 179.0]
    >>> gm.score_samples(np.deg2rad([180.0, 0.0])).round(1).tolist()
    [0.8, -18.7]

    Notes
    -----
    ``AngularMixture(...).fit(x)`` gives exactly ``fit_mixtures([x], ...)`` with
    the same arguments and the same ``random_state``: both run
    :func:`fingerloc._mog_kernels.fit_batch`.
    """

    def __init__(
        self,
        n_components: int = 3,
        *,
        tol: float = 1e-6,
        max_iter: int = 500,
        n_init: int = DEFAULT_N_INIT,
        min_sigma_deg: float = DEFAULT_MIN_SIGMA_DEG,
        random_state: int | np.random.Generator | None = None,
    ) -> None:
        self.n_components = n_components
        self.tol = tol
        self.max_iter = max_iter
        self.n_init = n_init
        self.min_sigma_deg = min_sigma_deg
        self.random_state = random_state

    def fit(self, X: ArrayLike, y: object = None) -> AngularMixture:
        """Fit by EM on bearings ``X`` (radians, shape (n,) or (n, 1), n >= 1); returns ``self``.

        Gives exactly ``fit_mixtures([X], ...)`` with the same arguments (the
        same compiled fit and the same random draws), through a shorter path:
        one compiled call that checks and wraps ``X``, draws the seeding's
        uniforms (for an int ``random_state``) and fits; no :class:`MixtureSet`.
        """
        k, tol_f, it, ni, msd = _check_params(
            self.n_components, self.tol, self.max_iter, self.n_init, self.min_sigma_deg
        )
        rs = self.random_state
        # rows 0-2 receive the weights, means and sigmas; rows 3: hold the uniforms of the seeding, the draws
        # fit_mixtures makes for one sample (its u[m], shape (n_init, k))
        buf = np.empty((3 + ni, k))
        rng = None
        if type(rs) is int and 0 <= rs < 2**63 and (_seeding_matches_numpy or _compiled_seeding_ok()):
            seed = rs  # default_rng(rs).random((n_init, k)), drawn in the compiled call
        else:
            rng = check_random_state(rs)
            seed = -1
        xa: Float64Array
        if isinstance(X, np.ndarray) and X.dtype == np.float64 and X.ndim == 1:
            fl = X.flags  # read, never written: writeable so that all calls share one compiled specialisation
            xa = X if fl.c_contiguous and fl.writeable else np.array(X)
        else:
            xa = _as_vector(X, "X")
            if not xa.flags.writeable:
                xa = xa.copy()
        if xa.size == 0:
            raise InvalidParameterError("X is empty: a mixture needs at least one bearing")
        if rng is not None:  # a Generator (or None): draw from it only for a valid X, as before
            if not np.all(np.isfinite(xa)):
                raise InvalidParameterError("X holds a non-finite bearing (nan or inf)")
            buf[3:] = rng.random((ni, k))
        # one compiled call: the check for nan and inf, wrap(X) into a new array, the draws, the fit
        conv, n_iter, ll, used = _k.fit_single(xa, k, buf, seed, tol_f, it, math.radians(msd))
        if used < 0:
            raise InvalidParameterError("X holds a non-finite bearing (nan or inf)")
        self.weights_ = buf[0]
        self.means_ = buf[1]
        self.sigmas_ = buf[2]
        self.converged_ = bool(conv)
        self.n_iter_ = int(n_iter)
        self.lower_bound_ = float(ll)
        self.n_components_ = int(used)
        if not self.converged_:
            warnings.warn(
                f"EM did not converge in max_iter={self.max_iter} iterations (tol={self.tol}); raise max_iter or tol",
                ConvergenceWarning,
                stacklevel=2,
            )
        return self

    def _check_fitted(self) -> None:
        if not hasattr(self, "weights_"):
            raise NotFittedError("this AngularMixture is not fitted yet: call fit first")

    def score_samples(self, X: ArrayLike) -> Float64Array:
        """Log-density ``log p_MOG(x)`` of each bearing, shape (n,), nats per radian."""
        self._check_fitted()
        return mixture_log_density(X, self.weights_[None], self.means_[None], self.sigmas_[None])[0]

    def score(self, X: ArrayLike, y: object = None) -> float:
        """Mean log-density of ``X`` per sample."""
        s = self.score_samples(X)
        if s.size == 0:
            raise InvalidParameterError("X is empty: cannot average over no bearings")
        return float(s.mean())

    def _n_parameters(self) -> int:
        # per used component a weight, a mean and a sigma; the weights sum to 1
        return 3 * int(np.count_nonzero(self.weights_ > 0)) - 1

    def bic(self, X: ArrayLike) -> float:
        """Bayesian information criterion on ``X``: ``-2 log L + p log n`` (lower is better).

        ``p = 3 k_used - 1`` counts the weight, mean and sigma of each component
        with weight > 0, less one for the weights summing to 1.
        """
        s = self.score_samples(X)
        if s.size == 0:
            raise InvalidParameterError("X is empty")
        return float(-2.0 * s.sum() + self._n_parameters() * math.log(s.size))

    def aic(self, X: ArrayLike) -> float:
        """Akaike information criterion on ``X``: ``-2 log L + 2 p`` (lower is better)."""
        s = self.score_samples(X)
        if s.size == 0:
            raise InvalidParameterError("X is empty")
        return float(-2.0 * s.sum() + 2.0 * self._n_parameters())

    def _log_joint(self, X: ArrayLike) -> Float64Array:
        xa = _as_bearings(X, "X")
        out = np.full((xa.size, self.weights_.size), -np.inf)
        for j in np.flatnonzero(self.weights_ > 0):
            out[:, j] = math.log(self.weights_[j]) + component_log_density(xa, self.means_[j], self.sigmas_[j])
        return out

    def predict_log_proba(self, X: ArrayLike) -> Float64Array:
        """Log responsibilities ``log r_ik``, shape (n, K); padding columns are -inf."""
        self._check_fitted()
        lj = self._log_joint(X)
        if lj.shape[0] == 0:
            return lj
        mx = lj.max(axis=1, keepdims=True)
        return np.asarray(lj - (mx + np.log(np.exp(lj - mx).sum(axis=1, keepdims=True))), dtype=np.float64)

    def predict_proba(self, X: ArrayLike) -> Float64Array:
        """Responsibilities ``r_ik``, shape (n, K), rows sum to 1; padding columns are 0."""
        return np.exp(self.predict_log_proba(X))

    def predict(self, X: ArrayLike) -> NDArray[np.int64]:
        """Most responsible component of each bearing, shape (n,)."""
        return np.asarray(self.predict_log_proba(X).argmax(axis=1), dtype=np.int64)

    def sample(
        self, n_samples: int = 1, *, random_state: int | np.random.Generator | None = None
    ) -> tuple[Float64Array, NDArray[np.int64]]:
        """Draw bearings from the fitted mixture.

        Each draw picks a component by weight, then ``mu + z`` wrapped, with
        ``z ~ N(0, sigma^2)`` truncated to ``(-pi, pi]`` (rejection).

        Parameters
        ----------
        n_samples : int, default 1
        random_state : int, Generator or None
            Defaults to the estimator's ``random_state``.

        Returns
        -------
        x : ndarray of float64, shape (n_samples,)
            Bearings in radians, ``[-pi, pi)``.
        labels : ndarray of int64, shape (n_samples,)
            The component each draw came from.
        """
        self._check_fitted()
        n = _check_int("n_samples", n_samples, 1)
        rng = check_random_state(self.random_state if random_state is None else random_state)
        labels = rng.choice(self.weights_.size, size=n, p=self.weights_ / self.weights_.sum())
        z = np.empty(n)
        todo = np.arange(n)
        while todo.size:
            draw = rng.normal(0.0, self.sigmas_[labels[todo]])
            ok = (draw > -np.pi) & (draw <= np.pi)
            z[todo[ok]] = draw[ok]
            todo = todo[~ok]
        return wrap(self.means_[labels] + z), labels.astype(np.int64)
