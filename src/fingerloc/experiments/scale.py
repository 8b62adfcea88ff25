"""``fingerloc bench scale``: learning and localizing among 1,000 to 100,000 places.

For each size ``N`` and each preset, on the first ``N`` places of the
simulated campus (:mod:`fingerloc.sim.campus`: rooms and corridors, 3
training views a place on the paper's circle and one query inside it; a
360 deg laser of 360 beams, plus a camera for the ``paper`` preset, whose
mixtures of bearings need every view at one heading, as in the paper's
protocol; ``laser2d`` views have random headings):

1. *learn* (a fresh process): draw the campus, ``PlaceModel.fit`` with the
   preset, save the place database. ``learn_s`` is the fit alone (wall and
   process CPU, ``learn_cpu_s``); ``db_mb`` the database file;
   ``learn_peak_rss_mb`` the process's peak resident memory (the drawn
   campus included).
2. *localize* (another fresh process, as ``fingerloc localize`` would be;
   the queries are drawn with the campus in the first process and handed
   over): load the database (``load_s``), build the exact index
   (:class:`fingerloc.retrieval.PlaceIndex`, ``index_s``), then answer the
   queries of ``queries`` random places: the best 5 places exactly, their
   posterior, and the heading at the best place (for a cyclic model), one
   query at a time (``localize_ms``, ``localize_cpu_ms``) and in chunks of 256
   (``localize_batched_ms``). ``top1`` and ``mean_rank`` are those of the
   true places (the rank exactly: the index scores every place that could
   rank above the truth); ``peak_rss_mb`` is this process's peak resident
   memory.
3. *exactness*: for ``exact_queries`` of the queries the linear scan
   (``model.joint_log_likelihood``, every place) is run too (``linear_ms``):
   ``exact`` is true when every one has the same 5 best places in the same
   order with bit-identical joint log-likelihoods. ``scored`` is the mean
   number of places the index scored in full, ``mass_bound`` the median
   bound on the posterior mass of the places it did not score, relative to
   those it did (:mod:`fingerloc.retrieval`).
4. *the posterior*: ``localize`` asks the index for every probability
   within :data:`~fingerloc.retrieval.POSTERIOR_TOL` (1e-9) of the linear
   scan's; ``localize_posterior_ms`` (and ``_cpu_ms``) times that for the
   first :data:`POSTERIOR_QUERIES` queries, ``scored_posterior`` the places
   it scored, ``exact_posterior`` checks the 5 best places and their
   probabilities against the linear scan (those of the exactness queries).
   ``index_used_by_localize``: whether ``localize`` goes through the index
   at this size (:func:`~fingerloc.retrieval.index_for`).

Also the 1-minute load average at the end of each step: timings on a
shared machine are only comparable with it.
"""

from __future__ import annotations

import math
import os
import resource
import tempfile
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidParameterError

__all__ = ["PRESETS", "run_scale", "scale_figures"]

#: The presets measured, and how their views are drawn: (camera, random heading).
PRESETS: dict[str, tuple[bool, bool]] = {"laser2d": (False, True), "paper": (True, False)}
#: Queries answered with the posterior within the tolerance ``localize`` asks (``localize_posterior_ms``).
POSTERIOR_QUERIES = 20
#: Queries answered in one batch by the batched figure (``localize`` reads a log 256 at a time).
CHUNK = 256


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _load1() -> float:
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


def _campus(preset: str, n_places: int, seed: int, query_places: np.ndarray | None) -> tuple[list[Any], list[Any]]:
    """Training views of every place and the queries of ``query_places`` (all when None)."""
    from ..sim.campus import campus_chunks

    camera, random_heading = PRESETS[preset]
    train: list[Any] = []
    queries: list[Any] = []
    wanted = None if query_places is None else set(int(p) for p in query_places)
    for ch in campus_chunks(n_places, camera=camera, random_heading=random_heading, seed=seed):
        train += ch.train
        for i, o in enumerate(ch.queries):
            if wanted is None or ch.first + i in wanted:
                queries.append(o)
    return train, queries


