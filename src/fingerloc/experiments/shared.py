"""Results shared between the methods of one benchmark run (``fingerloc bench carmen``).

Several methods of the real-log benchmark repeat the same work on a log:
``fingerprint``, ``fingerprint-filtered``, ``fingerprint-odometry`` and
``odometry-only`` all fit the ``fingerprint`` program on the training scans,
score the same queries with it and calibrate it on the same held-out folds;
every fingerprint program extracts the same laser features of the same
scans. Within :func:`shared_results` (``run_benchmark`` opens one per log)
these are computed once:

* :func:`observations` memoises the laser features of a scan (per extractor
  parameters);
* :func:`shared_method` makes a registered single-shot method whose ``fit``
  on a list of scans (the same scan objects, in the same order, with the same
  labels) and whose ``score`` of a list of scans are computed once and handed
  to every later instance.

Only deterministic methods are shared (every registered single-shot method
is: the fingerprint program is seeded by its own ``random_state``), so the
figures are those of a run without sharing; ``tests/test_bench_shared.py``
checks this. Outside :func:`shared_results` nothing is cached. The cache
lives in a context variable: each thread (a Dask thread worker running a
log) has its own.
"""

from __future__ import annotations

import contextvars
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np

from .._types import FArray

__all__ = ["RunCache", "active_cache", "observations", "shared_method", "shared_results"]


class RunCache:
    """What :func:`shared_results` holds: features, fitted methods, scores (keyed by scan identity).

    Every key holds the ids of scan objects; the objects themselves are kept
    alive by the cache (``_keep``) so that an id is never reused while the
    cache lives.

    Attributes
    ----------
    hits, misses : dict of str to int
        Per kind (``"features"``, ``"fit"``, ``"score"``): lookups answered
        from the cache, and computed.
    """

    def __init__(self) -> None:
        self.features: dict[tuple[int, str], Any] = {}
        self.fits: dict[tuple[Any, ...], Any] = {}
        self.scores: dict[tuple[Any, ...], FArray] = {}
        self._keep: dict[int, object] = {}
        self.hits: dict[str, int] = {"features": 0, "fit": 0, "score": 0}
        self.misses: dict[str, int] = {"features": 0, "fit": 0, "score": 0}

    def scan_ids(self, scans: Sequence[object]) -> tuple[int, ...]:
        """The ids of ``scans`` (each object kept alive by the cache)."""
        ids = tuple(id(s) for s in scans)
        for i, s in zip(ids, scans, strict=True):
            self._keep.setdefault(i, s)
        return ids


_ACTIVE: contextvars.ContextVar[RunCache | None] = contextvars.ContextVar("fingerloc_run_cache", default=None)


def active_cache() -> RunCache | None:
    """The cache of the enclosing :func:`shared_results`, or None."""
    return _ACTIVE.get()


@contextmanager
def shared_results() -> Iterator[RunCache]:
    """Share features, fits and scores between the methods run inside (a fresh cache, dropped on exit)."""
    cache = RunCache()
    token = _ACTIVE.set(cache)
    try:
        yield cache
    finally:
        _ACTIVE.reset(token)


def observations(scans: Sequence[Any], key: str, extract: Callable[[Any], Any]) -> list[Any]:
    """``[extract(s) for s in scans]``, each computed once per ``(scan, key)`` in the active cache.

    ``key`` names the extractor and its parameters (equal keys must mean
    equal extractors); the results must not be modified by the caller.
    """
    cache = _ACTIVE.get()
    if cache is None:
        return [extract(s) for s in scans]
    out = []
    for i, s in zip(cache.scan_ids(scans), scans, strict=True):
        k = (i, key)
        o = cache.features.get(k)
        if o is None:
            o = extract(s)
            cache.features[k] = o
            cache.misses["features"] += 1
        else:
            cache.hits["features"] += 1
        out.append(o)
    return out


class SharedMethod:
    """A registered single-shot method whose fit and scores are shared within :func:`shared_results`.

    Behaves as the method itself (attributes are looked up on the fitted
    inner method, ``inner_``). Outside :func:`shared_results` it fits and
    scores as the method would.

    Parameters
    ----------
    name : str
        The registered name (part of every cache key).
    factory : callable
        Makes a fresh, unfitted method.
    """

    def __init__(self, name: str, factory: Callable[[], Any]) -> None:
        self.name = name
        self._factory = factory
        self.inner_: Any = None
        self._fit_key: tuple[Any, ...] | None = None

    def fit(self, scans: Sequence[Any], labels: Any) -> SharedMethod:
        """Fit (or take the fit of an earlier instance on the same scans and labels)."""
        cache = _ACTIVE.get()
        y = np.asarray(labels, dtype=np.int64).reshape(-1)
        if cache is None:
            self.inner_ = self._factory()
            self.inner_.fit(scans, y)
            return self
        key = (self.name, cache.scan_ids(scans), y.tobytes())
        inner = cache.fits.get(key)
        if inner is None:
            inner = self._factory()
            inner.fit(scans, y.copy())
            cache.fits[key] = inner
            cache.misses["fit"] += 1
        else:
            cache.hits["fit"] += 1
        self.inner_, self._fit_key = inner, key
        return self

    def score(self, scans: Sequence[Any]) -> FArray:
        """The inner method's scores (a fresh copy; computed once per fit and list of scans)."""
        if self.inner_ is None:
            raise AttributeError(f"{self.name}: score before fit")
        cache = _ACTIVE.get()
        if cache is None or self._fit_key is None:
            return np.asarray(self.inner_.score(scans), dtype=np.float64)
        key = (self._fit_key, cache.scan_ids(scans))
        s = cache.scores.get(key)
        if s is None:
            s = np.asarray(self.inner_.score(scans), dtype=np.float64)
            cache.scores[key] = s
            cache.misses["score"] += 1
        else:
            cache.hits["score"] += 1
        return s.copy()

    def __getattr__(self, attr: str) -> Any:
        inner = self.__dict__.get("inner_")
        if inner is None or attr.startswith("__"):
            raise AttributeError(attr)
        return getattr(inner, attr)


def shared_method(name: str, factory: Callable[[], Any] | None = None) -> Any:
    """A :class:`SharedMethod` for the registered method ``name`` (or one made by ``factory``)."""
    if factory is None:
        from .protocol import METHODS, load_methods

        load_methods()
        factory = METHODS[name]
    return SharedMethod(name, factory)
