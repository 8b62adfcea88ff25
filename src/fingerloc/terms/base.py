"""The contract of one term of the Bayesian program (docs/METHOD.md §4).

A *term* is one factor ``P(term | Loc)`` of the decomposition
``P(Loc VE CP Ex B Fp ...) = P(Loc) prod_term P(term | Loc)``. It learns from
the training observations of every place, and answers, for new observations,
the log-likelihood of each under each place. :class:`fingerloc.model.PlaceModel`
combines terms (weights, prior, the unknown place, normalisation) and knows
nothing of how a term computes its answer.

Places are given as ``groups``: ``groups[j]`` is the list of training
observations of place ``j`` (the ``j``-th entry of ``PlaceModel.classes_``).

Headings. With the heading unknown, a term that depends on the robot's
orientation (the angle-space mixtures) may be asked to score each observation
after rotating it by ``rotations[i, j]`` (radians, shape ``(n, P)``): the
heading that a heading-aware term (the fingerprint alignment) estimates for
observation ``i`` at place ``j``. A heading-free term ignores ``rotations``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .._types import FArray
from ..observation import Observation

__all__ = ["FArray", "Term"]



class Term:
    """Base class of a term of the Bayesian program.

    Subclasses set :attr:`name` and implement :meth:`fit`,
    :meth:`log_likelihood`, and (for the database) :meth:`to_state` /
    :meth:`from_state`. The defaults of the other methods say "no evidence".

    Attributes
    ----------
    name : str
        The term's name in ``PlaceModel(terms=...)``: ``"VE"``, ``"Fp"``, ``"R"``, ``"A"``, ...
    heading_free : bool
        True when the term's answer does not depend on the robot's heading.
    """

    name: str = ""
    heading_free: bool = True

    def fit(self, groups: Sequence[Sequence[Observation]]) -> Term:
        """Learn every place from scratch (and the term's own calibration); returns self."""
        raise NotImplementedError

    def update(self, groups: Sequence[Sequence[Observation]], changed: Sequence[int]) -> Term:
        """Refit only the places ``changed`` (indices into ``groups``, which holds every place).

        Places may have been appended at the end of ``groups``. The term's
        global calibration is kept. The default refits everything.
        """
        return self.fit(groups)

    def log_likelihood(self, observations: Sequence[Observation], *, rotations: FArray | None = None) -> FArray:
        """``log P(term | place)`` of each observation under each place, shape ``(n, P)``.

        ``rotations`` (radians, ``(n, P)``), when given, is the heading of each
        observation at each place: heading-dependent terms rotate the
        observation by it before scoring.
        """
        raise NotImplementedError

    def log_likelihood_at(self, observations: Sequence[Observation], places: Sequence[int] | np.ndarray) -> FArray:
        """:meth:`log_likelihood` at the given places only (columns ``places``), shape ``(n, len(places))``.

        The very values of ``log_likelihood(observations)[:, places]``; terms that can score some
        places without scoring all of them override it (exact retrieval, :mod:`fingerloc.retrieval`).
        """
        return self.log_likelihood(observations)[:, np.asarray(places, dtype=np.int64)]

    def unknown_log_likelihood(self, observations: Sequence[Observation]) -> FArray:
        """Log-likelihood of each observation under the "no learned place" hypothesis, shape ``(n,)``."""
        return np.zeros(len(observations))

    def headings(self, observations: Sequence[Observation]) -> FArray | None:
        """Heading (radians) of each observation at each place, ``(n, P)``, or None if the term has none."""
        return None

    def to_state(self) -> dict[str, Any]:
        """The fitted state as plain data (JSON-ready values and float64 arrays), for the place database."""
        return {}

    def set_state(self, state: dict[str, Any], groups: Sequence[Sequence[Observation]]) -> Term:
        """Restore the fitted state from :meth:`to_state` and the places' stored observations; returns self."""
        raise NotImplementedError
