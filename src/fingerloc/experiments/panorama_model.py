"""The ``PlaceModel`` path of ``fingerloc bench panorama``: what ``learn`` / ``localize`` give a user, and their speed.

:func:`run_preset_loo`: each photo whose place has two or more photos is a
query against a :class:`~fingerloc.model.PlaceModel` fit (with a preset, as
``learn`` fits it) on every other photo; the photos whose place has a single
photo are queries of an *unknown* place (their place is not in the model).
Reported: top-1, the posterior's calibration
(:func:`fingerloc.experiments.panorama.calibration`), the unknown-place
probability of the known and the unknown queries, and where the heading of
each right answer comes from.

:func:`speed`: CPU seconds of ``fingerloc features`` on 2048x1024 copies of
the photos, and of one query against a model of about 1,000 stored views.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..observation import Observation

__all__ = ["run_preset_loo", "speed"]


def run_preset_loo(
    obs: Sequence[Observation],
    labels: Sequence[str],
    *,
    preset: str = "panorama",
    overrides: dict[str, Any] | None = None,
    unknown_prior: float = 0.1,
    max_queries: int | None = None,
    on_step: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Leave-one-out through ``PlaceModel`` with a preset (module docstring).

    Parameters
    ----------
    obs, labels : sequences of one length
        The photos' observations and place labels.
    preset : str
        A preset name (:data:`fingerloc.pipeline.presets.PRESETS`).
    overrides : dict, optional
        PlaceModel options replacing the preset's (JSON form).
    unknown_prior : float
        Prior of the unknown place when its probability is reported (the
        posterior over the learned places does not depend on it).
    max_queries : int, optional
        At most this many known-place queries (a seeded sample), and as many unknown ones.

    Returns
    -------
    dict
        ``top1``, ``n_queries``, ``calibration``, ``temper`` (median, least
        and largest tempering factor of the models), ``variants`` (name ->
        ``top1`` and ``calibration`` of the same models' posterior: ``preset``,
        ``untempered`` (the weighted sum without the factor, with
        ``temper=True``) and each term of positive weight alone), ``unknown`` (mean
        probability of the unknown place for known and unknown queries, and
        the share above 0.5 of each), ``heading_from`` (counts of the heading
        sources of the right answers), ``options`` (the model's options).
    """
    from ..pipeline.presets import resolve_preset
    from .panorama import calibration

    counts: dict[str, int] = {}
    for lab in labels:
        counts[lab] = counts.get(lab, 0) + 1
    known = [k for k, lab in enumerate(labels) if counts[lab] >= 2]
    unknown = [k for k, lab in enumerate(labels) if counts[lab] == 1]
    rng = np.random.default_rng(0)
    if max_queries is not None:
        if len(known) > max_queries:
            known = sorted(rng.choice(known, max_queries, replace=False).tolist())
        if len(unknown) > max_queries:
            unknown = sorted(rng.choice(unknown, max_queries, replace=False).tolist())
    given = {**(overrides or {}), "unknown_prior": unknown_prior}
    resolved = resolve_preset(preset, list(obs), given)
    rows: dict[str, list[np.ndarray]] = {}
    truth: list[int] = []
    tempers: list[float] = []
    p_unknown: dict[str, list[float]] = {"known": [], "unknown": []}
    sources: dict[str, int] = {}
    hits = 0
    todo = [(k, "known") for k in known] + [(k, "unknown") for k in unknown]
    for step, (k, kind) in enumerate(todo):
        train = [o.with_label(labels[i]) for i, o in enumerate(obs) if i != k]
        model = resolved.model().fit(train)
        q = [obs[k]]
        terms = model.term_log_likelihoods(q)
        joint = model.combine(terms)
        p_unknown[kind].append(float(model.predict_unknown_proba(q)[0]))
        if kind == "known":
            tau = float(model.__dict__.get("temper_", 1.0))
            tempers.append(tau)
            for name, row in _variant_rows(model, terms, joint[0], tau).items():
                rows.setdefault(name, []).append(row)
            col = model.column_of(labels[k])
            truth.append(col)
            best = int(np.argmax(joint[0]))
            if best == col:
                hits += 1
                _, _, src = model.heading_sources(q, [model.classes_[best]])
                sources[str(src[0])] = sources.get(str(src[0]), 0) + 1
        if on_step is not None:
            on_step(step + 1, len(todo))
    # every known query's model has the same places (its place keeps another photo): one calibration
    y = np.asarray(truth, dtype=np.int64)
    variants = {}
    for name, r in rows.items():
        m = np.stack(r)
        variants[name] = {"top1": float(np.mean(np.argmax(m, axis=1) == y)), "calibration": calibration(m, y)}
    return {
        "preset": resolved.name,
        "options": {k: v for k, v in resolved.options.items() if k in ("terms", "weights", "temper")},
        "n_queries": len(known),
        "n_unknown_queries": len(unknown),
        "top1": hits / len(known) if known else None,
        "calibration": variants["preset"]["calibration"] if rows else None,
        "temper": {"median": float(np.median(tempers)), "min": min(tempers), "max": max(tempers)} if tempers else None,
        "variants": variants,
        "unknown": {
            kind: {
                "mean": float(np.mean(v)) if v else None,
                "above_0.5": float(np.mean(np.asarray(v) > 0.5)) if v else None,
            }
            for kind, v in p_unknown.items()
        },
        "heading_from": sources,
    }


