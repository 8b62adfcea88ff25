"""The place graph: places as nodes, transitions counted while mapping as edges (docs/METHOD.md §6).

A :class:`PlaceGraph` is a directed graph over the learned places (a
``networkx.DiGraph``): edge ``(a, b)`` carries ``count``, how many times the
robot went from place ``a`` at one step to place ``b`` at the next while
mapping; a self-loop ``(a, a)`` counts the steps it stayed at ``a``. The
graph is built from the sequence of places the mapping pass went through
(:meth:`PlaceGraph.from_sequence`), from a given adjacency
(:meth:`PlaceGraph.from_edges`), or read back from a place database
(:func:`load_graph`; the counts are the database's ``graph_edges`` table).

The Markov filter (:mod:`fingerloc.map.filter`) turns the counts into a
transition model.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import networkx as nx
import numpy as np
from numpy.typing import NDArray

from .._types import FArray
from ..errors import InvalidParameterError

__all__ = ["PlaceGraph", "load_graph", "nearest_place_sequence"]



class PlaceGraph:
    """Places and the transition counts between them.

    Parameters
    ----------
    places : sequence of str
        Node labels, in the order of the model's ``classes_`` (the order of the
        rows and columns of :meth:`count_matrix`).
    counts : mapping (src, dst) -> int, optional
        Transition counts; a self-loop ``(a, a)`` counts steps spent at ``a``.
        Both ends must be in ``places``; counts must be >= 0 (zero-count edges
        are kept: "adjacent, never seen").

    Attributes
    ----------
    graph : networkx.DiGraph
        Nodes = places (in ``places`` order), edges with attribute ``count``.
    """

    def __init__(self, places: Sequence[str], counts: Mapping[tuple[str, str], int] | None = None) -> None:
        labels = [str(p) for p in places]
        if len(set(labels)) != len(labels):
            raise InvalidParameterError("places must not repeat a label")
        self.graph: nx.DiGraph = nx.DiGraph()
        self.graph.add_nodes_from(labels)
        for (src, dst), c in (counts or {}).items():
            self.add_transition(str(src), str(dst), c)

    # -- construction ----------------------------------------------------------------------------
    def add_transition(self, src: str, dst: str, count: int = 1) -> None:
        """Add ``count`` passages from ``src`` to ``dst`` (both must be places)."""
        for p in (src, dst):
            if p not in self.graph:
                raise InvalidParameterError(f"unknown place {p!r} in a graph edge")
        c = int(count)
        if c < 0 or c != count:
            raise InvalidParameterError(
                f"a transition count must be an integer >= 0, got {count!r} for ({src!r}, {dst!r})"
            )
        if self.graph.has_edge(src, dst):
            self.graph[src][dst]["count"] += c
        else:
            self.graph.add_edge(src, dst, count=c)

    @classmethod
    def from_sequence(cls, places: Sequence[str], sequence: Iterable[str | None]) -> PlaceGraph:
        """Count the transitions between consecutive steps of a place sequence.

        Parameters
        ----------
        places : sequence of str
            All places (nodes), model order.
        sequence : iterable of str or None
            The place at each step of the mapping pass, in order; ``None``
            (no place) breaks the chain: no transition is counted across it.

        Returns
        -------
        PlaceGraph
        """
        g = cls(places)
        prev: str | None = None
        for cur in sequence:
            cur = None if cur is None else str(cur)
            if prev is not None and cur is not None:
                g.add_transition(prev, cur)
            prev = cur
        return g

    @classmethod
    def from_edges(
        cls, edges: Mapping[tuple[str, str], int] | Iterable[tuple[str, str]], places: Sequence[str] | None = None
    ) -> PlaceGraph:
        """A graph from counted edges (a mapping) or a plain adjacency (pairs, count 0 each).

        ``places`` defaults to the edges' ends in first-seen order.
        """
        counts: dict[tuple[str, str], int] = (
            {(str(a), str(b)): int(c) for (a, b), c in edges.items()}
            if isinstance(edges, Mapping)
            else {(str(a), str(b)): 0 for a, b in edges}
        )
        if places is None:
            places = list(dict.fromkeys(p for e in counts for p in e))
        return cls(places, counts)

    # -- views -----------------------------------------------------------------------------------
    @property
    def places(self) -> list[str]:
        """Node labels in matrix order."""
        return [str(n) for n in self.graph.nodes]

    @property
    def n_places(self) -> int:
        """Number of places."""
        return int(self.graph.number_of_nodes())

    def edges(self) -> dict[tuple[str, str], int]:
        """``{(src, dst): count}``, ready for :func:`fingerloc.map.database.save_model`'s ``graph_edges``."""
        return {(str(a), str(b)): int(d["count"]) for a, b, d in self.graph.edges(data=True)}

    def count_matrix(self, places: Sequence[str] | None = None) -> FArray:
        """Counts as a matrix ``C[i, j]`` = passages from place ``i`` to place ``j``, shape (P, P).

        Parameters
        ----------
        places : sequence of str, optional
            Row / column order (default :attr:`places`); every label must be a node.
        """
        order = self.places if places is None else [str(p) for p in places]
        index = {p: i for i, p in enumerate(order)}
        missing = [p for p in self.graph.nodes if p not in index]
        if missing or len(index) != len(order):
            raise InvalidParameterError(
                f"places must list each of the graph's {self.n_places} places once (missing {missing[:3]!r})"
            )
        c = np.zeros((len(order), len(order)))
        for a, b, d in self.graph.edges(data=True):
            c[index[a], index[b]] += d["count"]
        return c

    def adjacency(self, places: Sequence[str] | None = None, *, symmetric: bool = True) -> NDArray[np.bool_]:
        """Whether an edge joins two different places, shape (P, P), diagonal False.

        ``symmetric=True`` (default) treats an edge in either direction as a
        corridor usable both ways: a robot that went from ``a`` to ``b`` while
        mapping can come back.
        """
        order = self.places if places is None else [str(p) for p in places]
        index = {p: i for i, p in enumerate(order)}
        a = np.zeros((len(order), len(order)), dtype=bool)
        for u, v in self.graph.edges:
            if u != v:
                a[index[u], index[v]] = True
        if symmetric:
            a |= a.T
        return a

    def stay_fraction(self) -> float:
        """Fraction of counted steps that stayed at a place (self-loops / all counts); NaN with no count."""
        c = self.count_matrix()
        total = float(c.sum())
        return float(np.trace(c) / total) if total > 0 else float("nan")

    def __repr__(self) -> str:
        return f"PlaceGraph({self.n_places} places, {self.graph.number_of_edges()} edges)"


