"""The angle-space mixture terms ``P(f | Loc)``, f in VE, CP, Ex, B (docs/METHOD.md §3-4).

``P(f | loc) = prod_{x in f} p_MOG(x | theta_{f,loc})``, ``theta_{f,loc}`` fit
by EM on every training bearing of ``f`` at ``loc`` (:func:`fingerloc.mog.fit_mixtures`).

Choices the paper leaves open:

* a place with no training bearing of the type gets the uniform density
  ``1 / (2 pi)`` (it says nothing for or against a bearing);
* an observation with no bearing of the type adds ``log 1 = 0`` everywhere;
* a field of view narrower than the circle renormalises each mixture to the
  seen arc, ``p(x | loc, x seen) = p_MOG(x) / P_MOG(seen)``, the mass
  integrated on a grid of ``fov_grid`` points and floored at ``min_fov_mass``;
* ``outlier_weight`` mixes a uniform component into every place's density,
  ``(1 - w) p_MOG + w / (2 pi)``;
* with ``rotations`` (heading unknown), observation ``i`` is turned by
  ``rotations[i, j]`` before place ``j`` scores it, field of view included.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..angles import TWO_PI, wrap
from ..observation import Observation
from .base import FArray, Term

__all__ = ["LOG_UNIFORM", "MOG_TERMS", "MixtureTerm", "fit_mixture_terms"]

#: Terms of the Bayesian program computed from mixtures of Gaussians, in fitting order.
MOG_TERMS: tuple[str, ...] = ("VE", "CP", "Ex", "B")
LOG_UNIFORM = -math.log(TWO_PI)

Mixture = tuple[FArray, FArray, FArray]


class MixtureTerm(Term):
    """``P(f | Loc)`` for one feature type ``f`` as a product of angular mixtures.

    Parameters
    ----------
    name : {"VE", "CP", "Ex", "B"}
    n_components, min_sigma_deg, tol, max_iter, n_init, random_state
        Mixture fitting (:func:`fingerloc.mog.fit_mixtures`).
    outlier_weight : float
        Weight of the uniform component mixed into every place's density.
    fov_grid : int
        Grid points used to integrate a mixture over a partial field of view.
    min_fov_mass : float
        Floor of a mixture's mass inside a partial field of view.

    Attributes
    ----------
    mixtures_ : list of (weights, means, sigmas) or None
        Per place, arrays of shape ``(K,)`` (radians); None where the place
        had no training bearing of this type.
    """

    heading_free = False

    def __init__(
        self,
        name: str,
        *,
        n_components: int = 5,
        min_sigma_deg: float = 1.0,
        tol: float = 1e-6,
        max_iter: int = 500,
        n_init: int = 3,
        outlier_weight: float = 0.0,
        fov_grid: int = 720,
        min_fov_mass: float = 1e-3,
        random_state: int | np.random.Generator | None = 0,
    ) -> None:
        self.name = name
        self.n_components = n_components
        self.min_sigma_deg = min_sigma_deg
        self.tol = tol
        self.max_iter = max_iter
        self.n_init = n_init
        self.outlier_weight = outlier_weight
        self.fov_grid = fov_grid
        self.min_fov_mass = min_fov_mass
        self.random_state = random_state

    # -- learning --------------------------------------------------------------
    def fit(self, groups: Sequence[Sequence[Observation]]) -> MixtureTerm:
        fit_mixture_terms([self], groups, range(len(groups)), fresh=True)
        return self

    def update(self, groups: Sequence[Sequence[Observation]], changed: Sequence[int]) -> MixtureTerm:
        fit_mixture_terms([self], groups, changed, fresh=False)
        return self

    def _set_mixtures(self, mixtures: list[Mixture | None]) -> None:
        self.mixtures_ = mixtures
        k = max([mx[0].size for mx in mixtures if mx is not None], default=1)
        p = len(mixtures)
        w, m, s = np.zeros((p, k)), np.zeros((p, k)), np.ones((p, k))
        has = np.zeros(p, dtype=bool)
        for j, mx in enumerate(mixtures):
            if mx is not None:
                pw, pm, ps = mx
                w[j, : pw.size], m[j, : pm.size], s[j, : ps.size] = pw, pm, ps
                has[j] = True
        self._stack = (w, m, s, has)
        self._fov_cache: dict[Any, FArray] = {}

    # -- inference -------------------------------------------------------------
    def place_log_density(self, x: FArray) -> FArray:
        """``log p(x_i | place)`` for every place, shape ``(P, n)``; uniform where a place has no mixture."""
        from ..mog import mixture_log_density

        w, m, s, has = self._stack
        if x.size and has.all():  # every place has a mixture: no copy into a uniform background
            return self._with_outliers(mixture_log_density(x, w, m, s))
        out = np.full((w.shape[0], x.size), LOG_UNIFORM)
        if x.size and has.any():
            out[has] = mixture_log_density(x, w[has], m[has], s[has])
        return self._with_outliers(out)

    def _one_place_log_density(self, x: FArray, j: int) -> FArray:
        from ..mog import mixture_log_density

        w, m, s, has = self._stack
        out = mixture_log_density(x, w[j : j + 1], m[j : j + 1], s[j : j + 1])[0] if has[j] else np.full(x.size, LOG_UNIFORM)
        return self._with_outliers(out)

    def _with_outliers(self, logp: FArray) -> FArray:
        if self.outlier_weight > 0:
            w = self.outlier_weight
            return np.logaddexp(np.log1p(-w) + logp, math.log(w) + LOG_UNIFORM)
        return logp

    def fov_log_mass(self, fov: tuple[tuple[float, float], ...]) -> FArray:
        """log of each place's mixture mass inside ``fov``, shape ``(P,)``; 0 for the full circle (cached)."""
        if any(width >= TWO_PI - 1e-12 for _, width in fov):
            return np.zeros(self._stack[0].shape[0])
        if fov not in self._fov_cache:
            grid = wrap(-np.pi + (np.arange(self.fov_grid) + 0.5) * TWO_PI / self.fov_grid)
            inside = np.zeros(grid.size, dtype=bool)
            for start, width in fov:
                inside |= np.mod(grid - start, TWO_PI) <= width
            dens = np.exp(self.place_log_density(grid[inside]))  # (P, g)
            mass = dens.sum(axis=1) * TWO_PI / self.fov_grid
            self._fov_cache[fov] = np.log(np.clip(mass, self.min_fov_mass, 1.0))
        return self._fov_cache[fov]

    def log_likelihood(self, observations: Sequence[Observation], *, rotations: FArray | None = None) -> FArray:
        obs = list(observations)
        n_places = self._stack[0].shape[0]
        ll = np.zeros((len(obs), n_places))
        plain: list[int] = []
        for i, o in enumerate(obs):
            x = o.bearings(self.name)
            if x.size == 0:
                continue
            if rotations is None or not np.any(rotations[i]):
                plain.append(i)
            else:
                ll[i] = self._rotated(o, x, rotations[i])
        if plain:
            # every bearing of every (unturned) observation in one density call, then a sum per observation
            xs = [obs[i].bearings(self.name) for i in plain]
            dens = self.place_log_density(np.concatenate(xs))  # (P, total bearings)
            starts = np.cumsum([0] + [x.size for x in xs[:-1]])
            sums = np.add.reduceat(dens, starts, axis=1).T  # (len(plain), P)
            sizes = np.array([x.size for x in xs], dtype=np.float64)
            by_fov: dict[Any, list[int]] = {}
            for k, i in enumerate(plain):
                by_fov.setdefault(obs[i].fov, []).append(k)
            rows = np.asarray(plain, dtype=np.int64)
            for fov, ks in by_fov.items():  # per observation: sums - n_bearings * log mass in its fov
                mass = self.fov_log_mass(fov)
                ll[rows[ks]] = sums[ks] - sizes[ks, None] * mass[None, :]
        return ll

    def log_likelihood_at(self, observations: Sequence[Observation], places: Sequence[int] | np.ndarray) -> FArray:
        """:meth:`log_likelihood` (no rotations) at the given places only, shape ``(n, len(places))``: the same values."""
        from ..mog import mixture_log_density

        obs = list(observations)
        pl = np.asarray(places, dtype=np.int64)
        ll = np.zeros((len(obs), pl.size))
        w, m, s, has = self._stack
        for i, o in enumerate(obs):
            x = o.bearings(self.name)
            if x.size == 0 or pl.size == 0:
                continue
            dens = np.full((pl.size, x.size), LOG_UNIFORM)
            sel = has[pl]
            if sel.any():
                dens[sel] = mixture_log_density(x, w[pl[sel]], m[pl[sel]], s[pl[sel]])
            dens = self._with_outliers(dens)
            sums = np.add.reduceat(dens, np.zeros(1, dtype=np.int64), axis=1)[:, 0]
            ll[i] = sums - x.size * self.fov_log_mass(o.fov)[pl]
        return ll

    def _rotated(self, o: Observation, x: FArray, rot: FArray) -> FArray:
        """Per place ``j``: the log-likelihood of ``x`` turned by ``rot[j]`` (its field of view too)."""
        out = np.empty(rot.size)
        for j, r in enumerate(rot):
            if not np.isfinite(r):
                r = 0.0
            dens = self._one_place_log_density(wrap(x + r), j).sum()
            fov = tuple((float(wrap(np.float64(s + r))), w) for s, w in o.fov)
            out[j] = dens - x.size * self.fov_log_mass(fov)[j]
        return out

    def unknown_log_likelihood(self, observations: Sequence[Observation]) -> FArray:
        """Uniform density on the seen part of the circle for every bearing."""
        return np.array(
            [o.bearings(self.name).size * (LOG_UNIFORM - math.log(max(o.fov_coverage(), 1e-12))) for o in observations]
        )

    # -- state -----------------------------------------------------------------
    def to_state(self) -> dict[str, Any]:
        return {"mixtures": [None if mx is None else [a.copy() for a in mx] for mx in self.mixtures_]}

    def set_state(self, state: dict[str, Any], groups: Sequence[Sequence[Observation]]) -> MixtureTerm:
        mixtures = state["mixtures"]
        if len(mixtures) != len(groups):
            from ..errors import DatabaseError

            raise DatabaseError(f"term {self.name}: {len(mixtures)} mixtures stored for {len(groups)} places")
        self._set_mixtures(
            [None if mx is None else tuple(np.asarray(a, dtype=np.float64) for a in mx) for mx in mixtures]  # type: ignore[misc]
        )
        return self