def _variant_rows(model: Any, terms: dict[str, np.ndarray], joint: np.ndarray, tau: float) -> dict[str, np.ndarray]:
    """One query's log-posterior rows ``(P,)``: the model's, its sum without tempering, each weighted term alone.

    The variants come from the same fitted model (each term is calibrated on
    its own, so a term alone is the model with only that term's weight).
    """
    from ..model import normalise_log

    out = {"preset": normalise_log(joint[None, :])[0]}
    if tau != 1.0:
        out["untempered"] = normalise_log(joint[None, :] / tau)[0]
    weights = model.weights_ if model.weights == "fit" else (model.weights or {})
    for name, ll in terms.items():
        if float(weights.get(name, 1.0)) > 0.0:
            out[name] = normalise_log(np.asarray(ll, dtype=np.float64)[:1])[0]
    return out


def speed(
    photo_files: Sequence[Path],
    obs: Sequence[Observation],
    labels: Sequence[str],
    *,
    n_views: int = 1000,
    n_queries: int = 20,
    preset: str = "panorama",
) -> dict[str, Any]:
    """CPU time of ``features`` on 2048x1024 photos and of ``localize`` against about ``n_views`` stored views.

    ``photo_files``: photos to copy as 2048x1024 JPEG (quality 90) into a
    temporary folder and read back through ``fingerloc features``' reader
    (decoding, band, every feature). The model: the preset fit on the
    observations repeated until ``n_views`` views (each copy with its
    keypoints' bearings and its profile turned by a different angle, so that
    every stored view is distinct; the copies of a photo share its place);
    the queries are ``n_queries`` of the observations, answered one at a
    time (posterior and heading, as ``localize``), with the memo of verified
    pairs emptied after the fit (as in a new ``localize`` process). Times are CPU seconds
    (``time.process_time``: every thread, the BLAS threads' waiting included) and, for localize,
    wall seconds too, with the load average at the start and the BLAS threads (``blas_threads``).
    """
    from dataclasses import replace

    from PIL import Image

    from ..pipeline.files import KINDS, FeatureOptions
    from ..pipeline.presets import resolve_preset

    out: dict[str, Any] = {"load_average": list(os.getloadavg())}
    per: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, f in enumerate(photo_files):
            with Image.open(f) as im:
                small = im.convert("RGB").resize((2048, 1024), Image.Resampling.BOX)
            path = Path(tmp) / f"photo{k}.jpg"
            small.save(path, quality=90)
            t0 = time.process_time()
            for _ in KINDS["panorama"](path, FeatureOptions()):
                pass
            per.append(time.process_time() - t0)
    out["features_cpu_s"] = {"photos": len(per), "mean": float(np.mean(per)) if per else None,
                             "median": float(np.median(per)) if per else None}  # fmt: skip
    views: list[Observation] = []
    copy = 0
    while len(views) < n_views:
        turn = 2.0 * np.pi * ((copy * 0.618034) % 1.0)
        for o, lab in zip(obs, labels, strict=True):
            if len(views) >= n_views:
                break
            views.append(replace(o.rotated(turn), label=lab, source=f"{o.source}#{copy}"))
        copy += 1
    resolved = resolve_preset(preset, views)
    t0 = time.process_time()
    model = resolved.model().fit(views)
    out["learn_cpu_s"] = time.process_time() - t0
    # a localize process starts without the pairs verified at learning (the queries are stored views here)
    from ..terms.keypoints import clear_pair_cache

    clear_pair_cache()
    out["views"] = len(views)
    q = list(obs[:n_queries])
    times, walls = [], []
    for o in q:
        w0, t0 = time.perf_counter(), time.process_time()
        logp = model.predict_log_proba([o])
        model.heading_sources([o], [model.classes_[int(np.argmax(logp[0]))]])
        times.append(time.process_time() - t0)
        walls.append(time.perf_counter() - w0)
    out["localize_cpu_s"] = {"queries": len(times), "mean": float(np.mean(times)), "median": float(np.median(times))}
    out["localize_wall_s"] = {"queries": len(walls), "mean": float(np.mean(walls)), "median": float(np.median(walls))}
    out["blas_threads"] = _blas_threads()
    return out


def _blas_threads() -> int | None:
    """Threads of the BLAS numpy uses (their spinning counts in the process's CPU time), None when unknown."""
    try:
        from threadpoolctl import threadpool_info  # a dependency of scikit-learn (the bench extra)
    except ImportError:
        return None
    blas = [int(i["num_threads"]) for i in threadpool_info() if i.get("user_api") == "blas"]
    return max(blas) if blas else None
