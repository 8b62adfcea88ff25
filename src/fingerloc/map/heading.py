"""The heading a view implies at a place, as evidence for the pose filter: a robust density and its fit."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._types import FArray
from ..angles import wrap
from ..errors import InvalidParameterError
from ._checks import finite as _finite

__all__ = ["HeadingModel", "fit_heading_model"]


@dataclass(frozen=True, slots=True)
class HeadingModel:
    """How far the robot's true heading lies from the heading a view implies at a place: a robust density.

    ``delta = true heading - implied heading`` (radians) has density
    ``f(delta | x) = g(x) [(1 - reverse) vM(delta; 0, kappa) + reverse
    vM(delta; pi, kappa)] + (1 - g(x)) / (2 pi)``: a von Mises peak where
    the alignment behind the estimate is right, part of it at the reverse
    heading (a corridor seen from its other end can look alike), and a
    uniform part for estimates that are noise. How often the estimate is
    right depends on how well the view matched the place: ``g(x) = cap
    sigmoid(intercept + slope x)``, ``x`` = the observation's log-probability
    of that place (the softmax of its row, <= 0). The pose filter weighs a
    particle at a place by ``2 pi f(particle heading - implied heading |
    x)`` (1 when the place has no implied heading: as uninformative as the
    uniform part). :func:`fit_heading_model` fits it on the mapping run.

    Attributes
    ----------
    kappa : float, default 20.0
        Concentration of the peaks (> 0; 1 / kappa ~ their variance in rad^2).
    intercept : float, default 0.0
        Logit of ``g / cap`` for a place the observation is sure of (``x = 0``).
    slope : float, default 0.0
        Per nat of ``x`` (0: the same reliability for every place).
    reverse : float, default 0.0
        Share of the peak at the reverse heading, in ``[0, 1]``.
    cap : float, default 0.95
        Largest peak share (the uniform part keeps ``1 - cap``), in ``[0, 1]``.
    """

    kappa: float = 20.0
    intercept: float = 0.0
    slope: float = 0.0
    reverse: float = 0.0
    cap: float = 0.95

    def __post_init__(self) -> None:
        k = _finite("kappa", self.kappa)
        if k <= 0:
            raise InvalidParameterError(f"kappa must be > 0, got {self.kappa!r}")
        _finite("slope", self.slope)
        if not math.isfinite(float(self.intercept)):
            raise InvalidParameterError(f"intercept must be finite, got {self.intercept!r}")
        for name in ("reverse", "cap"):
            if _finite(name, getattr(self, name)) > 1:
                raise InvalidParameterError(f"{name} must be in [0, 1], got {getattr(self, name)!r}")

    def peak_share(self, x: Any = 0.0) -> FArray:
        """``g(x)``: the chance that the heading estimate is right (``x`` = log-probability of the place)."""
        xx = np.maximum(np.asarray(x, dtype=np.float64), -50.0)
        return np.asarray(self.cap / (1.0 + np.exp(-(self.intercept + self.slope * xx))), dtype=np.float64)

    def log_factor(self, delta: Any, x: Any = 0.0) -> FArray:
        """``log(2 pi f(delta | x))``: a particle's weight factor, relative to an uninformative heading."""
        from scipy.special import i0e

        d = np.asarray(delta, dtype=np.float64)
        g = self.peak_share(x)
        c = np.cos(d)
        norm = 1.0 / float(i0e(self.kappa))  # 2 pi vM(delta) = exp(kappa (cos delta - 1)) / i0e(kappa)
        peak = (1.0 - self.reverse) * np.exp(self.kappa * (c - 1.0))
        if self.reverse > 0:
            peak = peak + self.reverse * np.exp(self.kappa * (-c - 1.0))
        with np.errstate(divide="ignore"):
            return np.asarray(np.log(g * norm * peak + (1.0 - g)), dtype=np.float64)

    def log_mean_tempered(self, weight: float, x: Any = 0.0) -> FArray:
        """``log mean_delta (2 pi f(delta | x)) ** weight`` over the circle, per ``x`` (0 at weight 1)."""
        xs = np.asarray(x, dtype=np.float64)
        if weight == 1.0:
            return np.zeros(xs.shape)
        grid = np.linspace(-math.pi, math.pi, 360, endpoint=False)
        lf = weight * self.log_factor(grid[:, None], xs.reshape(1, -1))
        top = lf.max(axis=0)
        return np.asarray(top + np.log(np.mean(np.exp(lf - top), axis=0)), dtype=np.float64).reshape(xs.shape)

    def sample(self, implied: Any, rng: np.random.Generator, x: Any = 0.0) -> FArray:
        """Headings drawn from ``f(. | x)`` around each implied heading (radians)."""
        mu = np.asarray(implied, dtype=np.float64).reshape(-1)
        n = mu.size
        g = np.broadcast_to(self.peak_share(x), (n,))
        u = rng.uniform(0.0, 1.0, n)
        flip = rng.uniform(0.0, 1.0, n) < self.reverse
        peak = wrap(mu + np.where(flip, math.pi, 0.0) + rng.vonmises(0.0, self.kappa, n))
        return np.where(u < g, peak, rng.uniform(-math.pi, math.pi, n))


def fit_heading_model(
    delta: Any,
    x: Any = None,
    *,
    reverse: bool = True,
    slope: bool = True,
    cap: float = 0.95,
    max_kappa: float = 400.0,
) -> HeadingModel | None:
    """Fit :class:`HeadingModel` to heading errors ``true - implied`` (radians) by maximum likelihood.

    Meant for the mapping run: each held-out mapping view's heading implied
    at its own place (by a front end fit on the other views) against the
    view's recorded heading, with ``x`` the view's log-probability of that
    place (default 0: no dependence). ``reverse`` / ``slope``: fit those
    parts too (else 0). ``None`` when fewer than 10 finite errors are given
    (no heading evidence).
    """
    from scipy.optimize import minimize

    d = np.asarray(delta, dtype=np.float64).reshape(-1)
    xx = np.zeros_like(d) if x is None else np.asarray(x, dtype=np.float64).reshape(-1)
    if xx.shape != d.shape:
        raise InvalidParameterError(f"x must have one entry per error ({d.size}), got {xx.size}")
    ok = np.isfinite(d) & ~np.isnan(xx)
    d, xx = wrap(d[ok]), np.maximum(xx[ok], -50.0)
    if d.size < 10:
        return None
    cp = _finite("cap", cap)

    def model(p: FArray) -> HeadingModel:
        return HeadingModel(
            kappa=float(min(math.exp(p[0]), max_kappa)),
            intercept=float(p[1]),
            slope=float(p[2]) if slope else 0.0,
            reverse=float(1.0 / (1.0 + math.exp(-p[3]))) if reverse else 0.0,
            cap=cp,
        )

    def nll(p: FArray) -> float:
        return -float(np.sum(model(p).log_factor(d, xx)))

    best = None
    for k0 in (2.0, 10.0, 50.0):
        r = minimize(nll, np.array([math.log(k0), 0.0, 0.5, -2.0]), method="L-BFGS-B",
                     bounds=[(math.log(1e-2), math.log(max_kappa)), (-10, 10), (0, 10), (-10, 10)])  # fmt: skip
        if best is None or r.fun < best.fun:
            best = r
    assert best is not None
    return model(best.x)
