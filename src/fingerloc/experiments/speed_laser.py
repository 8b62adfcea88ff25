"""Speed section ``laser`` of ``fingerloc bench speed``: the ``laser2d`` preset at 1,000 places.

The data are simulated, so anyone can run it: ``n_places`` offices of
:func:`fingerloc.sim.make_offices` (seed 20040426), one place each;
``n_train`` training views per place on the paper's circle around the
office's anchor (:func:`fingerloc.sim.poses.protocol_poses`) and one query
inside it, every pose with its own random heading. Each view is a
Hokuyo-like scan of 1,081 beams over 270 deg (0.25 deg steps, 30 m range):
the middle 1,081 beams of a 1,440-beam simulated turn. The model is the
``laser2d`` preset (fingerprint with laser letters + range term, cyclic,
feature-aware costs), learned from the extracted features of the training
scans. ``--quick``: 100 places.

Figures, per query, as wall time and as process CPU time (``*_cpu_*``, all
threads; steadier on a loaded machine), best of ``repeat`` rounds:

- ``extract_ms``: feature extraction from the raw scan
  (:func:`fingerloc.features.laser.observation_from_scan` with the preset's
  extractor arguments);
- ``term_Fp_ms``, ``term_R_ms``: each term's log-likelihoods against every place;
- ``localize_ms``: what ``fingerloc localize`` computes for one observation
  (:func:`localize_answers`: the terms once, the posterior, the ranks and the
  heading at the best place), and ``localize_with_extraction_ms`` with the
  extraction (target: <= 5 ms);
- ``*_batched_ms``: the same per query when ``chunk`` queries come at once,
  as ``localize`` reads a log (its chunks of 256).

Also the 1-minute load average at the end of the run.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..observation import Observation
from ..sensors import Scan
from .speed import section

__all__ = ["LaserPlaces", "hokuyo_scan", "laser_figures", "laser_places", "localize_answers", "speed_laser"]

#: Beams of the simulated scanner (a Hokuyo UTM-30LX: 270 deg at 0.25 deg).
BEAMS = 1081
_TURN = 1440  # beams of a full turn at 0.25 deg


def hokuyo_scan(world: Any, pose: tuple[float, float, float], *, random_state: int) -> Scan:
    """A 1,081-beam, 270 deg scan (0.25 deg steps, 30 m range) at ``pose`` in a simulated ``world``."""
    from ..sim import simulate_scan

    s = simulate_scan(world, pose, n_beams=_TURN, max_range=30.0, random_state=random_state)
    keep = slice(_TURN // 2 - BEAMS // 2, _TURN // 2 + BEAMS // 2 + 1)
    inten = None if s.intensities is None else s.intensities[keep]
    return Scan(ranges=s.ranges[keep], bearings=s.bearings[keep], max_range=30.0, intensities=inten, pose=s.pose)


@dataclass(slots=True)
class LaserPlaces:
    """Simulated laser data: raw scans and their labels (``train``: ``n_train`` per place; ``queries``: one per place)."""

    train: list[Scan]
    train_labels: list[str]
    queries: list[Scan]
    query_labels: list[str]

    def observations(self, scans: Sequence[Scan], labels: Sequence[str] | None = None) -> list[Observation]:
        """The scans' observations through the ``laser2d`` preset's extractor."""
        from ..features.laser import observation_from_scan
        from ..pipeline.presets import PRESETS

        feats = PRESETS["laser2d"]["features"]
        labs: Sequence[str | None] = [None] * len(scans) if labels is None else labels
        return [observation_from_scan(s, label=lab, **feats) for s, lab in zip(scans, labs, strict=True)]


def laser_places(n_places: int, *, n_train: int = 3, seed: int = 20040426) -> LaserPlaces:
    """``n_places`` simulated offices, one place each, ``n_train`` training scans and one query per place."""
    from ..sim import make_offices
    from ..sim.poses import protocol_poses

    rng = np.random.default_rng(seed)
    worlds = make_offices(n_places, random_state=seed)
    data = LaserPlaces([], [], [], [])
    for p, w in enumerate(worlds):
        train, test = protocol_poses(w, n_train=n_train, n_test=1, random_state=rng)
        label = f"place-{p}"
        for pose in train:
            data.train.append(hokuyo_scan(w, (pose[0], pose[1], rng.uniform(-math.pi, math.pi)), random_state=int(rng.integers(2**31))))
            data.train_labels.append(label)
        for pose in test:
            data.queries.append(hokuyo_scan(w, (pose[0], pose[1], rng.uniform(-math.pi, math.pi)), random_state=int(rng.integers(2**31))))
            data.query_labels.append(label)
    return data


def localize_answers(model: Any, observations: Sequence[Observation]) -> dict[str, Any]:
    """What ``fingerloc localize`` computes for a chunk of observations (its table and JSON come from it).

    The terms' log-likelihoods once, the posterior, the ranks, the best place
    and, for a cyclic model, the heading at the best place with its reference view.
    """
    from ..metrics import rank_scores
    from ..model import normalise_log

    obs = list(observations)
    terms = model.term_log_likelihoods(obs)
    logp = normalise_log(model.combine(terms))
    ranks = rank_scores(logp)
    best = np.argmax(logp, axis=1)
    out: dict[str, Any] = {"terms": terms, "log_posterior": logp, "ranks": ranks, "best": best}
    if model.cyclic:
        out["headings"], out["refs"] = model.headings_with_reference(obs, [model.classes_[j] for j in best])
    return out


def _wall_cpu(fn: Callable[[], object], repeat: int, number: int = 1) -> tuple[float, float]:
    """Best wall and best process-CPU seconds per call of ``fn`` (``number`` calls a round, ``repeat`` rounds)."""
    best_w = best_c = math.inf
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        for _ in range(number):
            fn()
        best_w = min(best_w, (time.perf_counter() - w0) / number)
        best_c = min(best_c, (time.process_time() - c0) / number)
    return best_w, best_c


@section("laser")
def speed_laser(quick: bool) -> dict[str, Any]:
    """Time the ``laser2d`` preset's localization; return JSON-ready figures."""
    if quick:
        return laser_figures(n_places=100, n_queries=5, chunk=20, repeat=2)
    return laser_figures()


