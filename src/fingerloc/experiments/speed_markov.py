"""Speed of the Markov filter over places (``fingerloc bench speed --only markov``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..map.filter import MarkovFilter, TransitionModel
from ..map.graph import PlaceGraph
from .speed import best_time, section


def _corridor(n_places: int, metres: float | None) -> TransitionModel:
    """A loop of places visited three steps each, twice (a mapping pass's counts)."""
    seq = [str(j) for _ in range(2) for j in np.repeat(np.arange(n_places), 3)]
    return TransitionModel.from_graph(PlaceGraph.from_sequence([str(j) for j in range(n_places)], seq),
                                      metres_per_move=metres)  # fmt: skip


@section("markov")
def markov_section(quick: bool) -> dict[str, Any]:
    """Microseconds per filter step (predict + update) for 50 and 500 places, without and with odometry."""
    out: dict[str, Any] = {}
    rng = np.random.default_rng(0)
    steps = 50 if quick else 500
    for p in (50, 500):
        ll = rng.normal(size=(steps, p))
        dist = rng.uniform(0.0, 1.5, steps)
        for odo in (False, True):
            f = MarkovFilter(_corridor(p, 2.5 if odo else None))
            f.transition_matrix(1.0 if odo else None)  # build the cache outside the timing

            def run(f: MarkovFilter = f, ll: Any = ll, dist: Any = dist, odo: bool = odo) -> None:
                f.reset()
                for t in range(steps):
                    f.step(ll[t], float(dist[t]) if odo else None)

            out[f"us_per_step_{p}_places{'_odometry' if odo else ''}"] = 1e6 * best_time(run, repeat=3) / steps
    return out
