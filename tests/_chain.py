"""A synthetic corridor walk with a synthetic sensor, for the discrete filter's kidnap tests (no sensor data)."""

from __future__ import annotations

import numpy as np

from fingerloc.experiments.kidnap import TrackingData, with_synthetic_likelihood
from fingerloc.map.filter import TransitionModel
from fingerloc.map.graph import PlaceGraph
from fingerloc.pipeline.calibration import step_distances


def chain_data(p=30, per_place=3, seed=0):
    """A robot walking a 30-place corridor three steps per place, one metre a step, with a synthetic sensor."""
    truth = np.repeat(np.arange(p), per_place)
    pos = np.column_stack([np.arange(truth.size) * 1.0, np.zeros(truth.size)])
    g = PlaceGraph.from_sequence([str(i) for i in range(p)], [str(i) for i in truth])

    class Fitted:
        transition_ = TransitionModel.from_graph(g, metres_per_move=3.0)

    data = TrackingData(Fitted(), np.zeros((truth.size, p)), step_distances(pos), truth, pos)  # type: ignore[arg-type]
    return with_synthetic_likelihood(data, 2.5, random_state=seed)