def _query_places(n_places: int, n_queries: int, seed: int) -> np.ndarray:
    """The places queried: ``n_queries`` random ones (all when fewer), ascending."""
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(n_places, min(n_queries, n_places), replace=False))


def _learn_step(preset: str, n_places: int, seed: int, db: str, n_queries: int) -> tuple[dict[str, Any], list[Any]]:
    """Fresh process: draw the campus, learn, save. Returns the learn figures and the queries (drawn with the campus)."""
    from ..map.database import save_model
    from ..pipeline.presets import resolve_preset

    t0 = time.perf_counter()
    train, queries = _campus(preset, n_places, seed, _query_places(n_places, n_queries, seed))
    simulate_s = time.perf_counter() - t0
    model = resolve_preset(preset).model()
    w0, c0 = time.perf_counter(), time.process_time()
    model.fit(train)
    learn_s, learn_cpu_s = time.perf_counter() - w0, time.process_time() - c0
    del train
    t0 = time.perf_counter()
    size = save_model(model, db)
    cal = {name: getattr(t, "calibration_", {}) for name, t in model.terms_.items() if getattr(t, "calibration_", None)}
    return {
        "places": n_places,
        "views": int(sum(len(p.observations) for p in model.places_.values())),
        "simulate_s": simulate_s,
        "learn_s": learn_s,
        "learn_cpu_s": learn_cpu_s,
        "save_s": time.perf_counter() - t0,
        "db_mb": size / 1e6,
        "learn_peak_rss_mb": _peak_rss_mb(),
        "calibration": cal,
        "load_average_learn": _load1(),
    }, queries


def _localize_step(db: str, queries: list[Any], exact_queries: int, repeat: int) -> dict[str, Any]:
    """Fresh process: load, index, answer the queries (module docstring). Returns the localize figures."""
    from ..map.database import load_model
    from ..model import normalise_log
    from ..retrieval import POSTERIOR_TOL, PlaceIndex, index_for

    t0 = time.perf_counter()
    model = load_model(db)
    load_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    index = PlaceIndex(model)
    index_s = time.perf_counter() - t0
    labels = [o.label for o in queries]

    def localize(obs: Sequence[Any]) -> Any:
        res = index.search(obs, k=5)
        if model.cyclic:  # the heading at the best place, with its reference view (as localize shows)
            model.headings_with_reference(obs, [model.classes_[int(j)] for j in res.places[:, 0]])
        return res

    localize(queries[:2])  # compile
    walls, cpus = [], []
    for o in queries:
        best_w = best_c = math.inf
        for _ in range(repeat):
            w0, c0 = time.perf_counter(), time.process_time()
            localize([o])
            best_w, best_c = min(best_w, time.perf_counter() - w0), min(best_c, time.process_time() - c0)
        walls.append(best_w)
        cpus.append(best_c)
    batch = queries[:CHUNK]
    w0, c0 = time.perf_counter(), time.process_time()
    localize(batch)
    batched_ms, batched_cpu_ms = 1e3 * (time.perf_counter() - w0) / len(batch), 1e3 * (time.process_time() - c0) / len(batch)
    ranked = index.search(queries, k=5, truth=labels)
    truth = np.array([model.column_of(lab) for lab in labels])
    plain = index.search(queries, k=5)
    out: dict[str, Any] = {
        "queries": len(queries),
        "load_s": load_s,
        "index_s": index_s,
        "groups": index.layout.n_groups,
        "localize_ms": 1e3 * float(np.mean(walls)),
        "localize_cpu_ms": 1e3 * float(np.mean(cpus)),
        "localize_batched_ms": batched_ms,
        "localize_batched_cpu_ms": batched_cpu_ms,
        "top1": float(np.mean(plain.places[:, 0] == truth)),
        "mean_rank": float(np.mean(ranked.rank_of_truth)),
        "scored": float(np.mean(plain.scored)),
        "mass_bound": float(np.median(plain.mass_bound)),
    }
    # the posterior within POSTERIOR_TOL, as ``localize`` asks of the index (on the first queries)
    n_post = min(POSTERIOR_QUERIES, len(queries))
    w0, c0 = time.perf_counter(), time.process_time()
    post = index.search(queries[:n_post], k=5, tol=POSTERIOR_TOL)
    out["localize_posterior_ms"] = 1e3 * (time.perf_counter() - w0) / max(n_post, 1)
    out["localize_posterior_cpu_ms"] = 1e3 * (time.process_time() - c0) / max(n_post, 1)
    out["scored_posterior"] = float(np.mean(post.scored)) if n_post else None
    n_check = min(exact_queries, len(queries))
    same = same_post = True
    lin = []
    for i in range(n_check):
        c0 = time.process_time()
        joint = model.joint_log_likelihood([queries[i]])[0]
        lin.append(time.process_time() - c0)
        top = np.lexsort((np.arange(joint.size), -joint))[:5]
        same &= bool(np.array_equal(top, plain.places[i]) and np.array_equal(joint[top], plain.joint[i]))
        if i < n_post:
            p_lin = np.exp(normalise_log(joint[None, :])[0, top])
            same_post &= bool(np.array_equal(top, post.places[i]) and np.max(np.abs(p_lin - np.exp(post.log_posterior[i]))) <= POSTERIOR_TOL)
    out.update(
        exact=same, exact_posterior=same_post, exact_queries=n_check, linear_cpu_ms=1e3 * float(np.mean(lin)) if lin else None,
        index_used_by_localize=index_for(model) is not None,
    )  # fmt: skip
    out["peak_rss_mb"] = _peak_rss_mb()
    out["load_average"] = _load1()
    return out