def fit_mixture_terms(
    terms: Sequence[MixtureTerm],
    groups: Sequence[Sequence[Observation]],
    changed: Sequence[int] | range,
    *,
    fresh: bool,
) -> None:
    """Fit the mixtures of several mixture terms in one batched EM call.

    Jobs run place by place, then in the order of ``terms``; the terms must
    share their fitting parameters (those of ``terms[0]`` are used). Places
    not in ``changed`` keep their mixtures (``fresh=False``); with
    ``fresh=True`` every place starts unfitted.
    """
    from ..mog import fit_mixtures

    if not terms:
        return
    n = len(groups)
    current: dict[str, list[Mixture | None]] = {}
    for t in terms:
        old = [] if fresh else list(getattr(t, "mixtures_", []))
        current[t.name] = old + [None] * (n - len(old))
    jobs: list[tuple[str, int]] = []
    samples: list[FArray] = []
    for j in changed:
        for t in terms:
            current[t.name][j] = None
            x = np.concatenate([o.bearings(t.name) for o in groups[j]]) if groups[j] else np.empty(0)
            if x.size:
                jobs.append((t.name, j))
                samples.append(x)
    if samples:
        t0 = terms[0]
        ms = fit_mixtures(
            samples,
            t0.n_components,
            tol=t0.tol,
            max_iter=t0.max_iter,
            n_init=t0.n_init,
            min_sigma_deg=t0.min_sigma_deg,
            random_state=t0.random_state,
        )
        for i, (name, j) in enumerate(jobs):
            current[name][j] = (ms.weights[i].copy(), ms.means[i].copy(), ms.sigmas[i].copy())
    for t in terms:
        t._set_mixtures(current[t.name])


