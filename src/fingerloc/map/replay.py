"""Random draws recorded once and replayed by runs that draw the same numbers (private)."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["SharedDraws"]


class SharedDraws:
    """The random draws of one seed, recorded by a first run and replayed by the next (private).

    Runs of the filter that differ only in settings which do not change the
    *sequence* of draws (the tuning grid of
    :func:`fingerloc.pipeline.tracker.tune_pose_filter`: same seed, same
    steps, other ``outlier`` and tempering) draw the same random numbers.
    :meth:`generator` gives a :class:`numpy.random.Generator` seeded with
    ``seed`` that returns, call for call, what a fresh ``default_rng(seed)``
    would: the first generator draws and records; the next ones return the
    recorded arrays while their calls are the same (method and arguments),
    and at the first call that differs they bring their own bit generator to
    that point (re-drawing the calls so far) and draw for themselves from
    then on. Recorded arrays are read only. ``choice`` with probabilities
    is done as NumPy does it (a cumulative sum of ``p``, ``random(size)``,
    ``searchsorted``) so that its uniform draws are shared.
    """

    def __init__(self, seed: int) -> None:
        self.seed = int(seed)
        self.log: list[tuple[tuple[Any, ...], Any]] = []

    def generator(self) -> np.random.Generator:
        """A generator equal in its draws to ``numpy.random.default_rng(seed)``."""
        return _ReplayGenerator(self)


def _shareable(x: Any) -> bool:
    if isinstance(x, tuple):
        return all(_shareable(v) for v in x)
    return x is None or isinstance(x, (bool, int, float, str, np.integer, np.floating))


class _ReplayGenerator(np.random.Generator):
    """A generator that replays :class:`SharedDraws` while its calls match (see there)."""

    def __init__(self, shared: SharedDraws) -> None:
        super().__init__(np.random.PCG64(shared.seed))
        self._shared = shared
        self._i = 0  # calls made
        self._synced = 0  # calls whose draws the own bit generator has made
        self._own = False  # diverged from the record: every draw is this generator's

    def _draw(self, name: str, args: tuple[Any, ...], kwargs: dict[str, Any]) -> Any:
        if self._own and self._synced == self._i:  # diverged and in step: a plain draw (the same as below)
            self._i = self._synced = self._i + 1
            return getattr(np.random.Generator, name)(self, *args, **kwargs)
        key = (name, args, tuple(sorted(kwargs.items())))
        log = self._shared.log
        i = self._i
        if not self._own:
            if i < len(log):  # a recorded key holds no array: the comparison is of plain values
                try:
                    same = name != "choice" and log[i][0] == key
                except ValueError:  # an array among the arguments
                    same = False
                if same:
                    self._i = i + 1
                    return log[i][1]
                self._own = True
            elif name == "choice" or not _shareable(key[1:]):
                self._own = True
        if self._synced < i:  # bring the own bit generator to call i: the record's calls so far
            for k in range(self._synced, i):
                n_k, a_k, kw_k = log[k][0]
                getattr(np.random.Generator, n_k)(self, *a_k, **dict(kw_k))
        out = getattr(np.random.Generator, name)(self, *args, **kwargs)
        self._i = self._synced = i + 1
        if not self._own:
            if isinstance(out, np.ndarray):
                out.flags.writeable = False
            log.append((key, out))
        return out

    def standard_normal(self, *args: Any, **kwargs: Any) -> Any:
        return self._draw("standard_normal", args, kwargs)

    def uniform(self, *args: Any, **kwargs: Any) -> Any:
        return self._draw("uniform", args, kwargs)

    def random(self, *args: Any, **kwargs: Any) -> Any:
        return self._draw("random", args, kwargs)

    def integers(self, *args: Any, **kwargs: Any) -> Any:
        return self._draw("integers", args, kwargs)

    def vonmises(self, *args: Any, **kwargs: Any) -> Any:
        return self._draw("vonmises", args, kwargs)

    def choice(self, a: Any, size: Any = None, replace: bool = True, p: Any = None, **kwargs: Any) -> Any:  # type: ignore[override]
        if p is not None and replace and not kwargs and isinstance(a, (int, np.integer)) and isinstance(size, (int, np.integer)):
            # numpy.random.Generator.choice with p: cdf = cumsum(p) / its last entry; searchsorted(cdf, random(size), "right")
            pp = np.asarray(p, dtype=np.float64)
            if pp.ndim == 1 and pp.size == a and np.all(np.isfinite(pp)) and not np.any(pp < 0) and abs(pp.sum() - 1.0) < 1e-9:
                cdf = pp.cumsum()
                cdf /= cdf[-1]
                return np.asarray(cdf.searchsorted(self.random(int(size)), side="right"), dtype=np.int64)
        return self._draw("choice", (a, size, replace, p), kwargs)  # never shared
