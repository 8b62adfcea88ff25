"""Speed of the Bayesian program: learn 1,000 places, localize against them, bytes per place."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..observation import Observation
from .speed import best_time, section

# Mean features per measurement of the paper's robot (docs/METHOD.md §5, Table II), plus corners.
_MEAN_COUNTS = {"VE": 5.6, "Ex": 5.6, "CP": 2.7, "B": 3.9, "c": 4.0}


def synthetic_places(
    n_places: int, n_train: int, *, noise_deg: float = 5.0, random_state: int = 0
) -> tuple[list[Observation], list[str], list[Observation], list[str]]:
    """Random places with the paper's feature counts; ``n_train`` noisy views each and one query each."""
    rng = np.random.default_rng(random_state)
    train: list[Observation] = []
    tl: list[str] = []
    test: list[Observation] = []
    ql: list[str] = []
    for p in range(n_places):
        base = {k: rng.uniform(0, 360, max(1, rng.poisson(m))) for k, m in _MEAN_COUNTS.items()}
        hues = rng.uniform(0, 360, base["CP"].size)
        for i in range(n_train + 1):
            f: dict[str, Any] = {k: v + rng.normal(0, noise_deg, v.size) for k, v in base.items()}
            f["CP"] = list(zip(f["CP"], hues, strict=True))
            o = Observation.from_degrees(f, label=f"place-{p}")
            if i < n_train:
                train.append(o)
                tl.append(f"place-{p}")
            else:
                test.append(o)
                ql.append(f"place-{p}")
    return train, tl, test, ql


@section("model")
def bench_model(quick: bool) -> dict[str, Any]:
    """Learn 1,000 places (8 views each), localize one observation against them, database size."""
    from ..map.database import save_model
    from ..model import PlaceModel

    n_places = 100 if quick else 1000
    train, tl, test, ql = synthetic_places(n_places, 8)
    PlaceModel(5).fit(train[:16], tl[:16]).predict_proba(test[:2])  # compile the kernels first
    t0 = time.perf_counter()
    model = PlaceModel(5).fit(train, tl)
    learn_s = time.perf_counter() - t0
    q = test[:1]
    per_query = best_time(lambda: model.predict_proba(q), repeat=5, number=3)
    batch = test[:100]
    per_query_batch = best_time(lambda: model.predict_proba(batch), repeat=2) / len(batch)
    top1 = model.score(test, ql)
    with tempfile.TemporaryDirectory() as d:
        size = save_model(model, Path(d) / "p.sqlite")
    fps = [fp for g in model.terms_["Fp"].fingerprints_ for fp in g]  # type: ignore[attr-defined]
    letters = sum(len(fp) for fp in fps)
    return {
        "places": n_places,
        "train_views_per_place": 8,
        "learn_s": learn_s,
        "localize_one_ms": per_query * 1e3,
        "localize_batched_ms_per_obs": per_query_batch * 1e3,
        "top1_synthetic": top1,
        "db_bytes": size,
        "db_bytes_per_place": size / n_places,
        "fingerprint_letters_bytes_per_place": letters / n_places,
        "fingerprint_with_bearings_bytes_per_place": letters * 9 / n_places,
        "terms": "VE,CP,Ex,B,Fp; cyclic off; unit costs",
    }