def _in_child(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` in a fresh process (its own memory figures)."""
    with ProcessPoolExecutor(max_workers=1, mp_context=get_context("spawn")) as pool:
        return pool.submit(fn, *args).result()


def scale_figures(
    preset: str,
    n_places: int,
    *,
    seed: int = 20040426,
    n_queries: int = 200,
    exact_queries: int = 20,
    repeat: int = 3,
    workdir: str | Path | None = None,
) -> dict[str, Any]:
    """The figures of one preset at one size (module docstring), each step in its own process."""
    if preset not in PRESETS:
        raise InvalidParameterError(f"unknown preset {preset!r} for bench scale (known: {', '.join(PRESETS)})")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        db = str(Path(tmp) / "places.sqlite")
        out, queries = _in_child(_learn_step, preset, n_places, seed, db, n_queries)
        out.update(_in_child(_localize_step, db, queries, exact_queries, repeat))
    out["size_wall_s"] = time.perf_counter() - t0  # this size and preset, from the first drawn place to the last answer
    return out


def run_scale(
    sizes: Sequence[int],
    *,
    presets: Sequence[str] = tuple(PRESETS),
    seed: int = 20040426,
    n_queries: int = 200,
    exact_queries: int = 20,
    repeat: int = 3,
    on_step: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """``{"presets": {name: {"sizes": {N: figures}}}, "wall_s": ...}`` for every preset and size."""
    for n in sizes:
        if isinstance(n, bool) or not isinstance(n, int) or n < 2:
            raise InvalidParameterError(f"--places: sizes must be integers >= 2, got {n!r}")
    for p in presets:
        if p not in PRESETS:
            raise InvalidParameterError(f"--preset: unknown preset {p!r} (known: {', '.join(PRESETS)})")
    t0 = time.perf_counter()
    res: dict[str, Any] = {"presets": {}, "seed": seed, "queries": n_queries, "exact_queries": exact_queries}
    for p in presets:
        sizes_out: dict[str, Any] = {}
        for n in sizes:
            if on_step is not None:
                on_step(f"{p}, {n:,} places")
            sizes_out[str(n)] = scale_figures(p, n, seed=seed, n_queries=n_queries, exact_queries=exact_queries, repeat=repeat)
        res["presets"][p] = {"sizes": sizes_out}
    res["wall_s"] = time.perf_counter() - t0
    return res
