"""Small labelled place data shared by the model and database tests."""

import numpy as np

from fingerloc import Observation


def office(rng, base, noise=3.0, **extra):
    feats = {k: list(np.asarray(v) + rng.normal(0, noise, len(v))) for k, v in base.items()}
    return Observation.from_degrees(feats, **extra)


BASES = {
    "a": {"VE": [10, 80, 170, 260], "Ex": [30, 200], "c": [45, 135, 225, 315], "B": [100]},
    "b": {"VE": [40, 130, 300], "Ex": [90, 250, 330], "c": [45, 135, 225, 315], "B": [10, 200]},
    "c": {"VE": [5, 60, 120, 180, 240], "Ex": [150], "c": [60, 300]},
}


def dataset(seed=0, n=6, noise=3.0):
    rng = np.random.default_rng(seed)
    obs, labels = [], []
    for lab, base in BASES.items():
        for _ in range(n):
            obs.append(office(rng, base, noise))
            labels.append(lab)
    return obs, labels