def laser_figures(
    *, n_places: int = 1000, n_train: int = 3, n_queries: int = 20, chunk: int = 256, repeat: int = 3, seed: int = 20040426
) -> dict[str, Any]:
    """The figures of the ``laser`` section (module docstring); ``n_queries`` queries are timed one at a time."""
    from ..fingerprint import make_fingerprint
    from ..pipeline.presets import resolve_preset

    t0 = time.perf_counter()
    data = laser_places(n_places, n_train=n_train, seed=seed)
    sim_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    train = data.observations(data.train, data.train_labels)
    queries = data.observations(data.queries, data.query_labels)
    extract_all_s = time.perf_counter() - t0
    model = resolve_preset("laser2d").model()
    t0 = time.perf_counter()
    model.fit(train, data.train_labels)
    learn_s = time.perf_counter() - t0
    localize_answers(model, queries[:2])  # compile
    q_scans = data.queries[:n_queries]
    q_obs = queries[:n_queries]
    ms = 1e3
    out: dict[str, Any] = {
        "places": n_places,
        "train_views_per_place": n_train,
        "beams": BEAMS,
        "references": len(train),
        "mean_letters": float(np.mean([len(make_fingerprint(o, laser_letters=True)) for o in queries])),
        "simulate_s": sim_s,
        "extract_all_s": extract_all_s,
        "learn_s": learn_s,
    }

    def per_query(fn: Callable[[Any], object], items: Sequence[Any]) -> tuple[float, float]:
        w = c = 0.0
        for it in items:
            wi, ci = _wall_cpu(lambda it=it: fn(it), repeat)  # type: ignore[misc]
            w, c = w + wi, c + ci
        return ms * w / len(items), ms * c / len(items)

    out["extract_ms"], out["extract_cpu_ms"] = per_query(lambda s: data.observations([s]), q_scans)
    for name, term in model.terms_.items():

        def score(o: Observation, t: Any = term) -> object:
            return t.log_likelihood([o])

        out[f"term_{name}_ms"], out[f"term_{name}_cpu_ms"] = per_query(score, q_obs)
    out["localize_ms"], out["localize_cpu_ms"] = per_query(lambda o: localize_answers(model, [o]), q_obs)
    out["localize_with_extraction_ms"], out["localize_with_extraction_cpu_ms"] = per_query(
        lambda s: localize_answers(model, data.observations([s])), q_scans
    )
    batch = queries[:chunk]
    w, c = _wall_cpu(lambda: localize_answers(model, batch), max(1, repeat - 1))
    out["localize_batched_ms"], out["localize_batched_cpu_ms"] = ms * w / len(batch), ms * c / len(batch)
    answers = localize_answers(model, queries)
    truth = np.array([model.column_of(lab) for lab in data.query_labels])
    out["top1"] = float(np.mean(answers["best"] == truth))
    out["mean_rank"] = float(np.mean(answers["ranks"][np.arange(truth.size), truth]))
    out["load_average_1min"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return out
