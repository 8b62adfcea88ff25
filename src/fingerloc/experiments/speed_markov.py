"""Speed of the Markov filter over places and of the pose filter (``fingerloc bench speed --only markov``)."""

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
    out.update(_pose_filter_times(quick))
    return out


def _pose_filter_times(quick: bool) -> dict[str, float]:
    """Microseconds per pose-filter step, 3,000 particles: a prediction, and a prediction + observation."""
    from ..map.pose_filter import PoseFilter

    rng = np.random.default_rng(1)
    steps = 20 if quick else 200
    out: dict[str, float] = {}
    for p in (50, 500):
        centres = np.column_stack([np.arange(p) * 2.0, np.zeros(p)])
        f = PoseFilter(centres, 1.0, n_particles=3000, kidnap=0.005, random_state=0)
        ll = rng.normal(size=(steps, p))
        inc = np.column_stack([rng.uniform(0.3, 1.0, steps), np.zeros(steps), rng.normal(0, 0.1, steps)])

        def predict(f: PoseFilter = f, inc: Any = inc) -> None:
            for t in range(steps):
                f.predict(inc[t])

        def observe(f: PoseFilter = f, inc: Any = inc, ll: Any = ll) -> None:
            for t in range(steps):
                f.step(ll[t], inc[t], 0.5)

        out[f"pose_filter_us_per_prediction_{p}_places"] = 1e6 * best_time(predict, repeat=3) / steps
        out[f"pose_filter_us_per_observed_step_{p}_places"] = 1e6 * best_time(observe, repeat=3) / steps
    return out