def nearest_place_sequence(positions: Any, centres: Any, *, radius: float | None = None) -> NDArray[np.int64]:
    """Index of the nearest place centre at each step (``-1`` when farther than ``radius``).

    Parameters
    ----------
    positions : array_like, shape (n, 2)
        Robot positions, metres.
    centres : array_like, shape (P, 2)
        Place centres, metres.
    radius : float, optional
        Metres; ``None`` assigns every step to its nearest centre (the
        Voronoi cell of the place), which is what the filter's state means.

    Returns
    -------
    ndarray of int, shape (n,)
        Ties go to the lower index.
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    if c.shape[0] == 0:
        raise InvalidParameterError("nearest_place_sequence needs at least one centre")
    d = np.hypot(pos[:, None, 0] - c[None, :, 0], pos[:, None, 1] - c[None, :, 1])
    near = np.argmin(d, axis=1).astype(np.int64)
    if radius is not None:
        near[d[np.arange(pos.shape[0]), near] > radius] = -1
    return near


def load_graph(path: str | Path, places: Sequence[str] | None = None) -> PlaceGraph:
    """The place graph stored in a place database (its ``graph_edges`` table).

    Parameters
    ----------
    path : path
        Place database.
    places : sequence of str, optional
        Node order (default: the database's places, in model order). Stored
        edges whose ends are not places raise :class:`~fingerloc.errors.DatabaseError`.
    """
    from ..errors import DatabaseError
    from .database import load_model, read_graph_edges

    if places is None:
        places = [str(c) for c in load_model(path).classes_]
    edges = read_graph_edges(path)
    known = set(places)
    for a, b in edges:
        if a not in known or b not in known:
            raise DatabaseError(f"{path}: graph edge ({a!r}, {b!r}) names a place the database does not hold")
    return PlaceGraph(places, edges)
